"""Every image-sized fill and copy of the rig's one depth program, and what each costs at run time.

The Argoverse 2 sweep's and the nuScenes sample's depth program (``bench_rig_against_checkout``'s, what the
jobs run) compiled with the library's options; in its optimised HLO (``compiled.as_text()``) every
instruction outside a fusion with at least ``--min-elements`` elements that is a ``copy``, a fusion that only
copies or transposes one operand (``wrapped_copy``), or a fill (a fusion that broadcasts a scalar), with its
dtype, bytes, the computation it sits in (the entry, a loop body, or a conditional's branch ``[0]`` /
``[1]``: a :func:`~jaxdepth._src.xla_tuning.stage` conditional's branch 0 is its ``zeros`` branch, never
taken) and the JAX operation it comes from. Then, after three warm runs, ``--runs`` runs in one ``jax.profiler``
trace (the process keeping freed memory as the ``jaxdepth`` command does): each listed instruction's kernel time
(mean ms a run; kernels split over threads add up their parts) and calls a run (0: never executed).

``--transposes ROUNDS``: the distance transform alone (``nearest_seed``, L1) with the seed mask's columns
packed 32 to a uint32 before their transpose (:func:`~jaxdepth._src.xla_tuning.mask_columns`, the library) against
the transposed bool mask (the form before, set as ``distance.mask_columns`` / ``mask_column``), on random 1 % masks
of the Argoverse 2 groups' shapes under ``vmap`` ((6, 1550, 2048), (1, 2048, 1550)) and random 5 % masks of the
KITTI frame's (352, 1216); outputs compared, process CPU of interleaved rounds, the median of per-round ratios
library / before.

``--row-keys ROUNDS``: the distance transform alone (``nearest_seed``, L1) with the row keys transposed as int32
pairs on images of >= 2**20 pixels (:func:`~jaxdepth._src.xla_tuning.key_rows`, the library, branch rigtail13)
against the int16 transpose at every size (the form before, ``distance.key_rows`` set to ``keys.T``), at the
Argoverse 2 groups', the nuScenes group's ((6, 900, 1600), 1 %) and the KITTI frame's shapes (the frame: the
same program in both, the pairs start at 2**20 pixels); outputs compared, CPU ratio library / before.

``--column-pass ROUNDS``: a probe of one way to drop the distance transform's int32 zero fill: the L1
column pass's first sweep writing into the row keys transposed and widened to int32 (one transposing
convert) instead of into a zero-filled buffer read from the int16 transpose (the library), on random 1 %
masks of the Argoverse 2 landscape group's shape (6, 1550, 2048) under ``vmap``; outputs compared, process
CPU of interleaved rounds, ratio variant / library.

    python -m benchmarks.bench_rig_fills [--cases av2 nuscenes] [--runs 3] [--min-elements 1000000]
        [--column-pass 9] [--transposes 15] [--row-keys 21] [--json benchmarks/results/rig_fills.json]
"""

from __future__ import annotations

import argparse
import collections
import math
import re
import statistics
import time

from benchmarks._common import RESULTS, write_results

_BYTES = {"pred": 1, "s8": 1, "u8": 1, "s16": 2, "u16": 2, "s32": 4, "u32": 4, "f32": 4, "c64": 8}


def hlo_fills_and_copies(text: str, min_elements: int) -> list:
    """The image-sized copies and fills of an optimised HLO module's text (see the module docs)."""
    comps, cur = {}, None
    for line in text.splitlines():
        m = re.match(r"^(?:ENTRY )?%?([\w.\-]+) \(.*\) -> .* \{$", line)
        if m:
            cur = comps.setdefault(m.group(1), [])
        elif line.startswith("}"):
            cur = None
        elif cur is not None and line.strip():
            cur.append(line.strip())
    caller, fused = {}, set()
    for name, lines in comps.items():
        for line in lines:
            for kind, names in re.findall(r"(calls|branch_computations|body|condition|to_apply)=\{?([%\w.,\- ]+)\}?",
                                          line):
                for i, callee in enumerate(x.strip().lstrip("%") for x in names.split(",")):
                    caller.setdefault(callee, (name, kind, i, line.split(" = ")[0].replace("ROOT ", "")))
                    fused.update([callee] if kind == "calls" else [])
    rows = []
    for name, lines in comps.items():
        if name in fused:
            continue
        for line in lines:
            m = re.match(r"(?:ROOT )?%([\w.\-]+) = (\w+)\[([\d,]*)\]\S* ([\w\-]+)\((.*?)\)(.*)", line)
            if not m:
                continue
            inst, dtype, dims, op, _, rest = m.groups()
            n = math.prod(int(d) for d in dims.split(",") if d)
            kind = None
            if n >= min_elements and op == "copy":
                kind = "copy"
            elif n >= min_elements and op == "fusion":
                body = comps[re.search(r"calls=%([\w.\-]+)", rest).group(1)]
                root = next(x for x in body if x.startswith("ROOT"))
                if " broadcast(" in root and all(re.search(r" (parameter|constant)\(", x) for x in body[:-1]):
                    kind = "fill"
                elif re.search(r" (copy|transpose)\(", root) and len(body) == 2:
                    kind = "copy (layout)"
            if kind:
                where = caller.get(name)
                origin = re.search(r'op_name="([^"]*)"', line)
                rows.append({"kind": kind, "name": inst, "shape": f"{dtype}[{dims}]", "elements": n,
                             "mb": n * _BYTES.get(dtype, 4) / 1e6,
                             "in": "entry" if where is None else f"{where[3]} {where[1]}[{where[2]}]",
                             "op": origin.group(1) if origin else ""})
    return rows


