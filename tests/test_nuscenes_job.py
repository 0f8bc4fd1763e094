"""nuScenes dataroot -> depth PNG per camera (jaxdepth.io.nuscenes, jaxdepth.batch.nuscenes_job, `complete --nusc-version`).

The dataroot is a fake v1.0-mini table set built in tmp_path around the shared
sample's real sweep and calibration (copied into tmp_path by the test only).
Cameras are the sample's six, at a quarter of the resolution (400 x 225, K
scaled) to keep the tests fast. Oracles: SciPy's quaternions and plain NumPy for
the transform chain, a NumPy z-buffer for the projection, and the existing
library path (``rig_from_nuscenes_calibration`` -> ``read_points`` ->
``prepare_sweep`` -> ``complete_rig``) for the completion.
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.conftest import require_shared

VERSION = "v1.0-mini"
SCALE = 0.25
WIDTH, HEIGHT = 400, 225
LIDAR_FILE = "n015-2018-07-24-11-22-45+0800__LIDAR_TOP__1532402927647951.pcd.bin"
T0 = 1532402927647951  # the sample's LiDAR timestamp, microseconds
D_CAM_M = 0.5  # sample 2: the vehicle moved this far forward (ego +x) between the LiDAR and the cameras
D_SWEEP_M = 0.4  # sample 2: and this far between its previous sweep and its key frame


# ---------------------------------------------------------------- oracle helpers (SciPy / NumPy)


def wxyz(R: np.ndarray) -> list:
    x, y, z, w = Rotation.from_matrix(np.asarray(R, np.float64)).as_quat()
    return [float(w), float(x), float(y), float(z)]


def oracle_pose(record: dict) -> np.ndarray:
    w, x, y, z = record["rotation"]
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    T[:3, 3] = record["translation"]
    return T


def moved(pose: dict, forward_m: float) -> dict:
    """``pose`` (ego -> global) with the vehicle moved ``forward_m`` along its own +x."""
    R = oracle_pose(pose)[:3, :3]
    return {"rotation": pose["rotation"], "translation": (np.asarray(pose["translation"]) + R[:, 0] * forward_m).tolist()}


def zbuffer(points: np.ndarray, K: np.ndarray, T: np.ndarray, height: int, width: int) -> np.ndarray:
    """NumPy projection, nearest point per pixel, pixel = round(u), round(v), depth > 0.1 m."""
    p = points[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    z = p[:, 2]
    front = z > 0.1
    uv = p[front] @ K.T
    u = np.round(uv[:, 0] / uv[:, 2]).astype(np.int64)
    v = np.round(uv[:, 1] / uv[:, 2]).astype(np.int64)
    z = z[front]
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    depth = np.full((height, width), np.inf)
    np.minimum.at(depth, (v[inside], u[inside]), z[inside])
    depth[np.isinf(depth)] = 0.0
    return depth


# ---------------------------------------------------------------- the fake dataroot


def camera_jpeg(sample_dir: pathlib.Path, channel: str) -> np.ndarray | None:
    """The shared sample's image of ``channel`` (BGR, as OpenCV reads it) at the tests' quarter size, or None."""
    found = sorted(sample_dir.glob(f"*__{channel}__*.jpg"))
    if not found:
        return None
    return cv2.resize(cv2.imread(str(found[0]), cv2.IMREAD_COLOR), (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA)


def build_dataroot(root: pathlib.Path, sample_dir: pathlib.Path) -> dict:
    """A v1.0-mini table set: sample s1 (all ego poses equal), s2 (cameras 0.5 m ahead of the
    LiDAR, one earlier sweep 0.4 m behind), s3 (its LiDAR file is missing). Every camera row's
    JPEG is the shared sample's image of that camera at quarter size (when ``sample_dir`` has it).
    Returns the tables."""
    calib = json.loads((sample_dir / "calibration.json").read_text())
    (root / "samples" / "LIDAR_TOP").mkdir(parents=True)
    (root / "sweeps" / "LIDAR_TOP").mkdir(parents=True)
    shutil.copyfile(sample_dir / LIDAR_FILE, root / "samples" / "LIDAR_TOP" / "s1.pcd.bin")
    shutil.copyfile(sample_dir / LIDAR_FILE, root / "samples" / "LIDAR_TOP" / "s2.pcd.bin")
    shutil.copyfile(sample_dir / LIDAR_FILE, root / "sweeps" / "LIDAR_TOP" / "s2_prev.pcd.bin")
    lidar2ego = np.asarray(calib["lidar2ego"])
    ego2global = np.asarray(calib["ego2global"])
    channels = list(calib["cameras"])
    sensor = [{"token": "sensor_lidar", "channel": "LIDAR_TOP", "modality": "lidar"}]
    cs = [{"token": "cs_lidar", "sensor_token": "sensor_lidar", "translation": lidar2ego[:3, 3].tolist(),
           "rotation": wxyz(lidar2ego[:3, :3]), "camera_intrinsic": []}]
    for ch in channels:
        image = camera_jpeg(sample_dir, ch)
        if image is not None:
            (root / "samples" / ch).mkdir(parents=True)
            for name in ("s1", "s2", "s3"):
                cv2.imwrite(str(root / "samples" / ch / f"{name}.jpg"), image)
        cam2ego = np.asarray(calib["cameras"][ch]["cam2ego"])
        K = np.diag([SCALE, SCALE, 1.0]) @ np.asarray(calib["cameras"][ch]["cam2img"])
        sensor.append({"token": f"sensor_{ch}", "channel": ch, "modality": "camera"})
        cs.append({"token": f"cs_{ch}", "sensor_token": f"sensor_{ch}", "translation": cam2ego[:3, 3].tolist(),
                   "rotation": wxyz(cam2ego[:3, :3]), "camera_intrinsic": K.tolist()})
    base = {"rotation": wxyz(ego2global[:3, :3]), "translation": ego2global[:3, 3].tolist()}
    ego, sample, sample_data = [], [], []

    def add(token, sample_token, ts, pose, cs_token, filename, key, w=0, h=0, prev=""):
        ego.append({"token": f"ep_{token}", "timestamp": ts, **pose})
        sample_data.append({"token": token, "sample_token": sample_token, "ego_pose_token": f"ep_{token}",
                            "calibrated_sensor_token": cs_token, "timestamp": ts, "fileformat": "",
                            "is_key_frame": key, "height": h, "width": w, "filename": filename,
                            "prev": prev, "next": ""})

    plans = {"s1": (0, 0.0, 0.0), "s2": (500_000, D_CAM_M, None), "s3": (1_000_000, 0.0, 0.0)}
    for name, (dt, d_cam, _) in plans.items():
        ts = T0 + dt
        sample.append({"token": name, "timestamp": ts, "scene_token": "scene0", "prev": "", "next": ""})
        prev = ""
        if name == "s2":
            add("lidar_s2_prev", "s2", ts - 50_000, moved(base, -D_SWEEP_M), "cs_lidar",
                "sweeps/LIDAR_TOP/s2_prev.pcd.bin", False)
            prev = "lidar_s2_prev"
        add(f"lidar_{name}", name, ts, base, "cs_lidar", f"samples/LIDAR_TOP/{name}.pcd.bin", True, prev=prev)
        for ch in channels:
            add(f"{ch}_{name}", name, ts - 30_000, moved(base, d_cam), f"cs_{ch}", f"samples/{ch}/{name}.jpg", True,
                WIDTH, HEIGHT)
    tables = {"sensor": sensor, "calibrated_sensor": cs, "ego_pose": ego, "sample": sample,
              "sample_data": sample_data,
              "scene": [{"token": "scene0", "log_token": "log0", "nbr_samples": 3, "first_sample_token": "s1",
                         "last_sample_token": "s3", "name": "scene-0001", "description": ""}],
              "log": [{"token": "log0", "logfile": "n015-2018-07-24-11-22-45+0800", "vehicle": "n015",
                       "date_captured": "2018-07-24", "location": "singapore-onenorth"}]}
    for empty in ("category", "attribute", "visibility", "instance", "sample_annotation", "map"):
        tables[empty] = []
    folder = root / VERSION
    folder.mkdir()
    for name, records in tables.items():
        (folder / f"{name}.json").write_text(json.dumps(records))
    return tables


@pytest.fixture(scope="module")
def dataroot(tmp_path_factory):
    sample_dir = require_shared("nuscenes", "sample")
    root = tmp_path_factory.mktemp("nuscenes")
    tables = build_dataroot(root, sample_dir)
    return root, tables, sample_dir


@pytest.fixture(scope="module")
def rig_traces():
    """(points, cameras, height, width) of every trace of the job's compiled rig completion."""
    return []


