"""The PNG encoding benchmark's variants (``benchmarks.bench_png_encoding``): every row filter, level and
zlib strategy it times must write a PNG that an independent decoder (OpenCV) reads back to the same uint16
array, and its "up, level 1" variant must be the library's encoding byte for byte.
"""

import cv2
import numpy as np
import pytest

from benchmarks.bench_png_encoding import STRATEGIES, encode, filter_rows, variants
from jaxdepth.io import encode_depth_png, read_depth_png

FILTERS = ("up", "sub", "avg", "paeth", "none")


def _arrays(kitti_frame):
    rng = np.random.default_rng(7)
    noise = rng.integers(0, 65536, (9, 13)).astype(np.uint16)       # every byte value: the modulo and Paeth's ties
    noise[0, 0], noise[-1, -1] = 65535, 0
    gt = read_depth_png(kitti_frame / "groundtruth_image_02.png")
    smooth = np.rint(np.maximum.accumulate(gt, axis=1) * 256).astype(np.uint16)  # real structure, holes filled
    return {"noise": noise, "one_pixel": np.array([[40000]], np.uint16), "kitti": smooth}


@pytest.mark.parametrize("kind", FILTERS)
def test_every_variant_decodes_with_opencv_to_the_same_array(kind, kitti_frame):
    for name, array in _arrays(kitti_frame).items():
        for variant in variants([kind], [0, 1, 2], list(STRATEGIES), [8, 9]):
            data = encode(array, *variant)
            back = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
            assert back is not None and back.dtype == np.uint16, (name, variant)
            np.testing.assert_array_equal(back, array, err_msg=f"{name} {variant}")
            assert encode(array.copy(), *variant) == data              # the same array, the same bytes


def test_filter_type_bytes_and_the_library_encoding(kitti_frame, monkeypatch):
    from jaxdepth.io import depth_png
    monkeypatch.setattr(depth_png, "_isal_zlib", None)  # the library's zlib path (the extra fast-png off)
    array = _arrays(kitti_frame)["kitti"]
    h, w = array.shape
    for code, kind in enumerate(("none", "sub", "up", "avg", "paeth")):
        rows = filter_rows(array.astype(">u2").view(np.uint8).reshape(h, 2 * w), kind)
        assert rows.shape == (h, 2 * w + 1) and (rows[:, 0] == code).all()
    for level in range(10):
        assert encode(array, "up", level, "default") == encode_depth_png(array, compression=level)
