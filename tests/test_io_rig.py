"""Rig JSON reader/writer and the KITTI / nuScenes converters."""

from __future__ import annotations

import copy
import json

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxdepth._src.geometry import project_to_image
from jaxdepth._src.presets import KITTI_HDL64, KITTI_T_CAM2_LIDAR, NUSCENES_HDL32
from jaxdepth._src.types import Camera, LidarSpec
from jaxdepth.io import (BENCHMARK_SIZE, InputError, OutputError, Rig, RigCamera, crop_to_benchmark,
                         default_lidar_spec, pad_points, read_kitti_raw_calib, read_points, read_rig_json,
                         rig_from_kitti_raw, rig_from_nuscenes_calibration, write_rig_json)

_HYP = settings(deadline=None, max_examples=40, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _rot(rx, ry, rz) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.array([rx, ry, rz], np.float64))
    return R


def _doc(n_cameras=3) -> dict:
    cams = []
    for i in range(n_cameras):
        T = np.eye(4)
        T[:3, :3] = _rot(0.1 * i, -0.2, 0.3 + i)
        T[:3, 3] = [0.1 * i, -0.3, 0.5]
        cams.append({"name": f"CAM_{i}", "width": 1600, "height": 900,
                     "K": [[1266.4, 0, 816.3], [0, 1266.4, 491.5], [0, 0, 1]], "T_cam_lidar": T.tolist()})
    return {"lidar": {"beams": 64}, "cameras": cams}


def _write_doc(path, doc):
    path.write_text(json.dumps(doc))
    return path


def test_minimal_rig_and_defaults(tmp_path):
    rig = read_rig_json(_write_doc(tmp_path / "rig.json", _doc()))
    assert rig.lidar == KITTI_HDL64
    assert [c.name for c in rig.cameras] == ["CAM_0", "CAM_1", "CAM_2"]
    cam = rig.cameras[2]
    assert cam.K.dtype == np.float32 and cam.T_cam_lidar.dtype == np.float32
    assert cam.K.shape == (3, 3) and cam.T_cam_lidar.shape == (4, 4)
    np.testing.assert_allclose(cam.T_cam_lidar, np.array(_doc()["cameras"][2]["T_cam_lidar"]), atol=1e-7)
    with pytest.raises(ValueError):
        cam.K[0, 0] = 1.0  # frozen data, not only frozen attributes
    assert rig.camera("CAM_1") is rig.cameras[1]
    with pytest.raises(KeyError, match="CAM_9"):
        rig.camera("CAM_9")


@pytest.mark.parametrize("lidar, want", [
    ({"beams": 32}, NUSCENES_HDL32),
    ({"beams": 16}, LidarSpec(beams=16, fov_up_deg=2.0, fov_down_deg=-24.9, columns=2048)),
    ({"beams": 64, "columns": 1024, "units": "m"}, LidarSpec(64, 2.0, -24.9, 1024)),
    ({"beams": 32, "fov_up_deg": 15, "fov_down_deg": -15.5}, LidarSpec(32, 15.0, -15.5, 1088)),
])
def test_lidar_defaults_from_beam_table(tmp_path, lidar, want):
    doc = _doc(1)
    doc["lidar"] = lidar
    assert read_rig_json(_write_doc(tmp_path / "r.json", doc)).lidar == want
    assert default_lidar_spec(lidar["beams"]).beams == lidar["beams"]


@settings(deadline=None, max_examples=25)
@given(n=st.integers(1, 4), seed=st.integers(0, 2**32 - 1), beams=st.sampled_from([16, 32, 64, 128]))
def test_round_trip(tmp_path_factory, n, seed, beams):
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        T = np.eye(4)
        T[:3, :3] = _rot(*rng.uniform(-3, 3, 3))
        T[:3, 3] = rng.uniform(-5, 5, 3)
        K = np.array([[rng.uniform(100, 2000), rng.uniform(-1, 1), rng.uniform(0, 1600)],
                      [0, rng.uniform(100, 2000), rng.uniform(0, 900)], [0, 0, 1]])
        cams.append(RigCamera(f"cam \"{i}\" é", int(rng.integers(1, 4000)), int(rng.integers(1, 4000)), K, T))
    rig = Rig(lidar=default_lidar_spec(beams), cameras=tuple(cams))
    path = tmp_path_factory.mktemp("rig") / "rig.json"
    write_rig_json(path, rig)
    back = read_rig_json(path)
    assert back == rig  # exact float32 equality
    for a, b in zip(back.cameras, rig.cameras):
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.T_cam_lidar, b.T_cam_lidar)
    assert json.loads(path.read_text())["lidar"]["units"] == "m"
    write_rig_json(path, back)
    assert read_rig_json(path) == rig


