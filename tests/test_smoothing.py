"""Gaussian smoothing (Step 4b) against OpenCV and SciPy; jit, vmap and retrace via tests/_harness.py."""

import cv2
import jax
import numpy as np
import pytest
import scipy.ndimage

from jaxdepth._src.smoothing import gaussian_blur

from _harness import assert_close


def _blur_ulps(radius: int) -> int:
    """Rounding budget of a separable (2r+1)-tap blur against a float64 / other float32 one.

    Two passes of 2r+1 multiply-adds, each rounding by at most half an eps of the running
    value (bounded by max |image|), plus the weights' own rounding: 2 (2r+1) + 1 eps.
    """
    return 2 * (2 * radius + 1) + 1


def _cv2_blur(image, *, sigma_px, radius_px):
    k = 2 * radius_px + 1
    return cv2.GaussianBlur(np.asarray(image), (k, k), sigma_px, sigmaY=sigma_px, borderType=cv2.BORDER_REFLECT_101)


def _scipy_blur(image, sigma_px, *, radius_px):
    image = np.asarray(image, np.float64)
    if float(sigma_px) <= 0 or radius_px == 0:
        return image
    return scipy.ndimage.gaussian_filter(image, float(sigma_px), mode="mirror", truncate=radius_px / float(sigma_px))


#: The image size of the stage table's blur rows.
SHAPE = (20, 30)
#: The blurs compiled: one program per (shape, sigma, radius) case. Op by op, each call compiles its
#: stage fences (a ``lax.cond`` whose branches hold the weights) anew; jit == eager is the stage table's.
_blur = jax.jit(gaussian_blur, static_argnames=("sigma_px", "radius_px"))
#: (sigma, radius) of the static blur's cases; the traced blur is compared with these.
STATIC_CASES = ((1.0, 2), (1.5, 4), (0.8, 1))


# Border and kernel-fit cases; the image size does not change the per-pixel maths (no KITTI size needed).
@pytest.mark.parametrize("shape", [SHAPE, (2, 9), (64, 3)])
def test_matches_opencv_and_scipy(shape):
    img = np.random.default_rng(0).uniform(0, 80, shape).astype(np.float32)
    for sigma, radius in STATIC_CASES:
        ours = np.asarray(_blur(img, sigma_px=sigma, radius_px=radius))
        if min(shape) > radius:  # OpenCV's reflect-101 needs the kernel to fit
            assert_close(ours, _cv2_blur(img, sigma_px=sigma, radius_px=radius), ulps=_blur_ulps(radius), scale=80.0)
        assert_close(ours, _scipy_blur(img, sigma, radius_px=radius), ulps=_blur_ulps(radius), scale=80.0)


def test_zero_sigma_is_identity_and_constant_preserved():
    img = np.random.default_rng(1).uniform(0, 1, SHAPE).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(_blur(img, sigma_px=0, radius_px=2)), img)
    const = np.full(SHAPE, 7.5, np.float32)
    np.testing.assert_allclose(np.asarray(_blur(const, sigma_px=1.0, radius_px=2)), const, rtol=1e-6)


# OpenCV oracle, jit == eager, vmap == loop, no retrace: row gaussian_blur of tests/stage_table.py.


# ------------------------------------------------------------- traced sigma

from jaxdepth._src.smoothing import gaussian_blur_traced  # noqa: E402


@pytest.mark.parametrize("radius", [1, 2, 4])
def test_traced_sigma_matches_static_blur_and_scipy(radius):
    """Every sigma against SciPy; the static blur's own cases (STATIC_CASES, the size of the test above:
    its programs) against the static blur."""
    img = np.random.default_rng(3).uniform(0, 80, SHAPE).astype(np.float32)
    blur = jax.jit(lambda x, s: gaussian_blur_traced(x, s, radius_px=radius))
    for sigma in (0.3, 0.8, 1.0, 1.5, 1.7, 3.0):
        ours = np.asarray(blur(img, np.float32(sigma)))
        if (sigma, radius) in STATIC_CASES:
            assert_close(ours, np.asarray(_blur(img, sigma_px=sigma, radius_px=radius)),
                         ulps=_blur_ulps(radius), scale=80.0)
        assert_close(ours, _scipy_blur(img, sigma, radius_px=radius), ulps=_blur_ulps(radius), scale=80.0)


def test_traced_sigma_zero_or_radius_zero_is_identity():
    img = np.random.default_rng(4).uniform(0, 1, SHAPE).astype(np.float32)
    blur = jax.jit(gaussian_blur_traced, static_argnames="radius_px")   # one program per radius
    np.testing.assert_array_equal(np.asarray(blur(img, 0.0, radius_px=3)), img)
    np.testing.assert_array_equal(np.asarray(blur(img, -1.0, radius_px=3)), img)
    np.testing.assert_array_equal(np.asarray(blur(img, 1.5, radius_px=0)), img)


# SciPy oracle, jit == eager, vmap == loop over images and sigmas, and over sigma alone with a shared
# image: rows gaussian_blur_traced* of tests/stage_table.py.


