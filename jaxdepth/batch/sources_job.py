"""Complete a :class:`~jaxdepth.io.sources.SourceCloud` (several LiDARs x sweeps) for a rig's cameras.

The entry point the dataset jobs (Argoverse 2, KITTI raw ``--sweeps``, nuScenes sweeps) and
``complete-rig`` with ``lidars`` / a sweeps JSON call: :func:`complete_cloud`. Host side it
fills in each source's :class:`~jaxdepth.LidarSpec` (the stated one, else an estimate from the
source's own points and rings, its field of view on a 0.25 degree grid, else the rig's), pads every
source to one power-of-two point bucket (so that one compiled program serves every sweep of a LiDAR
model: a VLP-32C's 57,600-cell sweeps all pad to 65,536) and hands
a :class:`~jaxdepth._src.sources.Sources` pytree to the core
(:func:`~jaxdepth._src.sources.complete_sources`).
"""

from __future__ import annotations

import logging

import numpy as np

from jaxdepth._src.config import DEFAULT_CONFIG, SGMConfig
from jaxdepth._src.types import LidarSpec
from jaxdepth.io.sweep_frame import source_points_local, source_spec

log = logging.getLogger("jaxdepth")

#: The smallest padded source: sources are padded to ``max(POINT_BUCKET, bucket_size(largest source))``,
#: a power of two (one compilation per bucket; padding slots are invalid and leave every output unchanged).
POINT_BUCKET = 8192
#: Rows and columns of a scan-matched witness grid (:func:`scan_witness_spec`) are multiples of this, so
#: that sweeps of one unit, whose point counts differ slightly, share one compiled program.
WITNESS_GRID_STEP = 16


def _directions(local):
    """(elevation, azimuth, covered azimuth span) of a source's (n, 3) own-frame points, radians: the span
    is 360 degrees less the widest azimuth gap holding no point."""
    local = np.asarray(local, np.float64)
    local = local[np.all(np.isfinite(local), axis=1) & (np.linalg.norm(local, axis=1) > 0)]
    el = np.arctan2(local[:, 2], np.hypot(local[:, 0], local[:, 1]))
    az = np.arctan2(local[:, 1], local[:, 0])
    ordered = np.sort(az)
    gaps = np.diff(np.concatenate([ordered, ordered[:1] + 2 * np.pi])) if az.size else np.zeros(1)
    return el, az, 2 * np.pi - float(gaps.max())


def spec_grid_evidence(local, spec: LidarSpec, *, min_cells: int = DEFAULT_CONFIG.free_space_min_cells) -> float:
    """The chance that a direction inside a scan's coverage finds free-space evidence on ``spec``'s grid.

    ``local``: (n, 3) the source's points in its own frame, binned into ``spec``'s range image (rows
    evenly by elevation). ``f``, the share of the grid's cells inside the scan's box (its elevations, its
    covered azimuth span) that hold a point; the 2 x 2 cells bracketing a direction then hold at least
    ``min_cells`` measurements with probability ``sum_k C(4, k) f^k (1 - f)^(4 - k)``, ``k >= min_cells``
    (cells taken as independent). A spinning or raster unit's lines fill the rows they run along
    (the raster twin, 64 lines on the rig's 64 x 2048 grid: f = 0.80, 0.82); a rosette's path leaves
    holes between its petals in any one sweep (f = 0.44, 0.23), which other sweeps' points fall into.
    """
    from math import comb
    el, az, span = _directions(local)
    if el.size == 0:
        return 0.0
    up, down = np.radians(spec.fov_up_deg), np.radians(spec.fov_down_deg)
    height, width = (up - down) / spec.beams, 2 * np.pi / spec.columns
    row = np.floor((up - el) / height).astype(np.int64)
    col = np.floor((np.pi - az) / width).astype(np.int64) % spec.columns
    inside = (row >= 0) & (row < spec.beams)
    if not inside.any():
        return 0.0
    occupied = np.unique(row[inside] * spec.columns + col[inside]).size
    rows = row[inside].max() - row[inside].min() + 1
    f = min(1.0, occupied / max(1.0, rows * max(1.0, np.ceil(span / width))))
    return float(sum(comb(4, k) * f ** k * (1 - f) ** (4 - k) for k in range(int(min_cells), 5)))


