"""Containers shared by every stage: sensor descriptions, the stage outputs, the host point cloud.

Nothing here computes beyond checking its own fields. Units: metres, radians, pixels. Images
are ``(H, W)``; points are ``(N, 3)`` float32 plus a ``(N,)`` bool validity mask.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import numpy as np


@dataclasses.dataclass(frozen=True)
class LidarSpec:
    """Static description of a spinning multi-beam LiDAR (hashable: usable as a jit static).

    Attributes:
      beams: number of laser beams L (rows of the range image; the paper's L).
      fov_up_deg: elevation of the highest beam, degrees (positive up).
      fov_down_deg: elevation of the lowest beam, degrees (negative down).
      columns: azimuth cells of the range image over 360 degrees.
    """

    beams: int = 64
    fov_up_deg: float = 2.0
    fov_down_deg: float = -24.9
    columns: int = 2048

    def __post_init__(self):
        if int(self.beams) < 1:
            raise ValueError(f"LidarSpec: field 'beams' expected a positive integer, got {self.beams!r}")
        if int(self.columns) < 4:
            raise ValueError(f"LidarSpec: field 'columns' expected an integer >= 4, got {self.columns!r}")
        if not self.fov_up_deg > self.fov_down_deg:
            raise ValueError(
                "LidarSpec: field 'fov_up_deg' expected to exceed 'fov_down_deg', "
                f"got {self.fov_up_deg!r} <= {self.fov_down_deg!r}")

    @property
    def fov_up_rad(self) -> float:
        return math.radians(self.fov_up_deg)

    @property
    def fov_down_rad(self) -> float:
        return math.radians(self.fov_down_deg)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Camera:
    """One pinhole camera.

    Attributes:
      K: (3, 3) float32 intrinsics, pixels.
      T_cam_lidar: (4, 4) float32 rigid transform, ``p_cam = T_cam_lidar @ p_lidar``
        (camera looks along +z, x right, y down).
      height, width: static image size in pixels (pytree metadata, not traced).
    """

    K: jax.Array
    T_cam_lidar: jax.Array
    height: int = dataclasses.field(metadata=dict(static=True))
    width: int = dataclasses.field(metadata=dict(static=True))


class Stages(NamedTuple):
    """Every intermediate product of the SGM pipeline for one camera image.

    All fields are (H, W) unless noted.

    Attributes:
      sparse_depth: float32 metres, 0 = empty: the input depth image.
      normals: (3, H, W) float32 unit surface normals of the sparse pixels in the
        camera frame (zero where the pixel is empty).
      inlier_mask: bool, sparse pixels kept by outlier removal (Step 2).
      seed_depth: float32 metres, z' of the nearest kept LiDAR pixel (Step 3).
      du, dv: int32 pixels; the nearest seed sits at (u + du, v + dv).
      residual: float32 metres, the paper's Delta z (Step 4).
      depth_raw: float32 metres, z' + Delta z before smoothing.
      depth: float32 metres, the final dense depth.
    """

    sparse_depth: jax.Array
    normals: jax.Array
    inlier_mask: jax.Array
    seed_depth: jax.Array
    du: jax.Array
    dv: jax.Array
    residual: jax.Array
    depth_raw: jax.Array
    depth: jax.Array


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

    def take(self, keep) -> "SourceCloud":
        """The same sources with only the points where ``keep`` ((N,) bool) holds (e.g. a hold-out's input)."""
        keep = np.asarray(keep, bool)
        if keep.shape != self.source.shape:
            raise ValueError(f"SourceCloud.take: field 'keep' expected shape {self.source.shape}, got {keep.shape}")
        return SourceCloud(points=self.points[keep], source=self.source[keep], T_ref_source=self.T_ref_source,
                           lidars=self.lidars, sweep=self.sweep, names=self.names,
                           ring=None if self.ring is None else self.ring[keep], path=self.path)

    @property
    def num_sources(self) -> int:
        return int(self.T_ref_source.shape[0])

    @property
    def origins_m(self) -> np.ndarray:
        """(S, 3) float64: where each source's LiDAR sat, reference frame."""
        return self.T_ref_source[:, :3, 3]