@pytest.fixture(scope="module")
def first_run(dataroot, tmp_path_factory, rig_traces):
    from jaxdepth.batch import nuscenes_job
    from jaxdepth._src import rig
    root, _, _ = dataroot
    dst = tmp_path_factory.mktemp("out")
    seen = []
    real = rig.complete_rig_stages
    recording = [True]

    def counted(points, valid, cameras, **kwargs):  # runs once per trace of the job's jit (during this run)
        if recording[0]:
            rig_traces.append((points.shape[0], cameras.count, cameras.height, cameras.width))
        return real(points, valid, cameras, **kwargs)

    nuscenes_job._depth_fn.cache_clear()
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(rig, "complete_rig_stages", counted)
        summary = nuscenes_job.run_nuscenes(root, dst, version=VERSION,
                                            on_progress=lambda n, s: seen.append((n, s)))
    # The job's compiled completion stays cached: the oracle of test_equal_poses_... calls it again.
    recording[0] = False
    return dst, summary, seen


def by_token(records):
    return {r["token"]: r for r in records}


# ---------------------------------------------------------------- geometry


def test_quaternion_matches_scipy():
    from jaxdepth.io.nuscenes import quaternion_matrix
    rng = np.random.default_rng(0)
    for q in rng.normal(size=(20, 4)) * rng.uniform(0.1, 10, size=(20, 1)):
        want = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
        np.testing.assert_allclose(quaternion_matrix(q), want, atol=1e-12)
    with pytest.raises(ValueError, match=r"field 'rotation' expected a non-zero quaternion \[w, x, y, z\], got \[0.0"):
        quaternion_matrix([0, 0, 0, 0])


