"""Batched offline processing: identical to single frames, one compilation per bucket, sharding."""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from jaxdepth import SGMConfig, complete_stages
from jaxdepth.batch import runner
from jaxdepth._src.methods import complete_with
from jaxdepth.io import read_depth_png

from helpers import small_frames, write_kitti_folder

CONFIG = SGMConfig()
#: The batching tests run the "nearest" method (outlier removal, which reads each frame's K and T,
#: then the nearest-seed fill): the runner's strategies, buckets and sharding wrap any per-frame
#: function alike, and this one compiles in a fraction of SGM's time. SGM through the runner is
#: checked against per-frame ``complete_stages`` by test_last_batch_is_padded_not_recompiled; SGM's
#: own vmap == loop by the ``complete`` rows of tests/stage_table.py; SGM sharded over two devices by
#: test_cli_split_makes_two_devices_and_two_devices_match_one.
PLUMBING = "nearest"

#: Every test here runs the batch runner (job runs, one of them in a subprocess: docs/testing.md).
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def frames():
    return small_frames(5)


@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 batches once
@pytest.mark.parametrize("strategy", ["loop", "map", "vmap"])
def test_batched_equals_single_frame_calls(frames, strategy):
    items, T = frames
    depths = np.stack([d for d, _ in items])
    Ks = np.stack([k for _, k in items])
    batched = runner.complete_batch(depths, Ks, T, batch_size=2, strategy=strategy, method=PLUMBING)
    single = np.stack([np.asarray(complete_with(d, k, T, method=PLUMBING)) for d, k in items])
    if strategy == "loop":  # single-frame calls: the same bytes
        assert batched.tobytes() == single.tobytes()
    # XLA may fuse the per-frame body differently inside a compiled batch: float32 rounding only
    np.testing.assert_allclose(batched, single, rtol=1e-6, atol=1e-5)


@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 batches once
def test_the_batch_program_compiles_with_the_entry_options_and_gives_the_plain_jit_bytes(frames):
    """The job's program (SGM, "map", as the offline job runs it) is an ``xla_tuning.entry_jit`` function: it
    carries the entry points' compile options (region-analysis copy insertion), which the program cache gives
    the ``jit`` of a stored program; oracle: a plain ``jax.jit`` of the same function, the same bytes."""
    import jax
    from jaxdepth._src import xla_tuning
    items, T = frames
    depths = np.stack([d for d, _ in items[:2]])
    Ks = np.stack([k for _, k in items[:2]])
    Ts = np.ascontiguousarray(np.broadcast_to(T, (2, 4, 4)), np.float32)
    fn = runner.batched_completion(2, *depths.shape[1:], method="sgm", config=CONFIG, lidar=runner.presets.KITTI_HDL64,
                                   strategy="map")
    assert fn.jitted.compiler_options == xla_tuning.COMPILER_OPTIONS
    plain = jax.jit(fn.jitted.__wrapped__)
    assert np.asarray(fn(depths, Ks, Ts)).tobytes() == np.asarray(plain(depths, Ks, Ts)).tobytes()


@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 batches once
def test_batch_size_changes_rounding_only(frames):
    items, T = frames
    depths = np.stack([d for d, _ in items])
    Ks = np.stack([k for _, k in items])
    # 5 frames: five calls of one frame against three of two (the last padded); batch sizes 1 and 2 are
    # the ones the other runner tests compile (a new batch size is a new program)
    one, two = (runner.complete_batch(depths, Ks, T, batch_size=b, strategy="map", method=PLUMBING) for b in (1, 2))
    np.testing.assert_allclose(one, two, rtol=1e-6, atol=1e-5)


def _count_traces(monkeypatch) -> list:
    """Counts the traces of the runner's compiled SGM batch: a job's listed program
    (:mod:`jaxdepth.batch.listed`) calls ``pipeline._complete_stages`` once per trace of its body
    (a Python wrapper around it, looked up at trace time)."""
    from jaxdepth._src import pipeline
    traces, real = [], pipeline._complete_stages

    def counted(*args, **kwargs):
        traces.append(args[0].shape)
        return real(*args, **kwargs)

    monkeypatch.setattr(pipeline, "_complete_stages", counted)
    return traces


