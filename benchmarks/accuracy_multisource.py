"""Several LiDARs and several sweeps, each seen from its own origin: accuracy and speed.

    PYTHONPATH=. python benchmarks/accuracy_multisource.py [--skip-av2] [--skip-sequences] [--skip-speed]

Writes ``benchmarks/results/accuracy_av2.json`` and ``benchmarks/results/accuracy_sequences.json``.
RMSE / MAE in mm (KITTI devkit metrics), mean over camera images.

Argoverse 2 (``../shared/data/av2``: one log, two sweeps, no images, no depth truth): each sweep
alone is the input (both LiDARs declared: ``up_lidar`` laser numbers 0-31, ``down_lidar`` 32-63,
their poses from the calibration), for the 7 ring cameras (pinhole part of the intrinsics, full
size). Two hold-outs, targets = the held-out points' own z-buffer, filtered by nothing any method
does:

- ``scan_lines``: odd laser numbers held out, even ones input (per LiDAR: 16 of each LiDAR's 32);
- ``random``: a seeded random 20 % of each sweep held out (seed 0).

Methods on the same input: ``nearest`` (city-block nearest LiDAR pixel), ``nearest_l2``
(Euclidean), ``ip_basic``, ``sgm_single_origin`` (the merged cloud as one LiDAR at the ego
origin with a 64-beam spec, as ``complete-rig`` did before: the sweep does not look like one
spinning LiDAR, so outlier removal is off) and ``sgm_sources`` (each LiDAR its own source:
:func:`jaxdepth.batch.sources_job.complete_cloud`, its spec estimated from its own rings).
Nothing was tuned on these numbers: every option is the library default.

Synthetic sequences (:func:`jaxdepth._src.synthetic.make_street_sequence`, exact depth): an ego
moving 1.5 m per sweep, moving cars, a rig of 2 or 3 LiDARs at different heights and tilts;
the reference camera of the last sweep, at half size (176 x 608) and at KITTI's size (352 x 1216;
``--sequence-scales``); every pixel with truth scored. Rows: 1 sweep (all LiDARs of the reference
sweep), 5 sweeps accumulated plainly (every point as one cloud from the reference LiDAR's origin, no
removal beyond the single-origin SGM's), 5 sweeps with the rules (per-source Steps 1 and 2, free
space); the nearest fills and IP_Basic on the 5-sweep stack and on the reference sweep; and, as a
diagnosis (not a method), the SGM on the input without the points the truth shows wrong at their
pixel. Ghost pixels: depth off by more than 1 m where a moving car was in an earlier sweep but
is not now, and within 1 m of where that car was (the car's ghost, not an ordinary error).
``boundary_sse_share_pct``: the share of the squared error on depth boundaries found from the
truth alone. Seeds 0 and 1 are reported; the free-space rule's choices were made on seeds 10, 11.

Speed: median wall time (compile excluded) of one two-LiDAR sweep as two sources against the
same points as one cloud, and of 1, 2, 3, 5 sweeps.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import platform
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import jaxdepth  # noqa: E402
from jaxdepth._src.config import SGMConfig  # noqa: E402
from jaxdepth._src.ip_basic import ip_basic  # noqa: E402
from jaxdepth._src.metrics import depth_metrics, mean_metrics  # noqa: E402
from jaxdepth._src.types import LidarSpec  # noqa: E402
from jaxdepth.batch.sources_job import complete_cloud  # noqa: E402
from jaxdepth.io.atomic import atomic_write_bytes  # noqa: E402
from jaxdepth.io.rig import Rig, RigCamera  # noqa: E402
from jaxdepth.io.sources import SourceCloud  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
AV2_LOG = DATA / "av2" / "sensor" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
RING_CAMERAS = ("ring_front_center", "ring_front_left", "ring_front_right", "ring_rear_left", "ring_rear_right",
                "ring_side_left", "ring_side_right")
KEYS = ("rmse", "mae", "irmse", "imae")
#: Before this work: the merged cloud described as one 64-beam LiDAR (rig JSON ``beams: 64``).
SINGLE_ORIGIN_SPEC = LidarSpec(beams=64)
#: Fallback spec of a VLP-32C source (its beams and field of view are estimated from its rings).
VLP32C = LidarSpec(beams=32, fov_up_deg=15.0, fov_down_deg=-25.0, columns=1800)


# ---------------------------------------------------------------- Argoverse 2, read with pyarrow

def _pose(row) -> np.ndarray:
    qw, qx, qy, qz = (float(row[k]) for k in ("qw", "qx", "qy", "qz"))
    R = np.array([[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
                  [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
                  [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = [float(row[k]) for k in ("tx_m", "ty_m", "tz_m")]
    return T


def _table(path):
    import pyarrow.feather as feather
    t = feather.read_table(str(path))
    return {k: t.column(k).to_numpy(zero_copy_only=False) for k in t.schema.names}


def av2_rig_and_poses():
    """(Rig of the 7 ring cameras, ego frame -> camera; {lidar name: T_ego_lidar})."""
    ext = _table(AV2_LOG / "calibration" / "egovehicle_SE3_sensor.feather")
    intr = _table(AV2_LOG / "calibration" / "intrinsics.feather")
    poses = {str(n): _pose({k: ext[k][i] for k in ext}) for i, n in enumerate(ext["sensor_name"])}
    cams = []
    for name in RING_CAMERAS:
        i = list(intr["sensor_name"]).index(name)
        K = np.array([[intr["fx_px"][i], 0.0, intr["cx_px"][i]], [0.0, intr["fy_px"][i], intr["cy_px"][i]],
                      [0.0, 0.0, 1.0]], np.float32)
        T = np.linalg.inv(poses[name]).astype(np.float32)
        cams.append(RigCamera(name, int(intr["width_px"][i]), int(intr["height_px"][i]), K, T))
    return Rig(lidar=SINGLE_ORIGIN_SPEC, cameras=tuple(cams)), {k: poses[k] for k in ("up_lidar", "down_lidar")}


def av2_sweeps():
    """[(points (N, 3) float32 ego frame, laser_number (N,) int)] of the log's sweeps, in time order."""
    out = []
    for f in sorted((AV2_LOG / "sensors" / "lidar").glob("*.feather")):
        t = _table(f)
        pts = np.stack([t["x"], t["y"], t["z"]], axis=1).astype(np.float32)
        out.append((pts, t["laser_number"].astype(np.int32)))
    return out


