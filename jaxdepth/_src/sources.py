"""Points from several origins (LiDARs x sweeps): Steps 1 and 2 per source, free space across sweeps.

A *source* is one LiDAR of a rig in one sweep. :class:`Sources` holds every
source's points, padded to one point bucket ``P``, in the *reference frame*
(the points' frame of the reference sweep, the frame every camera's
``T_cam_lidar`` maps from), and each source's LiDAR pose ``T_ref_source``.

* Step 1 per source (:func:`source_normals`): each source's points go back into
  its own LiDAR frame (``inv(T_ref_source[s])``), are binned into that LiDAR's own
  range image (its :class:`~jaxdepth.LidarSpec`) and get their Badino normals
  there; the normals are rotated back into the reference frame. Sources that
  share a LidarSpec are vmapped together (one static range-image shape per group).
* Free space (:func:`free_space_keep`): a point of an earlier sweep that lies where a
  LiDAR of the reference sweep or of the window's end sweeps saw empty space is removed
  (a moving object's ghost, or a registration error); for each camera, a point of an earlier
  sweep that the reference-sweep LiDAR next to the camera saw covered on all sides by a nearer
  surface is removed too (occlusion). See :func:`reference_view`, :func:`camera_witness`.
* Step 2 per source (:func:`source_keep_mask`): Algorithm 1 on the camera's
  z-buffer of all sources' points, where each pixel's point is tested with *its
  own source's* origin as the viewpoint compared with the camera's; every
  pixel, whatever its source, is a neighbour ``j``. One pass over the image for
  all sources: each candidate carries its own origin. For a scan without scan lines
  (``SGMConfig.outlier_sweeps``, :func:`per_sweep_applies`) each sweep is also judged
  alone against the reference sweep with one sweep's window (:func:`sweep_keep_mask`).
* Above the reference sweep's top scan line (``SGMConfig.reference_top_line``; by default for one
  reference-sweep scan that fills its range-image rows, :func:`top_line_applies`):
  in each camera, the kept pixels of other sweeps' points above the reference sweep's kept top
  scan line and nearer than its top pixels by more than epsilon are no seeds
  (:func:`~jaxdepth._src.above_scan.top_line_keep`).
* Steps 3 and 4 are the single-source ones on the merged, filtered image (``above_scan``: :func:`above_scan_rule`).

As the rig's (:func:`~jaxdepth._src.rig.run_rig_stages`), the pipeline is written as three stages
(:func:`run_sources_stages`): :func:`sources_stage_projection` (Step 1 per source, free space, occlusion, each
camera's z-buffer), :func:`sources_stage_keep` (Step 2, the top-line rule), :func:`sources_stage_tail` (Steps 3-4).

One source at the points' origin: :func:`complete_sources` runs ``complete_rig``'s program (``rig.one_sweep_call``).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.above_scan import resolved_config, top_line_keep
from jaxdepth._src.config import DEFAULT_CONFIG, SGMConfig
from jaxdepth._src.geometry import invert_rigid, transform_points
from jaxdepth._src.normals import point_normals
from jaxdepth._src.outliers import _keep_mask, window_half_sizes
from jaxdepth._src.pipeline import project_winners, winners_apart
from jaxdepth._src.range_image import angles_xyz, range_image_and_slots, row_col
from jaxdepth._src.rig import (CameraView, RigCameras, call_stage, camera_tails, check_images, depth_output,
                              keep_by_size, map_by_size_shared, one_sweep_call, rig_depth_program, rig_program)
from jaxdepth._src.types import LidarSpec, Stages
from jaxdepth._src.xla_tuning import entry_jit, small_matmul

# The multi-source constants are SGMConfig fields (recorded in run records, settable from the CLI);
# these names keep their defaults for the functions that take them one by one.
#: Range noise and registration error allowed for before a point counts as being in free space, metres.
FREE_SPACE_NOISE_M = DEFAULT_CONFIG.free_space_noise_m
#: Surface slope allowance of the free-space margin (:func:`free_space_margin`).
FREE_SPACE_SLOPE = DEFAULT_CONFIG.free_space_slope
#: Measured cells (of the 2 x 2 whose rays bracket a point) needed before a LiDAR's view there counts.
FREE_SPACE_MIN_CELLS = DEFAULT_CONFIG.free_space_min_cells
#: Sweeps on each side whose points a LiDAR of a sweep other than the reference and end sweeps judges
#: for free space (None: every other sweep, a cost quadratic in the sweeps). 0: none (measured: the
#: end sweeps' witnesses already give what the neighbours add).
NEIGHBOUR_SWEEPS = DEFAULT_CONFIG.free_space_neighbour_sweeps
#: Largest distance from a camera to the reference-sweep LiDAR whose view stands in for the camera's in
#: the occlusion test of other sweeps' points (:func:`camera_witness`), metres; a LiDAR farther away
#: sees around near objects differently from the camera, and the test is then skipped for that camera.
OCCLUSION_MAX_BASELINE_M = DEFAULT_CONFIG.occlusion_max_baseline_m


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Sources:
    """S sources' points in one reference frame, padded to P points each (a pytree).

    Attributes:
      points: (S, P, 3) float32 metres, reference frame.
      valid: (S, P) bool; padding rows are False.
      T_ref_source: (S, 4, 4) float32 pose of each source's LiDAR in the reference frame
        (``p_source = inv(T_ref_source[s]) @ p_ref``).
      lidars: static tuple of S :class:`LidarSpec`, each source's own scan geometry.
      sweep: static tuple of S ints, each source's sweep; 0 is the reference sweep.
      rows: optional (S, P) int32 range-image row of each point in its own LiDAR's range
        image: its laser's rank by elevation (0 = highest), for LiDARs whose beams are not
        evenly spaced (the VLP-32C); -1 or None: the row of the point's elevation.
      witnesses: optional static tuple of S :class:`LidarSpec`, the range-image grid each source
        bins its points into when it judges other sweeps' points for free space and occlusion
        (:func:`reference_view`); None: ``lidars``. For a scan without laser rows whose spec is
        not stated (a raster or rosette unit), a grid matched to its own point spacing
        (:func:`jaxdepth.batch.sources_job.scan_witness_spec`).
    """

    points: jax.Array
    valid: jax.Array
    T_ref_source: jax.Array
    lidars: tuple = dataclasses.field(metadata=dict(static=True))
    sweep: tuple = dataclasses.field(metadata=dict(static=True))
    rows: jax.Array | None = None
    witnesses: tuple | None = dataclasses.field(default=None, metadata=dict(static=True))

    @property
    def count(self) -> int:
        return len(self.lidars)


def make_sources(points, valid, T_ref_source, *, lidars, sweep=None, rows=None, witnesses=None) -> Sources:
    """Checks shapes and builds :class:`Sources` (``sweep`` defaults to all 0: one sweep, several LiDARs)."""
    points = jnp.asarray(points, jnp.float32)
    valid = jnp.asarray(valid, bool)
    T = jnp.asarray(T_ref_source, jnp.float32)
    lidars = tuple(lidars)
    if points.ndim != 3 or points.shape[2] != 3:
        raise ValueError(f"Sources: field 'points' expected shape (S, P, 3), got {points.shape}")
    s, p = points.shape[:2]
    if valid.shape != (s, p):
        raise ValueError(f"Sources: field 'valid' expected shape {(s, p)}, got {valid.shape}")
    if T.shape != (s, 4, 4):
        raise ValueError(f"Sources: field 'T_ref_source' expected shape {(s, 4, 4)}, got {T.shape}")
    if len(lidars) != s or not all(isinstance(x, LidarSpec) for x in lidars):
        raise ValueError(f"Sources: field 'lidars' expected {s} LidarSpec, got {lidars!r}")
    sweep = (0,) * s if sweep is None else tuple(int(x) for x in sweep)
    if len(sweep) != s:
        raise ValueError(f"Sources: field 'sweep' expected {s} ints, got {sweep!r}")
    if rows is not None:
        rows = jnp.asarray(rows, jnp.int32)
        if rows.shape != (s, p):
            raise ValueError(f"Sources: field 'rows' expected shape {(s, p)}, got {rows.shape}")
    if witnesses is not None:
        witnesses = tuple(witnesses)
        if len(witnesses) != s or not all(isinstance(x, LidarSpec) for x in witnesses):
            raise ValueError(f"Sources: field 'witnesses' expected {s} LidarSpec, got {witnesses!r}")
        if witnesses == lidars:
            witnesses = None
    return Sources(points=points, valid=valid, T_ref_source=T, lidars=lidars, sweep=sweep, rows=rows,
                   witnesses=witnesses)


def _spec_groups(lidars) -> list[tuple[LidarSpec, np.ndarray]]:
    """Static groups of source indices sharing one LidarSpec, in order of first appearance."""
    groups: dict = {}
    for i, spec in enumerate(lidars):
        groups.setdefault(spec, []).append(i)
    return [(spec, np.asarray(idx, np.int32)) for spec, idx in groups.items()]


def _to_source_frames(T_ref_source, points):
    """(G, P, 3) reference-frame points -> each source's own LiDAR frame."""
    return jax.vmap(lambda T, p: transform_points(invert_rigid(T), p))(T_ref_source, points)


