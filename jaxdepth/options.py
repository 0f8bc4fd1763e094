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
    p.add_argument("--above-scan", dest="above_scan", choices=("auto", "plane", "background", "capped"),
                   default=argparse.SUPPRESS,
                   help="Step 4 above the top scan line: plane (the nearest seed's plane, as in the paper), "
                        "background (the farthest seed within one LiDAR point spacing, |du| < W L / N, no plane) or "
                        "capped (the plane followed at most one scan-line spacing, h / L rows, above its seed); "
                        "auto (default): capped for a sweep of several LiDARs (a rig's lidars), else plane")
    p.add_argument("--seed-horizontal-cost", dest="seed_horizontal_cost", type=int, metavar="C",
                   default=argparse.SUPPRESS,
                   help="Step 3 (l1, unguided): a seed's horizontal offset costs C times its vertical offset "
                        "(1: the paper's city block); default: SGMConfig's")
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


def _top_line_mode(text: str) -> str:
    """--reference-top-line: auto, on or off."""
    if text not in ("auto", "on", "off"):
        raise argparse.ArgumentTypeError(f"expected 'auto', 'on' or 'off', got {text!r}")
    return text


def _older_sweeps_test(text: str) -> str:
    """--older-sweeps-test: footprint or paper."""
    if text not in ("footprint", "paper"):
        raise argparse.ArgumentTypeError(f"expected 'footprint' or 'paper', got {text!r}")
    return text


def _outlier_sweeps_mode(text: str) -> str:
    """--outlier-sweeps: auto, each or merged."""
    if text not in ("auto", "each", "merged"):
        raise argparse.ArgumentTypeError(f"expected 'auto', 'each' or 'merged', got {text!r}")
    return text


#: The multi-source options (docs/multi_source.md): flag -> (SGMConfig field, type, metavar, what it sets).
#: Unset flags keep the config's default.
_SOURCES_OPTIONS = {
    "--free-space-noise": ("free_space_noise_m", float, "M", "range noise and pose error in the free-space margin, "
                           "metres (default 0.3)"),
    "--free-space-slope": ("free_space_slope", float, "K", "gaps between neighbouring lasers in the margin "
                           "(default 2.0)"),
    "--free-space-min-cells": ("free_space_min_cells", int, "N", "measured cells (of the 2 x 2 bracketing a point) a "
                               "LiDAR needs to judge it, 1-4 (default 3)"),
    "--neighbour-sweeps": ("free_space_neighbour_sweeps", _sweeps_count, "N|all", "sweeps on each side the other "
                           "sweeps' LiDARs judge (default 0; all: every sweep, a cost quadratic in the sweeps)"),
    "--occlusion-max-baseline": ("occlusion_max_baseline_m", float, "M", "largest camera-to-LiDAR distance of the "
                                 "occlusion test of other sweeps' points, metres (default 1.0)"),
    "--witness-cell": ("free_space_witness_cell", float, "K", "free-space grid of a scan without laser rows or "
                       "stated spec whose own grid it fills too sparsely (a rosette): cells of K mean point "
                       "spacings (default 2.0; 0: the rig's LiDAR spec)"),
    "--reference-top-line": ("reference_top_line", _top_line_mode, "auto|on|off", "other sweeps' points above "
                             "the reference sweep's top scan line in a camera and nearer than its top pixels by more "
                             "than epsilon are no seeds (default auto: on for one LiDAR scanned in laser rows)"),
    "--outlier-sweeps": ("outlier_sweeps", _outlier_sweeps_mode, "auto|each|merged", "Step 2 also judges each sweep "
                         "against the reference sweep with one sweep's window (default auto: for a scan without scan "
                         "lines, a rosette)"),
    "--older-sweeps-test": ("older_sweeps_test", _older_sweeps_test, "footprint|paper", "condition 1 of Step 2 "
                            "for the older sweeps' points: paper also judges them by the paper's axis-aligned "
                            "flips (default footprint: as every point)"),
}


def add_sources_options(p: argparse.ArgumentParser) -> None:
    """The multi-source SGMConfig options (free space, occlusion), part of :func:`add_config_options`."""
    for flag, (field, kind, metavar, what) in _SOURCES_OPTIONS.items():
        p.add_argument(flag, dest=field, type=kind, metavar=metavar, default=argparse.SUPPRESS,
                       help=f"several LiDARs / sweeps: {what}")


def config_changes(args) -> dict:
    """SGMConfig fields set by :func:`add_config_options`' arguments."""
    changes = {"distance_metric": args.distance, **_HYPOTHESES[args.hypotheses]}
    for field in ("above_scan", "seed_horizontal_cost"):
        if hasattr(args, field):
            changes[field] = getattr(args, field)
    if getattr(args, "epsilon", None) is not None:
        changes["epsilon_m"] = args.epsilon
    changes.update({f: getattr(args, f) for f, *_ in _SOURCES_OPTIONS.values() if hasattr(args, f)})
    return changes
