"""KITTI depth-completion layout: the benchmark crop and folder listing.

The benchmark (``val_selection_cropped``, ``test_depth_completion_anonymous``)
uses 352 x 1216 images cut from the ~375 x 1242 rectified frames: the bottom
352 rows and the centre 1216 columns. For 375 x 1242 that is rows 23..374 and
columns 13..1228, so ``cx -= 13`` and ``cy -= 23``.
"""

from __future__ import annotations

import pathlib
import re

import numpy as np

from jaxdepth.io.errors import PathLike, file_error

#: (height, width) of the KITTI depth-completion benchmark images.
BENCHMARK_SIZE = (352, 1216)


def benchmark_crop_offsets(height: int, width: int, *, size: tuple[int, int] = BENCHMARK_SIZE) -> tuple[int, int]:
    """(top, left) of the benchmark crop of an image of ``height`` x ``width`` pixels.

    The crop keeps the bottom ``size[0]`` rows and the centre ``size[1]`` columns
    (``left = (width - size[1]) // 2``).

    >>> benchmark_crop_offsets(375, 1242)
    (23, 13)

    Raises:
      ValueError: the image is smaller than ``size``.
    """
    crop_h, crop_w = (int(s) for s in size)
    if crop_h < 1 or crop_w < 1:
        raise ValueError(f"benchmark_crop_offsets: field 'size' expected positive (height, width), got {size}")
    if height < crop_h or width < crop_w:
        raise ValueError(f"benchmark_crop_offsets: field 'image' expected at least {crop_h}x{crop_w} "
                         f"(height x width), got {height}x{width}")
    return height - crop_h, (width - crop_w) // 2


def crop_to_benchmark(image: np.ndarray, K: np.ndarray, *,
                      size: tuple[int, int] = BENCHMARK_SIZE) -> tuple[np.ndarray, np.ndarray]:
    """Cuts the KITTI benchmark window out of a full frame and shifts K to match.

    Args:
      image: (H, W) or (H, W, C) array (depth, colour, ...), H >= 352, W >= 1216.
        Not modified.
      K: (3, 3) intrinsics of the full frame, pixels.
      size: (height, width) of the crop; KITTI's 352 x 1216 by default.

    Returns:
      (cropped, K_shifted): a copy of ``image[top:top + h, left:left + w]`` and
      float32 K with ``cx -= left``, ``cy -= top``, where (top, left) =
      :func:`benchmark_crop_offsets`. Projecting with ``K_shifted`` into the crop
      equals projecting with ``K`` into the full frame and cropping.

    Raises:
      ValueError: image with fewer than 2 or more than 3 dimensions, an image
        smaller than the crop, or K not (3, 3) finite.
    """
    image = np.asarray(image)
    K = np.asarray(K)
    if image.ndim not in (2, 3):
        raise ValueError(f"crop_to_benchmark: field 'image' expected shape (H, W) or (H, W, C), got {image.shape}")
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"crop_to_benchmark: field 'K' expected a finite (3, 3) matrix, got shape {K.shape}")
    top, left = benchmark_crop_offsets(image.shape[0], image.shape[1], size=size)
    crop_h, crop_w = (int(s) for s in size)
    cropped = image[top:top + crop_h, left:left + crop_w].copy()
    K_shifted = np.array(K, np.float64)
    # K [x, y, 1]: a shift of the pixel origin only moves the principal point (skew keeps its row).
    K_shifted[0, 2] -= left * K_shifted[2, 2]
    K_shifted[1, 2] -= top * K_shifted[2, 2]
    return cropped, K_shifted.astype(np.float32)


def _require_folder(path: pathlib.Path, what: str) -> None:
    if not path.exists():
        raise file_error(path, f"{what} not found")
    if not path.is_dir():
        raise file_error(path, f"{what} expected a folder, got a file")


def _intrinsics_candidates(stem: str) -> list[str]:
    """KITTI names the intrinsics after the image, e.g. ``..._velodyne_raw_0000000005_image_02``
    goes with ``..._image_0000000005_image_02.txt``; the test set uses equal stems."""
    names = [stem]
    if "velodyne_raw" in stem:
        names.append(stem.replace("velodyne_raw", "image", 1))
    return names


