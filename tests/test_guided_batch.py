"""Image-guided seeds in the batch runner, its Ray actor and `jaxdepth complete` (issue 16, KITTI side).

Oracles: each frame's output is the library API (`jaxdepth.complete(..., image=)`) on the same
inputs with the image decoded independently here (OpenCV, BGR -> RGB); crops against
`crop_to_benchmark`; unguided runs against a run of the same jobs without any image.
"""

from __future__ import annotations

import pathlib

import cv2
import numpy as np
import pytest

import jaxdepth
from jaxdepth.batch import runner
from jaxdepth.io import crop_to_benchmark, encode_depth_uint16, read_depth_png
from jaxdepth.io import guidance_images

from helpers import H, W, block_images, small_frames, write_kitti_folder

GUIDED = jaxdepth.SGMConfig(guidance_weight=2.0)


@pytest.fixture(scope="module")
def frames():
    return small_frames(3)


def _images(count: int, *, seed: int = 1) -> list[np.ndarray]:
    """Colour images with real edges (:func:`helpers.block_images`), written as OpenCV's BGR."""
    return block_images([(H, W)] * count, seed=seed)


def _selection(root: pathlib.Path, frames, *, grey=()) -> tuple[pathlib.Path, list]:
    """A selection folder (velodyne_raw/, intrinsics/, image/) and its jobs with image paths."""
    src = write_kitti_folder(root, frames)
    (src / "image").mkdir()
    jobs = []
    for i, (png, image) in enumerate(zip(sorted((src / "velodyne_raw").glob("*.png")), _images(len(frames)))):
        cv2.imwrite(str(src / "image" / png.name), cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if i in grey else image)
        jobs.append(runner.FrameJob(name=png.name, sparse_path=png, out_path=root.parent / "out" / png.name,
                                    intrinsics_path=src / "intrinsics" / (png.stem + ".txt"),
                                    image_path=src / "image" / png.name))
    (root.parent / "out").mkdir(exist_ok=True)
    return src, jobs


def _api_png(job, K, T, config) -> np.ndarray:
    """The API's answer as the uint16 PNG values; the image read here with OpenCV (BGR -> RGB)."""
    image = cv2.imread(str(job.image_path), cv2.IMREAD_UNCHANGED)
    if image.ndim == 3:
        image = image[:, :, ::-1]
    return encode_depth_uint16(np.asarray(jaxdepth.complete(read_depth_png(job.sparse_path), K, T,
                                                            config=config, image=image)))


