"""KITTI dataset roots -> frame descriptions: one discovery function per layout.

Each function lists the frames of one KITTI layout and returns a
:class:`DatasetScan` whose ``jobs`` are :class:`FrameFiles`: plain records of a
frame's input file, output path, calibration and camera image. Nothing here
completes or writes: the batch runner turns each record into a job
(:meth:`jaxdepth.batch.runner.FrameJob.from_files`), so every layout runs through
the same batched, resumable, atomic runner (and the Ray engine). Every frame carries
its own ``K`` and ``T_cam_lidar`` from the layout's own calibration. The runner
writes into existing folders: create them first
(:func:`jaxdepth.io.atomic.make_output_folders` of the ``out_path`` s).

Layouts (outputs under ``dst``):

- **KITTI raw** (:func:`kitti_raw_jobs`): a date folder
  ``<date>/calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``,
  ``<date>_drive_XXXX_sync/velodyne_points/data/*.bin``; a single drive folder
  (calibration in its parent, the date folder); or a folder of date folders.
  Sweep frames (the ``.bin`` completed by :func:`jaxdepth.complete_points`), one per
  sweep and camera; image size from ``S_rect_0X``. Output
  ``dst/<drive>/proj_depth/<name>/image_0X/<frame>.png``.
- **KITTI depth-completion trees** (:func:`kitti_depth_tree_jobs`): ``train`` /
  ``val`` (or their parent, or one drive) holding
  ``<drive>/proj_depth/velodyne_raw/image_0X/*.png``. K and the extrinsic come
  from the per-date raw calibration in ``calib_dir``. Output mirrors the input,
  ``velodyne_raw`` replaced by ``<name>``: from ``train``,
  ``dst/<drive>/proj_depth/<name>/image_0X/<frame>.png``.
- **KITTI object** (:func:`kitti_object_jobs`): ``training`` / ``testing`` (or
  their parent) with ``velodyne/*.bin``, ``calib/*.txt``, ``image_2/*.png``.
  Sweep frames with the frame's own calibration, image size from the frame's
  PNG. Output ``dst/<split>/depth_X/<frame>.png`` (X: camera, 2 by default).

:func:`discover_kitti` picks the layout of a folder (None: not one of these).

Each frame also names its camera image (``FrameFiles.image_path``, read only by
image-guided runs): a raw drive's own ``image_0X/data/<frame>.png`` (cut like the
depth with ``crop``: ``FrameFiles.image_crop_from``), an object split's
``image_X/<frame>.png``, and for depth-completion trees, which hold no images, the
frame in a KITTI raw root given as ``image_dir`` (:mod:`jaxdepth.io.guidance_images`).
"""

from __future__ import annotations

import dataclasses
import pathlib
import re
from typing import Iterable

import numpy as np

from jaxdepth.io.errors import InputError, PathLike, file_error
from jaxdepth.io.guidance_images import raw_image_path

#: Sweep record of KITTI velodyne ``.bin`` files: x, y, z, reflectance (float32).
KITTI_POINT_COLUMNS = 4

_DRIVE = re.compile(r"^(\d{4}_\d{2}_\d{2})_drive_\d+_sync$")
_IMAGE_DIR = re.compile(r"^image_0([0-3])$")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

LAYOUTS = (
    "KITTI raw: a date folder (calib_cam_to_cam.txt, calib_velo_to_cam.txt, "
    "<date>_drive_XXXX_sync/velodyne_points/data/*.bin), one drive folder, or a folder of date folders",
    "KITTI depth-completion train/val trees (<drive>/proj_depth/velodyne_raw/image_0X/*.png, with --calib-dir)",
    "KITTI object training/testing (velodyne/*.bin, calib/*.txt, image_2/*.png)",
    "a KITTI selection folder (velodyne_raw/*.png + intrinsics/*.txt) or a flat folder of depth PNGs",
)