def scan_witness_spec(local, fallback: LidarSpec, *, cell_spacings: float) -> LidarSpec:
    """The free-space witness grid of a scan without laser rows (raster, rosette): square cells of
    ``cell_spacings`` times the scan's mean angular point spacing.

    ``local``: (n, 3) the source's points in its own LiDAR frame. The spacing is ``sqrt(omega / n)``,
    ``omega`` the solid angle of the directions' box: elevations from the lowest to the highest
    point, azimuths over the covered span (:func:`_directions`). A rosette's 31,000 points in its
    35-degree cone are 0.35 degree apart on average, while the rig's 64 x 2048 spec cuts 1.09 x 0.18
    degree cells, 44 % of those in the cone measured in one sweep: the 2 x 2 cells bracketing a query
    then rarely hold the 3 measurements the free-space test needs. With ``cell_spacings=2`` a cell
    holds 4 points on average, so it is empty with probability about ``exp(-4)`` (2 %) where the scan
    covers. Rows and columns are rounded up to multiples of :data:`WITNESS_GRID_STEP`, the field of
    view to the 0.25 degree grid of estimated specs. Returns ``fallback`` for fewer than 2 points.
    """
    from jaxdepth.io.sweep_frame import on_fov_grid
    el, _, span = _directions(local)
    if el.size < 2:
        return fallback
    omega = max(span, 1e-6) * max(float(np.sin(el.max()) - np.sin(el.min())), 1e-6)
    cell = cell_spacings * float(np.sqrt(omega / el.size))
    up, down = on_fov_grid(np.degrees(el.max() + 0.5 * cell), np.ceil), on_fov_grid(np.degrees(el.min() - 0.5 * cell), np.floor)
    rows = int(np.ceil(np.radians(up - down) / cell / WITNESS_GRID_STEP)) * WITNESS_GRID_STEP
    columns = int(np.ceil(2 * np.pi / cell / WITNESS_GRID_STEP)) * WITNESS_GRID_STEP
    return LidarSpec(beams=rows, fov_up_deg=up, fov_down_deg=down, columns=columns)


def witness_spec(local, spec: LidarSpec, *, cell_spacings: float, min_cells: int = DEFAULT_CONFIG.free_space_min_cells):
    """The free-space witness grid of a source with neither a stated spec nor laser rows: ``spec``'s own
    when a direction in its coverage finds evidence there more often than not
    (:func:`spec_grid_evidence` >= 1/2), else :func:`scan_witness_spec`'s (``cell_spacings`` 0: always ``spec``)."""
    if cell_spacings <= 0 or spec_grid_evidence(local, spec, min_cells=min_cells) >= 0.5:
        return spec
    return scan_witness_spec(local, spec, cell_spacings=cell_spacings)


def cloud_sources(cloud, *, fallback: LidarSpec, bucket: int = POINT_BUCKET,
                  witness_cell_spacings: float = DEFAULT_CONFIG.free_space_witness_cell,
                  min_cells: int = DEFAULT_CONFIG.free_space_min_cells):
    """The :class:`~jaxdepth._src.sources.Sources` pytree of a SourceCloud: each source padded to one bucket,
    the power of two (:func:`jaxdepth.io.bucket_size`) that holds the largest source, at least ``bucket``.

    A source with neither a stated spec nor laser rows (its spec is ``fallback``) judges free space on
    :func:`witness_spec`'s grid (``witness_cell_spacings`` > 0; 0: on ``fallback``'s).

    Returns:
      (sources, index): ``index`` (S, P) int64, the cloud row of each padded slot (-1 for padding).
    """
    from jaxdepth._src.sources import make_sources
    from jaxdepth.io import bucket_size
    S = cloud.num_sources
    counts = np.bincount(cloud.source, minlength=S)
    P = max(int(bucket), bucket_size(int(counts.max())))
    points = np.zeros((S, P, 3), np.float32)
    valid = np.zeros((S, P), bool)
    index = np.full((S, P), -1, np.int64)
    rows = np.full((S, P), -1, np.int32)
    specs, witnesses = [], []
    for s in range(S):
        mine = np.nonzero(cloud.source == s)[0]
        points[s, :mine.size] = cloud.points[mine]
        valid[s, :mine.size] = np.all(np.isfinite(cloud.points[mine]), axis=1)
        index[s, :mine.size] = mine
        spec, rank = source_spec(cloud, s, fallback)
        specs.append(spec)
        witness = spec
        if rank is not None:
            rows[s, :mine.size] = rank
        elif cloud.lidars[s] is None and witness_cell_spacings > 0:
            witness = witness_spec(source_points_local(cloud, s), spec, cell_spacings=witness_cell_spacings,
                                   min_cells=min_cells)
        witnesses.append(witness)
    sources = make_sources(points, valid, cloud.T_ref_source.astype(np.float32), lidars=tuple(specs),
                           sweep=tuple(int(x) for x in cloud.sweep), rows=rows if np.any(rows >= 0) else None,
                           witnesses=tuple(witnesses))
    return sources, index


