"""Free-space witnesses of scans without laser rows (raster, rosette): a grid matched to the scan's point spacing."""

from __future__ import annotations

import jax
import numpy as np

from jaxdepth._src.sources import make_sources, reference_view
from jaxdepth._src.types import LidarSpec, SourceCloud
from jaxdepth.batch.sources_job import (WITNESS_GRID_STEP, cloud_sources, scan_witness_spec, spec_grid_evidence,
                                        witness_spec)

#: reference_view compiled (a plain function: called as it is, it runs op by op and compiles every primitive)
_view = jax.jit(reference_view)

#: What a rig JSON without ``beams`` gives a rosette unit: rows 1.09 deg, columns 0.18 deg.
FALLBACK = LidarSpec(beams=64, fov_up_deg=35.0, fov_down_deg=-35.0, columns=2048)
WALL_X = 20.0


def _cone_directions(n, half_angle_deg, seed):
    """(n, 3) unit directions uniform over a cone about +x (uniform in solid angle)."""
    rng = np.random.default_rng(seed)
    cos_t = 1.0 - rng.random(n) * (1.0 - np.cos(np.radians(half_angle_deg)))
    phi = rng.random(n) * 2 * np.pi
    sin_t = np.sqrt(1.0 - cos_t ** 2)
    return np.stack([cos_t, sin_t * np.cos(phi), sin_t * np.sin(phi)], 1)


def _on_wall(directions, origin):
    """Where rays from ``origin`` along ``directions`` (all +x) hit the wall x = WALL_X."""
    t = (WALL_X - origin[0]) / directions[:, 0]
    return (origin + t[:, None] * directions).astype(np.float32)


def test_scan_witness_cells_are_twice_the_mean_spacing_and_filled_as_poisson_says():
    # Analytic oracle: n directions uniform in a box of solid angle omega are sqrt(omega / n) apart on
    # average; cells of twice that hold 4 points on average, so a cell inside the box is empty with
    # probability exp(-4) (Poisson), whatever the grid's rounding to WITNESS_GRID_STEP shrinks it by.
    rng = np.random.default_rng(0)
    n = 40000
    az = rng.uniform(-np.radians(40), np.radians(40), n)
    el = np.arcsin(rng.uniform(np.sin(np.radians(-20)), np.sin(np.radians(10)), n))
    local = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1) * 30.0
    spec = scan_witness_spec(local, FALLBACK, cell_spacings=2.0)
    omega = np.radians(80) * (np.sin(np.radians(10)) - np.sin(np.radians(-20)))
    cell = 2.0 * np.sqrt(omega / n)
    assert spec.beams % WITNESS_GRID_STEP == 0 and spec.columns % WITNESS_GRID_STEP == 0
    width = 2 * np.pi / spec.columns
    height = np.radians(spec.fov_up_deg - spec.fov_down_deg) / spec.beams
    assert 0.8 * cell <= width <= cell * 1.001 and 0.8 * cell <= height <= cell * 1.001
    assert spec.fov_up_deg >= 10.0 and spec.fov_down_deg <= -20.0
    # Fill of the cells well inside the box, binned as the range image bins them.
    col = np.floor((np.pi - az) / width).astype(int)
    row = np.floor((np.radians(spec.fov_up_deg) - el) / height).astype(int)
    counts = np.zeros((spec.beams, spec.columns), int)
    np.add.at(counts, (row, col), 1)
    c_in = np.arange(int(np.ceil((np.pi - np.radians(38)) / width)), int((np.pi + np.radians(38)) / width))
    r_in = np.arange(int(np.ceil((np.radians(spec.fov_up_deg) - np.radians(8)) / height)),
                     int((np.radians(spec.fov_up_deg) + np.radians(18)) / height))
    inner = counts[np.ix_(r_in, c_in)]
    mean = inner.mean()
    assert 2.5 < mean <= 4.0 * 1.01
    assert abs((inner == 0).mean() - np.exp(-mean)) < 0.02


def test_a_ghost_a_sparse_scan_saw_through_is_removed_on_the_scan_grid_and_kept_on_the_spec_grid():
    # A rosette-like reference scan (directions uniform in a 35 deg cone, 8000 points) sees a wall at
    # 20 m. An older sweep from 1 m behind holds a car's old place: points 8-12 m ahead, where every
    # reference ray went on to the wall. On the rig's 64 x 2048 grid the reference's cells are too
    # sparse for 3 of the 4 bracketing cells to hold a measurement; on its own spacing's grid they do.
    origin_old = np.array([-1.0, 0.0, 0.0])
    ref = _on_wall(_cone_directions(8000, 35.0, 1), np.zeros(3))
    wall_old = _on_wall(_cone_directions(8000, 35.0, 2), origin_old)
    rng = np.random.default_rng(3)
    ghost = np.stack([rng.uniform(8, 12, 600), rng.uniform(-2, 2, 600), rng.uniform(-1.5, 1.5, 600)], 1)
    old = np.concatenate([wall_old, ghost.astype(np.float32)])
    P = 16384
    pts = np.zeros((2, P, 3), np.float32)
    valid = np.zeros((2, P), bool)
    for i, p in enumerate((ref, old)):
        pts[i, :len(p)], valid[i, :len(p)] = p, True
    T = np.stack([np.eye(4), np.eye(4)])
    T[1, :3, 3] = origin_old
    witness = scan_witness_spec(ref, FALLBACK, cell_spacings=2.0)
    free = {}
    for name, wit in (("spec", None), ("scan", (witness, witness))):
        src = make_sources(pts, valid, T, lidars=(FALLBACK, FALLBACK), sweep=(0, -1), witnesses=wit)
        free[name] = np.asarray(_view(src)[0])[1, :len(old)]
    is_ghost = np.arange(len(old)) >= len(wall_old)
    assert free["scan"][is_ghost].mean() > 0.9
    assert free["spec"][is_ghost].mean() < 0.5
    assert not free["scan"][~is_ghost].any(), "the wall is static: never free"


