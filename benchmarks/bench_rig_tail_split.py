"""The rig's Steps 3-4 per pixel against the single-camera tail: size, window form, ``vmap`` (issue 38 item 2).

One process (host memory kept, ``keep_freed_memory``, as the jobs), interleaved rounds, process CPU per pixel,
each program compiled with the library's compile options (``xla_tuning.COMPILER_OPTIONS``, as ``entry_jit``
gives the rig and single-frame programs), returning ``depth``:

- ``rig``: the Argoverse 2 sweep's tail stage program (``sources_stage_tail``, seven cameras, two size groups)
  on the stage inputs ``bench_stage_programs`` builds;
- ``one``: ``pipeline._complete_tail`` (the single-camera tail) on the first landscape camera's view and
  Step 2 mask (1550 x 2048), no window;
- ``one_window``: the same with the camera's ``image_size`` (the rig's window form: the bracket's gap, the
  blur's select padding);
- ``vmap6``: the window form under ``vmap`` over the six landscape cameras (the rig's size group);
- ``one_kitti_size``: ``one`` on a 352 x 1216 crop of that camera (rows 600-951);
- ``kitti``: the tail on the real KITTI frame (``benchmarks._common.FRAME``, camera 2; its view and
  Step 2 mask from ``complete_stages``).
- ``kitti_frame``: the whole KITTI frame (``complete_with(method="sgm")``, the first bar's program).

Outputs checked: ``one_window`` and ``vmap6``'s first camera against ``one`` (counted, not required: the
window form rounds the blur apart, docs/speed.md "The rig's tail, kernel by kernel"). With ``--profile``,
each program's largest kernels under ``jax.profiler`` (``bench_rig_tail_profile``'s sum; kernel times are
wall, and under load they overlap and stretch: read shares, not sums).

    python -m benchmarks.bench_rig_tail_split [--rounds 9] [--profile] [--json benchmarks/results/rig_tail_split.json]
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import time

import numpy as np

from benchmarks._common import RESULTS, load_frames, write_results


def av2_landscape_group() -> dict:
    """The Argoverse 2 sweep's stage inputs (``bench_stage_programs``) and its six 1550 x 2048 landscape cameras:
    ``stage``, ``statics``, ``tail_args`` (the tail stage program's inputs), ``config``, ``beams``, ``sizes`` (every
    camera's (h, w)), ``view`` and ``keep`` (the group's :class:`CameraView` and Step 2 mask), ``K``, ``T`` (6, ...)."""
    import jax
    import jax.numpy as jnp

    from benchmarks.bench_stage_programs import _case_inputs
    stages, args, statics, _, one_args = _case_inputs("av2")
    jitted = [jax.jit(functools.partial(s, **e)) for s, e in zip(stages, statics)]
    views = jitted[0](*args[0])
    keeps = jitted[1](*args[1](views))
    cameras = one_args[-1]
    sizes = np.asarray(cameras.image_size).tolist()
    group = next(g for g, v in enumerate(views) if v.sparse_depth.shape[-2:] == (1550, 2048))
    landscape = [i for i, s in enumerate(sizes) if s == [1550, 2048]]
    return dict(stage=stages[2], statics=statics[2], tail_args=args[2]((views, keeps)), config=statics[2]["config"],
                beams=statics[2]["beams"], sizes=sizes, view=views[group], keep=keeps[group],
                K=jnp.asarray(np.asarray(cameras.K)[landscape], jnp.float32),
                T=jnp.asarray(np.asarray(cameras.T_cam_lidar)[landscape], jnp.float32))


def _programs() -> dict:
    """``{name: (jitted function, args, real pixels)}`` (module docs)."""
    import jax
    import jax.numpy as jnp

    import jaxdepth
    from jaxdepth._src import presets
    from jaxdepth._src.methods import complete_with
    from jaxdepth._src.pipeline import _complete_tail, clear_outside_window
    g = av2_landscape_group()
    config, beams, sizes, view, keep, K, T = (g[k] for k in ("config", "beams", "sizes", "view", "keep", "K", "T"))

    def tail(sparse, normals, points, keep, K, T, size=None, *, beams=beams):
        out = _complete_tail(sparse, normals, points, K, T, beams=beams, config=config, keep=keep, image_size=size)
        return (out if size is None else clear_outside_window(out, size)).depth

    def first(tree, rows=slice(None), cols=slice(None)):
        return jax.tree.map(lambda a: a[0][..., rows, cols], tree)

    one = (view.sparse_depth, view.normals_cam, view.points_cam, keep)
    crop = dict(rows=slice(600, 952), cols=slice(0, 1216))
    sparse, _, K_kitti, T_kitti = load_frames()["image_02"]
    kitti = jaxdepth.complete_stages(jnp.asarray(sparse), jnp.asarray(K_kitti), jnp.asarray(T_kitti),
                                     config=config, lidar=presets.KITTI_HDL64)
    kitti_args = (kitti.sparse_depth, kitti.normals, None, kitti.inlier_mask, jnp.asarray(K_kitti, jnp.float32),
                  jnp.asarray(T_kitti, jnp.float32))
    size = jnp.asarray([1550, 2048], jnp.int32)
    return {
        "rig": (jax.jit(lambda *a: functools.partial(g["stage"], **g["statics"])(*a).depth), g["tail_args"],
                float(sum(h * w for h, w in sizes))),
        "one": (jax.jit(tail), (*first(one), K[0], T[0]), 1550 * 2048.0),
        "one_window": (jax.jit(tail), (*first(one), K[0], T[0], size), 1550 * 2048.0),
        "vmap6": (jax.jit(jax.vmap(tail, in_axes=(0,) * 6 + (None,))), (*one, K, T, size), 6 * 1550 * 2048.0),
        "one_kitti_size": (jax.jit(tail), (*first(one, **crop), K[0], T[0]), 352 * 1216.0),
        "kitti": (jax.jit(functools.partial(tail, beams=presets.KITTI_HDL64.beams)), kitti_args, 352 * 1216.0),
        "kitti_frame": (jax.jit(functools.partial(complete_with, method="sgm", config=config,
                                                  lidar=presets.KITTI_HDL64)),
                        (jnp.asarray(sparse), jnp.asarray(K_kitti), jnp.asarray(T_kitti)), 352 * 1216.0),
    }


def interleaved_cpu(runs: dict, rounds: int) -> dict:
    """``{name: [process CPU ns per real pixel, one a round]}`` of ``runs`` (``{name: (executable, args, pixels)}``),
    ``rounds`` interleaved rounds, the order alternating."""
    import jax
    cpu = {name: [] for name in runs}
    for r in range(rounds):
        for name in (list(runs) if r % 2 == 0 else list(runs)[::-1]):
            exe, a, px = runs[name]
            c = time.process_time()
            jax.block_until_ready(exe(*a))
            cpu[name].append((time.process_time() - c) * 1e9 / px)
        print(r, {k: round(v[-1], 2) for k, v in cpu.items()}, "CPU ns/px, load", os.getloadavg(), flush=True)
    return cpu


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=9)
    parser.add_argument("--profile", action="store_true", help="also each program's largest kernels")
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--json", default=str(RESULTS / "rig_tail_split.json"))
    args, t0 = parser.parse_args(argv), time.time()
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jaxdepth command (else page faults decide)

    from jaxdepth._src.xla_tuning import COMPILER_OPTIONS
    exes = {name: (fn.lower(*a).compile(COMPILER_OPTIONS), a, px) for name, (fn, a, px) in _programs().items()}
    ref = np.asarray(exes["one"][0](*exes["one"][1]))
    differ = {"one_window": int(np.sum(np.asarray(exes["one_window"][0](*exes["one_window"][1])) != ref)),
              "vmap6_first": int(np.sum(np.asarray(exes["vmap6"][0](*exes["vmap6"][1]))[0] != ref))}
    print("depth values differing from one:", differ, flush=True)
    cpu = interleaved_cpu(exes, args.rounds)
    median = {k: statistics.median(v) for k, v in cpu.items()}
    ratio = {k: statistics.median([a / b for a, b in zip(v, cpu["one"])]) for k, v in cpu.items()}
    print("median CPU ns/px", {k: round(v, 2) for k, v in median.items()}, "per-round ratio to one",
          {k: round(v, 3) for k, v in ratio.items()}, flush=True)
    doc = {"what": "rig tail per pixel against the single-camera tail (module docs), process CPU ns per real pixel, "
                   "interleaved rounds", "load_average": os.getloadavg(), "cpu_ns_px": cpu, "cpu_ns_px_median": median,
           "cpu_over_one_per_round_median": ratio, "cpu_ns_px_min": {k: min(v) for k, v in cpu.items()},
           "depth_values_differing_from_one": differ}
    if args.profile:
        from benchmarks.bench_rig_tail_profile import _kernels
        doc["kernels"] = {name: _kernels(exe, a, px, args.top) for name, (exe, a, px) in exes.items()}
    write_results(args.json, doc, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