def source_normals(sources: Sources, *, smoothing: int = DEFAULT_CONFIG.normal_smoothing,
                   fill_max_gap: int = DEFAULT_CONFIG.range_fill_max_gap) -> jax.Array:
    """Step 1 per source: (S, P, 3) float32 unit normals, reference frame (zeros for invalid points).

    Each source's normals come from its own range image about its own origin and
    axes (:func:`~jaxdepth.point_normals` of its points in its LiDAR frame, with
    its LidarSpec), rotated back into the reference frame; they face that
    source's LiDAR (``n . (p - origin_s) <= 0``).
    """
    out = jnp.zeros(sources.points.shape, jnp.float32)
    for spec, idx in _spec_groups(sources.lidars):
        T = sources.T_ref_source[idx]
        local = _to_source_frames(T, sources.points[idx])
        normals = functools.partial(point_normals, lidar=spec, smoothing=smoothing, fill_max_gap=fill_max_gap)
        if sources.rows is None:
            n = jax.vmap(normals)(local, sources.valid[idx])
        else:
            n = jax.vmap(lambda p, v, r: normals(p, v, rows=r))(local, sources.valid[idx], sources.rows[idx])
        out = out.at[idx].set(small_matmul(n, jnp.swapaxes(T[:, :3, :3], 1, 2)))     # each n @ R.T
    return out


def free_space_margin(range_m, lidar: LidarSpec, *, noise_m: float = FREE_SPACE_NOISE_M,
                      slope: float = FREE_SPACE_SLOPE, gap_rad=None):
    """The free-space margin at ``range_m`` metres for a LiDAR of range-image geometry ``lidar``.

    ``noise_m + slope * range_m * delta``, ``delta`` (radians) the larger of the vertical gap
    between the LiDAR's neighbouring lasers where the point lies and the horizontal step
    ``2 pi / columns``. ``gap_rad`` (broadcasting with ``range_m``) is that vertical gap, measured
    from the lasers' own elevations (:func:`reference_view` takes it from the witness's range image:
    one row per laser with ring indices); None: a uniform ``(fov_up - fov_down) / beams``. A surface
    at 45 degrees to the ray changes range by ``range * delta`` between two neighbouring beams;
    ``noise_m`` covers range noise and pose (registration) error.
    """
    horizontal = 2 * math.pi / lidar.columns
    if gap_rad is None:
        delta = max(math.radians(lidar.fov_up_deg - lidar.fov_down_deg) / lidar.beams, horizontal)
    else:
        delta = jnp.maximum(gap_rad, horizontal)
    return noise_m + slope * delta * range_m


