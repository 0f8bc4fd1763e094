"""Command line: a thin layer of argument parsing, exit codes and progress over the library.

Exit codes: 0 success, 1 data error (one-line message) or failed items, 2 usage error, 130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import argparse
import logging
import pathlib
import sys
import time

from jaxdepth import __version__, interrupts
from jaxdepth.batch import devices
from jaxdepth.cli_common import (add_force_option as _add_force_option,
                                  add_method_options as _add_method_options,
                                  add_overwrite_and_force_options as _add_overwrite_and_force_options,
                                  config_from as _config_from, extras_from as _extras_from,
                                  extras_usage as _extras_usage, guidance_usage as _guidance_usage,
                                  progress as _progress, settle_rig_baseline_removal as _settle_rig_baseline_removal)
from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION
from jaxdepth.io.errors import JaxdepthError

log = logging.getLogger("jaxdepth")


def cmd_demo(args) -> int:
    from jaxdepth import demo
    result = demo.run_demo(pathlib.Path(args.out), seed=args.seed, method=args.method, config=_config_from(args))
    for line in result.report_lines():
        print(line)
    return 0


_PNG_COMPRESSION_DEFAULT = DEFAULT_PNG_COMPRESSION


def cmd_complete(args) -> int:
    from jaxdepth.batch import runner
    from jaxdepth.io.calib import read_intrinsics_txt
    from jaxdepth.io.errors import InputError
    from jaxdepth.io.kitti_layout import list_depth_completion_folder

    from jaxdepth.io.calib import read_extrinsic_txt
    from jaxdepth.io.kitti_layout import KittiExtrinsics

    usage = _extras_usage(args)
    if usage:
        print(f"jaxdepth: error: {usage}", file=sys.stderr)
        return 2
    if (code := _complete_own_job(args)) is not None:  # nuScenes, Argoverse 2, KITTI raw --sweeps
        return code
    usage = _guidance_usage(args)
    if usage:
        print(f"jaxdepth: error: {usage}", file=sys.stderr)
        return 2
    guided = args.guidance_weight > 0
    src, dst = pathlib.Path(args.src), pathlib.Path(args.dst)
    scan = _discover_dataset(src, dst, args)
    if scan is not None and guided and scan.layout == "kitti-depth-tree" and args.image_dir is None:
        raise InputError(f"{src}: a KITTI depth-completion train/val tree holds no camera images; for "
                         "--guidance-weight pass --image-dir with the KITTI raw root "
                         "(DIR/<date>/<drive>/image_0X/data/<frame>.png)")
    pre_failed = [] if scan is None else scan.failed
    if scan is None and getattr(args, "crop", False):
        raise InputError(f"{src}: --crop needs a KITTI raw or object folder (LiDAR sweeps)")
    if args.extrinsic is not None and (args.camera is not None or args.calib_dir is not None):
        raise InputError("--extrinsic gives the extrinsic itself: use it without --camera / --calib-dir")
    if scan is not None:
        jobs = [runner.FrameJob.from_files(frame) for frame in scan.jobs]
    elif args.extrinsic is not None:
        T_fixed = read_extrinsic_txt(args.extrinsic)
        extrinsic_of = lambda path: T_fixed  # noqa: E731
    else:
        extrinsic_of = KittiExtrinsics(args.calib_dir, camera=args.camera)
    if scan is not None:
        _claim_output_folder(dst, args, inputs=[src], out_paths=[job.out_path for job in jobs], crop=args.crop,
                             camera=args.camera, outputs=_job_identities(jobs, args))
        from jaxdepth.io.atomic import make_output_folders
        make_output_folders(job.out_path for job in jobs)
    elif src.is_file() or src.suffix.lower() == ".png":
        if not src.exists():
            raise InputError(f"{src}: input file not found")
        if args.intrinsics is None:
            raise InputError(f"{src}: a single image needs --intrinsics K.txt (9 numbers, row-major K)")
        image_of = _image_finder(src, args)
        from jaxdepth.io.atomic import ensure_output_dir
        ensure_output_dir(dst.parent)  # before the computation, not at its first write
        jobs = [runner.FrameJob(name=src.name, sparse_path=src, out_path=dst,
                                K=read_intrinsics_txt(args.intrinsics), T_cam_lidar=extrinsic_of(src),
                                image_path=image_of(src))]
        from jaxdepth.batch.run_record import claim_output_file  # its record beside it: out.jaxdepth_run.json
        claim_output_file(dst, _run_record(args, [src], camera=args.camera), _job_identities(jobs, args)[dst],
                          overwrite=args.overwrite)
    else:
        K_override = read_intrinsics_txt(args.intrinsics) if args.intrinsics else None
        frames = list_depth_completion_folder(src)
        image_of = _image_finder(src, args)
        jobs = [runner.FrameJob(name=name, sparse_path=png, out_path=dst / png.name,
                                intrinsics_path=k_path, K=K_override, T_cam_lidar=extrinsic_of(png),
                                image_path=image_of(png))
                for name, png, k_path in frames]
        _claim_output_folder(dst, args, inputs=[src], camera=args.camera, outputs=_job_identities(jobs, args),
                             intrinsics=None if args.intrinsics is None else str(args.intrinsics),
                             extrinsic=None if args.extrinsic is None else str(args.extrinsic))
    return _run_frame_jobs(_forced_jobs(jobs, args), pre_failed, args)


def _run_frame_jobs(jobs, pre_failed, args) -> int:
    """Runs ``complete``'s frame jobs on the local or Ray engine with progress; the exit code."""
    from jaxdepth.batch import runner
    if args.engine == "local" and len(jobs) > 1 and args.cpu_devices != 1:
        devices.split_cpu_into_devices(None if args.cpu_devices == 0 else args.cpu_devices)
    if args.engine == "ray" and args.png_compression != _PNG_COMPRESSION_DEFAULT:
        print("jaxdepth: error: --png-compression is only supported with --engine local", file=sys.stderr)
        return 2
    unit = "sweeps" if jobs and jobs[0].image_size is not None else "images"
    progress = _progress(args, len(jobs) + len(pre_failed), unit)
    for name, message in pre_failed:
        progress.update(name, f"failed: {message}")
    if args.engine == "ray":
        from jaxdepth.batch import scale
        summary = scale.run_jobs_ray(jobs, method=args.method, config=_config_from(args),
                                     batch_size=args.batch_size, overwrite=args.overwrite,
                                     address=args.ray_address, on_progress=progress.update,
                                     extras=_extras_from(args))
    else:
        summary = runner.run_jobs(jobs, method=args.method, config=_config_from(args), batch_size=args.batch_size,
                                  overwrite=args.overwrite, png_compression=args.png_compression,
                                  io_threads=devices.io_threads(), on_progress=progress.update,
                                  extras=_extras_from(args))
    progress.close()
    summary.failed[:0] = pre_failed
    return _report(summary, args.quiet, t_start=getattr(args, "t_start", None), unit=unit)


