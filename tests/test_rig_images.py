"""Image-guided seeds on a rig (complete_rig(..., images=), stack_images).

Oracles: the single-camera path (complete_points_stages with image=) per camera
(vmap == loop); geodesic_seed on the camera's own window cropped out of the
canvas (the padding must not create paths); the unguided rig (weight 0 ignores
the images, bit for bit).
"""

from __future__ import annotations

import numpy as np
import pytest

from jaxdepth import (Camera, SGMConfig, complete_points_stages, complete_rig, complete_rig_stages, stack_cameras,
                      stack_images)
from jaxdepth._src.geodesic import geodesic_seed
from helpers import block_images
from scenes import SMALL_LIDAR, stereo_street

LIDAR = SMALL_LIDAR
#: The module's one guided configuration (one compiled guided rig program, one single-camera program), with
#: the noise floor on: its median is a window's own (test_smaller_camera_seeds_stay_in_its_window), and the
#: seed search without a floor is the same path with the floor's term at 0 (tests/test_geodesic.py
#: checks both settings against geodesic_seed).
GUIDED = SGMConfig(guidance_weight=5.0, guidance_sweeps=2, guidance_noise_floor=1.0)


@pytest.fixture(scope="module")
def stereo():
    return stereo_street()


def _images(cams, *, seed=0):
    """Piecewise-constant colour blocks plus noise: real edges for the geodesic cost."""
    return block_images([(cam.height, cam.width) for cam in cams], seed=seed, noise_dn=10)


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
@pytest.mark.xdist_group("rig_images_guided")  # one worker compiles the guided rig program once
def test_guided_rig_equals_loop_over_cameras(stereo):
    """(Grey images take the same path with one channel: tests/test_geodesic.py covers them.)"""
    frame, cams = stereo
    imgs = _images(cams)
    cameras = stack_cameras(cams)
    rig = complete_rig_stages(frame.points, frame.valid, cameras, lidar=LIDAR, config=GUIDED,
                              images=stack_images(imgs, cameras))
    unguided = complete_rig_stages(frame.points, frame.valid, cameras, lidar=LIDAR,
                                   images=stack_images(imgs, cameras))  # weight 0: images ignored
    for i, cam in enumerate(cams):
        single = complete_points_stages(frame.points, frame.valid, cam, lidar=LIDAR, config=GUIDED, image=imgs[i])
        np.testing.assert_array_equal(np.asarray(rig.inlier_mask[i]), np.asarray(single.inlier_mask))
        np.testing.assert_array_equal(np.asarray(rig.du[i]), np.asarray(single.du))
        np.testing.assert_array_equal(np.asarray(rig.dv[i]), np.asarray(single.dv))
        np.testing.assert_allclose(np.asarray(rig.depth[i]), np.asarray(single.depth), rtol=1e-5, atol=1e-4)
        # the image changed the seeds (the test would not see a guidance that is silently off)
        assert np.mean(np.asarray(rig.du[i]) != np.asarray(unguided.du[i])) > 0.01


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_weight_zero_ignores_images_bit_for_bit(stereo):
    frame, cams = stereo
    cameras = stack_cameras(cams)
    plain = complete_rig_stages(frame.points, frame.valid, cameras, lidar=LIDAR)
    with_images = complete_rig_stages(frame.points, frame.valid, cameras, lidar=LIDAR,
                                      images=stack_images(_images(cams), cameras))
    for field in ("du", "dv", "depth_raw", "depth"):
        np.testing.assert_array_equal(np.asarray(getattr(with_images, field)), np.asarray(getattr(plain, field)))
    # still checked when ignored
    with pytest.raises(ValueError, match=r"complete_rig: field 'images' expected dtype uint8 .* got uint16 "
                                         r"\(a 16-bit image"):
        complete_rig(frame.points, frame.valid, cameras, lidar=LIDAR,
                     images=stack_images(_images(cams), cameras).astype(np.uint16))


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
@pytest.mark.xdist_group("rig_images_guided")  # one worker compiles the guided rig program once
def test_smaller_camera_seeds_stay_in_its_window(stereo):
    """Camera 1 is 16 x 40 px smaller than the canvas. Its seeds equal geodesic_seed on its own window
    (cropped keep mask and image), whatever the padding holds: no path runs through the padding, and
    the noise floor's median is the window's own (the guided rig program of the test above)."""
    assert GUIDED.guidance_noise_floor > 0
    frame, cams = stereo
    big = cams[0]
    small = Camera(K=cams[1].K, T_cam_lidar=cams[1].T_cam_lidar, height=big.height - 16, width=big.width - 40)
    cameras = stack_cameras([big, small])
    imgs = _images([big, small], seed=3)
    canvas = stack_images(imgs, cameras)
    np.testing.assert_array_equal(stack_images(imgs, [big, small]), canvas)  # the cameras themselves: same canvas
    np.testing.assert_array_equal(canvas[1, :small.height, :small.width], imgs[1])
    assert canvas.shape == (2, big.height, big.width, 3) and not canvas[1, small.height:].any()
    h, w = small.height, small.width
    results = []
    for fill in (0, 255, "noise"):  # the padding's content must not matter
        padded = canvas.copy()
        pad = np.ones(padded.shape[1:3], bool)
        pad[:h, :w] = False
        padded[1][pad] = (np.random.default_rng(1).integers(0, 256, (pad.sum(), 3)) if fill == "noise" else fill)
        results.append(complete_rig_stages(frame.points, frame.valid, cameras, lidar=LIDAR, config=GUIDED,
                                           images=padded))
    out = results[0]
    keep = np.asarray(out.inlier_mask[1])[:h, :w]
    want = geodesic_seed(keep, imgs[1].astype(np.float32) / 255.0, color_weight=GUIDED.guidance_weight,
                         sweeps=GUIDED.guidance_sweeps, noise_floor=GUIDED.guidance_noise_floor)
    np.testing.assert_array_equal(np.asarray(out.du[1])[:h, :w], np.asarray(want.du))
    np.testing.assert_array_equal(np.asarray(out.dv[1])[:h, :w], np.asarray(want.dv))
    for other in results[1:]:
        for field in ("du", "dv", "depth"):
            np.testing.assert_array_equal(np.asarray(getattr(other, field)[1])[:h, :w],
                                          np.asarray(getattr(out, field)[1])[:h, :w], err_msg=field)
    depth = np.asarray(out.depth[1])
    assert not depth[h:].any() and not depth[:, w:].any() and np.all(depth[:h, :w] > 0)