def reference_view(sources: Sources, *, noise_m: float = FREE_SPACE_NOISE_M, slope: float = FREE_SPACE_SLOPE,
                   min_cells: int = FREE_SPACE_MIN_CELLS, neighbour_sweeps: int | None = NEIGHBOUR_SWEEPS,
                   end_sweeps: bool = True):
    """Where the rig's LiDARs place each point of another sweep: ``(free, shadow, hidden)``.

    ``free``, ``shadow``: (S, P) bool; ``hidden``: (R, S, P) bool, one layer per reference-sweep
    source (``sweep == 0``, in source order; R of them).

    Witnesses (sweep numbers in time order, as the readers give them): every LiDAR of the
    reference sweep (``sweep == 0``) and, with ``end_sweeps``, of the first and last of the other
    sweeps (the two ends of the window) judges the points of every other sweep; every LiDAR of
    another sweep ``w`` judges the points of the sweeps ``v`` with ``0 < |v - w| <=
    neighbour_sweeps``, or of every other sweep with ``neighbour_sweeps=None`` (every sweep a
    witness of every other: cost quadratic in the number of sweeps). With ``neighbour_sweeps`` an
    int each point meets a bounded number of witnesses, so the cost is linear in the sweeps.
    The ends are there because an object that moved is best seen gone by the sweep farthest in
    time from the one that saw it, and for every sweep that is one of the window's ends (or the
    reference). ``neighbour_sweeps=0, end_sweeps=False``: the reference sweep's witnesses alone.
    A witness ``r`` bins its own points into its own range
    image (its LidarSpec, about its own origin and axes). A point ``q`` of another sweep than
    ``r``'s, seen from ``r``'s origin, falls in a cell; the rays bracketing ``q``'s direction are
    those of the 2 x 2 cells made of its own cell, the neighbouring row on the side of ``q``'s
    elevation and the neighbouring column on the side of its azimuth. ``R_lo`` is the nearest
    range among them.

    * ``free`` (needs at least ``min_cells`` of those 4 cells measured, else no evidence):
      ``|q - origin_r| < R_lo - margin(R_lo)``: every ray around ``q`` travelled past it and hit
      nothing there, so ``q`` sits in space ``r`` saw empty: an object that moved (its ghost, or
      an object that has not yet arrived) or a registration error. Taking the nearest bracketing
      range keeps surfaces between rays (a slanted road; a pole between two scan lines, whose
      range is then ``R_lo``). A ray farther from ``q`` than the bracketing ones is no witness of
      the space at ``q`` (the road two scan lines below a car's bumper).
    * ``shadow`` (reference-sweep witnesses only; needs ``q``'s own cell measured, range ``R``):
      ``|q - origin_r| > R + margin(R)``: the reference LiDAR's ray through ``q``'s cell stopped
      in front of it, ``q`` is hidden from the reference LiDAR. Step 2 then also removes it when
      the camera sees a nearer pixel next to it (:func:`source_keep_mask`).
    * ``hidden[k]`` (the ``k``-th reference-sweep LiDAR as witness; ``min_cells`` of the 4 cells
      measured): ``|q - origin_r| > R_hi + margin(R_hi)``, ``R_hi`` the farthest range measured
      among the bracketing cells: every ray around ``q`` stopped in front of it, so a surface
      covers ``q`` on all sides as seen from that LiDAR (not only its edge: at a silhouette one
      bracketing ray passes the edge and ``R_hi`` is the background's). For a camera next to that
      LiDAR (:func:`camera_witness`) ``q`` is hidden too: a point an earlier origin 1.5-6 m
      behind saw around a near object.

    ``margin(R)`` is :func:`free_space_margin`. Points of the reference sweep get no
    flag; points outside ``r``'s vertical field of view neither. Shapes are static: each
    witness gathers the sources it judges by a static index array (padded with masked slots),
    the witnesses are vmapped, and their verdicts are OR-ed back onto the sources.
    """
    s, p = sources.points.shape[:2]
    sweep = np.asarray(sources.sweep)
    tested = jnp.asarray(np.repeat(sweep, p) != 0)
    free = jnp.zeros((s, p), bool)
    shadow = jnp.zeros((s, p), bool)
    n_ref = int(np.sum(sweep == 0))
    hidden = jnp.zeros((n_ref, s, p), bool)
    if neighbour_sweeps is not None and int(neighbour_sweeps) < 0:
        raise ValueError(f"reference_view: field 'neighbour_sweeps' expected None or >= 0, got {neighbour_sweeps!r}")
    others = sweep[sweep != 0]
    wide = {0} | ({int(others.min()), int(others.max())} if end_sweeps and others.size else set())
    for spec, idx in _spec_groups(sources.lidars if sources.witnesses is None else sources.witnesses):
        judge = functools.partial(_witness_verdicts, spec=spec, noise_m=noise_m, slope=slope, min_cells=min_cells)
        # The reference and end sweeps' witnesses judge the points of every other sweep (the reference's
        # alone judge shadow); each other witness those of its neighbouring sweeps. Sweep 0's points
        # are never judged, so never gathered.
        wide_w = [i for i in idx if sweep[i] in wide]
        near_w = [i for i in idx if sweep[i] not in wide] if neighbour_sweeps != 0 else []
        for wit, reach in ((wide_w, None), (near_w, neighbour_sweeps)):
            near = [np.flatnonzero((sweep != 0) & (sweep != sweep[w]) &
                                   (True if reach is None else np.abs(sweep - sweep[w]) <= reach)) for w in wit]
            wit, near = [w for w, n in zip(wit, near) if n.size], [n for n in near if n.size]
            if not wit:            # e.g. the end sweep of two sweeps: nothing of another tested sweep to judge
                continue
            f, h, d = _gathered_verdicts(judge, sources, np.asarray(wit, np.int32), near)
            free = free | f
            shadow = shadow | (h if reach is None else False)
            hidden = hidden | (d if reach is None else False)
    tested = tested.reshape(s, p)
    return free & tested, shadow & tested, hidden & tested[None]


