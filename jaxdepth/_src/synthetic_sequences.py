"""Synthetic drives with exact depth: an ego moving down the procedural street, moving cars, 2-3 LiDARs.

The street of :func:`~jaxdepth._src.synthetic.street_scene_arrays` with its three lane cars
replaced by three *moving* cars (one driving ahead of the ego, one oncoming, one crossing), an
ego that moves ``step_m`` per sweep along the street, and a rig of 2 or 3 spinning LiDARs at
different heights and tilts (:data:`RIG_LIDARS`).

Frames. The *reference frame* is the ego frame of the reference sweep (sweep 0, the latest),
with the first LiDAR at its origin (the ground at ``z = -1.73``); sweep ``-k`` is ``k`` sweeps
earlier (signed offsets, negative = earlier, as every reader gives them), the ego then
``k * step_m`` further back along x. The reference camera (KITTI-like,
looking forward) and its exact depth belong to sweep 0. Every point is given in the reference
frame; ``T_ref_source`` is each source's LiDAR pose (ego pose of its sweep composed with the
LiDAR's mounting). A source is one LiDAR in one sweep, ordered sweep-major.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.poses import rigid, rotation_rpy
from jaxdepth._src.scene import _box, cast_rays, scene_arrays, street_scene_arrays
from jaxdepth._src.synthetic import lidar_rays, render_depth, rig_cameras
from jaxdepth._src.types import Camera, LidarSpec, SourceCloud

#: The rig: (name, position in the reference LiDAR's ego frame (m), roll, pitch (deg), LidarSpec).
RIG_LIDARS = (
    ("top", (0.0, 0.0, 0.0), 0.0, 0.0, LidarSpec(beams=32, fov_up_deg=10.0, fov_down_deg=-25.0, columns=1024)),
    ("front_low", (1.2, 0.0, -0.95), 0.0, 8.0, LidarSpec(beams=16, fov_up_deg=15.0, fov_down_deg=-15.0,
                                                         columns=1024)),
    ("rear_left", (-0.7, 0.55, 0.2), 6.0, -3.0, LidarSpec(beams=16, fov_up_deg=15.0, fov_down_deg=-15.0,
                                                          columns=1024)),
)
#: Index range of the street's three lane cars (body and cabin boxes) in ``street_scene_arrays``.
_LANE_CAR_BOXES = slice(39, 45)
_GROUND_Z = -1.73


@dataclasses.dataclass(frozen=True, kw_only=True)
class SyntheticSequence(SourceCloud):
    """Sweeps of a drive: a :class:`~jaxdepth._src.types.SourceCloud` (every valid return of every
    source, reference frame; ``lidars`` are the rig's specs, ``sweep`` 0 the reference) with the
    reference camera's exact depth.

    Attributes (beyond SourceCloud's):
      camera: the reference :class:`Camera` (``T_cam_lidar`` maps reference-frame points).
      dense_depth: (H, W) float32 exact depth of the reference camera, 0 = sky.
      ghost_region: (H, W) bool: pixels where a moving car was in an earlier sweep, more than
        1 m in front of what the camera sees now, and no moving car is seen now (where its
        ghost would show).
      ghost_depth: (K - 1, H, W) float32 depth of the moving cars alone in each earlier sweep (sweep -1, -2, ...)
        (0 where none): a prediction within 1 m of it inside ``ghost_region`` shows a ghost.
    """

    camera: Camera
    dense_depth: np.ndarray
    ghost_region: np.ndarray
    ghost_depth: np.ndarray


def _moving_cars(seed: int):
    """(x0, y0, yaw, vx, vy, length, width, body_h, cabin_h) of the three moving cars (reference time)."""
    rng = np.random.default_rng([seed, 7])
    cars = []
    for x0, y0, yaw, speed in ((rng.uniform(11.0, 16.0), rng.uniform(1.3, 1.9), 0.0, rng.uniform(1.8, 2.6)),
                               (rng.uniform(24.0, 34.0), -rng.uniform(1.3, 1.9), math.pi, rng.uniform(2.0, 3.0)),
                               (rng.uniform(18.0, 24.0), rng.uniform(-1.0, 1.0), 0.5 * math.pi,
                                rng.uniform(1.0, 1.5))):
        cars.append((x0, y0, yaw, speed * math.cos(yaw), speed * math.sin(yaw), rng.uniform(3.9, 4.7),
                     rng.uniform(1.7, 1.9), rng.uniform(0.9, 1.1), rng.uniform(0.45, 0.6)))
    return cars


def _car_boxes(cars, sweep: int):
    boxes = []
    for x0, y0, yaw, vx, vy, length, width, body_h, cabin_h in cars:
        x, y = x0 + sweep * vx, y0 + sweep * vy
        boxes.append(_box(x, y, _GROUND_Z, length, width, body_h, yaw))
        back = -0.15 * length
        boxes.append(_box(x + back * math.cos(yaw), y + back * math.sin(yaw), _GROUND_Z + body_h,
                          0.55 * length, width - 0.15, cabin_h, yaw))
    return np.asarray(boxes, np.float32)


def sequence_scene(seed: int, sweep: int):
    """(:class:`SceneArrays` at signed sweep offset ``sweep`` (0 the reference, -1 one sweep earlier),
    the moving cars alone then), reference frame."""
    base = street_scene_arrays(seed)
    cars = _moving_cars(seed)
    boxes = np.asarray(base.boxes).copy()
    boxes[_LANE_CAR_BOXES] = _car_boxes(cars, sweep)
    return (scene_arrays(planes=base.planes, boxes=boxes, cylinders=base.cylinders),
            scene_arrays(boxes=_car_boxes(cars, sweep)))


@functools.partial(jax.jit, static_argnames=("lidar", "max_range_m"))
def _cast_sweep(scene, R, t, *, lidar: LidarSpec, max_range_m: float):
    d = lidar_rays(lidar) @ jnp.asarray(R, jnp.float32).T
    o = jnp.asarray(t, jnp.float32)
    hit = cast_rays(o, d, scene)
    valid = hit <= max_range_m
    return jnp.where(valid[:, None], o + d * jnp.where(valid, hit, 0.0)[:, None], 0.0), valid


def make_street_sequence(seed: int = 0, *, sweeps: int = 5, lidars: int = 3, step_m: float = 1.5,
                         image_scale: float = 0.5, noise_std_m: float = 0.01,
                         max_range_m: float = 80.0) -> SyntheticSequence:
    """Renders ``sweeps`` sweeps of a drive down the street (see the module docstring).

    Args:
      seed: scene seed (the street and the moving cars); same arguments, same bytes.
      sweeps: number of sweeps, the reference (latest) one included.
      lidars: 2 or 3 LiDARs of :data:`RIG_LIDARS`.
      step_m: ego motion per sweep along the street, metres.
      image_scale: scale of the KITTI-like reference camera (0.5: 176 x 608).
      noise_std_m: Gaussian range noise, metres (``default_rng([seed, sweep, lidar])``).
      max_range_m: LiDAR rays without a hit within this range return nothing.

    Returns:
      :class:`SyntheticSequence`.
    """
    if not 1 <= lidars <= len(RIG_LIDARS):
        raise ValueError(f"make_street_sequence: field 'lidars' expected 1..{len(RIG_LIDARS)}, got {lidars!r}")
    if int(sweeps) < 1:
        raise ValueError(f"make_street_sequence: field 'sweeps' expected >= 1, got {sweeps!r}")
    camera = rig_cameras("kitti", image_scale=image_scale)[0]
    points, source, poses, specs, sweep_of, names = [], [], [], [], [], []
    car_depths = []
    for k in range(int(sweeps)):
        offset = -k                                   # signed: negative = earlier
        scene, cars_only = sequence_scene(seed, offset)
        ego = rigid(np.eye(3), (offset * step_m, -0.05 * offset, 0.0))
        for j, (name, pos, roll, pitch, spec) in enumerate(RIG_LIDARS[:lidars]):
            T = ego @ rigid(rotation_rpy(roll, pitch, degrees=True), pos)
            pts, valid = (np.asarray(a) for a in _cast_sweep(scene, T[:3, :3], T[:3, 3], lidar=spec,
                                                              max_range_m=float(max_range_m)))
            if noise_std_m > 0:
                rng = np.random.default_rng([seed, k, j])
                ray = pts - T[:3, 3]
                dist = np.linalg.norm(ray, axis=1, keepdims=True)
                pts = pts + ray / np.maximum(dist, 1e-6) * noise_std_m * rng.standard_normal((pts.shape[0], 1))
            s = len(poses)
            points.append(pts[valid].astype(np.float32))
            source.append(np.full(int(valid.sum()), s, np.int32))
            poses.append(T)
            specs.append(spec)
            sweep_of.append(offset)
            names.append(f"{name}@{offset}")
        car_depths.append(np.asarray(render_depth(camera, cars_only, max_range_m=max_range_m)))
    scene0, _ = sequence_scene(seed, 0)
    gt = np.asarray(render_depth(camera, scene0, max_range_m=max_range_m))
    car_now = (car_depths[0] > 0) & (np.abs(car_depths[0] - gt) < 0.05)
    ghost = np.zeros(gt.shape, bool)
    for d in car_depths[1:]:
        ghost |= (d > 0) & ((gt == 0) | (d < gt - 1.0))
    ghost &= ~car_now
    return SyntheticSequence(points=np.concatenate(points), source=np.concatenate(source),
                             T_ref_source=np.stack(poses), lidars=tuple(specs), sweep=np.asarray(sweep_of, np.int32),
                             names=tuple(names), camera=camera, dense_depth=gt, ghost_region=ghost,
                             ghost_depth=np.stack(car_depths[1:]) if len(car_depths) > 1
                             else np.zeros((0,) + gt.shape, np.float32))


__all__ = ["SyntheticSequence", "make_street_sequence", "sequence_scene", "RIG_LIDARS"]