def test_bad_images_name_the_field(stereo):
    frame, cams = stereo
    cameras = stack_cameras(cams)
    h, w = cameras.height, cameras.width
    run = lambda images, config=GUIDED: complete_rig(frame.points, frame.valid, cameras, lidar=LIDAR,  # noqa: E731
                                                     config=config, images=images)
    with pytest.raises(ValueError, match=rf"complete_rig: field 'images' expected \(2, {h}, {w}\) grey or "
                                         rf"\(2, {h}, {w}, 3\) colour .* because config.guidance_weight > 0, got None"):
        run(None)
    with pytest.raises(ValueError, match=rf"field 'images' expected shape \(2, {h}, {w}\) \(grey\) or "
                                         rf"\(2, {h}, {w}, 3\) \(colour\).*got \(1, {h}, {w}, 3\)"):
        run(np.zeros((1, h, w, 3), np.uint8))
    with pytest.raises(ValueError, match=r"got \(2, %d, %d, 4\)" % (h, w)):  # RGBA
        run(np.zeros((2, h, w, 4), np.uint8))
    with pytest.raises(ValueError, match=r"expected dtype uint8 \(0-255\) or float in \[0, 1\], got int32"):
        run(np.zeros((2, h, w), np.int32))
    imgs = _images(cams)
    with pytest.raises(ValueError, match=r"stack_images: field 'images' expected one image per camera \(2\), got 1"):
        stack_images(imgs[:1], cameras)
    with pytest.raises(ValueError, match=rf"stack_images: field 'images\[1\]' expected shape \({h}, {w}\) \(grey\) "
                                         rf"or \({h}, {w}, 3\) \(colour\), camera 1's image size, got \(10, 20, 3\)"):
        stack_images([imgs[0], np.zeros((10, 20, 3), np.uint8)], cameras)
    with pytest.raises(ValueError, match=r"stack_images: field 'images\[1\]' expected .* colour like images\[0\] "
                                         r"\(all grey or all colour\)"):
        stack_images([imgs[0], imgs[1][..., 0]], cameras)
    with pytest.raises(ValueError, match=r"stack_images: field 'images\[1\]' expected dtype uint8 like images\[0\], "
                                         r"got float32"):
        stack_images([imgs[0], imgs[1].astype(np.float32)], cameras)