def _gathered_verdicts(judge, sources, wit, near):
    """``(free, shadow)`` (S, P) bool and ``hidden`` (R, S, P) of witnesses ``wit`` (static source
    indices), witness ``k`` judging the points of the sources ``near[k]`` (static), OR-ed over
    witnesses; ``shadow`` only from reference-sweep witnesses, ``hidden`` by reference witness. Each witness's query sources are gathered by one static index
    array padded to the longest; the witnesses are vmapped; the verdicts are scattered back with
    padded slots (and, for ``shadow``, other sweeps' witnesses) sent to a dropped row ``S``."""
    s, p = sources.points.shape[:2]
    m = max(len(n) for n in near)
    query = np.full((wit.size, m), s, np.int32)           # padded slots: row S, dropped
    for k, n in enumerate(near):
        query[k, :len(n)] = n
    q_points = sources.points[np.minimum(query, s - 1)].reshape(wit.size, m * p, 3)
    rows = () if sources.rows is None else (sources.rows[wit],)
    f, h, d = jax.vmap(judge)(sources.T_ref_source[wit], sources.points[wit], sources.valid[wit], q_points, *rows)
    sweep = np.asarray(sources.sweep)
    to_shadow = np.where((sweep[wit] == 0)[:, None], query, s)
    n_ref = int(np.sum(sweep == 0))
    slot = np.where(sweep[wit] == 0, np.cumsum(sweep == 0)[wit] - 1, n_ref)     # rank among reference sources
    zero = jnp.zeros((s + 1, p), bool)
    return (zero.at[query].max(f.reshape(wit.size, m, p))[:s],
            zero.at[to_shadow].max(h.reshape(wit.size, m, p))[:s],
            jnp.zeros((n_ref + 1, s + 1, p), bool).at[slot[:, None], query].max(d.reshape(wit.size, m, p))[:n_ref, :s])


def _witness_verdicts(T_r, points_r, valid_r, q, *rows_r, spec, noise_m, slope, min_cells):
    """One witness LiDAR (pose ``T_r``, its own (P, 3) reference-frame points) on (Q, 3) query
    points: ``(free, shadow, hidden)``, (Q,) bool, as :func:`reference_view` defines them."""
    ri, _ = range_image_and_slots(transform_points(invert_rigid(T_r), points_r), valid_r, spec, *rows_r)
    q = transform_points(invert_rigid(T_r), q)
    rq, th, ph, ok = angles_xyz(q[:, 0], q[:, 1], q[:, 2], jnp.ones(q.shape[:1], bool))
    half = 0.5 * (spec.fov_up_rad - spec.fov_down_rad) / spec.beams
    inside = ok & (ph <= spec.fov_up_rad + half) & (ph >= spec.fov_down_rad - half)
    if rows_r:     # rows by laser rank: the query's row is that of the laser nearest in elevation
        row = _row_of_elevation(ri, ph)
        _, col = row_col(th, ph, spec)
    else:
        row, col = row_col(th, ph, spec)
    r_lo, r_hi, n_cells, gap = _bracket_2x2(ri, row, col, th, ph, spec)
    enough = inside & (n_cells >= min_cells)
    r_own = ri.r[row, col]
    margin = functools.partial(free_space_margin, lidar=spec, noise_m=noise_m, slope=slope, gap_rad=gap)
    return (enough & (rq < r_lo - margin(r_lo)),
            inside & (r_own > 0) & (rq > r_own + margin(r_own)),
            enough & (rq > r_hi + margin(r_hi)))


def _bracket_2x2(ri, row, col, theta, phi, spec):
    """Nearest and farthest measured range (inf and 0 where none), count of measured cells among the 2 x 2 cells
    whose rays bracket each query direction, and the vertical gap between the two bracketing rows, radians:
    its own cell ``(row, col)``, the row on the side of
    its elevation (judged by the row's mean measured elevation, else its centre) and the column on
    the side of its azimuth. Rows beyond the image count as unmeasured; columns wrap around. The gap is
    the difference of the two rows' mean measured elevations (rows by laser: the real gap between the
    two lasers), at the image's edge that to the row on the other side, the row height where either row
    holds no measurement."""
    n_rows, n_cols = ri.r.shape
    has = ri.r > 0
    count = jnp.sum(has, axis=1)
    mean = jnp.sum(jnp.where(has, ri.phi, 0.0), axis=1) / jnp.maximum(count, 1)
    centre = spec.fov_up_rad - (jnp.arange(n_rows, dtype=jnp.float32) + 0.5) * (
        (spec.fov_up_rad - spec.fov_down_rad) / n_rows)
    mean = jnp.where(count > 0, mean, centre)
    row2 = jnp.where(phi > mean[row], row - 1, row + 1)
    row_ok = (row2 >= 0) & (row2 < n_rows)
    other = jnp.clip(jnp.where(row_ok, row2, 2 * row - row2), 0, n_rows - 1)   # the gap's second row
    row2 = jnp.clip(row2, 0, n_rows - 1)
    measured = (count[row] > 0) & (count[other] > 0) & (other != row)
    gap = jnp.where(measured, jnp.abs(mean[row] - mean[other]), (spec.fov_up_rad - spec.fov_down_rad) / n_rows)
    col_f = (jnp.pi - theta) * (n_cols / (2 * jnp.pi)) - col
    col2 = jnp.where(col_f < 0.5, col - 1, col + 1) % n_cols
    r = jnp.where(has, ri.r, jnp.inf)
    cells = (r[row, col], r[row, col2], jnp.where(row_ok, r[row2, col], jnp.inf),
             jnp.where(row_ok, r[row2, col2], jnp.inf))
    lo = functools.reduce(jnp.minimum, cells)
    hi = functools.reduce(jnp.maximum, [jnp.where(jnp.isfinite(c), c, 0.0) for c in cells])
    n = sum(jnp.isfinite(c).astype(jnp.int32) for c in cells)
    return lo, hi, n, gap


