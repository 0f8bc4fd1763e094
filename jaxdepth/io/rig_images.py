"""Camera images of a rig for image-guided seeds (``complete-rig``, nuScenes samples).

:func:`read_camera_image` decodes one 8-bit PNG / JPEG with OpenCV and checks it
against its camera; :func:`read_rig_images` reads one per camera and stacks them
on the rig's canvas (:func:`jaxdepth.stack_images`), which is what
``jaxdepth.complete_rig(..., images=)`` takes. Colour images come out RGB
(OpenCV decodes BGR). All cameras of one call must agree on grey vs colour.

Where ``complete-rig`` finds each camera's file (:func:`rig_image_paths`):
``--image-dir DIR`` -> ``DIR/<camera name>.png``, ``.jpg`` or ``.jpeg`` (the
first that exists); otherwise the camera's ``image`` field in the rig JSON
(a path relative to the JSON's folder, or absolute).

Errors are :class:`~jaxdepth.io.errors.InputError` naming the file and what was
expected: missing, not decodable, 16-bit, 2 or 4 channels (alpha), a size other
than the camera's, grey where the other cameras are colour (or the reverse).
"""

from __future__ import annotations

import os
import pathlib
from typing import Sequence

import numpy as np

from jaxdepth.io.errors import InputError, PathLike, file_error
from jaxdepth.io.guidance_images import decode_camera_image

#: File name endings tried in an image folder, in this order.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def _channels_word(channels: int) -> str:
    return "colour (3 channels)" if channels == 3 else "grey (1 channel)"


def read_camera_image(path: PathLike, *, width: int, height: int, colour: bool | None = None,
                      camera: str = "the camera", like: str | None = None) -> np.ndarray:
    """One camera image, decoded and checked.

    Args:
      path: 8-bit grey or colour PNG / JPEG file.
      width, height: the camera's image size in pixels.
      colour: True / False to require colour / grey; None accepts either.
      camera: camera name for the messages.
      like: where ``colour`` comes from, for the message (e.g. "like CAM_FRONT.jpg").

    Returns:
      (height, width) uint8 grey or (height, width, 3) uint8 RGB, C-contiguous.

    Raises:
      InputError naming the file: missing or unreadable, not decodable, not
      8-bit (e.g. a 16-bit PNG), 2 or 4 channels, another size, or grey / colour
      other than ``colour``.
    """
    path = pathlib.Path(path)
    image = decode_camera_image(path)
    channels = 1 if image.ndim == 2 else 3
    if image.shape[:2] != (height, width):
        raise file_error(path, f"camera image expected {width}x{height} (width x height of {camera}), "
                               f"got {image.shape[1]}x{image.shape[0]}")
    if colour is not None and (channels == 3) != colour:
        raise file_error(path, f"camera image expected {_channels_word(3 if colour else 1)} for {camera}"
                               f"{' (' + like + ')' if like else ''}, got {_channels_word(channels)}")
    return np.ascontiguousarray(image)


def read_rig_images(paths: Sequence[PathLike], cameras, *, colour: bool | None = None) -> np.ndarray:
    """One image per camera, stacked on the rig's canvas for ``complete_rig(..., images=)``.

    Args:
      paths: one file per camera, in the cameras' order.
      cameras: the cameras (anything with ``name``, ``width``, ``height``:
        :class:`~jaxdepth.io.RigCamera`), the canvas is their largest size as
        in :func:`jaxdepth.stack_cameras`.
      colour: True / False to require colour / grey; None: the first camera's
        image decides and the others must match.

    Returns:
      (C, H, W) or (C, H, W, 3) uint8 (:func:`jaxdepth.stack_images`: each image
      in the top-left corner of the canvas, zeros elsewhere).

    Raises:
      InputError naming the file (see :func:`read_camera_image`); a grey image
      among colour ones names both files.
    """
    from jaxdepth._src.rig import stack_images

    cameras = list(cameras)
    if len(paths) != len(cameras):
        raise InputError(f"expected one camera image per camera ({len(cameras)}), got {len(paths)}")
    images = []
    for i, (path, cam) in enumerate(zip(paths, cameras)):
        like = None if colour is not None or i == 0 else f"like {os.fspath(paths[0])}"
        images.append(read_camera_image(path, width=cam.width, height=cam.height, camera=f"camera {cam.name}",
                                        colour=colour if i == 0 or colour is not None else images[0].ndim == 3,
                                        like=like))
    return stack_images(images, cameras)


def rig_image_paths(cameras, *, image_dir: PathLike | None = None, rig_json: PathLike | None = None,
                    json_images: dict | None = None) -> list[pathlib.Path]:
    """Where ``complete-rig`` looks for each camera's image (see the module docstring).

    Args:
      cameras: the rig's cameras (with ``name``).
      image_dir: ``--image-dir``: ``<dir>/<name>.png`` / ``.jpg`` / ``.jpeg``, the first that exists.
      rig_json: the rig JSON file (relative ``image`` fields are relative to its folder).
      json_images: camera name -> the ``image`` field of that camera in the rig JSON.

    Returns:
      One path per camera (not opened: reading a missing one fails naming it).

    Raises:
      InputError: ``image_dir`` is not a folder, or a camera has no image (no
        ``image_dir`` and no ``image`` field), naming the camera and the rig file.
    """
    json_images = json_images or {}
    if image_dir is not None:
        folder = pathlib.Path(image_dir)
        if not folder.is_dir():
            raise file_error(folder, "image folder not found (--image-dir expected a folder with "
                                     "<camera name>.png or .jpg per camera)")
        out = []
        for cam in cameras:
            tried = [folder / f"{cam.name}{suffix}" for suffix in IMAGE_SUFFIXES]
            found = next((p for p in tried if p.is_file()), None)
            if found is None:
                raise file_error(folder, f"no image for camera {cam.name}: expected one of "
                                         f"{', '.join(p.name for p in tried)}")
            out.append(found)
        return out
    base = pathlib.Path(rig_json).parent if rig_json is not None else pathlib.Path(".")
    out = []
    for cam in cameras:
        given = json_images.get(cam.name)
        if given is None:
            where = f"{os.fspath(rig_json)}: " if rig_json is not None else ""
            raise InputError(f"{where}camera {cam.name} has no image: give --image-dir DIR "
                             f"(DIR/{cam.name}.png or .jpg) or an \"image\" field for that camera")
        out.append(base / given)
    return out


__all__ = ["read_camera_image", "read_rig_images", "rig_image_paths", "IMAGE_SUFFIXES"]
