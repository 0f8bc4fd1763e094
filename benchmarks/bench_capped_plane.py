"""The capped plane's cost on the Argoverse 2 program (issue 38 x issue 37, branch capfast): in one process.

The Argoverse 2 sweep's depth program (``sources_depth_program``'s pipeline, what the Argoverse 2 job runs) and its
tail stage program (``sources_stage_tail``, Steps 3-4, ``depth`` alone), each compiled with
``SGMConfig(above_scan="plane")`` and ``"capped"``, for this library and for another checkout's (copied as
``jaxdepth_base``, as ``bench_rig_against_checkout``): eight programs, compiled with the options each library gives
its rig programs, outputs compared byte for byte (this against the checkout, mode by mode), then ``--rounds``
interleaved rounds (the order alternating), process CPU ns per real pixel. Ratios per round: capped / plane of each
library (what the cap costs) and this / checkout under capped (what the change gains).

    python -m benchmarks.bench_capped_plane --checkout /path/to/main [--rounds 7] [--json PATH]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import statistics
import tempfile
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from benchmarks.bench_rig_against_checkout import BASE, _copy_as_base, _program
from benchmarks.bench_rig_tail_split import interleaved_cpu

MODES = ("plane", "capped")


def _programs() -> dict:
    """``{library/program/mode: (compiled, args, real pixels)}`` (module docs)."""
    runs = {}
    for library, package in (("this", "jaxdepth"), ("base", BASE)):
        for mode in MODES:
            runs[f"{library}/program/{mode}"] = _program(package, "av2", True, above_scan=mode)
            runs[f"{library}/tail/{mode}"] = _program(package, "av2", True, stages=True, above_scan=mode)["tail"]
    return runs


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", type=pathlib.Path, required=True, help="a checkout of the baseline commit")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--json", default=str(RESULTS / "capped_plane.json"))
    args, t0 = parser.parse_args(argv), time.time()
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jaxdepth command (else page faults decide)
    with tempfile.TemporaryDirectory() as tmp:
        _copy_as_base(args.checkout.resolve(), pathlib.Path(tmp))
        runs = _programs()
    import jax
    differing = {}
    for name in runs:
        if name.startswith("this/"):
            other = "base/" + name.split("/", 1)[1]
            a, b = (np.asarray(jax.device_get(runs[k][0](*runs[k][1]))) for k in (name, other))
            differing[name.split("/", 1)[1]] = int(np.sum(a.view(np.uint32) != b.view(np.uint32)))
    print("depth values differing, this against the checkout:", differing, flush=True)
    load = [os.getloadavg()]
    cpu = interleaved_cpu(runs, args.rounds)
    load.append(os.getloadavg())
    ratios = {}
    for program in ("program", "tail"):
        for library in ("this", "base"):
            ratios[f"{library}/{program}/capped_over_plane"] = [
                c / p for c, p in zip(cpu[f"{library}/{program}/capped"], cpu[f"{library}/{program}/plane"])]
        ratios[f"{program}/capped/this_over_base"] = [
            t / b for t, b in zip(cpu[f"this/{program}/capped"], cpu[f"base/{program}/capped"])]
    summary = {k: statistics.median(v) for k, v in ratios.items()}
    median = {k: statistics.median(v) for k, v in cpu.items()}
    print("median CPU ns/px", {k: round(v, 2) for k, v in median.items()}, "\nratio medians",
          {k: round(v, 3) for k, v in summary.items()}, flush=True)
    doc = {"what": "the Argoverse 2 depth program and tail stage, above_scan plane / capped, this library and the "
                   "checkout's (module docs), process CPU ns per real pixel, interleaved rounds",
           "checkout": str(args.checkout), "load_average_before_after": load, "depth_values_differing": differing,
           "cpu_ns_px": cpu, "cpu_ns_px_median": median, "ratios_per_round": ratios, "ratio_medians": summary}
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