def _complete_own_job(args) -> int | None:
    """Runs ``complete`` on a layout with its own job (a nuScenes dataroot with --nusc-version, an Argoverse 2
    log or folder of logs, KITTI raw drives with --sweeps N > 0) and returns the exit code; None for the
    other layouts."""
    if getattr(args, "nusc_version", None) is not None:
        return _cmd_complete_nuscenes(args)
    from jaxdepth.batch.av2_job import is_av2_root
    if is_av2_root(args.src):
        return _cmd_complete_av2(args)
    for flag, value in (("--cameras", args.cameras), ("--lidar-time", args.lidar_time or None)):
        if value is not None:
            print(f"jaxdepth: error: {flag} applies to Argoverse 2 logs", file=sys.stderr)
            return 2
    if args.sweeps:
        src = pathlib.Path(args.src)
        return _cmd_complete_kitti_sweeps(args, _discover_dataset(src, pathlib.Path(args.dst), args))
    return None


def _multi_source_usage(args, what: str) -> str | None:
    """Why the options given cannot be used with a multi-source job (None: they can)."""
    if args.guidance_weight > 0:
        return f"{what}: --guidance-weight is not supported (no camera images are read)"
    extras = _extras_from(args)
    if extras.kinds or extras.needs_seeds:
        return f"{what}: the extra outputs (--preview, --validity, ...) are not supported"
    if args.engine != "local":
        return f"{what}: --engine local only"
    return None


