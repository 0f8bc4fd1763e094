"""The rig subcommands of ``jaxdepth``: ``complete-rig`` (one sweep, or many in one process) and ``warmup``.

Parsing, messages and exit codes only; the jobs are :func:`jaxdepth.batch.rig_job.run_rig_job` (one
sweep), :func:`jaxdepth.batch.rig_sweeps.run_rig_sweeps` (a folder, glob or list of sweeps,
:mod:`jaxdepth.io.sweep_list`), :func:`jaxdepth.batch.rig_sweeps.warm_rig` and
:func:`jaxdepth.batch.av2_job.warm_av2` (``warmup --av2``).
"""

from __future__ import annotations

import sys

from jaxdepth.batch import devices
from jaxdepth.cli_common import (add_method_options, add_overwrite_and_force_options, config_from, extras_from,
                                 extras_usage, guidance_usage, progress, settle_rig_baseline_removal)


def _reporter(args):
    def report(kind: str, text: str) -> None:
        if kind == "warning":
            print(f"warning: {text}", file=sys.stderr)
        elif kind == "skipped":
            print(text, file=sys.stderr)
        elif kind == "note" and not args.quiet:
            print(f"sweep: {text}", file=sys.stderr)
        elif kind == "written" and not args.quiet:
            print(text)
    return report


def cmd_complete_rig(args) -> int:
    from jaxdepth.batch import run_record
    from jaxdepth.batch.rig_job import run_rig_job
    from jaxdepth.io.sweep_list import list_sweeps

    usage = extras_usage(args) or guidance_usage(args) or settle_rig_baseline_removal(args)
    if usage:
        print(f"jaxdepth: error: {usage}", file=sys.stderr)
        return 2
    sweeps = list_sweeps(args.points)
    if sweeps is not None and args.guidance_weight > 0:
        print("jaxdepth: error: --guidance-weight takes one sweep per call (the camera images belong to one sweep)",
              file=sys.stderr)
        return 2
    # above_scan: the jobs read the rig JSON (once) and record the rule its sweeps resolve (run_record.rig_above_scan)
    settings = run_record.settings_of(config_from(args), method=args.method, extras=extras_from(args),
                                      estimate=not args.no_estimate)
    record = run_record.make_record(settings, inputs=[args.points, args.rig],
                                    command=getattr(args, "command_line", None))
    if sweeps is not None:
        return _complete_rig_sweeps(args, sweeps, record)
    job_progress = progress(args, 1, "sweeps", label="complete-rig")
    try:
        summary = run_rig_job(args.points, args.rig, args.out_dir, config=config_from(args),
                              extras=extras_from(args), point_columns=args.point_columns,
                              estimate=not args.no_estimate, image_dir=args.image_dir, overwrite=args.overwrite,
                              report=_reporter(args), force=args.force, record=record, method=args.method)
    finally:
        job_progress.close()
    return summary.exit_code


def _complete_rig_sweeps(args, sweeps, record) -> int:
    """``complete-rig`` over several sweeps: exit 0, or 1 when a sweep failed (each one listed)."""
    from jaxdepth.batch.rig_sweeps import run_rig_sweeps
    from jaxdepth.progress import report_summary

    job_progress = progress(args, len(sweeps), "sweeps", label="complete-rig")
    try:
        summary = run_rig_sweeps(sweeps, args.rig, args.out_dir, config=config_from(args), extras=extras_from(args),
                                 point_columns=args.point_columns, estimate=not args.no_estimate,
                                 overwrite=args.overwrite, report=_reporter(args), force=args.force, record=record,
                                 io_threads=devices.io_threads(), on_progress=job_progress.update,
                                 method=args.method)
    finally:
        job_progress.close()
    return report_summary(summary, quiet=args.quiet, t_start=getattr(args, "t_start", None), unit="sweeps")


def cmd_warmup(args) -> int:
    from jaxdepth.batch.rig_sweeps import warm_rig

    usage = extras_usage(args) or _warmup_usage(args)
    if usage:
        print(f"jaxdepth: error: {usage}", file=sys.stderr)
        return 2
    folder = devices.compile_cache_folder()
    if folder is None:
        print("warning: the compile cache is off (--no-compile-cache or JAXDEPTH_COMPILE_CACHE=0): nothing is "
              "kept for later runs", file=sys.stderr)
    if args.av2 is not None:
        from jaxdepth.batch.av2_job import warm_av2
        cameras = None if args.cameras is None else tuple(c.strip() for c in args.cameras.split(",") if c.strip())
        done = [warm_av2(args.av2, sweeps=args.sweeps, cameras=cameras, config=config_from(args),
                         time="lidar" if args.lidar_time else "camera", extras=extras_from(args))]
        what = args.av2
    else:
        done = warm_rig(args.rig, config=config_from(args), extras=extras_from(args), points=args.points,
                        sample=args.sample, estimate=not args.no_estimate, report=_reporter(args))
        what = args.rig
    if not args.quiet:
        for label, seconds in done:
            print(f"{what}: compiled for {label} in {seconds:.1f} s" + (f" -> {folder}" if folder else ""))
    return 0