def test_write_is_atomic_and_respects_overwrite(tmp_path):
    rig = read_rig_json(_write_doc(tmp_path / "in.json", _doc(1)))
    before = (tmp_path / "in.json").read_text()
    with pytest.raises(OutputError, match=r"in\.json: already exists"):
        write_rig_json(tmp_path / "in.json", rig, overwrite=False)
    assert (tmp_path / "in.json").read_text() == before
    with pytest.raises(OutputError, match="does not exist"):
        write_rig_json(tmp_path / "missing" / "rig.json", rig)
    with pytest.raises(ValueError, match=r"'rig' expected a Rig, got dict"):
        write_rig_json(tmp_path / "x.json", _doc())


def _mutate(doc, where, value):
    """where: list of keys / indices; value=... deletes."""
    doc = copy.deepcopy(doc)
    target = doc
    for key in where[:-1]:
        target = target[key]
    if value is Ellipsis:
        del target[where[-1]]
    else:
        target[where[-1]] = value
    return doc


def _field(pattern: str) -> str:
    return pattern if pattern.startswith("field ") else "field " + pattern


_SHEAR = [[1, 0.2, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
_MIRROR = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]
_SCALED = [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]
_SINGULAR = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]


@pytest.mark.parametrize("where, value, pattern", [
    (["cameras", 2, "T_cam_lidar"], _SHEAR, r"field 'cameras\[2\]\.T_cam_lidar' expected a rigid transform"),
    (["cameras", 2, "T_cam_lidar"], _MIRROR, r"'cameras\[2\]\.T_cam_lidar' expected a rigid .*det R = -1"),
    (["cameras", 2, "T_cam_lidar"], _SCALED, r"'cameras\[2\]\.T_cam_lidar' expected a rigid"),
    (["cameras", 2, "T_cam_lidar"], _SINGULAR, r"'cameras\[2\]\.T_cam_lidar' expected a rigid .*det R = 0"),
    (["cameras", 1, "T_cam_lidar", 3], [0, 0, 1, 1], r"'cameras\[1\]\.T_cam_lidar' expected last row \[0, 0, 0, 1\]"),
    (["cameras", 1, "T_cam_lidar", 3], [0, 0, 1], r"'cameras\[1\]\.T_cam_lidar\[3\]' expected a row of 4 numbers, "
                                                    r"got a list of 3"),
    (["cameras", 1, "T_cam_lidar"], [[1, 0, 0, 0]] * 3, r"'cameras\[1\]\.T_cam_lidar' expected a 4x4 matrix"),
    (["cameras", 0, "T_cam_lidar"], ..., r"'cameras\[0\]\.T_cam_lidar' expected a field \(required\), got nothing"),
    (["cameras", 0, "K", 0, 0], -5, r"'cameras\[0\]\.K' expected positive focal lengths"),
    (["cameras", 0, "K", 1, 1], 0, r"'cameras\[0\]\.K' expected positive focal lengths .*fy=0"),
    (["cameras", 0, "K", 1, 1], "700", r"'cameras\[0\]\.K\[1\]\[1\]' expected a number, got \"700\""),
    (["cameras", 0, "K", 1, 1], True, r"'cameras\[0\]\.K\[1\]\[1\]' expected a number, got true"),
    (["cameras", 0, "K", 2], [0, 0, 2], r"'cameras\[0\]\.K' expected a pinhole matrix"),
    (["cameras", 0, "K"], [[1, 0, 0], [0, 1, 0]], r"'cameras\[0\]\.K' expected a 3x3 matrix"),
    (["cameras", 0, "width"], 0, r"'cameras\[0\]\.width' expected a positive integer, got 0"),
    (["cameras", 0, "height"], 900.5, r"'cameras\[0\]\.height' expected a positive integer, got 900.5"),
    (["cameras", 0, "name"], "", r"'cameras\[0\]\.name' expected a non-empty string"),
    (["cameras", 2, "name"], "CAM_0", r"'cameras\[2\]\.name' expected a unique name \(cameras\[0\] is also 'CAM_0'\)"),
    (["cameras", 1, "distortion"], [0, 0], r"'cameras\[1\]\.distortion' expected one of the known fields"),
    (["cameras"], [], r"field 'cameras' expected a non-empty list"),
    (["cameras"], ..., r"field 'cameras' expected a field \(required\)"),
    (["cameras", 1], "CAM", r"field 'cameras\[1\]' expected an object, got \"CAM\""),
    (["lidar", "units"], "mm", r"field 'lidar\.units' expected \"m\" \(metres; unknown units\), got \"mm\""),
    (["lidar", "beams"], ..., r"field 'lidar\.beams' expected a positive integer \(required\)"),
    (["lidar", "beams"], -3, r"field 'lidar\.beams' expected a positive integer, got -3"),
    (["lidar", "columns"], 2, r"field 'lidar\.columns' expected an integer >= 4, got 2"),
    (["lidar", "fov_up_deg"], -30, r"field 'lidar\.fov_up_deg' expected -90 <= fov_down_deg < fov_up_deg <= 90"),
    (["lidar", "fov_down_deg"], None, r"field 'lidar\.fov_down_deg' expected a finite number, got null"),
    (["lidar", "range"], 100, r"field 'lidar\.range' expected one of the known fields"),
    (["lidar"], [64], r"field 'lidar' expected an object, got a list of 1"),
    (["extra"], 1, r"field 'extra' expected one of the known fields"),
])
def test_error_messages_name_file_and_field(tmp_path, where, value, pattern):
    path = _write_doc(tmp_path / "my_rig.json", _mutate(_doc(), where, value))
    with pytest.raises(InputError, match=r"^\S*my_rig\.json: " + _field(pattern)):
        read_rig_json(path)