def test_transform_chain_matches_numpy(dataroot):
    """T_cam_lidar = inv(C_cam) inv(E(t_cam)) E(t_lidar) C_lidar, against SciPy matrices; with the vehicle
    D_CAM_M ahead at the camera's time, a LiDAR point's camera coordinates move by -R_cam^T (D, 0, 0)."""
    from jaxdepth.io import nuscenes as nusc
    root, tables, _ = dataroot
    t = nusc.load_tables(root, VERSION)
    cs, ep, sd = by_token(tables["calibrated_sensor"]), by_token(tables["ego_pose"]), by_token(tables["sample_data"])
    points = np.fromfile(root / "samples" / "LIDAR_TOP" / "s2.pcd.bin", np.float32).reshape(-1, 5)[:, :3]
    for name in ("s1", "s2"):
        lidar = sd[f"lidar_{name}"]
        for ch in ("CAM_FRONT", "CAM_BACK_LEFT"):
            cam = sd[f"{ch}_{name}"]
            want = (np.linalg.inv(oracle_pose(cs[cam["calibrated_sensor_token"]]))
                    @ np.linalg.inv(oracle_pose(ep[cam["ego_pose_token"]]))
                    @ oracle_pose(ep[lidar["ego_pose_token"]]) @ oracle_pose(cs["cs_lidar"]))
            got = nusc.camera_from_lidar(t, cam, lidar)
            np.testing.assert_allclose(got, want, atol=1e-9)
            static = np.linalg.inv(oracle_pose(cs[cam["calibrated_sensor_token"]])) @ oracle_pose(cs["cs_lidar"])
            np.testing.assert_allclose(nusc.camera_from_lidar(t, cam, lidar, ego_motion=False), static, atol=1e-9)
            if name == "s1":  # equal ego poses: compensation changes nothing
                np.testing.assert_allclose(got, static, atol=1e-9)
            else:  # by hand: p_cam' = p_cam - R_cam^T (D, 0, 0)
                R_cam = oracle_pose(cs[cam["calibrated_sensor_token"]])[:3, :3]
                p_static = points @ static[:3, :3].T + static[:3, 3]
                p_got = points @ got[:3, :3].T + got[:3, 3]
                np.testing.assert_allclose(p_got, p_static - R_cam.T @ [D_CAM_M, 0.0, 0.0], atol=1e-6)


def test_ego_translation_shifts_projected_depth(dataroot):
    """The library's projection with the tables' T equals a NumPy z-buffer of the points moved by hand,
    and CAM_FRONT's depths drop by about D_CAM_M (its axis is the vehicle's +x)."""
    import jax.numpy as jnp

    from jaxdepth._src.geometry import project_to_image
    from jaxdepth.io import nuscenes as nusc
    root, tables, _ = dataroot
    t = nusc.load_tables(root, VERSION)
    inputs = nusc.sample_inputs(t, "s2")
    still = nusc.sample_inputs(t, "s2", ego_motion=False)
    cs = by_token(tables["calibrated_sensor"])
    points = inputs.points[:, :3]
    for cam, cam0 in zip(inputs.cameras, still.cameras):
        C = oracle_pose(cs[f"cs_{cam.channel}"])
        # by hand: LiDAR -> ego, the ego frame at the camera's time is D_CAM_M further along +x, -> camera
        p_ego = points.astype(np.float64) @ oracle_pose(cs["cs_lidar"])[:3, :3].T + oracle_pose(cs["cs_lidar"])[:3, 3]
        p_cam_ego = p_ego - [D_CAM_M, 0.0, 0.0]
        want = zbuffer(np.c_[p_cam_ego, np.zeros(len(p_cam_ego))], cam.K, np.linalg.inv(C), HEIGHT, WIDTH)
        got, index = project_to_image(jnp.asarray(points), jnp.ones(len(points), bool),
                                      jnp.asarray(cam.K, jnp.float32), jnp.asarray(cam.T_cam_lidar, jnp.float32),
                                      height=HEIGHT, width=WIDTH)
        got, index = np.asarray(got), np.asarray(index)
        same = (got > 0) == (want > 0)
        assert same.mean() > 0.999, cam.channel  # float32 vs float64 rounding may move a pixel or two
        both = (got > 0) & (want > 0)
        np.testing.assert_allclose(got[both], want[both], atol=1e-3)
        # each pixel's point is D_CAM_M * (camera z axis . ego x) nearer than without compensation
        hit = index[got > 0]
        z_still = points[hit].astype(np.float64) @ cam0.T_cam_lidar[2, :3] + cam0.T_cam_lidar[2, 3]
        np.testing.assert_allclose(got[got > 0], z_still - D_CAM_M * C[0, 2], atol=1e-3)
        if cam.channel == "CAM_FRONT":
            assert C[0, 2] > 0.99  # it looks along the vehicle's +x: depths drop by ~D_CAM_M


def test_multisweep_accumulation_by_hand(dataroot):
    """Two sweeps: each without its 1 m box, the earlier one moved by the vehicle's D_SWEEP_M (devkit semantics)."""
    from jaxdepth.io import nuscenes as nusc
    root, tables, _ = dataroot
    t = nusc.load_tables(root, VERSION)
    raw = np.fromfile(root / "samples" / "LIDAR_TOP" / "s2.pcd.bin", np.float32).reshape(-1, 5)
    key = t.tables["sample_data"]["lidar_s2"]
    np.testing.assert_array_equal(nusc.accumulate_sweeps(t, key, sweeps=1), raw)  # as recorded
    kept = raw[~((np.abs(raw[:, 0]) < 1.0) & (np.abs(raw[:, 1]) < 1.0))]
    R_lidar = oracle_pose(by_token(tables["calibrated_sensor"])["cs_lidar"])[:3, :3]
    earlier = kept.copy()
    # the earlier sweep was taken D_SWEEP_M further back: in the key frame its points sit R^T (-D, 0, 0) away
    earlier[:, :3] = kept[:, :3] + R_lidar.T @ [-D_SWEEP_M, 0.0, 0.0]
    for sweeps in (2, 5):  # 5: the scene starts after 2, the walk stops there
        got = nusc.accumulate_sweeps(t, key, sweeps=sweeps)
        assert got.shape == (2 * len(kept), 5)
        np.testing.assert_array_equal(got[:len(kept)], kept)
        np.testing.assert_allclose(got[len(kept):, :3], earlier[:, :3], atol=1e-5)
        np.testing.assert_array_equal(got[len(kept):, 3:], kept[:, 3:])


