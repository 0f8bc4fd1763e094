"""Colour helpers: shapes, dtype, empty pixels black, the value -> colour mapping."""

from __future__ import annotations

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth._src import colorize as cz


def lut_index(rgb: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Index of the LUT row equal to each colour (the LUT rows of turbo are distinct)."""
    flat = rgb.reshape(-1, 1, 3).astype(np.int32)
    hits = np.all(flat == lut[None].astype(np.int32), axis=-1)
    assert hits.any(axis=1).all(), "a colour is not in the colour map"
    return hits.argmax(axis=1).reshape(rgb.shape[:-1])


def test_lut_is_opencv_colormap_in_rgb():
    lut = cz.colormap_lut("turbo")
    assert lut.shape == (256, 3) and lut.dtype == np.uint8
    bgr = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_TURBO)[:, 0]
    np.testing.assert_array_equal(lut, bgr[:, ::-1])
    assert len({tuple(r) for r in lut}) == 256  # distinct rows: lut_index is well defined
    np.testing.assert_array_equal(cz.colormap_lut("gray")[:, 0], np.arange(256))


def test_colorize_depth_shape_dtype_and_black_empties():
    rng = np.random.default_rng(0)
    d = rng.uniform(1.0, 80.0, (17, 23)).astype(np.float32)
    d[rng.random(d.shape) < 0.4] = 0.0
    d[0, 0], d[0, 1], d[0, 2] = np.nan, -3.0, np.inf
    for arr in (d, jnp.asarray(d)):
        out = cz.colorize_depth(arr)
        assert out.shape == (17, 23, 3) and out.dtype == np.uint8
        empty = ~(np.isfinite(d) & (d > 0))
        assert (out[empty] == 0).all()
        # turbo's darkest entry is not black, so every valid pixel is visibly coloured
        assert (out[~empty].sum(axis=-1) > 0).all()
    assert (cz.colorize_depth(np.zeros((4, 5), np.float32)) == 0).all()


def test_colorize_depth_mapping_is_monotone_and_matches_formula():
    depth = np.linspace(2.0, 50.0, 300, dtype=np.float32)[None, :]
    want = np.rint((depth[0].astype(np.float64) - 2.0) / 48.0 * 255.0).astype(int)
    lut = cz.colormap_lut("turbo")  # distinct rows: colours can be mapped back to indices
    idx = lut_index(cz.colorize_depth(depth), lut)[0]
    assert idx[0] == 0 and idx[-1] == 255
    assert (np.diff(idx) >= 0).all()  # nearer -> lower end, farther -> higher end
    np.testing.assert_array_equal(idx, want)
    inv = lut_index(cz.colorize_depth(depth, invert=True), lut)[0]
    np.testing.assert_array_equal(inv, 255 - want)
    for cmap in ("viridis", "jet"):  # their LUTs repeat rows: compare colours
        np.testing.assert_array_equal(cz.colorize_depth(depth, cmap=cmap)[0], cz.colormap_lut(cmap)[want])
    gray = cz.colorize_depth(depth, cmap="gray")
    assert (np.diff(gray[0, :, 0].astype(int)) >= 0).all()


def test_colorize_depth_clips_to_vmin_vmax():
    d = np.array([[1.0, 5.0, 10.0, 20.0, 0.0]], np.float32)
    lut = cz.colormap_lut("turbo")
    out = cz.colorize_depth(d, vmin=5.0, vmax=10.0)
    np.testing.assert_array_equal(lut_index(out[:, :4], lut)[0], [0, 0, 255, 255])
    assert (out[0, 4] == 0).all()


def test_colorize_depth_validates():
    with pytest.raises(ValueError, match=r"depth: expected shape \(H, W\), got \(2, 2, 2\)"):
        cz.colorize_depth(np.ones((2, 2, 2)))
    with pytest.raises(ValueError, match="cmap: expected one of"):
        cz.colorize_depth(np.ones((2, 2)), cmap="nope")
    with pytest.raises(ValueError, match=r"vmax: expected >= vmin \(5.0\), got 1.0"):
        cz.colorize_depth(np.ones((2, 2)), vmin=5.0, vmax=1.0)


def test_colorize_normals():
    rng = np.random.default_rng(1)
    n = rng.normal(size=(3, 9, 11)).astype(np.float32)
    n /= np.linalg.norm(n, axis=0, keepdims=True)
    n[:, 0, 0] = 0.0
    n[:, 1, 1] = np.nan
    for arr in (n, jnp.asarray(n)):
        out = cz.colorize_normals(arr)
        assert out.shape == (9, 11, 3) and out.dtype == np.uint8
        assert (out[0, 0] == 0).all() and (out[1, 1] == 0).all()
        want = np.rint((np.moveaxis(n, 0, -1) + 1.0) / 2.0 * 255.0)
        ok = np.ones((9, 11), bool)
        ok[0, 0] = ok[1, 1] = False
        np.testing.assert_array_equal(out[ok], want[ok].astype(np.uint8))
    # the mapping is monotone per channel: -1 -> 0, 0 -> 128 (rounded 127.5), +1 -> 255
    axis = np.zeros((3, 1, 3), np.float32)
    axis[0, 0, 0], axis[0, 0, 1], axis[0, 0, 2] = -1.0, 1e-3, 1.0
    axis[1] = 1e-3  # keep these normals non-zero
    np.testing.assert_array_equal(cz.colorize_normals(axis)[0, :, 0], [0, 128, 255])
    with pytest.raises(ValueError, match=r"normals: expected shape \(3, H, W\), got \(9, 11, 3\)"):
        cz.colorize_normals(np.moveaxis(n, 0, -1))


# ------------------------------------------------------------- overlays

def _brute_min_filter(d: np.ndarray, r: int) -> np.ndarray:
    """Smallest valid depth within Chebyshev distance r (inf where none), by loops."""
    h, w = d.shape
    out = np.full((h, w), np.inf)
    for v in range(h):
        for u in range(w):
            for y in range(max(0, v - r), min(h, v + r + 1)):
                for x in range(max(0, u - r), min(w, u + r + 1)):
                    if np.isfinite(d[y, x]) and d[y, x] > 0:
                        out[v, u] = min(out[v, u], d[y, x])
    return out


@pytest.mark.parametrize("radius", [0, 1, 2])
def test_overlay_depth_matches_brute_force_nearest_on_top(radius):
    rng = np.random.default_rng(10 + radius)
    d = rng.uniform(2.0, 60.0, (13, 17)).astype(np.float32)
    d[rng.random(d.shape) < 0.85] = 0.0
    d[0, 0] = np.nan
    image = rng.integers(0, 256, (13, 17, 3), dtype=np.uint8)
    valid = np.isfinite(d) & (d > 0)
    lo, hi = float(d[valid].min()), float(d[valid].max())
    out = cz.overlay_depth(image, d, dot_radius_px=radius)
    assert out.shape == (13, 17, 3) and out.dtype == np.uint8
    near = _brute_min_filter(d, radius)
    covered = np.isfinite(near)
    np.testing.assert_array_equal(out[~covered], image[~covered])
    lut = cz.colormap_lut("turbo")
    idx = np.rint((near[covered] - lo) / (hi - lo) * 255).astype(int)
    np.testing.assert_array_equal(out[covered], lut[idx])
    assert not np.shares_memory(out, image)


def test_overlay_depth_grey_image_empty_depth_and_errors():
    grey = np.arange(20, dtype=np.uint8).reshape(4, 5)
    out = cz.overlay_depth(grey, np.zeros((4, 5), np.float32))
    np.testing.assert_array_equal(out, np.repeat(grey[..., None], 3, axis=-1))
    with pytest.raises(ValueError, match="image"):
        cz.overlay_depth(np.zeros((4, 6, 3), np.uint8), np.zeros((4, 5)))
    with pytest.raises(ValueError, match="uint8"):
        cz.overlay_depth(np.zeros((4, 5, 3), np.float32), np.zeros((4, 5)))
    with pytest.raises(ValueError, match="dot_radius_px"):
        cz.overlay_depth(grey, np.zeros((4, 5)), dot_radius_px=-1)


@pytest.mark.parametrize("radius", [0, 1, 3])
def test_overlay_mask_matches_brute_force(radius):
    rng = np.random.default_rng(20 + radius)
    mask = rng.random((11, 14)) < 0.05
    image = rng.integers(0, 256, (11, 14, 3), dtype=np.uint8)
    out = cz.overlay_mask(image, mask, color=(255, 0, 0), dot_radius_px=radius)
    grown = _brute_min_filter(np.where(mask, 1.0, 0.0), radius) == 1.0
    np.testing.assert_array_equal(out[grown], np.broadcast_to([255, 0, 0], out[grown].shape))
    np.testing.assert_array_equal(out[~grown], image[~grown])
    with pytest.raises(ValueError, match="color"):
        cz.overlay_mask(image, mask, color=(300, 0, 0))
    with pytest.raises(ValueError, match="mask"):
        cz.overlay_mask(image, mask.astype(np.uint8))
