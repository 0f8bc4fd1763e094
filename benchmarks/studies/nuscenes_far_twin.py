"""The nuScenes `uncovered` gap against a twin with the real sample's far edges (issue 37, nusc11).

    PYTHONPATH=. python -m benchmarks.studies.nuscenes_far_twin \
        [--layouts street open] [--twin-seeds 0 1] [--seeds 0 1 2 3 4] [--scale 1] [--skip-real] \
        [--json benchmarks/results/nuscenes_far_twin_nusc11.json]

1. **Scene statistics** (:func:`jaxdepth.research.twin_measure.scene_statistics`) of the real nuScenes
   sample and of the nuScenes twin in each scene layout (``make_twin(layout=)``; ``"street"`` the
   default canyon, ``"open"`` the right side open as the real sample's): per camera the depth histogram
   of the LiDAR points and their share beyond 20 / 40 m, depth edges per scan line by the far side's
   range; and per hold-out draw (``hidden-eval``'s protocol, 20 % of the points at >= 1 m) the share of
   the targets covered (a nearer point within the 9 x 9 window) and the **far edge targets**:
   `uncovered` targets at >= 20 m where the SGM and the city-block fill predict different surfaces
   (more than max(1 m, 5 %) apart), the statistic of ``nuscenes_uncovered_gap``. The real sample's
   draws run :func:`benchmarks.studies.nuscenes_uncovered_gap.draw_pixels` (the same code and draws).
2. **Scores on each twin** (1 sweep, the single-sweep path a user's point file and rig JSON take):
   the SGM default, without removal, both nearest fills (city block, Euclidean) and IP_Basic, on the
   whole input against the exact depth of every pixel, and per draw against the exact depth of every
   pixel, at the held-out pixels and under both protocols (all targets, `uncovered`); the baselines
   fill the prepared frame's points (as ``benchmarks.accuracy_twins``). At the far edge targets the
   MAE difference SGM minus city-block fill against the targets and against the exact depth (the
   same weights as ``nuscenes_uncovered_gap``: each target 1 / (images x its image's targets)).
3. **A far-edge rule, checked** (``sgm_far_fill``, a study patch, not a library option): the SGM's
   depth, but the city-block fill's where the two are more than max(1 m, 5 %) apart and the farther
   of them is >= 20 m (the far edge pixels, chosen without the truth). Scored as the methods above,
   and on the real sample's `uncovered` targets of the same draws.

Nothing here changes a default; the twins' exact depth is read only to score.
"""

from __future__ import annotations

import argparse
import glob
import tempfile
import time

import numpy as np

from benchmarks._common import DATA, RESULTS, write_results
from jaxdepth._src.config import SGMConfig

METHODS = ("sgm", "sgm_no_removal", "nearest", "nearest_l2", "ip_basic", "sgm_far_fill")
PROTOCOLS = ("exact_dense", "exact_held_out", "hidden_all", "hidden_uncovered")
FAR_M = 20.0


def _off(a, b):
    """|a - b| > max(1 m, 5 % of b) (another surface)."""
    return np.abs(a - b) > np.maximum(1.0, 0.05 * b)


def far_fill(sgm: np.ndarray, fill: np.ndarray) -> np.ndarray:
    """``sgm_far_fill``: the fill where it and the SGM are apart and the farther is >= :data:`FAR_M`."""
    far = (np.maximum(sgm, fill) >= FAR_M) & _off(sgm, fill) & (fill > 0)
    return np.where(far, fill, sgm).astype(np.float32)


