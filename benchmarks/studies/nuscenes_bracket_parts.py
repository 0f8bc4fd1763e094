"""Study (issue 38): the nuScenes tail's column bracket, part by part, and a one-key-image form of it.

nusc16 cut the one-source tail stage (``nuscenes_tail_parts``) and found the bracket ~a third of it, half not
explained by its own passes. Here the bracket alone is replaced at trace time (``pipeline.column_hypotheses``;
no library edit) in the same tail stage program (6 x 900 x 1600, depth only, host memory kept), forms timed in
interleaved rounds in one process (process CPU, medians):

* ``library``: the bracket as shipped since nusc17 (one key image and its copy, the 900-step running max, the
  clip in the last kernel);
* ``two key images (the base's)``: ``one_key_image=False``, the form before nusc17 (two key fusions);
* ``none``: no bracket (the plane depth passes through);
* ``image f32``: a plain float image (``kept * 3``) materialised (fenced) and read by the last kernel: the price
  of one extra image-sized buffer in this program;
* ``one key image``, ``two key images``: the base's keys materialised (fenced), read (one bit) by the last kernel;
* ``keys and loop``: the two key images and the running-max loop, the loop's outputs read (one bit) by the last
  kernel, no clip;
* ``clip apart``: the library's bracket with the plane depth fenced first (the clip in a kernel of its own, not in
  the one with the four gathers at the seed);
* ``one key image in place``: a candidate with the library's values bit for bit (checked): one key image, a loop
  whose first half writes each direction's running max into it (rows i and h - 1 - i, disjoint) and whose second
  half recovers each row's key from the other direction's stored max and clips the plane depth's rows in place.

The cut forms' outputs are not the depth; ``library``, the base's form and ``one key image in place`` must be
equal (printed).

    python -m benchmarks.studies.nuscenes_bracket_parts [--rounds 9] [--calls 3]
        [--json benchmarks/results/nuscenes_bracket_parts.json]
"""

from __future__ import annotations

import argparse
import functools
import math
import statistics
import time

from benchmarks._common import RESULTS, write_results


