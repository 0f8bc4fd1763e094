"""Study (issue 38): the one-source rig's tail (Steps 3-4) on the nuScenes sample, part by part.

The tail stage program (``rig.rig_stage_tail``, depth only, as ``bench_rig_against_checkout --stages``) on
the shared nuScenes sample (6 x 900 x 1600, one source) is compiled whole and in four cut-down forms made
at trace time (no library edit; ``pipeline``'s names replaced while tracing), each cut dropping one more
part from the end:

* ``whole tail``: the library's program;
* ``no blur``: ``gaussian_blur`` the identity (the last clip stays);
* ``... no bracket``: ``column_hypotheses`` returns the plane depth (its input, the seed distance and the
  masked depth, dropped with it);
* ``... no plane depth``: ``_plane_depth`` returns the gathered seed depth plus the seed normal's channels
  (the four gathers at the seed stay, the residual goes);
* ``seed search only``: ``_tail_after_seeds`` returns the seed index as the depth (the distance transform,
  its fences and one image written out).

Timed in interleaved rounds in one process (host memory kept, ``keep_freed_memory``, as the jobs; process CPU and wall per call, medians over rounds of
``--calls`` calls); the differences of consecutive forms are the parts. The cut forms' outputs are not the
depth. ``--hlo``: the optimised HLO's fusions and loops of the whole tail, counted (``fusion``, ``while``,
``gather`` and ``transpose`` ops, and any ``s64`` / ``f64`` shapes).

    python -m benchmarks.studies.nuscenes_tail_parts [--rounds 9] [--calls 3]
        [--json benchmarks/results/nuscenes_tail_parts.json]
"""

from __future__ import annotations

import argparse
import functools
import os
import re
import statistics
import time

from benchmarks._common import RESULTS, write_results
from benchmarks.bench_end_to_end import wall_and_cpu_ms


def _tail_inputs():
    """``(stage, args, statics, pixels)`` of the nuScenes sample's tail stage (the library's earlier stages run)."""
    import numpy as np

    import jaxdepth
    from benchmarks.bench_rigs import NUSCENES
    from jaxdepth import io
    from jaxdepth._src import rig as R
    rig = io.rig_from_nuscenes_calibration(NUSCENES / "calibration.json")
    points, valid = io.pad_points(io.read_points(next(NUSCENES.glob("*LIDAR_TOP*.pcd.bin")), columns=5)[0])
    cameras = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras])
    recorded = []

    def call(stage, *stage_args, **statics):
        recorded.append((stage, stage_args, statics))
        return stage(*stage_args, **statics)

    R.run_rig_stages(points, valid, cameras, config=jaxdepth.SGMConfig(), lidar=rig.lidar, call=call)
    stage, args, statics = recorded[2]
    pixels = float(sum(int(h) * int(w) for h, w in np.asarray(cameras.image_size)))
    return stage, args, statics, pixels


def _cuts():
    """``{name: {pipeline attribute: replacement}}``, each cut adding one replacement to the previous one's."""
    import jax.numpy as jnp

    from jaxdepth._src import pipeline as P
    from jaxdepth._src.types import Stages

    def no_plane(seed_depth, seed_normal, du, dv, K, *, config):
        kept = seed_depth + seed_normal[0] + seed_normal[1] + seed_normal[2]
        return kept, kept

    def seeds_only(sparse_depth, keep, normals_cam, K, has_seed, *seed_args, **_):
        z = jnp.where(has_seed, seed_args[0].astype(jnp.float32), 0.0)
        normals = jnp.stack(normals_cam) if isinstance(normals_cam, tuple) else normals_cam
        return Stages(sparse_depth=sparse_depth, normals=normals, inlier_mask=keep, seed_depth=z, du=seed_args[0],
                      dv=seed_args[0], residual=z, depth_raw=z, depth=z)

    steps = [("no blur", "gaussian_blur", lambda x, **_: x),
             ("... no bracket", "column_hypotheses", lambda depth_raw, *a, **_: depth_raw),
             ("... no plane depth", "_plane_depth", no_plane),
             ("seed search only", "_tail_after_seeds", seeds_only)]
    cuts, patch = {"whole tail": {}}, {}
    for name, attr, fn in steps:
        assert hasattr(P, attr), attr
        patch = {**patch, attr: fn}
        cuts[name] = patch
    return cuts


