"""Per-pixel cost of the single-camera SGM by stage, against the image size (issue 38).

One camera of the shared Argoverse 2 sweep (ring front centre, 1550 x 2048; the sweep's two
VLP-32C merged as one source, as ``bench_rigs``'s single-camera path) cropped to windows of
the same focal length (so a pixel sees the same LiDAR density at every size): 375 x 1242 (the
KITTI image's size), 900 x 1600 (a nuScenes camera's) and the whole 1550 x 2048. Each crop is
centred on the projected points. For each size, each stage of ``complete_points_stages`` is
jitted apart (inputs precomputed), plus the whole single-camera program and a nearest fill of
the same camera; the sizes and stages are timed in interleaved rounds in one process and
reported as ns per pixel (medians) and as each size's ratio to the smallest.

    python -m benchmarks.bench_stage_sizes [--repeats 5] [--out benchmarks/results/stage_sizes.json]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from benchmarks.bench_rigs import AV2_LOG

SIZES = ((375, 1242), (900, 1600), (1550, 2048))


def _timed(fn):
    import jax
    t = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t


def _crop(camera, points, valid, height, width):
    """``camera`` cropped to ``height`` x ``width`` around the median pixel of the points it sees."""
    import jax.numpy as jnp

    from jaxdepth._src.geometry import project_to_image
    from jaxdepth._src.types import Camera
    depth, _ = project_to_image(points, valid, camera.K, camera.T_cam_lidar, height=camera.height,
                                width=camera.width)
    rows, cols = np.nonzero(np.asarray(depth) > 0)
    top = int(np.clip(np.median(rows) - height // 2, 0, camera.height - height))
    left = int(np.clip(np.median(cols) - width // 2, 0, camera.width - width))
    K = np.asarray(camera.K, np.float32).copy()
    K[0, 2] -= left
    K[1, 2] -= top
    return Camera(K=jnp.asarray(K), T_cam_lidar=camera.T_cam_lidar, height=height, width=width)


def _stage_fns(points, valid, camera, spec, config):
    """``{stage: thunk}`` for one camera, each stage its own jit on precomputed inputs."""
    import jax
    import jax.numpy as jnp

    import jaxdepth
    from jaxdepth._src.distance import nearest_seed
    from jaxdepth._src.geometry import project_to_image
    from jaxdepth._src.hypotheses import column_hypotheses
    from jaxdepth._src.normals import point_normals
    from jaxdepth._src.outliers import keep_mask_for_config
    from jaxdepth._src.distance import seed_index
    from jaxdepth._src.pipeline import _at_seed_index, _complete_tail, _gather_seeds, project_with_normals
    from jaxdepth._src.residual import plane_residual
    from jaxdepth._src.smoothing import gaussian_blur
    from jaxdepth._src.validity import seed_distance
    h, w, K, T = camera.height, camera.width, camera.K, camera.T_cam_lidar
    points, valid = jnp.asarray(points), jnp.asarray(valid)
    normals_fn = jax.jit(lambda p, v: point_normals(p, v, lidar=spec, smoothing=config.normal_smoothing,
                                                    fill_max_gap=config.range_fill_max_gap))
    normals = normals_fn(points, valid)
    project_fn = jax.jit(lambda p, v, n: project_with_normals(p, v, n, T, K, height=h, width=w))
    project = lambda: project_fn(points, valid, normals)  # noqa: E731
    sparse, _, pc, nc = project()
    keep_fn = jax.jit(lambda s, pc: keep_mask_for_config(s, K, T, beams=spec.beams, config=config, points_cam=pc))
    keep = keep_fn(sparse, pc)
    seeds_fn = jax.jit(lambda k: nearest_seed(k, metric=config.distance_metric)[1:3])
    du, dv = seeds_fn(keep)

    @jax.jit
    def residual_fn(s, nc, k, du, dv):
        seed_depth, seed_normal = _gather_seeds(s, k, nc, _at_seed_index(seed_index(du, dv)), jnp.any(k))
        return seed_depth, plane_residual(seed_depth, seed_normal, du, dv, K, min_abs_denom=config.min_abs_denom,
                                          max_residual_ratio=config.max_residual_ratio)
    seed_depth, residual = residual_fn(sparse, nc, keep, du, dv)
    depth_raw = jnp.where(seed_depth > 0, seed_depth + residual, 0.0)
    bracket_fn = jax.jit(lambda d, s, k, sd, du, dv, nc: column_hypotheses(
        d, jnp.where(k, s, 0.0), jnp.where(sd > 0, seed_distance(du, dv, sd, metric=config.distance_metric), 0.0),
        nc, K, window_px=h / spec.beams, materialise=True, min_abs_denom=config.min_abs_denom,
        max_residual_ratio=config.max_residual_ratio))
    blur_fn = jax.jit(lambda d: gaussian_blur(d, sigma_px=config.smoothing_sigma_px,
                                              radius_px=config.smoothing_radius_px))
    tail_fn = jax.jit(lambda s, nc, pc: _complete_tail(s, nc, pc, K, T, beams=spec.beams, config=config).depth)
    near_config = jaxdepth.SGMConfig(outlier_removal=False)
    nearest_jit = jax.jit(lambda p, v: jaxdepth.complete_with(
        project_to_image(p, v, K, T, height=h, width=w)[0], K, T, method="nearest", config=near_config))
    nearest_fn = lambda: nearest_jit(points, valid)  # noqa: E731
    return {"projection": project,
            "Step 2 (outlier mask)": lambda: keep_fn(sparse, pc),
            "Step 3 (nearest seed)": lambda: seeds_fn(keep),
            "Step 4a (seed gather + residual)": lambda: residual_fn(sparse, nc, keep, du, dv),
            "Step 4b (column bracket)": lambda: bracket_fn(depth_raw, sparse, keep, seed_depth, du, dv, nc),
            "Step 4c (Gaussian blur)": lambda: blur_fn(depth_raw),
            "Steps 2-4 in one jit": lambda: tail_fn(sparse, nc, pc),
            "whole single-camera program (complete_points)": lambda: jaxdepth.complete_points(
                points, valid, camera, config=config, lidar=spec),
            "nearest fill (projection + complete_with nearest)": nearest_fn}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=str(RESULTS / "stage_sizes.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    if not AV2_LOG.exists():
        print(f"bench_stage_sizes: {AV2_LOG} not found (shared data)", file=sys.stderr)
        return 1
    import jaxdepth
    from jaxdepth._src.types import LidarSpec
    from jaxdepth.batch.sources_job import cloud_sources
    from jaxdepth.io import av2, pad_points
    config = jaxdepth.SGMConfig()
    log = av2.read_log(AV2_LOG)
    rig = av2.read_rig(log)
    cloud = av2.read_cloud(log)
    sources, _ = cloud_sources(cloud, fallback=rig.lidar)
    spec = sources.lidars[0]
    merged = LidarSpec(beams=2 * spec.beams, fov_up_deg=spec.fov_up_deg, fov_down_deg=spec.fov_down_deg,
                       columns=spec.columns)
    points, valid = pad_points(cloud.points)
    front = next(c for c in rig.cameras if c.height < c.width).as_camera()
    fns = {}
    for h, w in SIZES:
        camera = _crop(front, points, valid, h, w)
        for stage, fn in _stage_fns(points, valid, camera, merged, config).items():
            fns[(f"{h}x{w}", stage)] = fn
        print(f"{h} x {w}: compiled", flush=True)
    for fn in fns.values():
        _timed(fn)
    runs = {key: [] for key in fns}
    for r in range(args.repeats):
        for key, fn in fns.items():
            runs[key].append(_timed(fn))
        print(f"round {r + 1} done", flush=True)
    ns_per_px, growth = {}, {}
    smallest = f"{SIZES[0][0]}x{SIZES[0][1]}"
    for (size, stage), times in runs.items():
        h, w = map(int, size.split("x"))
        ns_per_px.setdefault(stage, {})[size] = statistics.median(times) / (h * w) * 1e9
    for stage, by_size in ns_per_px.items():
        growth[stage] = {size: value / by_size[smallest] for size, value in by_size.items()}
        print(f"{stage:55s} " + "  ".join(f"{s} {v:6.1f} ns/px ({growth[stage][s]:.2f}x)"
                                          for s, v in by_size.items()))
    doc = {"what": "ns per pixel per stage of the single-camera SGM, Argoverse 2 front camera cropped, one process",
           "camera": rig.cameras[[c.height < c.width for c in rig.cameras].index(True)].name
           if hasattr(rig.cameras[0], "name") else "landscape ring camera",
           "points": int(len(cloud.points)), "repeats": args.repeats,
           "ns_per_px_median": ns_per_px, "per_px_ratio_to_smallest": growth,
           "runs_s": {f"{size} | {stage}": v for (size, stage), v in runs.items()}}
    write_results(args.out, doc, config, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
