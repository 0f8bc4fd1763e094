"""Study (issue 38): a rig's tail (Steps 3-4) part by part: the nuScenes sample (one source) or the Argoverse 2 sweep.

The tail stage program (depth only, as ``bench_rig_against_checkout --stages``: ``rig.rig_stage_tail`` on the
shared nuScenes sample, 6 x 900 x 1600, one source; with ``--case av2`` ``sources.sources_stage_tail`` on the
shared Argoverse 2 sweep, two LiDARs, two sweeps, ``above_scan="capped"``, six 1550 x 2048 cameras and one
2048 x 1550) is compiled whole and in cut-down forms made at trace time (no library edit; ``pipeline``'s
names replaced while tracing), each cut dropping one more part from the end:

* ``whole tail``: the library's program;
* ``no blur``: ``gaussian_blur`` a fence (its input written out, as the blur reads it; the last clip stays;
  the identity let XLA fuse the plane's kernels into the canvas's stacking, 1.8x the whole tail on Argoverse 2);
* ``... no capped plane`` (``capped`` only): ``capped_above_scan`` returns its input (its top-line loop and
  window go with it; its clip stays);
* ``... no bracket``: ``column_hypotheses`` returns the plane depth (its input, the seed distance and the
  masked depth, dropped with it);
* ``... no plane depth``: ``_plane_depth`` returns the gathered seed depth plus the seed normal's channels
  (the four gathers at the seed stay, the residual goes);
* ``... no gathers``: ``_gather_seeds`` returns each pixel's own depth and normals (no gather at the seed);
* ``seed search only``: ``_tail_after_seeds`` returns the seed index as the depth (the distance transform,
  its fences and one image written out).

``--groups``: every form also on each size group alone (``rig.map_by_size``'s ``per_camera`` run for that
group, zeros of its outputs' shapes for the others), then ``no group`` (the canvas's stacking of zeros).
Timed in interleaved rounds in one process (host memory kept, ``keep_freed_memory``, as the jobs; process CPU
and wall per call, medians over rounds of ``--calls`` calls); the differences of consecutive forms are the
parts. The cut forms' outputs are not the depth. ``--hlo``: the whole tail's optimised HLO counted (``fusion``,
``while``, ``conditional``, ``gather``, ``transpose``, ``copy`` ... ops, any ``s64`` / ``f64`` shapes, the loops'
trip counts, the gathers' shapes).

    python -m benchmarks.studies.nuscenes_tail_parts [--case nuscenes | av2] [--groups] [--rounds 9] [--calls 3]
        [--hlo] [--json benchmarks/results/<case>_tail_parts.json]
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


def _tail_inputs(case: str):
    """``(stage, args, statics, pixels, groups)`` of the case's tail stage (the library's earlier stages run);
    ``groups``: the rig's size groups, ``((h, w), camera indices)``."""
    from benchmarks.bench_rig_against_checkout import case_run, record_stages
    from jaxdepth._src import rig as R
    run, args, pixels = case_run("jaxdepth", case)
    stage, stage_args, statics = record_stages(run, args)[2]
    return stage, stage_args, statics, pixels, R.size_groups(args[-1])


def _cuts(capped: bool):
    """``{name: {pipeline attribute: replacement}}``, each cut adding one replacement to the previous one's
    (``capped``: the capped plane, ``above_scan="capped"``, cut after the blur)."""
    import jax.numpy as jnp

    from jaxdepth._src import pipeline as P
    from jaxdepth._src.types import Stages
    from jaxdepth._src.xla_tuning import fence

    def no_plane(seed_depth, seed_normal, du, dv, K, *, config):
        kept = seed_depth + seed_normal[0] + seed_normal[1] + seed_normal[2]
        return kept, kept

    def no_gathers(sparse_depth, keep, normals, at, has_seed):
        return jnp.where(has_seed, sparse_depth, 0.0), jnp.stack(normals) if isinstance(normals, tuple) else normals

    def seeds_only(sparse_depth, keep, normals_cam, K, has_seed, *seed_args, **_):
        z = jnp.where(has_seed, seed_args[0].astype(jnp.float32), 0.0)
        normals = jnp.stack(normals_cam) if isinstance(normals_cam, tuple) else normals_cam
        return Stages(sparse_depth=sparse_depth, normals=normals, inlier_mask=keep, seed_depth=z, du=seed_args[0],
                      dv=seed_args[0], residual=z, depth_raw=z, depth=z)

    steps = [("no blur", "gaussian_blur", lambda x, **_: fence(x)[0]),
             *([("... no capped plane", "capped_above_scan", lambda depth_raw, *a, **_: depth_raw)] if capped else []),
             ("... no bracket", "column_hypotheses", lambda depth_raw, *a, **_: depth_raw),
             ("... no plane depth", "_plane_depth", no_plane),
             ("... no gathers", "_gather_seeds", no_gathers),
             ("seed search only", "_tail_after_seeds", seeds_only)]
    cuts, patch = {"whole tail": {}}, {}
    for name, attr, fn in steps:
        assert hasattr(P, attr), attr
        patch = {**patch, attr: fn}
        cuts[name] = patch
    return cuts