def _record_buckets(monkeypatch) -> list:
    """(batch size, listed_only) of each program the runner asks :func:`runner.batched_completion` for."""
    sizes, real = [], runner.batched_completion

    def spy(batch_size, *args, **kwargs):
        sizes.append((batch_size, kwargs.get("listed_only", False)))
        return real(batch_size, *args, **kwargs)

    monkeypatch.setattr(runner, "batched_completion", spy)
    return sizes


@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 batches once
def test_last_batch_is_padded_not_recompiled(tmp_path, frames, monkeypatch):
    items, T = frames
    src = write_kitti_folder(tmp_path / "src", items)
    jobs = [runner.FrameJob(name=p.name, sparse_path=p, out_path=tmp_path / "out" / p.name,
                            intrinsics_path=src / "intrinsics" / (p.stem + ".txt"))
            for p in sorted((src / "velodyne_raw").glob("*.png"))]
    (tmp_path / "out").mkdir()
    runner.batched_completion.cache_clear()
    traces = _count_traces(monkeypatch)
    buckets = _record_buckets(monkeypatch)
    summary = runner.run_jobs(jobs, batch_size=2, T_cam_lidar=T, config=CONFIG)
    assert summary.ok and len(summary.done) == 5
    # 5 frames in batches of 2 (the last padded), one bucket: these frames (71 % of the pixels with depth)
    # overflow the listed program, so batch 1 is recomputed by the full program when collected (after batch
    # 2's dispatch, listed); from then on the bucket runs the full program (batch 3; batch 2's recompute);
    # each program traced at most once (the full one may come from the program cache: this group's entry-options
    # test stores the same program)
    listed, full = (2, True), (2, False)
    assert buckets == [listed, listed, full, full, full] and 1 <= len(traces) <= 2
    # Oracle: the public per-frame pipeline, complete_stages (the program test_extras_cli's oracle
    # compiles for these frames: same size, LiDAR and call form)
    for (depth, K), job in zip(items, jobs):
        expected = np.asarray(complete_stages(read_depth_png(job.sparse_path), K, T).depth)
        got = read_depth_png(job.out_path)
        np.testing.assert_allclose(got, np.round(expected * 256) / 256, atol=1 / 256 + 1e-6)


@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 batches once
def test_resume_skips_finished_and_never_touches_inputs(tmp_path, frames):
    items, T = frames
    src = write_kitti_folder(tmp_path / "src", items[:3])
    before = {p: p.read_bytes() for p in src.rglob("*") if p.is_file()}
    jobs = [runner.FrameJob(name=p.name, sparse_path=p, out_path=tmp_path / "out" / p.name,
                            intrinsics_path=src / "intrinsics" / (p.stem + ".txt"))
            for p in sorted((src / "velodyne_raw").glob("*.png"))]
    (tmp_path / "out").mkdir()
    first = runner.run_jobs(jobs[:2], batch_size=2, T_cam_lidar=T, method=PLUMBING)
    stamps = {j.out_path: j.out_path.stat().st_mtime_ns for j in jobs[:2]}
    second = runner.run_jobs(jobs, batch_size=2, T_cam_lidar=T, method=PLUMBING)  # one frame left: bucket 1
    assert len(first.done) == 2 and second.skipped == [j.name for j in jobs[:2]] and second.done == [jobs[2].name]
    assert all(j.out_path.stat().st_mtime_ns == stamps[j.out_path] for j in jobs[:2])
    assert before == {p: p.read_bytes() for p in src.rglob("*") if p.is_file()}


@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 batches once
def test_bad_frame_is_reported_and_the_rest_completes(tmp_path, frames):
    items, T = frames
    src = write_kitti_folder(tmp_path / "src", items[:3])
    (src / "velodyne_raw" / "frame_001.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    jobs = [runner.FrameJob(name=p.name, sparse_path=p, out_path=tmp_path / "out" / p.name,
                            intrinsics_path=src / "intrinsics" / (p.stem + ".txt"))
            for p in sorted((src / "velodyne_raw").glob("*.png"))]
    (tmp_path / "out").mkdir()
    summary = runner.run_jobs(jobs, batch_size=2, T_cam_lidar=T, method=PLUMBING)
    assert [name for name, _ in summary.failed] == ["frame_001.png"]
    assert "frame_001.png" in summary.failed[0][1]
    assert sorted(summary.done) == ["frame_000.png", "frame_002.png"]
    assert not (tmp_path / "out" / "frame_001.png").exists()
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["frame_000.png", "frame_002.png"]