def _job_devices(args) -> int:
    """The devices of a rig job (nuScenes, Argoverse 2): ``--cpu-devices N`` > 1 on the local engine splits the
    CPU into N host devices (before JAX starts) and the job deals whole samples / sweeps to them round robin,
    N programs at once; the default (0) and 1 keep one device, which spreads a sample over the cores."""
    if args.engine != "local" or args.cpu_devices <= 1:
        return 1
    devices.split_cpu_into_devices(args.cpu_devices)   # the job uses the devices there are, at most N
    return args.cpu_devices


def _cmd_complete_av2(args) -> int:
    """``jaxdepth complete ROOT DST``: Argoverse 2 logs (exit 0 ok, 1 failed, 2 usage)."""
    from jaxdepth.batch import run_record
    from jaxdepth.batch.av2_job import cli_usage, find_logs, run_av2

    usage = cli_usage(args) or _settle_rig_baseline_removal(args)
    if usage:
        print(f"jaxdepth: error: {usage}", file=sys.stderr)
        return 2
    dst = pathlib.Path(args.dst)
    cameras = None if args.cameras is None else tuple(c.strip() for c in args.cameras.split(",") if c.strip())
    time_ = "lidar" if args.lidar_time else "camera"
    _claim_output_folder(dst, args, inputs=[args.src], sweeps=args.sweeps or 0, time=time_,
                         cameras=None if cameras is None else ",".join(cameras),
                         above_scan=run_record.lidars_above_scan(_config_from(args).above_scan, lidars=2))
    sweep_devices = _job_devices(args)
    total = sum(len(list((log / "sensors" / "lidar").glob("*.feather"))) for log in find_logs(args.src))
    progress = _progress(args, total, "sweeps")
    summary = run_av2(args.src, dst, sweeps=args.sweeps or 0, cameras=cameras, config=_config_from(args),
                      overwrite=args.overwrite, png_compression=args.png_compression,
                      io_threads=devices.io_threads(), on_progress=progress.update, force=args.force,
                      time=time_, method=args.method, extras=_extras_from(args),
                      on_note=lambda text: print(f"jaxdepth: note: {text}", file=sys.stderr), devices=sweep_devices)
    progress.close()
    return _report(summary, args.quiet, t_start=getattr(args, "t_start", None), unit="sweeps")


def _cmd_complete_kitti_sweeps(args, scan) -> int:
    """``jaxdepth complete KITTI_RAW DST --sweeps N`` (N > 0): each sweep with N neighbours on each side."""
    from jaxdepth.batch.kitti_sweeps_job import run_kitti_raw_sweeps
    from jaxdepth.io.errors import InputError

    if scan is None or scan.layout != "kitti-raw":
        raise InputError(f"{args.src}: --sweeps applies to KITTI raw drives, Argoverse 2 logs and nuScenes "
                         "(--nusc-version)")
    usage = _multi_source_usage(args, "--sweeps") or _settle_rig_baseline_removal(args)
    if usage is None and args.sweeps < 0:
        usage = f"--sweeps expected an integer >= 0 (neighbours on each side), got {args.sweeps}"
    if usage:
        print(f"jaxdepth: error: {usage}", file=sys.stderr)
        return 2
    from jaxdepth.batch.kitti_sweeps_job import sweep_identities
    _claim_output_folder(pathlib.Path(args.dst), args, inputs=[args.src],
                         out_paths=[job.out_path for job in scan.jobs], crop=args.crop, camera=args.camera,
                         sweeps=args.sweeps, outputs=sweep_identities(scan.jobs, sweeps=args.sweeps))
    progress = _progress(args, len({job.sparse_path for job in scan.jobs}), "sweeps")
    for name, message in scan.failed:
        progress.update(name, f"failed: {message}")
    summary = run_kitti_raw_sweeps(scan.jobs, sweeps=args.sweeps, config=_config_from(args),
                                   overwrite=args.overwrite, png_compression=args.png_compression,
                                   io_threads=devices.io_threads(), on_progress=progress.update, force=args.force,
                                   method=args.method)
    progress.close()
    summary.failed[:0] = scan.failed
    return _report(summary, args.quiet, t_start=getattr(args, "t_start", None), unit="sweeps")


