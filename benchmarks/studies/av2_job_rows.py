"""The Argoverse 2 job's range-image rows: a stated VLP-32C spec against rows from the laser numbers.

    PYTHONPATH=. python -m benchmarks.studies.av2_job_rows [--json benchmarks/results/av2_job_rows.json]
        [--cameras ring_front_center,...] [--fraction 0.2] [--seed 0]

The job's own completion call (:func:`jaxdepth.batch.cloud_runner.complete_sources`, free space
on) on each sweep of the shared log (two sweeps, 7 ring cameras at full size, LiDAR time: the log
has no images), with each LiDAR's input read two ways by :func:`jaxdepth.io.av2.read_cloud`:

- ``stated_spec`` (the job before this study): ``spec=AV2_VLP32C``, a uniform 40 deg / 31 spacing,
  so each point's row follows from its elevation; the VLP-32C's lasers near the horizon are
  0.33 deg apart, and several share a row;
- ``laser_rows`` (the job now, and the ``sgm_sources`` column of ``accuracy_multisource.py``): no
  spec stated, one row per laser, ranked by its elevation about its own LiDAR.

``rows_filled``: distinct range-image rows each LiDAR's points fall on (of 32). Two hold-outs, as
``accuracy_multisource.py``: ``scan_lines`` (odd laser numbers held out) and ``random`` (a seeded
20 % of each sweep). Targets: the held-out points' own z-buffer, all of them (``all``) and without
the ones that nearer sweep points cover on both sides (``uncovered``,
:func:`jaxdepth.research.hidden.covered_targets`, half height from the stated spec's scan-line
spacing). ``nearest``: the job's ``--method nearest`` on the same input, for scale. Mean over the
14 camera images, RMSE / MAE in mm, iRMSE / iMAE in 1/km.
"""

from __future__ import annotations

import argparse
import time

import jax.numpy as jnp
import numpy as np

import jaxdepth  # noqa: F401
from benchmarks._common import DATA, ROOT, write_results
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.metrics import depth_metrics, mean_metrics
from jaxdepth._src.presets import AV2_VLP32C

LOG = DATA / "av2" / "sensor" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
KEYS = ("rmse", "mae", "irmse", "imae")
VARIANTS = ("stated_spec", "laser_rows", "nearest")


def rows_filled(cloud, fallback) -> list:
    """Distinct range-image rows of each source's points: the per-laser rows, else the rows of elevation."""
    from jaxdepth.batch.sources_job import source_spec
    out = []
    for s in range(cloud.num_sources):
        spec, rank = source_spec(cloud, s, fallback)
        if rank is not None:
            out.append(int(np.unique(rank).size))
            continue
        mine = cloud.source == s
        T = np.linalg.inv(cloud.T_ref_source[s])
        local = cloud.points[mine].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        el = np.degrees(np.arctan2(local[:, 2], np.hypot(local[:, 0], local[:, 1])))
        # jaxdepth._src.range_image.row_col: row = floor((fov_up - elevation) / (fov_up - fov_down) * beams)
        row_f = (spec.fov_up_deg - el) * spec.beams / (spec.fov_up_deg - spec.fov_down_deg)
        row = np.clip(np.floor(np.clip(row_f, -1.0, spec.beams)), 0, spec.beams - 1)
        out.append(int(np.unique(row).size))
    return out


def _z_buffers(points, hidden, rig, half_height):
    """Per camera: (target, uncovered target), from the held-out points and the whole sweep."""
    from jaxdepth.io import pad_points
    from jaxdepth.research.hidden import covered_targets
    pts, valid = pad_points(points)
    out = []
    for cam in rig.cameras:
        def zb(mask, cam=cam):
            return jaxdepth.project_to_image(pts, mask, jnp.asarray(cam.K), jnp.asarray(cam.T_cam_lidar),
                                             height=cam.height, width=cam.width)[0]
        target = zb(jnp.asarray(np.pad(hidden, (0, pts.shape[0] - hidden.size))) & valid)
        covered = covered_targets(target, zb(valid), half_height_px=half_height)
        out.append((np.asarray(target), np.asarray(jnp.where(covered, 0.0, target))))
    return out


