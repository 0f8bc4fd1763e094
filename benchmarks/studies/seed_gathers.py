"""Study (issue 38, nusc18): the one-source tail's four gathers at the seed on the nuScenes sample (6 x 900 x 1600).

The tail stage program's last kernel (optimised HLO: one loop fusion, ``minimum_select_fusion``) reads the seed
depth and the three normal channels at every pixel's flat seed index (``pipeline._gather_seeds`` through
``xla_tuning.take_last``: one flat gather per channel, the camera's offset added inside the fusion), with the
residual, the plane depth and the bracket's clip. Two sets of forms, each timed in interleaved rounds in one
process (host memory kept, ``keep_freed_memory``, as the jobs; process CPU per call, medians; per-round ratios to
the first form):

* ``--part alone``: the gathers alone, on the sample's real seed index (the library's seed search run first) and
  its real depth and normals, one (6, 900, 1600) float32 image out: ``four`` (the library's four flat gathers,
  summed), ``one`` (the depth's gather alone), ``none`` (the four images read at the pixel itself, no gather),
  ``index`` (the index converted, nothing gathered), ``identity`` (the four gathers at each pixel's own index),
  ``rows4`` (one gather of a (6 H W, 4) row from the four channels packed beforehand, outside the timed
  program), ``rows4_packed`` (the same with the packing inside the program), ``rows4_strided`` /
  ``rows4_sliced`` (four gathers of the packed array, at ``4 i + k`` / at ``4 i`` of four shifted slices), ``pairs`` (two complex64 gathers
  from the channels packed in pairs beforehand), ``offsets_signed`` / ``offsets_unsigned`` (the residual's du,
  dv from the index as int32 or uint32 remainder and quotient, with two products; no gather).
* ``--part tail``: the tail stage program (depth only, ``bench_rig_against_checkout --stages``'s) as the
  library traces it; ``packed_input``: the same program traced with the four channels handed in packed,
  (6, H, W, 4), and read by one row gather (what a projection that wrote the packed layout would give the
  tail; the packing itself is not in it); ``packed_strided`` / ``packed_sliced``: the packed input read by four
  gathers at ``4 i + k`` / at ``4 i`` of four shifted slices (each form's depth compared bit for bit with the
  library's); ``no_gathers``:
  the four channels read at the pixel itself (the gathers' share of the real kernel; not the depth); and
  ``pack`` (a program that packs the four channels, alone: the pass a tail-side packing would add).

    python -m benchmarks.studies.seed_gathers [--part alone tail] [--rounds 9] [--calls 5]
        [--json benchmarks/results/seed_gathers.json]
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import time

from benchmarks._common import RESULTS, write_results


def _timed(calls: dict, rounds: int, per_round: int) -> dict:
    """``{name: {cpu_ms, ratio}}``: process CPU ms a call, medians of ``rounds`` interleaved rounds
    (:func:`~benchmarks.studies.nuscenes_tail_parts.time_forms`, each call a compiled form and its arguments)."""
    from benchmarks.studies.nuscenes_tail_parts import time_forms

    res, _ = time_forms(calls, (), rounds=rounds, calls=per_round)
    cpu = {n: [c for c, _ in v] for n, v in res.items()}
    first = cpu[next(iter(cpu))]
    return {n: {"cpu_ms": statistics.median(v),
                "ratio_to_first": statistics.median(a / b for a, b in zip(v, first)),
                "cpu_ms_rounds": v} for n, v in cpu.items()}


def _stage():
    """``(stage, args, statics)`` of the nuScenes tail stage and the sample's flat seed index (6, 900, 1600)."""
    import jax
    import jax.numpy as jnp

    from benchmarks.studies.nuscenes_tail_parts import _tail_inputs
    from jaxdepth._src import pipeline as P
    from jaxdepth._src.types import Stages
    stage, args, statics, *_ = _tail_inputs("nuscenes")

    def seeds_only(sparse_depth, keep, normals_cam, K, has_seed, *seed_args, **_):
        z = jnp.zeros(sparse_depth.shape, jnp.float32)
        return Stages(sparse_depth=sparse_depth, normals=jnp.stack(normals_cam), inlier_mask=keep, seed_depth=z,
                      du=seed_args[0], dv=seed_args[0], residual=z, depth_raw=z, depth=z)

    saved, P._tail_after_seeds = P._tail_after_seeds, seeds_only
    try:
        jax.clear_caches()
        index = jax.block_until_ready(stage(*args, **statics).du)
    finally:
        P._tail_after_seeds = saved
        jax.clear_caches()
    return stage, args, statics, index