def _profiled(exe, args, runs: int) -> tuple:
    """``({kernel: ms a run}, {kernel: calls a run})`` over ``runs`` runs in one ``jax.profiler`` trace, after
    three warm runs (the heap at its peak: a trace per run, parsed between runs, left the Argoverse 2 program's
    large fills faulting their pages in again, ~10x their time)."""
    import glob
    import gzip
    import json
    import tempfile

    import jax
    for _ in range(3):
        jax.block_until_ready(exe(*args))
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            for _ in range(runs):
                jax.block_until_ready(exe(*args))
        trace = json.load(gzip.open(glob.glob(f"{tmp}/**/perfetto_trace.json.gz", recursive=True)[0]))
    us, calls = collections.Counter(), collections.Counter()
    for event in trace["traceEvents"] if isinstance(trace, dict) else trace:
        if event.get("ph") == "X" and not event.get("name", "$").startswith(("$", "ThunkExecutor", "end: ")):
            us[event["name"]] += event.get("dur", 0)
            calls[event["name"]] += 1
    return {k: v / runs / 1e3 for k, v in us.items()}, {k: v / runs for k, v in calls.items()}


def run_case(case: str, runs: int, min_elements: int) -> dict:
    from benchmarks.bench_rig_against_checkout import _program
    exe, args, pixels = _program("jaxdepth", case, True)
    rows = hlo_fills_and_copies(exe.as_text(), min_elements)
    ms, calls = _profiled(exe, args, runs)
    for row in rows:
        row["ms"], row["calls"] = ms.get(row["name"], 0.0), calls.get(row["name"], 0)
        print(f"{case:9s} {row['kind']:13s} {row['shape']:18s} {row['mb']:6.1f} MB {row['ms']:7.2f} ms "
              f"x{row['calls']:<4g} {row['name']:22s} {row['in'][:40]:40s} {row['op'][-60:]}", flush=True)
    executed = [r for r in rows if r["calls"] > 0]
    print(f"{case}: kernels' sum {sum(ms.values()):.0f} ms a run; executed fills and copies "
          f"{sum(r['ms'] for r in executed):.1f} ms ({len(executed)} of {len(rows)} listed)", flush=True)
    return {"rows": rows, "kernels_ms_a_run": sum(ms.values()), "pixels": pixels,
            "executed_ms": sum(r["ms"] for r in executed)}


def _interleaved(exes: dict, mask, rounds: int) -> tuple:
    """Two compiled forms ``{name: exe}`` of one function of ``mask``: (every output the same, ``{name: [process
    CPU s a round]}``), ``rounds`` rounds, the order alternating."""
    import jax
    import numpy as np
    outs = [jax.block_until_ready(e(mask)) for e in exes.values()]
    same = all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(*outs))
    cpu = {k: [] for k in exes}
    for r in range(rounds):
        for k in (list(exes) if r % 2 == 0 else list(exes)[::-1]):
            t = time.process_time()
            jax.block_until_ready(exes[k](mask))
            cpu[k].append(time.process_time() - t)
    return same, cpu


