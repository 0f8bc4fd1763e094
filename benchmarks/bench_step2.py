"""Step 2 (the outlier mask) alone, ns per pixel, on KITTI and Argoverse 2 geometry, against a baseline.

Cases: the KITTI frame (352 x 1216, image input); the Argoverse 2 front camera cropped at the same
focal length to 375 x 1242, 900 x 1600 and the whole 1550 x 2048 (the sweep's two VLP-32C as one
64-beam source, points given: as ``bench_stage_sizes``); two cameras of the rig path (each pixel's own
LiDAR origin, ``sources.source_keep_mask``'s call): a landscape 1550 x 2048 and the portrait 2048 x 1550.
Each case reports its window half sizes, the run-time half width ``k``, the points, the prefilter's
candidates and the exact test's chunks. ``--baseline FILE``: another version of
``jaxdepth/_src/outliers.py`` (e.g. ``git show main:jaxdepth/_src/outliers.py > /tmp/outliers_main.py``),
loaded beside this one; both run in interleaved rounds in one process, their masks must be equal, and
the ratio this / baseline is taken within each round (median), of wall and of process CPU time
(the CPU figures hold up better on a loaded machine). ``--checkout PATH``: instead, another checkout's whole
library (``PATH/jaxdepth`` copied as the package ``jaxdepth_base``, as ``bench_rig_against_checkout`` does),
so that its ``outlier_exact.py`` and ``compaction.py`` are the baseline's too. ``--cases``: only the cases
whose names start so.

    python -m benchmarks.bench_step2 [--repeats 5] [--baseline FILE | --checkout PATH] [--cases "AV2 rig" ...]
        [--out benchmarks/results/step2.json]
"""

from __future__ import annotations

import argparse
import importlib.util
import inspect
import os
import statistics
import sys
import time

import numpy as np

from benchmarks._common import RESULTS, load_frames, write_results
from benchmarks.bench_rigs import AV2_LOG


def _inputs():
    """``{case: (args, beams, origins?)}``: the (depth, K, T, points[, (3, H, W) origins, (S, 3) origins, pixel
    source]) of each case."""
    import jax.numpy as jnp

    import jaxdepth
    from benchmarks.bench_stage_sizes import SIZES, _crop
    from jaxdepth._src import sources as S
    from jaxdepth._src.normals import point_normals
    from jaxdepth._src.pipeline import project_with_normals
    from jaxdepth._src.types import LidarSpec
    from jaxdepth.batch.sources_job import cloud_sources
    from jaxdepth.io import av2, pad_points
    config = jaxdepth.SGMConfig()
    s, _, K, T = load_frames()["image_02"]
    cases = {"KITTI 352x1216 (image)": ((jnp.asarray(s), jnp.asarray(K, jnp.float32), jnp.asarray(T, jnp.float32),
                                         None), 64, False)}
    log = av2.read_log(AV2_LOG)
    rig, cloud = av2.read_rig(log), av2.read_cloud(log)
    sources, _ = cloud_sources(cloud, fallback=rig.lidar)
    spec = sources.lidars[0]
    merged = LidarSpec(beams=2 * spec.beams, fov_up_deg=spec.fov_up_deg, fov_down_deg=spec.fov_down_deg,
                       columns=spec.columns)
    points, valid = (jnp.asarray(a) for a in pad_points(cloud.points))
    normals = point_normals(points, valid, lidar=merged, smoothing=config.normal_smoothing,
                            fill_max_gap=config.range_fill_max_gap)
    front = next(c for c in rig.cameras if c.height < c.width).as_camera()
    for h, w in SIZES:
        cam = _crop(front, points, valid, h, w)
        depth, _, pc, _ = project_with_normals(points, valid, normals, cam.T_cam_lidar, cam.K, height=h, width=w)
        cases[f"AV2 crop {h}x{w}"] = ((depth, cam.K, cam.T_cam_lidar, pc), merged.beams, False)
    n_src, per = sources.points.shape[:2]
    src_normals = S.source_normals(sources, smoothing=config.normal_smoothing,
                                   fill_max_gap=config.range_fill_max_gap).reshape(-1, 3)
    source_id = jnp.repeat(jnp.arange(n_src, dtype=jnp.int32), per)
    portrait = next(c for c in rig.cameras if c.height > c.width)
    for label, c in (("landscape", rig.cameras[1] if rig.cameras[0] is portrait else rig.cameras[0]),
                     ("portrait", portrait)):
        cam = c.as_camera()
        depth, index, pc, _ = project_with_normals(sources.points.reshape(-1, 3), sources.valid.reshape(-1),
                                                   src_normals, cam.T_cam_lidar, cam.K, height=cam.height,
                                                   width=cam.width)
        hit = index >= 0
        pixel_source = jnp.where(hit, source_id[jnp.where(hit, index, 0).reshape(-1)].reshape(index.shape), 0)
        T_cs = jnp.einsum("ij,sjk->sik", cam.T_cam_lidar, sources.T_ref_source)
        origins = jnp.stack([T_cs[:, k, 3][pixel_source] for k in range(3)])
        cases[f"AV2 rig {label} {cam.height}x{cam.width} (per-pixel origins)"] = (
            (depth, cam.K, T_cs[0], pc, origins, T_cs[:, :3, 3], pixel_source), S.default_beams(sources), True)
    return cases