def _take_rows():
    """``values[index]`` of a (N, 4) table at an integer index image; under ``vmap`` one flat gather of the batch's
    rows (member ``b`` at ``b N + index``), as ``xla_tuning.take_last`` for the last axis."""
    import jax.numpy as jnp
    from jax import custom_batching

    @custom_batching.custom_vmap
    def take(values, index):
        return values.at[index].get(mode="promise_in_bounds", wrap_negative_indices=False)

    @take.def_vmap
    def _(axis_size, in_batched, values, index):
        b, n = values.shape[:2]
        flat = values.reshape(b * n, values.shape[-1])
        at = (jnp.arange(b, dtype=jnp.int32) * n).reshape((b,) + (1,) * (index.ndim - 1)) + index
        return flat.at[at].get(mode="promise_in_bounds", wrap_negative_indices=False), True

    return take


def part_alone(stage_args, index, rounds: int, per_round: int) -> dict:
    import jax
    import jax.numpy as jnp

    from jaxdepth._src.xla_tuning import COMPILER_OPTIONS
    view = stage_args[0][0]
    d, (n0, n1, n2) = view.sparse_depth, view.normals_cam
    c, h, w = d.shape
    n = h * w
    base = (jnp.arange(c, dtype=jnp.int32) * n)[:, None, None]
    vv, uu = jnp.arange(h, dtype=jnp.int32)[:, None], jnp.arange(w, dtype=jnp.int32)[None, :]

    def take(x, at):
        return x.reshape(-1).at[at].get(mode="promise_in_bounds", wrap_negative_indices=False)

    def pack(d, n0, n1, n2):
        return jnp.stack([x.reshape(-1) for x in (d, n0, n1, n2)], axis=-1)

    def four(d, n0, n1, n2, i):
        return take(d, base + i) + take(n0, base + i) + take(n1, base + i) + take(n2, base + i)

    def rows(p, i):
        g = p.at[base + i].get(mode="promise_in_bounds", wrap_negative_indices=False)
        return g[..., 0] + g[..., 1] + g[..., 2] + g[..., 3]

    def strided(p, i):
        at = 4 * (base + i)
        return take(p, at) + take(p, at + 1) + take(p, at + 2) + take(p, at + 3)

    def sliced(p, i):
        at, m = 4 * (base + i), 4 * c * n - 3
        return sum(take(jax.lax.slice(p.reshape(-1), (k,), (k + m,)), at) for k in range(4))

    def pairs(a, b, i):
        ga, gb = take(a, base + i), take(b, base + i)
        return ga.real + ga.imag + gb.real + gb.imag

    def offsets(i, unsigned):
        j = i.astype(jnp.uint32) if unsigned else i
        du, dv = (j % w).astype(jnp.int32) - uu, (j // w).astype(jnp.int32) - vv
        return du.astype(jnp.float32) * n0 + dv.astype(jnp.float32) * n1

    identity = jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32).reshape(h, w), (c, h, w))
    packed = jax.block_until_ready(jax.jit(pack)(d, n0, n1, n2))
    pair_a, pair_b = jax.block_until_ready((jax.lax.complex(d, n0), jax.lax.complex(n1, n2)))
    forms = {"four": (four, (d, n0, n1, n2, index)),
             "one": (lambda d, i: take(d, base + i), (d, index)),
             "none": (lambda d, n0, n1, n2: d + n0 + n1 + n2, (d, n0, n1, n2)),
             "index": (lambda i: i.astype(jnp.float32), (index,)),
             "identity": (four, (d, n0, n1, n2, identity)),
             "rows4": (rows, (packed, index)),
             "rows4_packed": (lambda d, n0, n1, n2, i: rows(pack(d, n0, n1, n2), i), (d, n0, n1, n2, index)),
             "rows4_strided": (strided, (packed, index)),
             "rows4_sliced": (sliced, (packed, index)),
             "pairs": (pairs, (pair_a, pair_b, index)),
             "offsets_signed": (lambda i: offsets(i, False), (index,)),
             "offsets_unsigned": (lambda i: offsets(i, True), (index,))}
    exes = {k: (jax.jit(f).lower(*a).compile(COMPILER_OPTIONS), a) for k, (f, a) in forms.items()}
    return _timed({k: functools.partial(e, *a) for k, (e, a) in exes.items()}, rounds, per_round)


