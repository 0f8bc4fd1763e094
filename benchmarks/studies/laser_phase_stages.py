"""Which SGM stage pays for staggered laser phases on the KITTI twin (issue 37).

    PYTHONPATH=. python -m benchmarks.studies.laser_phase_stages [--sweeps 1 5] [--seed 0] [--scale 1]
        [--json benchmarks/results/laser_phase_stages.json]

The KITTI twin (seed 0, full size) with the lasers sharing one azimuth phase (``aligned``, the published twins)
and each at its own (``staggered``: ``make_twin(laser_phases=True)``,
:func:`jaxdepth.research.twin_sensors.stagger_lasers`), each scored against its exact depth (KITTI devkit
RMSE / MAE mm, mean over the two cameras) with one stage changed at a time, all else the default:

- ``default``; ``no_removal`` (Step 2 off); ``no_bracket`` (Step 4's column bracket off); ``above_background``
  (``SGMConfig.above_scan="background"``: no plane extrapolated above the top scan line);
- 1 sweep, Step 1's normals swapped in through :func:`jaxdepth._src.rig.run_rig_stages`' ``call`` hook:
  ``normals_exact`` (each point's normal from the twin's scene: its ray from the LiDAR cast on the scene's
  primitives and spheres), ``normals_phase_following`` (the range image of the points each laser's ring turned
  back by its phase, so that its samples sit where the aligned twin's do, the normals turned forward again;
  staggered only), ``normals_exact_no_bracket`` and ``default_via_hook`` (the library's normals through the
  hook: must score as ``default``);
- more than 1 sweep (the multi-source path): ``no_free_space`` (the extra sweeps' free-space / occlusion
  rules off, ``complete_cloud(free_space=False)``), and it with ``no_bracket``.

1 sweep also: each point's Step 1 normal against its exact one (:func:`normal_errors`, by ring where the
cameras look) and :func:`diagnostics` (seed offsets, residual and squared error by |dv| band).

No library code changes; nothing tuned.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time

import jax.numpy as jnp
import numpy as np

from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig


def twin_input(sweeps: int, seed: int, scale: float, staggered: bool):
    """(twin, user input, exact depth per camera) of the KITTI twin."""
    from benchmarks.accuracy_twins import exact_truth, read_user_input
    from jaxdepth.research.twins import make_twin, write_twin
    tw = make_twin("kitti", sweeps=sweeps, seed=seed, scale=scale, laser_phases=staggered)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(tw, tmp)
        inp = read_user_input(paths["sweeps_json"] if sweeps > 1 else paths["sweeps"][0], paths["rig"])
    return tw, inp, exact_truth(tw, inp.rig)


def exact_normals(tw, points_ref: np.ndarray) -> np.ndarray:
    """(n, 3) unit normal, reference frame, of the surface each ray from the twin's LiDAR through
    ``points_ref`` (n, 3) hits first (scene primitives or spheres; 0 where nothing is hit)."""
    from jaxdepth._src.synthetic_images import _hit_normals, cast_rays_labelled
    from jaxdepth.research import twin_scene
    from jaxdepth.research.twin_rigs import RIG_BUILDERS
    from jaxdepth.research.twin_sensors import NO_EFFECTS, sphere_hits
    from jaxdepth.research.twins import ego_pose
    rdef = RIG_BUILDERS["kitti"](NO_EFFECTS)
    T = ego_pose(rdef, 0) @ rdef.T_ego_points
    origin = T[:3, :3] @ tw.point_origin[0].astype(np.float64) + T[:3, 3]
    p = points_ref.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    d = p - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    scene = twin_scene.twin_scene(tw.seed, 0, dt_s=rdef.dt_s)
    spheres = twin_scene.twin_spheres(tw.seed)
    o32, d32 = jnp.asarray(np.broadcast_to(origin, d.shape), jnp.float32), jnp.asarray(d, jnp.float32)
    t, label = cast_rays_labelled(o32, d32, scene)
    ts = np.asarray(sphere_hits(jnp.asarray(origin, jnp.float32), d32, spheres))
    t = np.asarray(t)
    hit = origin + np.minimum(t, ts)[:, None] * d
    n = np.asarray(_hit_normals(jnp.asarray(hit, jnp.float32), d32, label, scene), np.float64)
    c = spheres[np.argmin(np.abs(np.linalg.norm(hit[:, None, :] - spheres[None, :, :3], axis=2) - spheres[None, :, 3]),
                          axis=1)]
    ns = (hit - c[:, :3]) / np.maximum(c[:, 3:4], 1e-6)
    n = np.where((ts < t)[:, None], -ns, n)
    n = np.where(np.isfinite(np.minimum(t, ts))[:, None], n, 0.0)
    return (n @ T[:3, :3]).astype(np.float32)


def phase_following_normals(points: np.ndarray, ring: np.ndarray, valid: np.ndarray, lidar, config, *,
                            seed: int = 0) -> np.ndarray:
    """Step 1's normals (LiDAR frame) from the range image of ``points`` with ring ``r`` turned back by its laser's
    phase (:func:`stagger_lasers`' draw for unit 0 of ``seed``), the normals turned forward again."""
    from jaxdepth._src.normals import point_normals
    phase = np.random.default_rng([int(seed), 39]).uniform(-0.5, 0.5, 64)
    a = (2.0 * math.pi * phase / 2048)[ring]

    def turn(v, s):
        c, sn = np.cos(s * a), np.sin(s * a)
        return np.stack([c * v[:, 0] - sn * v[:, 1], sn * v[:, 0] + c * v[:, 1], v[:, 2]], axis=1)

    back = np.where(valid[:, None], turn(np.nan_to_num(points.astype(np.float64)), 1.0), 0.0).astype(np.float32)
    n = point_normals(jnp.asarray(back), jnp.asarray(valid), lidar=lidar, smoothing=config.normal_smoothing,
                      fill_max_gap=config.range_fill_max_gap)
    return turn(np.asarray(n, np.float64), -1.0).astype(np.float32)


def single_with_normals(inp, config: SGMConfig, normals_of, *, stages: bool = False):
    """(``stages``: the :class:`~jaxdepth.Stages` canvas instead of) per camera depth of the single-sweep path (``accuracy_twins.single_path``) with Step 1's normals
    ``normals_of(frame, valid)`` ((N, 3) LiDAR frame; None: the library's)."""
    import jaxdepth
    from benchmarks.accuracy_twins import crops
    from jaxdepth._src import rig as rigmod
    from jaxdepth.io import pad_points, prepare_sweep
    frame = prepare_sweep(inp.cloud.points, inp.rig, ring=inp.cloud.ring)
    if not frame.outlier_removal_trusted:
        config = config.replace(outlier_removal=False)
    padded, valid = pad_points(frame.points)
    cams = jaxdepth.stack_cameras([c.as_camera() for c in frame.rig.cameras])
    lidar = frame.rig.lidar
    normals = None if normals_of is None else np.zeros((len(padded), 3), np.float32)
    if normals is not None:
        n = len(frame.points)
        normals[:n] = normals_of(frame, np.asarray(valid[:n]))

    def projection(points, valid, cameras, *, config, lidar):
        pts = jnp.where(valid[:, None], jnp.asarray(points, jnp.float32), 0.0)

        def per_camera(K, T, size, image, *, height, width):
            K, T = jnp.asarray(K, jnp.float32), jnp.asarray(T, jnp.float32)
            sd, pc, nc, _ = rigmod.project_apart(pts, valid, jnp.asarray(normals), T, K, height=height, width=width,
                                                 image_size=size)
            return rigmod.CameraView(sd, pc, nc)
        return rigmod.map_by_size(per_camera, cameras)

    def call(stage, *args, **statics):
        return (projection if stage is rigmod.rig_stage_projection and normals is not None else stage)(*args, **statics)

    out = rigmod.run_rig_stages(jnp.asarray(padded), jnp.asarray(valid), cams, config=config, lidar=lidar, call=call)
    if stages:
        return out
    return crops(np.asarray(out.depth), inp.rig)


def score(pred: list, exact: list) -> dict:
    from benchmarks.accuracy_twins import score as devkit
    s = devkit(pred, exact)
    return {"rmse": round(s["rmse"], 1), "mae": round(s["mae"], 1)}


def one_sweep_rows(tw, inp, exact, staggered: bool, seed: int) -> dict:
    d = SGMConfig()
    nb = d.replace(column_bracket=False)
    ring = np.asarray(tw.point_ring)

    def ex(frame, valid):
        return exact_normals(tw, np.asarray(inp.cloud.points)[:len(frame.points)])

    def pf(frame, valid):
        pts = np.asarray(frame.points)
        return (phase_following_normals(pts, ring[:len(pts)], valid, frame.rig.lidar, d, seed=0) if staggered
                else None)
    rows = {"default": score(single_with_normals(inp, d, None), exact),
            "default_via_hook": score(single_with_normals(inp, d, lambda f, v: _library_normals(f, v, d)), exact),
            "no_removal": score(single_with_normals(inp, d.replace(outlier_removal=False), None), exact),
            "no_bracket": score(single_with_normals(inp, nb, None), exact),
            "normals_exact": score(single_with_normals(inp, d, ex), exact),
            "normals_exact_no_bracket": score(single_with_normals(inp, nb, ex), exact),
            "above_background": score(single_with_normals(inp, d.replace(above_scan="background"), None), exact)}
    if staggered:
        rows["normals_phase_following"] = score(single_with_normals(inp, d, pf), exact)
    rows["normal_error_deg"] = normal_errors(tw, d, staggered)
    rows["diagnostics"] = {"library_normals": diagnostics(single_with_normals(inp, d, None, stages=True), inp, exact),
                           "exact_normals": diagnostics(single_with_normals(inp, d, ex, stages=True), inp, exact)}
    return rows


def normal_errors(tw, config: SGMConfig, staggered: bool) -> dict:
    """Angle (deg) between each point's Step 1 normal (the library's; ``phase_following`` when staggered)
    and its exact one, over the points with both: mean, median, share over 10 deg, mean within 20 m."""
    from jaxdepth._src.normals import point_normals
    from jaxdepth._src.presets import KITTI_HDL64
    pts, ring = tw.cloud.points.astype(np.float32), np.asarray(tw.point_ring)
    valid = np.ones(len(pts), bool)
    ne = exact_normals(tw, pts)
    runs = {"library": np.asarray(point_normals(jnp.asarray(pts), jnp.asarray(valid), lidar=KITTI_HDL64,
                                                smoothing=config.normal_smoothing,
                                                fill_max_gap=config.range_fill_max_gap))}
    if staggered:
        runs["phase_following"] = phase_following_normals(pts, ring, valid, KITTI_HDL64, config)
    from jaxdepth.research.twin_tables import KITTI_ELEVATIONS_DEG
    out, near = {}, np.linalg.norm(pts, axis=1) < 20
    top = np.argsort(-np.asarray(KITTI_ELEVATIONS_DEG))
    ahead = (pts[:, 0] > 0) & (np.abs(pts[:, 1]) < pts[:, 0])
    for name, n in runs.items():
        ok = (np.linalg.norm(ne, axis=1) > 0.5) & (np.linalg.norm(n, axis=1) > 0.5)
        ang = np.degrees(np.arccos(np.clip(np.abs(np.sum(n * ne, axis=1)), 0, 1)))
        out[name] = {"mean": round(float(ang[ok].mean()), 2), "median": round(float(np.median(ang[ok])), 2),
                     "share_over_10": round(float((ang[ok] > 10).mean()), 4),
                     "mean_within_20m": round(float(ang[ok & near].mean()), 2)}
        for band, rings in (("top_ring", top[:1]), ("rings_2_4", top[1:4]), ("other_rings", top[4:])):
            m = ok & ahead & np.isin(ring, rings)            # the cameras' quarter, x > |y|
            out[name][f"ahead_{band}"] = {"points": int(m.sum()), "mean": round(float(ang[m].mean()), 2),
                                          "share_over_30": round(float((ang[m] > 30).mean()), 4)}
    return out


def diagnostics(st, inp, exact) -> dict:
    """Where Step 3's seeds sit and what Step 4 adds, over pixels with exact depth and a seed: the mean |du|,
    |dv| (px), the share with |dv| > |du|; by |dv| band the share of pixels, mean |Delta z| (m) and the band's
    part of the mean squared error (mm^2); the seed depth's (Step 3 alone) RMSE / MAE mm, the mean |Delta z|."""
    from benchmarks.accuracy_twins import crops
    f = {k: crops(np.asarray(getattr(st, k)), inp.rig) for k in ("du", "dv", "seed_depth", "residual", "depth")}
    du, dv = (np.concatenate([np.abs(x).ravel() for x in f[k]]) for k in ("du", "dv"))
    ok = np.concatenate([((e > 0) & (s > 0)).ravel() for e, s in zip(exact, f["seed_depth"])])
    res = np.concatenate([np.abs(r).ravel() for r in f["residual"]])
    ex = np.concatenate([e.ravel() for e in exact])
    sq = (np.concatenate([x.ravel() for x in f["depth"]]) - ex) ** 2 * 1e6
    bands = {}
    for name, sel in (("dv_0_2", dv <= 2), ("dv_3_8", (dv > 2) & (dv <= 8)), ("dv_over_8", dv > 8)):
        m = ok & sel
        bands[name] = {"share": round(float(m.sum() / ok.sum()), 4), "mean_abs_residual_m": round(float(res[m].mean()), 4),
                       "mse_contribution_mm2": round(float(sq[m].sum() / ok.sum()), 1)}
    return {"bands_by_abs_dv": bands, "mean_abs_du_px": round(float(du[ok].mean()), 3), "mean_abs_dv_px": round(float(dv[ok].mean()), 3),
            "share_dv_over_du": round(float((dv[ok] > du[ok]).mean()), 4),
            "seed_depth": score(f["seed_depth"], exact), "mean_abs_residual_m": round(float(res[ok].mean()), 4),
            "share_residual_over_0.1m": round(float((res[ok] > 0.1).mean()), 4)}


def _library_normals(frame, valid, config) -> np.ndarray:
    """The library's Step 1 normals through the hook (checks the hook: must score as ``default``)."""
    from jaxdepth._src.normals import point_normals
    pts = np.where(valid[:, None], np.nan_to_num(np.asarray(frame.points, np.float32)), 0.0).astype(np.float32)
    return np.asarray(point_normals(jnp.asarray(pts), jnp.asarray(valid), lidar=frame.rig.lidar,
                                    smoothing=config.normal_smoothing, fill_max_gap=config.range_fill_max_gap))


def multi_sweep_rows(inp, exact) -> dict:
    from benchmarks.accuracy_twins import crops
    from jaxdepth.batch.sources_job import complete_cloud
    d = SGMConfig()

    def run(config, **kw):
        return score(crops(complete_cloud(inp.cloud, inp.rig, config=config, **kw), inp.rig), exact)
    return {"default": run(d), "no_removal": run(d.replace(outlier_removal=False)),
            "no_free_space": run(d, free_space=False), "no_bracket": run(d.replace(column_bracket=False)),
            "no_free_space_no_bracket": run(d.replace(column_bracket=False), free_space=False),
            "above_background": run(d.replace(above_scan="background"))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweeps", nargs="+", type=int, default=[1, 5])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--json", default=str(RESULTS / "laser_phase_stages.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    doc = {"rig": "kitti", "seed": args.seed, "scale": args.scale, "cases": {}}
    for sweeps in args.sweeps:
        for staggered in (False, True):
            t = time.time()
            tw, inp, exact = twin_input(sweeps, args.seed, args.scale, staggered)
            rows = one_sweep_rows(tw, inp, exact, staggered, args.seed) if sweeps == 1 else multi_sweep_rows(inp, exact)
            name = f"sweeps{sweeps}_{'staggered' if staggered else 'aligned'}"
            doc["cases"][name] = rows
            print(name, rows, f"{time.time() - t:.0f} s", flush=True)
            write_results(args.json, doc, SGMConfig(), t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