def test_sweep_cloud_sources(dataroot):
    """sweep_cloud: the accumulated points, one source per sweep; the earlier sweep's LiDAR sat D_SWEEP_M
    behind the key frame's (vehicle x), and its points about that origin are its raw file's."""
    from jaxdepth.io import nuscenes as nusc
    root, tables, _ = dataroot
    t = nusc.load_tables(root, VERSION)
    key = t.tables["sample_data"]["lidar_s2"]
    one = nusc.sweep_cloud(t, key, sweeps=1)
    raw = np.fromfile(root / "samples" / "LIDAR_TOP" / "s2.pcd.bin", np.float32).reshape(-1, 5)
    np.testing.assert_array_equal(one.points, raw[:, :3])
    np.testing.assert_array_equal(one.T_ref_source, np.eye(4)[None])
    np.testing.assert_array_equal(one.ring, raw[:, 4].astype(np.int32))
    cloud = nusc.sweep_cloud(t, key, sweeps=3)  # the scene holds 2
    stacked = nusc.accumulate_sweeps(t, key, sweeps=3)
    np.testing.assert_array_equal(cloud.points, stacked[:, :3])
    assert cloud.sweep.tolist() == [0, -1] and cloud.names == ("LIDAR_TOP@0", "LIDAR_TOP@-1")
    R_lidar = oracle_pose(by_token(tables["calibrated_sensor"])["cs_lidar"])[:3, :3]
    np.testing.assert_allclose(cloud.T_ref_source[1][:3, 3], R_lidar.T @ [-D_SWEEP_M, 0.0, 0.0], atol=1e-9)
    earlier = cloud.points[cloud.source == 1].astype(np.float64)
    T = cloud.T_ref_source[1]
    kept = raw[~((np.abs(raw[:, 0]) < 1.0) & (np.abs(raw[:, 1]) < 1.0))]
    np.testing.assert_allclose((earlier - T[:3, 3]) @ T[:3, :3], kept[:, :3], atol=1e-5)
    inputs = nusc.sample_inputs(t, "s2", sweeps=2, sources=True)
    np.testing.assert_array_equal(inputs.points, stacked)
    np.testing.assert_array_equal(inputs.cloud.points, cloud.points)


# ---------------------------------------------------------------- the job


def calibration_path_frame(tables, sample_dir, tmp_path):
    """s1's sweep through the calibration-JSON rig path (the oracle of the job: s1's ego poses are
    equal), the JSON written from the tables' calibrated_sensor rows."""
    from jaxdepth.io import prepare_sweep, read_points, rig_from_nuscenes_calibration
    cs = by_token(tables["calibrated_sensor"])
    doc = {"cameras": {}}
    for ch in json.loads((sample_dir / "calibration.json").read_text())["cameras"]:
        lidar2cam = np.linalg.inv(oracle_pose(cs[f"cs_{ch}"])) @ oracle_pose(cs["cs_lidar"])
        doc["cameras"][ch] = {"cam2img": cs[f"cs_{ch}"]["camera_intrinsic"], "lidar2cam": lidar2cam.tolist()}
    (tmp_path / "calibration.json").write_text(json.dumps(doc))
    rig = rig_from_nuscenes_calibration(tmp_path / "calibration.json", width=WIDTH, height=HEIGHT)
    points, extra = read_points(sample_dir / LIDAR_FILE, columns=5)
    return prepare_sweep(points, rig, ring=extra[:, -1])


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
@pytest.mark.xdist_group("jobs_nuscenes")  # one worker runs the module's first_run job and compiles its programs once
def test_equal_poses_match_the_calibration_rig_path(dataroot, first_run, tmp_path):
    """s1 (ego poses equal) completes exactly as the existing rig path does from a calibration JSON.

    The oracle's completion runs through the job's own jit of ``complete_rig`` (a second compile of
    the same function would only cost time; tests/test_rig.py checks complete_rig itself): what is
    compared is the job's reading of the tables against the calibration-JSON path."""
    import jax

    import jaxdepth
    from jaxdepth import SGMConfig
    from jaxdepth.batch import nuscenes_job
    from jaxdepth.io import encode_depth_uint16, pad_points
    root, tables, sample_dir = dataroot
    dst, summary, _ = first_run
    frame = calibration_path_frame(tables, sample_dir, tmp_path)
    assert frame.outlier_removal_trusted
    padded, valid = pad_points(frame.points)
    cameras = jaxdepth.stack_cameras([c.as_camera() for c in frame.rig.cameras])
    # placed on the device as the job places them (committed arrays: the job's compiled program)
    args = jax.device_put((padded, valid, cameras), jax.local_devices()[0])
    want = np.asarray(nuscenes_job._depth_fn(SGMConfig(), frame.rig.lidar)(*args))
    for i, cam in enumerate(frame.rig.cameras):
        out = dst / VERSION / cam.name / f"{cam.name}_s1.png"
        got = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
        assert got.dtype == np.uint16 and got.shape == (HEIGHT, WIDTH)
        expected = encode_depth_uint16(want[i])
        assert np.count_nonzero(expected) > 0.5 * expected.size, cam.name
        np.testing.assert_array_equal(got, expected, err_msg=cam.name)


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
@pytest.mark.xdist_group("jobs_nuscenes")  # one worker runs the module's first_run job and compiles its programs once
def test_output_tree_resume_and_bad_sample(dataroot, first_run, rig_traces):
    from jaxdepth.batch.nuscenes_job import run_nuscenes
    root, tables, _ = dataroot
    dst, summary, seen = first_run
    channels = sorted(r["channel"] for r in tables["sensor"] if r["modality"] == "camera")
    files = sorted(p.relative_to(dst).as_posix() for p in dst.rglob("*") if p.is_file())
    assert files == sorted(f"{VERSION}/{ch}/{ch}_{s}.png" for ch in channels for s in ("s1", "s2"))
    assert sorted(summary.done) == ["s1", "s2"] and summary.skipped == []
    [(name, message)] = summary.failed
    assert name == "s3" and "s3.pcd.bin" in message and "not found" in message
    assert sorted(seen) == [("s1", "done"), ("s2", "done"), ("s3", f"failed: {message}")]
    assert len(rig_traces) == 1  # s1 and s2 share the point bucket and the canvas: one trace
    stamps = {f: (dst / f).stat().st_mtime_ns for f in files}
    again = run_nuscenes(root, dst, version=VERSION)
    assert sorted(again.skipped) == ["s1", "s2"] and again.done == [] and [n for n, _ in again.failed] == ["s3"]
    assert {f: (dst / f).stat().st_mtime_ns for f in files} == stamps
    # a partly written sample: only the missing camera is recomputed, with the same bytes
    lost = dst / VERSION / "CAM_BACK" / "CAM_BACK_s2.png"
    before = lost.read_bytes()
    lost.unlink()
    third = run_nuscenes(root, dst, version=VERSION)
    assert third.done == ["s2"] and lost.read_bytes() == before
    assert all((dst / f).stat().st_mtime_ns == stamps[f] for f in files if not f.endswith("CAM_BACK_s2.png"))
    assert not [p for p in dst.rglob("*") if p.name.startswith(".") or p.suffix != ".png" and p.is_file()]