def _png(path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
@pytest.mark.xdist_group("jobs_guided_batches")  # one worker compiles the guided batch and its oracle once
def test_guided_runner_equals_the_api_per_frame(tmp_path, frames):
    items, T = frames
    _, jobs = _selection(tmp_path / "src", items)
    summary = runner.run_jobs(jobs, batch_size=2, T_cam_lidar=T, config=GUIDED)  # 3 frames: last batch padded
    assert summary.ok and sorted(summary.done) == sorted(j.name for j in jobs)
    for (depth, K), job in zip(items, jobs):
        np.testing.assert_array_equal(_png(job.out_path), _api_png(job, K, T, GUIDED))


def test_grey_and_colour_frames_batch_apart_and_unguided_keys_are_unchanged(tmp_path, frames):
    items, T = frames
    _, jobs = _selection(tmp_path / "src", items, grey=(1,))
    keys = []
    for job in jobs:
        loaded, message = runner.try_load(job, runner.loader(GUIDED))
        assert message is None
        keys.append(runner.batch_item(job, loaded, T)[0])
        plain, _ = runner.try_load(job)  # unguided: (depth, K), no image
        assert len(plain) == 2 and runner.batch_item(job, plain, T)[0] == (H, W)
    assert keys == [(H, W, "image", 3), (H, W, "image", 1), (H, W, "image", 3)]
    grey = runner.try_load(jobs[1], runner.loader(GUIDED))[0][2]
    np.testing.assert_array_equal(grey, cv2.imread(str(jobs[1].image_path), cv2.IMREAD_GRAYSCALE))


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_unguided_run_never_opens_images_and_writes_the_same_bytes(tmp_path, frames, monkeypatch):
    items, T = frames
    _, jobs = _selection(tmp_path / "src", items)
    for job in jobs:
        job.image_path.write_bytes(b"not an image")  # unguided: never read
    plain = [runner.FrameJob(name=j.name, sparse_path=j.sparse_path, out_path=tmp_path / "plain" / j.name,
                             intrinsics_path=j.intrinsics_path) for j in jobs]
    (tmp_path / "plain").mkdir()
    calls = []
    real = runner._group_call

    def spy(key, items, **kwargs):
        fn, args, n = real(key, items, **kwargs)
        calls.append((key, len(args)))
        return fn, args, n

    monkeypatch.setattr(runner, "_group_call", spy)
    with_images = runner.run_jobs(jobs, batch_size=2, T_cam_lidar=T)
    without = runner.run_jobs(plain, batch_size=2, T_cam_lidar=T)
    assert with_images.ok and without.ok
    assert calls == [((H, W), 3)] * 4  # depth, K, T: no image argument
    for a, b in zip(jobs, plain):
        assert a.out_path.read_bytes() == b.out_path.read_bytes()


def _bad_images(folder: pathlib.Path, good: np.ndarray) -> dict[str, str]:
    """Writes one bad image per case; returns file name -> expected words of its message."""
    cases = {}
    cases["missing.png"] = "not found"
    cv2.imwrite(str(folder / "small.png"), good[: H // 2])
    cases["small.png"] = f"expected {W}x{H}"
    cv2.imwrite(str(folder / "deep.png"), good.astype(np.uint16) * 257)
    cases["deep.png"] = "8-bit"
    cv2.imwrite(str(folder / "alpha.png"), cv2.cvtColor(good, cv2.COLOR_BGR2BGRA))
    cases["alpha.png"] = "got 4"
    (folder / "junk.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    cases["junk.png"] = "cannot decode"
    return cases


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
@pytest.mark.xdist_group("jobs_guided_batches")  # one worker compiles the guided batch and its oracle once
def test_each_bad_image_fails_its_frame_only_and_a_rerun_resumes(tmp_path, frames):
    items, T = frames
    many = [items[i % len(items)] for i in range(6)]
    src, jobs = _selection(tmp_path / "src", many)
    cases = _bad_images(src / "image", _images(1)[0])
    bad_jobs = {}
    for job, name in zip(jobs[1:], cases):
        bad_jobs[job.name] = name
    jobs = [jobs[0]] + [runner.FrameJob(**{**job.__dict__, "image_path": src / "image" / bad_jobs[job.name]})
                        for job in jobs[1:]]
    summary = runner.run_jobs(jobs, batch_size=2, T_cam_lidar=T, config=GUIDED)
    assert summary.done == [jobs[0].name]
    failed = dict(summary.failed)
    assert sorted(failed) == sorted(bad_jobs)
    for frame, image_name in bad_jobs.items():
        assert str(src / "image" / image_name) in failed[frame], failed[frame]
        assert cases[image_name] in failed[frame], failed[frame]
    np.testing.assert_array_equal(_png(jobs[0].out_path), _api_png(jobs[0], many[0][1], T, GUIDED))
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [jobs[0].name]
    # fix one image: the re-run skips the finished frame and completes the fixed one
    fixed = next(j for j in jobs if bad_jobs.get(j.name) == "small.png")
    cv2.imwrite(str(fixed.image_path), _images(2)[1])
    again = runner.run_jobs(jobs, batch_size=2, T_cam_lidar=T, config=GUIDED)
    assert again.skipped == [jobs[0].name] and again.done == [fixed.name] and len(again.failed) == 4


def test_a_guided_frame_without_an_image_fails_with_a_clear_message(tmp_path, frames):
    items, T = frames
    _, jobs = _selection(tmp_path / "src", items[:1])
    job = runner.FrameJob(**{**jobs[0].__dict__, "image_path": None})
    summary = runner.run_jobs([job], config=GUIDED, T_cam_lidar=T)
    (name, message), = summary.failed
    assert name == job.name and "no camera image" in message and "--image-dir" in message


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
@pytest.mark.xdist_group("jobs_guided_batches")  # one worker compiles the guided batch and its oracle once
def test_complete_batch_with_images_and_its_errors(frames):
    items, T = frames
    depths = np.stack([d for d, _ in items])
    Ks = np.stack([k for _, k in items])
    images = np.stack([im[:, :, ::-1] for im in _images(len(items))])
    got = runner.complete_batch(depths, Ks, T, config=GUIDED, images=images, batch_size=2, devices=1)
    for i, (depth, K) in enumerate(items):
        expected = np.asarray(jaxdepth.complete(depth, K, T, config=GUIDED, image=images[i]))
        np.testing.assert_array_equal(encode_depth_uint16(got[i]), encode_depth_uint16(expected))
    with pytest.raises(ValueError, match="images.*guidance_weight > 0, got None"):
        runner.complete_batch(depths, Ks, T, config=GUIDED)
    with pytest.raises(ValueError, match="images.*expected None"):
        runner.complete_batch(depths, Ks, T, images=images)
    with pytest.raises(ValueError, match="need method 'sgm'"):
        runner.run_jobs([], method="nearest", config=GUIDED)


def test_benchmark_crop_of_the_image_matches_crop_to_benchmark(tmp_path):
    rng = np.random.default_rng(3)
    full = rng.integers(0, 256, (375, 1242, 3), np.uint8)
    path = tmp_path / "full.png"
    cv2.imwrite(str(path), full)
    got = guidance_images.read_guidance_image(path, size=(352, 1216), crop_from=(375, 1242))
    expected, _ = crop_to_benchmark(full, np.eye(3))
    np.testing.assert_array_equal(got, expected[:, :, ::-1])
    assert got.flags.c_contiguous and got.dtype == np.uint8
    with pytest.raises(jaxdepth.io.InputError, match=r"full.png: camera image expected 1240x375 .*got 1242x375"):
        guidance_images.read_guidance_image(path, size=(352, 1216), crop_from=(375, 1240))


def test_image_names_of_selection_folders_and_plain_folders(tmp_path):
    sel = tmp_path / "sel"
    (sel / "velodyne_raw").mkdir(parents=True)
    (sel / "image").mkdir()
    assert guidance_images.selection_image_folder(sel) == sel / "image"
    assert guidance_images.selection_image_folder(sel / "velodyne_raw" / "x.png") == sel / "image"
    kitti = "2011_09_26_drive_0001_sync_velodyne_raw_0000000005_image_02"
    (sel / "image" / "2011_09_26_drive_0001_sync_image_0000000005_image_02.png").write_bytes(b"")
    (sel / "image" / "plain.png").write_bytes(b"")
    assert guidance_images.find_image(sel / "image", kitti).name == \
        "2011_09_26_drive_0001_sync_image_0000000005_image_02.png"
    assert guidance_images.find_image(sel / "image", "plain") == sel / "image" / "plain.png"
    (sel / "image" / f"{kitti}.png").write_bytes(b"")  # both names present: KITTI's naming first
    assert "_image_0000000005_" in guidance_images.find_image(sel / "image", kitti).name
    with pytest.raises(jaxdepth.io.InputError, match="--image-dir"):
        guidance_images.selection_image_folder(tmp_path / "flat")
    assert guidance_images.selection_image_folder(tmp_path / "flat", sel / "image") == sel / "image"


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
@pytest.mark.xdist_group("jobs_guided_batches")  # one worker compiles the guided batch and its oracle once
def test_ray_actor_reads_the_same_images_as_the_local_runner(tmp_path, frames):
    """The Ray engine's actor (called directly, no cluster): records carry the image, same bytes."""
    from jaxdepth.batch import scale
    items, T = frames
    _, jobs = _selection(tmp_path / "src", items)
    cropped = runner.FrameJob(**{**jobs[0].__dict__, "image_crop_from": (375, 1242)})
    assert scale._jobs_from_batch({k: [v] for k, v in scale._record(cropped).items()})[0].image_crop_from == \
        (375, 1242)
    records = [scale._record(job) for job in jobs]
    batch = {key: np.array([r[key] for r in records], dtype=object) for key in records[0]}
    assert [j.image_path for j in scale._jobs_from_batch(batch)] == [j.image_path for j in jobs]
    actor = scale._CompleteFrames(method="sgm", config=GUIDED, lidar=jaxdepth.KITTI_HDL64, T_cam_lidar=T,
                                  batch_size=2)
    rows = actor(batch)
    assert list(rows["status"]) == ["done"] * 3, rows["message"]
    (tmp_path / "local").mkdir()
    local = runner.run_jobs([runner.FrameJob(**{**j.__dict__, "out_path": tmp_path / "local" / j.name})
                             for j in jobs], batch_size=2, config=GUIDED, T_cam_lidar=T)
    assert local.ok
    for job in jobs:
        assert _png(job.out_path).tobytes() == _png(tmp_path / "local" / job.name).tobytes()


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
@pytest.mark.xdist_group("jobs_guided_batches")  # one worker compiles the guided batch and its oracle once
def test_cli_end_to_end_on_a_selection_folder_and_its_usage_errors(tmp_path, frames, capsys):
    from jaxdepth import cli
    items, T = frames
    src, jobs = _selection(tmp_path / "src", items)
    extrinsic = tmp_path / "T.txt"
    extrinsic.write_text(" ".join(f"{x:.9g}" for x in T.reshape(-1)))
    base = ["complete", str(src), str(tmp_path / "cli"), "--extrinsic", str(extrinsic), "--batch-size", "2", "-q"]
    assert cli.main(base + ["--guidance-weight", "2"]) == 0
    T32 = np.loadtxt(extrinsic).reshape(4, 4).astype(np.float32)
    for (depth, K), job in zip(items, jobs):
        np.testing.assert_array_equal(_png(tmp_path / "cli" / job.name), _api_png(job, K, T32, GUIDED))
    # --image-dir elsewhere: the same names are looked up there
    moved = tmp_path / "elsewhere"
    (src / "image").rename(moved)
    assert cli.main(base + ["--guidance-weight", "2", "--overwrite", "--image-dir", str(moved)]) == 0
    capsys.readouterr()
    code = cli.main(base + ["--guidance-weight", "2", "--overwrite"])  # no image/ folder any more
    err = capsys.readouterr().err
    assert code == 1 and "no camera images found" in err and "--image-dir" in err
    assert cli.main(base + ["--image-dir", str(moved)]) == 2
    assert "use it with --guidance-weight" in capsys.readouterr().err
    assert cli.main(base + ["--guidance-weight", "2", "--method", "nearest"]) == 2
    assert "needs --method sgm" in capsys.readouterr().err
