"""The twins' scene layouts (``make_twin(layout=)``) and the far-structure statistics that matched them
(:func:`jaxdepth.research.twin_measure.scene_statistics`) against NumPy counts."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from jaxdepth.research.twin_measure import SCENE_EDGE_BINS_M, scene_statistics
from jaxdepth.research.twin_rigs import RIG_BUILDERS
from jaxdepth.research.twin_scene import (
    FAR_SHRUBS,
    LAYOUTS,
    NEAR_BARRIERS,
    NEAR_BLOCKS,
    NEAR_BOLLARDS,
    NEAR_BUSHES,
    NEAR_PEOPLE,
    twin_scene,
    twin_spheres,
)
from jaxdepth.research.twin_sensors import NO_EFFECTS
from jaxdepth.research.twins import make_twin
from tests.test_twins import _surface_distance, _to_world

SCALE = 0.1
pytestmark = pytest.mark.xdist_group("twins")


@pytest.fixture(scope="module")
def open_exact():
    return make_twin("nuscenes", sweeps=1, seed=1, scale=SCALE, effects=False, layout="open")


def _camera_count(points, cam, lo):
    """Points projecting into ``cam`` with camera depth >= ``lo``, and all of them: one point at a time."""
    T, K = np.asarray(cam.T_cam_lidar, np.float64), np.asarray(cam.K, np.float64)
    seen = far = 0
    for x, y, z in np.asarray(points, np.float64):
        X, Y, Z = T[:3, :3] @ (x, y, z) + T[:3, 3]
        if Z <= 0.1:
            continue
        u, v = K[0, 0] * X / Z + K[0, 2], K[1, 1] * Y / Z + K[1, 2]
        if 0 <= u < cam.width and 0 <= v < cam.height:
            seen += 1
            far += Z >= lo
    return far, seen


def _ring_edges(points, ring):
    """Edges per ring by the far side's range bin: a plain loop over each ring's azimuth-sorted returns."""
    bins = SCENE_EDGE_BINS_M
    count, lines = np.zeros(len(bins) - 1), 0
    for b in np.unique(ring):
        p = [q for q, r in zip(np.asarray(points, np.float64), ring) if r == b and np.linalg.norm(q) > 1.0]
        if len(p) < 200:
            continue
        lines += 1
        p.sort(key=lambda q: math.atan2(q[1], q[0]))
        az = [math.atan2(q[1], q[0]) for q in p]
        step = float(np.median(np.diff(az)))
        for i in range(len(p) - 1):
            a, c = float(np.linalg.norm(p[i])), float(np.linalg.norm(p[i + 1]))
            if az[i + 1] - az[i] < 1.5 * step and abs(a - c) > max(1.0, 0.05 * min(a, c)):
                k = next(j for j in range(len(bins) - 1) if bins[j] <= max(a, c) < bins[j + 1])
                count[k] += 1
    return count / max(lines, 1), lines


def test_scene_statistics_match_a_plain_count_on_an_analytic_ring():
    """Four rings of 720 returns: a wall at 8 m with two posts at 5 m (4 edges at 8 m), and behind a gap a
    building at 30 m with a tree at 24 m (4 edges at 30 m); one camera looking along +x."""
    rng = np.random.default_rng(0)
    az = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    r = np.where(np.abs(az) < 0.5, 30.0, 8.0)
    r[(az > 0.1) & (az < 0.2)] = 24.0
    r[(az > 1.0) & (az < 1.05)] = 5.0
    r[(az > -1.5) & (az < -1.45)] = 5.0
    pts, ring = [], []
    for b, el in enumerate((-0.1, -0.05, 0.0, 0.05)):
        rr = r + rng.uniform(-0.05, 0.05, r.size)
        pts.append(np.stack([rr * np.cos(el) * np.cos(az), rr * np.cos(el) * np.sin(az), rr * np.sin(el)], 1))
        ring.append(np.full(az.size, b))
    pts, ring = np.concatenate(pts), np.concatenate(ring)
    # Camera: x forward -> camera z, y left -> camera -x, z up -> camera -y.
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]
    cam = SimpleNamespace(name="front", K=np.array([[200.0, 0, 160], [0, 200.0, 120], [0, 0, 1]]),
                          T_cam_lidar=T, width=320, height=240)
    st = scene_statistics(pts, ring, [cam])
    far, seen = _camera_count(pts, cam, 20.0)
    assert st["cameras"]["front"]["count"] == seen > 0
    assert st["cameras"]["front"]["share_ge_20m"] == pytest.approx(far / seen)
    per_line, lines = _ring_edges(pts, ring)
    assert st["edges"]["lines"] == lines == 4
    np.testing.assert_allclose(list(st["edges"]["per_line"].values()), per_line)
    np.testing.assert_allclose(per_line, [4, 0, 4, 0])       # the analytic count


def test_street_layout_is_the_default():
    a = make_twin("nuscenes", sweeps=1, seed=0, scale=SCALE, effects=False)
    b = make_twin("nuscenes", sweeps=1, seed=0, scale=SCALE, effects=False, layout="street")
    np.testing.assert_array_equal(a.cloud.points, b.cloud.points)
    np.testing.assert_array_equal(a.dense_depth, b.dense_depth)
    assert LAYOUTS[0] == "street"
    with pytest.raises(ValueError, match="layout"):
        make_twin("nuscenes", sweeps=1, seed=0, scale=SCALE, layout="canyon")


def test_open_layout_has_fixed_shapes_and_its_points_on_its_surfaces(open_exact):
    shapes = {(twin_scene(s, 0, layout="open").boxes.shape, twin_scene(s, 0, layout="open").cylinders.shape,
               twin_spheres(s, "open").shape) for s in range(3)}
    assert len(shapes) == 1
    _assert_on_surfaces(open_exact, "open", 0)


def _assert_on_surfaces(tw, layout, draw):
    """3000 of the seed-1 twin's exact points lie on the layout's surfaces (NumPy distance oracle)."""
    pick = np.random.default_rng(draw).choice(len(tw.cloud.points), size=3000, replace=False)
    p = _to_world(tw, tw.cloud.points[pick])
    dt = RIG_BUILDERS["nuscenes"](NO_EFFECTS).dt_s
    dist, inside = _surface_distance(p, twin_scene(1, 0, dt_s=dt, layout=layout), twin_spheres(1, layout))
    tol = 1e-4 + 2e-6 * np.linalg.norm(tw.cloud.points[pick], axis=1)
    assert np.all(dist <= tol) and np.all(inside <= tol)


def test_open_layout_sees_far_on_the_right(open_exact):
    """The right-hand cameras see beyond 20 m (the real sample: 39-40 % of their points), the street's not."""
    street = make_twin("nuscenes", sweeps=1, seed=1, scale=SCALE, effects=False)
    for name in ("CAM_FRONT_RIGHT", "CAM_BACK_RIGHT"):
        cam = next(c for c in open_exact.rig.cameras if c.name == name)
        far, seen = _camera_count(open_exact.cloud.points, cam, 20.0)
        far_street, seen_street = _camera_count(street.cloud.points, cam, 20.0)
        assert far / seen > 0.25 > 0.1 > far_street / seen_street
        st = scene_statistics(open_exact.cloud.points, open_exact.cloud.ring, [cam])
        assert st["cameras"][name]["share_ge_20m"] == pytest.approx(far / seen)


