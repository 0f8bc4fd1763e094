"""One KITTI frame folder (sparse input, ground truth, calibration, image, sweep) as arrays.

The frame folder holds one KITTI raw frame with its depth-completion files, named
by camera ``X`` in {2, 3}::

    calib_cam_to_cam.txt, calib_velo_to_cam.txt   KITTI raw calibration of the drive's date
    velodyne_raw_image_0X.png                      sparse LiDAR depth (KITTI depth PNG)
    groundtruth_image_0X.png                       dense ground truth (KITTI depth PNG)
    image_0X.png                                   the camera's 8-bit image
    lidar_data.bin                                 the sweep, 4 float32 values per point

This is the layout of the shared development frame; the readers are the library's
own (:func:`read_depth_png`, :func:`read_kitti_raw_calib`, :func:`crop_to_benchmark`,
:func:`decode_camera_image`, :func:`read_points`), so every message on bad input
names the file and field they name.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from typing import Union

import numpy as np

from jaxdepth.io.calib import read_kitti_raw_calib
from jaxdepth.io.depth_png import read_depth_png
from jaxdepth.io.guidance_images import decode_camera_image
from jaxdepth.io.kitti_layout import crop_to_benchmark
from jaxdepth.io.points import read_points

PathLike = Union[str, "os.PathLike[str]"]


@dataclasses.dataclass(frozen=True)
class KittiFrame:
    """One camera of a KITTI frame folder.

    Attributes:
      sparse: (H, W) float32 metres, 0 = empty (``velodyne_raw_image_0X.png``).
      truth: (H, W) float32 metres, 0 = empty (``groundtruth_image_0X.png``).
      K: (3, 3) float32 intrinsics of these arrays (shifted by the crop).
      T_cam_lidar: (4, 4) float32 LiDAR -> camera X (rectified) transform.
      image: (H, W, 3) RGB or (H, W) grey uint8 camera image, or None when not read.
      scan: (N, 4) float32 sweep: x, y, z in metres and reflectance.
      camera: the KITTI camera index X.
    """

    sparse: np.ndarray
    truth: np.ndarray
    K: np.ndarray
    T_cam_lidar: np.ndarray
    image: np.ndarray | None
    scan: np.ndarray
    camera: int


def load_kitti_frame(root: PathLike, *, camera: int = 2, crop: bool = True, image: bool = True) -> KittiFrame:
    """Reads one camera of a KITTI frame folder (layout in the module docstring).

    Args:
      root: the frame folder.
      camera: KITTI camera index, 2 or 3.
      crop: cut depth, truth and image to the 352 x 1216 benchmark window
        (:func:`crop_to_benchmark`) and shift K to match; False keeps the full frame.
      image: also decode ``image_0X.png`` (False: ``image`` is None).

    Returns:
      A :class:`KittiFrame`.

    Raises:
      ValueError: ``camera`` not 2 or 3.
      InputError: a missing or malformed file, naming the file and field.

    Examples:
      >>> frame = load_kitti_frame("../shared/data/kitti/drive_0001_frame05")  # doctest: +SKIP
      >>> frame.sparse.shape, frame.K.dtype                                     # doctest: +SKIP
      ((352, 1216), dtype('float32'))
    """
    if camera not in (2, 3):
        raise ValueError(f"load_kitti_frame: field 'camera' expected 2 or 3, got {camera!r}")
    root = pathlib.Path(root)
    calib = read_kitti_raw_calib(root / "calib_cam_to_cam.txt", root / "calib_velo_to_cam.txt")
    K = np.asarray(calib["cameras"][camera]["K"], np.float32)
    sparse = np.asarray(read_depth_png(root / f"velodyne_raw_image_0{camera}.png"), np.float32)
    truth = np.asarray(read_depth_png(root / f"groundtruth_image_0{camera}.png"), np.float32)
    rgb = decode_camera_image(root / f"image_0{camera}.png") if image else None
    if crop:
        sparse, K_crop = crop_to_benchmark(sparse, K)
        truth, _ = crop_to_benchmark(truth, K)
        rgb = None if rgb is None else crop_to_benchmark(rgb, K)[0]
        K = np.asarray(K_crop, np.float32)
    points, extra = read_points(root / "lidar_data.bin", columns=4)
    return KittiFrame(sparse=sparse, truth=truth, K=K,
                      T_cam_lidar=np.asarray(calib["cameras"][camera]["T_cam_lidar"], np.float32),
                      image=rgb, scan=np.concatenate([points, extra], axis=1).astype(np.float32),
                      camera=camera)
