"""KITTI benchmark crop and depth-completion folder listing."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxdepth._src.geometry import project_to_image
from jaxdepth._src.presets import KITTI_K_CAM2, KITTI_T_CAM2_LIDAR
from jaxdepth.io import (InputError, benchmark_crop_offsets, crop_to_benchmark, list_depth_completion_folder,
                         pad_points, read_depth_png, read_points)


def test_crop_offsets_kitti():
    assert benchmark_crop_offsets(375, 1242) == (23, 13)  # data README: rows 23..374, columns 13..1228
    assert benchmark_crop_offsets(370, 1224) == (18, 4)
    assert benchmark_crop_offsets(352, 1216) == (0, 0)
    with pytest.raises(ValueError, match=r"'image' expected at least 352x1216 \(height x width\), got 351x1242"):
        benchmark_crop_offsets(351, 1242)


def test_crop_real_image(kitti_frame):
    depth = read_depth_png(kitti_frame / "velodyne_raw_image_02.png")
    before = depth.copy()
    cropped, K = crop_to_benchmark(depth, KITTI_K_CAM2)
    np.testing.assert_array_equal(depth, before)
    assert cropped.shape == (352, 1216)
    np.testing.assert_array_equal(cropped, depth[23:375, 13:1229])
    np.testing.assert_allclose(K, [[721.5377, 0, 596.5593], [0, 721.5377, 149.854], [0, 0, 1]], atol=1e-4)
    cropped[0, 0] = -1
    assert depth[23, 13] != -1  # a copy, not a view
    colour = np.zeros((375, 1242, 3), np.uint8)
    assert crop_to_benchmark(colour, KITTI_K_CAM2)[0].shape == (352, 1216, 3)


@settings(deadline=None, max_examples=25)
@given(h=st.integers(1, 30), w=st.integers(1, 30), ch=st.integers(1, 10), cw=st.integers(1, 10),
       fx=st.floats(10, 1000), cx=st.floats(-50, 50), cy=st.floats(-50, 50))
def test_crop_projection_property(h, w, ch, cw, fx, cx, cy):
    """Oracle: a pixel (u, v) of the full image holds the point that projects with the shifted K to (u-left, v-top)."""
    K = np.array([[fx, 0.0, cx], [0.0, fx, cy], [0, 0, 1]], np.float32)
    image = np.arange(h * w, dtype=np.float32).reshape(h, w)
    if h < ch or w < cw:
        with pytest.raises(ValueError, match="expected at least"):
            crop_to_benchmark(image, K, size=(ch, cw))
        return
    cropped, K2 = crop_to_benchmark(image, K, size=(ch, cw))
    top, left = h - ch, (w - cw) // 2
    assert cropped.shape == (ch, cw) and cropped[0, 0] == image[top, left]
    p = np.array([0.3, -0.2, 2.0])
    uv = K.astype(np.float64) @ p
    uv2 = K2.astype(np.float64) @ p
    np.testing.assert_allclose(uv2[:2] / uv2[2], uv[:2] / uv[2] - [left, top], rtol=1e-5, atol=1e-3)


def test_crop_equals_projection_into_crop(kitti_frame):
    points, _ = read_points(kitti_frame / "lidar_data.bin")
    padded, valid = pad_points(points)
    full, _ = project_to_image(padded, valid, KITTI_K_CAM2, KITTI_T_CAM2_LIDAR, height=375, width=1242)
    want, K = crop_to_benchmark(np.asarray(full), KITTI_K_CAM2)
    got, _ = project_to_image(padded, valid, K, KITTI_T_CAM2_LIDAR, height=352, width=1216)
    assert np.count_nonzero(np.asarray(got) != want) <= 10  # float32 rounding ties only


def test_crop_validation():
    with pytest.raises(ValueError, match=r"'image' expected shape \(H, W\) or \(H, W, C\), got \(400,\)"):
        crop_to_benchmark(np.zeros(400), KITTI_K_CAM2)
    with pytest.raises(ValueError, match=r"'K' expected a finite \(3, 3\) matrix, got shape \(3, 4\)"):
        crop_to_benchmark(np.zeros((400, 1300)), np.zeros((3, 4)))


def _touch(path, text="721.5377 0 596.5593 0 721.5377 149.854 0 0 1"):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_list_val_selection_cropped_naming(tmp_path):
    d = "2011_09_26_drive_0002_sync"
    v1 = _touch(tmp_path / "velodyne_raw" / f"{d}_velodyne_raw_0000000005_image_02.png")
    v2 = _touch(tmp_path / "velodyne_raw" / f"{d}_velodyne_raw_0000000005_image_03.png")
    t1 = _touch(tmp_path / "intrinsics" / f"{d}_image_0000000005_image_02.txt")
    t2 = _touch(tmp_path / "intrinsics" / f"{d}_image_0000000005_image_03.txt")
    _touch(tmp_path / "image" / f"{d}_image_0000000005_image_02.png")
    _touch(tmp_path / "velodyne_raw" / "notes.md")
    assert list_depth_completion_folder(tmp_path) == [(v1.stem, v1, t1), (v2.stem, v2, t2)]


def test_list_test_set_naming_and_no_image_folder(tmp_path):
    v = [_touch(tmp_path / "velodyne_raw" / f"{i:010d}.png") for i in (1, 0)]
    t = [_touch(tmp_path / "intrinsics" / f"{i:010d}.txt") for i in (1, 0)]
    assert list_depth_completion_folder(str(tmp_path)) == [("0000000000", v[1], t[1]), ("0000000001", v[0], t[0])]


def test_list_without_intrinsics_and_flat(tmp_path):
    v = _touch(tmp_path / "a" / "velodyne_raw" / "x.png")
    assert list_depth_completion_folder(tmp_path / "a") == [("x", v, None)]
    flat = tmp_path / "flat"
    p1, p2 = _touch(flat / "b.png"), _touch(flat / "a.PNG")
    k2 = _touch(flat / "b.txt")
    assert list_depth_completion_folder(flat) == [("a", p2, None), ("b", p1, k2)]


def test_list_errors(tmp_path):
    with pytest.raises(InputError, match=r"nowhere: input folder not found"):
        list_depth_completion_folder(tmp_path / "nowhere")
    file = _touch(tmp_path / "file.png")
    with pytest.raises(InputError, match=r"file\.png: input folder expected a folder, got a file"):
        list_depth_completion_folder(file)
    (tmp_path / "empty" / "velodyne_raw").mkdir(parents=True)
    with pytest.raises(InputError, match=r"velodyne_raw: no \.png files found"):
        list_depth_completion_folder(tmp_path / "empty")
    _touch(tmp_path / "s" / "velodyne_raw" / "f_velodyne_raw_1.png")
    (tmp_path / "s" / "intrinsics").mkdir()
    with pytest.raises(InputError, match=r"intrinsics: missing intrinsics for frame 'f_velodyne_raw_1\.png' "
                                         r"\(expected f_velodyne_raw_1\.txt or f_image_1\.txt\)"):
        list_depth_completion_folder(tmp_path / "s")


def test_listing_feeds_the_readers(kitti_frame, tmp_path):
    """A real file placed in the layout reads back through the listing."""
    (tmp_path / "velodyne_raw").mkdir()
    (tmp_path / "velodyne_raw" / "f.png").write_bytes((kitti_frame / "velodyne_raw_image_02.png").read_bytes())
    [(name, png, txt)] = list_depth_completion_folder(tmp_path)
    assert name == "f" and txt is None and int((read_depth_png(png) > 0).sum()) == 19154