def av2_cloud(points, laser, lidar_poses, name="") -> SourceCloud:
    """Both LiDARs of one sweep as two sources (ego frame is the reference)."""
    source = (laser >= 32).astype(np.int32)
    return SourceCloud(points=points, source=source,
                       T_ref_source=np.stack([lidar_poses["up_lidar"], lidar_poses["down_lidar"]]),
                       lidars=(None, None), sweep=np.zeros(2, np.int32), names=("up_lidar", "down_lidar"),
                       ring=(laser % 32).astype(np.int32), path=name)


def _z_buffer(points, cam):
    pts, valid = jaxdepth.io.pad_points(points)
    return np.asarray(jaxdepth.project_to_image(pts, valid, jnp.asarray(cam.K), jnp.asarray(cam.T_cam_lidar),
                                                height=cam.height, width=cam.width)[0])


def _one_camera_rig(rig, cam):
    return Rig(lidar=rig.lidar, cameras=(cam,), lidar_origin_m=rig.lidar_origin_m, lidar_stated=rig.lidar_stated)


def _score(pred, gt):
    m = depth_metrics(jnp.asarray(pred), jnp.asarray(gt))
    return {k: float(m[k]) for k in KEYS} | {"count": int(m["count"])}


def av2_methods(points, laser, cam, rig, lidar_poses, config):
    """{method: (H, W) prediction} of one camera from one sweep's input points."""
    from jaxdepth.io import prepare_sweep
    one = _one_camera_rig(rig, cam)
    frame = prepare_sweep(points, one)          # what complete-rig does with a merged cloud
    cfg_single = config if frame.outlier_removal_trusted else config.replace(outlier_removal=False)
    cams = jaxdepth.stack_cameras([c.as_camera() for c in frame.rig.cameras])
    pts, valid = jaxdepth.io.pad_points(frame.points)
    single = jaxdepth.complete_rig_stages(pts, valid, cams, config=cfg_single, lidar=frame.rig.lidar)
    plain = jaxdepth.complete_rig_stages(pts, valid, cams, config=config.replace(outlier_removal=False),
                                         lidar=frame.rig.lidar)
    l2 = jaxdepth.complete_rig_stages(pts, valid, cams, lidar=frame.rig.lidar,
                                      config=config.replace(outlier_removal=False, distance_metric="l2"))
    one_src = Rig(lidar=VLP32C, cameras=(cam,))
    sources = complete_cloud(av2_cloud(points, laser, lidar_poses), one_src, config=config)
    return {"nearest": np.asarray(plain.seed_depth[0]), "nearest_l2": np.asarray(l2.seed_depth[0]),
            "ip_basic": np.asarray(ip_basic(plain.sparse_depth[0])),
            "sgm_single_origin": np.asarray(single.depth[0]), "sgm_sources": sources[0]}, {
        "single_origin_outlier_removal": bool(cfg_single.outlier_removal), "single_origin_notes": list(frame.notes)}