@dataclasses.dataclass(frozen=True)
class FrameFiles:
    """One frame of a dataset: where its input is, where its output goes, its calibration.

    Attributes:
      name: the frame's name in progress lines and reports (``<drive>/image_0X/<frame>``).
      sparse_path: the input, a sparse depth PNG or (``image_size`` set) a LiDAR sweep
        ``.bin`` of ``point_columns`` float32 values per point (x, y, z first, metres).
      out_path: the output depth PNG.
      K: (3, 3) float32 intrinsics of the output image.
      T_cam_lidar: (4, 4) float32 LiDAR -> camera extrinsic (None: the run's default).
      image_size: (height, width) of the output image for a sweep; None for a depth PNG.
      point_columns: values per sweep record (None: inferred from the file).
      image_path: the frame's camera image (read only by image-guided runs), or None.
      image_crop_from: (H, W) of the full frame whose 352 x 1216 benchmark crop is
        completed (the image is cut the same way); None: no crop.
    """

    name: str
    sparse_path: pathlib.Path
    out_path: pathlib.Path
    K: np.ndarray | None = None
    T_cam_lidar: np.ndarray | None = None
    image_size: tuple[int, int] | None = None
    point_columns: int | None = None
    image_path: pathlib.Path | None = None
    image_crop_from: tuple[int, int] | None = None


@dataclasses.dataclass(frozen=True)
class DatasetScan:
    """What a discovery function found.

    Attributes:
      layout: "kitti-raw", "kitti-depth-tree" or "kitti-object".
      jobs: list of :class:`FrameFiles`, sorted, distinct output paths.
      failed: ``(name, message)`` of frames that cannot be listed (e.g. an unreadable
        calibration file of one object frame); the run reports them as failed.
      summary: one line saying what was found (frames, cameras, dates).
    """

    layout: str
    jobs: list
    failed: list
    summary: str


# ---------------------------------------------------------------- helpers


def _dirs(folder: pathlib.Path) -> list[pathlib.Path]:
    try:
        return sorted(p for p in folder.iterdir() if p.is_dir())
    except OSError:
        return []


def _files(folder: pathlib.Path, suffix: str) -> list[pathlib.Path]:
    try:
        return sorted(p for p in folder.iterdir() if p.suffix.lower() == suffix and p.is_file())
    except OSError:
        return []


def _cameras(camera: int | None, default: Iterable[int]) -> tuple[int, ...]:
    if camera is None:
        return tuple(default)
    if isinstance(camera, bool) or camera not in (0, 1, 2, 3):
        raise ValueError(f"KITTI discovery: field 'camera' expected 0, 1, 2, 3 or None, got {camera!r}")
    return (int(camera),)


def _check_name(name: str) -> str:
    if not isinstance(name, str) or not name or name in (".", "..") or "/" in name or "\\" in name:
        raise ValueError(f"KITTI discovery: field 'name' expected a folder name (no '/'), got {name!r}")
    return name


def _camera_list(cameras: Iterable[int]) -> str:
    return ", ".join(str(c) for c in sorted(set(cameras)))


def png_image_size(path: PathLike) -> tuple[int, int]:
    """(height, width) of a PNG from its header (the image is not decoded).

    Raises:
      InputError: missing file, or not a PNG (bad signature or IHDR chunk).
    """
    path = pathlib.Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(24)
    except FileNotFoundError:
        raise file_error(path, "image not found (needed for the image size)") from None
    except OSError as err:
        raise file_error(path, f"cannot read ({err.strerror or err})") from None
    if len(head) < 24 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise file_error(path, "expected a PNG image (signature and IHDR header), got other bytes")
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if width < 1 or height < 1:
        raise file_error(path, f"PNG header gives an empty image {width}x{height}")
    return height, width


def _sweep_job(name: str, sweep: pathlib.Path, out: pathlib.Path, camera, *, image: pathlib.Path | None = None,
               crop_from: tuple[int, int] | None = None) -> FrameFiles:
    return FrameFiles(name=name, sparse_path=sweep, out_path=out, K=np.asarray(camera.K, np.float32),
                      T_cam_lidar=np.asarray(camera.T_cam_lidar, np.float32),
                      image_size=(int(camera.height), int(camera.width)), point_columns=KITTI_POINT_COLUMNS,
                      image_path=image, image_crop_from=crop_from)


# ---------------------------------------------------------------- KITTI raw


def _is_drive(folder: pathlib.Path) -> bool:
    return (folder / "velodyne_points" / "data").is_dir()


def _date_drives(folder: pathlib.Path) -> list[pathlib.Path]:
    """Drive folders (``<date>_drive_XXXX_sync`` with velodyne_points/data) of a date folder."""
    return [d for d in _dirs(folder) if _DRIVE.match(d.name) and _is_drive(d)]


def _is_raw_date(folder: pathlib.Path) -> bool:
    return (folder / "calib_cam_to_cam.txt").is_file() and bool(_date_drives(folder))