def _hlo_counts(text: str) -> dict:
    ops = ("fusion", "while", "gather", "transpose", "copy", "concatenate", "sort")
    counts = {op: len(re.findall(rf"= \S+ {op}\(", text)) for op in ops}
    counts["s64_or_f64_shapes"] = len(re.findall(r"\b(?:s64|f64)\[", text))
    return counts


def time_forms(exes: dict, stage_args, *, rounds: int, calls: int):
    """``({name: [(CPU ms, wall ms) a call, per round]}, [load averages])``: each compiled form run twice, then
    ``rounds`` interleaved rounds (the order reversed every other round) of ``calls`` calls each."""
    import jax
    for exe in exes.values():
        for _ in range(2):
            jax.block_until_ready(exe(*stage_args))
    names, res, load = list(exes), {n: [] for n in exes}, [os.getloadavg()]
    for r in range(rounds):
        for n in names if r % 2 == 0 else names[::-1]:
            wall, cpu = wall_and_cpu_ms(lambda: jax.block_until_ready([exes[n](*stage_args) for _ in range(calls)]))
            res[n].append((cpu / calls, wall / calls))
        print(r, {n: round(v[-1][0], 1) for n, v in res.items()}, "CPU ms", os.getloadavg(), flush=True)
    load.append(os.getloadavg())
    return res, load


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--calls", type=int, default=3)
    parser.add_argument("--hlo", action="store_true", help="count the whole tail's optimised HLO ops")
    parser.add_argument("--json", default=str(RESULTS / "nuscenes_tail_parts.json"))
    args, t0 = parser.parse_args(argv), time.time()
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jobs (no run pays page faults they do not)
    import jax

    from jaxdepth._src import pipeline as P
    stage, stage_args, statics, pixels = _tail_inputs()
    options = getattr(stage, "compiler_options", None)
    fn = (lambda f: lambda *a: f(*a).depth)(functools.partial(stage, **statics))
    exes, hlo = {}, {}
    for name, patch in _cuts().items():
        saved = {attr: getattr(P, attr) for attr in patch}
        try:
            for attr, repl in patch.items():
                setattr(P, attr, repl)
            jax.clear_caches()
            exes[name] = jax.jit(fn).lower(*stage_args).compile(options)
            if args.hlo and name == "whole tail":
                hlo = _hlo_counts(exes[name].as_text())
        finally:
            for attr, orig in saved.items():
                setattr(P, attr, orig)
    jax.clear_caches()
    names, (res, load) = list(exes), time_forms(exes, stage_args, rounds=args.rounds, calls=args.calls)
    whole = res[names[0]]
    rows = {n: {"cpu_ms": statistics.median(c for c, _ in res[n]), "wall_ms": statistics.median(w for _, w in res[n]),
                "cpu_ns_px": statistics.median(c for c, _ in res[n]) * 1e6 / pixels,
                "cpu_ratio_to_whole": statistics.median(a[0] / b[0] for a, b in zip(res[n], whole)),
                "cpu_ms_rounds": [c for c, _ in res[n]]} for n in names}
    parts = {f"{a} - {b}": rows[a]["cpu_ms"] - rows[b]["cpu_ms"] for a, b in zip(names, names[1:])}
    for n, row in rows.items():
        print(f"{n:22s} CPU {row['cpu_ms']:7.2f} ms ({row['cpu_ns_px']:.2f} ns/px)  wall {row['wall_ms']:7.2f} ms  "
              f"CPU / whole {row['cpu_ratio_to_whole']:.3f}")
    print({k: round(v, 2) for k, v in parts.items()}, hlo, "load", load)
    doc = {"what": "the nuScenes sample's one-source tail stage (depth only) whole and cut at trace time: the "
                   "differences of consecutive forms are the blur, the column bracket, the plane depth, the gathers "
                   "at the seed; the last form is the seed search alone", "pixels": pixels, "rounds": args.rounds,
           "calls": args.calls, "forms": rows, "parts_cpu_ms": parts, "hlo_counts_whole": hlo, "load_average": load}
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