def _fns(module, args, beams, origins):
    import jax
    import jax.numpy as jnp

    from jaxdepth._src.outliers import window_half_sizes
    h, w = args[0].shape
    hw, hh = window_half_sizes(h, w, beams=beams, max_half_width_px=12, max_half_height_px=24)
    opts = dict(beams=beams, half_width=hw, half_height=hh)
    if origins:     # as sources.source_keep_mask calls it (the sources' origins and each pixel's source, where taken)
        if "pixel_source" in inspect.signature(module._keep_mask).parameters:
            f = jax.jit(lambda s, K, T, p, o, table, src: module._keep_mask(
                s, K, T, p, jnp.float32(1.0), origins=table, pixel_source=src, **opts))
        else:
            f = jax.jit(lambda s, K, T, p, o, table, src: module._keep_mask(s, K, T, p, jnp.float32(1.0), origins=o,
                                                                            **opts))
    else:
        f = jax.jit(lambda s, K, T, p: module._keep_mask(s, K, T, p, jnp.float32(1.0), **opts))
    return (lambda: f(*args)), dict(half_width=hw, half_height=hh)


def _info(args, beams, hw, hh):
    """k, points, candidates and chunks of a case (this version's phases)."""
    import jax.numpy as jnp

    from jaxdepth._src import outliers as O
    from jaxdepth._src.outlier_exact import CHUNK
    depth = args[0]
    valid = (depth > 0) & jnp.isfinite(depth)
    bounds = O._bounds(valid, beams=beams, half_width=hw, half_height=hh)
    reach, hs = None, 0
    if args[3] is None and len(args) == 4 and O._row_block(depth.shape[0], hh) is None:   # as _keep_mask: image input
        reach, hs = O._reach(jnp.asarray(args[1], jnp.float32), jnp.asarray(args[2], jnp.float32)[:3, 3], bounds,
                             shape=depth.shape, beams=beams, hh=hh)
    words = O._prefilter(depth, jnp.float32(1.0), bounds, hh=hh, hw=hw, reach=reach, hs=hs)
    count = int(O._compact(words)[0])
    return dict(points=int(bounds.n_points), k=int(bounds.k_max), candidates=count, chunks=-(-count // CHUNK))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default=None, help="another outliers.py to time against (masks must agree)")
    parser.add_argument("--checkout", default=None, help="another checkout whose whole library is the baseline")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=str(RESULTS / "step2.json"))
    parser.add_argument("--cases", nargs="*", default=None, help="only the cases whose names start so")
    args, t0 = parser.parse_args(argv), time.time()
    if not AV2_LOG.exists():
        print(f"bench_step2: {AV2_LOG} not found (shared data)", file=sys.stderr)
        return 1
    import jax

    from jaxdepth._src import outliers
    versions = {"this": outliers}
    if args.baseline:
        spec = importlib.util.spec_from_file_location("outliers_baseline", args.baseline)
        versions["baseline"] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(versions["baseline"])
    elif args.checkout:
        import pathlib
        import tempfile

        from benchmarks.bench_rig_against_checkout import BASE, _copy_as_base
        folder = tempfile.TemporaryDirectory(prefix="bench_step2_")     # removed when main returns
        _copy_as_base(pathlib.Path(args.checkout), pathlib.Path(folder.name))
        versions["baseline"] = importlib.import_module(f"{BASE}._src.outliers")
    fns, info, px = {}, {}, {}
    for case, (case_args, beams, origins) in _inputs().items():
        if args.cases and not any(case.startswith(c) for c in args.cases):
            continue
        masks = []
        for name, module in versions.items():
            fns[(case, name)], sizes = _fns(module, case_args, beams, origins)
            masks.append(np.asarray(fns[(case, name)]()))
        if any((m != masks[0]).any() for m in masks[1:]):
            print(f"bench_step2: {case}: the masks differ from the baseline's", file=sys.stderr)
            return 1
        info[case] = dict(sizes, **_info(case_args, beams, sizes["half_width"], sizes["half_height"]))
        px[case] = int(case_args[0].size)
        print(case, info[case], flush=True)
    runs, cpu = {key: [] for key in fns}, {key: [] for key in fns}
    for r in range(args.repeats):
        for key, fn in (list(fns.items()) if r % 2 == 0 else list(fns.items())[::-1]):   # order alternating
            t, c = time.perf_counter(), time.process_time()
            jax.block_until_ready(fn())
            runs[key].append(time.perf_counter() - t)
            cpu[key].append(time.process_time() - c)
    ns_per_px = {f"{case} | {name}": statistics.median(v) / px[case] * 1e9 for (case, name), v in runs.items()}
    cpu_ns_per_px = {f"{case} | {name}": statistics.median(v) / px[case] * 1e9 for (case, name), v in cpu.items()}
    ratio, cpu_ratio = ({case: statistics.median(a / b for a, b in zip(r[(case, "this")], r[(case, "baseline")]))
                         for case in info} if len(versions) > 1 else {} for r in (runs, cpu))
    for case in info:
        print(f"{case:55s} " + "  ".join(f"{n} {ns_per_px[f'{case} | {n}']:6.1f} ns/px "
                                         f"(CPU {cpu_ns_per_px[f'{case} | {n}']:5.1f})" for n in versions)
              + (f"  this/baseline {ratio[case]:.2f} (CPU {cpu_ratio[case]:.2f})" if ratio else ""))
    doc = {"what": "Step 2 alone (outliers._keep_mask), ns per pixel, medians of interleaved rounds, one process",
           "baseline": args.baseline or args.checkout, "repeats": args.repeats, "cases": info, "ns_per_px_median": ns_per_px,
           "ratio_this_to_baseline": ratio, "cpu_ns_per_px_median": cpu_ns_per_px, "cpu_ratio_this_to_baseline": cpu_ratio,
           "load_average": os.getloadavg(), "runs_s": {f"{case} | {name}": v for (case, name), v in runs.items()},
           "runs_cpu_s": {f"{case} | {name}": v for (case, name), v in cpu.items()}}
    write_results(args.out, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