def part_tail(stage, stage_args, statics, rounds: int, per_round: int) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxdepth._src import pipeline as P
    from jaxdepth._src.xla_tuning import take_last
    options = getattr(stage, "compiler_options", None)
    take_rows = _take_rows()
    views = stage_args[0]
    view = views[0]
    packed = jnp.stack([view.sparse_depth, *view.normals_cam], axis=-1)               # (C, H, W, 4)
    packed_args = ((view._replace(normals_cam=(packed,)),) + tuple(views[1:]),) + tuple(stage_args[1:])

    flat_at = P._at_seed_index

    def at_rows(seed_at):
        h, w = seed_at.shape
        flat = flat_at(seed_at)
        return lambda f: take_rows(f.reshape(h * w, 4), seed_at) if f.ndim == 3 else flat(f)

    def at_strided(seed_at):
        h, w = seed_at.shape
        flat = flat_at(seed_at)
        return lambda f: (jnp.stack([take_last(f.reshape(h * w * 4), 4 * seed_at + k) for k in range(4)], axis=-1)
                          if f.ndim == 3 else flat(f))

    def at_sliced(seed_at):
        h, w = seed_at.shape
        flat, m = flat_at(seed_at), 4 * h * w - 3
        return lambda f: (jnp.stack([take_last(jax.lax.slice(f.reshape(4 * h * w), (k,), (k + m,)), 4 * seed_at)
                                     for k in range(4)], axis=-1) if f.ndim == 3 else flat(f))

    def gather_rows(sparse_depth, keep, normals, at, has_seed):
        g = at(normals[0])
        return jnp.where(has_seed, g[..., 0], 0.0), jnp.stack([g[..., 1], g[..., 2], g[..., 3]])

    def no_gathers(seed_at):
        return lambda f: f

    fn = (lambda f: lambda *a: f(*a).depth)(functools.partial(stage, **statics))
    patches = {"library": ({}, stage_args), "packed_input": ({"_at_seed_index": at_rows, "_gather_seeds": gather_rows},
                                                              packed_args),
               "packed_strided": ({"_at_seed_index": at_strided, "_gather_seeds": gather_rows}, packed_args),
               "packed_sliced": ({"_at_seed_index": at_sliced, "_gather_seeds": gather_rows}, packed_args),
               "no_gathers": ({"_at_seed_index": no_gathers}, stage_args)}
    exes = {}
    for name, (patch, args) in patches.items():
        saved = {attr: getattr(P, attr) for attr in patch}
        try:
            for attr, repl in patch.items():
                setattr(P, attr, repl)
            jax.clear_caches()
            exes[name] = (jax.jit(fn).lower(*args).compile(options), args)
        finally:
            for attr, orig in saved.items():
                setattr(P, attr, orig)
    jax.clear_caches()
    if os.environ.get("SEED_GATHERS_HLO"):
        for k, (e, _) in exes.items():
            with open(os.path.join(os.environ["SEED_GATHERS_HLO"], f"{k}.hlo"), "w") as f:
                f.write(e.as_text())
    pack = jax.jit(lambda d, n: jnp.stack([d, *n], axis=-1)).lower(view.sparse_depth, view.normals_cam).compile(options)
    exes["pack"] = (pack, (view.sparse_depth, view.normals_cam))
    depth = {k: np.asarray(e(*a)) for k, (e, a) in exes.items() if k != "pack"}
    differ = {k: int(np.sum(depth[k].view(np.uint32) != depth["library"].view(np.uint32)))
              for k in ("packed_input", "packed_strided", "packed_sliced")}
    timed = _timed({k: functools.partial(e, *a) for k, (e, a) in exes.items()}, rounds, per_round)
    return {"forms": timed, "depth_values_differing_from_library": differ}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", nargs="+", choices=("alone", "tail"), default=["alone", "tail"])
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--calls", type=int, default=5)
    parser.add_argument("--json", default=str(RESULTS / "seed_gathers.json"))
    args, t0 = parser.parse_args(argv), time.time()
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jobs
    stage, stage_args, statics, index = _stage()
    doc, load = {"rounds": args.rounds, "calls": args.calls}, [os.getloadavg()]
    if "alone" in args.part:
        doc["alone"] = part_alone(stage_args, index, args.rounds, args.calls)
    if "tail" in args.part:
        doc["tail"] = part_tail(stage, stage_args, statics, args.rounds, args.calls)
    load.append(os.getloadavg())
    doc["load_average"] = load
    for part in ("alone", "tail"):
        forms = doc.get(part, {}).get("forms", doc.get(part, {}))
        for name, row in forms.items():
            print(f"{part:6s} {name:18s} CPU {row['cpu_ms']:7.2f} ms  / first {row['ratio_to_first']:.3f}")
    if "tail" in doc:
        print("depth values differing from the library's:", doc["tail"]["depth_values_differing_from_library"])
    print("load", load)
    doc["what"] = ("the nuScenes one-source tail's four gathers at the seed: alone on the sample's seed index, and in "
                   "the tail stage program (library, packed input, no gathers, the packing pass alone)")
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