def _row_of_elevation(ri, phi):
    """Row of each elevation in a range image whose rows are lasers (ranked by elevation, 0 = highest):
    the row whose median measured elevation is nearest (empty rows never chosen)."""
    has = ri.r > 0
    count = jnp.sum(has, axis=1)
    mean = jnp.sum(jnp.where(has, ri.phi, 0.0), axis=1) / jnp.maximum(count, 1)
    mean = jnp.where(count > 0, mean, jnp.inf)
    return jnp.argmin(jnp.abs(phi[:, None] - mean[None, :]), axis=1).astype(jnp.int32)


def free_space_keep(sources: Sources, **options) -> jax.Array:
    """(S, P) bool: ``valid`` without the points of earlier sweeps that lie in space another sweep
    saw empty (``free`` of :func:`reference_view`; options as there)."""
    free, _, _ = reference_view(sources, **options)
    return sources.valid & ~free


def source_keep_mask(sparse_depth, pixel_source, points_cam, K, T_cam_sources, *, beams: int,
                     config: SGMConfig = DEFAULT_CONFIG, pixel_shadow=None, image_size=None,
                     source_sweep=None, all_sweep=None, defer=False) -> jax.Array:
    """Step 2 per source: (H, W) bool keep mask of a camera image holding several sources' points.

    Args:
      sparse_depth: (H, W) float32 z-buffer of all sources' points (0 = empty).
      pixel_source: (H, W) int8 or int32 source of each pixel's point (any value where empty).
      points_cam: (3, H, W) float32 camera-frame coordinates of each pixel's point (or three (H, W) channels).
      K: (3, 3). T_cam_sources: (S, 4, 4) pose of each source's LiDAR in the camera frame
        (only the translations, the LiDARs' origins, are used).
      beams: static L of the window bounds (H / L, W L / N): the beams of one sweep of the rig.
      config: static; ``outlier_removal``, ``epsilon_m``, window caps and ``outlier_test`` apply.
      pixel_shadow: optional (H, W) bool: pixels whose point lies in a reference LiDAR's
        shadow (:func:`reference_view`); such a point is also removed when a pixel of its
        window S(i) is nearer by more than epsilon (condition 2 alone: the reference
        LiDAR saw something in front of it, and so, next to it, does the camera).
      image_size: optional traced (2,) int32 (h, w): the image is the top-left window of a
        rig's canvas; the window bounds are the image's own (as :func:`~jaxdepth.outlier_keep_mask`).
      source_sweep: optional static tuple of S ints, each source's sweep (0 = reference): given, with
        several sweeps, each sweep's pixels are also judged as on the one-sweep path
        (:func:`sweep_keep_mask`; :func:`per_sweep_applies` decides when, from ``config.outlier_sweeps``).
      all_sweep: optional static tuple of S ints, each source's sweep (0 = reference), for
        ``config.older_sweeps_test="paper"``: with several sweeps, the older sweeps' pixels are also judged by
        the paper form of condition 1 (same window, origins and epsilon; the reference sweep's are not).
      defer: static; True (one sweep only): the pass's phases 1-2 (``outliers.KeepParts``, for ``rig.keep_by_size``).

    Algorithm 1 tests each pixel's point with that point's own source origin as the
    viewpoint compared with the camera's; every pixel of the image is a possible occluder
    ``j``. All sources share one pass over the image (each candidate carries its origin),
    which gives the same mask as one pass per source at about the cost of one.
    """
    valid = (sparse_depth > 0) & jnp.isfinite(sparse_depth)
    if not config.outlier_removal:
        return valid
    height, width = sparse_depth.shape
    hw, hh = window_half_sizes(height, width, beams=int(beams), max_half_width_px=config.outlier_max_half_width_px,
                               max_half_height_px=config.outlier_max_half_height_px)
    eps = jnp.asarray(config.epsilon_m, jnp.float32)
    n_src = T_cam_sources.shape[0]
    safe = jnp.clip(pixel_source, 0, n_src - 1)
    origins = T_cam_sources[:, :3, 3]       # (S, 3): pixel i's origin is origins[safe[i]], read where used
    nearer = None if pixel_shadow is None else valid & pixel_shadow
    keep = _keep_mask(  # within ``valid`` already; the source clipped where read (``origins_of``)
        sparse_depth, K, T_cam_sources[0], points_cam, eps, beams=int(beams), half_width=hw, half_height=hh, defer=defer,
        test=config.outlier_test, origins=origins, nearer=nearer, image_size=image_size, pixel_source=pixel_source)
    if (config.older_sweeps_test == "paper" and config.outlier_test != "paper" and all_sweep is not None
            and len(set(all_sweep)) > 1):      # older sweeps' points: the paper form too
        older = valid & (jnp.asarray(np.asarray(all_sweep, np.int32))[safe] != 0)
        keep = keep & _keep_mask(sparse_depth, K, T_cam_sources[0], points_cam, eps, older, beams=int(beams),
                                 half_width=hw, half_height=hh, test="paper", origins=origins, image_size=image_size,
                                 pixel_source=safe)
    if source_sweep is None or len(set(source_sweep)) < 2:
        return keep
    pixel_sweep = jnp.asarray(np.asarray(source_sweep, np.int32))[safe]
    return keep & sweep_keep_mask(sparse_depth, valid & (pixel_sweep == 0), pixel_sweep, points_cam, K, origins,
                                  sweeps=tuple(sorted(set(source_sweep))), beams=int(beams), half_width=hw,
                                  half_height=hh, config=config, nearer=nearer, image_size=image_size,
                                  pixel_source=safe)


