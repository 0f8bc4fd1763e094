"""Every row of tests/stage_table.py through the harness: oracle, jit == eager, vmap == loop, no retrace."""

from __future__ import annotations

import inspect

import pytest

import jaxdepth

from _harness import check_stage
from stage_table import ROWS

#: Public functions without a row, and where their oracle / jit / vmap checks live instead.
NO_ROW = {
    "complete_points_stages": "the same traced body as complete_points (its .depth); test_pipeline checks stages",
    "complete_with": "a dispatcher to complete / ip_basic (both rows): test_pipeline (IP_Basic on KITTI), test_cli",
    "complete_rig": "vmap of complete over a camera stack: test_rig (rig == per-camera loop)",
    "complete_rig_stages": "vmap of complete_stages over a camera stack: test_rig",
    "stack_cameras": "stacking Camera objects onto the largest canvas: test_rig",
    "stack_images": "host-side padding of camera images onto the rig canvas (NumPy): test_rig_images",
    "make_sources": "shape checks and assembly of several sweeps into Sources: test_sources",
    "complete_sources": "multi-source pipeline: test_sources",
    "complete_sources_stages": "multi-source pipeline: test_sources",
    "free_space_keep": "multi-source free-space test: test_sources",
    "mean_metrics": "host-side mean of per-image metrics (no JAX program): test_metrics",
    "hidden_point_mask": "research protocol on a whole sweep: test_hidden_cover",
    "hidden_point_scores": "research protocol on a whole sweep: test_hidden_cover (jit with traced cameras)",
    "colorize_depth": "uint8 rendering for previews: test_colorize (OpenCV colour-map oracle)",
    "colorize_normals": "uint8 rendering for previews: test_colorize",
    "overlay_depth": "uint8 rendering for previews: test_colorize",
    "overlay_mask": "uint8 rendering for previews: test_colorize",
    "depth_preview": "uint8 rendering with a scale bar: test_validity",
    "ray_elevation": "inside validity_and_distance (row); float64 loop oracle in test_validity",
    "fov_mask": "inside validity_and_distance (row); analytic FOV rows in test_validity",
    "seed_distance": "inside validity_and_distance (row); brute-force oracle in test_validity",
    "make_street_scene": "the synthetic scene generator (test input, not a stage): test_synthetic",
}


def _marks(row) -> list:
    return ([pytest.mark.slow] if row.slow else []) + ([pytest.mark.xdist_group(row.group)] if row.group else [])


@pytest.mark.parametrize("row", [pytest.param(row, id=row.name, marks=_marks(row)) for row in ROWS])
def test_stage(row):
    inputs = row.inputs()
    outs = check_stage(row.fn, inputs, static=row.static, oracle=row.oracle, select=row.select,
                       oracle_ulps=row.oracle_ulps, oracle_scale=row.oracle_scale, ulps=row.ulps, scale=row.scale,
                       in_axes=row.in_axes, vmap=row.vmap, eager_inputs=row.eager_inputs)
    if row.check is not None:
        row.check(outs, inputs)


def test_every_public_stage_function_has_a_row():
    public = {name for name in jaxdepth.__all__ if callable(getattr(jaxdepth, name)) and not inspect.isclass(getattr(jaxdepth, name))}
    covered = {name for row in ROWS for name in row.names()}
    missing = public - covered - set(NO_ROW)
    assert not missing, f"public functions without a row in tests/stage_table.py (or a NO_ROW reason): {missing}"
    stale = set(NO_ROW) & covered
    assert not stale, f"NO_ROW names that now have a row: {stale}"
    assert not set(NO_ROW) - public, f"NO_ROW names that are not public: {set(NO_ROW) - public}"
