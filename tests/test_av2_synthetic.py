"""The Argoverse 2 reader and job on a synthetic drive written in the dataset's own layout.

The drive: a straight road at 10 m/s (city poses every 10 ms), a box of walls (the front one 20 m
ahead of the ego origin at the first sweep) over a flat ground, two VLP-32C-like LiDARs (up_lidar
upright, down_lidar upside down, the datasheet's uneven laser elevations, laser numbers not in
elevation order) ray-cast at two sweeps 100 ms apart, one small front camera (96 x 64) whose
images are taken 50 ms after each sweep. Oracles: the exact depth of the box seen from the
camera at its image's time (ray-plane intersections), the laser table itself (rows), brute-force
pairing of times, a brute-force z-buffer and nearest-pixel search (baselines), OpenCV's IP_Basic.
"""

from __future__ import annotations

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
import pyarrow.feather as feather  # noqa: E402

from jaxdepth.batch import av2_job  # noqa: E402
from jaxdepth.io import av2  # noqa: E402
from jaxdepth.io.depth_png import read_depth_png  # noqa: E402

SPEED = 10.0  # m/s along the city x axis
T0 = 315_966_265_000_000_000  # first sweep, ns
SWEEPS = (T0, T0 + 100_000_000)
CAMERA_DELAY_NS = 50_000_000  # each image 50 ms after its sweep: the car moves 0.5 m
CAMERA = "ring_front_center"
W, H, F = 96, 64, 48.0
#: VLP-32C laser elevations (deg, the datasheet's table), highest last; LASER_OF_RANK[k] = laser number of
#: the k-th lowest laser (a permutation: laser numbers are not in elevation order).
ELEVATIONS = np.array([-25.0, -15.64, -11.31, -8.84, -7.25, -6.15, -5.33, -4.67, -4.0, -3.67, -3.33, -3.0, -2.67,
                       -2.33, -2.0, -1.67, -1.33, -1.0, -0.67, -0.33, 0.0, 0.33, 0.67, 1.0, 1.33, 1.67, 2.33,
                       3.33, 4.67, 7.0, 10.33, 15.0])
LASER_OF_RANK = (np.arange(32) * 7) % 32
COLUMNS = 900
#: Planes of the box in the city frame: (axis, value); the ground is z = 0.
PLANES = ((0, 20.0), (0, -30.0), (1, 12.0), (1, -12.0), (2, 0.0))
R_FLIP = np.diag([1.0, -1.0, -1.0])  # down_lidar: upside down (180 deg about x)
R_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # OpenCV camera -> ego (looks along +x)
SENSORS = {"up_lidar": (np.eye(3), (1.35, 0.0, 1.64)), "down_lidar": (R_FLIP, (1.35, 0.0, 1.53)),
           CAMERA: (R_CAM, (1.6, 0.0, 1.4))}


def _ego_x(t_ns) -> float:
    return SPEED * (int(t_ns) - T0) / 1e9


def _cast(origin, dirs):
    """(N,) distance along unit-or-not ``dirs`` (N, 3) from the city-frame ``origin`` (3,) to the box."""
    best = np.full(dirs.shape[0], np.inf)
    for axis, value in PLANES:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (value - origin[axis]) / dirs[:, axis]
        best = np.where((t > 1e-6) & (t < best), t, best)
    return best


def _quaternion(R):
    from scipy.spatial.transform import Rotation
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return w, x, y, z


def _pose_table(names, poses):
    cols = {"qw": [], "qx": [], "qy": [], "qz": [], "tx_m": [], "ty_m": [], "tz_m": []}
    for R, t in poses:
        for k, v in zip(("qw", "qx", "qy", "qz"), _quaternion(R)):
            cols[k].append(float(v))
        for k, v in zip(("tx_m", "ty_m", "tz_m"), t):
            cols[k].append(float(v))
    return {**names, **{k: pa.array(v, pa.float64()) for k, v in cols.items()}}