def column_pass_probe(rounds: int) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxdepth._src import distance as D
    from jaxdepth._src.xla_tuning import COMPILER_OPTIONS
    library = D._l1_column_pass

    def widened(row_key_t, far, horizontal_cost=1):
        w, h = row_key_t.shape
        cb = D._bits(h) + 1
        init = jnp.full((w,), far << cb, jnp.int32)

        def forward(i, hk, carry):
            g = hk >> 1 if horizontal_cost == 1 else horizontal_cost * (hk >> 1)
            return jnp.minimum((jnp.minimum(g, far) << cb) | (i << 1) | (hk & 1), carry + (1 << cb))

        key = D._sweep(row_key_t.T.astype(jnp.int32), init, forward)
        return D._sweep(key, init, lambda i, row, carry: jnp.minimum(row, carry + (1 << cb)), reverse=True), cb

    mask = jnp.asarray(np.random.default_rng(0).random((6, 1550, 2048)) < 0.01)
    exes = {}
    try:
        for name, column_pass in (("library", library), ("widened", widened)):
            D._l1_column_pass = column_pass
            fn = jax.jit(jax.vmap(lambda m: tuple(D.nearest_seed.__wrapped__(m))))
            exes[name] = fn.lower(mask).compile(COMPILER_OPTIONS)
    finally:
        D._l1_column_pass = library
    same, cpu = _interleaved(exes, mask, rounds)
    ratios = [b / a for a, b in zip(cpu["library"], cpu["widened"])]
    out = {"same_bytes": same, "cpu_ms_median": {k: statistics.median(v) * 1e3 for k, v in cpu.items()},
           "ratio_widened_over_library": statistics.median(ratios), "ratios": ratios}
    print("column pass probe:", out, flush=True)
    return out


def _distance_forms_probe(label: str, names: tuple, before: tuple, shapes: tuple, rounds: int) -> dict:
    """``nearest_seed`` (L1) compiled with ``distance``'s functions ``names`` as the library has them and set to
    ``before``, on random masks of ``shapes`` ((shape, density); 3-D: under ``vmap``): outputs compared, process
    CPU of interleaved rounds, the median of per-round ratios library / before."""
    import jax
    import numpy as np

    from jaxdepth._src import distance as D
    from jaxdepth._src.xla_tuning import COMPILER_OPTIONS

    forms = {"library": tuple(getattr(D, n) for n in names), "before": before}
    out = {}
    for shape, density in shapes:
        mask = jax.numpy.asarray(np.random.default_rng(0).random(shape) < density)
        exes = {}
        try:
            for name, values in forms.items():
                for attr, value in zip(names, values):
                    setattr(D, attr, value)
                fn = lambda m: tuple(D.nearest_seed.__wrapped__(m))  # noqa: E731
                exes[name] = jax.jit(jax.vmap(fn) if len(shape) == 3 else fn).lower(mask).compile(COMPILER_OPTIONS)
        finally:
            for attr, value in zip(names, forms["library"]):
                setattr(D, attr, value)
        same, cpu = _interleaved(exes, mask, rounds)
        ratios = [a / b for a, b in zip(cpu["library"], cpu["before"])]
        key = "x".join(map(str, shape))
        out[key] = {"same_bytes": same, "cpu_ms_median": {k: statistics.median(v) * 1e3 for k, v in cpu.items()},
                    "ratio_library_over_before": statistics.median(ratios),
                    "rounds_below_1": sum(x < 1 for x in ratios), "ratios": ratios}
        print(f"{label} probe:", key, {k: v for k, v in out[key].items() if k != "ratios"}, flush=True)
    return out


def transposes_probe(rounds: int) -> dict:
    from jax import lax

    def before_column(columns, u):
        return lax.dynamic_index_in_dim(columns, u, 0, keepdims=False, allow_negative_indices=False)

    return _distance_forms_probe("transposes", ("mask_columns", "mask_column"), (lambda m: m.T, before_column),
                                 (((6, 1550, 2048), 0.01), ((1, 2048, 1550), 0.01), ((352, 1216), 0.05)), rounds)


def row_keys_probe(rounds: int) -> dict:
    return _distance_forms_probe("row keys", ("key_rows",), (lambda keys_t: keys_t.T,),
                                 (((6, 1550, 2048), 0.01), ((1, 2048, 1550), 0.01), ((6, 900, 1600), 0.01),
                                  ((352, 1216), 0.05)), rounds)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for flag, default in (("--runs", 3), ("--min-elements", 1_000_000), ("--column-pass", 0), ("--transposes", 0),
                          ("--row-keys", 0)):
        parser.add_argument(flag, type=int, default=default)
    parser.add_argument("--cases", nargs="*", default=["av2", "nuscenes"], choices=("av2", "nuscenes"))
    parser.add_argument("--json", help="result path (default results/rig_fills.json)")
    a = parser.parse_args(argv, argparse.Namespace(json=str(RESULTS / "rig_fills.json")))
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jaxdepth command
    t0 = time.time()
    doc = {"cases": {case: run_case(case, a.runs, a.min_elements) for case in a.cases}}
    if a.column_pass:
        doc["column_pass_probe"] = column_pass_probe(a.column_pass)
    if a.transposes:
        doc["transposes_probe"] = transposes_probe(a.transposes)
    if a.row_keys:
        doc["row_keys_probe"] = row_keys_probe(a.row_keys)
    with open("/proc/loadavg") as f:
        doc["loadavg_end"] = f.read().split()[:3]
    write_results(a.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
