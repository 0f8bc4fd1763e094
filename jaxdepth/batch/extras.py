"""Optional extra outputs of ``jaxdepth complete`` / ``complete-rig``: paths, encodings, writes.

Every extra of a depth PNG ``<dir>/<stem>.png`` is written beside it as
``<dir>/<stem>_<kind>.png`` (one rule for every layout: image folders, KITTI
trees, nuScenes, complete-rig's ``<camera>.png``):

* ``--preview``: ``<stem>_preview.png``, 8-bit RGB colour image of the written depth
  (:func:`jaxdepth.colorize_depth`, turbo, each frame's own range unless
  ``--preview-range``) with a scale bar in metres below it
  (:func:`jaxdepth.depth_preview`).
* ``--validity``: ``<stem>_validity.png``, uint8, 255 = supported (inside the LiDAR's
  vertical field of view and within ``--max-seed-distance-px`` of a seed, by default 3
  scan-line spacings of the camera (docs/validity.md),
  :func:`jaxdepth.validity_and_distance`), 0 = not.
* ``--seed-distance``: ``<stem>_seed_distance.png``, uint16 ``round(16 * distance_px)``
  to the nearest seed in the run's ``--distance`` metric; 65535 = no seed (or
  >= 4095.97 px).
* ``--zero-invalid``: the depth PNG itself holds 0 outside the validity mask.

``jaxdepth eval`` skips files named like extras. Writes are atomic. Resume: a
frame is skipped when its depth PNG and every requested extra exist; otherwise
it is computed again and only the missing files are written (an existing file
is replaced only with ``--overwrite``). So adding a flag on a re-run fills in
the new files; changing ``--zero-invalid``, ``--max-seed-distance-px``,
``--distance`` or ``--preview-range`` is refused by the folder's run record
(:mod:`jaxdepth.batch.run_record`) unless ``--overwrite``, which recomputes every file.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np


KINDS = ("preview", "validity", "seed_distance")
SEED_DISTANCE_SCALE = 16.0  # uint16 value per pixel of distance
SEED_DISTANCE_NONE = 65535  # no seed, or too far to store
# Same value as jaxdepth._src.validity.DEFAULT_MAX_SEED_DISTANCE_PX (a test checks it); a literal here so that
# `jaxdepth --help` does not import JAX.
DEFAULT_MAX_SEED_DISTANCE_PX = 16.0
#: ``ExtraOutputs.seed_limit`` when the limit follows from the sensor (the runner's static key).
SENSOR_LIMIT = "sensor"


@dataclasses.dataclass(frozen=True)
class ExtraOutputs:
    """Which extras to write (hashable). ``max_seed_distance_px`` in pixels, None (default): from the
    sensor, 3 scan-line spacings of each camera (:func:`jaxdepth._src.validity.sensor_max_seed_distance_px`);
    ``preview_range`` (vmin, vmax) metres or None for each frame's own range."""

    preview: bool = False
    validity: bool = False
    seed_distance: bool = False
    zero_invalid: bool = False
    max_seed_distance_px: float | None = None
    preview_range: tuple | None = None

    def __post_init__(self):
        m = self.max_seed_distance_px
        if m is None:
            pass
        elif isinstance(m, bool) or not np.isfinite(float(m)) or float(m) < 0:
            raise ValueError(f"ExtraOutputs: field 'max_seed_distance_px' expected a finite number >= 0, got {m!r}")
        else:
            object.__setattr__(self, "max_seed_distance_px", float(m))
        if self.preview_range is not None:
            lo, hi = (float(x) for x in self.preview_range)
            if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
                raise ValueError(f"ExtraOutputs: field 'preview_range' expected finite vmin < vmax, "
                                 f"got {self.preview_range!r}")
            object.__setattr__(self, "preview_range", (lo, hi))

    @property
    def needs_seeds(self) -> bool:
        """The device must also return the validity mask and the seed distance."""
        return self.validity or self.seed_distance or self.zero_invalid

    @property
    def seed_limit(self):
        """The validity limit as a static key: pixels, or :data:`SENSOR_LIMIT`."""
        return SENSOR_LIMIT if self.max_seed_distance_px is None else self.max_seed_distance_px

    @property
    def kinds(self) -> tuple:
        """The extra files requested, in :data:`KINDS` order."""
        return tuple(k for k in KINDS if getattr(self, k))


NONE = ExtraOutputs()


def extra_path(depth_path, kind: str) -> pathlib.Path:
    """``<dir>/<stem>_<kind>.png`` beside the depth PNG ``<dir>/<stem>.png``."""
    if kind not in KINDS:
        raise ValueError(f"extra_path: field 'kind' expected one of {KINDS}, got {kind!r}")
    p = pathlib.Path(depth_path)
    return p.with_name(f"{p.stem}_{kind}.png")


def output_paths(depth_path, extras: ExtraOutputs) -> list:
    """The depth PNG and every requested extra of one output."""
    return [pathlib.Path(depth_path)] + [extra_path(depth_path, k) for k in extras.kinds]


def is_done(depth_path, extras: ExtraOutputs) -> bool:
    """Every file of this output exists (resume skips it)."""
    return all(p.exists() for p in output_paths(depth_path, extras))


def encode_seed_distance(distance_px: np.ndarray) -> np.ndarray:
    """(H, W) float pixels -> uint16 ``round(16 * d)``; ``+inf`` / NaN / >= 4095.9 px -> 65535."""
    d = np.asarray(distance_px, np.float64)
    scaled = np.rint(np.where(np.isfinite(d), d, np.inf) * SEED_DISTANCE_SCALE)
    return np.where(scaled < SEED_DISTANCE_NONE, scaled, SEED_DISTANCE_NONE).astype(np.uint16)


