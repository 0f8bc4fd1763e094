"""The KITTI job's listed program (issue 38): a batch with a frame that does not fit the listed
normals is recomputed by the full program; the full program is not built when every frame fits.
Oracle: the public per-frame ``complete_stages`` (main's one program, with the dense fallback)."""

from __future__ import annotations

import numpy as np
import pytest

from jaxdepth import SGMConfig, complete_stages
from jaxdepth.batch import runner
from jaxdepth.io import read_depth_png, write_depth_png

from helpers import fitting, small_frames, write_kitti_folder

#: Every test here runs the batch runner (job runs: docs/testing.md), on the 64 x 128 frames of the group's
#: other job tests (the listed and full programs at batch 2, "map": one worker compiles them once).
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("jobs_small_sgm_batches")]


@pytest.fixture(scope="module")
def frames():
    """Two fitting frames (the synthetic street's, 71 % of the pixels with depth, kept on every 4th row
    and column: 4.4 %) and one overflowing (the first frame's whole image: more than H W / 16 pixels with
    depth, the dense fallback)."""
    items, T = small_frames(2)
    sparse = fitting(items)
    return [sparse[0], items[0], sparse[1]], T


def _jobs(tmp_path, frames):
    src = write_kitti_folder(tmp_path / "src", frames)
    (tmp_path / "out").mkdir()
    return [runner.FrameJob(name=p.name, sparse_path=p, out_path=tmp_path / "out" / p.name,
                            intrinsics_path=src / "intrinsics" / (p.stem + ".txt"))
            for p in sorted((src / "velodyne_raw").glob("*.png"))]


def _builds(monkeypatch) -> list:
    """The ``listed_only`` of every program the runner builds (:func:`runner.batched_completion` calls)."""
    seen, real = [], runner.batched_completion

    def spy(*args, **kwargs):
        seen.append(kwargs.get("listed_only", False))
        return real(*args, **kwargs)

    monkeypatch.setattr(runner, "batched_completion", spy)
    return seen


def _png(tmp_path, depth) -> bytes:
    """The PNG file the job writes for ``depth`` (the same writer, default compression)."""
    path = tmp_path / "expected.png"
    write_depth_png(path, depth)
    return path.read_bytes()


def _fits(depth, K, T) -> bool:
    """The ``fits`` of the "loop" job's own listed program (one whole-pipeline program fewer than a call of
    ``pipeline._complete_stages(listed_only=True)`` of its own)."""
    import jax
    fn = runner.batched_completion(1, *depth.shape, method="sgm", config=SGMConfig(), lidar=runner.presets.KITTI_HDL64,
                                   strategy="loop", devices=len(jax.local_devices()), listed_only=True)
    _, fits = fn(depth[None], K[None], np.asarray(T, np.float32)[None])
    return bool(np.asarray(fits)[0])


@pytest.mark.parametrize("strategy", ["loop", "map"])
def test_a_frame_beyond_the_listed_path_is_recomputed_with_the_bytes_of_complete(tmp_path, frames, strategy,
                                                                                   monkeypatch):
    items, T = frames
    assert [_fits(d, k, T) for d, k in items] == [True, False, True]  # the fixture's premise
    assert _fits(np.zeros_like(items[0][0]), items[0][1], T)  # a padding frame (empty) never forces a rerun
    jobs = _jobs(tmp_path, items)
    builds = _builds(monkeypatch)
    summary = runner.run_jobs(jobs, batch_size=1, T_cam_lidar=T, strategy=strategy)
    assert summary.ok and len(summary.done) == 3
    # three batches through the listed program; the full one built for the overflowing frame only
    assert builds == [True, True, True, False]
    for (depth, K), job in zip(items, jobs):
        expected = np.asarray(complete_stages(read_depth_png(job.sparse_path), K, T).depth)
        assert job.out_path.read_bytes() == _png(tmp_path, expected)


def test_after_a_frame_beyond_the_listed_path_the_size_runs_the_full_program(tmp_path, frames, monkeypatch):
    """A dataset denser than the capacity pays the recompute once, not per batch: the batch after the one
    dispatched beside the overflowing batch gets the full program directly (no listed build), same bytes."""
    items, T = frames
    jobs = _jobs(tmp_path, items + [items[2]])  # fit, overflow, fit, fit
    builds = _builds(monkeypatch)
    summary = runner.run_jobs(jobs, batch_size=1, T_cam_lidar=T, strategy="map")
    assert summary.ok and len(summary.done) == 4
    # batches 1-3 listed (batch 3 is dispatched before batch 2 is collected); then the full program, built
    # when batch 2 is recomputed, serves batch 4
    assert builds == [True, True, True, False, False]
    for (_, K), job in zip(items + [items[2]], jobs):
        expected = np.asarray(complete_stages(read_depth_png(job.sparse_path), K, T).depth)
        assert job.out_path.read_bytes() == _png(tmp_path, expected)


