"""Putting a sweep in its LiDAR's frame: rig origin field, shifted extrinsics, invariance."""

from __future__ import annotations

import functools
import json

import jax.numpy as jnp
import numpy as np
import pytest

import jaxdepth
from jaxdepth._src import presets
from jaxdepth._src.geometry import project_to_image
from jaxdepth._src.synthetic import make_street_scene
from jaxdepth.io import InputError, Rig, RigCamera, prepare_sweep, read_rig_json, shift_rig, write_rig_json

from scenes import stereo_street


def _rig_from_frame(frame, *, origin=None, T_extra=None):
    cams = []
    for i, cam in enumerate(frame.cameras):
        T = np.asarray(cam.T_cam_lidar, np.float64)
        if T_extra is not None:
            T = T @ T_extra
        cams.append(RigCamera(f"cam{i}", cam.width, cam.height, np.asarray(cam.K), T.astype(np.float32)))
    return Rig(lidar=frame.lidar, cameras=tuple(cams), lidar_origin_m=origin)


@pytest.fixture(scope="module")
def street():
    """The shared small stereo street (``scenes.stereo_street``: SMALL_LIDAR, two 1/4-scale cameras), whose
    two-camera ``complete_rig`` program tests/test_rig.py compiles."""
    return stereo_street()[0]


def test_origin_round_trips_through_json(tmp_path, street):
    rig = _rig_from_frame(street, origin=(0.8, -0.1, 1.9))
    path = write_rig_json(tmp_path / "rig.json", rig)
    back = read_rig_json(path)
    assert back.lidar_origin_m == pytest.approx((0.8, -0.1, 1.9)) and back == rig
    doc = json.loads(path.read_text())
    assert doc["lidar"]["origin_m"] == pytest.approx([0.8, -0.1, 1.9])


@pytest.mark.parametrize("value, message", [
    ([1.0, 2.0], "lidar.origin_m"),
    ("up", "lidar.origin_m"),
    ([0.0, "a", 1.0], r"lidar.origin_m\[1\]"),
])
def test_bad_origin_names_the_field(tmp_path, value, message):
    doc = {"lidar": {"beams": 32, "origin_m": value},
           "cameras": [{"name": "c", "width": 8, "height": 6, "K": [[5, 0, 4], [0, 5, 3], [0, 0, 1]],
                        "T_cam_lidar": np.eye(4).tolist()}]}
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=message):
        read_rig_json(path)


def test_stated_fields_are_recorded(tmp_path):
    doc = {"lidar": {"beams": 16},
           "cameras": [{"name": "c", "width": 8, "height": 6, "K": [[5, 0, 4], [0, 5, 3], [0, 0, 1]],
                        "T_cam_lidar": np.eye(4).tolist()}]}
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(doc))
    rig = read_rig_json(path)
    assert rig.lidar_stated == frozenset({"beams"}) and rig.lidar_origin_m is None