def av2_rows(config, *, fraction=0.2, seed=0, cameras=RING_CAMERAS):
    rig, lidar_poses = av2_rig_and_poses()
    sweeps = av2_sweeps()
    out = {}
    for protocol in ("scan_lines", "random"):
        per = {}
        info = {}
        for k, (points, laser) in enumerate(sweeps):
            finite = np.all(np.isfinite(points), axis=1)
            if protocol == "scan_lines":
                hidden = finite & (laser % 2 == 1)
            else:
                hidden = finite & (np.random.default_rng(seed).random(points.shape[0]) < fraction)
            given = finite & ~hidden
            for cam in rig.cameras:
                if cam.name not in cameras:
                    continue
                gt = _z_buffer(points[hidden], cam)
                preds, info = av2_methods(points[given], laser[given], cam, rig, lidar_poses, config)
                for name, pred in preds.items():
                    per.setdefault(name, []).append(_score(pred, gt))
                print(f"av2 {protocol} sweep {k} {cam.name}: " + ", ".join(
                    f"{n} {per[n][-1]['rmse']:.0f}/{per[n][-1]['mae']:.0f}" for n in preds), flush=True)
        mean = {n: {k: float(v) for k, v in mean_metrics(rows).items() if k in KEYS} for n, rows in per.items()}
        out[protocol] = {"mean": mean, "images": len(per["nearest"]),
                         "per_image": {n: [r["rmse"] for r in rows] for n, rows in per.items()}, **info}
    return out


# ---------------------------------------------------------------- synthetic sequences (exact depth)

def _sequence_cloud(sq, n_sweeps):
    keep = sq.sweep[sq.source] < n_sweeps
    S = int(np.sum(sq.sweep < n_sweeps))
    return SourceCloud(points=sq.points[keep], source=sq.source[keep], T_ref_source=sq.T_ref_source[:S],
                       lidars=sq.lidars[:S], sweep=sq.sweep[:S], names=sq.names[:S])


def _seq_score(pred, sq):
    gt = sq.dense_depth
    row = _score(pred, gt)
    scored = gt > 0
    near_old_car = np.any((sq.ghost_depth > 0) & (np.abs(pred[None] - sq.ghost_depth) < 1.0), axis=0)
    ghost = sq.ghost_region & scored & (np.abs(pred - gt) > 1.0) & near_old_car
    row["ghost_pct"] = 100.0 * float(ghost.sum()) / float(scored.sum())
    boundary = depth_boundaries(gt)
    err2 = np.where(scored, (np.asarray(pred, np.float64) - gt) ** 2, 0.0)
    row["boundary_sse_share_pct"] = 100.0 * float(err2[boundary].sum()) / max(float(err2.sum()), 1e-12)
    return row