def _image_finder(src: pathlib.Path, args):
    """``png -> camera image path`` (None when unguided) for a selection folder, flat folder or
    single file (:mod:`jaxdepth.io.guidance_images`: ``--image-dir`` or ``image/`` beside
    ``velodyne_raw/``; InputError when there is neither)."""
    from jaxdepth.io import guidance_images
    if not args.guidance_weight > 0:
        return lambda png: None
    folder = guidance_images.selection_image_folder(src, args.image_dir)
    return lambda png: guidance_images.find_image(folder, png.stem)


def _discover_dataset(src: pathlib.Path, dst: pathlib.Path, args):
    """The :class:`jaxdepth.io.kitti_datasets.DatasetScan` of a dataset root, None for a selection /
    flat folder or one file; one line on stderr says what was found. A folder in no known layout
    is an error listing the layouts understood."""
    from jaxdepth.io import kitti_datasets
    from jaxdepth.io.errors import InputError

    if not src.is_dir():
        return None
    scan = kitti_datasets.discover_kitti(src, dst, camera=args.camera, crop=args.crop,
                                         name=args.name or args.method, calib_dir=args.calib_dir,
                                         image_dir=args.image_dir)
    if scan is None:
        try:
            has_pngs = (src / "velodyne_raw").exists() or any(p.suffix.lower() == ".png" for p in src.iterdir())
        except OSError:  # an unreadable folder: the selection-folder reader names the problem
            has_pngs = True
        if not has_pngs:
            raise InputError(kitti_datasets.unknown_layout_message(src))
        return None
    for option, given in (("--intrinsics", args.intrinsics), ("--extrinsic", args.extrinsic)):
        if given is not None:
            raise InputError(f"{src}: {option} does not apply to a {scan.layout} folder (its calibration is used)")
    if scan.jobs and scan.jobs[0].image_size is not None and args.method != "sgm" and not args.sweeps:
        raise InputError(f"{src}: LiDAR sweeps complete with --method sgm only, got {args.method} (the baselines "
                         "run with --sweeps N > 0)")
    if not args.quiet:
        print(f"found {scan.summary}", file=sys.stderr)
    return scan


def _forced_jobs(jobs, args):
    """``--force``: every job reads inputs that fail the plausibility checks (logged once here, and per file)."""
    if not getattr(args, "force", False):
        return jobs
    import dataclasses
    log.warning("--force: inputs that fail the plausibility checks are used anyway (each one is logged)")
    return [dataclasses.replace(job, force=True) for job in jobs]


def _job_identities(jobs, args) -> dict:
    """``{output: input identity}`` of ``complete``'s frame jobs (:func:`jaxdepth.batch.runner.job_identity`)."""
    from jaxdepth.batch.runner import job_identity
    return {job.out_path: job_identity(job, guided=args.guidance_weight > 0) for job in jobs}


def _claim_output_folder(dst: pathlib.Path, args, *, inputs, out_paths=(), outputs=None, **options):
    """Checks the output folder's run record against this run's settings, output version and inputs
    (``outputs``: ``{output: input identity}``) and writes it (:mod:`jaxdepth.batch.run_record`; KITTI
    trees: one per ``proj_depth/<name>``): a re-run with other settings or another output version is
    refused unless --overwrite; outputs whose inputs changed are removed and so recomputed."""
    from jaxdepth.batch import run_record
    _ensure_writable_dir(dst)
    record = _run_record(args, inputs, **options)
    for folder in run_record.record_folders(dst, out_paths):
        run_record.claim_folder(folder, record, overwrite=args.overwrite, outputs=outputs)


def _run_record(args, inputs, **options) -> dict:
    """This run's record object (:func:`jaxdepth.batch.run_record.make_record`): settings, inputs, command."""
    from jaxdepth.batch import run_record
    settings = run_record.settings_of(_config_from(args), method=args.method, extras=_extras_from(args), **options)
    more = [p for p in (getattr(args, "calib_dir", None), getattr(args, "image_dir", None)) if p is not None]
    return run_record.make_record(settings, inputs=list(inputs) + more, command=getattr(args, "command_line", None))


