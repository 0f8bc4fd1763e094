"""Camera images for image-guided seeds: reading, checking, cropping, and where KITTI keeps them.

The batch runner reads a frame's camera image only when the run is guided
(``SGMConfig.guidance_weight > 0``). :func:`read_guidance_image` returns what
:func:`jaxdepth.complete` takes as ``image=``: (H, W) grey or (H, W, 3) RGB
uint8 (PNG / JPEG decoded by OpenCV, channels reordered from OpenCV's BGR).

Lookup rules (the path of each frame's image; nothing is opened here):

- KITTI raw layout (:func:`raw_image_path`): ``ROOT/<date>/<drive>/image_0X/data/<frame>.png``,
  or ``ROOT/<drive>/image_0X/data/<frame>.png`` (ROOT: a date folder or a folder of drives).
  A raw drive's own images use ``ROOT`` = the folder above its date folder; a
  depth-completion train/val tree (no images of its own) needs ``--image-dir ROOT``.
- Depth-completion selection folders and plain folders (:func:`image_candidates`):
  the image of ``velodyne_raw/X.png`` is ``DIR/X.png``, or, for KITTI's own naming,
  ``DIR/X'.png`` with the first ``velodyne_raw`` in ``X`` replaced by ``image``
  (``..._velodyne_raw_0000000005_image_02`` -> ``..._image_0000000005_image_02``); the
  KITTI name is tried first. ``DIR``: ``--image-dir``, else ``SRC/image/`` (the
  ``val_selection_cropped`` / ``test_*`` layout).
- KITTI object: ``<split>/image_X/<frame>.png`` (X: the camera).

Crops: a job that completes the 352 x 1216 benchmark window of a larger frame
(``--crop``) names the full frame size it expects (``crop_from``); the image
must have that size and is cut like the depth (:func:`~jaxdepth.io.kitti_layout.crop_to_benchmark`:
bottom rows, centre columns).
"""

from __future__ import annotations

import pathlib

import numpy as np

from jaxdepth.io.errors import PathLike, file_error, read_input_bytes

_WHAT = "a camera image (8-bit PNG or JPEG)"


def _size(shape) -> str:
    return f"{shape[1]}x{shape[0]}"


def decode_camera_image(path: PathLike) -> np.ndarray:
    """An 8-bit grey (H, W) or colour (H, W, 3) RGB image (OpenCV decodes BGR; reordered), checked.

    Raises:
      InputError naming the file: missing or unreadable, not decodable, not 8-bit
      (16-bit PNGs), 2 or 4 channels (alpha).
    """
    import cv2

    path = pathlib.Path(path)
    data = read_input_bytes(path, expected=_WHAT)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
    if image is None:
        raise file_error(path, f"cannot decode as an image (expected {_WHAT})")
    if image.dtype != np.uint8:
        bits = f"{image.dtype.itemsize * 8}-bit ({image.dtype})"
        raise file_error(path, f"camera image expected 8-bit (uint8) values, got {bits}; convert it to 8 bit")
    channels = 1 if image.ndim == 2 else image.shape[2]
    if channels not in (1, 3):
        raise file_error(path, f"camera image expected 1 (grey) or 3 (colour) channels, got {channels}"
                         + (" (an alpha channel: save it without alpha)" if channels in (2, 4) else ""))
    if image.ndim == 3 and channels == 1:
        return image[:, :, 0]
    return image[:, :, ::-1] if image.ndim == 3 else image  # OpenCV's BGR -> RGB