def depth_boundaries(gt, *, window_px=5, jump=0.1):
    """(H, W) bool, from the truth alone: scored pixels whose ``window_px`` square holds depths
    spanning more than ``jump`` times their own depth (a depth boundary within 2 px)."""
    from scipy import ndimage
    has = gt > 0
    hi = ndimage.maximum_filter(gt, window_px)
    lo = ndimage.minimum_filter(np.where(has, gt, np.inf), window_px)
    return has & (hi - lo > jump * gt)


def _truth_filtered(cloud, sq, tolerance_m=0.5):
    """Diagnosis only (uses the truth, not a method): the cloud without the points whose camera
    pixel's true depth differs from theirs by more than ``tolerance_m`` (points outside the
    camera kept). What perfect point removal could give a fill."""
    cam = sq.camera
    K, T = np.asarray(cam.K, np.float64), np.asarray(cam.T_cam_lidar, np.float64)
    pc = cloud.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    z = pc[:, 2]
    ok = z > 1e-3
    zs = np.where(ok, z, 1.0)
    u = np.round(K[0, 0] * pc[:, 0] / zs + K[0, 2]).astype(np.int64)
    v = np.round(K[1, 1] * pc[:, 1] / zs + K[1, 2]).astype(np.int64)
    h, w = sq.dense_depth.shape
    inside = ok & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    truth = np.zeros(z.shape)
    truth[inside] = sq.dense_depth[v[inside], u[inside]]
    keep = ~(inside & ((truth == 0) | (np.abs(z - truth) > tolerance_m)))
    return dataclasses.replace(cloud, points=cloud.points[keep], source=cloud.source[keep],
                               ring=None if cloud.ring is None else cloud.ring[keep])