def _roles(sweep, specs) -> list:
    """Each source's part in the free-space test with ``free_space_neighbour_sweeps = 0``
    (:func:`jaxdepth._src.sources.reference_view`): (``"ref"`` | ``"end"`` | ``"inner"``, spec). The ends
    are the sources of the smallest and largest sweep other than 0."""
    others = [int(w) for w in sweep if w != 0]
    ends = {min(others), max(others)} if others else set()
    return [("ref" if w == 0 else "end" if w in ends else "inner", spec) for w, spec in zip(sweep, specs)]


def fit_to_window(sources, index, window: tuple):
    """``sources`` (and its ``index``) spread over the slots of a fixed sweep ``window``, so that every frame of
    a job compiles one program: ``(sources, index)`` with ``len(window)`` sources, or None when it cannot.

    ``window``: the static sweep numbers of a frame with all its neighbours (the KITTI job: 0, -1, 1, ...;
    nuScenes: 0, -1, -2, ...). A frame at the start or end of a drive / scene holds fewer sources; each of
    them goes, in order, into the next slot of the same part in the free-space test (reference, end sweep
    or inner sweep, see :func:`_roles`) and the same LiDAR spec, and the slots left over get empty sources
    (no valid point, identity pose, the window's spec): an empty source bins nothing, so as a witness it
    judges nothing free, shadowed or hidden, and its points never reach an image. The sources' order is
    kept (the z-buffer's ties go to the earlier point), so the outputs are those of the frame's own
    program (tests/test_sources_window.py). None when the frame's sources do not fit in that order (e.g.
    the KITTI window 0, -1, 1, -2, 2 and a frame holding 0, -1, 1, 2: its end -1 precedes an inner sweep,
    the window's ends are its last two slots), or differ in spec from the window's, or judge free space
    on grids of their own (``sources.witnesses``).
    """
    from jaxdepth._src.sources import make_sources
    window = tuple(int(w) for w in window)
    if sources.count == len(window) and tuple(sources.sweep) == window:
        return sources, index
    if sources.count > len(window) or len(set(sources.lidars)) != 1 or sources.witnesses is not None:
        return None
    spec = sources.lidars[0]
    have = _roles(sources.sweep, sources.lidars)
    slots = _roles(window, (spec,) * len(window))
    placed, k = [], 0
    for role in have:
        while k < len(slots) and slots[k] != role:
            k += 1
        if k == len(slots):
            return None
        placed.append(k)
        k += 1
    S, P = len(window), sources.points.shape[1]
    points = np.zeros((S, P, 3), np.float32)
    valid = np.zeros((S, P), bool)
    T = np.tile(np.eye(4, dtype=np.float32), (S, 1, 1))
    rows = None if sources.rows is None else np.full((S, P), -1, np.int32)
    spread = np.full((S, P), -1, np.int64)
    for i, k in enumerate(placed):
        points[k], valid[k], T[k], spread[k] = sources.points[i], sources.valid[i], sources.T_ref_source[i], index[i]
        if rows is not None:
            rows[k] = sources.rows[i]
    return make_sources(points, valid, T, lidars=(spec,) * S, sweep=window, rows=rows), spread


