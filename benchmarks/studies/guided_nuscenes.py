"""Image-guided seeds on the nuScenes sample (6 cameras, 1600 x 900): hidden-point scores and time per sample.

Protocol: ``jaxdepth hidden-eval`` (:func:`jaxdepth.research.cli.hidden_eval`):
the sweep is put in its LiDAR's frame (``prepare_sweep`` with the ring column),
points nearer than 1 m are dropped, a seeded 20 % of the rest is held out
(``hidden_point_mask``, seeds 0-4), the rest is completed for all six cameras
with ``complete_rig`` and scored (KITTI devkit metrics) at the held-out points'
own per-pixel z-buffer, unfiltered. Rows: guidance weight 0 (the paper's
LiDAR-only SGM; checked equal to ``hidden_point_scores``' "sgm") and the given
weights, each camera image read from the sample's JPEG (RGB). The mean is over
the 6 camera images of every draw (``mean_metrics``, the devkit's data-set
score).

Time per sample: ``complete_rig`` on the whole sweep (jit-compiled first),
median of ``--repeats`` interleaved calls with ``block_until_ready``; the
images go in as uint8 NumPy (their host -> device copy is included).

    python -m benchmarks.studies.guided_nuscenes [--weights 1 5] [--seeds 0 1 2 3 4] [--json OUT]
"""

from __future__ import annotations

import argparse
import functools
import json
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth import SGMConfig, complete_rig, depth_metrics, hidden_point_mask, hidden_point_scores, project_to_image
from jaxdepth._src.metrics import mean_metrics
from jaxdepth._src.rig import complete_rig_stages, stack_cameras
from jaxdepth.io import pad_points, prepare_sweep, read_points, rig_from_nuscenes_calibration
from jaxdepth.io.rig_images import read_rig_images

from benchmarks._common import DATA

SAMPLE = DATA / "nuscenes" / "sample"
KEYS = ("rmse", "mae", "irmse", "imae")


@functools.partial(jax.jit, static_argnames=("config", "lidar"))
def _scores(points, given, hidden, cameras, images, *, config, lidar):
    stages = complete_rig_stages(points, given, cameras, config=config, lidar=lidar, images=images)

    def gt_for(K, T, size):
        return project_to_image(points, hidden, K, T, height=cameras.height, width=cameras.width,
                                valid_size=size)[0]

    gt = jax.vmap(gt_for)(cameras.K, cameras.T_cam_lidar, cameras.image_size)
    out = jax.vmap(depth_metrics)(stages.depth, gt)
    out["count"] = jnp.sum(gt > 0, axis=(1, 2))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--weights", type=float, nargs="+", default=[1.0, 5.0])
    parser.add_argument("--sweeps", type=int, default=2)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--fraction", type=float, default=0.2)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    rig = rig_from_nuscenes_calibration(SAMPLE / "calibration.json")
    sweep = next(SAMPLE.glob("*LIDAR_TOP*.pcd.bin"))
    points, extra = read_points(sweep, columns=5)
    frame = prepare_sweep(points, rig, ring=extra[:, -1])
    base = SGMConfig() if frame.outlier_removal_trusted else SGMConfig(outlier_removal=False)
    padded, valid = pad_points(frame.points)
    with np.errstate(invalid="ignore", over="ignore"):
        valid &= np.linalg.norm(padded.astype(np.float64), axis=1) >= 1.0
    cams = frame.rig.cameras
    cameras = stack_cameras([c.as_camera() for c in cams])
    paths = [next(SAMPLE.glob(f"*__{c.name}__*.jpg")) for c in cams]
    images = read_rig_images(paths, cams, colour=True)
    configs = {0.0: base}
    configs.update({w: base.replace(guidance_weight=w, guidance_sweeps=args.sweeps) for w in args.weights})

    result = {"sample": sweep.name, "cameras": [c.name for c in cams], "fraction": args.fraction,
              "seeds": args.seeds, "sweeps": args.sweeps, "points": int(valid.sum()),
              "outlier_removal": bool(base.outlier_removal), "weights": {}}
    per_draw = {w: [] for w in configs}
    for seed in args.seeds:
        hidden = hidden_point_mask(valid, fraction=args.fraction, seed=seed)
        given = valid & ~hidden
        for w, config in configs.items():
            out = _scores(padded, given, hidden, cameras, images if w > 0 else None, config=config,
                          lidar=frame.rig.lidar)
            out = {k: np.asarray(v) for k, v in out.items()}
            per_draw[w].extend({k: float(out[k][i]) for k in KEYS + ("count",)} for i in range(len(cams)))
            if seed == args.seeds[0] and w == 0.0:  # same numbers as the hidden-eval path
                ref = hidden_point_scores(padded, valid, hidden, cameras, config=base, lidar=frame.rig.lidar)
                np.testing.assert_allclose(out["rmse"], np.asarray(ref["sgm"]["rmse"]), rtol=1e-5)
            print(f"seed {seed} weight {w:g}: RMSE " + " ".join(f"{x:.0f}" for x in out["rmse"]), flush=True)
    for w in configs:
        m = mean_metrics(per_draw[w])
        per_camera = {c.name: {k: float(np.mean([d[k] for d in per_draw[w][i::len(cams)]])) for k in KEYS}
                      for i, c in enumerate(cams)}
        result["weights"][f"{w:g}"] = {"mean": {k: float(m[k]) for k in KEYS}, "per_camera": per_camera}

    # time per sample (all 6 cameras), interleaved
    def run(w):
        return complete_rig(padded, valid, cameras, config=configs[w], lidar=frame.rig.lidar,
                            images=images if w > 0 else None).block_until_ready()

    times = {w: [] for w in configs}
    for w in configs:
        run(w)  # compile
    for _ in range(args.repeats):
        for w in configs:
            t0 = time.perf_counter()
            run(w)
            times[w].append(time.perf_counter() - t0)
    for w in configs:
        result["weights"][f"{w:g}"]["seconds_per_sample"] = float(np.median(times[w]))
        result["weights"][f"{w:g}"]["seconds_all"] = [round(t, 4) for t in times[w]]

    print(f"{'weight':>8s} {'RMSE':>8s} {'MAE':>8s} {'iRMSE':>7s} {'iMAE':>7s} {'s/sample':>9s}")
    for key, row in result["weights"].items():
        m = row["mean"]
        print(f"{key:>8s} {m['rmse']:8.1f} {m['mae']:8.1f} {m['irmse']:7.2f} {m['imae']:7.2f} "
              f"{row['seconds_per_sample']:9.3f}")
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
