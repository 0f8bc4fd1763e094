"""Gaussian smoothing (Step 4b) against OpenCV and SciPy, jit and vmap."""

import cv2
import jax
import numpy as np
import pytest
import scipy.ndimage

from jaxdepth._src.smoothing import gaussian_blur


@pytest.mark.parametrize("shape", [(37, 53), (2, 9), (64, 3), (352, 1216)])
@pytest.mark.parametrize("sigma,radius", [(1.0, 2), (1.5, 4), (0.8, 1)])
def test_matches_opencv_and_scipy(shape, sigma, radius):
    img = np.random.default_rng(0).uniform(0, 80, shape).astype(np.float32)
    ours = np.asarray(gaussian_blur(img, sigma_px=sigma, radius_px=radius))
    if min(shape) > radius:  # OpenCV's reflect-101 needs the kernel to fit
        ref = cv2.GaussianBlur(img, (2 * radius + 1, 2 * radius + 1), sigma, sigmaY=sigma,
                               borderType=cv2.BORDER_REFLECT_101)
        np.testing.assert_allclose(ours, ref, rtol=1e-5, atol=1e-4)
    ref2 = scipy.ndimage.gaussian_filter(img.astype(np.float64), sigma, mode="mirror", truncate=radius / sigma)
    np.testing.assert_allclose(ours, ref2, rtol=1e-5, atol=1e-4)


def test_zero_sigma_is_identity_and_constant_preserved():
    img = np.random.default_rng(1).uniform(0, 1, (10, 12)).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(gaussian_blur(img, sigma_px=0, radius_px=2)), img)
    const = np.full((10, 12), 7.5, np.float32)
    np.testing.assert_allclose(np.asarray(gaussian_blur(const, sigma_px=1.0, radius_px=3)), const, rtol=1e-6)


def test_jit_vmap():
    imgs = np.random.default_rng(2).uniform(0, 10, (3, 20, 30)).astype(np.float32)
    f = lambda x: gaussian_blur(x, sigma_px=1.2, radius_px=3)
    loop = np.stack([np.asarray(f(x)) for x in imgs])
    np.testing.assert_allclose(np.asarray(jax.vmap(f)(imgs)), loop, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.stack([np.asarray(jax.jit(f)(x)) for x in imgs]), loop, rtol=1e-6, atol=1e-6)


# ------------------------------------------------------------- traced sigma

from jaxdepth._src.smoothing import gaussian_blur_traced  # noqa: E402


@pytest.mark.parametrize("radius", [1, 2, 4])
def test_traced_sigma_matches_static_blur_and_scipy(radius):
    img = np.random.default_rng(3).uniform(0, 80, (29, 41)).astype(np.float32)
    blur = jax.jit(lambda x, s: gaussian_blur_traced(x, s, radius_px=radius))
    for sigma in (0.3, 0.8, 1.0, 1.7, 3.0):
        ours = np.asarray(blur(img, np.float32(sigma)))
        np.testing.assert_allclose(ours, np.asarray(gaussian_blur(img, sigma_px=sigma, radius_px=radius)),
                                   rtol=1e-5, atol=1e-4)
        ref = scipy.ndimage.gaussian_filter(img.astype(np.float64), sigma, mode="mirror", truncate=radius / sigma)
        np.testing.assert_allclose(ours, ref, rtol=1e-5, atol=1e-4)


def test_traced_sigma_zero_or_radius_zero_is_identity():
    img = np.random.default_rng(4).uniform(0, 1, (10, 12)).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(gaussian_blur_traced(img, 0.0, radius_px=3)), img)
    np.testing.assert_array_equal(np.asarray(gaussian_blur_traced(img, -1.0, radius_px=3)), img)
    np.testing.assert_array_equal(np.asarray(gaussian_blur_traced(img, 1.5, radius_px=0)), img)


def test_traced_sigma_one_compile_vmap_equals_loop_and_jit_equals_eager():
    img = np.random.default_rng(5).uniform(0, 10, (20, 30)).astype(np.float32)
    sigmas = np.array([0.0, 0.5, 1.0, 2.5], np.float32)
    traces = []

    def f(s):
        traces.append(1)
        return gaussian_blur_traced(img, s, radius_px=3)

    jf = jax.jit(f)
    loop = np.stack([np.asarray(gaussian_blur_traced(img, s, radius_px=3)) for s in sigmas])
    jitted = np.stack([np.asarray(jf(s)) for s in sigmas])
    assert len(traces) == 1  # a new sigma does not retrace
    np.testing.assert_allclose(jitted, loop, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.asarray(jax.vmap(f)(sigmas)), loop, rtol=1e-6, atol=1e-6)
    # vmap over images and sigmas together
    imgs = np.random.default_rng(6).uniform(0, 10, (4, 20, 30)).astype(np.float32)
    both = jax.vmap(lambda x, s: gaussian_blur_traced(x, s, radius_px=2))(imgs, sigmas)
    loop2 = np.stack([np.asarray(gaussian_blur_traced(x, s, radius_px=2)) for x, s in zip(imgs, sigmas)])
    np.testing.assert_allclose(np.asarray(both), loop2, rtol=1e-6, atol=1e-6)


def test_traced_sigma_gradient_is_finite_and_matches_finite_difference():
    img = np.random.default_rng(7).uniform(0, 10, (12, 14)).astype(np.float32)
    loss = lambda s: jax.numpy.sum(gaussian_blur_traced(img, s, radius_px=3) ** 2)
    for s in (0.0, 1.2):
        g = float(jax.grad(loss)(jax.numpy.float32(s)))
        assert np.isfinite(g)
    h = 1e-2
    fd = (float(loss(np.float32(1.2 + h))) - float(loss(np.float32(1.2 - h)))) / (2 * h)
    np.testing.assert_allclose(float(jax.grad(loss)(np.float32(1.2))), fd, rtol=2e-2)


def test_traced_sigma_rejects_bad_arguments():
    img = np.zeros((5, 5), np.float32)
    with pytest.raises(ValueError, match="radius_px"):
        gaussian_blur_traced(img, 1.0, radius_px=-1)
    with pytest.raises(ValueError, match="sigma_px"):
        gaussian_blur_traced(img, np.ones(2, np.float32), radius_px=1)
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        gaussian_blur_traced(np.zeros((2, 5, 5), np.float32), 1.0, radius_px=1)