def run(cameras, *, fraction: float, seed: int, config: SGMConfig) -> dict:
    from jaxdepth.batch import av2_job
    from jaxdepth.batch.cloud_runner import complete_sources
    from jaxdepth.io import av2
    from jaxdepth.research.hidden import default_cover_half_height_px

    log = av2.read_log(LOG)
    rig = av2.read_rig(log, cameras)
    half_height = default_cover_half_height_px(np.stack([c.K for c in rig.cameras]), AV2_VLP32C)
    per = {p: {t: {v: [] for v in VARIANTS} for t in ("all", "uncovered")} for p in ("scan_lines", "random")}
    filled = {}
    for k, ts in enumerate(log.sweeps):
        clouds = {"stated_spec": av2.read_cloud(log, ts, spec=AV2_VLP32C), "laser_rows": av2.read_cloud(log, ts)}
        filled[str(ts)] = {v: rows_filled(c, rig.lidar) for v, c in clouds.items()}
        ref = clouds["laser_rows"]
        laser = ref.ring + av2.LASERS_PER_LIDAR * ref.source
        _, file_laser = av2.read_sweep(log.sweep_path(ts))
        order = np.argsort(file_laser // av2.LASERS_PER_LIDAR, kind="stable")  # cloud row -> file row
        for protocol in ("scan_lines", "random"):
            if protocol == "scan_lines":
                hidden = laser % 2 == 1
            else:
                hidden = (np.random.default_rng(seed).random(laser.size) < fraction)[order]
            targets = _z_buffers(ref.points, hidden, rig, half_height)
            preds = {v: complete_sources(c.take(~hidden), rig, config=config) for v, c in clouds.items()}
            preds["nearest"] = av2_job.baseline_depth(ref.take(~hidden), rig, method="nearest", config=config)
            for i, cam in enumerate(rig.cameras):
                for v, pred in preds.items():
                    window = jnp.asarray(pred[i, :cam.height, :cam.width])
                    for which, gt in zip(("all", "uncovered"), targets[i], strict=True):
                        m = depth_metrics(window, jnp.asarray(gt))
                        per[protocol][which][v].append({key: float(m[key]) for key in (*KEYS, "count")})
            print(f"sweep {k} {protocol}: " + ", ".join(
                f"{v} {np.mean([r['rmse'] for r in per[protocol]['all'][v][-len(cameras):]]):.0f}"
                for v in VARIANTS), flush=True)
    mean = {p: {t: {v: {key: float(val) for key, val in mean_metrics(rows).items() if key in KEYS}
                    for v, rows in by.items()} for t, by in targets_.items()} for p, targets_ in per.items()}
    return {"mean": mean, "rows_filled": filled, "images": len(cameras) * len(log.sweeps),
            "cover_half_height_px": int(half_height), "fraction": fraction, "seed": seed,
            "cameras": list(cameras)}


def main(argv=None) -> None:
    from jaxdepth.io.av2 import RING_CAMERAS
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "av2_job_rows.json"))
    ap.add_argument("--cameras", default=",".join(RING_CAMERAS))
    ap.add_argument("--fraction", type=float, default=0.2)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    t0 = time.time()
    config = SGMConfig()
    doc = run(tuple(args.cameras.split(",")), fraction=args.fraction, seed=args.seed, config=config)
    for p, by in doc["mean"].items():
        for t, rows in by.items():
            print(f"{p:10s} {t:9s} " + "  ".join(
                f"{v} {r['rmse']:.0f}/{r['mae']:.0f} ({r['irmse']:.1f}/{r['imae']:.1f})" for v, r in rows.items()))
    print("rows filled (up, down):", doc["rows_filled"])
    write_results(args.json, doc, config, t0)


if __name__ == "__main__":
    main()