def sweep_keep_mask(sparse_depth, reference, pixel_sweep, points_cam, K, origins, *, sweeps, beams: int,
                    half_width: int, half_height: int, config: SGMConfig = DEFAULT_CONFIG, nearer=None,
                    image_size=None, pixel_source=None) -> jax.Array:
    """Step 2 per sweep (``SGMConfig.outlier_sweeps="each"``): (H, W) bool, False where a sweep's own pass removes.

    Each sweep ``s`` of ``sweeps`` is judged as the one-sweep path judges one sweep: Algorithm 1 on the image of
    the ``reference`` pixels and sweep ``s``'s (the reference sweep: its own pixels alone), removing only sweep
    ``s``'s pixels, with the window of ONE sweep: ``N`` of ``|du| < W L / N`` counts the reference pixels (where
    the image holds none, every pixel), as ``L`` counts one sweep's beams. An older origin's view over a near
    object's top is then tested against the reference sweep's points of that object one point spacing of a
    sweep away (the merged image's ``N`` counts every sweep: its window is ``S`` times narrower, often a single
    column), and an older sweep's ghost, which the merged pass sees as an occluder, removes none of the
    reference sweep's points here.

    Args:
      sparse_depth: (H, W) float32 merged z-buffer (0 = empty). reference: (H, W) bool, the reference sweep's
        pixels. pixel_sweep: (H, W) int32 sweep of each pixel's point. points_cam: (3, H, W) float32 (or three (H, W) channels).
      K: (3, 3). origins: (3, H, W) float32 each pixel's LiDAR origin in the camera frame, or with ``pixel_source``
        the (S, 3) sources' origins.
      sweeps: static tuple of the sweep numbers present. beams, half_width, half_height: static, as
        :func:`source_keep_mask`'s window. config: ``epsilon_m``, ``outlier_test``.
      nearer: optional (H, W) bool, pixels removed by condition 2 alone (rule 4's shadow).
      image_size: optional traced (2,) int32 (h, w), the image on a rig's canvas.
      pixel_source: optional (H, W) int32 in [0, S): ``origins`` is then the (S, 3) table of the sources' origins,
        pixel i's ``origins[pixel_source[i]]`` (``outliers._keep_mask``'s).
    """
    valid = (sparse_depth > 0) & jnp.isfinite(sparse_depth)
    window = jnp.where(jnp.any(reference), reference, valid)
    eps = jnp.asarray(config.epsilon_m, jnp.float32)

    def one_sweep(s):           # one compiled pass, mapped over the sweeps
        mine = valid & (pixel_sweep == s)
        image = jnp.where(reference | mine, sparse_depth, 0.0)
        own = _keep_mask(image, K, jnp.eye(4, dtype=jnp.float32), points_cam, eps, mine, beams=beams,
                         half_width=half_width, half_height=half_height, test=config.outlier_test, origins=origins,
                         nearer=None if nearer is None else nearer & mine, image_size=image_size,
                         window_pixels=window, pixel_source=pixel_source)
        return own | ~mine

    return valid & jnp.all(jax.lax.map(one_sweep, jnp.asarray(sweeps, jnp.int32)), axis=0)


def camera_witness(T_cam_ref, T_ref_source, *, sweep, max_baseline_m: float = OCCLUSION_MAX_BASELINE_M):
    """The reference-sweep LiDAR whose view stands in for a camera's: ``(rank, usable)``.

    Args:
      T_cam_ref: (4, 4) reference frame -> camera. T_ref_source: (S, 4, 4) the sources' LiDAR poses.
      sweep: static tuple of S ints (0 = reference sweep).
      max_baseline_m: static; farther LiDARs are not used.

    Returns:
      rank: int32 scalar, the rank among the reference sweep's sources (``sweep == 0``, in source
      order) of the one whose origin is nearest the camera's centre; usable: bool scalar, that
      distance is at most ``max_baseline_m``.
    """
    ref = np.flatnonzero(np.asarray(sweep) == 0)
    T = jnp.asarray(T_cam_ref, jnp.float32)
    origins = jnp.einsum("ij,rj->ri", T[:3, :3], jnp.asarray(T_ref_source, jnp.float32)[ref, :3, 3]) + T[:3, 3]
    dist = jnp.linalg.norm(origins, axis=1)
    rank = jnp.argmin(dist).astype(jnp.int32)
    return rank, dist[rank] <= max_baseline_m


def top_line_applies(sources: Sources, mode: str = DEFAULT_CONFIG.reference_top_line) -> bool:
    """Whether rule 6 (``SGMConfig.reference_top_line``) runs on ``sources`` (static: from the sweeps and specs).

    Never with one sweep. ``"auto"``: when the reference sweep is one source whose free-space grid is its
    own :class:`LidarSpec` (a spinning LiDAR, or a scan that fills that grid's rows), so that its top row is a
    scan line; not with several reference-sweep LiDARs, nor for a scan too sparse for its spec's grid (a
    rosette: :attr:`Sources.witnesses` gives it a grid of its own point spacing).
    """
    if mode == "off" or all(sw == 0 for sw in sources.sweep):
        return False
    if mode == "on":
        return True
    ref = [i for i, sw in enumerate(sources.sweep) if sw == 0]
    grids = sources.lidars if sources.witnesses is None else sources.witnesses
    return len(ref) == 1 and grids[ref[0]] == sources.lidars[ref[0]]


def per_sweep_applies(sources: Sources, mode: str = DEFAULT_CONFIG.outlier_sweeps) -> bool:
    """Whether Step 2 also judges each sweep alone (``SGMConfig.outlier_sweeps``; static: from the sweeps and specs).

    Never with one sweep. ``"auto"``: when a reference-sweep source is a scan too sparse for its spec's grid (a
    rosette: :attr:`Sources.witnesses` gives it a grid of its own point spacing), whose sweeps fill the image in
    two dimensions; not for LiDARs scanning in lines (spinning, raster), whose sweeps re-sample the same lines.
    """
    if mode == "merged" or all(sw == 0 for sw in sources.sweep):
        return False
    if mode == "each" or sources.witnesses is None:
        return mode == "each"
    return any(sources.witnesses[i] != sources.lidars[i] for i, sw in enumerate(sources.sweep) if sw == 0)