def _raw_drives(src: pathlib.Path) -> list[tuple[pathlib.Path, pathlib.Path]]:
    """(date folder, drive folder) pairs of a raw root, date folder or drive; [] if none."""
    if _is_drive(src):
        return [(src.parent, src)]
    if _is_raw_date(src):
        return [(src, d) for d in _date_drives(src)]
    return [(date, d) for date in _dirs(src) if _is_raw_date(date) for d in _date_drives(date)]


def kitti_raw_jobs(src: PathLike, dst: PathLike, *, camera: int | None = None, crop: bool = False,
                   name: str = "sgm", image_dir: PathLike | None = None) -> DatasetScan:
    """Jobs for every sweep x camera of a KITTI raw date folder, drive folder, or folder of dates.

    Args:
      src: ``<date>`` folder (``calib_cam_to_cam.txt``, ``calib_velo_to_cam.txt``,
        ``<date>_drive_XXXX_sync/velodyne_points/data/*.bin``), one drive folder
        (calibration read from its parent), or a folder holding date folders.
      dst: output root: ``dst/<drive>/proj_depth/<name>/image_0X/<frame>.png``.
      camera: one KITTI camera (0-3); None: cameras 2 and 3 (colour).
      crop: complete the 352 x 1216 benchmark crop (:func:`~jaxdepth.io.rig_from_kitti_raw`).
      name: output folder under ``proj_depth`` (e.g. the method name).
      image_dir: raw root holding the camera images (:func:`~jaxdepth.io.guidance_images.raw_image_path`);
        None: the drive's own ``image_0X/data/<frame>.png``. Read only by guided runs; with
        ``crop`` the image is the full ``S_rect_0X`` frame, cut like the depth.

    Returns:
      :class:`DatasetScan` of sweep frames (``FrameFiles.image_size`` set; K and
      ``T_cam_lidar`` of that camera from that date's calibration; ``image_path``).

    Raises:
      InputError: no drive found, a date folder without its calibration files, or a
        bad calibration file (named with its field).
    """
    from jaxdepth.io.rig import rig_from_kitti_raw

    src, dst = pathlib.Path(src), pathlib.Path(dst)
    name = _check_name(name)
    cams = _cameras(camera, (2, 3))
    pairs = _raw_drives(src)
    if not pairs:
        raise file_error(src, "no KITTI raw drive found (expected <date>_drive_XXXX_sync/velodyne_points/data/)")
    rigs: dict = {}
    full: dict = {}  # date -> full-frame cameras (the image size a cropped job's image must have)
    jobs = []
    sweeps = 0
    for date, drive in pairs:
        if date not in rigs:
            c2c, v2c = date / "calib_cam_to_cam.txt", date / "calib_velo_to_cam.txt"
            for path in (c2c, v2c):
                if not path.is_file():
                    raise file_error(path, f"KITTI raw calibration of drive '{drive.name}' not found (expected "
                                     "calib_cam_to_cam.txt and calib_velo_to_cam.txt in its date folder)")
            rigs[date] = rig_from_kitti_raw(c2c, v2c, cameras=cams, crop=crop)
            full[date] = rig_from_kitti_raw(c2c, v2c, cameras=cams).cameras if crop else None
        bins = _files(drive / "velodyne_points" / "data", ".bin")
        sweeps += len(bins)
        root = date.parent if image_dir is None else pathlib.Path(image_dir)
        for i, cam in enumerate(rigs[date].cameras):
            index = int(_IMAGE_DIR.match(cam.name).group(1))
            crop_from = None if full[date] is None else (int(full[date][i].height), int(full[date][i].width))
            for sweep in bins:
                out = dst / drive.name / "proj_depth" / name / cam.name / f"{sweep.stem}.png"
                image = raw_image_path(root, date=date.name, drive=drive.name, camera=index, frame=sweep.stem)
                jobs.append(_sweep_job(f"{drive.name}/{cam.name}/{sweep.stem}", sweep, out, cam, image=image,
                                       crop_from=crop_from))
    if not jobs:
        raise file_error(src, "KITTI raw drives found but no sweeps (expected velodyne_points/data/*.bin)")
    dates = sorted({d.name for d in rigs})
    summary = (f"KITTI raw: {len(jobs)} frames = {sweeps} sweeps x cameras {_camera_list(cams)}, "
               f"{len(pairs)} drive(s), date(s) {', '.join(dates)}" + (", benchmark crop" if crop else ""))
    return DatasetScan("kitti-raw", sorted(jobs, key=lambda j: j.name), [], summary)


# ---------------------------------------------------------------- depth-completion trees