@pytest.mark.parametrize("text, pattern", [
    ("{", r"bad\.json: invalid JSON at line 1 column 2"),
    ("[1, 2]", r"bad\.json: field '\(top level\)' expected an object"),
    ('{"lidar": {"beams": 64, "beams": 32}, "cameras": []}', r"bad\.json: key 'beams' appears more than once"),
    ('{"lidar": {"beams": NaN}, "cameras": []}', r"bad\.json: field 'lidar\.beams' expected a positive integer"),
    ("[" * 100000, r"bad\.json: invalid JSON"),
])
def test_json_level_errors(tmp_path, text, pattern):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(InputError, match=pattern):
        read_rig_json(path)
    with pytest.raises(InputError, match=r"absent\.json: file not found"):
        read_rig_json(tmp_path / "absent.json")


def test_nan_in_matrix_is_rejected(tmp_path):
    doc = _doc(1)
    text = json.dumps(doc).replace("1266.4", "NaN", 1)
    (tmp_path / "n.json").write_text(text)
    with pytest.raises(InputError, match=r"'cameras\[0\]\.K' expected a 3x3 matrix of finite numbers"):
        read_rig_json(tmp_path / "n.json")


def test_rig_camera_constructor_validates():
    with pytest.raises(ValueError, match=r"RigCamera: field 'T_cam_lidar' expected a rigid"):
        RigCamera("a", 10, 10, np.eye(3), np.diag([1.0, 1.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match=r"Rig: field 'cameras' expected distinct names, got duplicates \['a'\]"):
        Rig(KITTI_HDL64, (RigCamera("a", 10, 10, np.eye(3), np.eye(4)),) * 2)
    with pytest.raises(ValueError, match=r"Rig: field 'cameras' expected a non-empty"):
        Rig(KITTI_HDL64, ())
    cam = RigCamera("a", 10, 20, np.eye(3), np.eye(4)).as_camera()
    assert isinstance(cam, Camera) and (cam.height, cam.width) == (20, 10)


# ---------------------------------------------------------------- fuzzing

_json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-5, 5000) | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=8),
    lambda children: st.lists(children, max_size=5) | st.dictionaries(
        st.sampled_from(["lidar", "cameras", "beams", "units", "name", "width", "height", "K", "T_cam_lidar",
                         "columns", "fov_up_deg", "x"]), children, max_size=6),
    max_leaves=40)


