"""The digital twins' world: the procedural street with movers and clutter (host side, NumPy).

World frame ``W``: the ego frame of the reference sweep with the ground at ``z = 0`` (x forward
along the street, y left, z up, metres). The static street is
:func:`jaxdepth._src.scene.street_scene_arrays` with its three lane cars taken out; added per seed:

- movers: three cars (one ahead, one oncoming, one crossing, 4-10 m/s) and four pedestrians
  (1.0-1.6 m/s; torso and two leg boxes, a head cylinder), placed at the reference time and
  moved back ``k * dt`` for sweep ``k``;
- vegetation: two hedges (rows of 12 boxes of random size, height and yaw, with 6 bushes (spheres)
  bulging out of them: an irregular, interpenetrating surface) and three trees (trunk cylinder,
  canopy of 6 overlapping spheres); spheres are cast by :mod:`jaxdepth.research.twin_sensors`
  (:func:`twin_spheres`, not part of :class:`SceneArrays`);
- thin poles: six sign posts, radius 2.5-5 cm;
- a fence: 28 slats 8 cm wide with 7 cm gaps between two rails.

Layouts (:data:`LAYOUTS`; ``layout=`` of :func:`twin_scene`, :func:`twin_spheres` and
:func:`~jaxdepth.research.twins.make_twin`): ``"street"`` (default) is the street above, a canyon
whose side walls stand 8-11 m from the centre line; ``"open"`` opens its right side (y < 0) as the
real nuScenes sample's (``benchmarks.studies.nuscenes_far_twin``): the right row and its angled
building stand 22-40 m further back, :data:`OPEN_TREES` large trees (canopy of
:data:`OPEN_CANOPY_SPHERES` spheres) and :data:`OPEN_POSTS` lamp posts stand on the open ground
between (12-35 m and 9-25 m from the centre line), and two of the six left-row buildings stand
12-20 m further back (gaps with far facades). ``"cluttered"`` is ``"open"`` with the real sample's
near clutter and denser far vegetation (``benchmarks.studies.nuscenes_far_twin``): within 10 m of
the ego :data:`NEAR_BARRIERS` barriers, :data:`NEAR_BOLLARDS` bollards, :data:`NEAR_PEOPLE` people
standing, :data:`NEAR_BLOCKS` irregular low blocks (planters, bins; random size and yaw) and
:data:`NEAR_BUSHES` bushes (spheres), and :data:`FAR_SHRUBS` shrubs (spheres) on the open right side
20-70 m out.

Every seed gives the same primitive counts (one compilation per rig); the same seed gives the
same bytes.
"""

from __future__ import annotations

import math

import numpy as np

from jaxdepth._src.scene import SceneArrays, scene_arrays, street_scene_arrays
from jaxdepth._src.scene import box_row

#: Boxes of the street's three lane cars (body and cabin each) in ``street_scene_arrays``.
_LANE_CAR_BOXES = np.arange(39, 45)
#: Seconds between sweeps at which the movers' speeds are applied (10 Hz LiDARs).
SWEEP_DT_S = 0.1
#: Counts of the added primitives (fixed for every seed).
PEDESTRIANS, HEDGE_BOXES, HEDGE_BUSHES, CANOPY_SPHERES, SLATS, SIGN_POSTS = 4, 12, 6, 6, 28, 6
#: The scene layouts (see the module docstring).
LAYOUTS: tuple = ("street", "open", "cluttered")
#: Counts of the ``"open"`` layout's added trees, their canopy spheres and lamp posts.
OPEN_TREES, OPEN_CANOPY_SPHERES, OPEN_POSTS = 30, 4, 24
#: Counts of the ``"cluttered"`` layout's near clutter (within 10 m) and far shrubs (set against the real
#: sample's point statistics only: ``benchmarks.studies.nuscenes_far_twin``).
NEAR_BARRIERS, NEAR_BOLLARDS, NEAR_PEOPLE, NEAR_BLOCKS, NEAR_BUSHES, FAR_SHRUBS = 3, 5, 3, 4, 6, 160
#: Rows of the street's buildings in ``street_scene_arrays``: the left row, the right row (each 6 and an angled one).
_LEFT_ROW, _RIGHT_ROW = np.arange(0, 6), np.arange(7, 14)