def read_guidance_image(path: PathLike, *, size: tuple[int, int],
                        crop_from: tuple[int, int] | None = None) -> np.ndarray:
    """The camera image of one frame, checked against the depth it guides.

    Args:
      path: image file (8-bit grey or colour PNG / JPEG).
      size: (height, width) of the frame's depth image, pixels.
      crop_from: None: the image must be ``size``. (H, W): the depth is the
        benchmark crop (bottom rows, centre columns) of an H x W frame; the image
        must be H x W and is cut the same way.

    Returns:
      (height, width) uint8 grey or (height, width, 3) uint8 RGB, C-contiguous.

    Raises:
      InputError naming the file: missing or unreadable, not decodable, not 8-bit
      (16-bit PNGs), 2 or 4 channels (alpha), or a size other than expected.
    """
    path = pathlib.Path(path)
    image = decode_camera_image(path)
    expected = tuple(int(s) for s in (size if crop_from is None else crop_from))
    if image.shape[:2] != expected:
        why = ("the size of the frame's depth image" if crop_from is None else
               f"the full frame whose {_size(size)} benchmark crop is completed")
        raise file_error(path, f"camera image expected {_size(expected)} (width x height, {why}), "
                         f"got {_size(image.shape)}")
    if crop_from is not None:
        from jaxdepth.io.kitti_layout import benchmark_crop_offsets
        top, left = benchmark_crop_offsets(image.shape[0], image.shape[1], size=size)
        image = image[top:top + size[0], left:left + size[1]]
    return np.ascontiguousarray(image)


def image_candidates(folder: PathLike, stem: str) -> list[pathlib.Path]:
    """Possible image files of the depth PNG ``stem`` in ``folder``, in the order tried:
    the KITTI name (first ``velodyne_raw`` -> ``image``) when it differs, then ``stem.png``."""
    folder = pathlib.Path(folder)
    names = []
    if "velodyne_raw" in stem:
        names.append(stem.replace("velodyne_raw", "image", 1))
    names.append(stem)
    return [folder / f"{name}.png" for name in names]


def find_image(folder: PathLike, stem: str) -> pathlib.Path:
    """The first existing :func:`image_candidates` file, else the first candidate (reading it
    then fails with 'not found' naming the file)."""
    candidates = image_candidates(folder, stem)
    return next((c for c in candidates if c.is_file()), candidates[0])


def selection_image_folder(src: PathLike, image_dir: PathLike | None = None) -> pathlib.Path:
    """The folder holding the camera images of a selection folder, flat folder or single depth PNG.

    ``image_dir`` when given; else ``SRC/image/`` beside ``SRC/velodyne_raw/`` (KITTI's
    ``val_selection_cropped`` and ``test_*`` folders), or, for one PNG inside a
    ``velodyne_raw/`` folder, the ``image/`` folder beside that. Each frame's file is then
    :func:`find_image`.

    Raises:
      InputError: ``image_dir`` is not a folder, or there is no ``image/`` folder
        (flat folders and single files need ``image_dir``).
    """
    if image_dir is not None:
        image_dir = pathlib.Path(image_dir)
        if not image_dir.is_dir():
            raise file_error(image_dir, "image folder not found (--image-dir expected a folder of camera images)")
        return image_dir
    src = pathlib.Path(src)
    velodyne = src.parent if src.suffix.lower() == ".png" else src / "velodyne_raw"
    if velodyne.name == "velodyne_raw" and (velodyne.parent / "image").is_dir():
        return velodyne.parent / "image"
    raise file_error(src, "no camera images found for image-guided seeds (expected an image/ folder beside "
                     "velodyne_raw/, as in KITTI's val_selection_cropped); pass --image-dir DIR")


def raw_image_path(root: PathLike, *, date: str, drive: str, camera: int, frame: str) -> pathlib.Path:
    """KITTI raw image of one frame under ``root``: ``root/<date>/<drive>/image_0X/data/<frame>.png``,
    or ``root/<drive>/...`` when ``root/<date>/<drive>`` is not a folder but ``root/<drive>`` is
    (``root`` a date folder); the first form when neither exists."""
    root = pathlib.Path(root)
    drive_dir = root / date / drive
    if not drive_dir.is_dir() and (root / drive).is_dir():
        drive_dir = root / drive
    return drive_dir / f"image_0{int(camera)}" / "data" / f"{frame}.png"


__all__ = ["find_image", "image_candidates", "raw_image_path", "read_guidance_image", "selection_image_folder"]