# ---------------------------------------------------------------- jaxdepth complete-rig with images


def _write_rig(folder, cams, frame, *, image_field=False):
    """Points (.npy, x y z intensity), a rig JSON stating the LiDAR (no estimate) and one PNG per camera."""
    import json

    import cv2
    points = np.asarray(frame.points)[np.asarray(frame.valid)]
    np.save(folder / "sweep.npy", np.c_[points, np.zeros(len(points))].astype(np.float32))
    names = [f"cam{i}" for i in range(len(cams))]
    (folder / "images").mkdir()
    imgs = _images(cams)
    for name, img in zip(names, imgs):
        cv2.imwrite(str(folder / "images" / f"{name}.png"), img[:, :, ::-1])  # RGB -> OpenCV's BGR
    doc = {"lidar": {"beams": LIDAR.beams, "fov_up_deg": LIDAR.fov_up_deg, "fov_down_deg": LIDAR.fov_down_deg,
                     "columns": LIDAR.columns, "origin_m": [0, 0, 0]},
           "cameras": [dict({"name": name, "width": cam.width, "height": cam.height,
                             "K": np.asarray(cam.K, float).tolist(), "T_cam_lidar": np.asarray(cam.T_cam_lidar,
                                                                                              float).tolist()},
                            **({"image": f"images/{name}.png"} if image_field else {}))
                       for name, cam in zip(names, cams)]}
    (folder / "rig.json").write_text(json.dumps(doc))
    return names, imgs


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_cli_complete_rig_with_images_writes_the_api_result(stereo, tmp_path, capsys):
    """--image-dir and the rig JSON's image fields give the same PNGs as complete_rig(..., images=) on the
    library's path (read_rig_json -> prepare_sweep -> pad_points); without images the guided run is an
    error naming the camera; --image-dir without a weight is a usage error."""
    import cv2

    from jaxdepth import cli
    from jaxdepth.io import encode_depth_uint16, pad_points, prepare_sweep, read_points, read_rig_json
    frame, cams = stereo
    names, imgs = _write_rig(tmp_path, cams, frame, image_field=True)
    rig = read_rig_json(tmp_path / "rig.json")
    points, _ = read_points(tmp_path / "sweep.npy")
    prepared = prepare_sweep(points, rig)
    padded, valid = pad_points(prepared.points)
    cameras = stack_cameras([c.as_camera() for c in prepared.rig.cameras])
    want = np.asarray(complete_rig(padded, valid, cameras, lidar=prepared.rig.lidar, config=GUIDED,
                                   images=stack_images(imgs, cameras)))
    base = ["complete-rig", str(tmp_path / "sweep.npy"), str(tmp_path / "rig.json")]
    guided = ["--guidance-weight", str(GUIDED.guidance_weight), "--guidance-sweeps", str(GUIDED.guidance_sweeps),
              "--guidance-noise-floor", str(GUIDED.guidance_noise_floor), "-q"]
    assert cli.main(base + [str(tmp_path / "a"), "--image-dir", str(tmp_path / "images")] + guided) == 0
    assert cli.main(base + [str(tmp_path / "b")] + guided) == 0  # the JSON's image fields
    for i, name in enumerate(names):
        expected = encode_depth_uint16(want[i])
        for out in ("a", "b"):
            got = cv2.imread(str(tmp_path / out / f"{name}.png"), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(got, expected, err_msg=f"{out}/{name}")
    assert cli.main(base + [str(tmp_path / "c"), "--image-dir", str(tmp_path / "images"), "-q"]) == 2
    assert "--image-dir gives the camera images of image-guided seeds" in capsys.readouterr().err
    (tmp_path / "images" / "cam1.png").unlink()
    assert cli.main(base + [str(tmp_path / "d"), "--image-dir", str(tmp_path / "images")] + guided) == 1
    assert "no image for camera cam1: expected one of cam1.png, cam1.jpg, cam1.jpeg" in capsys.readouterr().err
    assert cli.main(base + [str(tmp_path / "d")] + guided) == 1
    assert f"{tmp_path / 'images' / 'cam1.png'}: file not found" in capsys.readouterr().err


def test_bad_image_files_name_the_file_and_what_was_expected(stereo, tmp_path):
    import cv2

    from jaxdepth.io import InputError, read_rig_json
    from jaxdepth.io.rig_images import read_camera_image, read_rig_images, rig_image_paths
    frame, cams = stereo
    names, imgs = _write_rig(tmp_path, cams, frame)
    rig = read_rig_json(tmp_path / "rig.json")
    folder = tmp_path / "images"
    h, w = cams[0].height, cams[0].width
    # decoded RGB equals what was written (PNG is lossless)
    np.testing.assert_array_equal(read_camera_image(folder / "cam0.png", width=w, height=h), imgs[0])
    bad = {"grey.png": imgs[1][:, :, 0], "wide.png": np.zeros((h, w + 2, 3), np.uint8),
           "deep.png": np.zeros((h, w, 3), np.uint16), "rgba.png": np.zeros((h, w, 4), np.uint8)}
    for name, img in bad.items():
        cv2.imwrite(str(tmp_path / name), img)
    (tmp_path / "junk.jpg").write_bytes(b"\xff\xd8 not a jpeg")
    cases = {"wide.png": rf"wide.png: camera image expected {w}x{h} \(width x height of camera cam1\), "
                         rf"got {w + 2}x{h}",
             "deep.png": r"deep.png: camera image expected 8-bit \(uint8\) values, got 16-bit \(uint16\)",
             "rgba.png": r"rgba.png: camera image expected 1 \(grey\) or 3 \(colour\) channels, got 4 \(an alpha",
             "grey.png": r"grey.png: camera image expected colour \(3 channels\) for camera cam1 \(like .*cam0.png\), "
                         r"got grey \(1 channel\)",
             "junk.jpg": r"junk.jpg: cannot decode as an image"}
    for name, match in cases.items():
        with pytest.raises(InputError, match=match):
            read_rig_images([folder / "cam0.png", tmp_path / name], rig.cameras)
    with pytest.raises(InputError, match=r"image folder not found"):
        rig_image_paths(rig.cameras, image_dir=tmp_path / "nowhere")
    with pytest.raises(InputError, match=r"rig.json: camera cam0 has no image: give --image-dir DIR"):
        rig_image_paths(rig.cameras, rig_json=tmp_path / "rig.json")


def test_rig_json_image_field_round_trips_and_is_checked(tmp_path):
    import json

    from jaxdepth.io import InputError, read_rig_json, write_rig_json
    cam = {"name": "A", "width": 10, "height": 8, "K": [[5, 0, 5], [0, 5, 4], [0, 0, 1]],
           "T_cam_lidar": np.eye(4).tolist()}
    doc = {"lidar": {"beams": 32}, "cameras": [dict(cam, image="imgs/A.jpg"), dict(cam, name="B")]}
    (tmp_path / "rig.json").write_text(json.dumps(doc))
    rig = read_rig_json(tmp_path / "rig.json")
    assert [c.image for c in rig.cameras] == ["imgs/A.jpg", None]
    write_rig_json(tmp_path / "again.json", rig)
    assert read_rig_json(tmp_path / "again.json") == rig
    doc["cameras"][0]["image"] = ""
    (tmp_path / "rig.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"rig.json: field 'cameras\[0\].image' expected a non-empty string"):
        read_rig_json(tmp_path / "rig.json")
