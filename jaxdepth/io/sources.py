"""Points from several origins: the host-side container every multi-source reader fills.

A *source* is one LiDAR of a rig in one sweep. Readers of merged rigs (Argoverse 2's two
VLP-32C), of accumulated sweeps (KITTI raw drives with OXTS poses, nuScenes sweeps) and of
the rig JSON's ``lidars`` / the sweeps JSON all return a :class:`SourceCloud`; the core
(:mod:`jaxdepth._src`) turns it into fixed-shape arrays and runs Steps 1 and 2 per source.

Frames. Every point is in the *reference frame*: the points' frame of the reference sweep
(the frame the rig's ``T_cam_lidar`` maps from). ``T_ref_source[s]`` is the pose of source
``s``'s LiDAR in that frame: its translation is where that LiDAR sat when it measured the
points of source ``s``, its rotation the LiDAR's own axes (its z axis is the spin axis).
So ``p_source = inv(T_ref_source[s]) @ p_ref`` puts a point back in its own LiDAR's frame.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxdepth._src.types import LidarSpec

#: Tolerance of the rigidity check of a pose (rotation orthonormal, det +1, last row 0 0 0 1).
POSE_RIGID_TOL = 1e-3


def rigid_pose_problem(T, *, tol: float = POSE_RIGID_TOL) -> str | None:
    """None when ``T`` is a finite (4, 4) rigid transform, else a short description of what is wrong."""
    T = np.asarray(T, np.float64)
    if T.shape != (4, 4):
        return f"shape {T.shape}, expected (4, 4)"
    if not np.all(np.isfinite(T)):
        return "non-finite entries"
    if not np.allclose(T[3], (0.0, 0.0, 0.0, 1.0), atol=tol):
        return f"last row {T[3].tolist()}, expected [0, 0, 0, 1]"
    R = T[:3, :3]
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > tol:
        return f"rotation not orthonormal (|R^T R - I| = {err:.3g})"
    if np.linalg.det(R) < 0:
        return "rotation is a reflection (det < 0)"
    return None


@dataclasses.dataclass(frozen=True)
class SourceCloud:
    """Points of several sources (LiDARs x sweeps) in one reference frame.

    Attributes:
      points: (N, 3) float32 metres, reference frame.
      source: (N,) int32 index into the per-source fields, in [0, S).
      T_ref_source: (S, 4, 4) float64 pose of each source's LiDAR in the reference frame.
      lidars: S entries: the source's :class:`LidarSpec`, or None when it should be
        estimated from the source's own points.
      sweep: (S,) int32 sweep index of each source; 0 is the reference sweep.
      names: S strings, e.g. ``"up_lidar@0"``, for messages and logs.
      ring: optional (N,) int32 laser index within the point's own LiDAR (-1: unknown).
      path: optional file or folder the cloud was read from (for error messages).
    """

    points: np.ndarray
    source: np.ndarray
    T_ref_source: np.ndarray
    lidars: tuple
    sweep: np.ndarray
    names: tuple
    ring: np.ndarray | None = None
    path: str | None = None

    def __post_init__(self):
        where = f"{self.path}: " if self.path else ""
        pts = np.asarray(self.points, np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"{where}field 'points' expected shape (N, 3), got {pts.shape}")
        src = np.asarray(self.source)
        if src.shape != (pts.shape[0],) or not np.issubdtype(src.dtype, np.integer):
            raise ValueError(f"{where}field 'source' expected ({pts.shape[0]},) integers, got {src.shape} {src.dtype}")
        T = np.asarray(self.T_ref_source, np.float64)
        if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] < 1:
            raise ValueError(f"{where}field 'T_ref_source' expected shape (S, 4, 4) with S >= 1, got {T.shape}")
        S = T.shape[0]
        for s in range(S):
            problem = rigid_pose_problem(T[s])
            if problem is not None:
                raise ValueError(f"{where}field 'T_ref_source[{s}]' expected a rigid 4x4 pose, got {problem}")
        if src.size and (src.min() < 0 or src.max() >= S):
            bad = int(src[(src < 0) | (src >= S)][0])
            raise ValueError(f"{where}field 'source' expected indices in [0, {S}), got {bad}")
        lidars = tuple(self.lidars)
        if len(lidars) != S or not all(x is None or isinstance(x, LidarSpec) for x in lidars):
            raise ValueError(f"{where}field 'lidars' expected {S} LidarSpec or None entries, got {len(lidars)}")
        sweep = np.asarray(self.sweep)
        if sweep.shape != (S,) or not np.issubdtype(sweep.dtype, np.integer):
            raise ValueError(f"{where}field 'sweep' expected ({S},) integers, got {sweep.shape} {sweep.dtype}")
        names = tuple(str(n) for n in self.names)
        if len(names) != S:
            raise ValueError(f"{where}field 'names' expected {S} names, got {len(names)}")
        ring = None
        if self.ring is not None:
            ring = np.asarray(self.ring)
            if ring.shape != (pts.shape[0],) or not np.issubdtype(ring.dtype, np.integer):
                raise ValueError(f"{where}field 'ring' expected ({pts.shape[0]},) integers, got {ring.shape} {ring.dtype}")
            ring = ring.astype(np.int32)
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "source", src.astype(np.int32))
        object.__setattr__(self, "T_ref_source", T)
        object.__setattr__(self, "lidars", lidars)
        object.__setattr__(self, "sweep", sweep.astype(np.int32))
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "ring", ring)

    @property
    def num_sources(self) -> int:
        return int(self.T_ref_source.shape[0])

    @property
    def origins_m(self) -> np.ndarray:
        """(S, 3) float64: where each source's LiDAR sat, reference frame."""
        return self.T_ref_source[:, :3, 3]


__all__ = ["SourceCloud", "rigid_pose_problem", "POSE_RIGID_TOL"]