@_HYP
@given(doc=_json_values)
def test_fuzz_random_json(tmp_path, doc):
    path = tmp_path / "f.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError):
        read_rig_json(path)


@_HYP
@given(where=st.sampled_from([["cameras", 0, "K", 0], ["cameras", 1, "T_cam_lidar", 2, 1], ["lidar", "beams"],
                              ["cameras", 2, "width"], ["cameras", 0, "name"], ["lidar", "columns"]]),
       value=_json_values)
def test_fuzz_field_values(tmp_path, where, value):
    path = _write_doc(tmp_path / "f.json", _mutate(_doc(), where, value))
    try:
        rig = read_rig_json(path)
    except InputError:
        return
    assert len(rig.cameras) == 3


@_HYP
@given(data=st.binary(max_size=200))
def test_fuzz_random_bytes(tmp_path, data):
    path = tmp_path / "b.json"
    path.write_bytes(data)
    try:
        read_rig_json(path)
    except InputError:
        return
    raise AssertionError("random bytes parsed as a valid rig")


# ---------------------------------------------------------------- converters


def test_kitti_raw_converter(kitti_frame, tmp_path):
    c2c, v2c = kitti_frame / "calib_cam_to_cam.txt", kitti_frame / "calib_velo_to_cam.txt"
    rig = rig_from_kitti_raw(c2c, v2c)
    calib = read_kitti_raw_calib(c2c, v2c)
    assert rig.lidar == KITTI_HDL64 and [c.name for c in rig.cameras] == ["image_02", "image_03"]
    np.testing.assert_allclose(rig.cameras[0].T_cam_lidar, KITTI_T_CAM2_LIDAR, atol=1e-5)
    for cam, i in zip(rig.cameras, (2, 3)):
        np.testing.assert_array_equal(cam.K, calib["cameras"][i]["K"])
        assert (cam.height, cam.width) == (375, 1242)
    write_rig_json(tmp_path / "kitti.json", rig)
    assert read_rig_json(tmp_path / "kitti.json") == rig
    with pytest.raises(ValueError, match=r"'cameras' expected KITTI indices in 0\.\.3, got \(2, 4\)"):
        rig_from_kitti_raw(c2c, v2c, cameras=(2, 4))


def test_kitti_raw_converter_crop_matches_cropped_projection(kitti_frame):
    """Projecting with the cropped rig equals projecting full size and cropping."""
    c2c, v2c = kitti_frame / "calib_cam_to_cam.txt", kitti_frame / "calib_velo_to_cam.txt"
    full = rig_from_kitti_raw(c2c, v2c, cameras=(2,)).cameras[0]
    crop = rig_from_kitti_raw(c2c, v2c, cameras=(2,), crop=True).cameras[0]
    assert (crop.height, crop.width) == BENCHMARK_SIZE
    np.testing.assert_allclose(crop.K[:2, 2], full.K[:2, 2] - [13, 23], atol=1e-4)
    points, _ = read_points(kitti_frame / "lidar_data.bin")
    padded, valid = pad_points(points)
    d_full, _ = project_to_image(padded, valid, full.K, full.T_cam_lidar, height=full.height, width=full.width)
    d_crop, _ = project_to_image(padded, valid, crop.K, crop.T_cam_lidar, height=crop.height, width=crop.width)
    want, _ = crop_to_benchmark(np.asarray(d_full), full.K)
    # The principal point moves by whole pixels, so the rounding is identical except for float32
    # ties: allow a handful of differing pixels out of ~18,000.
    d_crop = np.asarray(d_crop)
    assert np.count_nonzero(d_crop != want) <= 10


@pytest.fixture(scope="module")
def nuscenes_rig(nuscenes_sample):
    return rig_from_nuscenes_calibration(nuscenes_sample / "calibration.json")