def _velodyne_dirs(src: pathlib.Path) -> list[pathlib.Path]:
    """``.../proj_depth/velodyne_raw/image_0X`` folders at the shallowest depth (0-2) below ``src``."""
    for pattern in ("proj_depth/velodyne_raw/image_0?", "*/proj_depth/velodyne_raw/image_0?",
                    "*/*/proj_depth/velodyne_raw/image_0?"):
        found = sorted(p for p in src.glob(pattern) if p.is_dir() and _IMAGE_DIR.match(p.name))
        if found:
            return found
    return []


def raw_calib_folder(calib_dir: PathLike, date: str, *, frame: str = "") -> pathlib.Path:
    """Folder holding the KITTI raw calibration of ``date``, as ``--calib-dir`` reads it.

    ``calib_dir/calib_cam_to_cam.txt`` (one calibration for every date) if present,
    else ``calib_dir/<date>/`` (the raw data's own layout); the same rule as
    :class:`~jaxdepth.io.kitti_layout.KittiExtrinsics`.

    Raises:
      InputError: neither holds ``calib_cam_to_cam.txt`` and ``calib_velo_to_cam.txt``.
    """
    calib_dir = pathlib.Path(calib_dir)
    folder = calib_dir if (calib_dir / "calib_cam_to_cam.txt").is_file() else calib_dir / date
    for file in ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt"):
        if not (folder / file).is_file():
            what = f" for '{frame}'" if frame else ""
            raise file_error(folder, f"no KITTI raw calibration for {date}{what} (expected {file}, in "
                             f"{calib_dir}/<date>/ or directly in {calib_dir})")
    return folder


def kitti_depth_tree_jobs(src: PathLike, dst: PathLike, *, calib_dir: PathLike | None, camera: int | None = None,
                          name: str = "sgm", image_dir: PathLike | None = None) -> DatasetScan:
    """Jobs for a KITTI depth-completion ``train`` / ``val`` tree (no intrinsics folder).

    Args:
      src: ``train`` or ``val`` (``<drive>/proj_depth/velodyne_raw/image_0X/*.png``),
        their parent, or one drive folder.
      dst: output root; each ``<rel>/proj_depth/velodyne_raw/image_0X/F.png`` (``rel``
        relative to ``src``; a drive given as ``src`` is ``rel = <drive>``) becomes
        ``dst/<rel>/proj_depth/<name>/image_0X/F.png``.
      calib_dir: KITTI raw calibration, ``calib_dir/<date>/calib_cam_to_cam.txt`` and
        ``calib_velo_to_cam.txt``, or both directly in ``calib_dir``; the date comes
        from the drive name (``<date>_drive_XXXX_sync``). K is ``P_rect_0X``'s 3x3 block.
      camera: only this camera's folder (``image_0X``); None: every camera found.
      name: output folder under ``proj_depth``.
      image_dir: KITTI raw root with the camera images (the trees hold none):
        ``image_dir/<date>/<drive>/image_0X/data/<frame>.png`` or ``image_dir/<drive>/...``
        (:func:`~jaxdepth.io.guidance_images.raw_image_path`). None: jobs without images.

    Returns:
      :class:`DatasetScan` of depth-PNG jobs with K and ``T_cam_lidar`` per camera and date.

    Raises:
      InputError: no ``calib_dir``, no velodyne_raw folder, a drive name without a
        date, missing or bad calibration files.
    """
    from jaxdepth.io.calib import read_kitti_raw_calib

    src, dst = pathlib.Path(src), pathlib.Path(dst)
    name = _check_name(name)
    folders = _velodyne_dirs(src)
    if not folders:
        raise file_error(src, "no depth-completion tree found (expected <drive>/proj_depth/velodyne_raw/image_0X/)")
    if calib_dir is None:
        raise InputError(f"{src}: a KITTI depth-completion tree has no intrinsics; pass --calib-dir DIR with the "
                         "KITTI raw calibration (DIR/<date>/calib_cam_to_cam.txt and calib_velo_to_cam.txt)")
    if not pathlib.Path(calib_dir).is_dir():
        raise file_error(pathlib.Path(calib_dir), "calibration folder not found")
    calibs: dict = {}
    jobs, drives, cams = [], set(), set()
    for folder in folders:
        cam = int(_IMAGE_DIR.match(folder.name).group(1))
        if camera is not None and cam != camera:
            continue
        drive = folder.parent.parent.parent
        match = _DRIVE.match(drive.name)
        if match is None:
            raise file_error(drive, "drive folder name expected '<YYYY_MM_DD>_drive_XXXX_sync' (the date picks "
                             "the calibration)")
        calib_folder = raw_calib_folder(calib_dir, match.group(1), frame=drive.name)
        if calib_folder not in calibs:
            calibs[calib_folder] = read_kitti_raw_calib(calib_folder / "calib_cam_to_cam.txt",
                                                        calib_folder / "calib_velo_to_cam.txt")
        c = calibs[calib_folder]["cameras"][cam]
        rel = drive.relative_to(src) if drive != src else pathlib.Path(drive.name)
        for png in _files(folder, ".png"):
            out = dst / rel / "proj_depth" / name / folder.name / png.name
            image = None if image_dir is None else raw_image_path(image_dir, date=match.group(1), drive=drive.name,
                                                                   camera=cam, frame=png.stem)
            jobs.append(FrameFiles(name=f"{rel.as_posix()}/{folder.name}/{png.stem}", sparse_path=png, out_path=out,
                                   K=np.asarray(c["K"], np.float32),
                                   T_cam_lidar=np.asarray(c["T_cam_lidar"], np.float32), image_path=image))
        drives.add(drive)
        cams.add(cam)
    if not jobs:
        which = f" for camera {camera}" if camera is not None else ""
        raise file_error(src, f"no velodyne_raw PNG found{which} (expected <drive>/proj_depth/velodyne_raw/"
                         "image_0X/*.png)")
    dates = sorted({_DRIVE.match(d.name).group(1) for d in drives})
    summary = (f"KITTI depth-completion tree: {len(jobs)} frames, {len(drives)} drive(s), cameras "
               f"{_camera_list(cams)}, date(s) {', '.join(dates)}")
    return DatasetScan("kitti-depth-tree", sorted(jobs, key=lambda j: j.name), [], summary)


