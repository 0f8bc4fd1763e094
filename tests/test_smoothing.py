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