def _only_group(size):
    """A ``rig.map_by_size`` replacement whose ``per_camera`` runs for the size group ``size`` ((h, w); None:
    for none) and gives zeros of its outputs' shapes for the others (the canvas's stacking kept)."""
    import jax
    import jax.numpy as jnp

    from jaxdepth._src import rig as R
    library = R.map_by_size

    def map_by_size(per_camera, cameras, images=None, per_group=None):
        def one(*a, height, width):
            if (height, width) == size:
                return per_camera(*a, height=height, width=width)
            shapes = jax.eval_shape(functools.partial(per_camera, height=height, width=width), *a)
            return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        return library(one, cameras, images, per_group)
    return map_by_size


def _forms(capped: bool, groups, per_group: bool) -> dict:
    """``{name: [(module, attribute, replacement)]}``: the cuts on every group; with ``per_group``, each cut on
    each size group alone, then no group (the canvas's stacking alone)."""
    from jaxdepth._src import pipeline as P
    from jaxdepth._src import rig as R
    cuts = _cuts(capped)
    forms = {name: [(P, a, f) for a, f in patch.items()] for name, patch in cuts.items()}
    if per_group:
        for (h, w), idx in groups:
            for name, patch in cuts.items():
                forms[f"{len(idx)} x {h} x {w}: {name}"] = [(R, "map_by_size", _only_group((h, w))),
                                                           *((P, a, f) for a, f in patch.items())]
        forms["no group"] = [(R, "map_by_size", _only_group(None))]
    return forms


def _hlo_counts(text: str) -> dict:
    ops = ("fusion", "while", "conditional", "gather", "transpose", "copy", "concatenate", "sort")
    counts = {op: len(re.findall(rf" {op}\(", text)) for op in ops}
    counts["s64_or_f64_shapes"] = len(re.findall(r"\b(?:s64|f64)\[", text))
    counts["loop_trip_counts"] = re.findall(r'"known_trip_count":\{"n":"(\d+)"', text)
    counts["gather_shapes"] = re.findall(r"= (\w+\[[\d,]*\])\S* gather\(", text)
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
    parser.add_argument("--case", choices=("nuscenes", "av2"), default="nuscenes")
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--calls", type=int, default=3)
    parser.add_argument("--groups", action="store_true", help="also every cut on each size group alone")
    parser.add_argument("--hlo", action="store_true", help="count the whole tail's optimised HLO ops")
    parser.add_argument("--json", default=None, help="default: benchmarks/results/<case>_tail_parts.json")
    args, t0 = parser.parse_args(argv), time.time()
    args.json = args.json or str(RESULTS / f"{args.case}_tail_parts.json")
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jobs (no run pays page faults they do not)
    import jax

    stage, stage_args, statics, pixels, groups = _tail_inputs(args.case)
    options = getattr(stage, "compiler_options", None)
    fn = (lambda f: lambda *a: f(*a).depth)(functools.partial(stage, **statics))
    exes, hlo = {}, {}
    for name, patch in _forms(statics["config"].above_scan == "capped", groups, args.groups).items():
        saved = [(mod, attr, getattr(mod, attr)) for mod, attr, _ in patch]
        try:
            for mod, attr, repl in patch:
                setattr(mod, attr, repl)
            jax.clear_caches()
            exes[name] = jax.jit(fn).lower(*stage_args).compile(options)
            if args.hlo and name == "whole tail":
                hlo = _hlo_counts(exes[name].as_text())
        finally:
            for mod, attr, orig in saved:
                setattr(mod, attr, orig)
        print("compiled", name, round(time.time() - t0), "s", flush=True)
    jax.clear_caches()
    names, (res, load) = list(exes), time_forms(exes, stage_args, rounds=args.rounds, calls=args.calls)
    whole = res[names[0]]
    rows = {n: {"cpu_ms": statistics.median(c for c, _ in res[n]), "wall_ms": statistics.median(w for _, w in res[n]),
                "cpu_ns_px": statistics.median(c for c, _ in res[n]) * 1e6 / pixels,
                "cpu_ratio_to_whole": statistics.median(a[0] / b[0] for a, b in zip(res[n], whole)),
                "cpu_ms_rounds": [c for c, _ in res[n]]} for n in names}
    parts = {f"{a} - {b}": rows[a]["cpu_ms"] - rows[b]["cpu_ms"] for a, b in zip(names, names[1:])}
    if "no group" in rows:
        parts.update({f"{n} - no group": rows[n]["cpu_ms"] - rows["no group"]["cpu_ms"] for n in names if ":" in n})
    for n, row in rows.items():
        print(f"{n:40s} CPU {row['cpu_ms']:7.2f} ms ({row['cpu_ns_px']:.2f} ns/px)  wall {row['wall_ms']:7.2f} ms  "
              f"CPU / whole {row['cpu_ratio_to_whole']:.3f}")
    print({k: round(v, 2) for k, v in parts.items()}, hlo, "load", load)
    doc = {"what": f"the {args.case} case's tail stage (depth only) whole and cut at trace time: the differences "
                   "of consecutive forms are the blur, the capped plane (av2), the column bracket, the plane depth, "
                   "the gathers at the seed; the last form is the seed search alone; with --groups each form on one "
                   "size group alone (the others zeros), and no group", "case": args.case,
           "groups": [[list(size), [int(i) for i in idx]] for size, idx in groups], "pixels": pixels,
           "rounds": args.rounds,
           "calls": args.calls, "forms": rows, "parts_cpu_ms": parts, "hlo_counts_whole": hlo, "load_average": load}
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
