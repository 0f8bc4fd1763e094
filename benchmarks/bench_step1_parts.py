"""Step 1 on the KITTI frame (``pixel_normals``) as stage programs: process CPU per part, interleaved.

Each part of the listed path is jitted on its own with its inputs computed beforehand (real buffers; every
program call also pays ~0.3-0.5 ms of its own: dispatch, output buffers), and as prefixes (the first n parts in
one program of the frame, the differences of which are each part's marginal cost), and the whole
``pixel_normals``; all are called in turn (the order rotating) for ``--rounds`` rounds of ``--calls`` calls
each; process CPU (every thread) per call, medians. Parts: the depth mask and the listing
of the pixels with depth (``compact_indices``); the window start and the per-point back-projection and
binning (``_pixel_points``); the range image (``window_range_image``: scatter-min, per-cell stage); the cell normals
(``cell_normals``: padding, basis, neighbour searches, the three fit stages, the smoothing); the per-point
normal gathers, the rotation into the camera frame and the scatter into the (3, H, W) output. Also each
part's kernels (the LLVM modules of its compiled program; the whole ``pixel_normals`` counts its dense
fallback branch and the never-taken zeros of its fences too).
The last prefix (all parts, without the fallback's test and branch) must give ``pixel_normals``' bytes.

    python -m benchmarks.bench_step1_parts [--rounds 30] [--calls 5] [--json benchmarks/results/step1_parts.json]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

from benchmarks._common import RESULTS, load_frame, write_results
from benchmarks.bench_compile_flags import _cpu


def _parts(d, k, t):
    """``{name: (jitted, args)}`` of Step 1's parts on the frame (inputs computed first)."""
    import jax
    import jax.numpy as jnp

    from jaxdepth._src import pixel_normals as pn
    from jaxdepth._src.compaction import compact_indices
    from jaxdepth._src.normals import cell_normals, normals_at_points
    from jaxdepth._src.presets import KITTI_HDL64 as lidar
    from jaxdepth._src.config import DEFAULT_CONFIG as cfg

    h, w = d.shape
    smoothing, gap = cfg.normal_smoothing, cfg.range_fill_max_gap
    margin, capacity, wc = max(1 + gap, smoothing), -(-h * w // 16), pn.default_window_columns(lidar)
    tok = lambda d: jax.lax.bitcast_convert_type(d[0, 0], jnp.int32)

    def listing(d):
        return compact_indices((jnp.isfinite(d) & (d > 0)).reshape(-1), capacity, tok(d))

    def points(pix, d, k, t):
        col0 = pn._window_start(k, t, h, w, lidar, wc)
        return col0, pn._pixel_points(pix, d, k, t, col0, tok(d), lidar=lidar, window_cols=wc, margin=margin)

    def range_image(pts, col0):
        return pn.window_range_image(pts, col0, pts.key[0], lidar=lidar, window_cols=wc)

    def normals(ri, col0):
        return cell_normals(ri, smoothing, gap, (col0, lidar.columns))

    def output(nxy, nz, pix, slot, key, xy, zr, t):
        ok = key != jnp.iinfo(jnp.int32).max
        xyz = (jnp.real(xy), jnp.imag(xy), jnp.real(zr))
        px, py, pz, sign = normals_at_points(nxy, nz, slot, ok, xyz, key[0])
        R = t[:3, :3]
        n_cam = jnp.stack([(R[i, 0] * px + R[i, 1] * py + R[i, 2] * pz) * sign for i in range(3)])
        return jnp.zeros((3, h * w), jnp.float32).at[:, jnp.where(ok, pix, h * w)].set(n_cam, mode="drop")

    pix, _ = jax.jit(listing)(d)
    col0, pts = jax.jit(points)(pix, d, k, t)
    ri = jax.jit(range_image)(pts, col0)
    nxy, nz = jax.jit(normals)(ri, col0)
    whole = jax.jit(lambda d, k, t: pn.pixel_normals(d, k, t, lidar=lidar, smoothing=smoothing, fill_max_gap=gap))
    def up_to(n):
        """The first ``n`` parts in one program of (d, k, t), returning the last part's outputs."""
        def run(d, k, t):
            pix, _ = listing(d)
            if n == 1:
                return pix
            col0, pts = points(pix, d, k, t)
            if n == 2:
                return pts
            ri = range_image(pts, col0)
            if n == 3:
                return ri
            nxy, nz = normals(ri, col0)
            if n == 4:
                return nxy, nz
            return output(nxy, nz, pix, pts.slot, pts.key, pts.xy, pts.zr, t)
        return jax.jit(run)

    names = ("listing (mask, compact_indices)", "points (window start, back-projection, binning)",
             "range image (scatter-min, cells)", "cell normals (pads, basis, neighbours, fit, smoothing)",
             "output (gathers, rotation, scatter into (3, H, W))")
    alone = {n: (jax.jit(f), a) for n, f, a in zip(names, (listing, points, range_image, normals, output), (
        (d,), (pix, d, k, t), (pts, col0), (ri, col0),
        (nxy, nz, pix, pts.slot, pts.key, pts.xy, pts.zr, t)))}
    prefix = {f"up to {n.split(' (')[0]}": (up_to(i + 1), (d, k, t)) for i, n in enumerate(names)}
    return alone | prefix | {"pixel_normals (whole Step 1)": (whole, (d, k, t))}


def _kernels(fn, args) -> int:
    """Kernels of ``fn``'s compiled program: the LLVM modules XLA:CPU emits (one per distinct kernel, as
    ``bench_compile_flags --anatomy`` counts them), from an ``xla_dump_to`` dump in a temporary folder."""
    import glob
    import tempfile
    with tempfile.TemporaryDirectory(prefix="jaxdepth-step1-") as tmp:
        fn.lower(*args).compile(compiler_options={"xla_dump_to": tmp})
        return len(glob.glob(f"{tmp}/*ir-with-opt.ll"))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=30)
    parser.add_argument("--calls", type=int, default=5)
    parser.add_argument("--json", default=str(RESULTS / "step1_parts.json"))
    args, t0 = parser.parse_args(argv), time.time()
    import jax
    import jax.numpy as jnp
    sparse, K, T, label = load_frame()
    parts = _parts(jnp.asarray(sparse), jnp.asarray(K), jnp.asarray(T))
    import numpy as np
    names = list(parts)
    chained, whole = (np.asarray(parts[n][0](*parts[n][1])) for n in names[-2:])   # all parts in one program
    same = bool(np.array_equal(chained.reshape(whole.shape).view(np.uint8), whole.view(np.uint8)))
    print(f"{label}: the parts chained give pixel_normals' bytes: {same}", flush=True)
    kernels = {n: _kernels(fn, a) for n, (fn, a) in parts.items()}
    cpu = {n: [] for n in names}
    for r in range(args.rounds):
        for n in names[r % len(names):] + names[:r % len(names)]:
            fn, a = parts[n]
            jax.block_until_ready(fn(*a))
            c0 = _cpu()
            for _ in range(args.calls):
                jax.block_until_ready(fn(*a))
            cpu[n].append((_cpu() - c0) / args.calls * 1e3)
    doc = {"what": "Step 1 (pixel_normals) parts as stage programs, process CPU ms per call (medians), interleaved",
           "frame": label, "rounds": args.rounds, "calls": args.calls, "parts_equal_whole": same,
           "cpu_ms_median": {n: statistics.median(cpu[n]) for n in names}, "kernels": kernels,
           "load_average": os.getloadavg(), "runs_cpu_ms": cpu}
    prefixes = [n for n in names if n.startswith("up to ")]
    med = doc["cpu_ms_median"]
    doc["marginal_cpu_ms"] = {n: med[n] - (med[prefixes[i - 1]] if i else 0.0) for i, n in enumerate(prefixes)}
    for n in names:
        extra = f"  (+{doc['marginal_cpu_ms'][n]:.3f} ms)" if n in prefixes else ""
        print(f"{n:58s} CPU {med[n]:6.3f} ms  kernels {kernels[n]}{extra}")
    print(f"load {doc['load_average']}")
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