def _ensure_writable_dir(path: pathlib.Path):
    from jaxdepth.io.atomic import ensure_output_dir
    ensure_output_dir(path)


def _report(summary, quiet: bool, *, t_start: float | None = None, unit: str = "images") -> int:
    """The job's summary on stderr (:func:`jaxdepth.progress.report_summary`); the exit code."""
    from jaxdepth.progress import report_summary
    return report_summary(summary, quiet=quiet, t_start=t_start, unit=unit)


def _add_nuscenes_options(parser) -> None:
    """The nuScenes options of ``jaxdepth complete`` (no JAX import)."""
    group = parser.add_argument_group(
        "nuScenes", "with --nusc-version, SRC is a nuScenes dataroot and DST an output root: one uint16 depth PNG "
                    "per camera image, DST/<version>/<CAM_CHANNEL>/<sample_data_token>.png (--engine local "
                    "or ray, same bytes; --method nearest / ip-basic: the baselines of the same points, local engine; --batch-size has no effect on the local engine: one "
                    "sample's cameras are one batch; --cpu-devices N > 1 deals whole samples to N host devices "
                    "(same bytes, each compiles its own copy, 0.935x the wall on 2 idle cores; default: one device); on Ray --batch-size is samples per actor call); with "
                    "--guidance-weight W > 0 every sample's camera JPEGs (samples/CAM_*/...) are read for "
                    "image-guided seeds, and a missing or bad image fails its sample")
    group.add_argument("--nusc-version", default=None, metavar="VERSION",
                       help="complete every sample of DATAROOT/VERSION (v1.0-mini, v1.0-trainval, v1.0-test)")
    group.add_argument("--no-ego-motion", dest="ego_motion", action="store_false",
                       help="do not compensate the vehicle's motion between the LiDAR and each camera's timestamp "
                            "(default: compensate, LiDAR -> ego(t_lidar) -> global -> ego(t_cam) -> camera)")


def _cmd_complete_nuscenes(args) -> int:
    """``jaxdepth complete DATAROOT DST --nusc-version V``: exit 0 ok, 1 data error or failed samples, 2 usage."""
    from jaxdepth.batch.nuscenes_job import run_nuscenes

    usage = None
    given = [flag for flag, value in (("--intrinsics", args.intrinsics), ("--camera", args.camera),
                                      ("--calib-dir", args.calib_dir), ("--extrinsic", args.extrinsic))
             if value is not None]
    if given:
        usage = f"{', '.join(given)} cannot be used with --nusc-version (the tables give K and the extrinsics)"
    elif getattr(args, "image_dir", None) is not None:
        usage = ("--image-dir cannot be used with --nusc-version: with --guidance-weight each camera's image is the "
                 "JPEG its sample_data row names in the dataroot")
    elif args.method != "sgm" and args.engine != "local":
        usage = f"--nusc-version with --method {args.method}: --engine local only"
    elif args.sweeps is not None and args.sweeps < 1:
        usage = f"--sweeps with --nusc-version expected an integer >= 1 (sweeps per sample), got {args.sweeps}"
    elif (args.sweeps or 1) > 1 and _extras_from(args).needs_seeds:
        usage = "--validity, --seed-distance and --zero-invalid need --sweeps 1 with --nusc-version"
    usage = usage or _settle_rig_baseline_removal(args)
    if usage:
        print(f"jaxdepth: error: {usage}", file=sys.stderr)
        return 2
    args.sweeps = 1 if args.sweeps is None else args.sweeps
    sample_devices = _job_devices(args)
    dst = pathlib.Path(args.dst)
    _ensure_writable_dir(dst)
    from jaxdepth.io import nuscenes as nusc
    tables = nusc.load_tables(args.src, args.nusc_version)
    # outputs go to DST/<version>/...: the version is an input, not a setting
    from jaxdepth.batch.nuscenes_job import output_identities
    _claim_output_folder(dst, args, inputs=[args.src], sweeps=args.sweeps, ego_motion=args.ego_motion,
                         outputs=output_identities(tables, dst, sweeps=args.sweeps, guided=args.guidance_weight > 0))
    progress = _progress(args, len(tables.tables["sample"]), "samples")
    options = dict(version=args.nusc_version, sweeps=args.sweeps, ego_motion=args.ego_motion,
                   config=_config_from(args), overwrite=args.overwrite, png_compression=args.png_compression,
                   on_progress=progress.update, tables=tables, extras=_extras_from(args),
                   force=bool(getattr(args, "force", False)))
    if options["force"]:
        log.warning("--force: sweeps that fail the plausibility checks are used anyway (each one is logged)")
    if args.engine == "ray":
        from jaxdepth.batch import scale
        summary = scale.run_nuscenes_ray(args.src, dst, batch_size=args.batch_size, address=args.ray_address,
                                         **options)
    else:
        summary = run_nuscenes(args.src, dst, io_threads=devices.io_threads(), method=args.method,
                               devices=sample_devices, **options)
    progress.close()
    return _report(summary, args.quiet, t_start=getattr(args, "t_start", None), unit="samples")