def test_shift_keeps_every_projection(street):
    """Points moved by -o and extrinsics composed with +o: every camera sees the same depth image."""
    origin = np.array([0.9, 0.2, 1.8])
    rig = _rig_from_frame(street)
    shifted = shift_rig(rig, origin)
    moved = (street.points.astype(np.float64) - origin).astype(np.float32)
    for a, b in zip(rig.cameras, shifted.cameras):
        da, _ = project_to_image(jnp.asarray(street.points), jnp.asarray(street.valid), a.K, a.T_cam_lidar,
                                 height=a.height, width=a.width)
        db, _ = project_to_image(jnp.asarray(moved), jnp.asarray(street.valid), b.K, b.T_cam_lidar,
                                 height=b.height, width=b.width)
        da, db = np.asarray(da), np.asarray(db)
        assert ((da > 0) == (db > 0)).mean() > 0.999
        both = (da > 0) & (db > 0)
        np.testing.assert_allclose(da[both], db[both], rtol=1e-5, atol=1e-5)


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_stated_origin_recovers_the_sensor_frame(street):
    """A sweep given in a vehicle frame (sensor 1.7 m up, 1.2 m ahead of the origin) with its origin
    stated in the rig completes like the sweep in the sensor's own frame."""
    origin = np.array([1.2, 0.0, 1.7])
    to_vehicle = np.eye(4)
    to_vehicle[:3, 3] = -origin                 # p_sensor = p_vehicle - origin
    vehicle_points = (street.points.astype(np.float64) + origin).astype(np.float32)
    rig_vehicle = _rig_from_frame(street, origin=tuple(origin), T_extra=to_vehicle)
    frame = prepare_sweep(vehicle_points, rig_vehicle)
    assert frame.origin_source == "rig" and frame.outlier_removal_trusted
    np.testing.assert_allclose(frame.points, street.points, atol=2e-6 * 60)
    sensor_rig = _rig_from_frame(street)
    for a, b in zip(frame.rig.cameras, sensor_rig.cameras):
        np.testing.assert_allclose(a.T_cam_lidar, b.T_cam_lidar, atol=1e-6)
    valid = jnp.asarray(street.valid)
    got = jaxdepth.complete_rig(jnp.asarray(frame.points), valid,
                                jaxdepth.stack_cameras([c.as_camera() for c in frame.rig.cameras]),
                                lidar=street.lidar)
    want = jaxdepth.complete_rig(jnp.asarray(street.points), valid,
                                 jaxdepth.stack_cameras([c.as_camera() for c in sensor_rig.cameras]),
                                 lidar=street.lidar)
    got, want = np.asarray(got), np.asarray(want)
    close = np.abs(got - want) <= 1e-3 * np.maximum(want, 1.0)
    assert close.mean() > 0.995


def test_no_estimate_keeps_the_points(street):
    rig = _rig_from_frame(street)
    frame = prepare_sweep(street.points, rig, estimate=False)
    assert frame.origin_source == "points" and frame.rig is rig
    np.testing.assert_array_equal(frame.points, street.points)


# ---------------------------------------------------------------- the estimate from the sweep
from jaxdepth.io.lidar_estimate import estimate_lidar_geometry  # noqa: E402
from jaxdepth._src.types import LidarSpec  # noqa: E402


@functools.lru_cache(maxsize=None)
def _street(spec):
    """The street seen by ``spec`` at 1/4 scale, made once per module (its HDL-32 frame serves three cases)."""
    return make_street_scene(0, lidar=spec, image_scale=0.25)


@pytest.mark.xdist_group("sweep_frame_hdl32")  # the HDL-32 street's render programs: one worker (suite18)
@pytest.mark.parametrize("spec", [LidarSpec(beams=16, fov_up_deg=15.0, fov_down_deg=-15.0, columns=1800),
                                  presets.NUSCENES_HDL32, presets.KITTI_HDL64])
def test_spinning_sweep_in_its_frame_is_recognised(spec):
    frame = _street(spec)
    points = frame.points[frame.valid]
    est = estimate_lidar_geometry(points)
    assert est.spinning and np.array_equal(est.origin_m, np.zeros(3))
    ring = np.repeat(np.arange(spec.beams), spec.columns)[frame.valid]   # row major (beam, column)
    with_ring = estimate_lidar_geometry(points, ring=ring)
    assert with_ring.spinning and with_ring.beams == len(np.unique(ring))
    top = spec.fov_up_deg if ring.min() == 0 else None
    if top is not None:
        assert abs(with_ring.fov_up_deg - spec.fov_up_deg) < 0.05
    assert abs(with_ring.fov_down_deg - spec.fov_down_deg) < 0.05