def _movers(seed: int):
    """Cars ``(x, y, yaw, vx, vy, length, width, body_h, cabin_h)`` and pedestrians ``(x, y, yaw, vx, vy, h)``."""
    rng = np.random.default_rng([seed, 37, 1])
    cars = []
    for x0, y0, yaw, speed in ((rng.uniform(10.0, 16.0), rng.uniform(1.3, 1.9), 0.0, rng.uniform(5.0, 9.0)),
                               (rng.uniform(22.0, 34.0), -rng.uniform(1.3, 1.9), math.pi, rng.uniform(6.0, 10.0)),
                               (rng.uniform(18.0, 26.0), rng.uniform(-1.0, 1.0), 0.5 * math.pi, rng.uniform(4.0, 6.0))):
        cars.append((x0, y0, yaw, speed * math.cos(yaw), speed * math.sin(yaw), rng.uniform(3.9, 4.7),
                     rng.uniform(1.7, 1.9), rng.uniform(0.9, 1.1), rng.uniform(0.45, 0.6)))
    peds = []
    for i in range(PEDESTRIANS):
        side = 1.0 if i % 2 == 0 else -1.0
        x0 = rng.uniform(4.0, 30.0) if i < 3 else -rng.uniform(4.0, 12.0)
        yaw = rng.choice([0.0, math.pi, 0.5 * math.pi * side])
        speed = rng.uniform(1.0, 1.6)
        peds.append((x0, side * rng.uniform(5.0, 7.0), yaw, speed * math.cos(yaw), speed * math.sin(yaw),
                     rng.uniform(1.55, 1.9)))
    return cars, peds


def _mover_prims(seed: int, t_s: float):
    """(boxes, cylinders) of the movers at time ``-t_s`` seconds (the reference sweep is t = 0)."""
    cars, peds = _movers(seed)
    boxes, cyls = [], []
    for x0, y0, yaw, vx, vy, length, width, body_h, cabin_h in cars:
        x, y = x0 - t_s * vx, y0 - t_s * vy
        boxes.append(box_row(x, y, 0.0, length, width, body_h, yaw))
        back = -0.15 * length
        boxes.append(box_row(x + back * math.cos(yaw), y + back * math.sin(yaw), body_h, 0.55 * length,
                          width - 0.15, cabin_h, yaw))
    for x0, y0, yaw, vx, vy, h in peds:
        x, y = x0 - t_s * vx, y0 - t_s * vy
        leg_h = 0.47 * h
        # Legs apart by a stride that changes with time (a walking gait), 0.25 m sideways apart.
        stride = 0.25 * math.sin(2.0 * math.pi * 0.9 * t_s)
        c, s = math.cos(yaw), math.sin(yaw)
        for sign in (1.0, -1.0):
            boxes.append(box_row(x + sign * stride * c - sign * 0.1 * s, y + sign * stride * s + sign * 0.1 * c,
                              0.0, 0.14, 0.13, leg_h, yaw))
        boxes.append(box_row(x, y, leg_h, 0.28, 0.42, 0.36 * h, yaw))
        cyls.append([x, y, 0.1, leg_h + 0.36 * h, h])
    return boxes, cyls


def _clutter(seed: int):
    """(boxes, cylinders) of the static clutter: hedges, trees, sign posts, a fence."""
    rng = np.random.default_rng([seed, 37, 2])
    boxes, cyls = [], []
    for side, x_start in ((1.0, rng.uniform(-20.0, -8.0)), (-1.0, rng.uniform(40.0, 55.0))):
        x = x_start
        for _ in range(HEDGE_BOXES):
            length = rng.uniform(0.5, 1.2)
            boxes.append(box_row(x, side * rng.uniform(6.6, 7.3), 0.0, length, rng.uniform(0.5, 1.1),
                              rng.uniform(0.7, 1.6), math.radians(rng.uniform(-35.0, 35.0))))
            x += 0.7 * length
    for tx, ty, trunk_h in _trees(seed):
        cyls.append([tx, ty, rng.uniform(0.12, 0.2), 0.0, trunk_h + 0.3])
    for _ in range(SIGN_POSTS):
        cyls.append([rng.uniform(-30.0, 60.0), rng.choice([1.0, -1.0]) * rng.uniform(5.2, 6.0),
                     rng.uniform(0.025, 0.05), 0.0, rng.uniform(2.2, 3.2)])
    # A fence of slats along the right kerb ahead: 8 cm slats, 7 cm gaps, two rails behind them.
    fx, fy = rng.uniform(14.0, 26.0), -rng.uniform(6.3, 6.8)
    for i in range(SLATS):
        boxes.append(box_row(fx + 0.15 * i, fy, 0.0, 0.08, 0.02, 1.2, 0.0))
    for z in (0.25, 0.95):
        boxes.append(box_row(fx + 0.075 * (SLATS - 1), fy - 0.04, z, 0.15 * SLATS, 0.04, 0.06, 0.0))
    return boxes, cyls