TWO_DEVICES = """
import sys
import jax
from jaxdepth import cli
placed = set()
real_put = jax.device_put
def put(x, device=None, *a, **k):
    if device is not None:
        placed.add(str(device))
    return real_put(x, device, *a, **k)
jax.device_put = put
argv = ["complete", {root!r}, {dst!r}, "--nusc-version", "v1.0-mini", "-q", "--cpu-devices", "2"]
first = cli.main(argv)
stamps = sorted((p.name, p.stat().st_mtime_ns) for p in __import__("pathlib").Path({dst!r}).rglob("*.png"))
again = cli.main(argv)
later = sorted((p.name, p.stat().st_mtime_ns) for p in __import__("pathlib").Path({dst!r}).rglob("*.png"))
print("devices", len(jax.local_devices()), "placed", len(placed), "exits", first, again, "same", stamps == later,
      "pngs", len(later), flush=True)
"""


@pytest.mark.slow  # two whole-pipeline compiles in a subprocess (one per host device)
@pytest.mark.xdist_group("jobs_nuscenes")  # one worker runs the module's first_run job and compiles its programs once
def test_two_host_devices_write_the_same_files_and_resume(dataroot, first_run, tmp_path):
    """``--cpu-devices 2`` (a subprocess: the split must come before JAX starts): whole samples dealt to two host
    devices, s1 to one and s2 to the other, write the files of the one-device run byte for byte (s3's sweep is
    missing: exit 1 both times); run again, every sample is skipped and no file is rewritten."""
    root, _, _ = dataroot
    one_dst, _, _ = first_run
    dst = tmp_path / "two"
    env = dict(os.environ)  # the suite's compile flags (tests/conftest.py), but no device count
    env["XLA_FLAGS"] = " ".join(f for f in env.get("XLA_FLAGS", "").split() if "device_count" not in f)
    env["JAX_PLATFORMS"] = "cpu"
    script = TWO_DEVICES.format(root=str(root), dst=str(dst))
    result = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=900,
                            cwd=pathlib.Path(__file__).parent.parent)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "devices 2 placed 2 exits 1 1 same True pngs 12" in result.stdout, (result.stdout, result.stderr[-2000:])
    ones = sorted(p.relative_to(one_dst) for p in one_dst.rglob("*.png"))
    assert ones == sorted(p.relative_to(dst) for p in dst.rglob("*.png")) and len(ones) == 12
    for rel in ones:
        assert (dst / rel).read_bytes() == (one_dst / rel).read_bytes(), rel


