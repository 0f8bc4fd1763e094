"""Scene primitives and ray casting for the synthetic data: the layer under the renderers.

A scene is a small set of primitives held in fixed-size float32 arrays
(:class:`SceneArrays`, LiDAR frame, metres): planes, boxes rotated about the
vertical axis (yaw), and closed vertical cylinders. :func:`cast_rays` /
:func:`nearest_hits` give the first hit of rays (pure, jit-compiled JAX with fixed
shapes); :func:`camera_rays` builds the rays of a camera's pixel centres;
:func:`street_scene_arrays` places the procedural street's primitives on the host.
The LiDAR / camera renderers (:mod:`jaxdepth._src.synthetic`) and the image
renderer (:mod:`jaxdepth._src.synthetic_images`) both build on this module.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src import geometry
from jaxdepth._src.types import Camera

# Hits closer than this ray parameter are ignored (guards against self hits).
_T_MIN = 1e-6
# Direction components with a smaller magnitude count as parallel to a face.
_TINY = 1e-12


class SceneArrays(NamedTuple):
    """The primitives of a scene, float32, LiDAR frame, metres (a pytree).

    Attributes:
      planes: (Q, 4) ``[nx, ny, nz, offset]``: the surface ``n . p = offset``
        with a unit normal n (two sided).
      boxes: (B, 7) ``[cx, cy, cz, half_x, half_y, half_z, yaw]``: a solid box
        centred at c with half extents along its own axes, rotated by ``yaw``
        radians about +z (counter-clockwise seen from above).
      cylinders: (P, 5) ``[cx, cy, radius, z_min, z_max]``: a closed solid
        vertical cylinder (side and both caps).
    """

    planes: jax.Array
    boxes: jax.Array
    cylinders: jax.Array


def scene_arrays(*, planes=None, boxes=None, cylinders=None) -> SceneArrays:
    """Builds a :class:`SceneArrays` from array-likes (missing kinds become empty).

    Args:
      planes: (Q, 4) or None. boxes: (B, 7) or None. cylinders: (P, 5) or None.
        See :class:`SceneArrays` for the layouts. Normals are normalised here.

    Returns:
      SceneArrays of NumPy float32 arrays (valid jit inputs).
    """
    def check(name, value, width):
        if value is None:
            return np.zeros((0, width), np.float32)
        arr = np.asarray(value, np.float64)
        if arr.ndim != 2 or arr.shape[1] != width:
            raise ValueError(f"scene_arrays: field {name!r} expected shape (n, {width}), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"scene_arrays: field {name!r} expected finite values, got non-finite entries")
        return arr

    planes = check("planes", planes, 4)
    norms = np.linalg.norm(planes[:, :3], axis=1)
    if np.any(norms == 0):
        raise ValueError("scene_arrays: field 'planes' expected non-zero normals, got a zero normal")
    planes = np.concatenate([planes[:, :3] / norms[:, None], planes[:, 3:] / norms[:, None]], axis=1)
    boxes = check("boxes", boxes, 7)
    if np.any(boxes[:, 3:6] < 0):
        raise ValueError("scene_arrays: field 'boxes' expected non-negative half extents, got a negative one")
    cylinders = check("cylinders", cylinders, 5)
    if np.any(cylinders[:, 2] < 0) or np.any(cylinders[:, 4] < cylinders[:, 3]):
        raise ValueError("scene_arrays: field 'cylinders' expected radius >= 0 and z_max >= z_min")
    return SceneArrays(planes.astype(np.float32), boxes.astype(np.float32), cylinders.astype(np.float32))


# --------------------------------------------------------------------------- ray casting


def _safe_inverse(x):
    ok = jnp.abs(x) > _TINY
    return ok, 1.0 / jnp.where(ok, x, 1.0)


def _first_hit_planes(o, d, planes):
    """o (M, 3) with M in {1, N}; d (N, 3) -> (N,) nearest plane hit or inf."""
    n = planes[:, :3]
    denom = d @ n.T                               # (N, Q)
    numer = planes[:, 3] - o @ n.T                # (M, Q)
    ok, inv = _safe_inverse(denom)
    t = numer * inv
    t = jnp.where(ok & (t > _T_MIN), t, jnp.inf)
    return jnp.min(t, axis=1, initial=jnp.inf)


def _first_hit_boxes(o, d, boxes):
    """Slab test in each box's own (yawed) frame -> (N,) nearest hit or inf."""
    c = boxes[:, 0:3]
    half = boxes[:, 3:6]
    cos, sin = jnp.cos(boxes[:, 6]), jnp.sin(boxes[:, 6])
    rx = o[:, 0:1] - c[:, 0]                      # (M, B)
    ry = o[:, 1:2] - c[:, 1]
    local_o = (cos * rx + sin * ry, -sin * rx + cos * ry, o[:, 2:3] - c[:, 2])
    dx, dy = d[:, 0:1], d[:, 1:2]                 # (N, 1)
    local_d = (cos * dx + sin * dy, -sin * dx + cos * dy, jnp.broadcast_to(d[:, 2:3], (d.shape[0], 1)))
    t_near = jnp.float32(-jnp.inf)
    t_far = jnp.float32(jnp.inf)
    for axis in range(3):
        oc, dc, hc = local_o[axis], local_d[axis], half[:, axis]
        ok, inv = _safe_inverse(dc)
        t1 = (-hc - oc) * inv
        t2 = (hc - oc) * inv
        inside = jnp.abs(oc) <= hc
        lo = jnp.where(ok, jnp.minimum(t1, t2), jnp.where(inside, -jnp.inf, jnp.inf))
        hi = jnp.where(ok, jnp.maximum(t1, t2), jnp.where(inside, jnp.inf, -jnp.inf))
        t_near = jnp.maximum(t_near, lo)
        t_far = jnp.minimum(t_far, hi)
    hit = (t_near <= t_far) & (t_far > _T_MIN)
    t = jnp.where(hit, jnp.where(t_near > _T_MIN, t_near, t_far), jnp.inf)
    return jnp.min(t, axis=1, initial=jnp.inf)


