"""Step 1 on the KITTI frame (``pixel_normals``) as stage programs: process CPU per part, interleaved.

Each part of the listed path is jitted on its own with its inputs computed beforehand (real buffers), and
the parts and the whole ``pixel_normals`` are called in turn (the order rotating) for ``--rounds`` rounds of
``--calls`` calls each; process CPU (every thread) per call, medians. Parts: the depth mask and the listing
of the pixels with depth (``compact_indices``); the window start and the per-point back-projection and
binning (``_pixel_points``); the range image (``scatter_argmin`` and the per-cell stage); the cell normals
(``cell_normals``: padding, basis, neighbour searches, the three fit stages, the smoothing); the per-point
normal gathers, the rotation into the camera frame and the scatter into the (3, H, W) output. Also each
part's kernels (the LLVM modules of its compiled program; the whole ``pixel_normals`` counts its dense
fallback branch and the never-taken zeros of its fences too).
The parts' sum exceeds the whole by the parts' own input and output handling.

    python -m benchmarks.bench_step1_parts [--rounds 30] [--calls 5] [--json benchmarks/results/step1_parts.json]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import time

from benchmarks._common import RESULTS, load_frame, write_results


def _cpu() -> float:
    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime


def _parts(d, k, t):
    """``{name: (jitted, args)}`` of Step 1's parts on the frame (inputs computed first)."""
    import jax
    import jax.numpy as jnp

    from jaxdepth._src import pixel_normals as pn
    from jaxdepth._src.compaction import compact_indices
    from jaxdepth._src.geometry import scatter_argmin
    from jaxdepth._src.normals import cell_normals, normals_at_points
    from jaxdepth._src.presets import KITTI_HDL64 as lidar
    from jaxdepth._src.range_image import RangeImage, cell_centres
    from jaxdepth._src.xla_tuning import stage
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

    def range_image(slot, key, thph, zr, col0):
        n_pts, n_win = slot.shape[0], lidar.beams * wc
        _, idx = scatter_argmin(slot, key, n_win, fill=jnp.iinfo(jnp.int32).max)

        def per_cell(idx, thph, zr, col0):     # as pixel_normals' own per-cell stage
            has = idx < n_pts
            safe = jnp.where(has, idx, 0)
            theta_c, phi_c = cell_centres(lidar)
            theta_c = jax.lax.dynamic_slice(jnp.concatenate([theta_c, theta_c[:, :wc]], axis=1), (0, col0), (1, wc))
            shape = (lidar.beams, wc)
            tp = thph.at[safe].get(mode="promise_in_bounds")
            r = jnp.imag(zr).at[safe].get(mode="promise_in_bounds")
            th = jnp.where(has, jnp.real(tp), jnp.broadcast_to(theta_c, shape).reshape(-1))
            ph = jnp.where(has, jnp.imag(tp), jnp.broadcast_to(phi_c, shape).reshape(-1))
            return (jnp.where(has, r, 0.0).reshape(shape), th.reshape(shape), ph.reshape(shape),
                    jnp.where(has, idx, -1).reshape(shape))
        return stage(per_cell, (idx, thph, zr, col0), key[0])

    def normals(r, th, ph, index, col0):
        ri = RangeImage(r=r, theta=th, phi=ph, index=index, cell=jnp.zeros((0,), jnp.int32))
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
    ri = jax.jit(range_image)(pts.slot, pts.key, pts.thph, pts.zr, col0)
    nxy, nz = jax.jit(normals)(*ri, col0)
    whole = jax.jit(lambda d, k, t: pn.pixel_normals(d, k, t, lidar=lidar, smoothing=smoothing, fill_max_gap=gap))
    return {"listing (mask, compact_indices)": (jax.jit(listing), (d,)),
            "points (window start, back-projection, binning)": (jax.jit(points), (pix, d, k, t)),
            "range image (scatter-min, cells)": (jax.jit(range_image), (pts.slot, pts.key, pts.thph, pts.zr, col0)),
            "cell normals (pads, basis, neighbours, fit, smoothing)": (jax.jit(normals), (*ri, col0)),
            "output (gathers, rotation, scatter into (3, H, W))": (jax.jit(output),
                                                                  (nxy, nz, pix, pts.slot, pts.key, pts.xy, pts.zr, t)),
            "pixel_normals (whole Step 1)": (whole, (d, k, t))}


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
    chained, whole = (np.asarray(parts[n][0](*parts[n][1])) for n in names[-2:])
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
    for n in names:
        print(f"{n:58s} CPU {doc['cpu_ms_median'][n]:6.3f} ms  kernels {kernels[n]}")
    print(f"sum of parts {sum(doc['cpu_ms_median'][n] for n in names[:-1]):.3f} ms; load {doc['load_average']}")
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
