"""The rig's Steps 3-4 sub-stage by sub-stage: process CPU of each part jitted apart (issue 38, the rigs' tail).

One process (host memory kept, ``keep_freed_memory``, as the jobs), interleaved rounds, process CPU per real
pixel, every program compiled with the library's compile options (``xla_tuning.COMPILER_OPTIONS``). The tail
``pipeline._complete_tail`` (default ``SGMConfig``: unguided L1 seed, column bracket, no blend) cut at its
sub-stages, each part a program of its own on the real inputs (the previous part's outputs):

- ``seed``: Step 3's distance transform (``nearest_seed`` of the Step 2 mask): ``du``, ``dv``;
- ``gather``: the seed depth and normals read at each pixel's seed (``_gather_seeds``, complex64 pairs);
- ``residual``: the plane residual and the clipped ``depth_raw`` (``plane_residual``);
- ``bracket``: the column bracket (``column_hypotheses``: the neighbour search and the clip);
- ``blur``: Step 4's Gaussian blur (``gaussian_blur``, the window form with ``image_size``);
- ``final``: the measured depth kept, the clips and the window cleared (``clear_outside_window``);
- ``whole``: the tail in one program (``_complete_tail`` then ``clear_outside_window``, ``depth`` out).

Cases: ``vmap6``, the parts under ``vmap`` over the Argoverse 2 sweep's six 1550 x 2048 landscape cameras (the rig's
size group, window form) and ``one``, a single 1550 x 2048 camera (the first, no window, the single-camera path);
beside them ``rig``, the Argoverse 2 tail stage program (``sources_stage_tail``: seven cameras, two size groups,
the canvas). The parts' chain must give the whole's ``depth`` bit for bit (checked). The sum of the parts against
the whole is what fusion between the sub-stages saves (or costs).

``--gather-forms``: instead, the whole tail programs (``vmap6``, ``one``, the Argoverse 2 and the nuScenes tail stage
programs) compiled twice from this library in one process, with its seed gather (``pipeline._gather_seeds``: four
float32 gathers) and with the form before branch rigtail8 (``_pairs_gather`` here: two complex64 pairs), outputs
compared byte for byte, interleaved rounds, per-round ratios library / pairs.

    python -m benchmarks.bench_rig_tail_parts [--rounds 7] [--gather-forms] [--json PATH]
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from benchmarks.bench_rig_tail_split import interleaved_cpu

PARTS = ("seed", "gather", "residual", "bracket", "blur", "final")


def _parts(config, beams: int) -> dict:
    """``{part: per-camera function}`` (module docs); every one takes ``size`` (None: no window) last."""
    import jax.numpy as jnp

    from jaxdepth._src.distance import nearest_seed
    from jaxdepth._src.hypotheses import column_hypotheses
    from jaxdepth._src.pipeline import _gather_seeds
    from jaxdepth._src.residual import plane_residual
    from jaxdepth._src.smoothing import gaussian_blur
    assert config.guidance_weight == 0 and config.column_bracket and not config.blend_hypotheses
    assert config.above_scan == "plane" and config.keep_measured_depth

    def seed(keep, size):
        s = nearest_seed(keep, metric=config.distance_metric, horizontal_cost=config.seed_horizontal_cost)
        return s.du, s.dv

    def gather(sparse, normals, keep, du, dv, size):
        return _gather_seeds(jnp.where(keep, sparse, 0.0), normals, du, dv)

    def residual(seed_depth, seed_normal, du, dv, K, size):
        res = plane_residual(seed_depth, seed_normal, du, dv, K, min_abs_denom=config.min_abs_denom,
                             max_residual_ratio=config.max_residual_ratio)
        return jnp.where(seed_depth > 0, jnp.clip(seed_depth + res, config.min_depth_m, config.max_depth_m), 0.0)

    def bracket(depth_raw, sparse, keep, normals, K, size):
        return column_hypotheses(depth_raw, jnp.where(keep, sparse, 0.0), jnp.zeros_like(depth_raw), normals, K,
                                 window_px=sparse.shape[0] / beams, blend=False, materialise=True,
                                 min_abs_denom=config.min_abs_denom, max_residual_ratio=config.max_residual_ratio,
                                 image_size=size, image_gap=None if size is None else size[0] // beams)

    def blur(depth_raw, size):
        return gaussian_blur(depth_raw, sigma_px=config.smoothing_sigma_px, radius_px=config.smoothing_radius_px,
                             image_size=size)

    def final(depth, sparse, keep, seed_depth, size):
        depth = jnp.where(seed_depth > 0, jnp.clip(jnp.where(keep, sparse, depth), config.min_depth_m,
                                                   config.max_depth_m), 0.0)
        if size is None:
            return depth
        h, w = depth.shape
        inside = (jnp.arange(h)[:, None] < size[0]) & (jnp.arange(w)[None, :] < size[1])
        return jnp.where(inside, depth, 0.0)

    return dict(seed=seed, gather=gather, residual=residual, bracket=bracket, blur=blur, final=final)


def _cases() -> tuple:
    """``(cases, rig)``: ``{case: {part: (jitted, arg builder)}, ...}`` and the rig program (module docs)."""
    import jax
    import jax.numpy as jnp

    from benchmarks.bench_rig_tail_split import av2_landscape_group
    from jaxdepth._src.pipeline import _complete_tail, clear_outside_window
    g = av2_landscape_group()
    config, beams, sizes, view, keep, K, T = (g[k] for k in ("config", "beams", "sizes", "view", "keep", "K", "T"))
    parts = _parts(config, beams)

    def whole(sparse, normals, points, keep, K, T, size):
        out = _complete_tail(sparse, normals, points, K, T, beams=beams, config=config, keep=keep, image_size=size)
        return (out if size is None else clear_outside_window(out, size)).depth

    inputs = {"vmap6": dict(sparse=view.sparse_depth, normals=view.normals_cam, points=view.points_cam, keep=keep,
                            K=K, T=T, size=jnp.broadcast_to(jnp.asarray([1550, 2048], jnp.int32), (6, 2))),
              "one": dict(sparse=view.sparse_depth[0], normals=tuple(n[0] for n in view.normals_cam),
                          points=tuple(p[0] for p in view.points_cam), keep=keep[0], K=K[0], T=T[0], size=None)}
    rig = (jax.jit(lambda *a: functools.partial(g["stage"], **g["statics"])(*a).depth), g["tail_args"],
           float(sum(h * w for h, w in sizes)))
    return inputs, parts, whole, rig


def _pairs_gather(seed_field, normals, du, dv):
    """The seed gather before branch rigtail8: two complex64 pairs (``xla_tuning.pack_pair``), XLA:CPU mode."""
    import jax.numpy as jnp

    from jaxdepth._src.distance import gather_at_seed
    from jaxdepth._src.xla_tuning import pack_pair, unpack_pair
    xy, zd = pack_pair(normals[0], normals[1]), pack_pair(normals[2], seed_field)
    (nx, ny), (nz, depth) = unpack_pair(gather_at_seed(xy, du, dv)), unpack_pair(gather_at_seed(zd, du, dv))
    return depth, jnp.stack([nx, ny, nz])


def _gather_forms(inputs, whole, rig, options) -> dict:
    """``{name: (executable, args, real pixels)}``: each whole tail with the library's gather and ``_pairs_gather``."""
    import jax

    from benchmarks.bench_stage_programs import _case_inputs
    from jaxdepth._src import pipeline
    stages, args, statics, _, one_args = _case_inputs("nuscenes")
    views = jax.jit(functools.partial(stages[0], **statics[0]))(*args[0])
    keeps = jax.jit(functools.partial(stages[1], **statics[1]))(*args[1](views))
    sizes = np.asarray(one_args[-1].image_size).tolist()
    nuscenes = (jax.jit(lambda *a: functools.partial(stages[2], **statics[2])(*a).depth), args[2]((views, keeps)),
                float(sum(h * w for h, w in sizes)))
    library, runs = pipeline._gather_seeds, {}
    for form, gather in (("library", library), ("pairs", _pairs_gather)):
        pipeline._gather_seeds = gather          # read when the programs are traced (below)
        try:
            for case, x in inputs.items():
                a = (x["sparse"], x["normals"], x["points"], x["keep"], x["K"], x["T"], x["size"])
                fn = jax.vmap(whole) if case == "vmap6" else (lambda *b: whole(*b[:-1], None))
                runs[f"{case}/{form}"] = (jax.jit(fn).lower(*a).compile(options), a,
                                          1550 * 2048.0 * (6 if case == "vmap6" else 1))
            for case, (fn, a, px) in (("av2_rig", rig), ("nuscenes_rig", nuscenes)):
                runs[f"{case}/{form}"] = (jax.jit(fn).lower(*a).compile(options), a, px)
        finally:
            pipeline._gather_seeds = library
    return runs


