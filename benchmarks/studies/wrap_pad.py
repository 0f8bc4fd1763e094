"""What the range-image wrap padding as one gather saves in Step 1's compile, and what it costs in its run.

    PYTHONPATH=. python -m benchmarks.studies.wrap_pad [--rounds 40] [--compiles 3]
        [--json benchmarks/results/wrap_pad.json]

``xla_tuning.wrap_pad`` pads the four range-image channels of :mod:`jaxdepth._src.normals` before the
neighbour search: columns wrap around 360 degrees, rows take a fill value. (The smoothing's box-sum
pads of computed normals stay ``wrap_pad_slices`` in both forms here: as a gather they changed last
bits at the test suite's compile flags; ``results/wrap_pad_allpads.json`` measured them gathered too.)
Two forms, in one process on the shared KITTI frame's ``pixel_normals`` (Step 1 of ``complete``:
the listed branch that the frame takes and the dense fallback, each with its own cell-normal chain):

- ``slices``: the form before (branch cold3), :func:`jaxdepth._src.xla_tuning.wrap_pad_slices`: the
  last and first ``k`` columns as two slices, the seam's +-2 pi added to them, one concatenate with
  the array and the fill rows (still the plain form, tricks off);
- ``gather``: the current :func:`jaxdepth._src.xla_tuning.wrap_pad` (tricks on, the default on CPU),
  one ``take`` with static column indices, the seam's +-2 pi through ``where`` on the pad columns,
  then ``jnp.pad`` for the rows.

Both give the same bits (checked). Reported: the compiled program's kernels (fusions, and the
compiled HLO's instruction lines), compile CPU seconds (``--compiles`` alternating compiles each),
and the run: ``--rounds`` interleaved rounds of 5 calls each, medians of wall and CPU ms per call.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import time


def _cpu() -> float:
    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=40)
    parser.add_argument("--compiles", type=int, default=3)
    parser.add_argument("--json", default="benchmarks/results/wrap_pad.json")
    args = parser.parse_args(argv)
    t0 = time.time()

    import jax
    import numpy as np

    from benchmarks._common import load_frame, write_results
    from jaxdepth._src import normals, presets
    from jaxdepth._src import pixel_normals as pn
    from jaxdepth._src.xla_tuning import wrap_pad_slices

    sparse, K, T, _ = load_frame()
    forms = {"slices": wrap_pad_slices, "gather": normals.wrap_pad}
    raw = pn.pixel_normals.__wrapped__

    def compiled(form):
        normals.wrap_pad = forms[form]
        try:
            lowered = jax.jit(lambda d, k, t: raw(d, k, t, lidar=presets.KITTI_HDL64)).lower(sparse, K, T)
            c0 = _cpu()
            exe = lowered.compile()
            return exe, _cpu() - c0
        finally:
            normals.wrap_pad = forms["gather"]

    compile_s = {name: [] for name in forms}
    exes = {}
    for r in range(args.compiles):
        for name in (list(forms) if r % 2 == 0 else list(forms)[::-1]):
            exes[name], seconds = compiled(name)
            compile_s[name].append(seconds)
    outs = {name: np.asarray(exe(sparse, K, T)) for name, exe in exes.items()}
    same = outs["slices"].tobytes() == outs["gather"].tobytes()
    hlo = {name: exe.as_text() for name, exe in exes.items()}
    kernels = {name: sum(" fusion(" in line for line in text.splitlines()) for name, text in hlo.items()}
    run = {name: [] for name in forms}
    for r in range(args.rounds):
        for name in (list(forms) if r % 2 == 0 else list(forms)[::-1]):
            exe = exes[name]
            jax.block_until_ready(exe(sparse, K, T))
            w, c = time.perf_counter(), _cpu()
            for _ in range(5):
                jax.block_until_ready(exe(sparse, K, T))
            run[name].append(((time.perf_counter() - w) / 5 * 1e3, (_cpu() - c) / 5 * 1e3))
    doc = {"what": "pixel_normals on the shared KITTI frame, wrap padding as slices + concatenate (before) or one "
                   "static gather (now); one process, interleaved",
           "outputs_identical": same, "fusions": kernels,
           "compile_cpu_s": compile_s, "compile_cpu_s_median": {n: statistics.median(v) for n, v in compile_s.items()},
           "run_ms_median": {n: {"wall": statistics.median(x[0] for x in v), "cpu": statistics.median(x[1] for x in v)}
                             for n, v in run.items()},
           "cpu_ratio_per_round_median": statistics.median(g[1] / s[1] for g, s in zip(run["gather"], run["slices"])),
           "rounds": args.rounds, "load_average": os.getloadavg()}
    print({k: v for k, v in doc.items() if k != "compile_cpu_s"})
    write_results(args.json, doc, None, t0)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
