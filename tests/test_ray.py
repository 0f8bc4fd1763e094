"""Ray engine (jaxdepth.batch.scale) against the single-process runner, on a local loopback Ray.

Oracle: :func:`jaxdepth.batch.runner.run_jobs` on the same folder must write the same
bytes. The folder holds the two real KITTI sparse frames (whole 375 x 1242 frames) when
../shared/data is there, else synthetic sparse images, plus one corrupt PNG.
Only needs Ray (``pip install 'jaxdepth[ray]'``), never the shared data.
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from jaxdepth.batch import runner, scale
from jaxdepth._src import presets
from jaxdepth.io.depth_png import read_depth_png, write_depth_png

# Ray starts its processes with fork+exec after JAX is up (harmless), and Ray Data reads its own
# deprecated settings when it copies its context.
pytestmark = [pytest.mark.slow,  # Ray clusters and subprocesses
              pytest.mark.xdist_group("ray"),  # one local cluster at a time, on one worker
              pytest.mark.filterwarnings("ignore:os.fork\\(\\) was called:RuntimeWarning"),
              pytest.mark.filterwarnings("ignore::DeprecationWarning:ray.data.context")]

#: Ray itself, imported by ``_import_ray`` when the module's first test runs, not while collecting: importing
#: ``ray`` and ``ray.data`` (pandas, pyarrow) costs each collecting process about 1.3 s of CPU, and the quick
#: subset collects this module without running a test of it.
ray = None


@pytest.fixture(autouse=True, scope="module")
def _import_ray():
    global ray
    ray = pytest.importorskip("ray")
    pytest.importorskip("ray.data")


METHOD = "nearest"  # the fastest method: the engines, not the algorithm, are under test
#: One frame per batch, at the frame's own 375 x 1242: the local runner's oracle run is then the nearest
#: fill that test_kitti_datasets' depth-completion tree and test_bad_inputs compile for one such frame
#: (the session's compilation cache, which Ray's workers share, reads it back).
BATCH = 1
H, W = 375, 1242  # a whole KITTI frame (camera 2's K as it is)
GOOD = ("frame_02", "frame_03")
BAD = "frame_bad"


def _shared_kitti() -> pathlib.Path:
    root = os.environ.get("JAXDEPTH_SHARED_DATA")
    root = pathlib.Path(root) if root else pathlib.Path(__file__).resolve().parents[2] / "shared" / "data"
    return root / "kitti" / "drive_0001_frame05"


def _frames() -> list[tuple[str, np.ndarray, np.ndarray]]:
    K = np.array(presets.KITTI_K_CAM2, np.float32).copy()
    kitti = _shared_kitti()
    frames = []
    for name, cam in zip(GOOD, ("02", "03")):
        png = kitti / f"velodyne_raw_image_{cam}.png"
        if png.exists():
            depth = read_depth_png(png)
            assert depth.shape == (H, W), depth.shape
        else:  # synthetic stand-in: ~4 % of pixels with depths 2..80 m, like the real input
            rng = np.random.default_rng(int(cam))
            depth = np.where(rng.random((H, W)) < 0.04, rng.uniform(2.0, 80.0, (H, W)), 0.0).astype(np.float32)
        frames.append((name, depth, K))
    return frames


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> pathlib.Path:
    """KITTI layout: velodyne_raw/*.png + intrinsics/*.txt, two good frames and one corrupt PNG."""
    root = tmp_path_factory.mktemp("kitti_layout")
    (root / "velodyne_raw").mkdir()
    (root / "intrinsics").mkdir()
    for name, depth, K in _frames():
        write_depth_png(root / "velodyne_raw" / f"{name}.png", depth)
        (root / "intrinsics" / f"{name}.txt").write_text(" ".join(f"{v:.9g}" for v in K.reshape(-1)) + "\n")
    # A PNG signature followed by garbage: the reader must refuse it.
    (root / "velodyne_raw" / f"{BAD}.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    (root / "intrinsics" / f"{BAD}.txt").write_text((root / "intrinsics" / f"{GOOD[0]}.txt").read_text())
    return root


def _jobs(src: pathlib.Path, dst: pathlib.Path) -> list:
    dst.mkdir(parents=True, exist_ok=True)
    names = [p.stem for p in sorted((src / "velodyne_raw").glob("*.png"))]
    return [runner.FrameJob(name=n, sparse_path=src / "velodyne_raw" / f"{n}.png", out_path=dst / f"{n}.png",
                            intrinsics_path=src / "intrinsics" / f"{n}.txt") for n in names]


@pytest.fixture(scope="module")
def reference(folder, tmp_path_factory) -> pathlib.Path:
    """Outputs of the single-process runner (the oracle)."""
    dst = tmp_path_factory.mktemp("reference")
    summary = runner.run_jobs(_jobs(folder, dst), method=METHOD, batch_size=BATCH)
    assert sorted(summary.done) == list(GOOD)
    assert [name for name, _ in summary.failed] == [BAD]
    return dst


def _assert_same_outputs(dst: pathlib.Path, reference: pathlib.Path) -> None:
    assert sorted(p.name for p in dst.glob("*.png")) == [f"{n}.png" for n in GOOD]
    assert not list(dst.glob(".*.tmp")), "a temporary file was left behind"
    for name in GOOD:
        got = (dst / f"{name}.png").read_bytes()
        assert got == (reference / f"{name}.png").read_bytes(), f"{name}: Ray output differs from run_jobs"


def _recorder():
    calls = []
    return calls, lambda name, status: calls.append((name, status))


def _check_reference_is_completion(folder: pathlib.Path, reference: pathlib.Path) -> None:
    for name in GOOD:
        sparse = read_depth_png(folder / "velodyne_raw" / f"{name}.png")
        dense = read_depth_png(reference / f"{name}.png")
        assert dense.shape == sparse.shape
        assert np.count_nonzero(dense) > 10 * np.count_nonzero(sparse)  # densified, not copied


def test_local_cluster_is_started_matches_runner_and_is_shut_down(folder, reference, tmp_path, monkeypatch):
    """address=None: a local Ray is started for the run and shut down after it."""
    if ray.is_initialized():
        pytest.skip("another test left Ray running in this process")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    _check_reference_is_completion(folder, reference)
    calls, record = _recorder()
    node_ips = set()

    def on_progress(name, status):
        node_ips.add(ray.util.get_node_ip_address())  # called while the local Ray is up
        record(name, status)

    dst = tmp_path / "out"
    summary = scale.run_jobs_ray(_jobs(folder, dst), method=METHOD, batch_size=BATCH, address=None,
                                 on_progress=on_progress)
    assert not ray.is_initialized()
    assert node_ips == {"127.0.0.1"}, "the local Ray was not on loopback only"
    assert sorted(summary.done) == list(GOOD)
    assert summary.skipped == []
    assert [name for name, _ in summary.failed] == [BAD]
    assert f"{BAD}.png" in summary.failed[0][1]  # the message names the file
    assert sorted(calls) == sorted([(n, "done") for n in GOOD] + [(BAD, f"failed: {summary.failed[0][1]}")])
    _assert_same_outputs(dst, reference)


@pytest.fixture(scope="module")
def local_ray():
    """One loopback Ray for the rest of the module; run_jobs_ray reuses it and leaves it running."""
    if ray.is_initialized():
        yield
        return
    with scale._local_ray(ray):
        assert ray.util.get_node_ip_address() == "127.0.0.1"
        yield


def test_folder_then_rerun_skips_finished_frames(local_ray, folder, reference, tmp_path):
    dst = tmp_path / "out"
    first = scale.complete_folder_ray(folder, dst, method=METHOD, batch_size=BATCH)
    assert ray.is_initialized()  # a cluster this process was already connected to is not shut down
    assert sorted(first.done) == list(GOOD)
    assert [name for name, _ in first.failed] == [BAD]
    _assert_same_outputs(dst, reference)
    written = {n: (dst / f"{n}.png").stat().st_mtime_ns for n in GOOD}

    # Re-run: finished frames are skipped before any work, the bad one is reported again.
    calls, on_progress = _recorder()
    again = scale.complete_folder_ray(folder, dst, method=METHOD, batch_size=BATCH, on_progress=on_progress)
    assert sorted(again.skipped) == list(GOOD)
    assert again.done == []
    assert [name for name, _ in again.failed] == [BAD]
    assert sorted(c for c in calls if c[1] == "skipped") == [(n, "skipped") for n in GOOD]
    assert {n: (dst / f"{n}.png").stat().st_mtime_ns for n in GOOD} == written


class _CrashOnce(scale._CompleteFrames):
    """Kills its actor process on the first batch while the flag file exists (removed first)."""

    flag = ""

    def __call__(self, batch):
        if self.flag and os.path.exists(self.flag):
            os.remove(self.flag)
            os._exit(1)
        return super().__call__(batch)


def test_overwrite_with_a_dead_actor_restarted_and_its_batch_retried(local_ray, folder, reference, tmp_path,
                                                                     monkeypatch):
    """overwrite=True replaces stale outputs; an actor killed mid-run is restarted and its batch retried."""
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import this test module
    flag = tmp_path / "crash-once"
    flag.write_text("")
    monkeypatch.setattr(_CrashOnce, "flag", str(flag))
    monkeypatch.setattr(scale, "_CompleteFrames", _CrashOnce)
    dst = tmp_path / "out"
    jobs = _jobs(folder, dst)
    for name in GOOD:  # stale outputs of an older run
        write_depth_png(dst / f"{name}.png", np.ones((4, 4), np.float32))
    summary = scale.run_jobs_ray(jobs, method=METHOD, batch_size=BATCH, overwrite=True)
    assert not flag.exists(), "the actor never crashed: nothing was retried"
    assert summary.skipped == []
    assert sorted(summary.done) == list(GOOD)
    assert [name for name, _ in summary.failed] == [BAD]
    _assert_same_outputs(dst, reference)


def test_without_ray_the_error_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # makes `import ray` raise ImportError
    with pytest.raises(ImportError, match=r"pip install 'jaxdepth\[ray\]'"):
        scale.run_jobs_ray([runner.FrameJob(name="x", sparse_path=pathlib.Path("x.png"),
                                            out_path=pathlib.Path("/nonexistent/x.png"))])


def test_bad_arguments_are_rejected_before_ray(tmp_path):
    job = runner.FrameJob(name="a", sparse_path=tmp_path / "a.png", out_path=tmp_path / "o.png")
    with pytest.raises(ValueError, match="batch_size"):
        scale.run_jobs_ray([job], batch_size=0)
    with pytest.raises(ValueError, match="distinct output paths"):
        scale.run_jobs_ray([job, job])


def test_ray_is_imported_only_when_the_ray_engine_runs():
    code = ("import sys, jaxdepth, jaxdepth.batch.runner, jaxdepth.batch.scale, jaxdepth.cli\n"
            "assert 'ray' not in sys.modules, sorted(m for m in sys.modules if m.startswith('ray'))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                            cwd=pathlib.Path(__file__).resolve().parents[1])
    assert result.returncode == 0, result.stderr


# ---------------------------------------------------------------- nuScenes dataroot (run_nuscenes_ray)


def _nuscenes_front(tmp_path: pathlib.Path) -> pathlib.Path:
    """The fake v1.0-mini dataroot of tests/test_nuscenes_job.py with CAM_FRONT only (no JPEGs): s1, s2
    complete, s3's LiDAR file is missing. The one-camera dataroot of test_extras_cli's nuScenes extras run:
    the same compiled rig completion with validity."""
    from scenes import nuscenes_front_dataroot
    return nuscenes_front_dataroot(tmp_path / "dataroot", tmp_path)[0]


def _nuscenes_six_cameras(tmp_path: pathlib.Path) -> pathlib.Path:
    """The fake v1.0-mini dataroot of tests/test_nuscenes_job.py as it is (six quarter-size cameras and their
    JPEGs): its guided run compiles the same guided rig completion as that module's."""
    from tests.conftest import require_shared
    from tests.test_nuscenes_job import build_dataroot
    root = tmp_path / "dataroot"
    build_dataroot(root, require_shared("nuscenes", "sample"))
    return root


def _tree(root: pathlib.Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_nuscenes_dataroot_matches_the_local_engine_reports_the_bad_sample_and_resumes(local_ray, tmp_path):
    """Oracle: nuscenes_job.run_nuscenes on the same dataroot (with validity masks): the same files, the
    same bytes; the bad sample is a failed row with the local engine's message, in a batch with the good
    ones; a re-run skips the finished samples before any work."""
    from jaxdepth.batch import extras, nuscenes_job
    from tests.test_nuscenes_job import VERSION

    root = _nuscenes_front(tmp_path)
    wanted = extras.ExtraOutputs(validity=True)
    local = nuscenes_job.run_nuscenes(root, tmp_path / "local", version=VERSION, extras=wanted)
    reference = _tree(tmp_path / "local")
    assert sorted(reference) == sorted(f"{VERSION}/CAM_FRONT/CAM_FRONT_{s}{kind}.png"
                                       for s in ("s1", "s2") for kind in ("", "_validity"))
    dense = read_depth_png(tmp_path / "local" / VERSION / "CAM_FRONT" / "CAM_FRONT_s1.png")
    assert np.count_nonzero(dense) > 0.5 * dense.size  # a completion, not an empty image

    calls, on_progress = _recorder()
    dst = tmp_path / "ray"
    summary = scale.run_nuscenes_ray(root, dst, version=VERSION, extras=wanted, on_progress=on_progress)
    assert ray.is_initialized()
    assert sorted(summary.done) == sorted(local.done) == ["s1", "s2"] and summary.skipped == []
    [(name, message)] = summary.failed
    assert summary.failed == local.failed and name == "s3" and "s3.pcd.bin" in message
    assert sorted(calls) == [("s1", "done"), ("s2", "done"), ("s3", f"failed: {message}")]
    got = _tree(dst)
    assert sorted(got) == sorted(reference), "the Ray engine wrote other files (or left temporaries)"
    for path, data in reference.items():
        assert got[path] == data, f"{path}: Ray output differs from run_nuscenes"

    stamps = {p: p.stat().st_mtime_ns for p in dst.rglob("*.png")}
    calls, on_progress = _recorder()
    again = scale.run_nuscenes_ray(root, dst, version=VERSION, extras=wanted, on_progress=on_progress)
    assert sorted(again.skipped) == ["s1", "s2"] and again.done == [] and [n for n, _ in again.failed] == ["s3"]
    assert sorted(c for c in calls if c[1] == "skipped") == [("s1", "skipped"), ("s2", "skipped")]
    assert {p: p.stat().st_mtime_ns for p in dst.rglob("*.png")} == stamps


def test_nuscenes_guided_matches_the_local_engine_and_reports_the_bad_image(local_ray, tmp_path):
    """Image-guided seeds (guidance_weight > 0) on Ray: each actor reads the samples' JPEGs itself; the PNGs
    are the local engine's bytes, and a corrupt JPEG fails its sample (s2) with the local engine's message."""
    from jaxdepth import SGMConfig
    from jaxdepth.batch import nuscenes_job
    from tests.test_nuscenes_job import VERSION

    root = _nuscenes_six_cameras(tmp_path)
    bad = root / "samples" / "CAM_BACK" / "s2.jpg"
    bad.write_bytes(bad.read_bytes()[:200])  # truncated: OpenCV cannot decode it
    config = SGMConfig(guidance_weight=2.0)
    local = nuscenes_job.run_nuscenes(root, tmp_path / "local", version=VERSION, config=config)
    assert local.done == ["s1"] and [n for n, _ in local.failed] == ["s2", "s3"]
    assert dict(local.failed)["s2"] == f"{bad}: cannot decode as an image (expected a camera image (8-bit PNG or JPEG))"
    summary = scale.run_nuscenes_ray(root, tmp_path / "ray", version=VERSION, config=config)
    assert summary.done == ["s1"] and sorted(summary.failed) == sorted(local.failed)
    reference, got = _tree(tmp_path / "local"), _tree(tmp_path / "ray")
    channels = sorted(p.name for p in (root / "samples").iterdir() if p.name.startswith("CAM_"))
    assert len(channels) == 6
    assert sorted(reference) == sorted(got) == [f"{VERSION}/{ch}/{ch}_s1.png" for ch in channels]
    for path, data in reference.items():
        assert got[path] == data, f"{path}: Ray output differs from run_nuscenes"