def _camera_view(won, n: int, per_source: int, shadow, *, height, width) -> CameraView:
    """Step 1's projection for one camera from :func:`~jaxdepth._src.pipeline.project_winners` of all sources' ``n``
    points (``per_source`` a source, one after another), with each pixel's source (and its shadow flag).
    The source label is int8 while the sources fit (a quarter of an int32 canvas's bytes to fill and read;
    its readers index with it: the same values), else int32."""
    label = jnp.int8 if n // per_source <= np.iinfo(np.int8).max else jnp.int32
    labels = (((jnp.arange(n, dtype=jnp.int32) // per_source).astype(label), -1),)      # each point's source
    labels += () if shadow is None else ((shadow, False),)
    sparse_depth, points_cam, normals_cam, (pixel_source, *pixel_shadow) = winners_apart(
        won, labels, height=height, width=width)
    return CameraView(sparse_depth, points_cam, normals_cam, pixel_source, pixel_shadow[0] if pixel_shadow else None)


def _camera_keep(view: CameraView, T_ref_source, K, T_cam_ref, keep=None, *, beams, config, image_size=None,
                 reference=None, sweep=None, all_sweep=None, defer=False) -> jax.Array:
    """Step 2 for one camera's :class:`CameraView`: :func:`source_keep_mask` (``defer``: its) or the ``keep`` given,
    then the top-line rule (``reference``: (S,) bool, the reference sweep's sources; None with one sweep)."""
    K = jnp.asarray(K, jnp.float32)
    T = jnp.asarray(T_cam_ref, jnp.float32)
    sparse_depth, pixel_source = view.sparse_depth, view.pixel_source
    T_cam_sources = jnp.einsum("ij,sjk->sik", T, T_ref_source)
    keep = keep if keep is not None else source_keep_mask(
        sparse_depth, pixel_source, view.points_cam, K, T_cam_sources, beams=beams, config=config, defer=defer,
        pixel_shadow=view.pixel_shadow, image_size=image_size, source_sweep=sweep, all_sweep=all_sweep)
    if reference is not None:     # other sweeps' near pixels above the reference sweep's top scan line: no seeds
        own = keep & reference[jnp.maximum(pixel_source, 0)]
        keep = own | (keep & top_line_keep(own, sparse_depth, beams=beams, epsilon_m=config.epsilon_m,
                                           max_half_width_px=config.outlier_max_half_width_px,
                                           image_width=None if image_size is None else image_size[1]))
    return keep


def default_beams(sources: Sources) -> int:
    """L of Step 2's window bounds: the beams of the reference sweep's LiDARs together."""
    return sum(spec.beams for spec, sw in zip(sources.lidars, sources.sweep) if sw == 0) or sources.lidars[0].beams


@functools.partial(entry_jit, static_argnames=("config", "free_space", "occlusion"))
def sources_stage_projection(sources: Sources, cameras: RigCameras, *, config: SGMConfig, free_space: bool,
                             occlusion: bool = True) -> tuple:
    """Stage program 1 of :func:`complete_sources_stages`: Step 1 per source, the free-space and occlusion
    rules, and each camera's projection of all sources.

    Returns: :func:`~jaxdepth._src.rig.map_by_size`'s tuple of :class:`~jaxdepth._src.rig.CameraView`
    (with ``pixel_source``, and ``pixel_shadow`` when free space is tested) per size group.
    """
    s, p = sources.points.shape[:2]
    points = jnp.asarray(sources.points, jnp.float32)
    valid = jnp.asarray(sources.valid, bool) & jnp.all(jnp.isfinite(points), axis=-1)
    points = jnp.where(valid[..., None], points, 0.0)
    sources = dataclasses.replace(sources, points=points, valid=valid)
    normals = source_normals(sources, smoothing=config.normal_smoothing, fill_max_gap=config.range_fill_max_gap)
    shadow = hidden = None
    if free_space and any(sw != 0 for sw in sources.sweep):       # one sweep: nothing to test
        free, shadow, hidden = reference_view(sources, noise_m=config.free_space_noise_m,
                                              slope=config.free_space_slope, min_cells=config.free_space_min_cells,
                                              neighbour_sweeps=config.free_space_neighbour_sweeps)
        valid = valid & ~free
        shadow = shadow.reshape(-1)
        hidden = hidden.reshape(hidden.shape[0], -1) if occlusion else None
    flat_points, flat_valid, flat_normals = points.reshape(-1, 3), valid.reshape(-1), normals.reshape(-1, 3)

    def winners(K, T, size, group_size, *, height, width):      # one vmap of every camera (rig.py)
        cam_valid = flat_valid
        if hidden is not None:       # other sweeps' points hidden from the LiDAR next to this camera
            rank, usable = camera_witness(T, sources.T_ref_source, sweep=sources.sweep,
                                          max_baseline_m=config.occlusion_max_baseline_m)
            cam_valid = cam_valid & ~(hidden[rank] & usable)
        return project_winners(flat_points, cam_valid, flat_normals, jnp.asarray(T, jnp.float32), jnp.asarray(
            K, jnp.float32), height=height, width=width, image_size=size, group_size=group_size)

    def per_camera(K, T, size, image, won, *, height, width):     # one vmap per camera size
        return _camera_view(won, flat_points.shape[0], p, shadow, height=height, width=width)

    return map_by_size_shared(winners, per_camera, cameras)


@functools.partial(entry_jit, static_argnames=("config", "beams"))
def sources_stage_keep(views: tuple, sources: Sources, cameras: RigCameras, *, config: SGMConfig,
                       beams: int) -> tuple:
    """Stage program 2 of :func:`complete_sources_stages`: Step 2 per source (:func:`source_keep_mask`, the
    per-sweep pass, the top-line rule), one (h, w) bool mask per camera, per size group (``views``:
    :func:`sources_stage_projection`'s; ``sources``: its statics and ``T_ref_source`` are used)."""
    reference = None
    if top_line_applies(sources, config.reference_top_line):
        reference = jnp.asarray(np.asarray(sources.sweep) == 0)
    sweep = sources.sweep if per_sweep_applies(sources, config.outlier_sweeps) else None
    T_ref_source = jnp.asarray(sources.T_ref_source, jnp.float32)

    def per_camera(K, T, size, image, view, keep=None, *, height, width, defer=False):
        return _camera_keep(view, T_ref_source, K, T, keep, beams=beams, config=config, image_size=size, defer=defer,
                            reference=reference, sweep=sweep, all_sweep=tuple(int(x) for x in sources.sweep))

    return keep_by_size(per_camera, cameras, views, beams=beams, config=config, shared=len(set(sources.sweep)) == 1)


@functools.partial(entry_jit, static_argnames=("config", "beams"))
def sources_stage_tail(views: tuple, keeps: tuple, cameras: RigCameras, images=None, *, config: SGMConfig,
                       beams: int) -> Stages:
    """Stage program 3 of :func:`complete_sources_stages`: Steps 3-4 on the canvas
    (:func:`~jaxdepth._src.rig.camera_tails`)."""
    return camera_tails(views, keeps, cameras, images, config=config, beams=beams, where="complete_sources")


def run_sources_stages(sources: Sources, cameras: RigCameras, images=None, *, config: SGMConfig, free_space: bool,
                       beams: int, occlusion: bool = True, call=call_stage) -> Stages:
    """:func:`complete_sources_stages` (``beams`` given) as three stage programs called through ``call``:
    :func:`sources_stage_projection`, :func:`sources_stage_keep`, :func:`sources_stage_tail` (the tail's
    ``above_scan`` resolved, :func:`~jaxdepth._src.above_scan.above_scan_rule`; see run_rig_stages)."""
    check_images(images, cameras, config, where="complete_sources")
    views = call(sources_stage_projection, sources, cameras, config=config, free_space=free_space, occlusion=occlusion)
    keeps = call(sources_stage_keep, views, sources, cameras, config=config, beams=beams)
    return call(sources_stage_tail, views, keeps, cameras, images, config=resolved_config(config, sources), beams=beams)


@functools.partial(entry_jit, static_argnames=("config", "free_space", "beams", "occlusion"))
def sources_program(sources: Sources, cameras: RigCameras, images=None, *, config: SGMConfig, free_space: bool,
                    beams: int, occlusion: bool = True) -> Stages:
    """:func:`complete_sources_stages`' program: the stages of :func:`run_sources_stages` in one ``jit``
    (see :func:`~jaxdepth._src.rig.rig_program`)."""
    return run_sources_stages(sources, cameras, images, config=config, free_space=free_space, beams=beams,
                              occlusion=occlusion)


@functools.partial(entry_jit, static_argnames=("config", "free_space", "beams", "occlusion", "seen"))
def sources_depth_program(sources: Sources, cameras: RigCameras, images=None, *, config: SGMConfig,
                          free_space: bool, beams: int, occlusion: bool = True, seen: bool = False):
    """:func:`sources_program`'s ``depth`` alone, or ``(depth, seen)`` (see ``rig_depth_program``)."""
    return depth_output(run_sources_stages(sources, cameras, images, config=config, free_space=free_space,
                                           beams=beams, occlusion=occlusion), seen)


def complete_sources_stages(sources: Sources, cameras: RigCameras, *, config: SGMConfig = DEFAULT_CONFIG,
                            free_space: bool = True, beams: int | None = None,
                            images: jax.Array | None = None, occlusion: bool = True) -> Stages:
    """SGM completion of several sources for C cameras; every :class:`Stages` field gains a leading C axis.

    Args:
      sources: :class:`Sources` (reference-frame points of S sources, their LiDAR poses and specs). cameras:
        :class:`RigCameras`; ``T_cam_lidar`` maps reference-frame points into each camera.
      config: static :class:`SGMConfig`; its ``free_space_*``, ``occlusion_max_baseline_m`` and ``reference_top_line``
        fields set the free-space, occlusion and top-line rules (:func:`reference_view`, :func:`camera_witness`).
      free_space: static; remove earlier sweeps' points in another sweep's free space (:func:`free_space_keep`).
      beams: static L of Step 2's window bounds (default :func:`default_beams`). images: as ``complete_rig``'s.
      occlusion: static; with ``free_space``, also remove for each camera the other sweeps' points hidden from
        the reference-sweep LiDAR next to it (``hidden`` of :func:`reference_view`, :func:`camera_witness`).

    Returns :class:`Stages` with (C, H, W) fields; ``inlier_mask``: the merged image's Step-2 mask. Runs
    :func:`sources_program`; one sweep as ``complete_rig`` takes it: ``rig_program`` (``rig.one_sweep_call``)."""
    one = one_sweep_call(rig_program, sources, cameras, images, config=config, beams=beams)
    if one is not None:
        return one
    beams = default_beams(sources) if beams is None else int(beams)
    return sources_program(sources, cameras, images, config=resolved_config(config, sources),
                           free_space=bool(free_space), beams=beams, occlusion=bool(occlusion))


def complete_sources(sources: Sources, cameras: RigCameras, *, config: SGMConfig = DEFAULT_CONFIG,
                     free_space: bool = True, beams: int | None = None,
                     images: jax.Array | None = None, occlusion: bool = True) -> jax.Array:
    """(C, H, W) float32 dense depth for every camera from several sources; see :func:`complete_sources_stages`
    (:func:`sources_depth_program`; one sweep as ``complete_rig`` takes it: its ``rig_depth_program``)."""
    one = one_sweep_call(rig_depth_program, sources, cameras, images, config=config, beams=beams)
    if one is not None:
        return one
    beams = default_beams(sources) if beams is None else int(beams)
    return sources_depth_program(sources, cameras, images, config=resolved_config(config, sources),
                                 free_space=bool(free_space), beams=beams, occlusion=bool(occlusion))