def methods(inp, keep, config: SGMConfig) -> dict:
    """{method: [camera image]} of :data:`METHODS` on the input's points where ``keep`` (single-sweep path)."""
    from benchmarks.accuracy_twins import crops, single_path, z_buffers
    from jaxdepth._src.methods import complete_with
    cloud = inp.cloud.take(keep)
    plain = config.replace(outlier_removal=False)
    sgm, _ = single_path(cloud.points, cloud.ring, inp.rig, config)
    no_removal, frame = single_path(cloud.points, cloud.ring, inp.rig, plain)
    out = {"sgm": crops(sgm, inp.rig), "sgm_no_removal": crops(no_removal, inp.rig)}
    sparse = z_buffers(frame.points, frame.rig)
    for name, method, metric in (("nearest", "nearest", "l1"), ("nearest_l2", "nearest", "l2"),
                                 ("ip_basic", "ip-basic", "l1")):
        cfg = plain.replace(distance_metric=metric)
        out[name] = [np.asarray(complete_with(s, c.K, c.T_cam_lidar, method=method, config=cfg, lidar=frame.rig.lidar))
                     for s, c in zip(sparse, frame.rig.cameras)]
    out["sgm_far_fill"] = [far_fill(s, f) for s, f in zip(out["sgm"], out["nearest"])]
    return out


def far_edges(preds: dict, target: list, covered: list, exact: list) -> dict:
    """At the `uncovered` targets: the far edge share and the MAE difference SGM minus city-block fill
    (mm; weights 1 / (images x the image's targets)) at the far edges and elsewhere, against the targets
    and against the exact depth; and the rule's difference against the SGM."""
    rows = {k: [] for k in ("z", "exact", "sgm", "nearest", "rule", "weight")}
    images = 0
    for i, (t, cv, e) in enumerate(zip(target, covered, exact)):
        sel = (t > 0) & ~cv & (e > 0)
        n = int(sel.sum())
        if not n:
            continue
        images += 1
        rows["z"].append(t[sel])
        rows["exact"].append(e[sel])
        for m, key in (("sgm", "sgm"), ("nearest", "nearest"), ("sgm_far_fill", "rule")):
            rows[key].append(preds[m][i][sel])
        rows["weight"].append(np.full(n, 1.0 / n))
    p = {k: np.concatenate(v).astype(np.float64) for k, v in rows.items()}
    w = p["weight"] / max(images, 1)
    far = (p["z"] >= FAR_M) & _off(p["sgm"], p["nearest"])
    out = {"targets": int(len(w)), "far_edge_share": float(far.mean()),
           "far_edge_share_exact": float(((p["exact"] >= FAR_M) & _off(p["sgm"], p["nearest"])).mean())}
    for truth in ("z", "exact"):
        diff = np.abs(p["sgm"] - p[truth]) - np.abs(p["nearest"] - p[truth])
        rule = np.abs(p["rule"] - p[truth]) - np.abs(p["sgm"] - p[truth])
        name = "targets" if truth == "z" else "exact"
        out[f"against_{name}"] = {"sgm_minus_fill_far_mm": float(1000 * np.sum((diff * w)[far])),
                                  "sgm_minus_fill_rest_mm": float(1000 * np.sum((diff * w)[~far])),
                                  "rule_minus_sgm_mm": float(1000 * np.sum(rule * w))}
    return out


def twin_case(layout: str, scene_seed: int, draws, scale: float, config: SGMConfig) -> dict:
    from benchmarks.accuracy_twins import (
        cover_half_height,
        exact_truth,
        hold_out,
        protocol_truths,
        read_user_input,
        score,
    )
    from jaxdepth.research.twin_measure import scene_statistics
    from jaxdepth.research.twins import make_twin, write_twin
    tw = make_twin("nuscenes", sweeps=1, seed=scene_seed, scale=scale, layout=layout)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(tw, tmp)
        inp = read_user_input(paths["sweeps"][0], paths["rig"])
    assert not inp.multi, "the nuScenes twin at 1 sweep takes the single-sweep path"
    exact = exact_truth(tw, inp.rig)
    case = {"layout": layout, "seed": scene_seed, "scale": scale, "points": len(inp.cloud.points),
            "statistics": scene_statistics(inp.cloud.points, inp.cloud.ring, inp.rig.cameras)}
    full = methods(inp, np.ones(len(inp.cloud.points), bool), config)
    case["full"] = {m: score(full[m], exact) for m in METHODS}
    half = cover_half_height(inp)
    case["draws"] = []
    for d in draws:
        hidden, targets, full_z = hold_out(inp, d)
        truths, stats = protocol_truths(exact, targets, full_z, half)
        preds = methods(inp, ~hidden, config)
        covered = [(t > 0) & (u == 0) for t, u in zip(targets, truths["hidden_uncovered"])]
        case["draws"].append({"draw": d, **stats, "far_edges": far_edges(preds, targets, covered, exact),
                              "scores": {p: {m: score(preds[m], truths[p]) for m in METHODS} for p in PROTOCOLS}})
        print(f"  {layout} seed {scene_seed} draw {d}: far edge share {case['draws'][-1]['far_edges']['far_edge_share']:.4f}",
              flush=True)
    return case