# ---------------------------------------------------------------- KITTI object


def _is_object_split(folder: pathlib.Path) -> bool:
    return (folder / "velodyne").is_dir() and (folder / "calib").is_dir()


def _object_splits(src: pathlib.Path) -> list[pathlib.Path]:
    if _is_object_split(src):
        return [src]
    return [d for d in _dirs(src) if _is_object_split(d)]


def kitti_object_jobs(src: PathLike, dst: PathLike, *, camera: int | None = None,
                      crop: bool = False) -> DatasetScan:
    """Jobs for every frame of KITTI object ``training`` / ``testing`` (or a folder holding them).

    Args:
      src: a split folder with ``velodyne/<frame>.bin``, ``calib/<frame>.txt`` and
        ``image_X/<frame>.png`` (only its size is read), or their parent.
      dst: output root: ``dst/<split>/depth_X/<frame>.png`` (``<split>``: the split
        folder's name, e.g. ``training``).
      camera: KITTI camera (2: ``image_2``, default; 3: ``image_3``).
      crop: complete the 352 x 1216 benchmark crop of each frame.

    Returns:
      :class:`DatasetScan` of sweep jobs with each frame's own calibration
      (:func:`~jaxdepth.io.rig_from_kitti_object`) and camera image
      (``image_X/<frame>.png``, cut like the depth with ``crop``). A frame whose
      calibration or image cannot be read is in ``failed``, the others are jobs.

    Raises:
      InputError: no split folder with ``velodyne/`` and ``calib/``.
    """
    from jaxdepth.io.errors import JaxdepthError
    from jaxdepth.io.rig import rig_from_kitti_object

    src, dst = pathlib.Path(src), pathlib.Path(dst)
    cam = _cameras(camera, (2,))[0]
    splits = _object_splits(src)
    if not splits:
        raise file_error(src, "no KITTI object split found (expected velodyne/ and calib/ folders)")
    jobs, failed = [], []
    for split in splits:
        for sweep in _files(split / "velodyne", ".bin"):
            frame = f"{split.name}/{sweep.stem}"
            image = split / f"image_{cam}" / f"{sweep.stem}.png"
            try:
                height, width = png_image_size(image)
                rig = rig_from_kitti_object(split / "calib" / f"{sweep.stem}.txt", width=width, height=height,
                                            cameras=(cam,), crop=crop)
            except JaxdepthError as err:
                failed.append((frame, str(err)))
                continue
            out = dst / split.name / f"depth_{cam}" / f"{sweep.stem}.png"
            jobs.append(_sweep_job(frame, sweep, out, rig.cameras[0], image=image,
                                   crop_from=(height, width) if crop else None))
    if not jobs and not failed:
        raise file_error(src, "KITTI object split found but no sweeps (expected velodyne/*.bin)")
    sizes = sorted({job.image_size for job in jobs})
    size_text = ", ".join(f"{w}x{h}" for h, w in sizes) or "none"
    summary = (f"KITTI object: {len(jobs) + len(failed)} frames in {', '.join(s.name for s in splits)}, "
               f"camera {cam}, image sizes {size_text}" + (", benchmark crop" if crop else ""))
    return DatasetScan("kitti-object", sorted(jobs, key=lambda j: j.name), failed, summary)


