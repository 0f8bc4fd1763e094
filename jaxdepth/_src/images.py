"""Camera images entering the pipeline: the dtype and shape rules, and the scaling to [0, 1].

A camera image is uint8 (0-255) or floating (taken as [0, 1]), grey (H, W) or colour
(H, W, 3), the size of the depth it guides. :func:`guidance_image` checks one camera's
image for :func:`~jaxdepth.complete` / :func:`~jaxdepth.complete_points`;
:func:`unit_float_image` is the dtype rule alone, shared with the rig's stacked images
(:mod:`jaxdepth._src.rig`). Images are only read by the image-guided seed search
(:mod:`jaxdepth._src.geodesic`); without guidance they are checked, then ignored.
"""

from __future__ import annotations

import jax.numpy as jnp


def guidance_image(image, shape: tuple[int, int], *, guided: bool, where: str):
    """Validates a camera image for the pipeline and scales it to float32 [0, 1].

    Args:
      image: None, or (H, W) grey / (H, W, 3) colour, uint8 (0-255) or
        floating (taken as [0, 1]); NumPy or JAX (checked at trace time).
      shape: (H, W) of the sparse depth it must match.
      guided: whether the seed search uses the image (``guidance_weight > 0``).
      where: caller name for the error message.

    Returns:
      float32 (H, W) or (H, W, 3) image when ``guided``, else None (an image
      given without guidance is checked, then ignored).

    Raises:
      ValueError naming the field 'image' with expected vs got: missing while
      guided, wrong size or channel count, or a dtype other than uint8/float
      (16-bit PNGs must be converted to 8 bit or scaled to [0, 1] first).
    """
    if image is None:
        if guided:
            raise ValueError(f"{where}: field 'image' expected an (H, W) or (H, W, 3) camera image because "
                             "config.guidance_weight > 0, got None")
        return None
    h, w = shape
    shp = tuple(image.shape)
    if not (shp == (h, w) or shp == (h, w, 3)):
        raise ValueError(f"{where}: field 'image' expected shape {(h, w)} (grey) or {(h, w, 3)} (colour), matching "
                         f"the sparse depth, got {shp}")
    return unit_float_image(image, guided=guided, where=where, field="image")


def unit_float_image(image, *, guided: bool, where: str, field: str):
    """The dtype rule of camera images: uint8 (0-255) or float (taken as [0, 1]).

    Returns ``image`` as float32 in [0, 1] when ``guided``, else None (checked,
    then ignored). Raises ValueError naming ``field`` for any other dtype (a
    16-bit image is told to convert to 8 bit or scale to [0, 1]).
    """
    dtype = jnp.dtype(image.dtype)
    if dtype != jnp.uint8 and not jnp.issubdtype(dtype, jnp.floating):
        raise ValueError(f"{where}: field '{field}' expected dtype uint8 (0-255) or float in [0, 1], got {dtype}"
                         + (" (a 16-bit image: convert to 8 bit or scale to [0, 1])" if dtype.itemsize == 2 else ""))
    if not guided:
        return None
    out = jnp.asarray(image, jnp.float32)
    return out / jnp.float32(255.0) if dtype == jnp.uint8 else out
