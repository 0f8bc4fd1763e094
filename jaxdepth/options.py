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


def config_changes(args) -> dict:
    """SGMConfig fields set by :func:`add_config_options`' arguments."""
    changes = {"distance_metric": args.distance, **_HYPOTHESES[args.hypotheses]}
    if getattr(args, "epsilon", None) is not None:
        changes["epsilon_m"] = args.epsilon
    return changes