@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 batches once
def test_a_single_frame_is_not_padded_to_the_default_batch(tmp_path, frames, monkeypatch):
    items, T = frames
    src = write_kitti_folder(tmp_path / "src", items[:1])
    png = next((src / "velodyne_raw").glob("*.png"))
    job = runner.FrameJob(name=png.name, sparse_path=png, out_path=tmp_path / "one.png",
                          intrinsics_path=src / "intrinsics" / (png.stem + ".txt"))
    runner.batched_completion.cache_clear()
    buckets = _record_buckets(monkeypatch)
    summary = runner.run_jobs([job], batch_size=4, T_cam_lidar=T, config=CONFIG, devices=1, method=PLUMBING)
    assert summary.ok and summary.done == [png.name]
    assert buckets == [(1, False)]  # compiled for a batch of one frame, not four (a baseline: no listed program)


@pytest.mark.parametrize("bad", [0, -1, 1.0, True, "2"])
def test_job_device_lists_come_from_one_helper(tmp_path, bad):
    """The rig jobs' device lists (batch.devices): the first N local devices, all there are when fewer (N > the
    devices there are is no error, as before), and a count that is not an integer >= 1 fails naming the job."""
    import jax

    from jaxdepth.batch.av2_job import run_av2
    from jaxdepth.batch.devices import check_device_count, first_devices
    assert first_devices(1) == jax.local_devices()[:1] and first_devices(64) == jax.local_devices()
    assert check_device_count(3, where="job") == 3
    with pytest.raises(ValueError, match=r"^run_nuscenes: field 'devices' expected an integer >= 1"):
        check_device_count(bad, where="run_nuscenes")
    with pytest.raises(ValueError, match=r"^run_av2: field 'devices' expected an integer >= 1"):
        run_av2(tmp_path / "logs", tmp_path / "out", devices=bad)


DEVICES = r"""
import os, sys
sys.path.insert(0, {tests!r})
from jaxdepth.batch.devices import split_cpu_into_devices
first = split_cpu_into_devices(2)
again = split_cpu_into_devices(3)   # XLA_FLAGS now sets a count: left alone
import jax
n = len(jax.local_devices())
late = split_cpu_into_devices(4)    # backends running: too late, left alone
print("split", first, again, n, late, os.environ["XLA_FLAGS"].count("device_count"), flush=True)
# the two devices made above: an SGM batch sharded over both (the test compares it with one device)
import numpy as np
from helpers import small_frames
from jaxdepth.batch import runner
assert len(jax.local_devices()) == 2, jax.local_devices()
items, T = small_frames(3)
depths = np.stack([d for d, _ in items]); Ks = np.stack([k for _, k in items])
np.save({out!r}, runner.complete_batch(depths, Ks, T, batch_size=2, devices=2, method="sgm"))
print("sharded-saved", flush=True)
"""


@pytest.mark.xdist_group("jobs_small_sgm_batches")  # one worker compiles the 64 x 128 batches once
def test_cli_split_makes_two_devices_and_two_devices_match_one(tmp_path):
    """A subprocess: the CLI's split of the CPU into one device per core, before JAX starts (and
    left alone once a count is set or JAX runs), then an SGM batch sharded over the two devices it
    made (the one check of SGM sharded over two devices; the sharding wraps every method's
    per-frame function alike). It equals the same batch on one device, computed here: the
    64 x 128 SGM batch of two that test_extras_cli and test_last_batch_is_padded_not_recompiled
    compile (in the subprocess the one-device batch would be a compile of its own: on a backend of
    two devices it has another compilation-cache key)."""
    env = dict(os.environ)  # the suite's compile flags (tests/conftest.py), but no device count
    env["XLA_FLAGS"] = " ".join(f for f in env.get("XLA_FLAGS", "").split() if "device_count" not in f)
    env["JAX_PLATFORMS"] = "cpu"
    out = tmp_path / "two_devices.npy"
    script = DEVICES.format(tests=str(pathlib.Path(__file__).parent), out=str(out))
    result = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "split 2 0 2 0 1" in result.stdout and "sharded-saved" in result.stdout, result.stdout
    items, T = small_frames(3)
    depths = np.stack([d for d, _ in items])
    Ks = np.stack([k for _, k in items])
    one = runner.complete_batch(depths, Ks, T, batch_size=2, devices=1, method="sgm")
    two = np.load(out)
    assert two.shape == one.shape == (3, 64, 128)
    np.testing.assert_allclose(two, one, rtol=1e-6, atol=1e-5)
