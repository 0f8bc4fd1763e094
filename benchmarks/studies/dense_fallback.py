"""Does ``pixel_normals``' dense fallback give the same bytes on another checkout? (branch cold4)

    PYTHONPATH=TREE python benchmarks/studies/dense_fallback.py --json OUT.json   # once per checkout
    python benchmarks/studies/dense_fallback.py --compare A.json B.json
    PYTHONPATH=. python benchmarks/studies/dense_fallback.py --timing [--rounds 15] [--compiles 3] --json OUT.json

Branch cold4 computed the fallback's cell normals on column windows of the listed path's width
(:func:`jaxdepth._src.normals.cell_normals_tiled`, so that the fallback shares the listed path's
kernels) instead of on the whole range image. This runs ``pixel_normals`` (each case its own compile,
persistent cache off) on the shared KITTI frame's camera 2 through both paths and hashes the (3, H, W)
float32 output: the listed path (the frame as it is), the fallback by count (``max_points=4096``, the
frame has 18.9k pixels with depth), by the seam (the LiDAR turned by 150-210 degrees about z, the
camera's window across the range image's 360-degree seam), a depth at every pixel (forwards and
backwards), other smoothing / gap options, and ``complete`` on the turned frame. Run it with each
checkout's ``jaxdepth`` first on ``PYTHONPATH`` (the script itself from either), then ``--compare``.

``--timing`` (branch cold4's code only; main kept the whole-image fallback): the fallback's two forms in one process on the dense depth (the
whole range image, traced with ``cell_normals_tiled`` swapped for ``cell_normals``, against the
windows), the KITTI frame turned by 180 degrees and the frame as it is (the listed path, which both
forms share; also through ``jit(complete)``): ``pixel_normals`` alone, compile CPU seconds (``--compiles`` alternating compiles of each
form's program, each traced and lowered anew), output bytes compared, then ``--rounds`` interleaved rounds of 5
calls each, medians of wall and process CPU ms per call.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time


def cases() -> dict:
    import jax
    import numpy as np

    import jaxdepth
    from benchmarks._common import load_frame
    from jaxdepth._src import pixel_normals as PN
    from jaxdepth._src.presets import KITTI_HDL64

    jax.config.update("jax_enable_compilation_cache", False)
    sparse, K, T, label = load_frame()
    sparse, K, T = (np.asarray(a, np.float32) for a in (sparse, K, T))

    def yaw(deg):
        a = np.deg2rad(deg)
        rz = np.array([[np.cos(a), -np.sin(a), 0, 0], [np.sin(a), np.cos(a), 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        return (T @ rz.astype(np.float32)).astype(np.float32)

    def normals(depth, t, **options):
        return PN.pixel_normals(depth, K, t, lidar=KITTI_HDL64, **options)

    dense = (10 + np.random.default_rng(0).random(sparse.shape, dtype=np.float32) * 0.2
             + np.linspace(0, 5, sparse.shape[1], dtype=np.float32)).astype(np.float32)
    runs = {"listed": lambda: normals(sparse, T),
            "fallback_by_count": lambda: normals(sparse, T, max_points=4096),
            "dense_forwards": lambda: normals(dense, T), "dense_backwards": lambda: normals(dense, yaw(180))}
    runs |= {f"yaw{d}": (lambda d=d: normals(sparse, yaw(d))) for d in (150, 170, 180, 190, 200, 210)}
    runs |= {f"yaw180_smoothing{s}_gap{g}": (lambda s=s, g=g: normals(sparse, yaw(180), smoothing=s, fill_max_gap=g))
             for s, g in ((0, 2), (2, 1), (1, 0))}
    runs["complete_yaw180"] = lambda: jaxdepth.complete(sparse, K, yaw(180))
    out = {}
    for name, run in runs.items():
        a = np.ascontiguousarray(np.asarray(run()))
        out[name] = {"sha256": hashlib.sha256(a.tobytes()).hexdigest(), "nonzero": int((a != 0).sum())}
    return {"frame": label, "jaxdepth": jaxdepth.__file__, "cases": out}


def timing(rounds: int, compiles: int) -> dict:
    import resource
    import statistics

    import jax
    import numpy as np

    import jaxdepth
    from benchmarks._common import load_frame
    from jaxdepth._src import normals as N
    from jaxdepth._src import pixel_normals as PN
    from jaxdepth._src.presets import KITTI_HDL64

    if not hasattr(PN, "cell_normals_tiled"):
        raise SystemExit("dense_fallback.py --timing: this checkout has no pixel_normals.cell_normals_tiled "
                         "(the windowed fallback was not taken; its code is on branch cold4)")

    def cpu():
        u = resource.getrusage(resource.RUSAGE_SELF)
        return u.ru_utime + u.ru_stime

    jax.config.update("jax_enable_compilation_cache", False)
    sparse, K, T, _ = load_frame()
    sparse, K, T = (np.asarray(a, np.float32) for a in (sparse, K, T))
    back = (T @ np.diag([-1.0, -1.0, 1.0, 1.0]).astype(np.float32)).astype(np.float32)
    dense = (10 + np.random.default_rng(0).random(sparse.shape, dtype=np.float32) * 0.2
             + np.linspace(0, 5, sparse.shape[1], dtype=np.float32)).astype(np.float32)
    plain = PN.pixel_normals.__wrapped__
    tiled = PN.cell_normals_tiled
    variants = {"whole": lambda ri, s, g, t: N.cell_normals(ri, s, g), "windows": tiled}
    compile_s, forms = {k: [] for k in variants}, {}
    for r in range(compiles):                 # alternating compiles, each of a fresh trace and lowering
        for name in (list(variants) if r % 2 == 0 else list(variants)[::-1]):
            PN.cell_normals_tiled = variants[name]    # read when the program is traced
            lowered = jax.jit(lambda d, t: plain(d, K, t, lidar=KITTI_HDL64)).lower(dense, T)
            PN.cell_normals_tiled = tiled
            c0 = cpu()
            forms[name] = lowered.compile()
            compile_s[name].append(cpu() - c0)
    # jit(complete) in both forms (jitted pixel_normals is traced once per form: caches cleared between)
    whole_program = {}
    for name in variants:
        jax.clear_caches()
        PN.cell_normals_tiled = variants[name]
        whole_program[name] = jax.jit(jaxdepth.complete).lower(sparse, K, T).compile()
        PN.cell_normals_tiled = tiled
    jax.clear_caches()
    out = {"compile_cpu_s": compile_s, "compile_cpu_s_median": {k: statistics.median(v) for k, v in compile_s.items()},
           "cases": {}}
    print(out, flush=True)
    calls = {"dense": (forms, dense, T), "kitti_backwards": (forms, sparse, back), "kitti_listed": (forms, sparse, T),
             "complete_kitti_listed": ({k: (lambda d, t, f=f: f(d, K, t)) for k, f in whole_program.items()}, sparse, T)}
    for case, (fns, depth, t) in calls.items():
        res = {k: np.asarray(jax.block_until_ready(f(depth, t))) for k, f in fns.items()}
        times = {k: {"wall": [], "cpu": []} for k in forms}
        for r in range(rounds):
            for k in (list(forms) if r % 2 == 0 else list(forms)[::-1]):
                f = fns[k]
                t0, c0 = time.perf_counter(), cpu()
                for _ in range(5):
                    jax.block_until_ready(f(depth, t))
                times[k]["wall"].append((time.perf_counter() - t0) / 5 * 1e3)
                times[k]["cpu"].append((cpu() - c0) / 5 * 1e3)
        out["cases"][case] = {"bytes_equal": bool(np.array_equal(res["whole"], res["windows"])),
                              **{f"{k}_ms": {m: statistics.median(v) for m, v in d.items()} for k, d in times.items()}}
        print(case, out["cases"][case], flush=True)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write this checkout's hashes here")
    parser.add_argument("--compare", nargs=2, metavar=("A", "B"), help="compare two --json files")
    parser.add_argument("--timing", action="store_true", help="the fallback's two forms in this process")
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--compiles", type=int, default=3)
    args = parser.parse_args(argv)
    if args.compare:
        a, b = (json.load(open(p)) for p in args.compare)
        diff = [k for k in a["cases"] if a["cases"][k]["sha256"] != b["cases"].get(k, {}).get("sha256")]
        print(f"{len(a['cases'])} cases, {len(diff)} differ: {diff}")
        return 1 if diff else 0
    t0 = time.time()
    doc = timing(args.rounds, args.compiles) if args.timing else cases()
    doc["seconds"] = time.time() - t0
    doc["load_average_at_end"] = list(__import__("os").getloadavg())
    print(json.dumps(doc, indent=1))
    if args.json:
        from jaxdepth.io.atomic import atomic_write_bytes
        atomic_write_bytes(args.json, (json.dumps(doc, indent=1) + "\n").encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