def _compile(fn, args, batched: bool, options):
    import jax
    if batched:
        fn = jax.vmap(fn)
    return jax.jit(fn).lower(*args).compile(options)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--gather-forms", action="store_true", help="the seed gather's two forms (module docs)")
    parser.add_argument("--json", default=None, help="default results/rig_tail_parts.json (--gather-forms: "
                                                        "rig_tail_gather_forms.json)")
    args, t0 = parser.parse_args(argv), time.time()
    args.json = args.json or str(RESULTS / ("rig_tail_gather_forms.json" if args.gather_forms else "rig_tail_parts.json"))
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jaxdepth command (else page faults decide)

    from jaxdepth._src.xla_tuning import COMPILER_OPTIONS
    inputs, parts, whole, rig = _cases()
    if args.gather_forms:
        return _time_gather_forms(_gather_forms(inputs, whole, rig, COMPILER_OPTIONS), args, t0)
    runs, same = {}, {}             # runs[name] = (executable, args, real pixels)
    for case, x in inputs.items():
        batched, px = case == "vmap6", 1550 * 2048.0 * (6 if case == "vmap6" else 1)
        size = x["size"]
        part_args = {"seed": (x["keep"], size)}
        chain = {}

        def run(name, a, batched=batched, case=case, px=px):
            fn = parts[name] if size is not None else (lambda *b, f=parts[name]: f(*b, None))
            a = a if size is not None else a[:-1]
            exe = _compile(fn, a, batched, COMPILER_OPTIONS)
            runs[f"{case}/{name}"] = (exe, a, px)
            return exe(*a)

        chain["du"], chain["dv"] = run("seed", part_args["seed"])
        chain["seed_depth"], chain["seed_normal"] = run(
            "gather", (x["sparse"], x["normals"], x["keep"], chain["du"], chain["dv"], size))
        chain["depth_raw"] = run("residual", (chain["seed_depth"], chain["seed_normal"], chain["du"], chain["dv"],
                                              x["K"], size))
        chain["bracketed"] = run("bracket", (chain["depth_raw"], x["sparse"], x["keep"], x["normals"], x["K"], size))
        chain["blurred"] = run("blur", (chain["bracketed"], size))
        depth = run("final", (chain["blurred"], x["sparse"], x["keep"], chain["seed_depth"], size))
        whole_args = (x["sparse"], x["normals"], x["points"], x["keep"], x["K"], x["T"], size)
        fn = whole if size is not None else (lambda *b: whole(*b, None))
        wa = whole_args if size is not None else whole_args[:-1]
        exe = _compile(fn, wa, batched, COMPILER_OPTIONS)
        runs[f"{case}/whole"] = (exe, wa, px)
        same[case] = int(np.sum(np.asarray(exe(*wa)) != np.asarray(depth)))
    runs["rig/whole"] = (rig[0].lower(*rig[1]).compile(COMPILER_OPTIONS), rig[1], rig[2])
    print("depth values of the parts' chain differing from the whole:", same, flush=True)
    cpu = interleaved_cpu(runs, args.rounds)
    median = {k: statistics.median(v) for k, v in cpu.items()}
    summary = {}
    for case in inputs:
        total = [sum(cpu[f"{case}/{p}"][r] for p in PARTS) for r in range(args.rounds)]
        summary[case] = {"parts_sum_median": statistics.median(total), "whole_median": median[f"{case}/whole"],
                         "whole_over_parts_per_round_median": statistics.median(
                             [w / t for w, t in zip(cpu[f"{case}/whole"], total)]),
                         "share_of_parts_sum": {p: statistics.median([cpu[f"{case}/{p}"][r] / total[r]
                                                                      for r in range(args.rounds)]) for p in PARTS}}
    print("median CPU ns/px", {k: round(v, 2) for k, v in median.items()}, flush=True)
    print("summary", summary, flush=True)
    doc = {"what": "the rig's tail sub-stage by sub-stage (module docs), process CPU ns per real pixel, "
                   "interleaved rounds", "load_average": os.getloadavg(), "cpu_ns_px": cpu, "cpu_ns_px_median": median,
           "summary": summary, "chain_depth_values_differing_from_whole": same}
    write_results(args.json, doc, None, t0)
    return 0