def test_traced_sigma_gradient_is_finite_and_matches_finite_difference():
    img = np.random.default_rng(7).uniform(0, 10, SHAPE).astype(np.float32)
    loss = jax.jit(lambda s: jax.numpy.sum(gaussian_blur_traced(img, s, radius_px=3) ** 2))
    grad = jax.jit(jax.grad(loss))   # compiled once (op by op, every primitive of the backward pass compiles)
    for s in (0.0, 1.2):
        g = float(grad(jax.numpy.float32(s)))
        assert np.isfinite(g)
    h = 1e-2
    fd = (float(loss(np.float32(1.2 + h))) - float(loss(np.float32(1.2 - h)))) / (2 * h)
    np.testing.assert_allclose(float(grad(np.float32(1.2))), fd, rtol=2e-2)


def test_traced_sigma_rejects_bad_arguments():
    img = np.zeros((5, 5), np.float32)
    with pytest.raises(ValueError, match="radius_px"):
        gaussian_blur_traced(img, 1.0, radius_px=-1)
    with pytest.raises(ValueError, match="sigma_px"):
        gaussian_blur_traced(img, np.ones(2, np.float32), radius_px=1)
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        gaussian_blur_traced(np.zeros((2, 5, 5), np.float32), 1.0, radius_px=1)


@pytest.mark.parametrize("radius", [1, 3, 4])
def test_window_padding_is_numpy_reflect_of_the_window(radius):
    """The window's padding (a select among static shifts) holds, bit for bit, NumPy's reflect-101 padding of
    the window (``np.pad(mode="reflect")`` where it reflects once, the folded index beyond), for every
    window size from 2 to the canvas's on both axes, and under ``vmap`` with each window's own size."""
    from jaxdepth._src.smoothing import _reflect101_index, _reflect101_pad_window

    rng = np.random.default_rng(radius)
    canvas = rng.uniform(-1, 1, (9, 7)).astype(np.float32)
    pad = jax.jit(_reflect101_pad_window, static_argnums=(1, 2))
    for axis in (0, 1):
        length = canvas.shape[axis]
        sizes = np.arange(2, length + 1, dtype=np.int32)
        # one program (a vmap outside jit would compile every batched primitive op by op)
        batched = jax.jit(jax.vmap(lambda n, axis=axis: _reflect101_pad_window(canvas, radius, axis, n)))(sizes)
        for n, got_batched in zip(sizes, np.asarray(batched)):
            window = np.take(canvas, np.arange(n), axis=axis)
            want = np.take(window, _reflect101_index(int(n), radius), axis=axis)
            if radius < n:
                widths = [(0, 0), (0, 0)]
                widths[axis] = (radius, radius)
                np.testing.assert_array_equal(want, np.pad(window, widths, mode="reflect"))
            for got in (np.asarray(pad(canvas, radius, axis, n)), got_batched):
                got = np.take(got, np.arange(n + 2 * radius), axis=axis)
                np.testing.assert_array_equal(got, want, err_msg=f"axis {axis}, window {n}")


@pytest.mark.parametrize("shape", [(24, 40), (40, 24), (31, 33), (2, 9), (9, 2)])
def test_border_by_copies_is_the_whole_window_bit_for_bit(shape):
    """``copies=True`` (the one-source rig tail's blur: both axes padded on the input, then the taps) equals, bit
    for bit, the window form with the window the whole image (the rig's bytes), jit and eager, under ``vmap`` and
    in a loop; and OpenCV's BORDER_REFLECT_101 blur within the rounding budget where its kernel fits."""
    sigma, radius = 1.4, 3
    rng = np.random.default_rng(sum(shape))
    images = (rng.uniform(0, 80, (3,) + shape) * (rng.uniform(size=(3,) + shape) > 0.1)).astype(np.float32)
    size = np.asarray(shape, np.int32)
    copies = jax.jit(jax.vmap(lambda a: gaussian_blur(a, sigma_px=sigma, radius_px=radius, copies=True)))
    window = jax.jit(jax.vmap(lambda a: gaussian_blur(a, sigma_px=sigma, radius_px=radius, image_size=size)))
    got = np.asarray(copies(images))
    np.testing.assert_array_equal(got, np.asarray(window(images)))
    one = jax.jit(lambda a: gaussian_blur(a, sigma_px=sigma, radius_px=radius, copies=True))
    for i, image in enumerate(images):
        np.testing.assert_array_equal(np.asarray(one(image)), got[i], err_msg=f"vmap == loop, image {i}")
        if min(shape) > radius:  # OpenCV's reflect-101 needs the kernel to fit
            assert_close(got[i], _cv2_blur(image, sigma_px=sigma, radius_px=radius), ulps=_blur_ulps(radius),
                         scale=80.0)
        assert_close(got[i], _scipy_blur(image, sigma, radius_px=radius), ulps=_blur_ulps(radius), scale=80.0)
    # op by op nothing is fused (no multiply-add contracted): equal within the rounding budget
    eager = np.asarray(gaussian_blur(images[0], sigma_px=sigma, radius_px=radius, copies=True))
    assert_close(eager, got[0], ulps=_blur_ulps(radius), scale=80.0, err_msg="jit == eager")