def _single_origin(cloud) -> bool:
    from jaxdepth._src.rig import at_origin
    return cloud.num_sources == 1 and at_origin(cloud.T_ref_source[0])


def _config_sources(cloud, rig, config: SGMConfig):
    """:func:`cloud_sources` of ``cloud`` as :func:`complete_cloud` builds them (``rig.lidar`` the fallback spec,
    ``config``'s free-space witness grid)."""
    return cloud_sources(cloud, fallback=rig.lidar, witness_cell_spacings=config.free_space_witness_cell,
                         min_cells=config.free_space_min_cells)


def cloud_above_scan(cloud, rig, config: SGMConfig = DEFAULT_CONFIG) -> str:
    """The ``SGMConfig.above_scan`` rule :func:`complete_cloud` (without ``window``) runs for ``cloud``: ``config``'s
    own unless ``"auto"``, which :func:`~jaxdepth._src.above_scan.above_scan_rule` resolves from the same sources
    the program gets (each LiDAR's spec and free-space grid: a LiDAR that states no spec and has no laser rows
    may get a grid of its own points' spacing, a rosette's, so the rule depends on the sweep), or the one
    LiDAR's of a cloud at the reference origin (:func:`~jaxdepth.complete_rig`'s path). Host only, no JAX."""
    from jaxdepth._src.above_scan import above_scan_rule
    if config.above_scan != "auto":
        return config.above_scan
    if _single_origin(cloud):
        return above_scan_rule(config.above_scan, sweep=(0,), lidars=(cloud.lidars[0],))    # complete_rig's path
    sources, _ = _config_sources(cloud, rig, config)
    return above_scan_rule(config.above_scan, sweep=sources.sweep, lidars=sources.lidars, witnesses=sources.witnesses)


def cloud_call(cloud, rig, *, config: SGMConfig = DEFAULT_CONFIG, free_space: bool = True, images=None,
               beams: int | None = None, stages: bool = False, neighbour_sweeps="default", occlusion: bool = True,
               window: tuple | None = None, seen: bool = False):
    """:func:`complete_cloud`'s host work done now, its program call left for later: ``call() -> out``.

    The same arguments as :func:`complete_cloud`. Now: the stacked cameras (from the rig cameras' NumPy K
    and T), the sources pytree (:func:`cloud_sources`, :func:`fit_to_window`) or the padded points: host
    work that waits for no program's result, so that a job runs it on a reader thread while the previous
    sweep's program runs (:func:`jaxdepth.batch.cloud_runner.run_cloud_jobs`). ``call()`` dispatches the
    program (asynchronously) and returns its device arrays: the :class:`~jaxdepth.Stages` with ``stages``,
    else the (C, H_max, W_max) depth (and with ``seen`` the ``(depth, seen)`` pair), which
    :func:`complete_cloud` reads back.
    """
    import functools

    import jaxdepth
    from jaxdepth.batch.program_cache import rig_stages, sources_stages
    if neighbour_sweeps != "default":
        config = config.replace(free_space_neighbour_sweeps=neighbour_sweeps)
    cameras = jaxdepth.stack_cameras(rig.cameras)     # the values RigCamera.as_camera's would hold
    options = dict(config=config, images=images, depth_only=not stages, seen=seen)
    sources = fitted = None
    if (window is not None and free_space and config.free_space_neighbour_sweeps == 0
            and cloud.num_sources <= len(window) and all(spec is not None for spec in cloud.lidars)):
        sources, index = _config_sources(cloud, rig, config)
        fitted = fit_to_window(sources, index, window)
    if fitted is not None:
        sources = fitted[0]
    elif _single_origin(cloud):
        from jaxdepth.io import pad_points
        padded, valid = pad_points(cloud.points)
        spec = cloud.lidars[0] if cloud.lidars[0] is not None else rig.lidar
        return functools.partial(rig_stages, padded, valid, cameras, lidar=spec, **options)
    elif sources is None:         # not built for the window above
        sources, _ = _config_sources(cloud, rig, config)
    return functools.partial(sources_stages, sources, cameras, free_space=free_space, beams=beams,
                             occlusion=occlusion, **options)