def _first_hit_cylinders(o, d, cylinders):
    """Closed vertical cylinders (side + caps) -> (N,) nearest hit or inf.

    The side hit uses the closest-approach form (no b^2 - 4ac cancellation):
    t = t_c -+ sqrt((r^2 - m^2) / a) with m the horizontal miss distance.
    """
    cx, cy, r, z0, z1 = (cylinders[:, i] for i in range(5))
    ox = o[:, 0:1] - cx                           # (M, P)
    oy = o[:, 1:2] - cy
    oz = o[:, 2:3]
    dx, dy, dz = d[:, 0:1], d[:, 1:2], d[:, 2:3]  # (N, 1)
    a = dx * dx + dy * dy
    ok_a, inv_a = _safe_inverse(a)
    t_c = -(ox * dx + oy * dy) * inv_a            # (N, P)
    mx = ox + t_c * dx
    my = oy + t_c * dy
    h2 = (r * r - (mx * mx + my * my)) * inv_a
    ok_side = ok_a & (h2 >= 0)
    half_chord = jnp.sqrt(jnp.where(ok_side, h2, 0.0))
    t_in = t_c - half_chord
    t_side = jnp.where(t_in > _T_MIN, t_in, t_c + half_chord)
    z_side = oz + t_side * dz
    best = jnp.where(ok_side & (t_side > _T_MIN) & (z_side >= z0) & (z_side <= z1), t_side, jnp.inf)
    ok_z, inv_dz = _safe_inverse(dz)
    for zc in (z0, z1):
        t_cap = (zc - oz) * inv_dz
        px = ox + t_cap * dx
        py = oy + t_cap * dy
        on_cap = ok_z & (t_cap > _T_MIN) & (px * px + py * py <= r * r)
        best = jnp.minimum(best, jnp.where(on_cap, t_cap, jnp.inf))
    return jnp.min(best, axis=1, initial=jnp.inf)


def checked_rays(origins, directions, *, where: str):
    """(origins (M, 3) with M = 1 or N, directions (N, 3)) as float32, shapes checked."""
    d = jnp.asarray(directions, jnp.float32)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"{where}: field 'directions' expected shape (N, 3), got {d.shape}")
    o = jnp.asarray(origins, jnp.float32)
    if o.shape not in ((3,), d.shape):
        raise ValueError(f"{where}: field 'origins' expected shape (3,) or {d.shape}, got {o.shape}")
    return o.reshape(-1, 3), d


def cast_rays(origins: jax.Array, directions: jax.Array, scene: SceneArrays) -> jax.Array:
    """First-hit ray parameter against every primitive of a scene (pure JAX, jittable).

    The primitives are visited by ``lax.scan`` (one vectorised pass over the rays
    per primitive), which keeps the working set at O(N) and compiles one body per
    primitive kind.

    Args:
      origins: (N, 3) or (3,) float32 ray origins, metres (a (3,) origin is
        shared by all rays).
      directions: (N, 3) float32 ray directions; need not be unit length.
      scene: :class:`SceneArrays`.

    Returns:
      (N,) float32 ``t`` of the nearest surface ``origin + t * direction`` with
      ``t > 1e-6``; ``inf`` when the ray hits nothing. ``t`` is in metres only for
      unit directions. A ray starting inside a solid returns its exit point.
    """
    o, d = checked_rays(origins, directions, where="cast_rays")
    return nearest_hits(o, d, scene, labelled=False)[0]


