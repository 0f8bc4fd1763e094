"""The nuScenes twin's near range with the real sweep's near-range rates (issue 37, nusc13): existing options.

    PYTHONPATH=. python -m benchmarks.studies.nuscenes_near_twin [--layouts cluttered] [--twin-seeds 0 1] \
        [--scale 1] [--ego] [--json benchmarks/results/nuscenes_near_twin_nusc13.json]

On the nuScenes twin (1 sweep, full size, the single-sweep path of a user's point file and rig JSON), with
the twin's rates (``SENSOR_EFFECTS``) and with the range bands measured on the real sweep
(``nuscenes_far_twin --near-bands``: noise and dropouts per 0-5, 5-10, 10-20 m band,
:func:`jaxdepth.research.twin_measure.band_effects`), the whole input is completed by the SGM default, a few
existing options (:data:`VARIANTS`: no removal, the normals' smoothing, Step 4's Gaussian), the city-block
and Euclidean fills, and scored (RMSE / MAE mm, mean over images) against the exact depth of every pixel, of
the pixels whose exact depth is within :data:`NEAR_M` and of those beyond it.
``--ego``: both with the real sweep's ego returns (``make_twin(ego=)``). No default is changed here; the
exact depth is read only to score.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig

NEAR_M = 10.0
#: Existing SGM options tried on the twin: name -> SGMConfig fields.
VARIANTS = {"sgm": {}, "sgm_no_removal": {"outlier_removal": False}, "normal_smoothing_0": {"normal_smoothing": 0},
            "normal_smoothing_2": {"normal_smoothing": 2}, "gaussian_sigma_0.8": {"smoothing_sigma_px": 0.8},
            "gaussian_sigma_2.0": {"smoothing_sigma_px": 2.0}}


def split_scores(pred: list, exact: list) -> dict:
    """{"all", "near", "far"}: :func:`benchmarks.accuracy_twins.score` against the exact depth of every
    pixel, of the pixels within :data:`NEAR_M` and of those beyond."""
    from benchmarks.accuracy_twins import score
    near = [np.where(e < NEAR_M, e, 0.0).astype(np.float32) for e in exact]
    far = [np.where(e >= NEAR_M, e, 0.0).astype(np.float32) for e in exact]
    out = {k: score(pred, t) for k, t in (("all", exact), ("near", near), ("far", far))}
    for v in out.values():
        v.pop("per_camera")
    return out


def case(layout: str, seed: int, effects, config: SGMConfig, scale: float = 1.0, ego=None) -> dict:
    from benchmarks.accuracy_twins import crops, exact_truth, read_user_input, single_path, z_buffers
    from jaxdepth._src.methods import complete_with
    from jaxdepth.research.twins import make_twin, write_twin
    tw = make_twin("nuscenes", sweeps=1, seed=seed, scale=scale, layout=layout, effects=effects, ego=ego)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(tw, tmp)
        inp = read_user_input(paths["sweeps"][0], paths["rig"])
    exact = exact_truth(tw, inp.rig)
    cloud = inp.cloud
    out = {}
    frame = None
    for name, fields in VARIANTS.items():
        depth, frame = single_path(cloud.points, cloud.ring, inp.rig, config.replace(**fields))
        out[name] = split_scores(crops(depth, inp.rig), exact)
    plain = config.replace(outlier_removal=False)
    sparse = z_buffers(frame.points, frame.rig)
    for name, metric in (("nearest", "l1"), ("nearest_l2", "l2")):
        pred = [np.asarray(complete_with(s, c.K, c.T_cam_lidar, method="nearest",
                                         config=plain.replace(distance_metric=metric), lidar=frame.rig.lidar))
                for s, c in zip(sparse, frame.rig.cameras)]
        out[name] = split_scores(pred, exact)
    return out


def markdown(doc: dict) -> str:
    """The docs' table: per method, RMSE / MAE mm (mean over seeds) of each effects setting, all / near / far."""
    runs = doc["runs"]
    tags = list(dict.fromkeys(r["effects_tag"] for r in runs))
    heads = [f"{t}, {part}" for t in tags for part in ("every pixel", f"< {NEAR_M:g} m", f">= {NEAR_M:g} m")]
    lines = ["| method | " + " | ".join(heads) + " |", "|---" * (len(heads) + 1) + "|"]
    for m in runs[0]["scores"]:
        cells = []
        for t in tags:
            rs = [r["scores"][m] for r in runs if r["effects_tag"] == t]
            for part in ("all", "near", "far"):
                cells.append("{:.1f} / {:.1f}".format(*np.mean([[s[part]["rmse"], s[part]["mae"]] for s in rs], axis=0)))
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layouts", nargs="+", default=["cluttered"])
    parser.add_argument("--twin-seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--ego", action="store_true", help="the twin's ego returns (nuscenes_far_twin --ego)")
    parser.add_argument("--json", default=str(RESULTS / "nuscenes_near_twin_nusc13.json"))
    parser.add_argument("--table", metavar="JSON", help="print the docs' table of a result file and exit")
    args = parser.parse_args(argv)
    if args.table:
        import json
        with open(args.table) as f:
            print(markdown(json.load(f)))
        return 0
    import dataclasses

    from benchmarks.studies.nuscenes_far_twin import real_ego_table, real_near_effects
    bands, _ = real_near_effects()
    ego = real_ego_table() if args.ego else None
    config = SGMConfig()
    t0 = time.time()
    doc = {"settings": {"layouts": args.layouts, "twin_seeds": args.twin_seeds, "scale": args.scale, "ego": bool(args.ego), "near_m": NEAR_M, "variants": VARIANTS,
                        "band_effects": dataclasses.asdict(bands)}, "runs": []}
    for layout in args.layouts:
        for seed in args.twin_seeds:
            for tag, eff in (("twin rates", True), ("real near bands", bands)):
                doc["runs"].append({"layout": layout, "seed": seed, "effects_tag": tag,
                                    "scores": case(layout, seed, eff, config, args.scale, ego)})
                s = doc["runs"][-1]["scores"]
                print(f"{layout} {seed} {tag} ({time.time() - t0:.0f} s): "
                      + ", ".join(f"{m} {v['near']['mae']:.1f}" for m, v in s.items()), flush=True)
                write_results(args.json, doc, config, t0, indent=None)
    print(markdown(doc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