def test_the_full_program_is_not_built_when_every_frame_fits(tmp_path, frames, monkeypatch):
    items, T = frames
    fitting = [items[0], items[2]]
    jobs = _jobs(tmp_path, fitting)
    builds = _builds(monkeypatch)
    summary = runner.run_jobs(jobs, batch_size=2, T_cam_lidar=T, strategy="map")
    assert summary.ok and len(summary.done) == 2
    assert builds == [True]
    batch = np.stack([read_depth_png(job.sparse_path) for job in jobs])  # the job's inputs
    Ks = np.stack([k for _, k in fitting])
    expected = runner.complete_batch(batch, Ks, T, batch_size=2, strategy="map")  # main's program
    for depth, job in zip(expected, jobs):
        assert job.out_path.read_bytes() == _png(tmp_path, depth)


def test_vmap_job_with_an_overflowing_frame_writes_the_bytes_of_main_s_vmap_program(tmp_path, frames):
    items, T = frames
    jobs = _jobs(tmp_path, items)
    summary = runner.run_jobs(jobs, batch_size=1, T_cam_lidar=T, strategy="vmap", devices=1)
    assert summary.ok and len(summary.done) == 3
    inputs = np.stack([read_depth_png(job.sparse_path) for job in jobs])
    expected = runner.complete_batch(inputs, np.stack([k for _, k in items]), T, batch_size=1, strategy="vmap",
                                     devices=1)  # main's program (with the dense fallback), frame by frame
    for depth, job in zip(expected, jobs):
        assert job.out_path.read_bytes() == _png(tmp_path, depth)


def _public(method, config, max_seed_distance_px):
    """The public functions a full-program frame is made of (oracle of ``frame_function``'s trace)."""
    import jaxdepth
    from jaxdepth._src.validity import validity_and_distance
    lidar = runner.presets.KITTI_HDL64
    if max_seed_distance_px is not None:
        def extras(depth, K, T):
            stages = jaxdepth.complete_stages(depth, K, T, config=config, lidar=lidar)
            return (stages.depth,) + validity_and_distance(stages, K, T, lidar=lidar, metric=config.distance_metric,
                                                          max_seed_distance_px=max_seed_distance_px)
        return extras
    if config.guidance_weight > 0:
        return lambda depth, K, T, image: jaxdepth.complete(depth, K, T, config=config, lidar=lidar, image=image)
    return lambda depth, K, T: jaxdepth.complete_with(depth, K, T, method=method, config=config, lidar=lidar)


@pytest.mark.parametrize("method, config, limit", [
    ("sgm", SGMConfig(), None), ("sgm", SGMConfig(distance_metric="l2"), None),
    ("sgm", SGMConfig(guidance_weight=10.0), None), ("sgm", SGMConfig(), 6.0), ("nearest", SGMConfig(), None)])
def test_the_full_program_s_frame_traces_the_public_functions(method, config, limit):
    """The one frame function of both programs (jaxdepth.batch.frame_program), without ``listed_only``: the
    jaxpr of the public functions (the job's bytes before the listed program); with it, one more output."""
    import jax
    from jaxdepth.batch.frame_program import frame_function
    args = (np.zeros((32, 48), np.float32), np.eye(3, dtype=np.float32), np.eye(4, dtype=np.float32))
    args += (np.zeros((32, 48), np.uint8),) if config.guidance_weight > 0 else ()
    frame = frame_function(method=method, config=config, lidar=runner.presets.KITTI_HDL64,
                           max_seed_distance_px=limit, listed_only=False)
    assert str(jax.make_jaxpr(frame)(*args)) == str(jax.make_jaxpr(_public(method, config, limit))(*args))
    if method == "sgm":
        listed = frame_function(method=method, config=config, lidar=runner.presets.KITTI_HDL64,
                                max_seed_distance_px=limit, listed_only=True)
        shapes = [o.shape for o in jax.eval_shape(listed, *args)]
        assert shapes == [(32, 48)] * (1 if limit is None else 3) + [()]