def _time_gather_forms(runs: dict, args, t0) -> int:
    cases = sorted({name.split("/")[0] for name in runs})
    differ = {c: int(np.sum(np.asarray(runs[f"{c}/library"][0](*runs[f"{c}/library"][1]))
                            != np.asarray(runs[f"{c}/pairs"][0](*runs[f"{c}/pairs"][1])))) for c in cases}
    print("depth values differing between the two forms:", differ, flush=True)
    cpu = interleaved_cpu(runs, args.rounds)
    ratio = {c: [a / b for a, b in zip(cpu[f"{c}/library"], cpu[f"{c}/pairs"])] for c in cases}
    median = {k: statistics.median(v) for k, v in cpu.items()}
    summary = {c: {"library_over_pairs_per_round_median": statistics.median(ratio[c]),
                   "rounds_below_1": sum(r < 1 for r in ratio[c])} for c in cases}
    print("median CPU ns/px", {k: round(v, 2) for k, v in median.items()}, "\nlibrary / pairs", summary, flush=True)
    doc = {"what": "the whole tail with the library's seed gather against the pairs form (module docs, --gather-forms), "
                   "process CPU ns per real pixel, interleaved rounds", "load_average": os.getloadavg(),
           "cpu_ns_px": cpu, "cpu_ns_px_median": median, "library_over_pairs_per_round": ratio, "summary": summary,
           "depth_values_differing": differ}
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