@pytest.mark.xdist_group("sweep_frame_hdl32")
@pytest.mark.parametrize("offset", [(1.2, -0.1, 1.8), (-0.9, 0.0, 1.6)])
def test_vehicle_frame_and_cones_are_not_trusted(offset):
    frame = _street(presets.NUSCENES_HDL32)
    points = frame.points[frame.valid] + np.asarray(offset, np.float32)
    ring = np.repeat(np.arange(32), presets.NUSCENES_HDL32.columns)[frame.valid]
    assert not estimate_lidar_geometry(points).spinning
    assert not estimate_lidar_geometry(points, ring=ring).spinning
    cone = frame.points[frame.valid]
    cone = cone[cone[:, 0] > np.abs(cone[:, 1])]                 # a forward-looking scan: no full turn
    est = estimate_lidar_geometry(cone)
    assert not est.spinning and est.azimuth_cover < 0.5


def test_prepare_sweep_backs_off_for_a_vehicle_frame(street):
    rig = _rig_from_frame(street)
    frame = prepare_sweep(street.points[street.valid] + np.float32([1.2, -0.1, 1.8]), rig)
    assert not frame.outlier_removal_trusted and frame.origin_source == "points"
    assert any("lidar.origin_m" in note for note in frame.notes)
    inframe = prepare_sweep(street.points[street.valid], rig)
    assert inframe.outlier_removal_trusted and inframe.rig is rig


@pytest.mark.shared_data
def test_real_sweeps_are_in_their_sensor_frame(kitti, nuscenes_sample):
    import glob
    from jaxdepth.io import read_points
    assert estimate_lidar_geometry(kitti.scan).spinning
    assert not estimate_lidar_geometry(kitti.scan + np.float32([-0.8, 0.3, 1.73])).spinning
    points, extra = read_points(glob.glob(str(nuscenes_sample / "*LIDAR_TOP*.pcd.bin"))[0], columns=5)
    est = estimate_lidar_geometry(points, ring=extra[:, 1])
    assert est.spinning and est.beams == 32
    assert abs(est.fov_up_deg - 10.67) < 0.5 and abs(est.fov_down_deg + 30.67) < 1.0
    assert not estimate_lidar_geometry(points + np.float32([0.94, 0.0, 1.84]), ring=extra[:, 1]).spinning


@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.uint16, np.int32, np.int64, np.uint64, np.float32])
def test_ring_labels_are_numpys_unique(dtype):
    from jaxdepth.io.lidar_estimate import ring_labels
    rng = np.random.default_rng(7)
    cases = [rng.choice([0, 3, 4, 31, 90], size=5000), rng.integers(0, 128, 3000), np.array([5]), np.array([], int)]
    if np.dtype(dtype).kind != "u":
        cases += [rng.integers(-3, 3, 200)]                     # negative rings: not counted
    if np.dtype(dtype).itemsize > 1:
        cases += [np.array([0, 65535, 65536, 7, 7])]            # beyond the counted range
    for ring in (np.asarray(c).astype(dtype) for c in cases):
        labels, inverse = ring_labels(ring)
        want_labels, want_inverse = np.unique(ring, return_inverse=True)
        assert labels.dtype == want_labels.dtype and inverse.dtype == want_inverse.dtype
        np.testing.assert_array_equal(labels, want_labels)
        np.testing.assert_array_equal(inverse, want_inverse)


def test_ring_medians_are_numpys_masked_medians():
    from jaxdepth.io.lidar_estimate import ring_medians
    rng = np.random.default_rng(11)
    for count, n in ((32, 4001), (5, 10), (70_000, 2000)):      # the last: more rings than a 16-bit key holds
        inverse = rng.integers(0, count, n)
        inverse[inverse == 1] = 0                               # ring 1 empty: NaN
        values = rng.normal(size=n) * 10
        values[::7] = values[0]                                 # ties
        got = ring_medians(values, inverse, count)
        assert got.dtype == np.float64 and got.shape == (count,)
        for i in np.unique(inverse)[:200]:
            assert got[i] == np.median(values[inverse == i])    # the same number, bit for bit
        assert np.isnan(got[1])
