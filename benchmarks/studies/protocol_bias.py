"""Does the hidden-point protocol rank methods as the truth does? Synthetic sweeps with exact depth.

    PYTHONPATH=. python -m benchmarks.studies.protocol_bias [--json benchmarks/results/protocol_bias.json]
        [--zoo-seeds 0 1] [--hidden-seeds 0 1] [--zoo-scale 0.5] [--sensors "spin32 sensor frame" ...]

The real held-out rows of the README (KITTI sweeps, nuScenes) score every method against the
held-out points' own z-buffer (``jaxdepth hidden-eval``), because no dense truth exists there.
Here the same protocol runs on the sensor zoo of ``accuracy_rigs.py`` (ray-cast street, exact
depth), and every method's same prediction is scored three ways:

- ``held-out target``: the protocol: the held-out points' z-buffer at their own pixels;
- ``exact at held-out pixels``: the scene's exact depth at those same pixels (what the
  camera really sees there);
- ``exact dense``: the scene's exact depth at every pixel;
- ``uncovered held-out target``: the protocol without the targets that nearer sweep points
  cover on both sides (``jaxdepth.research.hidden.covered_targets``, the separately
  reported score of ``hidden-eval``); ``covered_precision`` / ``covered_recall`` say how
  many of the targets it drops are wrong, and how many of the wrong ones it drops.

A held-out point that the camera cannot see (the LiDAR looks past an edge that hides it from
the camera) stays a target under the protocol; a method that copies its equally hidden
neighbours scores well on it and badly against what the camera sees. ``wrong_target_share``
counts the targets more than max(1 m, 5 %) off the exact depth at their pixel.
Nothing here chooses a default.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax.numpy as jnp
import numpy as np


import jaxdepth  # noqa: E402
from benchmarks._common import ROOT, write_results  # noqa: E402
from benchmarks.accuracy_rigs import prepared_zoo_frame  # noqa: E402
from jaxdepth._src.geometry import project_to_image  # noqa: E402
from jaxdepth.research.hidden import covered_targets, default_cover_half_height_px, hidden_point_mask  # noqa: E402
from jaxdepth._src.ip_basic import ip_basic  # noqa: E402
from jaxdepth._src.metrics import depth_metrics, mean_metrics  # noqa: E402
from jaxdepth.io import pad_points  # noqa: E402

METHODS = ("sgm", "sgm_no_removal", "nearest", "ip_basic")
PROTOCOLS = ("held-out target", "exact at held-out pixels", "exact dense", "uncovered held-out target")
SENSORS = ("spin16 sensor frame", "spin32 sensor frame", "spin64 sensor frame", "spin128 sensor frame")


def sensor_scores(name, zoo_seeds, hidden_seeds, scale, config):
    acc = {}
    wrong = total = covered_n = covered_wrong = 0
    for zoo_seed in zoo_seeds:
        prepared, cams, depths = prepared_zoo_frame(name, zoo_seed, scale)
        cfg = config if prepared.outlier_removal_trusted else config.replace(outlier_removal=False)
        padded, valid = pad_points(prepared.points)
        valid &= np.linalg.norm(padded, axis=1) >= 1.0          # as hidden-eval (min_range_m)
        stacked = jaxdepth.stack_cameras([c.as_camera() for c in prepared.rig.cameras])
        P = jnp.asarray(padded)
        half_height = default_cover_half_height_px(stacked.K, prepared.rig.lidar)
        for hidden_seed in hidden_seeds:
            hidden = hidden_point_mask(valid, fraction=0.2, seed=hidden_seed)
            given = jnp.asarray(valid & ~hidden)
            sgm = jaxdepth.complete_rig_stages(P, given, stacked, config=cfg, lidar=prepared.rig.lidar)
            plain = jaxdepth.complete_rig_stages(P, given, stacked, config=config.replace(outlier_removal=False),
                                                 lidar=prepared.rig.lidar)
            for i, cam in enumerate(cams):
                crop = lambda a: a[i, :cam.height, :cam.width]  # noqa: E731
                target = project_to_image(P, jnp.asarray(hidden), stacked.K[i], stacked.T_cam_lidar[i],
                                          height=stacked.height, width=stacked.width,
                                          valid_size=stacked.image_size[i])[0][:cam.height, :cam.width]
                full = project_to_image(P, jnp.asarray(valid), stacked.K[i], stacked.T_cam_lidar[i],
                                        height=stacked.height, width=stacked.width,
                                        valid_size=stacked.image_size[i])[0][:cam.height, :cam.width]
                covered = covered_targets(target, full, half_height_px=half_height)
                exact = jnp.asarray(depths[i])
                at_targets = jnp.where(target > 0, exact, 0.0)
                off = (target > 0) & (jnp.abs(target - exact) > jnp.maximum(1.0, 0.05 * exact))
                wrong += int(off.sum())
                total += int((target > 0).sum())
                covered_n += int(covered.sum())
                covered_wrong += int((covered & off).sum())
                uncovered = jnp.where(covered, 0.0, target)
                preds = {"sgm": crop(sgm.depth), "sgm_no_removal": crop(plain.depth), "nearest": crop(plain.seed_depth),
                         "ip_basic": ip_basic(crop(plain.sparse_depth))}
                for method, pred in preds.items():
                    for proto, truth in zip(PROTOCOLS, (target, at_targets, exact, uncovered)):
                        m = depth_metrics(pred, truth)
                        acc.setdefault(proto, {}).setdefault(method, []).append(
                            dict(m, count=int((truth > 0).sum())))
    scores = {proto: {m: {k: float(v) for k, v in mean_metrics(rows).items() if k != "count"}
                      for m, rows in per.items()} for proto, per in acc.items()}
    return scores, {"wrong_target_share": wrong / max(total, 1), "targets": total,
                    "covered_share": covered_n / max(total, 1), "covered_precision": covered_wrong / max(covered_n, 1),
                    "covered_recall": covered_wrong / max(wrong, 1), "cover_half_height_px": half_height}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "protocol_bias.json"))
    parser.add_argument("--zoo-seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--hidden-seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--zoo-scale", type=float, default=0.5)
    parser.add_argument("--sensors", nargs="+", default=list(SENSORS))
    args = parser.parse_args(argv)
    config = jaxdepth.SGMConfig()
    t0 = time.time()
    rows = {}
    for name in args.sensors:
        scores, meta = sensor_scores(name, args.zoo_seeds, args.hidden_seeds, args.zoo_scale, config)
        rows[name] = {"scores": scores, **meta}
        print(f"{name}  (targets {meta['targets']}, {100 * meta['wrong_target_share']:.1f} % off the exact depth; "
              f"covered {100 * meta['covered_share']:.1f} %, of which wrong {100 * meta['covered_precision']:.0f} %, "
              f"{100 * meta['covered_recall']:.0f} % of the wrong ones)")
        for proto in PROTOCOLS:
            s = scores[proto]
            best = min(METHODS, key=lambda m: s[m]["mae"])
            print(f"  {proto:26s}" + "".join(f"  {m} {s[m]['rmse']:7.1f}/{s[m]['mae']:6.1f}" for m in METHODS)
                  + f"   lowest MAE: {best}")
    write_results(args.json, {"fraction_hidden": 0.2, "zoo_seeds": args.zoo_seeds, "hidden_seeds": args.hidden_seeds,
                              "zoo_scale": args.zoo_scale, "rows": rows}, config, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