def _in_place(depth_raw, kept_depth, *, window_px):
    """The candidate: the bracket with one key image, clipped in the loop's second half (module docstring)."""
    import jax.numpy as jnp
    from jax import lax

    from jaxdepth._src.hypotheses import _depth_bits
    from jaxdepth._src.xla_tuning import put_row
    h, _ = kept_depth.shape
    g, last = int(math.floor(window_px)), h - 1
    bits, scale, top = _depth_bits(h)
    level = jnp.clip(jnp.round(kept_depth * scale), 1, top).astype(jnp.int32)
    keys = jnp.where(kept_depth > 0, (jnp.arange(h, dtype=jnp.int32)[:, None] << bits) | level, -1)
    get = functools.partial(lax.dynamic_index_in_dim, axis=0, keepdims=False, allow_negative_indices=False)
    down_key = lambda key, r: jnp.where(key >= 0, ((last - r) << bits) | (key & top), -1)  # noqa: E731
    depth = lambda key: jnp.where(key >= 0, (key & top).astype(jnp.float32) / scale, 0.0)  # noqa: E731

    def clip_row(d, up, down, r):
        up = jnp.where(r - (up >> bits) <= g, up, -1)
        down = jnp.where(last - (down >> bits) - r <= g, down, -1)
        ok = (jnp.where(up >= 0, up >> bits, -1) >= 0) & (jnp.where(down >= 0, last - (down >> bits), -1) >= 0)
        z_up, z_dn = depth(up), depth(down)
        return jnp.where(ok & (d > 0), jnp.clip(d, jnp.minimum(z_up, z_dn), jnp.maximum(z_up, z_dn)), d)

    def first(i, state):                        # rows i < h // 2 <= h - 1 - i: each direction's max stored
        c_up, c_dn, keys = state
        c_up = jnp.maximum(c_up, get(keys, i))
        c_dn = jnp.maximum(c_dn, down_key(get(keys, last - i), last - i))
        return c_up, c_dn, put_row(put_row(keys, c_up, i), c_dn, last - i)

    init = jnp.full(keys.shape[1:], -1, jnp.int32)
    c_up, c_dn, stored = lax.fori_loop(0, h // 2, first, (init, init, keys))

    def second(i, state):                       # rows i >= h - h // 2 > h - 1 - i: both neighbours known
        c_up, c_dn, out = state
        j = last - i
        dn_i, up_j = get(stored, i), get(stored, j)
        c_up = jnp.maximum(c_up, jnp.where(last - (dn_i >> bits) == i, (i << bits) | (dn_i & top), -1))
        c_dn = jnp.maximum(c_dn, down_key(jnp.where((up_j >> bits) == j, up_j, -1), j))
        out = put_row(out, clip_row(get(out, i), c_up, dn_i, i), i)
        return c_up, c_dn, put_row(out, clip_row(get(out, j), up_j, c_dn, j), j)

    out = depth_raw
    if h % 2:                                   # the middle row: both directions read its own key
        key = get(stored, h // 2)
        c_up, c_dn = jnp.maximum(c_up, key), jnp.maximum(c_dn, down_key(key, h // 2))
        out = put_row(out, clip_row(get(out, h // 2), c_up, c_dn, h // 2), h // 2)
    return lax.fori_loop(h - h // 2, h, second, (c_up, c_dn, out))[2]


def _forms():
    """``{name: replacement of pipeline.column_hypotheses or None (the library's)}``."""
    import jax.numpy as jnp

    from jaxdepth._src import hypotheses as Hy
    from jaxdepth._src.xla_tuning import fence

    def keys(kept):                             # _column_keys's two key images, before the running max
        h = kept.shape[0]
        bits, scale, top = Hy._depth_bits(h)
        rows = jnp.arange(h, dtype=jnp.int32)[:, None]
        level = jnp.clip(jnp.round(kept * scale), 1, top).astype(jnp.int32)
        return jnp.where(kept > 0, (rows << bits) | level, -1), jnp.where(kept > 0, ((h - 1 - rows) << bits) | level, -1)

    def read(depth_raw, *images):               # the last kernel reads one bit of each image
        return depth_raw + sum((a & 1) for a in images).astype(jnp.float32) * 0.0

    def form(body):
        return lambda depth_raw, kept, *_, window_px, **__: body(depth_raw, kept, window_px)

    return {"library": None,
            "two key images (the base's)": form(lambda d, k, w: Hy.column_hypotheses(d, k, None, None, None,
                                                                                     window_px=w)),
            "none": form(lambda d, k, _: d),
            "image f32": form(lambda d, k, _: d + fence(k * 3.0)[0] * 0.0),
            "one key image": form(lambda d, k, _: read(d, *fence(keys(k)[0]))),
            "two key images": form(lambda d, k, _: read(d, *fence(*keys(k)))),
            "keys and loop": form(lambda d, k, _: read(d, *Hy._running_max_rows(*keys(k)))),
            "clip apart": form(lambda d, k, w: Hy.column_hypotheses(fence(d)[0], k, None, None, None, window_px=w)),
            "one key image in place": form(lambda d, k, w: _in_place(d, k, window_px=w))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for flag, default in (("--rounds", 9), ("--calls", 3)):
        parser.add_argument(flag, type=int, default=default)
    parser.add_argument("--json", default=str(RESULTS / "nuscenes_bracket_parts.json"))
    args, t0 = parser.parse_args(argv), time.time()
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jobs
    import jax
    import numpy as np

    from benchmarks.studies.nuscenes_tail_parts import _tail_inputs, time_forms
    from jaxdepth._src import pipeline as P
    stage, stage_args, statics, pixels, _ = _tail_inputs("nuscenes")
    options = getattr(stage, "compiler_options", None)
    fn = (lambda f: lambda *a: f(*a).depth)(functools.partial(stage, **statics))
    exes, library = {}, P.column_hypotheses
    for name, repl in _forms().items():
        try:
            P.column_hypotheses = repl or library
            jax.clear_caches()
            exes[name] = jax.jit(fn).lower(*stage_args).compile(options)
        finally:
            P.column_hypotheses = library
    jax.clear_caches()
    outs = {n: np.asarray(e(*stage_args)) for n, e in exes.items()}
    same = {n: bool(np.array_equal(o, outs["library"])) for n, o in outs.items()}
    print("equal to the library's depth:", same)
    names, (res, load) = list(exes), time_forms(exes, stage_args, rounds=args.rounds, calls=args.calls)
    base = res["none"]
    rows = {n: {"cpu_ms": statistics.median(c for c, _ in res[n]), "wall_ms": statistics.median(w for _, w in res[n]),
                "cpu_ms_over_none": statistics.median(a[0] - b[0] for a, b in zip(res[n], base)),
                "cpu_ratio_to_library": statistics.median(a[0] / b[0] for a, b in zip(res[n], res["library"])),
                "equal_to_library": same[n], "cpu_ms_rounds": [c for c, _ in res[n]]} for n in names}
    for n, row in rows.items():
        print(f"{n:28s} CPU {row['cpu_ms']:7.2f} ms  over none {row['cpu_ms_over_none']:6.2f} ms  "
              f"/ library {row['cpu_ratio_to_library']:.3f}  equal {row['equal_to_library']}")
    print("load", load)
    doc = {"what": "the nuScenes one-source tail stage (depth only) with the column bracket replaced at trace time: "
                   "none, extra images materialised, the keys and loop without the clip, the clip apart, and a "
                   "one-key-image in-place candidate (same values)", "pixels": pixels, "rounds": args.rounds,
           "calls": args.calls, "forms": rows, "load_average": load}
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