def _warmup_usage(args) -> str | None:
    if (args.rig is None) == (args.av2 is None):
        return "warmup takes a rig JSON or --av2 LOG (one of them)"
    if args.av2 is not None and (args.points or args.sample or args.no_estimate):
        return "--av2 takes no --points, --sample or --no-estimate (it warms up on the log's own sweep)"
    if args.av2 is None and (args.cameras or args.lidar_time or args.sweeps):
        return "--cameras, --lidar-time and --sweeps go with --av2"
    if args.sweeps < 0:
        return f"--sweeps expected an integer >= 0 (neighbours on each side), got {args.sweeps}"
    return None


def _add_sweep_options(p, *, methods=("sgm",)) -> None:
    """The options ``complete-rig`` and ``warmup`` share (each is part of the compiled program); ``warmup``
    compiles the SGM's program only."""
    add_method_options(p, methods=methods)
    p.add_argument("-q", "--quiet", action="store_true")
    from jaxdepth.batch import extras as extras_cli
    extras_cli.add_cli_options(p)


def register(sub) -> None:
    """Adds ``complete-rig`` and ``warmup`` to the ``jaxdepth`` subparsers ``sub``."""
    p = sub.add_parser("complete-rig", help="complete LiDAR sweeps for every camera of a rig JSON")
    p.add_argument("points", metavar="SWEEP",
                   help="sweep: .bin float32 records (x, y, z, intensity[, ring]) or .npy/.npz, or a sweeps JSON "
                        "{\"sweeps\": [{\"file\", \"T_ref_sweep\"}]} (see docs/multi_source.md): writes "
                        "OUT/<camera>.png. Several sweeps in one process: a folder (its .bin/.npy/.npz files), a "
                        "quoted glob ('logs/*.bin'), or a list file (@list.txt or *.txt, one path per line): "
                        "writes OUT/<sweep stem>/<camera>.png (stems must differ)")
    p.add_argument("rig", help="rig JSON (see docs/rig_json.md: lidar beams, cameras with K and T_cam_lidar)")
    p.add_argument("out_dir", metavar="OUT", help="output folder: <camera name>.png per camera (uint16, depth*256)")
    p.add_argument("--point-columns", type=int, default=None,
                   help="float32 values per .bin record (default: 5 for *.pcd.bin, else the one of 4 or 5 that "
                        "the file size fits; a size that fits both must be given)")
    p.add_argument("--no-estimate", action="store_true",
                   help="do not check the sweep against its LiDAR (see docs/rig_json.md: lidar.origin_m)")
    p.add_argument("--image-dir", default=None, metavar="DIR",
                   help="with --guidance-weight: the camera images, DIR/<camera name>.png, .jpg or .jpeg (8-bit grey "
                        "or colour, each the camera's width x height; all grey or all colour); default: each "
                        "camera's \"image\" field in the rig JSON (relative to the JSON's folder)")
    add_overwrite_and_force_options(p)
    _add_sweep_options(p, methods=("sgm", "nearest", "ip-basic"))
    p.set_defaults(func=cmd_complete_rig)

    w = sub.add_parser("warmup", help="compile a rig's complete-rig program (or an Argoverse 2 job's) into the "
                                      "on-disk cache, writing nothing",
                       description="Compiles the program complete-rig runs for RIG with the same options (on an empty "
                                   "sweep, or on --sample SWEEP), or the one 'jaxdepth complete LOG' runs for "
                                   "Argoverse 2 (--av2 LOG: on the log's middle sweep), into the persistent compile "
                                   "cache (~/.cache/jaxdepth/xla), so that a later run's first sweep loads it "
                                   "instead of compiling (cluster jobs: warm the shared cache once before the "
                                   "workers start; see docs/speed.md).")
    w.add_argument("rig", nargs="?", default=None, help="rig JSON (see docs/rig_json.md)")
    w.add_argument("--points", type=int, action="append", default=None, metavar="N",
                   help="points per sweep (per LiDAR with lidars) of the sweeps to come (repeat for several sizes; "
                        "one program per power-of-two bucket); default: the LiDAR's beams x columns")
    w.add_argument("--sample", default=None, metavar="SWEEP",
                   help="warm up on this sweep (file or sweeps JSON), read and checked as complete-rig would: "
                        "needed when the rig's LiDARs are estimated from each sweep (lidars without beams, "
                        "with a ring column)")
    w.add_argument("--no-estimate", action="store_true", help="with --sample: as complete-rig's --no-estimate")
    w.add_argument("--av2", default=None, metavar="LOG",
                   help="warm up the Argoverse 2 job (jaxdepth complete LOG DST) instead: a log, split or root")
    w.add_argument("--sweeps", type=int, default=0, metavar="N", help="with --av2: as complete's --sweeps")
    w.add_argument("--cameras", default=None, metavar="NAMES", help="with --av2: as complete's --cameras")
    w.add_argument("--lidar-time", action="store_true", help="with --av2: as complete's --lidar-time")
    _add_sweep_options(w)
    w.set_defaults(func=cmd_warmup)


__all__ = ["register", "cmd_complete_rig", "cmd_warmup"]