def test_stated_specs_and_laser_rows_keep_their_own_grid():
    # The scan grid is only for sources with neither a stated spec nor laser rows: clouds of spinning
    # LiDARs (stated, or rows from rings) keep exactly their free-space witnesses.
    ring = np.tile(np.arange(16), 200)
    el = np.radians(10.0 - 2.0 * ring)
    az = np.repeat(np.linspace(-np.pi, np.pi, 200, endpoint=False), 16)
    p = (np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1) * 10).astype(np.float32)
    two = np.concatenate([p, p])
    source = np.repeat(np.arange(2, dtype=np.int32), len(p))
    T = np.stack([np.eye(4), np.eye(4)])
    stated = SourceCloud(points=two, source=source, T_ref_source=T, lidars=(FALLBACK, FALLBACK),
                         sweep=np.array([0, -1], np.int32), names=("a", "b"))
    assert cloud_sources(stated, fallback=FALLBACK)[0].witnesses is None
    rings = SourceCloud(points=two, source=source, T_ref_source=T, lidars=(None, None),
                        sweep=np.array([0, -1], np.int32), names=("a", "b"), ring=np.concatenate([ring, ring]))
    src = cloud_sources(rings, fallback=FALLBACK)[0]
    assert src.rows is not None and src.witnesses is None
    bare = SourceCloud(points=two, source=source, T_ref_source=T, lidars=(None, None),
                       sweep=np.array([0, -1], np.int32), names=("a", "b"))
    assert cloud_sources(bare, fallback=FALLBACK, witness_cell_spacings=0.0)[0].witnesses is None
    got = cloud_sources(bare, fallback=FALLBACK, witness_cell_spacings=2.0)[0].witnesses
    assert got == (witness_spec(p, FALLBACK, cell_spacings=2.0),) * 2
    assert got[0] == scan_witness_spec(p, FALLBACK, cell_spacings=2.0) != FALLBACK    # 16 lines on 64 rows


def _cell_centres(spec, rows, cols):
    """(n, 3) points at 10 m on the centres of ``spec``'s cells (row, column) for every pair."""
    h = np.radians(spec.fov_up_deg - spec.fov_down_deg) / spec.beams
    el = np.radians(spec.fov_up_deg) - (np.asarray(rows)[:, None] + 0.5) * h
    az = np.pi - (np.asarray(cols)[None, :] + 0.5) * 2 * np.pi / spec.columns
    el, az = np.broadcast_arrays(el, az)
    return 10.0 * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)


def test_spec_grid_evidence_is_the_binomial_chance_of_3_of_4_measured_cells():
    # Analytic oracle: a block of cells every one measured (f = 1) gives evidence 1; every other
    # column measured (f = 1/2) gives P(>= 3 of 4) = (4 + 1) / 16; one in four 4 f^3 (1 - f) + f^4.
    spec = LidarSpec(beams=32, fov_up_deg=10.0, fov_down_deg=-22.0, columns=1024)
    rows = np.arange(4, 20)
    full = _cell_centres(spec, rows, np.arange(100, 200))
    half = _cell_centres(spec, rows, np.arange(100, 200, 2))
    assert spec_grid_evidence(full, spec) == 1.0
    assert abs(spec_grid_evidence(half, spec) - 5 / 16) < 0.01
    f = 0.25
    quarter = _cell_centres(spec, rows, np.arange(100, 200, 4))
    assert abs(spec_grid_evidence(quarter, spec) - (4 * f ** 3 * (1 - f) + f ** 4)) < 0.01
    assert abs(spec_grid_evidence(half, spec, min_cells=2) - 11 / 16) < 0.01
    # A full grid keeps the spec as witness; a half-filled one (evidence 5/16 < 1/2) takes the scan's.
    assert witness_spec(full, spec, cell_spacings=2.0) == spec
    assert witness_spec(half, spec, cell_spacings=2.0) == scan_witness_spec(half, spec, cell_spacings=2.0) != spec
    assert witness_spec(half, spec, cell_spacings=0.0) == spec