def _trees(seed: int):
    """(x, y, trunk height) of the three trees."""
    rng = np.random.default_rng([seed, 37, 3])
    return [(rng.uniform(-25.0, 60.0), (1.0 if i != 1 else -1.0) * rng.uniform(6.4, 7.2), rng.uniform(2.0, 3.0))
            for i in range(3)]


def twin_spheres(seed: int, layout: str = "street") -> np.ndarray:
    """(S, 4) float32 ``[cx, cy, cz, radius]`` of the vegetation's spheres (static; frame ``W``):
    each tree's canopy of overlapping spheres and the bushes bulging out of the two hedges (and in
    the ``"open"`` layout its trees' canopies, appended)."""
    check_layout(layout)
    rng = np.random.default_rng([seed, 37, 4])
    out = []
    for tx, ty, trunk_h in _trees(seed):
        for _ in range(CANOPY_SPHERES):
            r = rng.uniform(0.6, 1.3)
            out.append([tx + rng.uniform(-1.0, 1.0), ty + rng.uniform(-1.0, 1.0), trunk_h + r + rng.uniform(-0.4, 0.8), r])
    hedge = np.random.default_rng([seed, 37, 2])
    for side, x_start in ((1.0, hedge.uniform(-20.0, -8.0)), (-1.0, hedge.uniform(40.0, 55.0))):
        for _ in range(HEDGE_BUSHES):
            r = rng.uniform(0.35, 0.75)
            out.append([x_start + rng.uniform(0.0, 0.7 * 0.85 * HEDGE_BOXES), side * rng.uniform(6.3, 6.9),
                        rng.uniform(0.3, 1.0), r])
    if layout in ("open", "cluttered"):
        crown = np.random.default_rng([seed, 37, 7])
        for tx, ty, _, trunk_h in _open_trees(seed):
            for _ in range(OPEN_CANOPY_SPHERES):
                r = crown.uniform(1.5, 2.8)
                out.append([tx + crown.uniform(-2.0, 2.0), ty + crown.uniform(-2.0, 2.0),
                            trunk_h + r + crown.uniform(-0.8, 0.8), r])
    if layout == "cluttered":
        out += _clutter_spheres(seed)
    return np.asarray(out, np.float32)


def check_layout(layout: str) -> None:
    if layout not in LAYOUTS:
        raise ValueError(f"field 'layout' expected one of {LAYOUTS}, got {layout!r}")


def _open_trees(seed: int):
    """(x, y, trunk radius, trunk height) of the ``"open"`` layout's trees on the right side."""
    rng = np.random.default_rng([seed, 37, 5])
    return [(rng.uniform(-45.0, 75.0), -rng.uniform(12.0, 35.0), rng.uniform(0.2, 0.35), rng.uniform(2.5, 4.0))
            for _ in range(OPEN_TREES)]


def _open_street(seed: int, static: np.ndarray):
    """The ``"open"`` layout: (the static boxes with the buildings moved, the added cylinders)."""
    rng = np.random.default_rng([seed, 37, 6])
    boxes = static.copy()
    boxes[_RIGHT_ROW, 1] -= rng.uniform(14.0, 28.0, size=_RIGHT_ROW.size)
    back = rng.choice(_LEFT_ROW, size=2, replace=False)
    boxes[back, 1] += rng.uniform(12.0, 20.0, size=2)
    cyls = [[x, y, r, 0.0, h + 0.5] for x, y, r, h in _open_trees(seed)]
    for _ in range(OPEN_POSTS):
        cyls.append([rng.uniform(-40.0, 70.0), -rng.uniform(9.0, 25.0), rng.uniform(0.08, 0.12), 0.0,
                     rng.uniform(6.0, 9.0)])
    return boxes, cyls


def _near_xy(rng, lo: float, hi: float):
    """A spot beside the road within 9.5 m of the ego: |y| in [lo, hi] m, then x within the circle."""
    y = rng.uniform(lo, hi)
    return rng.uniform(-1.0, 1.0) * math.sqrt(9.5 ** 2 - y ** 2), rng.choice([1.0, -1.0]) * y