def cmd_eval(args) -> int:
    from jaxdepth.research import evaluation
    from jaxdepth.batch import run_record
    table = evaluation.evaluate_folders(pathlib.Path(args.pred), pathlib.Path(args.gt), force=args.force)
    found = run_record.find_record(args.pred)
    if found is None:  # a KITTI tree: the records of its proj_depth/<name> folders, when they agree
        below = run_record.find_records_below(args.pred)
        if below and all(r["settings"] == below[0][1]["settings"] for _, r in below):
            found = below[0]
    for line in evaluation.format_table(table):
        print(line)
    if found is None:
        print(f"prediction settings: unknown (no {run_record.RUN_FILE} in {args.pred} or above)")
        table["prediction_run"] = None
    else:
        for line in run_record.summary_lines(found[1], path=found[0]):
            print(line)
        table["prediction_run"] = dict({k: v for k, v in found[1].items() if k != "outputs"}, path=str(found[0]))
    evaluation.write_table(table, json_path=args.json, csv_path=args.csv)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxdepth", description=(
        "Non-learning LiDAR depth completion (Surface Geometry Model, Zhao et al. RA-L 2021) in JAX."))
    parser.add_argument("--version", action="version", version=f"jaxdepth {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    parser.add_argument("--no-compile-cache", dest="compile_cache", action="store_false",
                        help="do not keep compiled functions in ~/.cache/jaxdepth/xla for later runs "
                             "(same outputs either way; also JAXDEPTH_COMPILE_CACHE=0)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_demo_command(sub)
    _add_complete_command(sub)
    from jaxdepth import cli_rig
    cli_rig.register(sub)
    _add_eval_command(sub)
    from jaxdepth.research import cli as research_cli
    research_cli.register(sub, complete_cloud=_complete_cloud)
    return parser


def _complete_cloud(*args, **kwargs):
    """:func:`jaxdepth.batch.sources_job.complete_cloud`, loaded on use (hidden-eval's multi-source path)."""
    from jaxdepth.batch.sources_job import complete_cloud
    return complete_cloud(*args, **kwargs)


def _add_demo_command(sub) -> None:
    p = sub.add_parser("demo", help="complete a built-in synthetic street scene and score it (no data needed)")
    p.add_argument("--out", default="jaxdepth_demo", help="output folder (default: ./jaxdepth_demo)")
    p.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    _add_method_options(p)
    p.set_defaults(func=cmd_demo)


def _add_complete_command(sub) -> None:
    p = sub.add_parser(
        "complete", help="complete a KITTI dataset root (raw, depth-completion train/val, object), a selection "
                         "folder or one PNG",
        description="Completes every frame of SRC into DST. SRC layouts: KITTI raw (a date folder, one drive, or "
                    "a folder of dates: velodyne_points/data/*.bin, calibration per date) -> "
                    "DST/<drive>/proj_depth/<name>/image_0X/<frame>.png; an Argoverse 2 sensor log or a folder of "
                    "logs (<log>/sensors/lidar/*.feather, calibration/) -> DST/<log>/<camera>/<lidar ts>.png, "
                    "needs pyarrow; KITTI depth-completion train/val "
                    "(<drive>/proj_depth/velodyne_raw/image_0X/*.png, needs --calib-dir) -> the same tree with "
                    "<name> for velodyne_raw; KITTI object training/testing (velodyne/, calib/, image_2/) -> "
                    "DST/<split>/depth_2/<frame>.png; a selection folder (velodyne_raw/ + intrinsics/) or flat "
                    "folder of PNGs -> DST/<file>.png; one PNG with --intrinsics -> DST. Finished outputs are "
                    "skipped (re-run to resume).")
    p.add_argument("src", help="dataset root (see above), folder with velodyne_raw/*.png and intrinsics/*.txt, "
                               "or one sparse depth PNG")
    p.add_argument("dst", help="output folder (or output PNG for a single image)")
    p.add_argument("--intrinsics", help="K.txt for a single image (or for every frame of a folder)")
    p.add_argument("--camera", type=int, choices=(0, 1, 2, 3), default=None,
                   help="KITTI camera: for a selection folder the one whose LiDAR extrinsic to use (default: the "
                        "file name's _image_0X suffix, else 2; built-in 2011_09_26 calibration for cameras 2 and "
                        "3); for a dataset root the only camera to complete (default: raw 2 and 3, train/val every "
                        "image_0X found, object 2)")
    p.add_argument("--calib-dir", default=None, metavar="DIR",
                   help="KITTI raw calibration per recording date: DIR/<date>/calib_cam_to_cam.txt and "
                        "calib_velo_to_cam.txt (date from the file or drive name), or the two files directly in DIR "
                        "(selection folders and depth-completion train/val trees)")
    p.add_argument("--crop", action="store_true",
                   help="KITTI raw / object: complete the 352x1216 benchmark crop (bottom rows, centre columns) "
                        "instead of the full frame")
    p.add_argument("--name", default=None,
                   help="output folder under proj_depth/ for KITTI raw and train/val trees (default: the method, "
                        "e.g. sgm)")
    p.add_argument("--extrinsic", default=None, metavar="T.txt",
                   help="LiDAR -> camera extrinsic for every frame: 12 (3x4) or 16 (4x4) numbers, row major")
    _add_method_options(p)
    p.add_argument("--image-dir", default=None, metavar="DIR",
                   help="camera images for --guidance-weight: a selection / flat folder or one PNG reads "
                        "DIR/<name>.png, where <name> is the depth PNG's name with 'velodyne_raw' replaced by "
                        "'image' (KITTI's naming), else the same name (default: the image/ folder beside "
                        "velodyne_raw/); a KITTI raw drive or a depth-completion train/val tree reads "
                        "DIR/<date>/<drive>/image_0X/data/<frame>.png (a raw root; default for raw: the drive's "
                        "own image_0X/data, train/val trees have none); KITTI object uses its image_X/")
    p.add_argument("--sweeps", type=int, default=None, metavar="N",
                   help="accumulate LiDAR sweeps, each completed as its own source (see docs/datasets.md): KITTI raw "
                        "and Argoverse 2: N neighbouring sweeps on each side of every sweep (default 0), posed by "
                        "OXTS + calib_imu_to_velo.txt / the city poses; nuScenes: N sweeps per sample, the key "
                        "frame and N-1 earlier ones (default 1, the devkit's from_file_multisweep)")
    from jaxdepth.batch import av2_job
    av2_job.add_cli_options(p)
    p.add_argument("--batch-size", type=int, default=4, help="frames per compiled batch (default 4)")
    _add_overwrite_and_force_options(p)
    p.add_argument("--png-compression", type=int, choices=range(10), default=_PNG_COMPRESSION_DEFAULT,
                   metavar="0-9",
                   help=f"zlib level of the output PNGs (default {_PNG_COMPRESSION_DEFAULT}: fast; 9: smallest, "
                        "slowest; 0: no compression, ~2.5x the bytes; 1-3 by ISA-L with the fast-png extra); "
                        "the depth values are the same at every level")
    p.add_argument("--cpu-devices", type=int, default=0, metavar="N",
                   help="on CPU, split the cores into N host devices that each complete their own frames "
                        "(default 0: one per core; 1: off; ignored if XLA_FLAGS sets a device count); nuScenes "
                        "and Argoverse 2 jobs: one device unless N > 1, then whole samples / sweeps dealt to N")
    p.add_argument("--engine", choices=("local", "ray"), default="local",
                   help="local threads + device (default) or a Ray cluster (pip install 'jaxdepth[ray]')")
    p.add_argument("--ray-address", default=None, help="Ray cluster address (default: start a local one)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    from jaxdepth.batch import extras as extras_cli
    extras_cli.add_cli_options(p)
    _add_nuscenes_options(p)
    p.set_defaults(func=cmd_complete)


def _add_eval_command(sub) -> None:
    p = sub.add_parser(
        "eval", help="KITTI devkit metrics of predictions against ground truth PNGs, paired by frame",
        description="Scores every prediction PNG under PRED_ROOT against the ground-truth PNG of the same frame "
                    "under GT_ROOT (KITTI devkit metrics: RMSE / MAE in mm, iRMSE / iMAE in 1/km; the mean is over "
                    "frames). Either side may be a flat folder or a tree, walked recursively. Frames are identified "
                    "by drive, camera and frame number for KITTI names (<drive>_velodyne_raw_<frame>_image_0X.png "
                    "pairs with <drive>_groundtruth_depth_<frame>_image_0X.png and with "
                    "<drive>/proj_depth/groundtruth/image_0X/<frame>.png), else by the path below the root with a "
                    "velodyne_raw / groundtruth_depth / groundtruth word dropped (same names, complete-rig's "
                    "<camera>.png). Frames on one side only are listed, not scored; two files of one frame are "
                    "an error.")
    p.add_argument("pred", metavar="PRED_ROOT", help="folder or tree of predicted depth PNGs")
    p.add_argument("gt", metavar="GT_ROOT",
                   help="folder or tree of ground-truth depth PNGs (e.g. data_depth_annotated/val, or a selection "
                        "folder: its groundtruth_depth/ is used)")
    p.add_argument("--json", metavar="PATH",
                   help="write mean, per-frame metrics, the file pairs and the unmatched files to this JSON file")
    p.add_argument("--csv", metavar="PATH",
                   help="write one row per frame to this CSV file: frame, rmse_mm, mae_mm, irmse_per_km, "
                        "imae_per_km, prediction, ground_truth (the paired files)")
    _add_force_option(p, force_help="score even when a side fails the checks (a PNG not in metres x 256; a "
                                    "prediction that covers under half of its ground truth: swapped folders or "
                                    "LiDAR input); logged")
    p.set_defaults(func=cmd_eval)


def main(argv=None) -> int:
    """The ``jaxdepth`` command. As the program (``argv`` None) a Ctrl-C ends the process with exit 130
    through :mod:`jaxdepth.interrupts`, never through the interpreter's shutdown (which crashes while
    XLA's compile threads run); a second Ctrl-C stops at once. Called with ``argv`` (tests) it returns 130."""
    t_start = time.perf_counter()
    program = argv is None
    if program:
        interrupts.catch()
    parser = build_parser()
    args = parser.parse_args(argv)
    # Our own logger follows -v; other libraries' (JAX's) INFO notes are not shown to users.
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    if args.verbose:
        log.setLevel(logging.INFO)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    args.t_start = t_start
    args.command_line = ["jaxdepth"] + [str(a) for a in (sys.argv[1:] if argv is None else argv)]
    try:
        if program:   # the jaxdepth process itself (not a test or script calling main): before JAX's threads start
            devices.keep_freed_memory()
        devices.quiet_jax_start()
        devices.use_compile_cache(args.compile_cache)
        code = int(args.func(args) or 0)
    except JaxdepthError as err:
        print(f"jaxdepth: error: {err}", file=sys.stderr)
        code = 1
    except KeyboardInterrupt:
        code = interrupts.interrupted(end_process=program)
    if program and interrupts.received():  # a Ctrl-C that JAX swallowed (e.g. in its gc callback) still stops
        code = interrupts.interrupted(end_process=True)
    if program and "ray" not in sys.modules:
        # Every output is written and closed: skip the interpreter's shutdown (JAX's clear_caches and backend
        # teardown, module and heap teardown: ~0.3-0.4 s of CPU after a cold KITTI job, docs/speed.md "The
        # cold process's ends"), as clang's -disable-free. Not with Ray loaded (its atexit stops its processes).
        logging.shutdown()
        interrupts.exit_now(code)
    return code


if __name__ == "__main__":
    sys.exit(main())