def complete_cloud(cloud, rig, *, config: SGMConfig = DEFAULT_CONFIG, free_space: bool = True, images=None,
                   beams: int | None = None, stages: bool = False, neighbour_sweeps="default", occlusion: bool = True,
                   window: tuple | None = None, seen: bool = False):
    """Dense depth for every camera of ``rig`` from every point of ``cloud``.

    Args:
      cloud: :class:`~jaxdepth.io.sources.SourceCloud`, points in the reference frame.
      rig: :class:`~jaxdepth.io.rig.Rig`; ``rig.cameras[i].T_cam_lidar`` maps reference-frame
        points into camera ``i``; ``rig.lidar`` is the fallback spec of sources whose spec is
        neither given nor estimable (and gives the range-image columns of estimated ones).
      config: :class:`SGMConfig`.
      free_space: remove other sweeps' points that lie in space another sweep's LiDARs saw empty.
      images: optional (C, H_max, W_max[, 3]) camera images on the rig's canvas
        (:func:`~jaxdepth.stack_images`), used only when ``config.guidance_weight > 0``.
      beams: L of Step 2's window bounds; default: the reference sweep's LiDARs' beams together.
      stages: return the :class:`~jaxdepth.Stages` (C leading axis) instead of the depth.
      neighbour_sweeps: sweeps on each side whose points a non-reference sweep's LiDARs judge for
        free space (None: every sweep); "default": ``config.free_space_neighbour_sweeps`` (the other
        free-space and occlusion constants are ``config`` fields too).
      occlusion: with ``free_space``, also remove for each camera the other sweeps' points hidden
        from the reference-sweep LiDAR next to it (see :func:`~jaxdepth._src.sources.reference_view`).
      window: optional static sweep numbers of a frame with all its neighbours (a job's ``--sweeps``): a
        cloud of fewer sources is spread over that window with empty sources (:func:`fit_to_window`), so
        every frame of the job runs one compiled program, same outputs; used with ``free_space`` on and
        ``free_space_neighbour_sweeps = 0`` (the default) when every source's spec is stated and the
        sources fit, else ignored.
      seen: without ``stages``, return ``(depth, seen)``: ``seen`` (C,) the pixels of each camera a point
        projects into (:func:`~jaxdepth._src.rig.seen_pixels`), from the same depth program.

    Returns:
      (C, H_max, W_max) float32 NumPy depth, metres, 0 = no depth: camera ``i``'s image in the
      top-left ``rig.cameras[i].height x width`` corner of the canvas, zeros beyond (one array,
      as :func:`~jaxdepth.complete_rig`). A cloud of one source at the reference origin gives
      exactly :func:`~jaxdepth.complete_rig`'s result (with the rig's LiDAR spec).
    """
    out = cloud_call(cloud, rig, config=config, free_space=free_space, images=images, beams=beams, stages=stages,
                     neighbour_sweeps=neighbour_sweeps, occlusion=occlusion, window=window, seen=seen)()
    if stages:
        return out
    return tuple(np.asarray(a) for a in out) if seen else np.asarray(out)


def checked_cloud(cloud, rig, config: SGMConfig = DEFAULT_CONFIG, *, estimate: bool = True):
    """The sweep check of a cloud read from a rig JSON (``complete-rig``, ``hidden-eval``): ``(frame, config)``.

    ``frame``: :func:`jaxdepth.io.sweep_frame.prepare_cloud`'s :class:`~jaxdepth.io.sweep_frame.CloudFrame`
    (complete ``frame.cloud`` with ``frame.rig``); ``config`` with outlier removal off when the check
    does not trust it, as the single-file path (:func:`jaxdepth.io.prepare_sweep`) decides.
    """
    from jaxdepth.io.sweep_frame import prepare_cloud
    frame = prepare_cloud(cloud, rig, estimate=estimate)
    if not frame.outlier_removal_trusted and config.outlier_removal:
        config = config.replace(outlier_removal=False)
    return frame, config


__all__ = ["cloud_above_scan", "cloud_call", "complete_cloud", "checked_cloud", "cloud_sources", "fit_to_window",
           "source_spec", "POINT_BUCKET", "WITNESS_GRID_STEP", "scan_witness_spec", "spec_grid_evidence",
           "witness_spec"]