def _sweep_table(t_ns):
    """The sweep at ``t_ns``: both LiDARs ray-cast against the box, points in the ego frame at ``t_ns``."""
    az = np.radians(np.arange(COLUMNS) * 360.0 / COLUMNS - 180.0)
    el = np.radians(ELEVATIONS)
    E, A = np.meshgrid(el, az, indexing="ij")
    local = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    rank = np.repeat(np.arange(32), COLUMNS)
    xyz, lasers = [], []
    ego = np.array([_ego_x(t_ns), 0.0, 0.0])
    for j, name in enumerate(("up_lidar", "down_lidar")):
        R, t = SENSORS[name]
        dirs = local @ R.T
        dist = _cast(np.asarray(t) + ego, dirs)
        keep = np.isfinite(dist)
        xyz.append(np.asarray(t) + dist[keep, None] * dirs[keep])
        lasers.append(32 * j + LASER_OF_RANK[rank[keep]])
    xyz, lasers = np.concatenate(xyz), np.concatenate(lasers)
    cols = {k: pa.array(xyz[:, i].astype(np.float32)) for i, k in enumerate("xyz")}
    return pa.table({**cols, "intensity": pa.array(np.full(len(lasers), 20, np.uint8)),
                     "laser_number": pa.array(lasers.astype(np.uint8)),
                     "offset_ns": pa.array(np.zeros(len(lasers), np.int32))})


def write_log(folder, *, images=True, sweeps=SWEEPS):
    """Writes the synthetic drive as an Argoverse 2 log folder; returns it."""
    (folder / "sensors" / "lidar").mkdir(parents=True)
    (folder / "calibration").mkdir()
    for t in sweeps:
        feather.write_feather(_sweep_table(t), folder / "sensors" / "lidar" / f"{t}.feather")
    names = list(SENSORS)
    feather.write_feather(pa.table(_pose_table({"sensor_name": pa.array(names)}, [SENSORS[n] for n in names])),
                          folder / "calibration" / "egovehicle_SE3_sensor.feather")
    intr = {"sensor_name": [CAMERA], "fx_px": [F], "fy_px": [F], "cx_px": [W / 2], "cy_px": [H / 2],
            "k1": [0.0], "k2": [0.0], "k3": [0.0], "height_px": [H], "width_px": [W]}
    feather.write_feather(pa.table(intr), folder / "calibration" / "intrinsics.feather")
    times = np.arange(T0 - 1_000_000_000, T0 + 1_000_000_001, 10_000_000, dtype=np.int64)
    city = _pose_table({"timestamp_ns": pa.array(times)}, [(np.eye(3), (_ego_x(t), 0.0, 0.0)) for t in times])
    feather.write_feather(pa.table(city), folder / "city_SE3_egovehicle.feather")
    if images:
        cam_dir = folder / "sensors" / "cameras" / CAMERA
        cam_dir.mkdir(parents=True)
        for t in sweeps:
            (cam_dir / f"{t + CAMERA_DELAY_NS}.jpg").write_bytes(b"")  # only the name (timestamp) is read
    return folder


