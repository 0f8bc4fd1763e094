"""``--method nearest`` / ``ip-basic`` on the multi-source jobs: nuScenes (``--nusc-version``), KITTI raw
``--sweeps N`` and ``complete-rig`` with a sweeps JSON (the Argoverse 2 job's: tests/test_av2_synthetic.py).

Each baseline fills the sparse depth of every source merged as projected. Oracles: the job's input
points (read by the library's readers) projected with a NumPy z-buffer (nearest point per pixel,
rounded pixels), then SciPy's exact city-block distance transform (``distance_transform_cdt``): every
output pixel must hold the depth of a sparse pixel at the smallest city-block distance (a tie: any of
them), and OpenCV's IP_Basic (:func:`jaxdepth.research.baselines.ip_basic_opencv`) for ``ip-basic``.
The run record keeps the method: a re-run with another method into the same folder is refused.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import distance_transform_cdt

from jaxdepth.io.depth_png import read_depth_png
from test_kitti_sweeps_job import drive  # noqa: F401 (the synthetic KITTI raw drive fixture)

Q = 1.0 / 256  # PNG quantisation


def zbuffer(points, K, T, height: int, width: int) -> np.ndarray:
    """(H, W) nearest depth per pixel of ``points`` (N, 3) (NumPy float64, pixel = rounded u, v, z > 0.1 m)."""
    p = np.asarray(points, np.float64)[:, :3] @ np.asarray(T, np.float64)[:3, :3].T + np.asarray(T, np.float64)[:3, 3]
    p = p[np.isfinite(p).all(axis=1) & (p[:, 2] > 0.1)]
    uv = p @ np.asarray(K, np.float64).T
    u = np.round(uv[:, 0] / uv[:, 2]).astype(np.int64)
    v = np.round(uv[:, 1] / uv[:, 2]).astype(np.int64)
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    depth = np.full((height, width), np.inf)
    np.minimum.at(depth, (v[inside], u[inside]), p[inside, 2])
    return np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)


def nearest_share(out: np.ndarray, sparse: np.ndarray, *, samples: int = 3000, seed: int = 0) -> float:
    """Share of ``samples`` random pixels whose ``out`` depth is, within the PNG step, the depth of a sparse
    pixel at the smallest city-block distance (SciPy's exact taxicab transform; ties: any of them)."""
    assert (sparse > 0).any()
    dist = distance_transform_cdt(sparse <= 0, metric="taxicab")
    rng = np.random.default_rng(seed)
    H, W = sparse.shape
    ok = 0
    for v, u in zip(rng.integers(0, H, samples), rng.integers(0, W, samples)):
        d = int(dist[v, u])
        v0, u0 = max(0, v - d), max(0, u - d)
        crop = sparse[v0:v + d + 1, u0:u + d + 1]
        sv, su = np.nonzero(crop > 0)
        at = np.abs(sv + v0 - v) + np.abs(su + u0 - u) == d
        ok += bool(np.any(np.abs(crop[sv[at], su[at]] - out[v, u]) <= Q + 1e-6))
    return ok / samples


def check_baseline(method: str, out: np.ndarray, sparse: np.ndarray) -> None:
    from jaxdepth.research.baselines import ip_basic_opencv
    if method == "nearest":
        share = nearest_share(out, sparse)
        assert share > 0.99, share
        assert np.all(out > 0)                       # every pixel filled
    else:
        want = ip_basic_opencv(sparse, blur_type="gaussian")  # jaxdepth.ip_basic's default blur
        share = np.mean(np.abs(out - want) <= Q + 1e-4)
        assert share > 0.99, share


# ---------------------------------------------------------------- nuScenes


@pytest.fixture(scope="module")
def nusc_root(tmp_path_factory):
    """The fake v1.0-mini dataroot of tests/test_nuscenes_job.py (the shared sample's sweep, six cameras at
    400 x 225; s2 has one earlier sweep, s3 a missing LiDAR file)."""
    from conftest import require_shared
    from test_nuscenes_job import build_dataroot
    root = tmp_path_factory.mktemp("nusc_baselines")
    build_dataroot(root, require_shared("nuscenes", "sample"))
    return root


@pytest.mark.slow  # a job run: the six-camera nearest and IP_Basic programs (docs/testing.md)
@pytest.mark.parametrize("method, sweeps", [("nearest", 2), ("ip-basic", 1)])
def test_nuscenes_baselines_fill_the_merged_projection(nusc_root, tmp_path, method, sweeps):
    """Every camera of every sample: the fill of the key frame's sweep and, with --sweeps 2, the earlier
    sweep moved into the key frame (s2), merged as projected; s3 fails (no LiDAR file), the rest completes."""
    from jaxdepth.batch.nuscenes_job import run_nuscenes
    from jaxdepth.io import nuscenes as nusc
    from test_nuscenes_job import VERSION

    summary = run_nuscenes(nusc_root, tmp_path, version=VERSION, sweeps=sweeps, method=method)
    assert sorted(summary.done) == ["s1", "s2"] and [t for t, _ in summary.failed] == ["s3"]
    tables = nusc.load_tables(nusc_root, VERSION)
    for token in ("s1", "s2"):
        inputs = nusc.sample_inputs(tables, token, sweeps=sweeps, sources=True)
        points = inputs.cloud.points
        if token == "s2" and sweeps == 2:
            assert inputs.cloud.num_sources == 2
        for cam in inputs.cameras:
            out = read_depth_png(nusc.output_path(tmp_path, VERSION, cam.channel, cam.token))
            check_baseline(method, out, zbuffer(points, cam.K, cam.T_cam_lidar, cam.height, cam.width))
    again = run_nuscenes(nusc_root, tmp_path, version=VERSION, sweeps=sweeps, method=method)
    assert sorted(again.skipped) == ["s1", "s2"] and not again.done


@pytest.mark.slow  # a job run: the six-camera nearest program (docs/testing.md)
def test_nuscenes_command_line_records_the_method(nusc_root, tmp_path, capsys):
    """``complete --nusc-version --method nearest`` writes every camera of the good samples (exit 1: s3 fails);
    a re-run with the SGM into that folder is refused (the run record's method), as is the Ray engine."""
    from jaxdepth import cli
    from jaxdepth.batch import run_record
    from test_nuscenes_job import VERSION

    dst = tmp_path / "out"
    base = ["complete", str(nusc_root), str(dst), "--nusc-version", VERSION, "-q"]
    assert cli.main(base + ["--method", "nearest"]) == 1
    assert "s3" in capsys.readouterr().err
    assert len(list((dst / VERSION).rglob("*.png"))) == 12
    assert run_record.read_record(dst)["settings"]["method"] == "nearest"
    before = {p: p.read_bytes() for p in dst.rglob("*.png")}
    assert cli.main(base) == 1
    err = capsys.readouterr().err
    assert "method" in err and "nearest" in err and "sgm" in err
    assert {p: p.read_bytes() for p in dst.rglob("*.png")} == before        # nothing recomputed or removed
    assert cli.main(base + ["--method", "ip-basic", "--engine", "ray"]) == 2
    assert "--engine local only" in capsys.readouterr().err
    assert cli.main(base + ["--method", "nearest", "--validity"]) == 2
    assert "need --method sgm" in capsys.readouterr().err


# ---------------------------------------------------------------- KITTI raw --sweeps


@pytest.mark.slow  # a job run: the nearest program at KITTI camera size (docs/testing.md)
def test_kitti_sweeps_nearest_fills_both_sweeps_merged(drive, tmp_path, capsys):  # noqa: F811
    """``complete DRIVE DST --sweeps 1 --method nearest``: each frame's fill of its own sweep and its neighbour
    (OXTS-posed, :func:`jaxdepth.io.kitti_oxts.read_drive_cloud`) merged; the record refuses ``ip-basic``."""
    from jaxdepth import cli
    from jaxdepth.batch import run_record
    from jaxdepth.io import kitti_datasets
    from jaxdepth.io.kitti_oxts import read_drive_cloud

    drive, _ = drive
    dst = tmp_path / "out"
    base = ["complete", str(drive), str(dst), "--sweeps", "1", "--camera", "2", "--name", "base", "-q"]
    assert cli.main(base + ["--method", "nearest"]) == 0
    scan = kitti_datasets.kitti_raw_jobs(drive, dst, camera=2, name="base")
    assert len(scan.jobs) == 2
    for job in scan.jobs:
        cloud = read_drive_cloud(drive, job.sparse_path.stem, sweeps=1)
        assert cloud.num_sources == 2
        h, w = (int(s) for s in job.image_size)
        check_baseline("nearest", read_depth_png(job.out_path), zbuffer(cloud.points, job.K, job.T_cam_lidar, h, w))
    assert run_record.read_record(scan.jobs[0].out_path.parents[1])["settings"]["method"] == "nearest"
    assert cli.main(base + ["--method", "ip-basic"]) == 1
    assert "method" in capsys.readouterr().err


# ---------------------------------------------------------------- complete-rig with a sweeps JSON


@pytest.mark.slow  # a job run: the small nearest and IP_Basic programs of a 44 x 152 camera (docs/testing.md)
def test_complete_rig_sweeps_json_baselines(tmp_path, capsys):
    """A sweeps JSON of two sweeps of two LiDARs (four sources): ``complete-rig --method nearest`` and
    ``ip-basic`` fill all four merged as the sweep check leaves them; a re-run with another method is refused;
    a list of sweeps (one process) writes the same bytes."""
    from jaxdepth import cli
    from jaxdepth.io import read_rig_json
    from jaxdepth.io.sweep_frame import prepare_cloud
    from jaxdepth.io.sweeps import read_sweeps_cloud
    from test_hidden_sources import _write_sequence

    sweeps, rig_path = _write_sequence(tmp_path, 2)
    rig = read_rig_json(rig_path)
    frame = prepare_cloud(read_sweeps_cloud(sweeps, rig), rig)
    assert frame.cloud.num_sources == 4
    cam = frame.rig.cameras[0]
    sparse = zbuffer(frame.cloud.points, cam.K, cam.T_cam_lidar, cam.height, cam.width)
    for method in ("nearest", "ip-basic"):
        out = tmp_path / method
        assert cli.main(["complete-rig", str(sweeps), str(rig_path), str(out), "--method", method, "-q"]) == 0
        check_baseline(method, read_depth_png(out / "cam.png"), sparse)
    assert cli.main(["complete-rig", str(sweeps), str(rig_path), str(tmp_path / "nearest"), "-q"]) == 1
    assert "method" in capsys.readouterr().err
    from jaxdepth.batch import run_record
    assert run_record.read_record(tmp_path / "nearest")["settings"]["outlier_removal"] is False   # what ran
    assert cli.main(["complete-rig", str(sweeps), str(rig_path), str(tmp_path / "refused"), "--method", "nearest",
                     "--outlier-removal", "-q"]) == 2
    assert "drop --outlier-removal" in capsys.readouterr().err and not (tmp_path / "refused").exists()
    (tmp_path / "list.txt").write_text(f"{sweeps}\n")
    listed = tmp_path / "listed"
    assert cli.main(["complete-rig", str(tmp_path / "list.txt"), str(rig_path), str(listed), "--method", "nearest",
                     "-q"]) == 0
    assert (listed / "sweeps" / "cam.png").read_bytes() == (tmp_path / "nearest" / "cam.png").read_bytes()


@pytest.mark.slow  # a job run: the small nearest programs of two cameras (docs/testing.md)
def test_complete_rig_one_sweep_nearest_each_camera_at_its_size(tmp_path, capsys):
    """One LiDAR sweep (the wall of tests/helpers.py), two cameras of different sizes turned 15 degrees left
    and 8 down (so that the depth changes from seed to seed along rows and columns): ``--method nearest
    --distance l2`` fills each camera at its own size with the depth of a Euclidean-nearest sparse pixel
    (SciPy's exact ``distance_transform_edt`` distances); the --preview extra works, --validity is refused."""
    from scipy.ndimage import distance_transform_edt
    from scipy.spatial.transform import Rotation

    from helpers import WALL_CAMERAS, LEVEL, wall_sweep, write_wall_rig
    from jaxdepth import cli

    sweep, rig = tmp_path / "sweep.npy", tmp_path / "rig.json"
    wall_sweep(sweep)
    T = np.asarray(LEVEL, np.float64)
    T[:3, :3] = Rotation.from_euler("yx", [-15.0, -8.0], degrees=True).as_matrix() @ T[:3, :3]
    write_wall_rig(rig, T_cam_lidar={name: T.tolist() for name in WALL_CAMERAS})
    out = tmp_path / "out"
    assert cli.main(["complete-rig", str(sweep), str(rig), str(out), "--no-estimate", "--method", "nearest",
                     "--distance", "l2", "--preview", "-q"]) == 0
    points = np.load(sweep)[:, :3]
    for name, (w, h, K) in WALL_CAMERAS.items():
        sparse = zbuffer(points, K, T, h, w)
        assert np.ptp(sparse[sparse > 0]) > 1.0 and (sparse > 0).mean() > 0.05
        got = read_depth_png(out / f"{name}.png")
        assert got.shape == (h, w) and (out / f"{name}_preview.png").exists()
        dist = distance_transform_edt(sparse <= 0)
        sv, su = np.nonzero(sparse)
        v, u = np.mgrid[0:h, 0:w]
        d2 = (v.reshape(-1, 1) - sv) ** 2 + (u.reshape(-1, 1) - su) ** 2        # (pixels, seeds), brute force
        np.testing.assert_allclose(np.sqrt(d2.min(axis=1)), dist.ravel())       # SciPy = brute force
        at = d2 == d2.min(axis=1, keepdims=True)
        ok = np.any(at & (np.abs(got.reshape(-1, 1) - sparse[sv, su]) <= Q + 1e-6), axis=1)
        assert ok.mean() > 0.99, ok.mean()
    assert cli.main(["complete-rig", str(sweep), str(rig), str(tmp_path / "v"), "--no-estimate", "--method",
                     "nearest", "--validity", "-q"]) == 2
    assert "need --method sgm" in capsys.readouterr().err


SEEDS = dict(validity=True)


@pytest.mark.parametrize("call", ["run_jobs", "run_jobs_ray", "run_av2", "run_nuscenes", "complete_samples",
                                  "rig_results"])
def test_every_job_refuses_a_baseline_with_seed_options_in_one_wording(call, tmp_path):
    """Each job's library entry point refuses ``method="nearest"`` with an extra that needs the SGM's seeds
    before it reads anything, naming itself, in the one wording of ``runner.check_sgm_only``; the
    multi-source jobs also refuse a method that is none of theirs."""
    from jaxdepth.batch import av2_job, nuscenes_job, rig_job, runner, scale
    from jaxdepth.batch.extras import ExtraOutputs

    extras = ExtraOutputs(**SEEDS)
    calls = {
        "run_jobs": lambda m: runner.run_jobs([], method=m, extras=extras),
        "run_jobs_ray": lambda m: scale.run_jobs_ray([], method=m, extras=extras),
        "run_av2": lambda m: av2_job.run_av2(tmp_path / "missing", tmp_path, method=m, extras=extras),
        "run_nuscenes": lambda m: nuscenes_job.run_nuscenes(tmp_path / "missing", tmp_path, version="v1.0-mini",
                                                            method=m, extras=extras),
        "complete_samples": lambda m: nuscenes_job.complete_samples(
            None, [], None, None, sweeps=1, ego_motion=True, config=None, extras=extras, overwrite=False,
            png_compression=1, method=m),
        "rig_results": lambda m: rig_job.rig_results(None, extras, method=m),
    }
    with pytest.raises(ValueError, match=r"^\S.*: validity, seed distance, zero-invalid and image guidance need "
                                         r"method 'sgm', got 'nearest'$"):
        calls[call]("nearest")
    if call not in ("run_jobs", "run_jobs_ray"):  # the KITTI runners take complete_with's methods
        with pytest.raises(ValueError, match=r"field 'method' expected one of \('sgm', 'nearest', 'ip-basic'\), "
                                             r"got 'bogus'"):
            calls[call]("bogus")