def real_sample(draws, config: SGMConfig) -> dict:
    from benchmarks.studies.nuscenes_uncovered_gap import _concat, draw_pixels
    from jaxdepth.io import read_points, rig_from_nuscenes_calibration
    from jaxdepth.io.points import ring_column
    from jaxdepth.research.twin_measure import scene_statistics
    nus = DATA / "nuscenes" / "sample"
    rig = rig_from_nuscenes_calibration(nus / "calibration.json")
    points, extra = read_points(glob.glob(str(nus / "*LIDAR_TOP*.pcd.bin"))[0], columns=5)
    ring = ring_column(extra, 5)
    row = {"statistics": scene_statistics(points, ring, rig.cameras)}
    per = [draw_pixels(points, ring, rig, d, config) for d in draws]
    row["covered_share"] = [float(x["covered_share"]) for x in per]
    p = _concat(per)
    w = p["weight"]
    far = (p["z"] >= FAR_M) & _off(p["sgm"], p["nearest"])
    rule = far_fill(p["sgm"], p["nearest"])
    _, inverse = np.unique(p["image"], return_inverse=True)
    count = np.bincount(inverse)

    def rm(pred):
        e = np.abs(pred.astype(np.float64) - p["z"])
        return [float(1000 * np.mean(np.sqrt(np.bincount(inverse, e ** 2) / count))), float(1000 * np.sum(e * w))]

    diff = np.abs(p["sgm"] - p["z"]) - np.abs(p["nearest"] - p["z"])
    row.update({"targets": int(len(w)), "far_edge_share": float(far.mean()),
                "uncovered_rmse_mae_mm": {"sgm": rm(p["sgm"]), "nearest": rm(p["nearest"]), "sgm_far_fill": rm(rule)},
                "sgm_minus_fill_far_mm": float(1000 * np.sum((diff * w)[far])),
                "sgm_minus_fill_rest_mm": float(1000 * np.sum((diff * w)[~far]))})
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layouts", nargs="+", default=["street", "open"])
    parser.add_argument("--twin-seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4], help="hold-out draws")
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--skip-real", action="store_true")
    parser.add_argument("--json", default=str(RESULTS / "nuscenes_far_twin_nusc11.json"))
    args = parser.parse_args(argv)
    config = SGMConfig()
    t0 = time.time()
    doc = {"settings": {"layouts": args.layouts, "twin_seeds": args.twin_seeds, "draws": args.seeds,
                        "scale": args.scale, "far_m": FAR_M}}
    if not args.skip_real:
        doc["real_sample"] = real_sample(args.seeds, config)
        r = doc["real_sample"]
        print(f"real ({time.time() - t0:.0f} s): far edge share {r['far_edge_share']:.4f} "
              f"uncovered {r['uncovered_rmse_mae_mm']}", flush=True)
        write_results(args.json, doc, config, t0)
    doc["twins"] = []
    for layout in args.layouts:
        for s in args.twin_seeds:
            doc["twins"].append(twin_case(layout, s, args.seeds, args.scale, config))
            print(f"{layout} seed {s} done ({time.time() - t0:.0f} s)", flush=True)
            write_results(args.json, doc, config, t0)
    write_results(args.json, doc, config, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