def sequence_rows(config, *, seeds=(0, 1), sweeps=5, lidars=(2, 3), image_scale=1.0):
    """Rows of the synthetic drives: 1 sweep vs 5 sweeps plainly accumulated vs 5 sweeps with the rules.

    ``*_truth_filtered`` rows are a diagnosis, not methods: the same input without the points
    the truth shows wrong at their pixel (what perfect point removal could give the fill).
    """
    from jaxdepth._src.synthetic_sequences import make_street_sequence
    per = {}
    for n_lidars in lidars:
        for seed in seeds:
            sq = make_street_sequence(seed, sweeps=sweeps, lidars=n_lidars, image_scale=image_scale)
            cam = sq.camera
            rig = Rig(lidar=sq.lidars[0], cameras=(RigCamera("cam", cam.width, cam.height, np.asarray(cam.K),
                                                             np.asarray(cam.T_cam_lidar)),))
            cams = jaxdepth.stack_cameras([cam])
            one, full = _sequence_cloud(sq, 1), _sequence_cloud(sq, sweeps)
            preds = {"sgm_sources_1_sweep": complete_cloud(one, rig, config=config)[0],
                     "sgm_sources_no_free_space": complete_cloud(full, rig, config=config, free_space=False)[0],
                     "sgm_sources": complete_cloud(full, rig, config=config)[0],
                     "sgm_sources_1_sweep_truth_filtered": complete_cloud(_truth_filtered(one, sq), rig,
                                                                          config=config, free_space=False)[0],
                     "sgm_sources_truth_filtered": complete_cloud(_truth_filtered(full, sq), rig, config=config,
                                                                  free_space=False)[0]}
            pts, valid = jaxdepth.io.pad_points(full.points)
            plain = jaxdepth.complete_rig_stages(pts, valid, cams, config=config, lidar=sq.lidars[0])
            raw = jaxdepth.complete_rig_stages(pts, valid, cams, config=config.replace(outlier_removal=False),
                                               lidar=sq.lidars[0])
            l2 = jaxdepth.complete_rig_stages(pts, valid, cams, lidar=sq.lidars[0],
                                              config=config.replace(outlier_removal=False, distance_metric="l2"))
            preds["sgm_accumulated_single_origin"] = np.asarray(plain.depth[0])
            preds["nearest"] = np.asarray(raw.seed_depth[0])
            preds["nearest_l2"] = np.asarray(l2.seed_depth[0])
            preds["ip_basic"] = np.asarray(ip_basic(raw.sparse_depth[0]))
            pts1, valid1 = jaxdepth.io.pad_points(one.points)
            raw1 = jaxdepth.complete_rig_stages(pts1, valid1, cams, config=config.replace(outlier_removal=False),
                                                lidar=sq.lidars[0])
            l21 = jaxdepth.complete_rig_stages(pts1, valid1, cams, lidar=sq.lidars[0],
                                               config=config.replace(outlier_removal=False, distance_metric="l2"))
            preds["nearest_1_sweep"] = np.asarray(raw1.seed_depth[0])
            preds["nearest_l2_1_sweep"] = np.asarray(l21.seed_depth[0])
            preds["ip_basic_1_sweep"] = np.asarray(ip_basic(raw1.sparse_depth[0]))
            for name, pred in preds.items():
                per.setdefault(f"{n_lidars}_lidars", {}).setdefault(name, []).append(_seq_score(np.asarray(pred), sq))
            print(f"sequence scale={image_scale} lidars={n_lidars} seed={seed}: " + ", ".join(
                f"{n} {per[f'{n_lidars}_lidars'][n][-1]['rmse']:.0f}/{per[f'{n_lidars}_lidars'][n][-1]['mae']:.0f}"
                f" ghost {per[f'{n_lidars}_lidars'][n][-1]['ghost_pct']:.3f} %" for n in preds), flush=True)
    out = {}
    for rig_name, rows in per.items():
        mean = {n: {k: float(np.mean([r[k] for r in rs])) for k in KEYS + ("ghost_pct", "boundary_sse_share_pct")}
                for n, rs in rows.items()}
        s5, s1, acc = mean["sgm_sources"], mean["sgm_sources_1_sweep"], mean["sgm_accumulated_single_origin"]
        out[rig_name] = {"mean": mean, "images": len(rows["sgm_sources"]),
                         "gain_5_vs_1_sweep_rmse_pct": 100.0 * (1.0 - s5["rmse"] / s1["rmse"]),
                         "gain_5_vs_1_sweep_truth_filtered_rmse_pct": 100.0 * (
                             1.0 - mean["sgm_sources_truth_filtered"]["rmse"] / s1["rmse"]),
                         "gain_vs_accumulation_pct": {k: 100.0 * (1.0 - s5[k] / acc[k]) for k in ("rmse", "mae")}}
    h, w = round(352 * image_scale), round(1216 * image_scale)
    return {"rigs": out, "seeds": list(seeds), "sweeps": sweeps, "image_scale": image_scale,
            "input": f"{sweeps} sweeps, ego 1.5 m per sweep, 3 moving cars; reference camera {h} x {w} "
                     f"(KITTI-like, scale {image_scale}); nearest / nearest_l2 / ip_basic on the plain "
                     f"{sweeps}-sweep stack and (*_1_sweep) on the reference sweep",
            "targets": {"gain_5_vs_1_sweep_rmse_pct": ">= 20", "gain_vs_accumulation_pct": "> 0 in both",
                        "ghost_pct": "< 0.1"}}


# ---------------------------------------------------------------- speed

def _median_time(fn, repeats=5):
    fn()                                     # compile
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def speed_av2(config):
    """One Argoverse 2 sweep, ring_front_left: two sources vs the same points as one cloud (both with removal)."""
    rig, lidar_poses = av2_rig_and_poses()
    cam = rig.cameras[1]
    points, laser = av2_sweeps()[0]
    ok = np.all(np.isfinite(points), axis=1)
    points, laser = points[ok], laser[ok]
    cloud = av2_cloud(points, laser, lidar_poses)
    one_src = Rig(lidar=VLP32C, cameras=(cam,))
    single = SourceCloud(points=points - lidar_poses["up_lidar"][:3, 3].astype(np.float32),
                         source=np.zeros(len(points), np.int32), T_ref_source=np.eye(4)[None],
                         lidars=(LidarSpec(beams=64, fov_up_deg=15.0, fov_down_deg=-25.0, columns=1800),),
                         sweep=np.zeros(1, np.int32), names=("merged",))
    shift = np.eye(4)
    shift[:3, 3] = lidar_poses["up_lidar"][:3, 3]
    cam_shift = RigCamera(cam.name, cam.width, cam.height, cam.K, (np.asarray(cam.T_cam_lidar, np.float64) @ shift
                                                                  ).astype(np.float32))
    one_rig = Rig(lidar=single.lidars[0], cameras=(cam_shift,))
    t_two = _median_time(lambda: complete_cloud(cloud, one_src, config=config))
    t_one = _median_time(lambda: complete_cloud(single, one_rig, config=config))
    return {"camera": cam.name, "points": int(len(points)), "two_sources_s": t_two, "one_cloud_s": t_one,
            "ratio": t_two / t_one, "target": "ratio <= 1.3"}