def nearest_hits(o: jax.Array, d: jax.Array, scene: SceneArrays, *, labelled: bool):
    """(t, label) of :func:`cast_rays` for checked rays (``o`` (1, 3) or (N, 3), ``d`` (N, 3)).

    ``label`` (N,) int32 is the hit primitive's index in the concatenation
    planes, boxes, cylinders (the first one in that order on an exact tie), -1
    where nothing is hit; None unless ``labelled`` (static).
    """
    t = jnp.full(d.shape[:1], jnp.inf, jnp.float32)
    label = jnp.full(d.shape[:1], -1, jnp.int32) if labelled else None
    start = 0
    for first_hit, prims in zip((_first_hit_planes, _first_hit_boxes, _first_hit_cylinders), scene):
        prims = jnp.asarray(prims, jnp.float32)
        if prims.shape[0] == 0:
            continue

        def body(carry, item, first_hit=first_hit):
            t_best, label_best = carry
            prim, index = item
            t_prim = first_hit(o, d, prim[None])
            if label_best is not None:
                label_best = jnp.where(t_prim < t_best, index, label_best)
            return (jnp.minimum(t_best, t_prim), label_best), None

        indices = start + jnp.arange(prims.shape[0], dtype=jnp.int32) if labelled else None
        (t, label), _ = jax.lax.scan(body, (t, label), (prims, indices))
        start += prims.shape[0]
    return t, label


def camera_rays(camera: Camera):
    """Rays through every pixel centre of a camera, in the LiDAR frame.

    Args:
      camera: :class:`Camera` (K, T_cam_lidar traced; height, width static).

    Returns:
      (origin, directions): origin (3,) float32, the optical centre in the
      LiDAR frame; directions (H * W, 3) float32 row major (v, u), scaled so the
      camera-frame z component is 1 (a hit's ray parameter is its depth z).
    """
    K = jnp.asarray(camera.K, jnp.float32)
    T = jnp.asarray(camera.T_cam_lidar, jnp.float32)
    v, u = geometry.pixel_grid(camera.height, camera.width)
    x, y = geometry.pixel_rays(K, v, u)
    d_cam = jnp.stack([x, y, jnp.ones_like(x)], axis=-1).reshape(-1, 3)
    R, t = T[:3, :3], T[:3, 3]
    return -(R.T @ t), d_cam @ R


# --------------------------------------------------------------------------- the street


def _box(x, y, z_bottom, length, width, height, yaw):
    return [x, y, z_bottom + 0.5 * height, 0.5 * length, 0.5 * width, 0.5 * height, yaw]


def box_row(x: float, y: float, z_bottom: float, length: float, width: float, height: float, yaw: float) -> list:
    """One row of :attr:`SceneArrays.boxes` for a box standing on ``z_bottom``.

    Args:
      x, y: centre of the footprint, metres. z_bottom: height of the bottom face.
      length, width, height: full extents along the box's own x, y and z, metres.
      yaw: radians about +z.

    Returns:
      list ``[cx, cy, cz, half_x, half_y, half_z, yaw]``.
    """
    return _box(x, y, z_bottom, length, width, height, yaw)


