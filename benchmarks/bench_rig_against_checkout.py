"""The rig programs of this library against another checkout's, in one process, interleaved rounds.

The Argoverse 2 sweep (``sources_program``'s pipeline, what the Argoverse 2 job runs) and the nuScenes sample
(``rig_program``'s; ``--depth-only``: a ``jit`` returning its ``depth`` alone, the nuScenes job's program),
inputs as ``bench_stage_programs`` builds them. The other checkout's ``jaxdepth`` package is copied into a
temporary folder as ``jaxdepth_base`` (its imports renamed), so that both libraries run in this process:
each program compiled apart, every output leaf compared byte for byte, then ``--rounds`` rounds timing
both (the order alternating), process CPU and wall ns per real pixel, per-round ratios this / base.
``--this-depth-only``: this library's program returns ``depth`` alone, the other's its ``Stages`` (the Argoverse 2
job's program before and after it ran a depth-only program, branch rigtail5); outputs compared on ``depth``.
``--stages``: the three stage programs (projection, Step 2, Steps 3-4) compiled and timed apart, each library's
on its own previous stages' outputs (with ``--depth-only`` the tail returns ``depth`` alone).
Each library's programs compile with the options that library gives its rig programs (``compiler_options`` of
its ``xla_tuning.entry_jit``, region-analysis copy insertion, since branch rigtail7; none before).

    python -m benchmarks.bench_rig_against_checkout --checkout /path/to/main [--cases av2 nuscenes]
        [--rounds 5] [--depth-only | --this-depth-only] [--stages] [--json benchmarks/results/rig_against_checkout.json]
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import pathlib
import re
import shutil
import statistics
import sys
import tempfile
import time

import numpy as np

from benchmarks._common import RESULTS, write_results

BASE = "jaxdepth_base"


def _copy_as_base(checkout: pathlib.Path, folder: pathlib.Path) -> None:
    """``checkout/jaxdepth`` as the package ``jaxdepth_base`` under ``folder`` (importable beside this one)."""
    target = folder / BASE
    shutil.copytree(checkout / "jaxdepth", target)
    for path in target.rglob("*.py"):
        path.write_text(re.sub(r"\bjaxdepth\b", BASE, path.read_text()))
    sys.path.insert(0, str(folder))


def case_run(package: str, case: str, above_scan=None):
    """``(run, args, real pixels)`` of ``case`` with the library ``package``: ``run(*args, call=...)`` runs the
    pipeline's three stage programs through ``call`` (``rig.call_stage``'s signature) and returns its ``Stages``.
    ``above_scan``: that ``SGMConfig.above_scan`` (None: the library's default)."""
    from benchmarks.bench_rigs import AV2_LOG, NUSCENES
    lib = importlib.import_module(package)
    R, S = (importlib.import_module(f"{package}._src.{m}") for m in ("rig", "sources"))
    config = lib.SGMConfig() if above_scan is None else lib.SGMConfig(above_scan=above_scan)
    if case == "av2":
        av2 = importlib.import_module(f"{package}.io.av2")
        jobs = importlib.import_module(f"{package}.batch.sources_job")
        log = av2.read_log(AV2_LOG)
        rig = av2.read_rig(log)
        sources, _ = jobs.cloud_sources(av2.read_cloud(log), fallback=rig.lidar)
        cameras = lib.stack_cameras([c.as_camera() for c in rig.cameras])
        beams = S.default_beams(sources)
        args = (sources, cameras)

        def run(src, cams, call=R.call_stage):
            return S.run_sources_stages(src, cams, config=config, free_space=True, beams=beams, call=call)
    else:
        io = importlib.import_module(f"{package}.io")
        rig = io.rig_from_nuscenes_calibration(NUSCENES / "calibration.json")
        points, valid = io.pad_points(io.read_points(next(NUSCENES.glob("*LIDAR_TOP*.pcd.bin")), columns=5)[0])
        cameras = lib.stack_cameras([c.as_camera() for c in rig.cameras])
        args = (points, valid, cameras)

        def run(p, v, cams, call=R.call_stage):
            return R.run_rig_stages(p, v, cams, config=config, lidar=rig.lidar, call=call)
    return run, args, float(sum(int(h) * int(w) for h, w in np.asarray(cameras.image_size)))


def _program(package: str, case: str, depth_only: bool, stages: bool = False, above_scan=None):
    """``(compiled program, args, real pixels)`` of ``case`` with the library ``package``; with ``stages``, a
    dict of them, one per stage program (``projection``, ``keep``, ``tail``; the tail's ``depth`` alone with
    ``depth_only``), each on the previous stages' outputs of the same library. ``above_scan``: as
    :func:`case_run`."""
    import jax

    run, args, pixels = case_run(package, case, above_scan)
    if stages:
        return _stage_programs(run, args, depth_only, pixels)
    S, R = (importlib.import_module(f"{package}._src.{m}") for m in ("sources", "rig"))
    fn = (lambda *a: run(*a).depth) if depth_only else run
    program = S.sources_depth_program if case == "av2" else R.rig_depth_program
    return jax.jit(fn).lower(*args).compile(_options(program)), args, pixels


def _options(program):
    """The compile options the library gives ``program`` (``xla_tuning.entry_jit``'s), None if it gives none."""
    return getattr(program, "compiler_options", None)


def record_stages(run, args) -> list:
    """``[(stage, stage_args, statics)]`` of the pipeline's three stage programs, as ``run`` (:func:`case_run`'s)
    called them (each on the previous ones' outputs)."""
    recorded = []

    def call(stage, *stage_args, **statics):
        recorded.append((stage, stage_args, statics))
        return stage(*stage_args, **statics)

    run(*args, call=call)
    return recorded


def _stage_programs(run, args, depth_only: bool, pixels: float) -> dict:
    """``{stage: (compiled, args, pixels)}``: the pipeline's three stage programs, each compiled apart on the
    inputs the previous ones gave (:func:`record_stages`)."""
    import jax
    out = {}
    for name, (stage, stage_args, statics) in zip(("projection", "keep", "tail"), record_stages(run, args)):
        fn = functools.partial(stage, **statics)
        if name == "tail" and depth_only:
            fn = (lambda f: lambda *a: f(*a).depth)(fn)
        out[name] = (jax.jit(fn).lower(*stage_args).compile(_options(stage)), stage_args, pixels)
    return out


def run_case(case: str, rounds: int, depth_only: bool, this_depth_only: bool = False, stages: bool = False) -> dict:
    if stages:
        base, this = _program(BASE, case, depth_only, stages=True), _program("jaxdepth", case, depth_only, stages=True)
        return {name: _timed(f"{case}/{name}", {"base": base[name], "this": this[name]}, rounds, depth_only)
                for name in this}
    programs = {"base": _program(BASE, case, depth_only),
                "this": _program("jaxdepth", case, depth_only or this_depth_only)}
    return _timed(case, programs, rounds, depth_only, this_depth_only)


def _timed(case: str, programs: dict, rounds: int, depth_only: bool, this_depth_only: bool = False) -> dict:
    """Outputs compared byte for byte, then ``rounds`` interleaved rounds of ``programs`` (base, this)."""
    import jax
    leaves = {k: jax.tree.leaves(jax.device_get(exe(*args))) for k, (exe, args, _) in programs.items()}
    if this_depth_only and not depth_only:
        leaves["base"] = [jax.device_get(programs["base"][0](*programs["base"][1])).depth]
    identical = all(np.asarray(a).tobytes() == np.asarray(b).tobytes() for a, b in zip(leaves["base"], leaves["this"]))
    del leaves
    pixels = programs["this"][2]
    cpu, wall = {k: [] for k in programs}, {k: [] for k in programs}
    for r in range(rounds):
        for name in (("base", "this") if r % 2 == 0 else ("this", "base")):
            exe, args, _ = programs[name]
            c, t = time.process_time(), time.perf_counter()
            jax.block_until_ready(exe(*args))
            cpu[name].append((time.process_time() - c) * 1e9 / pixels)
            wall[name].append((time.perf_counter() - t) * 1e9 / pixels)
        print(case, r, {k: round(v[-1], 1) for k, v in cpu.items()}, "CPU ns/px", os.getloadavg(), flush=True)
    ratios = [a / b for a, b in zip(cpu["this"], cpu["base"])]
    out = {"pixels": pixels, "depth_only": depth_only, "this_depth_only": this_depth_only, "identical": identical, "cpu_ns_px": cpu, "wall_ns_px": wall,
           "cpu_ns_px_median": {k: statistics.median(v) for k, v in cpu.items()},
           "wall_ns_px_median": {k: statistics.median(v) for k, v in wall.items()},
           "cpu_this_over_base_per_round": ratios, "cpu_this_over_base": statistics.median(ratios)}
    print(case, "identical", identical, "CPU this / base", round(out["cpu_this_over_base"], 3), flush=True)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", type=pathlib.Path, required=True, help="a checkout of the baseline commit")
    parser.add_argument("--cases", nargs="+", default=["av2", "nuscenes"], choices=("av2", "nuscenes"))
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--depth-only", action="store_true", help="programs returning depth alone (the nuScenes job's)")
    parser.add_argument("--this-depth-only", action="store_true",
                        help="this library's program returns depth alone, the other's its Stages (outputs: depth)")
    parser.add_argument("--stages", action="store_true",
                        help="time the three stage programs apart (each on its library's previous stages' outputs)")
    parser.add_argument("--json", default=str(RESULTS / "rig_against_checkout.json"))
    args = parser.parse_args(argv)
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jaxdepth command
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        _copy_as_base(args.checkout.resolve(), pathlib.Path(tmp))
        cases = {case: run_case(case, args.rounds, args.depth_only, args.this_depth_only, args.stages)
                 for case in args.cases}
    write_results(args.json, {"what": "rig programs, this library against another checkout's, one process, "
                                      "interleaved rounds, ns per real pixel", "checkout": str(args.checkout),
                              "load_average": os.getloadavg(), "cases": cases}, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