def test_nuscenes_converter_fields(nuscenes_rig, nuscenes_sample):
    raw = json.loads((nuscenes_sample / "calibration.json").read_text())
    assert nuscenes_rig.lidar == NUSCENES_HDL32
    assert [c.name for c in nuscenes_rig.cameras] == list(raw["cameras"])
    assert len(nuscenes_rig.cameras) == 6
    lidar2ego = np.array(raw["lidar2ego"])
    for cam in nuscenes_rig.cameras:
        entry = raw["cameras"][cam.name]
        assert (cam.width, cam.height) == (1600, 900)
        np.testing.assert_array_equal(cam.K, np.array(entry["cam2img"], np.float32))
        # Independent check of the direction: lidar -> ego -> camera. The file's lidar2cam also
        # compensates the ego motion between the LiDAR and camera timestamps (~35 ms, ~0.3 m here), so
        # only rotation (< 0.2 degrees) and translation (< 0.5 m) agree; an inverted T would not.
        T = np.linalg.inv(np.array(entry["cam2ego"])) @ lidar2ego
        dR = cam.T_cam_lidar[:3, :3].astype(np.float64) @ T[:3, :3].T
        angle = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
        assert angle < 0.2
        assert np.linalg.norm(cam.T_cam_lidar[:3, 3] - T[:3, 3]) < 0.5


def test_nuscenes_front_camera_projection(nuscenes_rig, nuscenes_sample):
    points, extra = read_points(next(nuscenes_sample.glob("*LIDAR_TOP*.pcd.bin")), columns=5)
    padded, valid = pad_points(points)
    counts = {}
    for cam in nuscenes_rig.cameras:
        depth, index = project_to_image(padded, valid, cam.K, cam.T_cam_lidar, height=900, width=1600)
        depth, index = np.asarray(depth), np.asarray(index)
        counts[cam.name] = int((depth > 0).sum())
        # Oracle: OpenCV's projection of the winning points lands on their pixels.
        won = index[depth > 0]
        rvec, _ = cv2.Rodrigues(cam.T_cam_lidar[:3, :3].astype(np.float64))
        uv, _ = cv2.projectPoints(points[won].astype(np.float64), rvec, cam.T_cam_lidar[:3, 3].astype(np.float64),
                                  cam.K.astype(np.float64), None)
        vv, uu = np.nonzero(depth > 0)
        assert np.max(np.abs(uv[:, 0] - np.c_[uu, vv])) <= 0.5 + 1e-3
        assert 8.0 <= float(np.median(depth[depth > 0])) <= 16.5  # README: 9-16 m (measured 8.8-16.0)
    assert 3000 <= counts["CAM_FRONT"] <= 4800  # data README
    assert all(3000 <= n <= 5000 for n in counts.values()), counts  # CAM_BACK: 4,825


@pytest.mark.parametrize("edit, pattern", [
    (lambda d: d["cameras"]["CAM_FRONT"].pop("cam2img"), r"'cameras\.CAM_FRONT\.cam2img' expected a field"),
    (lambda d: d["cameras"]["CAM_BACK"].__setitem__("lidar2cam", np.diag([1, 1, -1, 1]).tolist()),
     r"'cameras\.CAM_BACK\.lidar2cam' expected a rigid transform"),
    (lambda d: d["cameras"]["CAM_BACK"]["cam2img"][0].__setitem__(0, 0.0),
     r"'cameras\.CAM_BACK\.cam2img' expected positive focal lengths"),
    (lambda d: d.pop("cameras"), r"field 'cameras' expected an object mapping camera names"),
])
def test_nuscenes_converter_errors(nuscenes_sample, tmp_path, edit, pattern):
    doc = json.loads((nuscenes_sample / "calibration.json").read_text())
    edit(doc)
    path = _write_doc(tmp_path / "calibration.json", doc)
    with pytest.raises(InputError, match=r"^\S*calibration\.json: " + _field(pattern)):
        rig_from_nuscenes_calibration(path)


def test_nuscenes_4x4_cam2img(nuscenes_sample, tmp_path, nuscenes_rig):
    doc = json.loads((nuscenes_sample / "calibration.json").read_text())
    for entry in doc["cameras"].values():
        K4 = np.eye(4)
        K4[:3, :3] = entry["cam2img"]
        entry["cam2img"] = K4.tolist()
    rig = rig_from_nuscenes_calibration(_write_doc(tmp_path / "c.json", doc))
    assert rig == nuscenes_rig