def street_scene_arrays(seed: int = 0, *, lidar_height_m: float = 1.73) -> SceneArrays:
    """The primitives of the procedural street (host side, NumPy).

    The street runs along x. Per seed: a row of 6 buildings on each side
    (fronts 8-11 m from the centre line, 6-20 m tall) with gaps, one building on
    each side turned by 30-45 degrees of yaw, a building closing the street
    85-100 m ahead; 12 parked cars (8 ahead between 3 and 60 m, 4 behind) and 3
    cars in the lanes, each a body and a cabin box; 11 thin poles (radius 6-15 cm,
    3-7 m tall) along the kerbs; 2 cyclists (a thin bike box, a torso box and a
    head cylinder). The counts are fixed, so every seed has the same array
    shapes (49 boxes, 13 cylinders, 1 plane) and shares one compilation.

    Args:
      seed: seed of ``numpy.random.default_rng``.
      lidar_height_m: height of the LiDAR above the ground plane.

    Returns:
      :class:`SceneArrays`.
    """
    rng = np.random.default_rng(seed)
    g = -float(lidar_height_m)
    boxes, cylinders = [], []
    # Building rows along both sides, -50 m to about +90 m.
    for side in (1.0, -1.0):
        front = rng.uniform(8.0, 11.0)
        x = -50.0
        for _ in range(6):
            length, depth = rng.uniform(12.0, 24.0), rng.uniform(8.0, 14.0)
            y_front = front + rng.uniform(-0.5, 1.5)
            boxes.append(_box(x + 0.5 * length, side * (y_front + 0.5 * depth), g, length, depth,
                              rng.uniform(6.0, 20.0), 0.0))
            x += length + rng.uniform(1.0, 5.0)
        # An angled building: its nearest corner about 1.5 m in front of the row.
        yaw = math.radians(rng.uniform(30.0, 45.0))
        length, depth = 14.0, 8.0
        reach = 0.5 * length * math.sin(yaw) + 0.5 * depth * math.cos(yaw)
        boxes.append(_box(rng.uniform(18.0, 40.0), side * (front - 1.5 + reach), g, length, depth,
                          rng.uniform(8.0, 16.0), side * yaw))
    # A building across the end of the street.
    boxes.append(_box(rng.uniform(85.0, 100.0) + 5.0, rng.uniform(-5.0, 5.0), g, 10.0, 70.0,
                      rng.uniform(10.0, 25.0), math.radians(rng.uniform(-10.0, 10.0))))

    def car(x, y, yaw):
        length, width = rng.uniform(3.9, 4.7), rng.uniform(1.7, 1.9)
        body_h, cabin_h = rng.uniform(0.9, 1.1), rng.uniform(0.45, 0.6)
        boxes.append(_box(x, y, g, length, width, body_h, yaw))
        back = -0.15 * length
        boxes.append(_box(x + back * math.cos(yaw), y + back * math.sin(yaw), g + body_h,
                          0.55 * length, width - 0.15, cabin_h, yaw))

    # Parked cars: 8 ahead (one per 7.1 m bin between 3 and 60 m), 4 behind.
    for lo, hi in zip(np.linspace(3.0, 60.0, 9)[:-1], np.linspace(3.0, 60.0, 9)[1:]):
        side = rng.choice([1.0, -1.0])
        car(rng.uniform(lo + 2.4, hi - 2.4), side * rng.uniform(3.8, 4.6), math.radians(rng.uniform(-5, 5)))
    for lo, hi in zip(np.linspace(-44.0, -4.0, 5)[:-1], np.linspace(-44.0, -4.0, 5)[1:]):
        side = rng.choice([1.0, -1.0])
        car(rng.uniform(lo + 2.4, hi - 2.4), side * rng.uniform(3.8, 4.6), math.radians(rng.uniform(-5, 5)))
    # Cars in the lanes: ahead-left, oncoming ahead-right, behind.
    car(rng.uniform(12.0, 30.0), rng.uniform(1.2, 2.0), math.radians(rng.uniform(-3, 3)))
    car(rng.uniform(32.0, 55.0), -rng.uniform(1.2, 2.0), math.pi + math.radians(rng.uniform(-3, 3)))
    car(-rng.uniform(9.0, 25.0), rng.uniform(-0.5, 0.5), math.radians(rng.uniform(-3, 3)))

    # Poles along the kerbs: 8 ahead, 3 behind.
    for lo, hi in list(zip(np.linspace(3.0, 60.0, 9)[:-1], np.linspace(3.0, 60.0, 9)[1:])) + \
            list(zip(np.linspace(-40.0, -3.0, 4)[:-1], np.linspace(-40.0, -3.0, 4)[1:])):
        side = rng.choice([1.0, -1.0])
        cylinders.append([rng.uniform(lo, hi), side * rng.uniform(5.5, 6.2), rng.uniform(0.06, 0.15),
                          g, g + rng.uniform(3.0, 7.0)])

    # Cyclists: one in the right bike lane ahead, one further away on the left.
    for x, y in ((rng.uniform(6.0, 20.0), -rng.uniform(2.2, 3.0)), (rng.uniform(20.0, 40.0), rng.uniform(2.2, 3.0))):
        yaw = math.radians(rng.uniform(-10.0, 10.0))
        boxes.append(_box(x, y, g, 1.75, 0.12, 1.0, yaw))
        back = -0.15
        tx, ty = x + back * math.cos(yaw), y + back * math.sin(yaw)
        boxes.append(_box(tx, ty, g + 1.0, 0.45, 0.4, 0.65, yaw))
        cylinders.append([tx, ty, 0.11, g + 1.65, g + 1.9])

    planes = [[0.0, 0.0, 1.0, g]]
    return scene_arrays(planes=planes, boxes=boxes, cylinders=cylinders)