def speed_sequences(config, *, counts=(1, 2, 3, 5)):
    from jaxdepth._src.synthetic_sequences import make_street_sequence
    sq = make_street_sequence(0, sweeps=max(counts), lidars=2)
    cam = sq.camera
    rig = Rig(lidar=sq.lidars[0], cameras=(RigCamera("cam", cam.width, cam.height, np.asarray(cam.K),
                                                     np.asarray(cam.T_cam_lidar)),))
    times = {n: _median_time(lambda n=n: complete_cloud(_sequence_cloud(sq, n), rig, config=config), repeats=3)
             for n in counts}
    per_sweep = {n: times[n] / n for n in counts}
    return {"seconds": {str(n): t for n, t in times.items()}, "seconds_per_sweep": {str(n): t for n, t in
                                                                                   per_sweep.items()},
            "ratio_vs_1_sweep": {str(n): times[n] / times[1] for n in counts}, "lidars": 2,
            "target": "cost grows linearly with the number of sweeps"}


def _gain(row, base="nearest", method="sgm_sources"):
    return {k: 100.0 * (1.0 - row[method][k] / row[base][k]) for k in ("rmse", "mae")}


def write(path, doc):
    doc["platform"] = {"python": platform.python_version(), "jax": jax.__version__,
                       "backend": jax.default_backend()}
    atomic_write_bytes(pathlib.Path(path), (json.dumps(doc, indent=2, sort_keys=True) + "\n").encode())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-av2", action="store_true")
    ap.add_argument("--skip-sequences", action="store_true")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--speed-only", action="store_true", help="only add the speed sections to existing results")
    ap.add_argument("--cameras", nargs="*", default=list(RING_CAMERAS))
    ap.add_argument("--sequence-scales", nargs="*", type=float, default=[1.0, 0.5],
                    help="reference camera scales of the synthetic drives (1.0: KITTI's 352 x 1216)")
    ap.add_argument("--out-dir", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    config = SGMConfig()
    out = pathlib.Path(args.out_dir)
    if args.speed_only:
        path = out / "accuracy_av2.json"
        doc = json.loads(path.read_text()) if path.exists() else {}
        doc["speed"] = speed_av2(config)
        write(path, doc)
        path = out / "accuracy_sequences.json"
        doc = json.loads(path.read_text()) if path.exists() else {}
        doc["speed"] = speed_sequences(config)
        write(path, doc)
        return 0
    if not args.skip_av2:
        t0 = time.time()
        rows = av2_rows(config, cameras=tuple(args.cameras))
        doc = {"protocols": rows, "gain_vs_city_block_pct": {p: _gain(r["mean"]) for p, r in rows.items()},
               "targets": {"scan_lines": "rmse and mae >= 10 % better than nearest",
                           "random": "rmse >= 10 % better than nearest, mae no worse"},
               "seconds": round(time.time() - t0, 1)}
        if not args.skip_speed:
            doc["speed"] = speed_av2(config)
        write(out / "accuracy_av2.json", doc)
        for p, r in rows.items():
            print(p, json.dumps({n: (round(m["rmse"], 1), round(m["mae"], 1)) for n, m in r["mean"].items()}))
    if not args.skip_sequences:
        doc = {"protocols": {f"scale_{scale:g}": sequence_rows(config, image_scale=scale)
                             for scale in args.sequence_scales}}
        if not args.skip_speed:
            doc["speed"] = speed_sequences(config)
        write(out / "accuracy_sequences.json", doc)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
