"""The nuScenes `uncovered` gap against a twin with the real sample's far edges (issue 37, nusc11).

    PYTHONPATH=. python -m benchmarks.studies.nuscenes_far_twin \
        [--layouts street open] [--twin-seeds 0 1] [--seeds 0 1 2 3 4] [--scale 1] [--skip-real] \
        [--json benchmarks/results/nuscenes_far_twin_nusc11.json]
    PYTHONPATH=. python -m benchmarks.studies.nuscenes_far_twin --tables benchmarks/results/nuscenes_far_twin_nusc11.json
    PYTHONPATH=. python -m benchmarks.studies.nuscenes_far_twin --layouts cluttered --skip-real \
        --json benchmarks/results/nuscenes_far_twin_nusc12.json      # nusc12: near clutter, denser far vegetation
    PYTHONPATH=. python -m benchmarks.studies.nuscenes_far_twin --tables benchmarks/results/nuscenes_far_twin_nusc11.json \
        benchmarks/results/nuscenes_far_twin_nusc12.json
    PYTHONPATH=. python -m benchmarks.studies.nuscenes_far_twin --other-twins kitti raster rosette --scale 0.25 \
        --json benchmarks/results/nuscenes_far_twin_others_nusc11.json
    PYTHONPATH=. python -m benchmarks.studies.nuscenes_far_twin --near-only --layouts open cluttered \
        --json benchmarks/results/nuscenes_near_stats_nusc13.json                   # nusc13: near statistics
    PYTHONPATH=. python -m benchmarks.studies.nuscenes_far_twin --layouts open cluttered --skip-real --near-bands \
        --ego --json benchmarks/results/nuscenes_far_twin_ego_nusc13.json           # nusc13: real near returns

1. **Scene statistics** (:func:`jaxdepth.research.twin_measure.scene_statistics`) of the real nuScenes
   sample and of the nuScenes twin in each scene layout (``make_twin(layout=)``; ``"street"`` the
   default canyon, ``"open"`` the right side open as the real sample's, ``"cluttered"`` (nusc12) the open
   one with the real sample's near clutter and denser far vegetation): per camera the depth histogram
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
   same weights as ``nuscenes_uncovered_gap``: each target 1 / (images x its image's targets)); the
   difference elsewhere also split by target depth (:data:`REST_BANDS_M`, nusc12).
3. **Far-edge rules, checked** (:data:`RULES`, study patches, not library options): the SGM's depth
   except at the far edge pixels (:func:`far_pixels`: the SGM and the city-block fill more than
   max(1 m, 5 %) apart and the farther of them >= 20 m, chosen without the truth), where the rule takes
   the fill (``sgm_far_fill``), the SGM without Step 4's Gaussian (``sgm_far_raw``), the nearer
   (``sgm_far_near``, a Step 3 side choice) or the farther (``sgm_far_far``) of the two. Scored as the
   methods above, on the real sample's `uncovered` targets of the same draws, and (``--other-twins``)
   on other twins' exact depth.

4. **Near range** (nusc13): ``--near-only`` measures :func:`~jaxdepth.research.twin_measure.near_statistics`
   on the real sweep and the twin; ``--near-bands`` gives the twin the real sweep's noise and dropouts per
   near range band (:func:`~jaxdepth.research.twin_measure.band_effects`), ``--ego`` its ego returns
   (``make_twin(ego=)``), for the scores of 2.

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

METHODS = ("sgm", "sgm_no_removal", "nearest", "nearest_l2", "ip_basic", "sgm_far_fill", "sgm_far_raw",
           "sgm_far_near", "sgm_far_far")
#: The far-edge rules (study patches): at the far edge pixels (:func:`far_pixels`) the fill, the SGM without
#: Step 4's Gaussian, the nearer or the farther of the SGM and the fill; the SGM elsewhere.
RULES = ("sgm_far_fill", "sgm_far_raw", "sgm_far_near", "sgm_far_far")
PROTOCOLS = ("exact_dense", "exact_held_out", "hidden_all", "hidden_uncovered")
FAR_M = 20.0
#: Target depth bands (m) of the "elsewhere" difference's split (nusc12).
REST_BANDS_M = (0.0, 10.0, 20.0, np.inf)


def _off(a, b):
    """|a - b| > max(1 m, 5 % of b) (another surface)."""
    return np.abs(a - b) > np.maximum(1.0, 0.05 * b)


def rest_by_range(diff: np.ndarray, w: np.ndarray, far: np.ndarray, z: np.ndarray) -> dict:
    """The weighted sum (mm) of ``diff`` away from the far edges per :data:`REST_BANDS_M` band of target depth."""
    out = {}
    for lo, hi in zip(REST_BANDS_M, REST_BANDS_M[1:]):
        sel = ~far & (z >= lo) & (z < hi)
        out[f"{lo:g}-{hi:g}"] = float(1000 * np.sum((diff * w)[sel]))
    return out


def far_pixels(sgm: np.ndarray, fill: np.ndarray) -> np.ndarray:
    """The far edge pixels a rule may see: the SGM and the fill apart, the farther >= :data:`FAR_M`."""
    return (np.maximum(sgm, fill) >= FAR_M) & _off(sgm, fill) & (fill > 0)


def rules(sgm: np.ndarray, fill: np.ndarray, raw: np.ndarray) -> dict:
    """{rule: depth} of :data:`RULES` (``raw``: the SGM without Step 4's Gaussian, kept pixels kept)."""
    far = far_pixels(sgm, fill)
    pick = {"sgm_far_fill": fill, "sgm_far_raw": raw, "sgm_far_near": np.minimum(sgm, fill),
            "sgm_far_far": np.maximum(sgm, fill)}
    return {k: np.where(far, v, sgm).astype(np.float32) for k, v in pick.items()}


def methods(inp, keep, config: SGMConfig) -> dict:
    """{method: [camera image]} of :data:`METHODS` on the input's points where ``keep`` (single-sweep path)."""
    from benchmarks.accuracy_twins import crops, single_path, z_buffers
    from benchmarks.studies.nuscenes_uncovered_gap import _finish
    from jaxdepth._src.methods import complete_with
    cloud = inp.cloud.take(keep)
    plain = config.replace(outlier_removal=False)
    st, _ = single_path(cloud.points, cloud.ring, inp.rig, config, stages=True)
    every = np.ones(np.shape(st.depth), bool)
    raw = _finish(np.asarray(st.depth_raw)[every], st, every).reshape(np.shape(st.depth))
    no_removal, frame = single_path(cloud.points, cloud.ring, inp.rig, plain)
    out = {"sgm": crops(np.asarray(st.depth), inp.rig), "sgm_no_removal": crops(no_removal, inp.rig)}
    sparse = z_buffers(frame.points, frame.rig)
    for name, method, metric in (("nearest", "nearest", "l1"), ("nearest_l2", "nearest", "l2"),
                                 ("ip_basic", "ip-basic", "l1")):
        cfg = plain.replace(distance_metric=metric)
        out[name] = [np.asarray(complete_with(s, c.K, c.T_cam_lidar, method=method, config=cfg, lidar=frame.rig.lidar))
                     for s, c in zip(sparse, frame.rig.cameras)]
    per = [rules(s, f, r) for s, f, r in zip(out["sgm"], out["nearest"], crops(raw, inp.rig))]
    out.update({k: [r[k] for r in per] for k in RULES})
    return out


def far_edges(preds: dict, target: list, covered: list, exact: list) -> dict:
    """At the `uncovered` targets: the far edge share and the MAE difference SGM minus city-block fill
    (mm; weights 1 / (images x the image's targets)) at the far edges and elsewhere, against the targets
    and against the exact depth; and the rule's difference against the SGM."""
    rows = {k: [] for k in ("z", "exact", "sgm", "nearest", "weight") + RULES}
    images = 0
    for i, (t, cv, e) in enumerate(zip(target, covered, exact)):
        sel = (t > 0) & ~cv & (e > 0)
        n = int(sel.sum())
        if not n:
            continue
        images += 1
        rows["z"].append(t[sel])
        rows["exact"].append(e[sel])
        for m in ("sgm", "nearest") + RULES:
            rows[m].append(preds[m][i][sel])
        rows["weight"].append(np.full(n, 1.0 / n))
    p = {k: np.concatenate(v).astype(np.float64) for k, v in rows.items()}
    w = p["weight"] / max(images, 1)
    far = (p["z"] >= FAR_M) & _off(p["sgm"], p["nearest"])
    out = {"targets": int(len(w)), "far_edge_share": float(far.mean()),
           "far_edge_share_exact": float(((p["exact"] >= FAR_M) & _off(p["sgm"], p["nearest"])).mean())}
    for truth in ("z", "exact"):
        diff = np.abs(p["sgm"] - p[truth]) - np.abs(p["nearest"] - p[truth])
        name = "targets" if truth == "z" else "exact"
        out[f"against_{name}"] = {"sgm_minus_fill_far_mm": float(1000 * np.sum((diff * w)[far])),
                                  "sgm_minus_fill_rest_mm": float(1000 * np.sum((diff * w)[~far])),
                                  "sgm_minus_fill_rest_by_range_mm": rest_by_range(diff, w, far, p["z"])}
        for k in RULES:
            rule = np.abs(p[k] - p[truth]) - np.abs(p["sgm"] - p[truth])
            out[f"against_{name}"][f"{k}_minus_sgm_mm"] = float(1000 * np.sum(rule * w))
    return out


def twin_case(layout: str, scene_seed: int, draws, scale: float, config: SGMConfig, effects=True, ego=None) -> dict:
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
    tw = make_twin("nuscenes", sweeps=1, seed=scene_seed, scale=scale, layout=layout, effects=effects, ego=ego)
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


def other_twins(rigs, seeds, scale: float, config: SGMConfig) -> list:
    """The rules on other twins (1 sweep, default layout, whole input) against the exact depth of every
    pixel; a twin whose 1-sweep input takes the multi-source path is skipped (the rules patch the single path)."""
    from benchmarks.accuracy_twins import exact_truth, read_user_input, score
    from jaxdepth.research.twins import make_twin, write_twin
    out = []
    for rig in rigs:
        for seed in seeds:
            tw = make_twin(rig, sweeps=1, seed=seed, scale=scale)
            with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
                paths = write_twin(tw, tmp)
                inp = read_user_input(paths["sweeps"][0], paths["rig"])
            if inp.multi:
                out.append({"rig": rig, "seed": seed, "skipped": "multi-source path"})
                continue
            exact = exact_truth(tw, inp.rig)
            preds = methods(inp, np.ones(len(inp.cloud.points), bool), config)
            out.append({"rig": rig, "seed": seed, "scale": scale,
                        "exact_dense": {m: score(preds[m], exact) for m in ("sgm", "nearest") + RULES}})
            print(f"  {rig} seed {seed}: " + ", ".join(f"{m} {v['rmse']:.1f} / {v['mae']:.1f}"
                                                       for m, v in out[-1]["exact_dense"].items()), flush=True)
    return out


def real_near_effects():
    """(the nuScenes twin's rates with range bands measured on the real sweep, the real sweep's
    :func:`~jaxdepth.research.twin_measure.near_statistics`) (nusc13, ``--near-bands``)."""
    from jaxdepth.io import read_points
    from jaxdepth.io.points import ring_column
    from jaxdepth.research.twin_measure import band_effects, near_statistics
    from jaxdepth.research.twin_sensors import SensorEffects
    from jaxdepth.research.twin_tables import SENSOR_EFFECTS
    points, extra = read_points(glob.glob(str(DATA / "nuscenes" / "sample" / "*LIDAR_TOP*.pcd.bin"))[0], columns=5)
    near = near_statistics(points, ring_column(extra, 5))
    return band_effects(near, SensorEffects(**SENSOR_EFFECTS["nuscenes"])), near


def real_ego_table() -> dict:
    """The real sweep's returns per ring for ``make_twin(ego=)`` (nusc13, ``--ego``)."""
    from jaxdepth.io import read_points
    from jaxdepth.io.points import ring_column
    from jaxdepth.research.twin_measure import ego_table
    points, extra = read_points(glob.glob(str(DATA / "nuscenes" / "sample" / "*LIDAR_TOP*.pcd.bin"))[0], columns=5)
    return ego_table(points, ring_column(extra, 5))


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
    checked = rules(p["sgm"], p["nearest"], p["sgm_raw"])
    _, inverse = np.unique(p["image"], return_inverse=True)
    count = np.bincount(inverse)

    def rm(pred):
        e = np.abs(pred.astype(np.float64) - p["z"])
        return [float(1000 * np.mean(np.sqrt(np.bincount(inverse, e ** 2) / count))), float(1000 * np.sum(e * w))]

    diff = np.abs(p["sgm"] - p["z"]) - np.abs(p["nearest"] - p["z"])
    row.update({"targets": int(len(w)), "far_edge_share": float(far.mean()),
                "uncovered_rmse_mae_mm": {"sgm": rm(p["sgm"]), "nearest": rm(p["nearest"]),
                                          **{k: rm(v) for k, v in checked.items()}},
                "sgm_minus_fill_far_mm": float(1000 * np.sum((diff * w)[far])),
                "sgm_minus_fill_rest_mm": float(1000 * np.sum((diff * w)[~far])),
                "sgm_minus_fill_rest_by_range_mm": rest_by_range(diff, w, far, p["z"])})
    return row


#: The near statistics' rows in :func:`near_table` (key, label, scale to print).
NEAR_ROWS = (("points_share", "share of all points", 1.0), ("ground_second_diff_m", "ground second difference, mm", 1000.0),
             ("ground_second_diff_p90_m", "same, 90th percentile of |.|, mm", 1000.0),
             ("second_diff_m", "every smooth triple's second difference, mm", 1000.0),
             ("second_diff_p90_m", "same, 90th percentile of |.|, mm", 1000.0),
             ("dropout", "dropouts where the surface continues", 1.0),
             ("edge_triples", "edge triples (ends apart > max(1 m, 10 %))", 1.0),
             ("mixed_share", "of those, mixed (middle between)", 1.0),
             ("spike_near_share", "near spikes per smooth triple", 1.0),
             ("spike_far_share", "far spikes per smooth triple", 1.0))


def _camera_near(points, cameras) -> dict:
    """Per camera, the points projecting into it within 4 and 5 m of camera depth."""
    from jaxdepth.research.twin_measure import camera_depths
    out = {}
    for c in cameras:
        z = camera_depths(points, c.K, c.T_cam_lidar, c.width, c.height)
        out[c.name] = [int((z < 4.0).sum()), int((z < 5.0).sum())]
    return out


def near_only(layouts, seeds) -> dict:
    """nusc13: :func:`~jaxdepth.research.twin_measure.near_statistics` (and the points within 4 / 5 m of the real
    cameras' depth)
    of the real sweep and of the nuScenes twin (sweep 0, camera scale 0.05: the LiDAR does not depend on it)
    in each layout, with the twin's rates, with the range bands measured on the real sweep, and with those
    and the real sweep's ego returns."""
    from jaxdepth.io import read_points, rig_from_nuscenes_calibration
    from jaxdepth.research.twin_measure import near_statistics
    from jaxdepth.research.twins import make_twin
    bands, real = real_near_effects()
    ego = real_ego_table()
    nus = DATA / "nuscenes" / "sample"
    points, extra = read_points(glob.glob(str(nus / "*LIDAR_TOP*.pcd.bin"))[0], columns=5)
    cams = rig_from_nuscenes_calibration(nus / "calibration.json").cameras     # the twin's points frame is the LiDAR's
    cols = {"real": dict(real, camera_near=_camera_near(points, cams))}
    for layout in layouts:
        for seed in seeds:
            for tag, eff, e in (("", True, None), (" bands", bands, None), (" bands ego", bands, ego)):
                tw = make_twin("nuscenes", sweeps=1, seed=seed, scale=0.05, layout=layout, effects=eff, ego=e)
                cols[f"{layout} {seed}{tag}"] = dict(near_statistics(tw.cloud.points, tw.cloud.ring),
                                                     camera_near=_camera_near(tw.cloud.points, cams))
    return {"columns": cols}


def near_table(cols: dict) -> str:
    """The docs' table of :func:`near_only`'s columns (markdown)."""
    names = list(cols)
    lines = ["| band, statistic | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|",
             "| points nearer than 2 m (ego, housing, invalid) | "
             + " | ".join(f"{cols[n]['within_ego_m']:.3f}" for n in names) + " |"]
    for cam in cols[names[0]].get("camera_near", {}):
        lines.append(f"| camera points within 4 / 5 m, {cam} | "
                     + " | ".join("{} / {}".format(*cols[n]["camera_near"][cam]) for n in names) + " |")
    for band in cols[names[0]]["bands"]:
        for key, label, k in NEAR_ROWS:
            cells = [cols[n]["bands"][band][key] * k for n in names]
            fmt = "{:.0f}" if key == "edge_triples" else "{:.1f}" if k > 1 else "{:.4f}"
            lines.append(f"| {band} m: {label} | " + " | ".join(fmt.format(c) for c in cells) + " |")
    return "\n".join(lines)


def _pooled(case: dict, key: str) -> float:
    n = [d["far_edges"]["targets"] for d in case["draws"]]
    return float(np.average([d["far_edges"][key] for d in case["draws"]], weights=n))


def tables(doc: dict) -> str:
    """The docs' tables (markdown) of a result file."""
    real, twins = doc.get("real_sample"), doc["twins"]
    cols = ([("real", real["statistics"])] if real else []) + [(f"{c['layout']} {c['seed']}", c["statistics"])
                                                                for c in twins]
    lines = ["| statistic | " + " | ".join(n for n, _ in cols) + " |", "|---" * (len(cols) + 1) + "|"]
    row = lambda name, f: lines.append(f"| {name} | " + " | ".join(f(st) for _, st in cols) + " |")  # noqa: E731
    row("points in the cameras >= 20 / >= 40 m", lambda st: f"{st['all']['share_ge_20m']:.3f} / {st['all']['share_ge_40m']:.3f}")
    for cam in cols[0][1]["cameras"]:
        row(f"{cam} >= 20 m", lambda st, cam=cam: f"{st['cameras'][cam]['share_ge_20m']:.2f}")
    for b in cols[0][1]["edges"]["per_line"]:
        row(f"depth edges per scan line, far side {b} m",
            lambda st, b=b: f"{st['edges']['per_line'][b]:.1f} ({st['edges']['per_1000_pairs'][b]:.0f})")
    cov = ([f"{np.mean(real['covered_share']):.4f}"] if real else []) + [
        f"{np.mean([d['covered_share'] for d in c['draws']]):.4f}" for c in twins]
    lines.append("| targets covered (dropped by `uncovered`) | " + " | ".join(cov) + " |")
    far = ([f"{real['far_edge_share']:.4f}"] if real else []) + [f"{_pooled(c, 'far_edge_share'):.4f}" for c in twins]
    lines.append("| far edge targets (>= 20 m, SGM and fill apart) | " + " | ".join(far) + " |")
    lines.append("")
    layouts = sorted({c["layout"] for c in twins}, key=lambda x: (x != "street", x))
    heads = ["exact, every pixel (full input)", "exact, every pixel", "exact, held-out pixels", "all targets",
             "`uncovered`"]
    for layout in layouts:
        cases = [c for c in twins if c["layout"] == layout]
        lines += [f"{layout} (seeds {', '.join(str(c['seed']) for c in cases)}), RMSE / MAE mm, mean over seeds "
                  "(and draws)", "", "| method | " + " | ".join(heads) + " |", "|---" * (len(heads) + 1) + "|"]
        for m in [m for m in METHODS if m in cases[0]["full"]]:
            cells = [np.mean([[c["full"][m]["rmse"], c["full"][m]["mae"]] for c in cases], axis=0)]
            for p_ in PROTOCOLS:
                cells.append(np.mean([[d["scores"][p_][m]["rmse"], d["scores"][p_][m]["mae"]]
                                      for c in cases for d in c["draws"]], axis=0))
            lines.append(f"| {m} | " + " | ".join(f"{a:.1f} / {b:.1f}" for a, b in cells) + " |")
        lines.append("")
    lines += ["At the `uncovered` targets, MAE differences (mm, mean over draws): SGM minus fill at the far edge "
              "targets and elsewhere; each rule minus the SGM (all targets); each against the targets / the exact depth",
              "", "| twin, seed | far edge share | SGM - fill, far edges | SGM - fill, elsewhere | "
              + " | ".join(f"{k} - SGM" for k in RULES) + " |", "|---" * (4 + len(RULES)) + "|"]
    for c in twins:
        def f(k, c=c):
            if k not in c["draws"][0]["far_edges"]["against_targets"]:
                return "-"
            return " / ".join(f"{np.mean([d['far_edges'][t][k] for d in c['draws']]):+.1f}"
                              for t in ("against_targets", "against_exact"))
        keys = ["sgm_minus_fill_far_mm", "sgm_minus_fill_rest_mm"] + [f"{k}_minus_sgm_mm" for k in RULES]
        lines.append(f"| {c['layout']} {c['seed']} | {_pooled(c, 'far_edge_share'):.4f} | "
                     + " | ".join(f(k) for k in keys) + " |")
    if real:
        u = real["uncovered_rmse_mae_mm"]
        lines.append(f"| real sample | {real['far_edge_share']:.4f} | {real['sgm_minus_fill_far_mm']:+.1f} / - | "
                     f"{real['sgm_minus_fill_rest_mm']:+.1f} / - | "
                     + " | ".join(f"{u[k][1] - u['sgm'][1]:+.1f} / -" if k in u else "-" for k in RULES) + " |")
        lines += ["", "Real sample, `uncovered`, RMSE / MAE mm: " + ", ".join(f"{k} {a:.1f} / {b:.1f}"
                                                                          for k, (a, b) in u.items())]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layouts", nargs="+", default=["street", "open"])
    parser.add_argument("--twin-seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4], help="hold-out draws")
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--skip-real", action="store_true")
    parser.add_argument("--near-bands", action="store_true",
                        help="nusc13: the twin's noise and dropouts per near range band (0-5, 5-10, 10-20 m) as "
                             "measured on the real sweep (twin_measure.band_effects)")
    parser.add_argument("--json", default=str(RESULTS / "nuscenes_far_twin_nusc11.json"))
    parser.add_argument("--ego", action="store_true",
                        help="nusc13: the twin's rays whose real return is the ego's body (or an invalid return) "
                             "return that (make_twin(ego=))")
    parser.add_argument("--near-only", action="store_true",
                        help="nusc13: only the near statistics of the real sweep and the twin (--layouts, --twin-seeds)")
    parser.add_argument("--other-twins", nargs="+", default=[], metavar="RIG",
                        help="only the rules on these twins (1 sweep, whole input, exact depth), --twin-seeds, --scale")
    parser.add_argument("--tables", nargs="+", metavar="JSON",
                        help="print the docs' tables of result files (their twins side by side, the first real "
                             "sample) and exit")
    args = parser.parse_args(argv)
    if args.tables:
        import json
        docs = []
        for path in args.tables:
            with open(path) as f:
                docs.append(json.load(f))
        real = next((d["real_sample"] for d in docs if "real_sample" in d), None)
        if all("columns" in d for d in docs):
            print(near_table({k: v for d in docs for k, v in d["columns"].items()}))
            return 0
        print(tables({"twins": [c for d in docs for c in d.get("twins", [])], **({"real_sample": real} if real else {})}))
        return 0
    config = SGMConfig()
    t0 = time.time()
    doc = {"settings": {"layouts": args.layouts, "twin_seeds": args.twin_seeds, "draws": args.seeds,
                        "scale": args.scale, "far_m": FAR_M}}
    if args.near_only:
        doc.update(near_only(args.layouts, args.twin_seeds))
        write_results(args.json, doc, config, t0, indent=None)
        print(near_table(doc["columns"]))
        return 0
    if args.other_twins:
        doc["settings"] = {"other_twins": args.other_twins, "twin_seeds": args.twin_seeds, "scale": args.scale,
                           "far_m": FAR_M}
        doc["other_twins"] = other_twins(args.other_twins, args.twin_seeds, args.scale, config)
        write_results(args.json, doc, config, t0, indent=None)
        return 0
    effects = True
    if args.near_bands:
        import dataclasses
        effects, near = real_near_effects()
        doc["settings"]["effects"] = dataclasses.asdict(effects)
        doc["real_near_statistics"] = near
    ego = real_ego_table() if args.ego else None
    doc["settings"]["ego"] = bool(args.ego)
    if not args.skip_real:
        doc["real_sample"] = real_sample(args.seeds, config)
        r = doc["real_sample"]
        print(f"real ({time.time() - t0:.0f} s): far edge share {r['far_edge_share']:.4f} "
              f"uncovered {r['uncovered_rmse_mae_mm']}", flush=True)
        write_results(args.json, doc, config, t0, indent=None)
    doc["twins"] = []
    for layout in args.layouts:
        for s in args.twin_seeds:
            doc["twins"].append(twin_case(layout, s, args.seeds, args.scale, config, effects, ego))
            print(f"{layout} seed {s} done ({time.time() - t0:.0f} s)", flush=True)
            write_results(args.json, doc, config, t0, indent=None)
    write_results(args.json, doc, config, t0, indent=None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