@pytest.fixture(scope="module")
def cluttered_exact():
    return make_twin("nuscenes", sweeps=1, seed=1, scale=SCALE, effects=False, layout="cluttered")


def test_cluttered_layout_is_the_open_one_plus_its_clutter():
    """Every seed: the same shapes; the open layout's primitives first and unchanged, then the added ones,
    the near clutter within 10 m of the ego (footprint centres) and the far shrubs 20-70 m to the right."""
    shapes = set()
    for s in range(3):
        op, cl = twin_scene(s, 0, layout="open"), twin_scene(s, 0, layout="cluttered")
        so, sc = twin_spheres(s, "open"), twin_spheres(s, "cluttered")
        shapes.add((cl.boxes.shape, cl.cylinders.shape, sc.shape))
        np.testing.assert_array_equal(cl.boxes[:len(op.boxes)], op.boxes)
        np.testing.assert_array_equal(cl.cylinders[:len(op.cylinders)], op.cylinders)
        np.testing.assert_array_equal(sc[:len(so)], so)
        near = np.concatenate([cl.boxes[len(op.boxes):, :2], cl.cylinders[len(op.cylinders):, :2],
                               sc[len(so):len(so) + NEAR_BUSHES, :2]])
        assert np.all(np.hypot(near[:, 0], near[:, 1]) < 10.0)
        assert len(near) == NEAR_BARRIERS + NEAR_BLOCKS + NEAR_BOLLARDS + 2 * NEAR_PEOPLE + NEAR_BUSHES
        far = sc[len(so) + NEAR_BUSHES:]
        assert len(far) == FAR_SHRUBS and np.all((far[:, 1] <= -20.0) & (far[:, 1] >= -70.0))
    assert len(shapes) == 1


def test_cluttered_layout_points_on_its_surfaces(cluttered_exact):
    _assert_on_surfaces(cluttered_exact, "cluttered", 1)


def test_cluttered_layout_near_edges_by_a_plain_count(cluttered_exact, open_exact):
    """Its statistics equal a plain per-ring count, and the near clutter adds depth edges within 10 m
    (the real sample: 2.7 per scan line; the open layout 0.2-0.5)."""
    lo, hi = 8, 14           # rings 8-13 of 32 (those that reach the ground within 10 m): a small scene
    out = {}
    for name, tw in (("open", open_exact), ("cluttered", cluttered_exact)):
        sel = (tw.cloud.ring >= lo) & (tw.cloud.ring < hi)
        pts, ring = tw.cloud.points[sel], tw.cloud.ring[sel]
        st = scene_statistics(pts, ring, tw.rig.cameras[:1])
        per_line, lines = _ring_edges(pts, ring)
        assert st["edges"]["lines"] == lines
        np.testing.assert_allclose(list(st["edges"]["per_line"].values()), per_line)
        out[name] = per_line[0]
    assert out["cluttered"] > out["open"] + 1.0