def decode_seed_distance(image: np.ndarray) -> np.ndarray:
    """uint16 seed-distance PNG values -> float32 pixels, ``+inf`` where 65535."""
    v = np.asarray(image)
    return np.where(v == SEED_DISTANCE_NONE, np.inf, v.astype(np.float32) / SEED_DISTANCE_SCALE).astype(np.float32)


def apply_zero_invalid(depth: np.ndarray, valid: np.ndarray | None, extras: ExtraOutputs) -> np.ndarray:
    """The depth to write: ``depth * valid`` with ``--zero-invalid``, else ``depth`` unchanged."""
    if not extras.zero_invalid:
        return depth
    return np.where(np.asarray(valid, bool), depth, np.float32(0.0)).astype(np.float32)


def write_outputs(depth_path, depth: np.ndarray, *, extras: ExtraOutputs, valid: np.ndarray | None = None,
                  distance: np.ndarray | None = None, overwrite: bool = False,
                  compression: int | None = None) -> list:
    """Writes the depth PNG and the requested extras, each atomically; returns the paths written.

    Args:
      depth_path: the depth PNG; extras go beside it (:func:`extra_path`).
      depth: (H, W) float32 metres, as completed (``--zero-invalid`` is applied here).
      valid: (H, W) bool validity (needed when ``extras.needs_seeds``).
      distance: (H, W) float32 seed distance, pixels (needed for ``seed_distance``).
      overwrite: replace existing files; otherwise only missing files are written.
      compression: zlib level of the depth PNG (default: the library's).
    """
    from jaxdepth._src.colorize import depth_preview
    from jaxdepth.io.atomic import atomic_write_png
    from jaxdepth.io.depth_png import DEFAULT_PNG_COMPRESSION, write_depth_png

    if extras.needs_seeds and valid is None:
        raise ValueError("write_outputs: field 'valid' expected for --validity / --seed-distance / --zero-invalid")
    depth = apply_zero_invalid(np.asarray(depth, np.float32), valid, extras)
    depth_path = pathlib.Path(depth_path)
    written = []

    def wanted(path):
        return overwrite or not path.exists()

    if wanted(depth_path):
        write_depth_png(depth_path, depth,
                        compression=DEFAULT_PNG_COMPRESSION if compression is None else compression)
        written.append(depth_path)
    for kind in extras.kinds:
        path = extra_path(depth_path, kind)
        if not wanted(path):
            continue
        if kind == "preview":
            lo, hi = extras.preview_range or (None, None)
            rgb = depth_preview(depth, vmin=lo, vmax=hi)
            atomic_write_png(path, np.ascontiguousarray(rgb[..., ::-1]))
        elif kind == "validity":
            atomic_write_png(path, np.where(np.asarray(valid, bool), 255, 0).astype(np.uint8))
        else:
            atomic_write_png(path, encode_seed_distance(distance))
        written.append(path)
    return written


# ---------------------------------------------------------------- command line glue


def add_cli_options(parser) -> None:
    """The extra-output flags of ``complete`` and ``complete-rig`` (no JAX import)."""
    group = parser.add_argument_group(
        "extra outputs", "written beside each depth PNG <stem>.png as <stem>_<kind>.png (atomic; resumed like the "
                         "depth: a re-run with the same flags skips finished frames, a re-run with a new flag "
                         "writes only the missing files; other changed settings are refused unless --overwrite); --validity, "
                         "--seed-distance and --zero-invalid need --method sgm")
    group.add_argument("--preview", action="store_true",
                       help="<stem>_preview.png: colour image of the depth (turbo, black = empty) with a scale bar "
                            "in metres")
    group.add_argument("--preview-range", type=float, nargs=2, default=None, metavar=("MIN_M", "MAX_M"),
                       help="depth range of the preview colours (default: each frame's own min and max)")
    group.add_argument("--validity", action="store_true",
                       help="<stem>_validity.png: uint8 mask, 255 = pixel the LiDAR supports (its ray inside the "
                            "LiDAR's vertical field of view and within --max-seed-distance-px of a seed)")
    group.add_argument("--seed-distance", action="store_true",
                       help="<stem>_seed_distance.png: uint16 distance to the nearest seed in the --distance metric, "
                            "value = round(16 * pixels), 65535 = no seed")
    group.add_argument("--zero-invalid", action="store_true",
                       help="write depth 0 outside the validity mask (e.g. the sky above the top beam)")
    group.add_argument("--max-seed-distance-px", type=float, default=None, metavar="PX",
                       help="validity: farthest supported pixel from a seed, pixels in the --distance metric "
                            "(default: from the sensor, 3 times the camera's scan-line spacing fy * (fov_up - "
                            "fov_down) / (beams - 1): 16.1 px on KITTI, 88 px on nuScenes; see docs/validity.md)")


def from_args(args) -> ExtraOutputs:
    """The :class:`ExtraOutputs` of parsed CLI arguments (ValueError for a bad value)."""
    return ExtraOutputs(preview=bool(getattr(args, "preview", False)), validity=bool(getattr(args, "validity", False)),
                        seed_distance=bool(getattr(args, "seed_distance", False)),
                        zero_invalid=bool(getattr(args, "zero_invalid", False)),
                        max_seed_distance_px=getattr(args, "max_seed_distance_px", None),
                        preview_range=None if getattr(args, "preview_range", None) is None
                        else tuple(args.preview_range))


__all__ = ["ExtraOutputs", "KINDS", "extra_path", "output_paths", "is_done", "encode_seed_distance",
           "decode_seed_distance", "apply_zero_invalid", "write_outputs", "add_cli_options", "from_args"]
