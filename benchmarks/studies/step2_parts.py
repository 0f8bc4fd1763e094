"""Study (issue 38): where Step 2's time goes on the KITTI frame, and what a sharper candidate bound could save.

Three measurements of ``outliers._keep_mask`` (the paper's Algorithm 1, the default "footprint" test) on the
shared frame, each variant compiled once and timed in interleaved rounds in one process (process CPU and wall,
medians over rounds of ``--calls`` calls):

* **parts**: the whole stage against two cut-down programs made at trace time (no library edit): the
  prefilter and the candidate count alone (the exact test replaced by ``valid``), and the exact test without
  its rank loop (each chunk's compaction, candidate views and window words, no pair test). The differences
  are the chunks' set-up and the rank steps. The cut programs' outputs are not the mask.
* **chunks**: :data:`~jaxdepth._src.outlier_exact.CHUNK` (candidate slots per chunk) set to each of
  ``--chunks`` before tracing: fewer chunks, fewer launches (10 chunks of 512 on this frame; one chunk of
  8192); the masks must be equal.
* **pairs**: the candidates of condition 2 alone, the points in their windows, how many (candidate, point)
  pairs meet condition 2 and conditions 1 and 2 (the library's ``lidar_view`` / ``condition_1`` on the
  pairs), and how many candidates are removed: what an exact bound sharper than condition 2 could leave;
  and the candidates with the footprint form's reach bound (``outliers._Reach``).
* **reach**: Step 2 and the whole frame (``complete_with(method="sgm")``) with the reach bound on (the
  library) and off (``outliers._reach`` replaced at trace time), in one process, outputs equal.
  The parts and chunks above are the library's program (with the bound since branch kitti10).

    python -m benchmarks.studies.step2_parts [--rounds 15] [--calls 20] [--chunks 512 1024 2048 4096 8192]
        [--reach-rounds 30] [--json benchmarks/results/step2_parts.json]
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import time

import numpy as np

from benchmarks._common import RESULTS, load_frame, write_results
from benchmarks.bench_end_to_end import wall_and_cpu_ms


def _interleaved(exes, call, rounds, calls):
    """``{name: (median CPU ms, median wall ms, median per-round CPU ratio to the first)}`` per call."""
    names, res = list(exes), {n: [] for n in exes}
    for r in range(rounds):
        for n in names if r % 2 == 0 else names[::-1]:
            wall, cpu = wall_and_cpu_ms(lambda: [call(exes[n]) for _ in range(calls)][-1].block_until_ready())
            res[n].append((cpu / calls, wall / calls))
    first = res[names[0]]
    return {n: {"cpu_ms": statistics.median(c for c, _ in res[n]), "wall_ms": statistics.median(w for _, w in res[n]),
                "cpu_ratio_to_first": statistics.median(a[0] / b[0] for a, b in zip(res[n], first))} for n in names}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument("--chunks", type=int, nargs="+", default=[512, 1024, 2048, 4096, 8192])
    parser.add_argument("--reach-rounds", type=int, default=30)
    parser.add_argument("--json", default=str(RESULTS / "step2_parts.json"))
    args, t0 = parser.parse_args(argv), time.time()
    import jax
    import jax.numpy as jnp

    import jaxdepth
    from jaxdepth._src import outlier_exact as X
    from jaxdepth._src import outliers, presets
    from jaxdepth._src.methods import complete_with
    config = jaxdepth.SGMConfig()
    sparse, K, T, label = load_frame()
    d, k, t, eps = jnp.asarray(sparse), jnp.asarray(K, jnp.float32), jnp.asarray(T, jnp.float32), jnp.float32(1.0)
    height, width = d.shape
    hw, hh = outliers.window_half_sizes(height, width, beams=64, max_half_width_px=config.outlier_max_half_width_px,
                                        max_half_height_px=config.outlier_max_half_height_px)

    def compiled():
        jax.clear_caches()
        return outliers._keep_mask.lower(d, k, t, None, eps, beams=64, half_width=hw, half_height=hh).compile()

    def no_ranks(b, removed, *, ex, row, col, group, **_):   # _column_block's set-up, no rank loop
        start = jnp.clip(b * (2 * group + 1) - ex.k_max, -ex.hw, ex.hw - 2 * group)
        words = X._window_words(ex, row, col, start, 2 * group + 1)[0]
        return removed | jnp.any(jax.lax.population_count(words).sum(axis=0) > 64, axis=0)

    saved, saved_reach = (outliers.exact_test, X._column_block, X.CHUNK), outliers._reach
    exes = {"whole stage": compiled()}
    try:
        outliers.exact_test = lambda valid, ex: valid & (ex.count >= 0)
        exes["prefilter and count"] = compiled()
        outliers.exact_test, X._column_block = saved[0], no_ranks
        exes["... and the chunks' set-up (no rank loop)"] = compiled()
        X._column_block = saved[1]
        chunk_exes = {}
        for c in args.chunks:
            X.CHUNK = c
            chunk_exes[f"CHUNK {c}"] = compiled()
    finally:
        outliers.exact_test, X._column_block, X.CHUNK = saved
        jax.clear_caches()
    call = lambda e: e(d, k, t, None, eps)
    ref = np.asarray(call(exes["whole stage"]))
    assert all((np.asarray(call(e)) == ref).all() for e in chunk_exes.values()), "CHUNK changed the mask"
    for e in [*exes.values(), *chunk_exes.values()]:
        for _ in range(3):
            call(e).block_until_ready()
    load = [os.getloadavg()]
    parts = _interleaved(exes, call, args.rounds, args.calls)
    chunks = _interleaved(chunk_exes, call, args.rounds, args.calls)
    load.append(os.getloadavg())

    frame_kw = {"method": "sgm", "config": config, "lidar": presets.KITTI_HDL64}
    frame = lambda: complete_with.lower(d, k, t, **frame_kw).compile()
    reach_exes = {"Step 2, reach bound on": compiled(), "frame, reach bound on": frame()}
    outliers._reach = lambda *a, **kw: (None, 0)
    try:
        reach_exes.update({"Step 2, reach bound off": compiled(), "frame, reach bound off": frame()})
    finally:
        outliers._reach = saved_reach
        jax.clear_caches()
    reach = {}
    for part in ("Step 2", "frame"):
        pair = {n: e for n, e in reach_exes.items() if n.startswith(part)}
        run = (lambda e: e(d, k, t, None, eps)) if part == "Step 2" else (lambda e: e(d, k, t))
        outs = [np.asarray(run(e)) for e in pair.values()]
        assert (outs[0] == outs[1]).all(), f"{part}: the reach bound changed the output"
        reach.update(_interleaved(pair, run, args.reach_rounds, args.calls // 2))
    load.append(os.getloadavg())

    # pairs: every (candidate, point) of the candidates' windows, through the library's view and conditions
    valid = np.asarray(sparse) > 0
    bounds = outliers._bounds(jnp.asarray(valid), beams=64, half_width=hw, half_height=hh)
    k_max = int(bounds.k_max)
    words = np.asarray(outliers._prefilter(d.astype(jnp.float32), eps, bounds, hh=hh, hw=hw))     # condition 2 alone
    cand = np.unpackbits(words.view(np.uint8), bitorder="little").reshape(height, -1)[:, :width].astype(bool)
    ys, xs = np.nonzero(cand)
    owner, qy, qx = [], [], []
    for dv in range(-hh, hh + 1):
        for du in range(-k_max, k_max + 1):
            y, x = ys + dv, xs + du
            inside = (y >= 0) & (y < height) & (x >= 0) & (x < width)
            inside[inside] &= valid[y[inside], x[inside]]
            owner.append(np.nonzero(inside)[0])
            qy.append(y[inside])
            qx.append(x[inside])
    owner, qy, qx = (np.concatenate(a) for a in (owner, qy, qx))
    py, px, z = ys[owner], xs[owner], np.asarray(sparse, np.float32)
    view = functools.partial(X.lidar_view, K=k, t=t[:3, 3], points_cam=None)
    vp = view(jnp.asarray(z[py, px]), v=jnp.asarray(py, jnp.float32), u=jnp.asarray(px, jnp.float32))
    vq = view(jnp.asarray(z[qy, qx]), v=jnp.asarray(qy, jnp.float32), u=jnp.asarray(qx, jnp.float32))
    c1 = np.asarray(X.condition_1("footprint", vp, vq, jnp.asarray(qx - px), jnp.asarray(qy - py), bounds.cell_u,
                                  bounds.cell_v))
    c2 = z[py, px] > z[qy, qx] + np.float32(1.0)
    removed = np.zeros(len(ys), bool)
    np.logical_or.at(removed, owner, c1 & c2)
    box, hs = outliers._reach(k, t[:3, 3], bounds, shape=(height, width), beams=64, hh=hh)
    words = np.asarray(outliers._prefilter(d.astype(jnp.float32), eps, bounds, hh=hh, hw=hw, reach=box, hs=hs))
    reach_cand = np.unpackbits(words.view(np.uint8), bitorder="little").reshape(height, -1)[:, :width].astype(bool)
    keep = np.asarray(outliers.outlier_keep_mask(d, k, t, beams=64))
    assert removed.sum() == (valid & ~keep).sum(), "the pairs' removals differ from the mask's"
    pairs = {"points": int(valid.sum()), "k_max": k_max, "half_height": hh, "candidates": int(len(ys)),
             "chunks_of_512": int(-(-len(ys) // 512)), "pairs_in_windows": int(len(owner)),
             "pairs_condition_2": int(c2.sum()), "pairs_conditions_1_and_2": int((c1 & c2).sum()),
             "candidates_with_a_condition_2_pair": int(np.unique(owner[c2]).size), "removed": int(removed.sum()),
             "candidates_with_the_reach_bound": int(reach_cand.sum()), "reach_box_half_sizes": [int(box.a), hs],
             "removed_outside_the_reach_candidates": int((~keep & valid & ~reach_cand).sum())}
    for name, row in {**parts, **chunks, **reach}.items():
        print(f"{name:45s} CPU {row['cpu_ms']:.3f} ms  wall {row['wall_ms']:.3f} ms  CPU / first {row['cpu_ratio_to_first']:.3f}")
    print(pairs, "load", load)
    doc = {"what": "Step 2 (outliers._keep_mask) on the KITTI frame: the stage against its prefilter + count and its "
                   "exact test without the rank loop (parts), CHUNK sizes (masks equal), and the candidates' pairs",
           "frame": label, "rounds": args.rounds, "calls": args.calls, "parts": parts, "chunks": chunks,
           "reach_rounds": args.reach_rounds, "reach": reach, "pairs": pairs, "load_average": load}
    write_results(args.json, doc, config, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
