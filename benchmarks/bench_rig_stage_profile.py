"""Run time of each stage program of the rig pipelines, and of the projection's parts, in one process (ns/px).

The three stage programs of :func:`jaxdepth._src.sources.run_sources_stages` (Argoverse 2 sweep) or
:func:`jaxdepth._src.rig.run_rig_stages` (nuScenes sample): the projection, Step 2 (``keep``) and Steps
3-4 (``tail``), each compiled apart on its real input, and the whole one-program pipeline, as
``bench_stage_programs`` builds them. For the Argoverse 2 sweep also the projection's parts, each jitted
over the two size groups: the source normals (Step 1), the z-buffer alone, and the cameras' views (z-buffer
plus each pixel's point, normal and source) as the library forms them (``views``) and with the per-pixel
gather of before (``views_row_gather``: each pixel's (3,) row gathered, transposed, masked; the outputs
are compared byte for byte). ``--rounds`` interleaved rounds after a first call each (compile apart);
medians per variant in ns per real pixel (22.2 Mpx on Argoverse 2, 8.6 Mpx on nuScenes; wall, and process CPU
time: ``cpu_*``) and per-round
ratios to ``views_row_gather``; the projection stage and the one program also compiled with that gather of before
(``*_row_gather``, the same bytes checked). ``--baseline FILE``: Step 2 (``keep``) and the one program also
compiled with another ``outliers.py``'s ``_keep_mask`` (``*_baseline``; per-round ratios, the same bytes checked);
``--keep-only``: Step 2's stage program (and its baseline) alone. The process keeps freed memory as the ``jaxdepth`` command does
(``keep_freed_memory``), so no run pays page faults the job does not.

    python -m benchmarks.bench_rig_stage_profile [--cases av2 nuscenes] [--rounds 5] [--baseline FILE] [--keep-only]
        [--json benchmarks/results/rig_stage_profile.json]
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time

import numpy as np

from benchmarks._common import RESULTS, write_results


def _row_gather_view(points, valid, normals, per_source, K, T, size, *, height, width):
    """The cameras' view with the per-pixel gather of before (the baseline of ``views``)."""
    import jax.numpy as jnp

    from jaxdepth._src.geometry import camera_points, zbuffer_image
    from jaxdepth._src.rig import CameraView
    p_cam = camera_points(T, points)
    depth, index = zbuffer_image(p_cam, valid, K, height=height, width=width, valid_size=size)
    hit = index >= 0
    safe = jnp.where(hit, index, 0).reshape(-1)
    n_cam = camera_points(T, normals, translate=False)
    points_cam = jnp.where(hit[None], p_cam[safe].T.reshape(3, height, width), 0.0)
    normals_cam = jnp.where(hit[None], n_cam[safe].T.reshape(3, height, width), 0.0)
    source = jnp.repeat(jnp.arange(points.shape[0] // per_source, dtype=jnp.int32), per_source)
    return CameraView(depth, points_cam, normals_cam, jnp.where(hit, source[safe].reshape(height, width), -1))


def _projection_parts(sources, cameras, config) -> dict:
    """``{name: (jitted fn, args)}``: the Argoverse 2 projection's parts (see the module docs)."""
    import jax
    import jax.numpy as jnp

    from jaxdepth._src import rig as R
    from jaxdepth._src import sources as S
    from jaxdepth._src.geometry import camera_points, zbuffer_image
    p = sources.points.shape[1]
    normals_fn = jax.jit(lambda src: S.source_normals(src, smoothing=config.normal_smoothing,
                                                      fill_max_gap=config.range_fill_max_gap))
    points, valid = jnp.asarray(sources.points).reshape(-1, 3), jnp.asarray(sources.valid).reshape(-1)
    normals = normals_fn(sources).reshape(-1, 3)

    def grouped(view):
        def program(points, valid, normals, cams):
            return R.map_by_size(lambda K, T, size, image, *, height, width: view(
                points, valid, normals, p, K, T, size, height=height, width=width), cams)
        return jax.jit(program)

    def zbuffer(points, valid, normals, per_source, K, T, size, *, height, width):
        return zbuffer_image(camera_points(T, points), valid, K, height=height, width=width, valid_size=size)

    def library(points, valid, normals, per_source, K, T, size, *, height, width):
        return S._camera_view(points, valid, normals, per_source, None, K, T, height=height, width=width,
                              image_size=size)
    args = (points, valid, normals, cameras)
    return {"normals": (normals_fn, (sources,)), "zbuffer": (grouped(zbuffer), args),
            "views": (grouped(library), args), "views_row_gather": (grouped(_row_gather_view), args)}


def _row_gather_channels(values, index):
    """``pipeline.gather_channels`` as it was before: the (H W, C) row gather, transposed, masked."""
    import jax.numpy as jnp
    hit = index >= 0
    rows = values[jnp.where(hit, index, 0).reshape(-1)]
    return jnp.where(hit[None], rows.T.reshape(values.shape[1], *index.shape), 0.0)


def _compiled_with(fns: dict, names, suffix: str, swaps) -> dict:
    """``{name + suffix: (executable, args)}``: the programs ``names`` compiled with each ``(module, attribute,
    value)`` of ``swaps`` set (JAX's caches cleared around, so neither variant reuses the other's traces)."""
    import jax
    kept = [(m, a, getattr(m, a)) for m, a, _ in swaps]
    jax.clear_caches()
    for m, a, v in swaps:
        setattr(m, a, v)
    try:
        out = {f"{n}{suffix}": (fns[n][0].lower(*fns[n][1]).compile(), fns[n][1]) for n in names}
    finally:
        for m, a, v in kept:
            setattr(m, a, v)
        jax.clear_caches()
    return out


def _compiled_with_row_gather(fns: dict, names) -> dict:
    """The programs ``names`` compiled with ``pipeline.gather_channels`` swapped for the row gather of before."""
    from jaxdepth._src import pipeline
    return _compiled_with(fns, names, "_row_gather", [(pipeline, "gather_channels", _row_gather_channels)])


def _compiled_with_baseline(fns: dict, names, path: str) -> dict:
    """The programs ``names`` compiled with Step 2's ``_keep_mask`` from another ``outliers.py`` (``path``, e.g.
    main's), as ``sources`` and ``outliers`` call it (options it does not take are dropped; origins given as the
    sources' table and each pixel's source become the (3, H, W) maps of before)."""
    import importlib.util
    import inspect

    import jax.numpy as jnp

    from jaxdepth._src import outliers, sources
    spec = importlib.util.spec_from_file_location("outliers_baseline", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    takes = inspect.signature(module._keep_mask).parameters

    def keep_mask(*args, **options):
        if options.get("pixel_source") is not None and "pixel_source" not in takes:     # the (3, H, W) origin maps
            options["origins"] = jnp.moveaxis(options["origins"][options["pixel_source"]], -1, 0)
        return module._keep_mask(*args, **{k: v for k, v in options.items() if k in takes})
    return _compiled_with(fns, names, "_baseline", [(outliers, "_keep_mask", keep_mask),
                                                    (sources, "_keep_mask", keep_mask)])


def _programs(case: str, baseline=None, keep_only=False) -> tuple:
    """``({name: (jitted fn, args)}, real pixels)`` of a case (``baseline``: see :func:`_compiled_with_baseline`;
    ``keep_only``: Step 2's stage program alone)."""
    import jax

    from benchmarks.bench_stage_programs import _case_inputs
    stages, args, statics, one, one_args = _case_inputs(case)
    jitted = [jax.jit(functools.partial(stage, **extra)) for stage, extra in zip(stages, statics)]
    views = jitted[0](*args[0])
    keeps = jitted[1](*args[1](views))
    fns = {"projection": (jitted[0], args[0]), "keep": (jitted[1], args[1](views)),
           "tail": (jitted[2], args[2]((views, keeps))), "one_program": (one, one_args)}
    cameras = one_args[-1]
    pixels = float(sum(int(h) * int(w) for h, w in np.asarray(cameras.image_size)))
    if keep_only:
        fns = {"keep": fns["keep"]}
        fns.update(_compiled_with_baseline(fns, ("keep",), baseline) if baseline else {})
        return fns, pixels
    fns.update(_compiled_with_row_gather(fns, ("projection", "one_program")))
    if baseline:
        fns.update(_compiled_with_baseline(fns, ("keep", "one_program"), baseline))
    if case == "av2":
        fns.update({f"projection.{k}": v for k, v in _projection_parts(*one_args, statics[0]["config"]).items()})
    return fns, pixels


def _check_views(fns: dict) -> bool:
    return "projection.views" not in fns or _same(fns["projection.views"], fns["projection.views_row_gather"])


def _same(f, g) -> bool:
    """Whether two ``(fn, args)`` give the same bytes in every output leaf."""
    import jax
    a, b = (jax.device_get(fn(*args)) for fn, args in (f, g))
    return all(np.asarray(x).dtype == np.asarray(y).dtype and np.asarray(x).tobytes() == np.asarray(y).tobytes()
               for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


def run_case(case: str, rounds: int, baseline=None, keep_only=False) -> dict:
    import jax
    fns, pixels = _programs(case, baseline, keep_only)
    first = {}
    for name, (fn, args) in fns.items():
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        first[name] = time.perf_counter() - t
    runs, cpu = {name: [] for name in fns}, {name: [] for name in fns}
    for r in range(rounds):
        for name, (fn, args) in fns.items():
            t, c = time.perf_counter(), time.process_time()
            jax.block_until_ready(fn(*args))
            runs[name].append(time.perf_counter() - t)
            cpu[name].append(time.process_time() - c)
        print(case, r, {k: round(v[-1] * 1e9 / pixels, 1) for k, v in runs.items()}, flush=True)
    ns = {k: statistics.median(v) * 1e9 / pixels for k, v in runs.items()}
    out = {"pixels": pixels, "first_call_s": first, "runs_s": runs, "ns_per_px": ns, "cpu_runs_s": cpu,
           "cpu_ns_per_px": {k: statistics.median(v) * 1e9 / pixels for k, v in cpu.items()}}
    if not keep_only:
        out["views_identical_to_row_gather"] = _check_views(fns)
        out["one_program_identical_to_row_gather"] = _same(fns["one_program"], fns["one_program_row_gather"])
    for name in ("projection.views", "projection", "one_program"):
        if f"{name}_row_gather" in runs:
            base = runs[f"{name}_row_gather"]
            out[f"{name}_over_row_gather_per_round"] = [a / b for a, b in zip(runs[name], base)]
    if baseline:
        for name in [n for n in ("keep", "one_program") if n in fns]:
            out[f"{name}_over_baseline_per_round"] = [a / b for a, b in zip(runs[name], runs[f"{name}_baseline"])]
            out[f"{name}_over_baseline_cpu_per_round"] = [a / b for a, b in zip(cpu[name], cpu[f"{name}_baseline"])]
            out[f"{name}_identical_to_baseline"] = _same(fns[name], fns[f"{name}_baseline"])
        print(case, "keep / baseline", [round(x, 2) for x in out["keep_over_baseline_per_round"]], "CPU",
              [round(x, 2) for x in out["keep_over_baseline_cpu_per_round"]], "identical",
              out["keep_identical_to_baseline"], out.get("one_program_identical_to_baseline"))
    print(case, {k: round(v, 1) for k, v in ns.items()}, "identical", out.get("views_identical_to_row_gather"),
          out.get("one_program_identical_to_row_gather"))
    return out


def main(argv=None) -> int:
    import os
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["av2", "nuscenes"], choices=("av2", "nuscenes"))
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--json", default=str(RESULTS / "rig_stage_profile.json"))
    parser.add_argument("--baseline", default=None,
                        help="another outliers.py: Step 2 and the one program also compiled with its _keep_mask")
    parser.add_argument("--keep-only", action="store_true", help="time Step 2's stage program alone (less memory)")
    args = parser.parse_args(argv)
    from jaxdepth.batch.devices import keep_freed_memory
    keep_freed_memory()          # before JAX starts its threads, as the jaxdepth command
    t0 = time.time()
    cases = {case: run_case(case, args.rounds, args.baseline, args.keep_only) for case in args.cases}
    write_results(args.json, {"what": "rig pipelines: each stage program and the projection's parts, ns/px, one "
                                      "process", "load_average": os.getloadavg(), "baseline": args.baseline, "cases": cases}, None, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
