"""Command-line options shared by ``jaxdepth`` (:mod:`jaxdepth.cli`) and its research commands
(:mod:`jaxdepth.research.cli`): the SGMConfig options and the SGMConfig fields they set.

A leaf module (argparse only; the config class loads on use), so both command modules import it
without importing each other.
"""

from __future__ import annotations

import argparse


#: --hypotheses: the SGMConfig fields each of Step 4's variants sets.
_HYPOTHESES = {"paper": dict(column_bracket=False, blend_hypotheses=False),
               "bracket": dict(column_bracket=True, blend_hypotheses=False),
               "blend": dict(column_bracket=True, blend_hypotheses=True)}


def add_config_options(p: argparse.ArgumentParser) -> None:
    """The SGMConfig options every completing command takes (``jaxdepth`` and the research commands)."""
    p.add_argument("--distance", choices=("l1", "l2"), default="l1",
                   help="nearest-seed metric of the distance transform (default: l1, city block as in the paper; "
                        "l2: Euclidean, SGM 1.5-1.8x slower)")
    p.add_argument("--epsilon", type=float, default=None, help="outlier depth margin in metres (default 1.0)")
    p.add_argument("--hypotheses", choices=tuple(_HYPOTHESES), default="bracket",
                   help="Step 4's prediction between scan lines: paper (the nearest seed's plane only), bracket "
                        "(default: clipped to the depths of the LiDAR pixels straight above and below within one "
                        "scan-line spacing), blend (also average in those pixels' own planes)")
    add_sources_options(p)


def _sweeps_count(text: str):
    """--neighbour-sweeps: an integer >= 0, or "all" (None: every other sweep)."""
    if text == "all":
        return None
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0 or 'all', got {text!r}")
    return value


#: The multi-source options: (flag, SGMConfig field, add_argument keywords); unset flags keep the default.
_SOURCES_OPTIONS = (
    ("--free-space-noise", "free_space_noise_m", dict(type=float, metavar="M", help=(
        "several LiDARs / sweeps: range noise and registration error allowed before a point of another sweep "
        "counts as lying in space a LiDAR saw empty, metres (default 0.3)"))),
    ("--free-space-slope", "free_space_slope", dict(type=float, metavar="K", help=(
        "several LiDARs / sweeps: the free-space margin adds K x range x the gap between neighbouring lasers "
        "(default 2.0)"))),
    ("--free-space-min-cells", "free_space_min_cells", dict(type=int, choices=(1, 2, 3, 4), help=(
        "several LiDARs / sweeps: measured cells of the 2 x 2 around a point a LiDAR needs to judge it "
        "(default 3)"))),
    ("--neighbour-sweeps", "free_space_neighbour_sweeps", dict(type=_sweeps_count, metavar="N|all", help=(
        "several sweeps: sweeps on each side a non-reference, non-end sweep's LiDARs judge for free space "
        "(default 0; all: every sweep, cost quadratic in the sweeps)"))),
    ("--occlusion-max-baseline", "occlusion_max_baseline_m", dict(type=float, metavar="M", help=(
        "several sweeps: largest camera-to-LiDAR distance at which the reference LiDAR's view stands in for "
        "the camera's in the occlusion test, metres (default 1.0)"))),
)


def add_sources_options(p: argparse.ArgumentParser) -> None:
    """The multi-source SGMConfig options (free space, occlusion), part of :func:`add_config_options`."""
    for flag, field, options in _SOURCES_OPTIONS:
        p.add_argument(flag, dest=field, default=argparse.SUPPRESS, **options)


def config_changes(args) -> dict:
    """SGMConfig fields set by :func:`add_config_options`' arguments."""
    changes = {"distance_metric": args.distance, **_HYPOTHESES[args.hypotheses]}
    if getattr(args, "epsilon", None) is not None:
        changes["epsilon_m"] = args.epsilon
    changes.update({field: getattr(args, field) for _, field, _ in _SOURCES_OPTIONS if hasattr(args, field)})
    return changes
