"""Where the rig paths' time goes: the Argoverse 2 sweep and the nuScenes sample, stage by stage.

Measures in one process (the 2-core VM is shared and drifts by tens of percent within minutes,
so read the ratios of one run, not the seconds), medians of ``--repeats`` interleaved rounds
(every variant once per round, ratios taken within a round, then the median), each variant's
first call (trace + compile + one run) reported apart, ``block_until_ready`` before every clock:

* Argoverse 2, one sweep of the shared log (two VLP-32C as two sources, 7 ring cameras, one of
  them portrait: 2048 x 1550, six 1550 x 2048, 22.2 Mpx; the stacked canvas is 7 x 2048 x 2048
  = 29.4 Mpx):

  - ``rig stages`` : ``complete_sources_stages(...)`` then ``.depth`` (what ``complete_cloud``
    runs: every stage leaves the program), the cameras grouped by size (six on 1550 x 2048, one
    on 2048 x 1550);
  - ``rig stages, one canvas`` : the same program with every camera on the 2048 x 2048 canvas
    (``RigCameras.sizes=None``: the program before the grouping; outputs identical in each
    camera's window);
  - ``rig depth`` (``--depth-only``) : the grouped program in a jit that returns only the depth
    (tried before the grouping; no consistent gain);
  - ``single cameras`` : the single-camera path (``complete_points``, one camera at its own
    size, the sweep's points as one source at the ego origin, 64 merged lasers) over the 7
    cameras in a loop: the same pixels without the canvas;
  - ``nearest`` : a nearest fill of the same sweep through the public API (``project_to_image``
    per camera on the canvas, then ``complete_with(method="nearest")`` without outlier removal);
  - the rig path's stages, each jitted apart over the cameras of one size group (grouped, and
    ``one canvas stage``: all 7 on the canvas): source normals, projection (z-buffer, points and
    normals per pixel, each pixel's source), Step 2 (one pass, each point's own origin), Steps 3-4
    (seeds, residual, bracket, blur).

* nuScenes sample (one HDL-32E, 6 cameras of 900 x 1600, 8.6 Mpx, one size: one group):
  ``complete_rig_stages`` against a loop of ``complete_points`` over the cameras and the nearest fill.

Writes benchmarks/results/rigs.json.

    python -m benchmarks.bench_rigs [--repeats 3] [--skip-stages] [--skip-nuscenes] [--depth-only]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from benchmarks._common import DATA, RESULTS, write_results

AV2_LOG = DATA / "av2" / "sensor" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
NUSCENES = DATA / "nuscenes" / "sample"


def _timed(fn):
    import jax
    t = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t


def _nearest_fn(points, valid, cameras):
    """jit over the rig: project (z-buffer on the canvas) and nearest-fill each camera (no outlier removal)."""
    import jax

    import jaxdepth
    from jaxdepth._src.geometry import project_to_image
    config = jaxdepth.SGMConfig(outlier_removal=False)

    @jax.jit
    def run(points, valid, K, T, size):
        def one(K, T, size):
            sparse, _ = project_to_image(points, valid, K, T, height=cameras.height, width=cameras.width,
                                         valid_size=size)
            return jaxdepth.complete_with(sparse, K, T, method="nearest", config=config)
        return jax.vmap(one)(K, T, size)
    return lambda: run(points, valid, cameras.K, cameras.T_cam_lidar, cameras.image_size)


def _single_fns(points, valid, rig_cameras, spec, config):
    """One ``complete_points`` call per camera at its own size (the single-camera path), in a loop."""
    import jaxdepth
    cams = [c.as_camera() for c in rig_cameras]
    return lambda: [jaxdepth.complete_points(points, valid, c, config=config, lidar=spec) for c in cams]


def _stage_fns(sources, cameras, config, prefix="stage"):
    """The rig path's stages, each its own jit over the cameras of one size group (every camera on the
    canvas when ``cameras.sizes`` is None), the groups one after another: ``{name: thunk}`` (inputs
    precomputed)."""
    import jax
    import jax.numpy as jnp

    from jaxdepth._src import sources as S
    from jaxdepth._src.pipeline import (
        _complete_tail,
        clear_outside_window,
        project_with_normals,
    )
    from jaxdepth._src.rig import size_groups
    s, p = sources.points.shape[:2]
    beams = S.default_beams(sources)
    normals_fn = jax.jit(lambda src: S.source_normals(src, smoothing=config.normal_smoothing,
                                                      fill_max_gap=config.range_fill_max_gap))
    normals = normals_fn(sources).reshape(-1, 3)
    points, valid = sources.points.reshape(-1, 3), sources.valid.reshape(-1)
    source_id = jnp.repeat(jnp.arange(s, dtype=jnp.int32), p)

    def group(h, w, K, T, size):
        @jax.jit
        @jax.vmap
        def project(K, T, size):
            depth, index, pc, nc = project_with_normals(points, valid, normals, T, K, height=h, width=w,
                                                        image_size=size)
            hit = index >= 0
            pixel_source = jnp.where(hit, source_id[jnp.where(hit, index, 0).reshape(-1)].reshape(h, w), -1)
            return depth, pixel_source, pc, nc

        @jax.jit
        @jax.vmap
        def keep(depth, pixel_source, pc, K, T, size):
            T_cam_sources = jnp.einsum("ij,sjk->sik", T, sources.T_ref_source)
            return S.source_keep_mask(depth, pixel_source, pc, K, T_cam_sources, beams=beams, config=config,
                                      image_size=size)

        @jax.jit
        @jax.vmap
        def tail(depth, nc, pc, K, T, kept, size):
            stages = _complete_tail(depth, nc, pc, K, T, beams=beams, config=config, keep=kept, image_size=size)
            return clear_outside_window(stages, size).depth

        depth, pixel_source, pc, nc = project(K, T, size)
        kept = keep(depth, pixel_source, pc, K, T, size)
        return (lambda: project(K, T, size), lambda: keep(depth, pixel_source, pc, K, T, size),
                lambda: tail(depth, nc, pc, K, T, kept, size))

    groups = [group(h, w, cameras.K[idx], cameras.T_cam_lidar[idx], cameras.image_size[idx])
              for (h, w), idx in size_groups(cameras)]
    run_all = lambda k: lambda: [g[k]() for g in groups]  # noqa: E731
    return {f"{prefix}: source normals (Step 1)": lambda: normals_fn(sources),
            f"{prefix}: projection": run_all(0),
            f"{prefix}: Step 2 (per-source viewpoints)": run_all(1),
            f"{prefix}: Steps 3-4": run_all(2)}


def _rounds(variants: dict, repeats: int, baseline: str) -> dict:
    """First call of each variant, then ``repeats`` interleaved rounds: medians and ratios to ``baseline``."""
    first = {}
    for name, fn in variants.items():
        first[name] = _timed(fn)
        print(f"  first call {name}: {first[name]:.1f} s", flush=True)
    runs = {name: [] for name in variants}
    for r in range(repeats):
        for name, fn in variants.items():
            runs[name].append(_timed(fn))
        print(f"  round {r + 1}: " + ", ".join(f"{k} {v[-1]:.2f}" for k, v in runs.items()), flush=True)
    return {"first_call_s": first,
            "median_s": {k: statistics.median(v) for k, v in runs.items()},
            "runs_s": runs,
            f"ratio_to_{baseline.replace(' ', '_')}": {
                k: statistics.median(v[i] / runs[baseline][i] for i in range(repeats)) for k, v in runs.items()}}


def av2_sweep(repeats: int, stages: bool, depth_only: bool = False) -> dict:
    import dataclasses

    import jax

    import jaxdepth
    from jaxdepth._src import sources as S
    from jaxdepth._src.types import LidarSpec
    from jaxdepth.batch.sources_job import cloud_sources
    from jaxdepth.io import av2, pad_points

    config = jaxdepth.SGMConfig()
    log = av2.read_log(AV2_LOG)
    rig = av2.read_rig(log)
    cloud = av2.read_cloud(log)
    sources, _ = cloud_sources(cloud, fallback=rig.lidar)
    cameras = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras])
    real_px = sum(c.height * c.width for c in rig.cameras)
    canvas_px = cameras.count * cameras.height * cameras.width
    spec = sources.lidars[0]  # the stated spec, else the one estimated from the rings (cloud_sources)
    merged = LidarSpec(beams=2 * spec.beams, fov_up_deg=spec.fov_up_deg, fov_down_deg=spec.fov_down_deg,
                       columns=spec.columns)
    padded, valid = pad_points(cloud.points)
    one_canvas = dataclasses.replace(cameras, sizes=None)     # every camera on the 2048 x 2048 canvas
    variants = {
        "rig stages": lambda: np.asarray(S.complete_sources_stages(sources, cameras, config=config).depth),
        "rig stages, one canvas": lambda: np.asarray(
            S.complete_sources_stages(sources, one_canvas, config=config).depth),
        "single cameras": _single_fns(padded, valid, rig.cameras, merged, config),
        "nearest": _nearest_fn(padded, valid, cameras),
    }
    if depth_only:
        depth_fn = jax.jit(lambda src, cams: S.complete_sources_stages(src, cams, config=config).depth)
        variants["rig depth"] = lambda: depth_fn(sources, cameras)
    if stages:
        variants.update(_stage_fns(sources, cameras, config))
        variants.update(_stage_fns(sources, one_canvas, config, prefix="one canvas stage"))
    print(f"Argoverse 2: {len(cloud.points)} points, {sources.count} sources, {cameras.count} cameras, "
          f"{real_px / 1e6:.1f} Mpx real, {canvas_px / 1e6:.1f} Mpx canvas", flush=True)
    out = _rounds(variants, repeats, "single cameras")
    out["ns_per_real_px"] = {k: v / real_px * 1e9 for k, v in out["median_s"].items()}
    out.update(points=len(cloud.points), sources=sources.count, point_bucket=sources.points.shape[1],
               cameras={c.name: [c.height, c.width] for c in rig.cameras}, real_px=real_px, canvas_px=canvas_px)
    return out


def nuscenes_sample(repeats: int) -> dict:
    import jaxdepth
    from jaxdepth.io import pad_points, read_points, rig_from_nuscenes_calibration

    config = jaxdepth.SGMConfig()
    rig = rig_from_nuscenes_calibration(NUSCENES / "calibration.json")
    points, _ = read_points(next(NUSCENES.glob("*LIDAR_TOP*.pcd.bin")), columns=5)
    padded, valid = pad_points(points)
    cameras = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras])
    real_px = sum(c.height * c.width for c in rig.cameras)
    variants = {
        "rig stages": lambda: np.asarray(jaxdepth.complete_rig_stages(padded, valid, cameras, config=config,
                                                                      lidar=rig.lidar).depth),
        "single cameras": _single_fns(padded, valid, rig.cameras, rig.lidar, config),
        "nearest": _nearest_fn(padded, valid, cameras),
    }
    print(f"nuScenes: {len(points)} points, {cameras.count} cameras, {real_px / 1e6:.1f} Mpx", flush=True)
    out = _rounds(variants, repeats, "single cameras")
    out["ns_per_real_px"] = {k: v / real_px * 1e9 for k, v in out["median_s"].items()}
    out.update(points=len(points), real_px=real_px)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-stages", action="store_true", help="no per-stage jits of the Argoverse 2 rig path")
    parser.add_argument("--skip-nuscenes", action="store_true")
    parser.add_argument("--depth-only", action="store_true",
                        help="also the depth-only jit of the rig path (tried: no consistent gain)")
    parser.add_argument("--json", default=str(RESULTS / "rigs.json"))
    args = parser.parse_args(argv)
    if not AV2_LOG.is_dir():
        print(f"shared Argoverse 2 log not found: {AV2_LOG}", file=sys.stderr)
        return 1
    t0 = time.time()
    doc = {"what": "rig paths stage by stage against the single-camera path and a nearest fill, one process",
           "repeats": args.repeats,
           "av2": av2_sweep(args.repeats, stages=not args.skip_stages, depth_only=args.depth_only)}
    if not args.skip_nuscenes and NUSCENES.is_dir():
        doc["nuscenes"] = nuscenes_sample(args.repeats)
    write_results(args.json, doc, None, t0)
    for key in ("av2", "nuscenes"):
        if key in doc:
            print(key, {k: round(v, 3) for k, v in doc[key]["ratio_to_single_cameras"].items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
