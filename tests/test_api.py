"""Conventions of the public API (like dm_pix's api_test): documented names, keyword-only options."""

from __future__ import annotations

import inspect
import re

import jaxdepth

OPTION_NAMES = {"config", "lidar", "metric", "epsilon_m", "beams", "sigma_px", "radius_px", "method",
                "max_half_width_px", "max_half_height_px", "smoothing", "fill_max_gap", "min_abs_denom",
                "max_residual_ratio", "fill", "fraction", "seed", "vmin", "vmax", "cmap", "max_depth",
                "blur_type", "extrapolate", "height", "width", "test", "points_cam"}


# Positional on purpose: the scene seed is the function's only data; a traced sigma is data to vmap over.
DATA_ARGUMENTS = {("make_street_scene", "seed"), ("gaussian_blur_traced", "sigma_px")}


def public_callables():
    for name in jaxdepth.__all__:
        obj = getattr(jaxdepth, name)
        if callable(obj) and not isinstance(obj, type):
            yield name, obj


def public_parameters():
    """(function name, inspect.Parameter) of every public function with a signature."""
    for name, fn in public_callables():
        try:
            params = inspect.signature(fn).parameters.values()
        except (TypeError, ValueError):
            continue
        for p in params:
            yield name, p


def test_every_public_name_is_documented():
    missing = [name for name in jaxdepth.__all__ if not (getattr(jaxdepth, name).__doc__ or "").strip()]
    assert not missing, missing


def test_options_are_keyword_only():
    offenders = []
    for name, p in public_parameters():
        if ((name, p.name) not in DATA_ARGUMENTS and p.name in OPTION_NAMES
                and p.kind is not inspect.Parameter.KEYWORD_ONLY):
            offenders.append(f"{name}({p.name})")
    assert not offenders, offenders


SHAPE = r"\((?:[A-Z]|\d+)[\w ,]*\)"  # "(H, W)", "(N,)", "(3, 3)", "(C, 3, H, W)"


def _states_shape(doc: str, name: str) -> bool:
    """Whether ``doc`` documents argument ``name`` as ``name: (shape) ...`` or ``name: :class:`...```
    (also in a list: ``du, dv: (H, W) ...``)."""
    return re.search(rf"(?<![\w.]){name}(?:, \w+)*: (?:{SHAPE}|:class:)", doc) is not None


def test_array_functions_state_shapes():
    """Docstrings of the array functions give the shape of every positional (array) argument, in
    their own Args or in the function they refer to with "see :func:`...`", and of what they return
    (a Returns section, else the summary line)."""
    for name in ("complete", "complete_stages", "complete_points_stages", "complete_rig_stages", "nearest_seed",
                 "outlier_keep_mask", "point_normals", "plane_residual", "gaussian_blur", "project_to_image",
                 "depth_metrics", "ip_basic"):
        doc = inspect.getdoc(getattr(jaxdepth, name))
        docs = [doc] + [inspect.getdoc(getattr(jaxdepth, ref)) for ref in re.findall(r"see :func:`(\w+)`", doc)]
        arrays = [p.name for p in inspect.signature(getattr(jaxdepth, name)).parameters.values()
                  if p.kind in (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)]
        assert arrays, name
        missing = [a for a in arrays if not any(_states_shape(d, a) for d in docs)]
        assert not missing, f"{name}: no shape stated for {missing}"
        returns = doc.split("Returns:", 1)[1].strip().split("\n\n")[0] if "Returns:" in doc else doc.splitlines()[0]
        assert re.search(SHAPE + "|:class:|dict of", returns), f"{name}: return shape not stated in {returns!r}"


# Stage options that are SGMConfig fields under another name (issue 14: the stages' own
# defaults must be SGMConfig's, so calling a stage alone gives the pipeline's step).
CONFIG_FIELD_OF_OPTION = {"metric": "distance_metric", "min_abs_denom": "min_abs_denom",
                          "max_residual_ratio": "max_residual_ratio", "epsilon_m": "epsilon_m",
                          "max_half_width_px": "outlier_max_half_width_px",
                          "max_half_height_px": "outlier_max_half_height_px",
                          "smoothing": "normal_smoothing", "fill_max_gap": "range_fill_max_gap",
                          "test": "outlier_test", "horizontal_cost": "seed_horizontal_cost"}


def test_stage_defaults_are_the_config_defaults():
    config = jaxdepth.SGMConfig()
    checked, differ = 0, []
    for name, p in public_parameters():
        field = CONFIG_FIELD_OF_OPTION.get(p.name)
        if field is None or p.default is inspect.Parameter.empty:
            continue
        checked += 1
        if p.default != getattr(config, field):
            differ.append(f"{name}({p.name}={p.default!r}) vs SGMConfig.{field}={getattr(config, field)!r}")
    assert checked >= 5 and not differ, differ