# ---------------------------------------------------------------- dispatch


def detect_kitti_layout(src: PathLike) -> str | None:
    """"kitti-raw", "kitti-depth-tree", "kitti-object", or None (not one of these folder layouts)."""
    src = pathlib.Path(src)
    if not src.is_dir():
        return None
    if _raw_drives(src):
        return "kitti-raw"
    if _object_splits(src):
        return "kitti-object"
    if _velodyne_dirs(src):
        return "kitti-depth-tree"
    return None


def discover_kitti(src: PathLike, dst: PathLike, *, camera: int | None = None, crop: bool = False,
                   name: str = "sgm", calib_dir: PathLike | None = None,
                   image_dir: PathLike | None = None) -> DatasetScan | None:
    """The frames of a KITTI dataset folder in any layout :func:`detect_kitti_layout` knows, else None.

    ``crop`` applies to sweeps (raw, object); ``calib_dir`` to depth-completion trees
    (a raw tree carries its own calibration); ``image_dir`` (a KITTI raw root with the
    camera images) to raw drives and depth-completion trees (an object split reads its
    own ``image_X``). Options that do not apply are refused.

    Raises:
      InputError: an option that does not apply to the layout found, or what the
        layout's discovery function raises.
    """
    layout = detect_kitti_layout(src)
    if layout is None:
        return None
    if layout != "kitti-depth-tree" and calib_dir is not None:
        raise InputError(f"{src}: --calib-dir is for depth-completion trees; this {layout} folder carries its own "
                         "calibration")
    if image_dir is not None and not pathlib.Path(image_dir).is_dir():
        raise file_error(pathlib.Path(image_dir), "image folder not found (--image-dir expected a KITTI raw root)")
    if layout == "kitti-raw":
        return kitti_raw_jobs(src, dst, camera=camera, crop=crop, name=name, image_dir=image_dir)
    if layout == "kitti-object":
        if image_dir is not None:
            raise InputError(f"{src}: --image-dir does not apply to a KITTI object folder (its image_X/ folder "
                             "is used)")
        return kitti_object_jobs(src, dst, camera=camera, crop=crop)
    if crop:
        raise InputError(f"{src}: --crop applies to LiDAR sweeps (KITTI raw, object); depth-completion PNGs are "
                         "completed at their own size")
    return kitti_depth_tree_jobs(src, dst, calib_dir=calib_dir, camera=camera, name=name, image_dir=image_dir)


def unknown_layout_message(src: PathLike) -> str:
    """The error text for a folder in no layout ``jaxdepth complete`` understands."""
    items = "; ".join(f"({i}) {text}" for i, text in enumerate(LAYOUTS, start=1))
    src = pathlib.Path(src)
    nusc = [p.name for p in _children(src) if p.name.startswith("v1.0-") or p.name in ("samples", "sweeps")]
    hint = (f" It looks like a nuScenes dataroot ({', '.join(sorted(nusc))}): pass --nusc-version VERSION "
            "(v1.0-mini, v1.0-trainval, v1.0-test)." if nusc else "")
    return (f"{src}: no dataset layout recognised.{hint} Understood: {items}; ({len(LAYOUTS) + 1}) a nuScenes "
            "dataroot (v1.0-*/ tables, samples/, sweeps/) with --nusc-version VERSION; "
            f"({len(LAYOUTS) + 2}) Argoverse 2 sensor logs (<log>/sensors/lidar/*.feather and "
            "<log>/calibration/: one log or a folder of logs, e.g. sensor/val/); or one depth PNG with --intrinsics")


def _children(folder: pathlib.Path) -> list:
    try:
        return list(folder.iterdir())
    except OSError:
        return []


__all__ = ["DatasetScan", "FrameFiles", "KITTI_POINT_COLUMNS", "LAYOUTS", "detect_kitti_layout", "discover_kitti",
           "kitti_depth_tree_jobs", "kitti_object_jobs", "kitti_raw_jobs", "png_image_size", "raw_calib_folder",
           "unknown_layout_message"]