def list_depth_completion_folder(src: PathLike) -> list[tuple[str, pathlib.Path, pathlib.Path | None]]:
    """Lists the frames of a KITTI depth-completion folder.

    Accepted layouts (``image/`` and ``groundtruth_depth/`` are not needed):

    - ``SRC/velodyne_raw/*.png`` with optional ``SRC/intrinsics/*.txt``
      (``val_selection_cropped``, ``test_depth_completion_anonymous``). The
      intrinsics of ``X.png`` are ``X.txt``, or with ``velodyne_raw`` in the
      name replaced by ``image`` (KITTI's own naming);
    - a flat ``SRC/*.png`` folder, each with an optional ``SRC/X.txt`` beside it.

    Returns:
      Sorted list of ``(name, velodyne_png_path, intrinsics_txt_path or None)``,
      with ``name`` the PNG's stem. The intrinsics path is None when the layout
      has no intrinsics (no ``intrinsics/`` folder, or no ``.txt`` beside the
      PNG in the flat layout).

    Raises:
      InputError: SRC is missing or not a folder, it holds no PNG, or an
        ``intrinsics/`` folder exists but lacks the file of a frame (silently
        falling back to default intrinsics would give wrong depths).
    """
    src = pathlib.Path(src)
    _require_folder(src, "input folder")
    velodyne = src / "velodyne_raw"
    if velodyne.exists():
        _require_folder(velodyne, "velodyne_raw")
        png_folder, txt_folder = velodyne, src / "intrinsics"
        strict = txt_folder.exists()
        if strict:
            _require_folder(txt_folder, "intrinsics")
    else:
        png_folder, txt_folder, strict = src, src, False
    pngs = sorted(p for p in png_folder.iterdir() if p.suffix.lower() == ".png" and p.is_file())
    if not pngs:
        raise file_error(png_folder, "no .png files found (expected KITTI velodyne_raw depth PNGs, "
                         "in SRC/velodyne_raw/ or directly in SRC/)")
    frames = []
    for png in pngs:
        txt = None
        for candidate in _intrinsics_candidates(png.stem):
            if (txt_folder / f"{candidate}.txt").is_file():
                txt = txt_folder / f"{candidate}.txt"
                break
        if txt is None and strict:
            wanted = " or ".join(f"{c}.txt" for c in _intrinsics_candidates(png.stem))
            raise file_error(txt_folder, f"missing intrinsics for frame '{png.name}' (expected {wanted})")
        frames.append((png.stem, png, txt))
    return frames


_CAMERA_SUFFIX = re.compile(r"_image_0([0-3])$")
_DATE = re.compile(r"(\d{4}_\d{2}_\d{2})_drive_")


def kitti_camera_from_name(stem: str) -> int | None:
    """KITTI camera index from a depth-completion file stem ending in ``_image_0X``, else None.

    >>> kitti_camera_from_name("2011_09_26_drive_0001_sync_velodyne_raw_0000000005_image_03")
    3
    """
    match = _CAMERA_SUFFIX.search(stem)
    return int(match.group(1)) if match else None


def kitti_date_from_name(stem: str) -> str | None:
    """Recording date (``2011_09_26``) from a KITTI file stem holding ``<date>_drive_``, else None."""
    match = _DATE.search(stem)
    return match.group(1) if match else None


class KittiExtrinsics:
    """The LiDAR -> camera extrinsic of each KITTI depth-completion frame.

    The camera is the file name's ``_image_0X`` suffix (``camera`` overrides it;
    neither: camera 2). Without ``calib_dir`` the 2011_09_26 calibration built
    into jaxdepth is used (cameras 2 and 3); with it, the per-date KITTI raw
    calibration: ``calib_dir/<date>/calib_cam_to_cam.txt`` and
    ``calib_velo_to_cam.txt`` (the raw data's own layout), or the two files
    directly in ``calib_dir`` for every date. The date comes from the file name
    (``<date>_drive_...``). Calibrations are read once per date.
    """

    def __init__(self, calib_dir: PathLike | None = None, *, camera: int | None = None):
        self.calib_dir = None if calib_dir is None else pathlib.Path(calib_dir)
        if self.calib_dir is not None:
            _require_folder(self.calib_dir, "calibration folder")
        if camera is not None and camera not in (0, 1, 2, 3):
            raise ValueError(f"KittiExtrinsics: field 'camera' expected 0, 1, 2 or 3, got {camera!r}")
        self.camera = camera
        self._by_date: dict = {}

    def camera_of(self, stem: str) -> int:
        if self.camera is not None:
            return self.camera
        found = kitti_camera_from_name(stem)
        return 2 if found is None else found

    def __call__(self, path: PathLike):
        """(4, 4) float32 extrinsic of the frame stored at ``path``."""
        import numpy as np

        path = pathlib.Path(path)
        cam = self.camera_of(path.stem)
        if self.calib_dir is None:
            from jaxdepth._src.presets import KITTI_T_CAM_LIDAR
            if cam not in KITTI_T_CAM_LIDAR:
                raise file_error(path, f"camera {cam} has no built-in extrinsic (cameras 2 and 3 do); "
                                 "pass --calib-dir with the KITTI raw calibration")
            return np.asarray(KITTI_T_CAM_LIDAR[cam], np.float32)
        folder = self.calib_dir
        if not (folder / "calib_cam_to_cam.txt").is_file():
            date = kitti_date_from_name(path.stem)
            if date is None:
                raise file_error(path, "no recording date in the file name (expected '<YYYY_MM_DD>_drive_...') "
                                 f"to pick its calibration from {self.calib_dir}")
            folder = self.calib_dir / date
            if not (folder / "calib_cam_to_cam.txt").is_file():
                raise file_error(folder, f"no KITTI raw calibration for {date} (expected calib_cam_to_cam.txt and "
                                 f"calib_velo_to_cam.txt) for frame '{path.name}'")
        if folder not in self._by_date:
            from jaxdepth.io.calib import read_kitti_raw_calib
            self._by_date[folder] = read_kitti_raw_calib(folder / "calib_cam_to_cam.txt",
                                                         folder / "calib_velo_to_cam.txt")
        return np.asarray(self._by_date[folder]["cameras"][cam]["T_cam_lidar"], np.float32)


__all__ = ["BENCHMARK_SIZE", "benchmark_crop_offsets", "crop_to_benchmark", "list_depth_completion_folder",
           "kitti_camera_from_name", "kitti_date_from_name", "KittiExtrinsics"]
