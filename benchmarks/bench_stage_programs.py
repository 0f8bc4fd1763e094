"""Compile and run time of the rig pipelines as three stage programs against one program, in one process.

``complete_sources_stages`` / ``complete_rig_stages`` run three jitted stage programs one after another
(projection, Step 2, Steps 3-4: :func:`jaxdepth._src.sources.run_sources_stages`); the *one program*
is the same stages traced into one ``jit`` (XLA then fuses across the stage boundaries), which is what
the library compiled before the split. For each case, ``--rounds`` rounds alternate the two variants:
each round clears JAX's in-memory caches (no persistent cache in this process) and measures each
variant's lowering and XLA compile (``.lower(...).compile()``: wall seconds and the process's CPU
seconds, every thread), then ``--repeats`` interleaved runs of the compiled executables
(``block_until_ready``; medians, ratio split / one per run). Every output field is compared byte for
byte between the variants.

Cases: ``av2`` (the shared Argoverse 2 sweep: two VLP-32C as two sources, 7 ring cameras in two size
groups, as ``bench_rigs``), ``nuscenes`` (the shared nuScenes sample through the rig program: one
HDL-32E, 6 cameras).

    python -m benchmarks.bench_stage_programs [--cases av2 nuscenes] [--rounds 2] [--repeats 3]
        [--json benchmarks/results/stage_programs.json]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from benchmarks._common import RESULTS, write_results


def _clock():
    return time.perf_counter(), time.process_time()


def _compiled(fn, args: tuple) -> tuple:
    """``(executable, {"lower_wall_s", "lower_cpu_s", "compile_wall_s", "compile_cpu_s"})`` of ``jit`` fn."""
    w0, c0 = _clock()
    lowered = fn.lower(*args)
    w1, c1 = _clock()
    exe = lowered.compile()
    w2, c2 = _clock()
    return exe, {"lower_wall_s": w1 - w0, "lower_cpu_s": c1 - c0, "compile_wall_s": w2 - w1, "compile_cpu_s": c2 - c1}


def _split(stages, args: tuple, statics: list) -> tuple:
    """The three stage programs compiled on the real intermediate inputs: ``(run, costs per stage)``."""
    import functools

    import jax
    exes, costs, inputs = [], {}, None
    for k, (stage, extra) in enumerate(zip(stages, statics)):
        fn = jax.jit(functools.partial(stage, **extra))
        call_args = args[0] if k == 0 else args[k](inputs)
        exe, costs[stage.__name__] = _compiled(fn, call_args)
        out = exe(*call_args)
        inputs = out if k == 0 else (inputs, out)
        exes.append(exe)

    def run():
        views = exes[0](*args[0])
        keeps = exes[1](*args[1](views))
        return exes[2](*args[2]((views, keeps)))
    return run, costs


def _case_inputs(case: str):
    """``(stages, args, statics, one_program_fn, one_args)`` of a case (see the module docs)."""
    import jax

    import jaxdepth
    from jaxdepth._src import rig as R
    from jaxdepth._src import sources as S
    config = jaxdepth.SGMConfig()
    if case == "av2":
        from benchmarks.bench_rigs import AV2_LOG
        from jaxdepth.batch.sources_job import cloud_sources
        from jaxdepth.io import av2
        log = av2.read_log(AV2_LOG)
        rig = av2.read_rig(log)
        sources, _ = cloud_sources(av2.read_cloud(log), fallback=rig.lidar)
        cameras = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras])
        beams = S.default_beams(sources)
        stages = (S.sources_stage_projection, S.sources_stage_keep, S.sources_stage_tail)
        statics = [dict(config=config, free_space=True, occlusion=True), dict(config=config, beams=beams),
                   dict(config=config, beams=beams)]
        args = ((sources, cameras), lambda views: (views, sources, cameras), lambda vk: (vk[0], vk[1], cameras, None))
        one = jax.jit(lambda src, cams: S.run_sources_stages(src, cams, config=config, free_space=True, beams=beams))
        return stages, args, statics, one, (sources, cameras)
    from benchmarks.bench_rigs import NUSCENES
    from jaxdepth.io import pad_points, read_points, rig_from_nuscenes_calibration
    rig = rig_from_nuscenes_calibration(NUSCENES / "calibration.json")
    points, valid = pad_points(read_points(next(NUSCENES.glob("*LIDAR_TOP*.pcd.bin")), columns=5)[0])
    cameras, lidar = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras]), rig.lidar
    stages = (R.rig_stage_projection, R.rig_stage_keep, R.rig_stage_tail)
    statics = [dict(config=config, lidar=lidar), dict(config=config, beams=lidar.beams),
               dict(config=config, beams=lidar.beams)]
    args = ((points, valid, cameras), lambda views: (views, cameras), lambda vk: (vk[0], vk[1], cameras, None))
    one = jax.jit(lambda p, v, c: R.run_rig_stages(p, v, c, config=config, lidar=lidar))
    return stages, args, statics, one, (points, valid, cameras)


def _timed(fn) -> float:
    import jax
    t = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t


def run_case(case: str, rounds: int, repeats: int) -> dict:
    import jax
    stages, args, statics, one, one_args = _case_inputs(case)
    out = {"rounds": []}
    for r in range(rounds):
        jax.clear_caches()
        order = ("one", "split") if r % 2 == 0 else ("split", "one")
        got = {}
        for variant in order:
            if variant == "one":
                exe, cost = _compiled(one, one_args)
                got["one"] = (lambda exe=exe: exe(*one_args), {"one_program": cost})
            else:
                got["split"] = _split(stages, args, statics)
        a, b = jax.device_get(got["one"][0]()), jax.device_get(got["split"][0]())
        same = {name: np.asarray(getattr(a, name)).tobytes() == np.asarray(getattr(b, name)).tobytes()
                for name in a._fields}
        runs = {"one": [], "split": []}
        for _ in range(repeats):
            for variant in order:
                runs[variant].append(_timed(got[variant][0]))
        split_cpu = sum(c["compile_cpu_s"] for c in got["split"][1].values())
        row = {"order": order, "compile": {**got["one"][1], **got["split"][1]},
               "compile_cpu_s": {"one": got["one"][1]["one_program"]["compile_cpu_s"], "split": split_cpu},
               "run_s": runs, "run_ratio_split_to_one": statistics.median(s / o for s, o in zip(runs["split"],
                                                                                                 runs["one"])),
               "bytes_identical": same}
        print(case, r, {k: round(v, 2) for k, v in row["compile_cpu_s"].items()},
              {k: round(v["compile_cpu_s"], 2) for k, v in row["compile"].items()},
              "run ratio", round(row["run_ratio_split_to_one"], 3), "identical", all(same.values()), flush=True)
        out["rounds"].append(row)
    return out


def main(argv=None) -> int:
    import os
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["av2", "nuscenes"], choices=("av2", "nuscenes"))
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", default=str(RESULTS / "stage_programs.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    cases = {case: run_case(case, args.rounds, args.repeats) for case in args.cases}
    write_results(args.json, {"what": "rig pipelines: three stage programs against one program, one process",
                              "load_average": os.getloadavg(), "cases": cases}, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
