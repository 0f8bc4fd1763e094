"""The options and helpers that several ``jaxdepth`` subcommands share (:mod:`jaxdepth.cli`,
:mod:`jaxdepth.cli_rig`): method and configuration options, extra outputs, ``--overwrite`` /
``--force``, the job's progress line. Parsing only: no algorithm logic.
"""

from __future__ import annotations

import argparse

from jaxdepth.options import add_config_options, config_changes
from jaxdepth.progress import Progress


def add_method_options(p: argparse.ArgumentParser, *, methods=("sgm", "nearest", "ip-basic")):
    p.add_argument("--method", choices=methods, default="sgm", help="completion method (default: sgm)")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--outlier-removal", dest="outlier_removal", action="store_true", default=None,
                       help="run the paper's outlier removal in front of the method (default for every method; "
                            "the rig and multi-source jobs' baselines fill every projected point without it)")
    group.add_argument("--no-outlier-removal", dest="outlier_removal", action="store_false",
                       help="skip outlier removal")
    add_config_options(p)
    p.add_argument("--guidance-weight", type=float, default=0.0, metavar="W",
                   help="image-guided seeds (beyond the paper): geodesic seed search on the camera image with this "
                        "colour weight (default 0: off, the paper's LiDAR-only SGM)")
    p.add_argument("--guidance-sweeps", type=int, default=None, metavar="S",
                   help="raster sweeps of the geodesic transform (default 2)")
    p.add_argument("--guidance-noise-floor", type=float, default=None, metavar="F",
                   help="colour differences up to F times the image's median step difference cost nothing "
                        "(default 0: GeoS's plain cost)")


def config_from(args):
    from jaxdepth._src.config import SGMConfig
    changes = config_changes(args)
    if args.outlier_removal is not None:
        changes["outlier_removal"] = args.outlier_removal
    if getattr(args, "guidance_weight", None):
        changes["guidance_weight"] = args.guidance_weight
    if getattr(args, "guidance_sweeps", None) is not None:
        changes["guidance_sweeps"] = args.guidance_sweeps
    if getattr(args, "guidance_noise_floor", None) is not None:
        changes["guidance_noise_floor"] = args.guidance_noise_floor
    return SGMConfig(**changes)


def settle_rig_baseline_removal(args) -> str | None:
    """The rig and multi-source jobs' baselines (``--method nearest`` / ``ip-basic``) fill every projected
    point without outlier removal: an explicit ``--outlier-removal`` is refused (the returned message), else
    ``args.outlier_removal`` is set False so that the run record says what ran. None: settled."""
    if getattr(args, "method", "sgm") == "sgm":
        return None
    if args.outlier_removal:
        return (f"--method {args.method} on a rig or multi-source job fills every projected point without "
                "outlier removal: drop --outlier-removal")
    args.outlier_removal = False
    return None


def guidance_usage(args) -> str | None:
    """Why the image-guidance flags of ``complete`` cannot be used as given (None: they can)."""
    if args.guidance_weight > 0 and args.method != "sgm":
        return "--guidance-weight (image-guided seeds) needs --method sgm"
    if args.image_dir is not None and not args.guidance_weight > 0:
        return "--image-dir gives the camera images of image-guided seeds: use it with --guidance-weight W > 0"
    return None


def extras_from(args):
    from jaxdepth.batch import extras
    return extras.from_args(args)


def extras_usage(args) -> str | None:
    """Why the extra-output flags cannot be used as given (None: they can)."""
    try:
        extras = extras_from(args)
    except ValueError as err:
        return str(err)
    if extras.needs_seeds and getattr(args, "method", "sgm") != "sgm":
        return "--validity, --seed-distance and --zero-invalid need --method sgm (they use its seeds)"
    return None


def progress(args, total: int, unit: str, label: str = "complete") -> Progress:
    """The job's progress on stderr (:mod:`jaxdepth.progress`): a live line on a terminal, a line every
    few seconds in a log; ``-v`` adds one line per item; silent with ``--quiet``."""
    return Progress(total, enabled=not getattr(args, "quiet", False), unit=unit, label=label,
                    verbose=bool(getattr(args, "verbose", False)))


FORCE_HELP = ("use inputs that fail the plausibility checks (a sweep whose values no LiDAR gives, e.g. a "
              "wrong --point-columns; a depth PNG not in metres x 256; a calibration the sweep contradicts); "
              "each one is logged")


def add_overwrite_and_force_options(p, *, force_help: str = FORCE_HELP) -> None:
    """``--overwrite`` (the job commands) and ``--force`` (every command that checks its inputs)."""
    p.add_argument("--overwrite", action="store_true",
                   help="recompute outputs that already exist (also needed to re-run into a folder whose "
                        "jaxdepth_run.json records other settings)")
    add_force_option(p, force_help=force_help)


def add_force_option(p, *, force_help: str = FORCE_HELP) -> None:
    p.add_argument("--force", action="store_true", help=force_help)


__all__ = ["add_method_options", "config_from", "guidance_usage", "extras_from", "extras_usage", "progress",
           "FORCE_HELP", "add_overwrite_and_force_options", "add_force_option"]