@pytest.mark.xdist_group("jobs_nuscenes")  # one worker runs the module's first_run job and compiles its programs once
@pytest.mark.slow  # real nuScenes multi-sweep completion, six cameras
@pytest.mark.production_flags  # bit for bit at the production codegen; at the suite's level 0 the one-source rig's tail (nusc14: no window, the seed search's scalar masks) rounds Step 4's blur 1 ulp apart from the sources path's
def test_multisweep_job_completes_sources(dataroot, first_run, tmp_path):
    """sweeps=2: each sample's sweeps (s1: one, the scene's first; s2: two) go through complete_cloud as one
    source per sweep; the job's bytes are a direct call's, and s2's differ from the single-sweep job's."""
    from jaxdepth.batch.nuscenes_job import run_nuscenes
    from jaxdepth.batch.sources_job import complete_cloud
    from jaxdepth.io import encode_depth_uint16
    from jaxdepth.io import nuscenes as nusc
    from jaxdepth.io.rig import Rig, RigCamera
    from jaxdepth._src.presets import NUSCENES_HDL32

    from _harness import compiled_programs
    root, tables, _ = dataroot
    single, _, _ = first_run
    dst = tmp_path / "multi"
    with compiled_programs() as compiled:
        summary = run_nuscenes(root, dst, version=VERSION, sweeps=2)
    assert sorted(summary.done) == ["s1", "s2"]
    # s1 (the scene's first sample: one sweep) runs s2's program, its one source in a window of two
    assert compiled in ([], ["jit(sources_depth_program)"]), compiled     # [] when compiled earlier in the session
    t = nusc.load_tables(root, VERSION)
    changed = 0
    for sample, count in (("s1", 1), ("s2", 2)):
        inputs = nusc.sample_inputs(t, sample, sweeps=2, sources=True)
        assert inputs.cloud.num_sources == count
        rig = Rig(lidar=NUSCENES_HDL32, cameras=tuple(RigCamera(c.channel, c.width, c.height, c.K, c.T_cam_lidar)
                                                      for c in inputs.cameras), lidar_origin_m=(0.0, 0.0, 0.0))
        want = complete_cloud(inputs.cloud, rig, free_space=True)
        for i, cam in enumerate(rig.cameras):
            path = pathlib.Path(VERSION) / cam.name / f"{cam.name}_{sample}.png"
            got = cv2.imread(str(dst / path), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(got, encode_depth_uint16(want[i, :cam.height, :cam.width]))
            if sample == "s2":
                changed += (dst / path).read_bytes() != (single / path).read_bytes()
    assert changed > 0


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_command_line(dataroot, tmp_path, capsys):
    """`jaxdepth complete DATAROOT DST --nusc-version v1.0-mini`: exit 1 naming the bad sample, then 0 once
    it is fixed (the others are skipped); usage errors exit 2; a missing version lists the ones found."""
    from jaxdepth import cli
    root, _, sample_dir = dataroot
    dst = tmp_path / "out"
    assert cli.main(["complete", str(root), str(dst), "--nusc-version", VERSION, "-q"]) == 1
    err = capsys.readouterr().err
    assert "FAILED s3:" in err and "s3.pcd.bin" in err
    assert len(list((dst / VERSION).rglob("*.png"))) == 12
    fixed = root / "samples" / "LIDAR_TOP" / "s3.pcd.bin"
    shutil.copyfile(sample_dir / LIDAR_FILE, fixed)
    try:
        assert cli.main(["complete", str(root), str(dst), "--nusc-version", VERSION]) == 0
        err = capsys.readouterr().err
        assert "1 completed, 2 skipped (already done), 0 failed" in err
        assert len(list((dst / VERSION).rglob("*.png"))) == 18
    finally:
        fixed.unlink()
    # the baselines run here too (tests/test_job_baselines.py); the run record refuses to mix them with sgm
    assert cli.main(["complete", str(root), str(dst), "--nusc-version", VERSION, "--method", "nearest"]) == 1
    assert "method: sgm -> nearest" in capsys.readouterr().err
    assert cli.main(["complete", str(root), str(dst), "--nusc-version", VERSION, "--extrinsic", "T.txt"]) == 2
    capsys.readouterr()
    assert cli.main(["complete", str(root), str(dst), "--nusc-version", "v1.0-trainval"]) == 1
    assert "v1.0-trainval: nuScenes version folder not found (found: v1.0-mini)" in capsys.readouterr().err


def test_bad_tables_name_the_file(tmp_path):
    from jaxdepth.io import nuscenes as nusc
    from jaxdepth.io.errors import InputError
    folder = tmp_path / VERSION
    folder.mkdir()
    for name in nusc.TABLES:
        (folder / f"{name}.json").write_text("[]")
    (folder / "ego_pose.json").write_text('{"token": "x"}')
    with pytest.raises(InputError, match=r"ego_pose.json: expected a JSON list of records, got dict"):
        nusc.load_tables(tmp_path, VERSION)
    (folder / "ego_pose.json").unlink()
    with pytest.raises(InputError, match=r"ego_pose.json: file not found"):
        nusc.load_tables(tmp_path, VERSION)


def test_command_line_options_reach_the_job(dataroot, tmp_path, monkeypatch):
    from jaxdepth import cli
    from jaxdepth.batch import nuscenes_job
    from jaxdepth.batch.runner import RunSummary
    root, _, _ = dataroot
    calls = []
    monkeypatch.setattr(nuscenes_job, "run_nuscenes", lambda *a, **k: calls.append((a, k)) or RunSummary())
    argv = ["complete", str(root), str(tmp_path / "o"), "--nusc-version", VERSION, "-q"]
    assert cli.main(argv + ["--sweeps", "3", "--no-ego-motion", "--overwrite", "--png-compression", "6"]) == 0
    assert cli.main(argv) == 0
    (first, options), (_, defaults) = calls
    assert first == (str(root), tmp_path / "o")
    assert options["version"] == VERSION and options["tables"].version == VERSION
    assert (options["sweeps"], options["ego_motion"], options["overwrite"], options["png_compression"]) == \
        (3, False, True, 6)
    assert (defaults["sweeps"], defaults["ego_motion"], defaults["overwrite"]) == (1, True, False)
    assert cli.main(argv + ["--sweeps", "0"]) == 2
    assert cli.main(argv + ["--guidance-weight", "2", "--guidance-sweeps", "3", "--guidance-noise-floor", "1.5"]) == 0
    guided = calls[-1][1]["config"]  # guided: the config says so
    assert (guided.guidance_weight, guided.guidance_sweeps, guided.guidance_noise_floor) == (2.0, 3, 1.5)
    assert (defaults["config"].guidance_weight, defaults["config"].guidance_noise_floor) == (0.0, 0.0)


def test_bad_records_cost_their_sample_and_name_the_file(dataroot):
    from jaxdepth.io import nuscenes as nusc
    from jaxdepth.io.errors import InputError
    root, _, _ = dataroot
    t = nusc.load_tables(root, VERSION)
    t.tables["ego_pose"]["ep_CAM_FRONT_s1"]["rotation"] = None
    with pytest.raises(InputError, match=r"ego_pose.json: field 'ep_CAM_FRONT_s1.rotation' expected a list of numbers, got None"):
        nusc.sample_inputs(t, "s1")
    t.tables["calibrated_sensor"]["cs_CAM_BACK"]["camera_intrinsic"] = [[1, 0, 0], [0, 1, 0]]
    with pytest.raises(InputError, match=r"calibrated_sensor.json: field 'cs_CAM_BACK.camera_intrinsic' expected a 3x3"):
        nusc.sample_inputs(t, "s2")
    t.tables["sample_data"]["lidar_s2"]["prev"] = "gone"
    with pytest.raises(InputError, match=r"sample_data.json: field 'token' expected a record referenced by "
                                         r"sample_data 'lidar_s2' prev, got no record 'gone'"):
        nusc.accumulate_sweeps(t, t.tables["sample_data"]["lidar_s2"], sweeps=2)
    with pytest.raises(ValueError, match="plain file name"):
        nusc.output_path("out", VERSION, "CAM_FRONT", "../escape")


def test_command_line_ray_engine_reaches_run_nuscenes_ray(dataroot, tmp_path, monkeypatch):
    """`--engine ray` sends the job to scale.run_nuscenes_ray with the address, batch size and the same options
    the local engine gets (Ray itself is tested in tests/test_ray.py)."""
    from jaxdepth import cli
    from jaxdepth.batch import nuscenes_job, scale
    from jaxdepth.batch.runner import RunSummary
    root, _, _ = dataroot
    calls = []
    monkeypatch.setattr(scale, "run_nuscenes_ray", lambda *a, **k: calls.append(("ray", a, k)) or RunSummary())
    monkeypatch.setattr(nuscenes_job, "run_nuscenes", lambda *a, **k: calls.append(("local", a, k)) or RunSummary())
    argv = ["complete", str(root), str(tmp_path / "o"), "--nusc-version", VERSION, "-q", "--sweeps", "2",
            "--no-ego-motion", "--png-compression", "6"]
    assert cli.main(argv + ["--engine", "ray", "--ray-address", "HEAD:6379", "--batch-size", "3"]) == 0
    assert cli.main(argv) == 0
    (engine, args, ray_options), (local_engine, local_args, local_options) = calls
    assert (engine, local_engine) == ("ray", "local") and args == local_args == (str(root), tmp_path / "o")
    assert (ray_options.pop("address"), ray_options.pop("batch_size")) == ("HEAD:6379", 3)
    local_options.pop("io_threads")
    assert local_options.pop("method") == "sgm"  # the baselines run on the local engine only
    assert local_options.pop("devices") == 1  # one device unless --cpu-devices N > 1 (local engine)
    for options in (ray_options, local_options):
        options.pop("on_progress")
        options["tables"] = options["tables"].version
    assert ray_options == local_options
    assert (ray_options["sweeps"], ray_options["ego_motion"], ray_options["png_compression"]) == (2, False, 6)


# ---------------------------------------------------------------- image-guided seeds


@pytest.mark.xdist_group("jobs_nuscenes")  # one worker runs the module's first_run job and compiles its programs once
@pytest.mark.slow  # real nuScenes images, guided six-camera completion
def test_guided_job_reads_the_jpegs_fails_a_bad_image_and_resumes(dataroot, first_run, tmp_path):
    """--guidance-weight: s1's PNGs equal the guided rig completion of the calibration rig path with the
    JPEGs read by OpenCV (BGR -> RGB); s2 has a CAM_BACK JPEG of the wrong size: it fails naming the file,
    s1 completes; once the image is fixed a re-run completes s2 only."""
    import jax

    import jaxdepth
    from jaxdepth import SGMConfig
    from jaxdepth.batch import nuscenes_job
    from jaxdepth.batch.nuscenes_job import run_nuscenes
    from jaxdepth.io import encode_depth_uint16, pad_points
    _, tables, sample_dir = dataroot
    root = tmp_path / "root"
    build_dataroot(root, sample_dir)
    bad = root / "samples" / "CAM_BACK" / "s2.jpg"
    good = bad.read_bytes()
    cv2.imwrite(str(bad), np.zeros((HEIGHT // 2, WIDTH // 2, 3), np.uint8))
    config = SGMConfig(guidance_weight=2.0)
    dst = tmp_path / "out"
    summary = run_nuscenes(root, dst, version=VERSION, config=config)
    assert summary.done == ["s1"]
    failed = dict(summary.failed)
    assert sorted(failed) == ["s2", "s3"] and "s3.pcd.bin" in failed["s3"]
    assert failed["s2"] == (f"{bad}: camera image expected {WIDTH}x{HEIGHT} (width x height of camera CAM_BACK), "
                            f"got {WIDTH // 2}x{HEIGHT // 2}")
    assert not (dst / VERSION / "CAM_FRONT" / "CAM_FRONT_s2.png").exists()  # a failed sample writes nothing

    # the oracle: the calibration-JSON rig path (s1's ego poses are equal) with the JPEGs read by hand
    frame = calibration_path_frame(tables, sample_dir, tmp_path)
    padded, valid = pad_points(frame.points)
    cameras = jaxdepth.stack_cameras([c.as_camera() for c in frame.rig.cameras])
    images = np.stack([cv2.imread(str(root / "samples" / c.name / "s1.jpg"))[:, :, ::-1] for c in frame.rig.cameras])
    # complete_rig(..., images=) through the job's own jit of it (a second compile of the same function
    # would only cost time; tests/test_rig_images.py checks complete_rig itself)
    args = jax.device_put((padded, valid, cameras, images), jax.local_devices()[0])  # as the job places them
    want = np.asarray(nuscenes_job._depth_fn(config, frame.rig.lidar)(*args))
    unguided_dst = first_run[0]
    changed = 0
    for i, cam in enumerate(frame.rig.cameras):
        got = cv2.imread(str(dst / VERSION / cam.name / f"{cam.name}_s1.png"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(got, encode_depth_uint16(want[i]), err_msg=cam.name)
        plain = cv2.imread(str(unguided_dst / VERSION / cam.name / f"{cam.name}_s1.png"), cv2.IMREAD_UNCHANGED)
        changed += np.count_nonzero(got != plain)
    assert changed > 0.01 * 6 * WIDTH * HEIGHT  # the images changed the result

    bad.write_bytes(good)
    again = run_nuscenes(root, dst, version=VERSION, config=config)
    assert again.done == ["s2"] and again.skipped == ["s1"] and [n for n, _ in again.failed] == ["s3"]


def test_multisweep_refuses_seed_extras(dataroot, tmp_path, capsys):
    from jaxdepth import cli
    from jaxdepth.batch import extras as extra_outputs
    from jaxdepth.batch.nuscenes_job import run_nuscenes
    root, _, _ = dataroot
    with pytest.raises(ValueError, match="need sweeps = 1"):
        run_nuscenes(root, tmp_path / "o", version=VERSION, sweeps=2,
                     extras=extra_outputs.ExtraOutputs(validity=True))
    assert cli.main(["complete", str(root), str(tmp_path / "o"), "--nusc-version", VERSION, "--sweeps", "2",
                     "--validity", "-q"]) == 2
    assert "need --sweeps 1" in capsys.readouterr().err


def test_force_reaches_the_sweep_reader_on_both_engines(dataroot, tmp_path, monkeypatch):
    """A sweep in millimetres fails its sample naming the file; ``force`` (``--force``) reads it as is."""
    from jaxdepth import cli
    from jaxdepth.batch import nuscenes_job, scale
    from jaxdepth.batch.runner import RunSummary
    from jaxdepth.io import nuscenes as nusc
    from jaxdepth.io.errors import InputError
    root, _, _ = dataroot
    bad = tmp_path / "nuscenes"
    shutil.copytree(root, bad)
    sweep_file = bad / "samples" / "LIDAR_TOP" / "s1.pcd.bin"
    records = np.fromfile(sweep_file, np.float32).reshape(-1, 5)
    records[:, :3] *= 1000.0  # millimetres: no LiDAR returns at 1-300 km
    records.tofile(sweep_file)
    tables = nusc.load_tables(bad, VERSION)
    with pytest.raises(InputError, match="s1.pcd.bin"):
        nusc.sample_inputs(tables, "s1")
    forced = nusc.sample_inputs(tables, "s1", force=True)
    np.testing.assert_array_equal(forced.points, records)
    cloud = nusc.sample_inputs(tables, "s1", sweeps=2, sources=True, force=True).cloud  # s1 has no earlier sweep
    np.testing.assert_array_equal(cloud.points, nusc.remove_close(records, nusc.MULTISWEEP_MIN_DISTANCE_M)[:, :3])

    seen = []
    real = nusc.sample_inputs

    def recording(tables_, token, **options):  # only s1 is loaded: nothing is compiled here
        seen.append(options["force"])
        if token != "s1":
            raise InputError(f"{token}: not loaded in this test")
        return real(tables_, token, **options)

    monkeypatch.setattr(nusc, "sample_inputs", recording)
    summary = nuscenes_job.run_nuscenes(bad, tmp_path / "plain", version=VERSION, tables=tables)
    assert "s1.pcd.bin" in dict(summary.failed)["s1"] and seen and not any(seen)
    seen.clear()
    monkeypatch.setattr(nuscenes_job, "complete_samples",
                        lambda *a, **k: seen.append(k["force"]))
    nuscenes_job.run_nuscenes(bad, tmp_path / "forced", version=VERSION, tables=tables, force=True)
    assert seen == [True]

    calls = []
    monkeypatch.setattr(nuscenes_job, "run_nuscenes", lambda *a, **k: calls.append(k) or RunSummary())
    monkeypatch.setattr(scale, "run_nuscenes_ray", lambda *a, **k: calls.append(k) or RunSummary())
    argv = ["complete", str(bad), str(tmp_path / "cli"), "--nusc-version", VERSION, "-q"]
    assert cli.main(argv + ["--force"]) == 0
    assert cli.main(argv + ["--force", "--overwrite", "--engine", "ray"]) == 0
    assert cli.main(argv + ["--overwrite"]) == 0
    assert [k["force"] for k in calls] == [True, True, False]


def test_job_stacks_the_rig_cameras_as_as_camera_does():
    # The job stacks the RigCameras' NumPy K and T (no jax.Array read back, which would wait for the
    # sample in flight): the same RigCameras as from their as_camera() pytrees, bit for bit.
    from jaxdepth._src import presets
    from jaxdepth._src.rig import stack_cameras
    from jaxdepth.io.rig import RigCamera
    T = np.asarray(presets.KITTI_T_CAM2_LIDAR, np.float64).copy()
    cams = [RigCamera("a", 1600, 900, np.array([[1266.4, 0, 816.3], [0, 1266.4, 491.5], [0, 0, 1]]), T),
            RigCamera("b", 900, 1600, np.array([[809.2, 0, 449.7], [0, 809.2, 801.1], [0, 0, 1]]), T[[0, 1, 2, 3]])]
    got, want = stack_cameras(cams), stack_cameras([c.as_camera() for c in cams])
    for field in ("K", "T_cam_lidar", "image_size"):
        a, b = np.asarray(getattr(got, field)), np.asarray(getattr(want, field))
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), field
    assert (got.height, got.width, got.sizes) == (want.height, want.width, want.sizes) == (1600, 1600, ((900, 1600), (1600, 900)))