def true_depth(t_ns):
    """(H, W) exact depth of the box in the camera at time ``t_ns`` (pixel centres at integer u, v)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(u - W / 2) / F, (v - H / 2) / F, np.ones_like(u)], -1).reshape(-1, 3)
    R, t = SENSORS[CAMERA]
    return _cast(np.asarray(t) + (_ego_x(t_ns), 0.0, 0.0), rays @ R.T).reshape(H, W)  # ray z = 1: distance = depth


def _front_wall(depth_truth):
    """(H, W) bool: pixels on the front wall at least 2 px from its edge with the ground."""
    from scipy import ndimage
    wall = np.abs(depth_truth - np.median(depth_truth[H // 2 - 4:H // 2 - 2, W // 2 - 2:W // 2 + 2])) < 0.05
    return ndimage.binary_erosion(wall, iterations=2)


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    return write_log(tmp_path_factory.mktemp("av2") / "synthetic-log")


#: The first sweep of the drive alone, for the SGM runs: each sweep's LiDAR spec is estimated from
#: its own points (field of view to float rounding), so each sweep compiles a program of its own
#: (~8 s); one sweep checks the compensation as well as two.
FIRST = SWEEPS[:1]


@pytest.fixture(scope="module")
def drive_one(tmp_path_factory):
    return write_log(tmp_path_factory.mktemp("av2_one") / "synthetic-log", sweeps=FIRST)


def test_paired_image_is_a_mutual_nearest_match():
    """Brute force over every sweep and image: the pairing is the mutual nearest match, no image twice."""
    rng = np.random.default_rng(0)
    for _ in range(50):
        sweeps = tuple(int(x) for x in np.cumsum(rng.integers(80, 120, 8)) * 1_000_000)
        images = np.unique(rng.integers(0, sweeps[-1] + 100_000_000, rng.integers(1, 20)) // 5_000_000 * 5_000_000)
        log_ = av2.Av2Log(None, sweeps, {}, {}, np.zeros(0), np.zeros((0, 4, 4)), {"c": images.astype(np.int64)})
        got = [av2.paired_image(log_, "c", s) for s in sweeps]
        paired = [g for g in got if g is not None]
        assert len(paired) == len(set(paired))
        for s, g in zip(sweeps, got):
            d = np.abs(images - s)
            best = images[d == d.min()].max()  # nearest image, a tie to the later one
            ds = np.abs(np.asarray(sweeps) - best)
            back = np.asarray(sweeps)[ds == ds.min()].min()  # its nearest sweep, a tie to the earlier one
            assert g == (int(best) if back == s else None)
    log_ = av2.Av2Log(None, SWEEPS, {}, {}, np.zeros(0), np.zeros((0, 4, 4)), {})
    assert av2.paired_image(log_, CAMERA, SWEEPS[0]) is None  # no images of that camera


def test_log_reads_camera_times_and_rows_come_from_laser_numbers(drive):
    """Rows: each source's laser at rank k of the elevation table (highest = row 0), whatever its laser
    number, the upside-down LiDAR included; a stated spec gives no per-laser rows."""
    from jaxdepth._src.presets import AV2_VLP32C
    from jaxdepth.batch.sources_job import cloud_sources

    log_ = av2.read_log(drive)
    assert log_.camera_times[CAMERA].tolist() == [t + CAMERA_DELAY_NS for t in SWEEPS]
    cloud = av2.read_cloud(log_)
    assert cloud.lidars == (None, None)
    sources, index = cloud_sources(cloud, fallback=AV2_VLP32C)
    rank_of_laser = np.argsort(LASER_OF_RANK)  # laser number (mod 32) -> its rank from the lowest
    for s in (0, 1):
        rows = np.asarray(sources.rows)[s]
        mine = index[s] >= 0
        want = 31 - rank_of_laser[cloud.ring[index[s][mine]]]
        np.testing.assert_array_equal(rows[mine], want)
        spec = sources.lidars[s]
        assert spec.beams == 32
        # the outermost lasers plus half the mean spacing (40 / 31 degrees), widened to the 0.25 degree grid
        assert 15.0 + 20.0 / 31 - 0.01 <= spec.fov_up_deg < 15.0 + 20.0 / 31 + 0.25
        assert -25.0 - 20.0 / 31 - 0.25 < spec.fov_down_deg <= -25.0 - 20.0 / 31 + 0.01
        assert (4 * spec.fov_up_deg, 4 * spec.fov_down_deg) == (round(4 * spec.fov_up_deg), round(4 * spec.fov_down_deg))
    stated, _ = cloud_sources(av2.read_cloud(log_, spec=AV2_VLP32C), fallback=AV2_VLP32C)
    assert stated.rows is None and stated.lidars[0] == AV2_VLP32C


def test_camera_from_ego_is_the_motion_compensated_chain(drive):
    """The camera 50 ms after the sweep sits 0.5 m further along the road: a point ahead is 0.5 m nearer."""
    log_ = av2.read_log(drive)
    t_cam = SWEEPS[0] + CAMERA_DELAY_NS
    T = av2.camera_from_ego(log_, CAMERA, sweep_ns=SWEEPS[0], camera_ns=t_cam)
    calib = av2.camera_from_ego(log_, CAMERA)
    p = np.array([20.0, 1.0, 2.0, 1.0])  # ego frame at the sweep
    np.testing.assert_allclose((T @ p)[2], (calib @ p)[2] - 0.5, atol=1e-9)
    np.testing.assert_allclose((T @ p)[:2], (calib @ p)[:2], atol=1e-9)
    rig = av2.read_rig(log_, (CAMERA,), sweep_ns=SWEEPS[0], camera_ns={CAMERA: t_cam})
    np.testing.assert_allclose(rig.cameras[0].T_cam_lidar, T, atol=1e-6)


def test_find_logs_from_the_dataset_root_down(tmp_path):
    def log_at(*parts):
        folder = tmp_path.joinpath(*parts)
        (folder / "sensors" / "lidar").mkdir(parents=True)
        (folder / "calibration").mkdir()
        return folder

    a, b = log_at("av2", "sensor", "train", "log-a"), log_at("av2", "sensor", "val", "log-b")
    root = tmp_path / "av2"
    assert av2_job.find_logs(root) == [a, b]
    assert av2_job.find_logs(root / "sensor") == [a, b]
    assert av2_job.find_logs(root / "sensor" / "val") == [b]
    assert av2_job.find_logs(b) == [b]
    assert av2_job.is_av2_root(root) and not av2_job.is_av2_root(tmp_path / "nothing")
    log_at("av2", "sensor", "test", "log-a")
    with pytest.raises(Exception, match="log id 'log-a' also at"):
        av2_job.find_logs(root)
    with pytest.raises(Exception, match="no Argoverse 2 sensor log"):
        av2_job.find_logs(root / "sensor" / "train" / "log-a" / "calibration")


def _errors(depth, truth, mask):
    both = mask & (depth > 0)
    assert both.sum() > 0.9 * mask.sum() > 500
    return np.abs(depth[both] - truth[both])


@pytest.mark.xdist_group("jobs_av2")  # one worker compiles the Argoverse 2 sources programs once
@pytest.mark.slow  # the two-source SGM program of one sweep at 96 x 64 (compile ~10 s)
def test_depth_at_camera_time_compensates_the_ego_motion(drive_one, tmp_path):
    """At 10 m/s and 50 ms: under 5 cm off the camera-time truth with compensation; the LiDAR-time
    depth is right at the LiDAR's time and about 0.5 m off at the camera's."""
    drive = drive_one
    notes = []
    summary = av2_job.run_av2(drive, tmp_path / "cam", cameras=[CAMERA], on_note=notes.append)
    assert summary.done == [f"{drive.name}/{t}" for t in FIRST] and not notes
    lidar = av2_job.run_av2(drive, tmp_path / "lidar", cameras=[CAMERA], time="lidar")
    assert lidar.done == summary.done
    for t in FIRST:
        t_cam = t + CAMERA_DELAY_NS
        at_cam = read_depth_png(av2_job.output_path(tmp_path / "cam", drive.name, CAMERA, t_cam))
        at_lidar = read_depth_png(av2_job.output_path(tmp_path / "lidar", drive.name, CAMERA, t))
        truth_cam, truth_lidar = true_depth(t_cam), true_depth(t)
        wall = _front_wall(truth_cam) & _front_wall(truth_lidar)
        assert np.median(truth_lidar[wall] - truth_cam[wall]) == pytest.approx(0.5, abs=0.01)
        compensated = _errors(at_cam, truth_cam, wall)
        assert np.percentile(compensated, 90) < 0.05, np.percentile(compensated, [50, 90, 100])
        assert np.percentile(_errors(at_lidar, truth_lidar, wall), 90) < 0.05
        stale = _errors(at_lidar, truth_cam, wall)
        assert 0.4 < np.median(stale) < 0.6
    # The same drive without images: depth at the LiDAR timestamps, named so, with a note.
    bare = write_log(tmp_path / "bare" / "log", images=False, sweeps=FIRST)
    notes = []
    av2_job.run_av2(bare, tmp_path / "bare_out", cameras=[CAMERA], on_note=notes.append)
    assert len(notes) == 1 and "no images of ring_front_center" in notes[0]
    for t in FIRST:
        out = av2_job.output_path(tmp_path / "bare_out", "log", CAMERA, t)
        assert read_depth_png(out).tobytes() == read_depth_png(
            av2_job.output_path(tmp_path / "lidar", drive.name, CAMERA, t)).tobytes()


def _brute_z_buffer(points, cam):
    """(H, W) nearest depth per pixel of ``points`` (ego frame) in ``cam`` (NumPy, float64, rounded pixels)."""
    T = np.asarray(cam.T_cam_lidar, np.float64)
    q = points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    q = q[q[:, 2] > 0.1]
    K = np.asarray(cam.K, np.float64)
    u = np.round(K[0, 0] * q[:, 0] / q[:, 2] + K[0, 2]).astype(int)
    v = np.round(K[1, 1] * q[:, 1] / q[:, 2] + K[1, 2]).astype(int)
    inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    zbuf = np.full((cam.height, cam.width), np.inf)
    np.minimum.at(zbuf, (v[inside], u[inside]), q[inside, 2])
    return np.where(np.isfinite(zbuf), zbuf, 0.0).astype(np.float32)


@pytest.mark.xdist_group("jobs_av2")  # one worker compiles the Argoverse 2 programs once
@pytest.mark.slow  # runs the job twice (two small baseline programs at 96 x 64)
def test_baselines_fill_the_projected_points(drive, tmp_path):
    """--method nearest: every pixel holds the depth of a LiDAR pixel at the smallest city-block distance
    (brute force); --method ip-basic: OpenCV's IP_Basic (Gaussian blur) of the same projection; both at
    camera time."""
    from jaxdepth.research.baselines import ip_basic_opencv

    for method in ("nearest", "ip-basic"):
        assert av2_job.run_av2(drive, tmp_path / method, cameras=[CAMERA], method=method).ok
    log_ = av2.read_log(drive)
    t, t_cam = SWEEPS[0], SWEEPS[0] + CAMERA_DELAY_NS
    cam = av2.read_rig(log_, (CAMERA,), sweep_ns=t, camera_ns={CAMERA: t_cam}).cameras[0]
    sparse = _brute_z_buffer(av2.read_cloud(log_, t).points, cam)
    q = 1.0 / 256  # PNG quantisation
    near = read_depth_png(av2_job.output_path(tmp_path / "nearest", drive.name, CAMERA, t_cam))
    sv, su = np.nonzero(sparse)
    v, u = np.mgrid[0:H, 0:W]
    dist = np.abs(v.reshape(-1, 1) - sv) + np.abs(u.reshape(-1, 1) - su)  # (pixels, seeds) city block
    nearest = dist == dist.min(axis=1, keepdims=True)
    ok = np.any(nearest & (np.abs(near.reshape(-1, 1) - sparse[sv, su]) <= q), axis=1)
    assert ok.mean() > 0.99, ok.mean()
    ipb = read_depth_png(av2_job.output_path(tmp_path / "ip-basic", drive.name, CAMERA, t_cam))
    want = ip_basic_opencv(sparse, blur_type="gaussian")  # jaxdepth.ip_basic's default blur
    assert np.mean(np.abs(ipb - want) <= q + 1e-4) > 0.99


@pytest.mark.xdist_group("jobs_av2")  # one worker compiles the Argoverse 2 programs once
@pytest.mark.slow  # the two-source SGM program of the camera-time test, plus the validity program
def test_extra_outputs(drive_one, tmp_path):
    """--preview, --validity, --seed-distance and --zero-invalid are written (zero depth exactly where
    invalid; valid pixels within the sensor's seed-distance limit); the depth at camera time stays within
    5 cm on the wall; a re-run skips every sweep. (A clamped --sweeps: the command-line test.)"""
    from jaxdepth.batch.extras import ExtraOutputs, decode_seed_distance, extra_path

    drive = drive_one
    extras = ExtraOutputs(preview=True, validity=True, seed_distance=True, zero_invalid=True)
    dst = tmp_path / "x"
    summary = av2_job.run_av2(drive, dst, cameras=[CAMERA], extras=extras)
    assert len(summary.done) == len(FIRST)
    limit = 3 * F * np.radians(40.0 / 31)  # 3 scan-line spacings of the stated VLP-32C (docs/validity.md)
    for t in FIRST:
        out = av2_job.output_path(dst, drive.name, CAMERA, t + CAMERA_DELAY_NS)
        depth = read_depth_png(out)
        import cv2
        valid = cv2.imread(str(extra_path(out, "validity")), cv2.IMREAD_UNCHANGED) > 0
        distance = decode_seed_distance(cv2.imread(str(extra_path(out, "seed_distance")), cv2.IMREAD_UNCHANGED))
        preview = cv2.imread(str(extra_path(out, "preview")), cv2.IMREAD_UNCHANGED)
        assert preview.shape[1:] == (W, 3) and preview.shape[0] > H
        assert 0.3 < valid.mean() < 1.0
        np.testing.assert_array_equal(depth > 0, valid & (depth > 0))
        assert np.all(depth[~valid] == 0) and np.all(distance[valid] <= limit + 1 / 16)
        truth = true_depth(t + CAMERA_DELAY_NS)
        wall = _front_wall(truth) & valid
        assert np.percentile(_errors(depth, truth, wall), 90) < 0.05
    again = av2_job.run_av2(drive, dst, cameras=[CAMERA], extras=extras)
    assert len(again.skipped) == len(FIRST) and not again.done


def test_lidar_time_flag_applies_to_argoverse_only(tmp_path, capsys):
    from jaxdepth import cli

    assert cli.main(["complete", str(tmp_path), str(tmp_path / "out"), "--lidar-time", "-q"]) == 2
    assert "--lidar-time applies to Argoverse 2 logs" in capsys.readouterr().err


@pytest.mark.xdist_group("jobs_av2")  # one worker compiles the Argoverse 2 programs once
@pytest.mark.slow  # runs the job through the command line (the small nearest-fill program)
def test_command_line_names_outputs_by_time_and_records_it(drive, tmp_path, capsys):
    """Camera time by default (<camera ts>.png), --lidar-time gives <lidar ts>.png; the run record refuses
    to mix the two in one folder; a --sweeps beyond the log is clamped with a note on stderr."""
    from jaxdepth import cli

    dst = tmp_path / "out"
    base = ["complete", str(drive), str(dst), "--cameras", CAMERA, "--method", "nearest", "-q"]
    assert cli.main(base + ["--sweeps", "4"]) == 0
    assert "--sweeps 4 clamped to 1: the log has 2 sweeps" in capsys.readouterr().err
    outs = sorted(p.relative_to(dst).as_posix() for p in dst.rglob("*.png"))
    assert outs == [f"{drive.name}/{CAMERA}/{t + CAMERA_DELAY_NS}.png" for t in SWEEPS]
    assert cli.main(base + ["--sweeps", "4", "--lidar-time"]) == 1
    assert "time" in capsys.readouterr().err
    assert cli.main(base[:2] + [str(tmp_path / "lidar")] + base[3:] + ["--lidar-time"]) == 0
    outs = sorted(p.relative_to(tmp_path / "lidar").as_posix() for p in (tmp_path / "lidar").rglob("*.png"))
    assert outs == [f"{drive.name}/{CAMERA}/{t}.png" for t in SWEEPS]
