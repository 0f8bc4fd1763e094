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

Argoverse 2 is read by :mod:`jaxdepth.io.av2` (``read_log``, ``read_cloud``, ``read_rig``), the
reader the ``av2`` job uses; like the job, it leaves each LiDAR's spec to be estimated from its rings
(one range-image row per laser; ``read_cloud``'s default since issue 37 item 5).

Speed (``--speed-only`` adds just these sections): wall time of :func:`complete_cloud`, compile
(first call) reported apart, the functions of one section timed in turn over ``repeats`` rounds
(so the machine's drift hits all alike), medians, ratios from one process: one two-LiDAR sweep as
two sources against the same points as one cloud; and 1, 2, 3, 5, 8 sweeps of the synthetic
2-LiDAR drive, with its stages alone (host padding, Step-1 normals, free-space view, jitted core)
and the free-space view with every sweep a witness of every other (the quadratic rule).
"""

from __future__ import annotations

import argparse
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


# ---------------------------------------------------------------- Argoverse 2, read by jaxdepth.io.av2

def av2_log():
    from jaxdepth.io import av2
    return av2.read_log(AV2_LOG)


def av2_rig(log):
    """The Rig of the 7 ring cameras (ego frame -> camera), described as the single-origin baseline saw it:
    one 64-beam LiDAR (:data:`SINGLE_ORIGIN_SPEC`) at the ego origin."""
    from jaxdepth.io import av2
    return Rig(lidar=SINGLE_ORIGIN_SPEC, cameras=av2.read_rig(log, RING_CAMERAS).cameras)


def av2_clouds(log):
    """Each sweep of the log alone as a SourceCloud (``up_lidar`` and ``down_lidar`` its two sources), with
    each LiDAR's spec left to be estimated from its own rings (``lidars`` None), in time order."""
    import dataclasses
    from jaxdepth.io import av2
    out = []
    for t in log.sweeps:
        cloud = av2.read_cloud(log, t)
        out.append(dataclasses.replace(cloud, lidars=(None,) * cloud.num_sources))
    return out


def file_order(log, k: int) -> np.ndarray:
    """(N,) index into sweep ``k``'s file of each point of its one-sweep cloud (read_cloud groups points by
    LiDAR, keeping file order within each)."""
    from jaxdepth.io import av2
    _, laser = av2.read_sweep(log.sweep_path(log.sweeps[k]))
    return np.argsort(laser // av2.LASERS_PER_LIDAR, kind="stable")


def laser_numbers(cloud) -> np.ndarray:
    """(N,) Argoverse 2 laser number of each point of a one-sweep cloud (its ring within its LiDAR + 32 per LiDAR)."""
    from jaxdepth.io.av2 import LASERS_PER_LIDAR
    return cloud.ring + LASERS_PER_LIDAR * cloud.source


def _z_buffer(points, cam):
    pts, valid = jaxdepth.io.pad_points(points)
    return np.asarray(jaxdepth.project_to_image(pts, valid, jnp.asarray(cam.K), jnp.asarray(cam.T_cam_lidar),
                                                height=cam.height, width=cam.width)[0])


def _one_camera_rig(rig, cam):
    return Rig(lidar=rig.lidar, cameras=(cam,), lidar_origin_m=rig.lidar_origin_m, lidar_stated=rig.lidar_stated)


def _score(pred, gt):
    m = depth_metrics(jnp.asarray(pred), jnp.asarray(gt))
    return {k: float(m[k]) for k in KEYS} | {"count": int(m["count"])}


def av2_methods(cloud, cam, rig, config):
    """{method: (H, W) prediction} of one camera from one sweep's input points (a SourceCloud)."""
    from jaxdepth.io import prepare_sweep
    one = _one_camera_rig(rig, cam)
    frame = prepare_sweep(cloud.points, one)          # what complete-rig does with a merged cloud
    cfg_single = config if frame.outlier_removal_trusted else config.replace(outlier_removal=False)
    cams = jaxdepth.stack_cameras([c.as_camera() for c in frame.rig.cameras])
    pts, valid = jaxdepth.io.pad_points(frame.points)
    single = jaxdepth.complete_rig_stages(pts, valid, cams, config=cfg_single, lidar=frame.rig.lidar)
    plain = jaxdepth.complete_rig_stages(pts, valid, cams, config=config.replace(outlier_removal=False),
                                         lidar=frame.rig.lidar)
    l2 = jaxdepth.complete_rig_stages(pts, valid, cams, lidar=frame.rig.lidar,
                                      config=config.replace(outlier_removal=False, distance_metric="l2"))
    one_src = Rig(lidar=VLP32C, cameras=(cam,))
    sources = complete_cloud(cloud, one_src, config=config)
    return {"nearest": np.asarray(plain.seed_depth[0]), "nearest_l2": np.asarray(l2.seed_depth[0]),
            "ip_basic": np.asarray(ip_basic(plain.sparse_depth[0])),
            "sgm_single_origin": np.asarray(single.depth[0]), "sgm_sources": sources[0]}, {
        "single_origin_outlier_removal": bool(cfg_single.outlier_removal), "single_origin_notes": list(frame.notes)}


def av2_rows(config, *, fraction=0.2, seed=0, cameras=RING_CAMERAS):
    log = av2_log()
    rig = av2_rig(log)
    clouds = av2_clouds(log)
    out = {}
    for protocol in ("scan_lines", "random"):
        per = {}
        info = {}
        for k, cloud in enumerate(clouds):
            points, laser = cloud.points, laser_numbers(cloud)
            finite = np.all(np.isfinite(points), axis=1)
            if protocol == "scan_lines":
                hidden = finite & (laser % 2 == 1)
            else:
                # Drawn over the points in file order (read_cloud groups them by LiDAR, stably).
                draw = np.random.default_rng(seed).random(points.shape[0]) < fraction
                hidden = finite & draw[file_order(log, k)]
            given = finite & ~hidden
            for cam in rig.cameras:
                if cam.name not in cameras:
                    continue
                gt = _z_buffer(points[hidden], cam)
                preds, info = av2_methods(cloud.take(given), cam, rig, config)
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
    """The latest ``n_sweeps`` sweeps of a synthetic drive (sweep 0, -1, ...; sources ordered sweep-major)."""
    c = sq
    keep = c.sweep[c.source] > -n_sweeps
    S = int(np.sum(c.sweep > -n_sweeps))
    return SourceCloud(points=c.points[keep], source=c.source[keep], T_ref_source=c.T_ref_source[:S],
                       lidars=c.lidars[:S], sweep=c.sweep[:S], names=c.names[:S])


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


def _truth_filtered(cloud, sq, tolerance_m=0.5, *, only_older_sweeps=False):
    """Diagnosis only (uses the truth, not a method): the cloud without the points whose camera
    pixel's true depth differs from theirs by more than ``tolerance_m`` (points outside the
    camera kept). What perfect point removal could give a fill; with ``only_older_sweeps`` the
    reference sweep's points are all kept (what a perfect rule on the other sweeps could give)."""
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
    if only_older_sweeps:
        keep |= cloud.sweep[cloud.source] == 0
    return cloud.take(keep)


def _baselines(cloud, cams, lidar, config):
    """{nearest, nearest_l2, ip_basic: (H, W)} of a cloud's points as one image (no removal)."""
    pts, valid = jaxdepth.io.pad_points(cloud.points)
    raw = jaxdepth.complete_rig_stages(pts, valid, cams, config=config.replace(outlier_removal=False), lidar=lidar)
    l2 = jaxdepth.complete_rig_stages(pts, valid, cams, lidar=lidar,
                                      config=config.replace(outlier_removal=False, distance_metric="l2"))
    return {"nearest": np.asarray(raw.seed_depth[0]), "nearest_l2": np.asarray(l2.seed_depth[0]),
            "ip_basic": np.asarray(ip_basic(raw.sparse_depth[0]))}


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
                     "sgm_sources_no_occlusion": complete_cloud(full, rig, config=config, occlusion=False)[0],
                     "sgm_sources_older_sweeps_truth_filtered": complete_cloud(
                         _truth_filtered(full, sq, only_older_sweeps=True), rig, config=config)[0],
                     "sgm_sources_1_sweep_truth_filtered": complete_cloud(_truth_filtered(one, sq), rig,
                                                                          config=config, free_space=False)[0],
                     "sgm_sources_truth_filtered": complete_cloud(_truth_filtered(full, sq), rig, config=config,
                                                                  free_space=False)[0]}
            plain = jaxdepth.complete_rig_stages(*jaxdepth.io.pad_points(full.points), cams, config=config,
                                                 lidar=sq.lidars[0])
            preds["sgm_accumulated_single_origin"] = np.asarray(plain.depth[0])
            preds.update(_baselines(full, cams, sq.lidars[0], config))
            preds.update({f"{k}_1_sweep": v for k, v in _baselines(one, cams, sq.lidars[0], config).items()})
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
                         "gain_5_vs_1_sweep_no_occlusion_rmse_pct": 100.0 * (
                             1.0 - mean["sgm_sources_no_occlusion"]["rmse"] / s1["rmse"]),
                         "gain_5_vs_1_sweep_older_sweeps_truth_filtered_rmse_pct": 100.0 * (
                             1.0 - mean["sgm_sources_older_sweeps_truth_filtered"]["rmse"] / s1["rmse"]),
                         "gain_vs_accumulation_pct": {k: 100.0 * (1.0 - s5[k] / acc[k]) for k in ("rmse", "mae")}}
    h, w = round(352 * image_scale), round(1216 * image_scale)
    return {"rigs": out, "seeds": list(seeds), "sweeps": sweeps, "image_scale": image_scale,
            "input": f"{sweeps} sweeps, ego 1.5 m per sweep, 3 moving cars; reference camera {h} x {w} "
                     f"(KITTI-like, scale {image_scale}); nearest / nearest_l2 / ip_basic on the plain "
                     f"{sweeps}-sweep stack and (*_1_sweep) on the reference sweep",
            "targets": {"gain_5_vs_1_sweep_rmse_pct": ">= 20", "gain_vs_accumulation_pct": "> 0 in both",
                        "ghost_pct": "< 0.1"}}


# ---------------------------------------------------------------- speed

def _alternate(fns: dict, *, repeats: int) -> dict:
    """{name: {"first_call_s", "run_s"}}: each function called once (compile), then ``repeats`` rounds
    calling every function once per round in turn (so drift of the machine hits all alike); run_s is the
    median. Results are blocked on (``np.asarray`` / ``block_until_ready``) before the clock is read."""
    first, runs = {}, {k: [] for k in fns}
    for name, fn in fns.items():
        t = time.perf_counter()
        jax.block_until_ready(fn())
        first[name] = time.perf_counter() - t
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            jax.block_until_ready(fn())
            runs[name].append(time.perf_counter() - t)
    return {k: {"first_call_s": first[k], "run_s": float(np.median(runs[k])), "runs_s": runs[k]} for k in fns}


def speed_av2(config, *, repeats=7):
    """One Argoverse 2 sweep, ring_front_left: two sources vs the same points as one cloud (both with removal).

    The one cloud is the same points about ``up_lidar``'s origin with a 64-beam spec given (no estimate);
    the two sources get their specs estimated from their rings, host work that is timed as part of
    :func:`complete_cloud` (``host_spec_s`` reports it alone). Timed alternately, medians.
    """
    from jaxdepth.batch.sources_job import cloud_sources
    log = av2_log()
    rig = av2_rig(log)
    cam = rig.cameras[RING_CAMERAS.index("ring_front_left")]
    cloud = av2_clouds(log)[0]
    points = cloud.points
    up = log.sensor_pose("up_lidar")
    one_src = Rig(lidar=VLP32C, cameras=(cam,))
    single = SourceCloud(points=points - up[:3, 3].astype(np.float32),
                         source=np.zeros(len(points), np.int32), T_ref_source=np.eye(4)[None],
                         lidars=(LidarSpec(beams=64, fov_up_deg=15.0, fov_down_deg=-25.0, columns=1800),),
                         sweep=np.zeros(1, np.int32), names=("merged",))
    shift = np.eye(4)
    shift[:3, 3] = up[:3, 3]
    cam_shift = RigCamera(cam.name, cam.width, cam.height, cam.K, (np.asarray(cam.T_cam_lidar, np.float64) @ shift
                                                                  ).astype(np.float32))
    one_rig = Rig(lidar=single.lidars[0], cameras=(cam_shift,))
    times = _alternate({"two_sources": lambda: complete_cloud(cloud, one_src, config=config),
                        "one_cloud": lambda: complete_cloud(single, one_rig, config=config),
                        "host_spec": lambda: cloud_sources(cloud, fallback=VLP32C)}, repeats=repeats)
    return {"camera": cam.name, "points": int(len(points)), "two_sources_s": times["two_sources"]["run_s"],
            "one_cloud_s": times["one_cloud"]["run_s"], "host_spec_s": times["host_spec"]["run_s"],
            "compile_s": {k: v["first_call_s"] for k, v in times.items()},
            "ratio": times["two_sources"]["run_s"] / times["one_cloud"]["run_s"], "repeats": repeats,
            # the ratio within each round (both timed back to back), median over rounds: robust to drift
            "ratio_paired_median": float(np.median(np.asarray(times["two_sources"]["runs_s"])
                                                   / np.asarray(times["one_cloud"]["runs_s"]))),
            "target": "ratio <= 1.3"}


def _per_source_passes(sparse_depth, pixel_source, points_cam, K, T_cam_sources, *, beams, config, pixel_shadow=None):
    """Step 2 as it ran before one pass served all sources (the baseline of :func:`speed_step2_av2`):
    Algorithm 1 once per source (vmapped, that source's pixels the candidates), then a condition-2 pass for
    the shadow pixels."""
    from jaxdepth._src.outliers import _keep_mask, window_half_sizes
    valid = (sparse_depth > 0) & jnp.isfinite(sparse_depth)
    height, width = sparse_depth.shape
    hw, hh = window_half_sizes(height, width, beams=beams, max_half_width_px=config.outlier_max_half_width_px,
                               max_half_height_px=config.outlier_max_half_height_px)
    eps = jnp.asarray(config.epsilon_m, jnp.float32)
    n_src = T_cam_sources.shape[0]

    def one(s, T):
        return _keep_mask(sparse_depth, K, T, points_cam, eps, valid & (pixel_source == s), beams=beams,
                          half_width=hw, half_height=hh, test=config.outlier_test)

    keeps = jax.vmap(one)(jnp.arange(n_src, dtype=jnp.int32), T_cam_sources)
    mine = pixel_source[None] == jnp.arange(n_src, dtype=jnp.int32)[:, None, None]
    keep = valid & jnp.all(keeps | ~mine, axis=0)
    if pixel_shadow is not None:
        keep = keep & _keep_mask(sparse_depth, K, T_cam_sources[0], points_cam, eps, valid & pixel_shadow,
                                 beams=beams, half_width=hw, half_height=hh, test="nearer")
    return keep


def speed_step2_av2(config, *, repeats=5):
    """Step 2 alone on one Argoverse 2 sweep's ring_front_left image (two sources): one pass for all sources
    (:func:`~jaxdepth._src.sources.source_keep_mask`) against one pass per source, with and without shadow
    pixels (a random tenth of the pixels standing in for another sweep's), and the one-cloud pass
    (:func:`~jaxdepth.outlier_keep_mask` about ``up_lidar``'s origin). Same masks checked."""
    from jaxdepth._src.outliers import outlier_keep_mask
    from jaxdepth._src.pipeline import project_with_normals
    from jaxdepth._src.sources import source_keep_mask
    from jaxdepth.batch.sources_job import cloud_sources
    log = av2_log()
    cam = av2_rig(log).cameras[RING_CAMERAS.index("ring_front_left")]
    cloud = av2_clouds(log)[0]
    sources, _ = cloud_sources(cloud, fallback=VLP32C)
    s, p = sources.points.shape[:2]
    K, T = jnp.asarray(cam.K), jnp.asarray(cam.T_cam_lidar)
    depth, index, points_cam, _ = project_with_normals(sources.points.reshape(-1, 3), sources.valid.reshape(-1),
                                                       jnp.zeros((s * p, 3)), T, K, height=cam.height,
                                                       width=cam.width)
    pixel_source = jnp.where(index >= 0, jnp.where(index >= 0, index, 0) // p, -1).astype(jnp.int32)
    T_cam_sources = jnp.einsum("ij,sjk->sik", T, sources.T_ref_source)
    shadow = (index >= 0) & (jax.random.uniform(jax.random.PRNGKey(0), index.shape) < 0.1)
    beams = 64
    one = jax.jit(lambda *a, **k: source_keep_mask(*a, beams=beams, config=config, **k))
    per = jax.jit(lambda *a, **k: _per_source_passes(*a, beams=beams, config=config, **k))
    single = jax.jit(lambda d, pc, T_up: outlier_keep_mask(d, K, T_up, beams=beams, points_cam=pc))
    args = (depth, pixel_source, points_cam, K, T_cam_sources)
    for shadow_arg in (None, shadow):
        same = np.array_equal(np.asarray(one(*args, pixel_shadow=shadow_arg)),
                              np.asarray(per(*args, pixel_shadow=shadow_arg)))
        assert same, "one pass and one pass per source disagree"
    t = _alternate({"one_pass": lambda: one(*args), "per_source": lambda: per(*args),
                    "one_pass_shadow": lambda: one(*args, pixel_shadow=shadow),
                    "per_source_shadow": lambda: per(*args, pixel_shadow=shadow),
                    "one_cloud": lambda: single(depth, points_cam, T_cam_sources[0])}, repeats=repeats)
    run = {k: v["run_s"] for k, v in t.items()}
    return {"camera": cam.name, "pixels_with_depth": int(jnp.sum(index >= 0)), "seconds": run,
            "ratio_vs_one_cloud": {k: v / run["one_cloud"] for k, v in run.items()},
            "masks_equal": True, "repeats": repeats}


def speed_sequences(config, *, counts=(1, 2, 3, 5, 8), repeats=5):
    """Synthetic 2-LiDAR drive: :func:`complete_cloud` of the first 1, 2, 3, 5, 8 sweeps (2 sources each),
    timed alternately (compile excluded), with the stages alone: host padding (``cloud_sources``), Step-1
    normals per source, the free-space view (default witnesses; for comparison every sweep as witness of
    every other, the quadratic rule, and the reference sweep's witnesses alone), and the jitted core
    (``complete_sources_stages``)."""
    from jaxdepth._src import sources as core
    from jaxdepth._src.synthetic_sequences import make_street_sequence
    from jaxdepth.batch.sources_job import cloud_sources
    sq = make_street_sequence(0, sweeps=max(counts), lidars=2)
    cam = sq.camera
    rig = Rig(lidar=sq.lidars[0], cameras=(RigCamera("cam", cam.width, cam.height, np.asarray(cam.K),
                                                     np.asarray(cam.T_cam_lidar)),))
    cams = jaxdepth.stack_cameras([cam])
    normals, view = jax.jit(core.source_normals), jax.jit(core.reference_view)
    view_every = jax.jit(lambda s: core.reference_view(s, neighbour_sweeps=None, end_sweeps=False))
    view_ref = jax.jit(lambda s: core.reference_view(s, neighbour_sweeps=0, end_sweeps=False))
    fns, points = {}, {}
    for n in counts:
        cloud = _sequence_cloud(sq, n)
        sources, _ = cloud_sources(cloud, fallback=rig.lidar)
        points[n] = int(len(cloud.points))
        fns[f"{n}/complete_cloud"] = lambda cloud=cloud: complete_cloud(cloud, rig, config=config)
        fns[f"{n}/host_padding"] = lambda cloud=cloud: cloud_sources(cloud, fallback=rig.lidar)
        fns[f"{n}/normals"] = lambda s=sources: normals(s)
        fns[f"{n}/reference_view"] = lambda s=sources: view(s)
        fns[f"{n}/reference_view_every_sweep"] = lambda s=sources: view_every(s)
        # witnesses of the reference sweep only (the cheapest rule, more ghosts)
        fns[f"{n}/reference_view_reference_witnesses"] = lambda s=sources: view_ref(s)
        fns[f"{n}/core"] = lambda s=sources: core.complete_sources_stages(s, cams, config=config).depth
    t = _alternate(fns, repeats=repeats)
    run = {n: t[f"{n}/complete_cloud"]["run_s"] for n in counts}
    stages = {str(n): {k.split("/")[1]: round(v["run_s"], 4) for k, v in t.items() if k.startswith(f"{n}/")}
              for n in counts}
    view_s = {n: t[f"{n}/reference_view"]["run_s"] for n in counts}
    return {"seconds": {str(n): run[n] for n in counts},
            "reference_view_seconds_per_sweep": {str(n): view_s[n] / n for n in counts},
            "reference_view_every_sweep_seconds_per_sweep": {
                str(n): t[f"{n}/reference_view_every_sweep"]["run_s"] / n for n in counts},
            "seconds_per_sweep": {str(n): run[n] / n for n in counts},
            "ratio_vs_1_sweep": {str(n): run[n] / run[1] for n in counts},
            "points": {str(n): points[n] for n in counts}, "stages_s": stages,
            "compile_s": {str(n): round(t[f"{n}/complete_cloud"]["first_call_s"], 1) for n in counts},
            "lidars": 2, "repeats": repeats, "target": "cost grows linearly with the number of sweeps"}


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
        doc["speed_step2"] = speed_step2_av2(config)
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
            doc["speed_step2"] = speed_step2_av2(config)
        else:  # keep the speed sections of an earlier run (this script wrote them)
            prev = out / "accuracy_av2.json"
            prev = json.loads(prev.read_text()) if prev.exists() else {}
            doc.update({k: prev[k] for k in ("speed", "speed_step2") if k in prev})
        write(out / "accuracy_av2.json", doc)
        for p, r in rows.items():
            print(p, json.dumps({n: (round(m["rmse"], 1), round(m["mae"], 1)) for n, m in r["mean"].items()}))
    if not args.skip_sequences:
        doc = {"protocols": {f"scale_{scale:g}": sequence_rows(config, image_scale=scale)
                             for scale in args.sequence_scales}}
        old = out / "accuracy_sequences.json"
        old = json.loads(old.read_text()) if old.exists() else {}
        # only what this script writes is carried over (the speed section of an earlier --speed-only run):
        # a record that no script regenerates does not live in a results file
        if not args.skip_speed:
            doc["speed"] = speed_sequences(config)
        elif "speed" in old:
            doc["speed"] = old["speed"]
        write(out / "accuracy_sequences.json", doc)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