def _near_clutter(seed: int):
    """The ``"cluttered"`` layout's near clutter: (boxes, cylinders)."""
    rng = np.random.default_rng([seed, 37, 8])
    boxes, cyls = [], []
    for _ in range(NEAR_BARRIERS):
        x, y = _near_xy(rng, 3.2, 4.5)
        boxes.append(box_row(x, y, 0.0, rng.uniform(1.2, 2.5), rng.uniform(0.3, 0.6), rng.uniform(0.8, 1.1),
                             math.radians(rng.uniform(-20.0, 20.0))))
    for _ in range(NEAR_BOLLARDS):
        x, y = _near_xy(rng, 3.2, 6.0)
        cyls.append([x, y, rng.uniform(0.06, 0.12), 0.0, rng.uniform(0.8, 1.2)])
    for _ in range(NEAR_PEOPLE):
        x, y = _near_xy(rng, 4.0, 8.0)
        h, yaw = rng.uniform(1.55, 1.9), rng.uniform(0.0, math.pi)
        boxes.append(box_row(x, y, 0.0, 0.25, 0.38, 0.83 * h, yaw))
        cyls.append([x, y, 0.1, 0.83 * h, h])
    for _ in range(NEAR_BLOCKS):
        x, y = _near_xy(rng, 3.5, 8.0)
        boxes.append(box_row(x, y, 0.0, rng.uniform(0.3, 1.2), rng.uniform(0.3, 1.0), rng.uniform(0.3, 1.3),
                             rng.uniform(0.0, math.pi)))
    return boxes, cyls


def _clutter_spheres(seed: int) -> list:
    """The ``"cluttered"`` layout's spheres: near bushes, then the far shrubs on the open right side."""
    rng = np.random.default_rng([seed, 37, 9])
    out = []
    for _ in range(NEAR_BUSHES):
        x, y = _near_xy(rng, 4.5, 8.0)
        r = rng.uniform(0.3, 0.8)
        out.append([x, y, r * rng.uniform(0.3, 0.9), r])
    for _ in range(FAR_SHRUBS):
        r = rng.uniform(0.6, 1.8)
        out.append([rng.uniform(-60.0, 90.0), -rng.uniform(20.0, 70.0), r * rng.uniform(0.3, 0.9), r])
    return out


def twin_scene(seed: int, sweep: int, *, dt_s: float = SWEEP_DT_S, layout: str = "street") -> SceneArrays:
    """The world at sweep ``sweep`` (0 = reference; the movers ``sweep * dt_s`` seconds earlier), frame ``W``,
    in scene layout ``layout`` (:data:`LAYOUTS`).

    Returns:
      :class:`SceneArrays` (ground plane ``z = 0``), the same shapes for every seed and sweep of a layout.
    """
    check_layout(layout)
    base = street_scene_arrays(seed, lidar_height_m=0.0)
    static = np.delete(np.asarray(base.boxes), _LANE_CAR_BOXES, axis=0)
    mover_boxes, mover_cyls = _mover_prims(seed, sweep * dt_s)
    clutter_boxes, clutter_cyls = _clutter(seed)
    if layout in ("open", "cluttered"):
        static, open_cyls = _open_street(seed, static)
        clutter_cyls = clutter_cyls + open_cyls
    if layout == "cluttered":
        near_boxes, near_cyls = _near_clutter(seed)
        clutter_boxes, clutter_cyls = clutter_boxes + near_boxes, clutter_cyls + near_cyls
    boxes = np.concatenate([static, np.asarray(mover_boxes + clutter_boxes, np.float64)])
    cyls = np.concatenate([np.asarray(base.cylinders), np.asarray(mover_cyls + clutter_cyls, np.float64)])
    return scene_arrays(planes=base.planes, boxes=boxes, cylinders=cyls)


def mover_scene(seed: int, sweep: int, *, dt_s: float = SWEEP_DT_S) -> SceneArrays:
    """Only the movers at sweep ``sweep`` (for ghost regions), frame ``W``."""
    boxes, cyls = _mover_prims(seed, sweep * dt_s)
    return scene_arrays(boxes=boxes, cylinders=cyls)


__all__ = ["LAYOUTS", "SWEEP_DT_S", "mover_scene", "twin_scene", "twin_spheres"]
