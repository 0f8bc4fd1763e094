"""Put a sweep in its LiDAR's own frame before completion (host side, NumPy).

The SGM measures the LiDAR's angles (range image, Badino normals, Algorithm 1's
view from the LiDAR) from the origin of the points' frame. KITTI and nuScenes
sweeps are in the sensor's own frame; many other datasets give sweeps in a
vehicle frame whose origin lies on the ground, 1.5-2 m from the sensor, and
measured from there every angle is wrong.

:func:`prepare_sweep` moves the points so that the sensor sits at the origin
and moves every camera's ``T_cam_lidar`` with them (the cameras see exactly
the same points). Where the sensor sits comes from, in order:

1. the rig (``lidar.origin_m`` in the rig JSON, :attr:`Rig.lidar_origin_m`);
2. otherwise the points' origin, checked against the sweep itself
   (:func:`jaxdepth.io.lidar_estimate.estimate_lidar_geometry`): around its
   own sensor a spinning multi-beam LiDAR's points lie on rings of constant
   elevation. With ring indices the beam count and the vertical field of view
   come from the rings too (used where the rig left them open). When the sweep
   does not look like one spinning LiDAR around the points' origin (a vehicle
   frame, a merged cloud of several sensors, a non-repetitive or raster scan),
   the geometry of Algorithm 1 cannot be trusted and
   :attr:`SweepFrame.outlier_removal_trusted` is False: callers turn outlier
   removal off rather than delete good points, and the note says to state
   ``lidar.origin_m``.

Points farther than any LiDAR measures (:func:`jaxdepth.io.plausibility.far_point_mask`)
get NaN coordinates (a missing return), with a warning. Everything estimated is logged
on ``logging.getLogger("jaxdepth")`` and summarised in :attr:`SweepFrame.notes`.

:func:`prepare_cloud` makes the same decision for a
:class:`~jaxdepth.io.sources.SourceCloud` read from a rig JSON's point file or a sweeps JSON
(``complete-rig``'s multi-source path, ``hidden-eval``), so that one cloud gives one result
whichever way it is passed: one source (one sweep, no ``lidars``) goes through
:func:`prepare_sweep` itself; with several sweeps each sweep's points are checked about their
own origin, an estimated origin moves that source's pose, and one sweep that does not look like
one spinning LiDAR (a merged cloud of several units with no per-unit column) turns outlier
removal off as on the single path. Sources whose LiDAR pose the rig states (``lidars``,
``lidar.origin_m``) are trusted as stated, as :func:`prepare_sweep` trusts a stated origin.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from jaxdepth._src.types import LidarSpec
from jaxdepth.io.plausibility import far_point_mask, report_far_points
from jaxdepth.io.rig import Rig, RigCamera

log = logging.getLogger("jaxdepth")

#: An estimated origin closer than this to the points' origin is taken as the points' origin, metres.
ORIGIN_SNAP_M = 0.05


@dataclasses.dataclass(frozen=True)
class SweepFrame:
    """A sweep moved into its sensor's frame, and the rig that goes with it.

    Attributes:
      points: (N, 3) float32 points, metres, sensor at the origin (NaN rows kept as they were).
      rig: the :class:`Rig` with every ``T_cam_lidar`` composed with the shift and the
        LiDAR spec completed from the estimate where the rig left it open.
      origin_m: (3,) float64 where the sensor sits in the input points' frame.
      origin_source: "rig", "estimate" or "points" (the points' own origin).
      outlier_removal_trusted: False when the sweep does not look like one
        spinning LiDAR and nothing stated its origin.
      notes: human-readable lines of what was stated, estimated and assumed.
    """

    points: np.ndarray
    rig: Rig
    origin_m: np.ndarray
    origin_source: str
    outlier_removal_trusted: bool
    notes: tuple


def shift_rig(rig: Rig, origin_m, lidar: LidarSpec | None = None) -> Rig:
    """``rig`` for points moved by ``-origin_m``: each ``T_cam_lidar`` becomes ``T @ [I | origin]``."""
    origin = np.asarray(origin_m, np.float64).reshape(3)
    shift = np.eye(4)
    shift[:3, 3] = origin
    cameras = tuple(RigCamera(c.name, c.width, c.height, c.K,
                              (np.asarray(c.T_cam_lidar, np.float64) @ shift).astype(np.float32), image=c.image)
                    for c in rig.cameras)
    return Rig(lidar=rig.lidar if lidar is None else lidar, cameras=cameras, lidar_origin_m=None,
               lidar_stated=rig.lidar_stated)


def prepare_sweep(points: np.ndarray, rig: Rig, *, ring: np.ndarray | None = None,
                  estimate: bool = True, drop_far: bool = True) -> SweepFrame:
    """Moves ``points`` (and the rig's extrinsics) so that the LiDAR sits at the origin.

    Args:
      points: (N, >= 3) float points of one sweep, metres, in the frame the
        rig's ``T_cam_lidar`` maps from (extra columns are ignored).
      rig: the :class:`Rig`; ``rig.lidar_origin_m`` (if not None) is used as is.
      ring: optional (N,) beam index per point (e.g. nuScenes' 5th column):
        sharpens the estimate.
      estimate: estimate what the rig leaves open from the sweep (default);
        False keeps the points' origin and the rig's spec.
      drop_far: set points farther than any LiDAR measures to NaN, noted (False: ``--force``).

    Returns:
      :class:`SweepFrame`.
    """
    xyz = np.asarray(points, np.float32)[:, :3]
    notes = []
    far = far_point_mask(xyz) if drop_far else None
    if far is not None and far.any():  # an array from the API; the readers drop these already (io/plausibility.py)
        notes.append(report_far_points("sweep", xyz, far))
        xyz = np.where(far[:, None], np.float32(np.nan), xyz)
    spec = rig.lidar
    trusted = True
    if rig.lidar_origin_m is not None:
        origin = np.asarray(rig.lidar_origin_m, np.float64)
        source = "rig"
        notes.append(f"LiDAR origin stated by the rig: {_fmt(origin)} m")
    elif not estimate:
        origin, source = np.zeros(3), "points"
        notes.append("LiDAR origin assumed at the points' origin (no estimate asked for)")
    else:
        from jaxdepth.io.lidar_estimate import estimate_lidar_geometry
        est = estimate_lidar_geometry(xyz, ring=ring)
        notes.append(f"estimated from the sweep: {est.describe()}")
        if est.spinning:
            origin = np.asarray(est.origin_m, np.float64)
            if np.linalg.norm(origin) < ORIGIN_SNAP_M:
                origin, source = np.zeros(3), "points"
                notes.append("LiDAR origin: the points' origin (the estimate is within "
                             f"{100 * ORIGIN_SNAP_M:.0f} cm of it)")
            else:
                source = "estimate"
                notes.append(f"LiDAR origin estimated at {_fmt(origin)} m in the points' frame")
            spec = _complete_spec(rig, est, notes)
        else:
            origin, source = np.zeros(3), "points"
            trusted = False
            notes.append("the sweep does not look like one spinning LiDAR around the points' origin (a vehicle "
                         "frame, merged sensors or a non-spinning scan): outlier removal is turned off; state "
                         "where the sensor sits with lidar.origin_m in the rig JSON to keep it")
    for line in notes:
        log.info("%s", line)
    moved = xyz if not origin.any() else (xyz.astype(np.float64) - origin).astype(np.float32)
    new_rig = shift_rig(rig, origin, spec) if (origin.any() or spec is not rig.lidar) else rig
    return SweepFrame(points=moved, rig=new_rig, origin_m=origin, origin_source=source,
                      outlier_removal_trusted=trusted, notes=tuple(notes))


@dataclasses.dataclass(frozen=True)
class CloudFrame:
    """A SourceCloud after :func:`prepare_cloud`: the cloud and rig to complete, and the decision.

    Attributes:
      cloud: the :class:`~jaxdepth.io.sources.SourceCloud` (one source: its points moved so that the
        LiDAR sits at the origin, as :attr:`SweepFrame.points`; several: each source's pose moved to
        its estimated origin).
      rig: the :class:`Rig` that goes with it (as :attr:`SweepFrame.rig`).
      outlier_removal_trusted: False when a sweep does not look like one spinning LiDAR about an
        origin nothing stated: callers turn outlier removal off.
      notes: human-readable lines of what was stated, estimated and assumed.
    """

    cloud: object
    rig: Rig
    outlier_removal_trusted: bool
    notes: tuple


def prepare_cloud(cloud, rig: Rig, *, estimate: bool = True) -> CloudFrame:
    """The sweep check of :func:`prepare_sweep` for a SourceCloud read with ``rig`` (module docstring).

    Args:
      cloud: :class:`~jaxdepth.io.sources.SourceCloud` from :func:`jaxdepth.io.sweeps.read_point_file_cloud`
        or :func:`jaxdepth.io.sweeps.read_sweeps_cloud` with ``rig``.
      rig: the :class:`Rig`.
      estimate: as :func:`prepare_sweep`; False keeps every stated or points' origin and trusts it.

    Returns:
      :class:`CloudFrame`. A cloud of one source and a rig without ``lidars`` gives exactly
      :func:`prepare_sweep`'s points, rig and decision (the source's spec is the prepared rig's).
    """
    if rig.lidars:
        return CloudFrame(cloud, rig, True, ("LiDAR poses stated by the rig's lidars",))
    if cloud.num_sources == 1:
        frame = prepare_sweep(cloud.points, rig, ring=cloud.ring, estimate=estimate)
        moved = dataclasses.replace(cloud, points=frame.points, T_ref_source=np.eye(4)[None],
                                    lidars=(frame.rig.lidar,))
        return CloudFrame(moved, frame.rig, frame.outlier_removal_trusted, frame.notes)
    if rig.lidar_origin_m is not None or not estimate:
        where = "stated by the rig" if rig.lidar_origin_m is not None else "assumed at each sweep's points' origin"
        return CloudFrame(cloud, rig, True, (f"LiDAR origin {where}",))
    from jaxdepth.io.lidar_estimate import estimate_lidar_geometry
    poses, notes, trusted = np.array(cloud.T_ref_source, np.float64), [], True
    for s in range(cloud.num_sources):
        mine = cloud.source == s
        T = np.linalg.inv(poses[s])
        local = cloud.points[mine].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        est = estimate_lidar_geometry(local, ring=None if cloud.ring is None else cloud.ring[mine])
        notes.append(f"{cloud.names[s]}: estimated from the sweep: {est.describe()}")
        if not est.spinning:
            trusted = False
        elif np.linalg.norm(est.origin_m) >= ORIGIN_SNAP_M:
            poses[s, :3, 3] += poses[s, :3, :3] @ np.asarray(est.origin_m, np.float64)
            notes.append(f"{cloud.names[s]}: LiDAR origin estimated at {_fmt(est.origin_m)} m in the sweep's frame")
    if not trusted:
        notes.append("a sweep does not look like one spinning LiDAR around its points' origin (a vehicle frame, "
                     "merged sensors or a non-spinning scan): outlier removal is turned off; state where the "
                     "sensor sits with lidar.origin_m (or lidars) in the rig JSON to keep it")
    for line in notes:
        log.info("%s", line)
    return CloudFrame(dataclasses.replace(cloud, T_ref_source=poses), rig, trusted, tuple(notes))


#: Grid of an estimated source's field of view, degrees (:func:`source_spec`): a bound moves outwards
#: to the next multiple, by less than a fifth of any common spinning LiDAR's beam spacing.
FOV_GRID_DEG = 0.25


def on_fov_grid(degrees: float, direction) -> float:
    """``degrees`` moved to a multiple of :data:`FOV_GRID_DEG` by ``direction`` (``np.ceil`` outwards
    for an upper bound, ``np.floor`` for a lower one), so nearby estimates share one program."""
    return float(direction(round(degrees / FOV_GRID_DEG, 6)) * FOV_GRID_DEG)


def source_points_local(cloud, s: int) -> np.ndarray:
    """(n, 3) float64: source ``s``'s points of ``cloud`` in that source's own LiDAR frame, in cloud order."""
    T = np.linalg.inv(cloud.T_ref_source[s])
    return cloud.points[cloud.source == s].astype(np.float64) @ T[:3, :3].T + T[:3, 3]


def source_spec(cloud, s: int, fallback: LidarSpec):
    """Source ``s``'s range-image geometry: ``(LidarSpec, rows)``.

    The stated spec when the cloud gives one (``rows`` None: rows from elevation). Otherwise,
    with ring indices (``cloud.ring``), when the source's points in its own LiDAR frame look like
    one spinning LiDAR (:func:`jaxdepth.io.lidar_estimate.estimate_lidar_geometry`): one row per
    laser, ranked by its median elevation (``rows``: (n_s,) int32, 0 = highest laser; this keeps
    unevenly spaced beams, e.g. the VLP-32C's, one per row), beams = the number of lasers, the
    vertical field of view from the outermost lasers' elevations (half a mean spacing beyond them),
    widened to the next multiple of :data:`FOV_GRID_DEG`, columns from ``fallback``. Otherwise
    ``(fallback, None)``.

    The spec is static in the compiled program, so the grid is what lets one program serve a whole
    log: the raw estimate moves by about 0.01 degree from sweep to sweep (the two shared Argoverse 2
    sweeps), and each distinct value used to compile a program of its own (20 s of CPU per sweep).
    """
    spec = cloud.lidars[s]
    if spec is not None:
        return spec, None
    if cloud.ring is None:
        return fallback, None
    from jaxdepth.io.lidar_estimate import estimate_lidar_geometry, ring_labels, ring_medians
    mine = cloud.source == s
    local = source_points_local(cloud, s)
    ring = cloud.ring[mine]
    est = estimate_lidar_geometry(local, ring=ring)
    if not est.spinning or est.beams is None:
        log.info("%s: %s; using the rig's LiDAR spec", cloud.names[s], est.describe())
        return fallback, None
    el = np.degrees(np.arctan2(local[:, 2], np.hypot(local[:, 0], local[:, 1])))
    lasers, inverse = ring_labels(ring)
    far = np.linalg.norm(local, axis=1) > 2.0
    median = ring_medians(el[far], inverse[far], lasers.size)
    near_only = np.isnan(median)                    # a laser with no point beyond 2 m: the median of all its points
    if near_only.any():
        median[near_only] = ring_medians(el, inverse, lasers.size)[near_only]
    rank = np.empty(lasers.size, np.int32)
    rank[np.argsort(-median, kind="stable")] = np.arange(lasers.size, dtype=np.int32)
    half = 0.5 * (median.max() - median.min()) / max(lasers.size - 1, 1)
    spec = LidarSpec(beams=int(lasers.size), fov_up_deg=on_fov_grid(median.max() + half, np.ceil),
                     fov_down_deg=on_fov_grid(median.min() - half, np.floor), columns=fallback.columns)
    log.info("%s: %s", cloud.names[s], est.describe())
    return spec, rank[inverse]


def _complete_spec(rig: Rig, est, notes: list) -> LidarSpec:
    spec = rig.lidar
    if est.beams is not None and "beams" in rig.lidar_stated and est.beams != spec.beams:
        notes.append(f"the rig states {spec.beams} beams, the sweep shows {est.beams}: keeping the rig's")
    if est.fov_up_deg is None or est.fov_down_deg is None:
        return spec
    if "fov_up_deg" in rig.lidar_stated or "fov_down_deg" in rig.lidar_stated:
        return spec
    new = LidarSpec(beams=spec.beams, fov_up_deg=float(est.fov_up_deg), fov_down_deg=float(est.fov_down_deg),
                    columns=spec.columns)
    if new != spec:
        notes.append(f"vertical field of view from the sweep: {new.fov_up_deg:+.2f} / {new.fov_down_deg:+.2f} deg "
                     f"(the rig left it open; default was {spec.fov_up_deg:+.2f} / {spec.fov_down_deg:+.2f})")
    return new


def _fmt(v) -> str:
    return "(" + ", ".join(f"{x:+.3f}" for x in np.asarray(v, np.float64)) + ")"


__all__ = ["SweepFrame", "CloudFrame", "prepare_sweep", "prepare_cloud", "source_spec", "source_points_local", "shift_rig", "ORIGIN_SNAP_M"]
