"""The I/O edge of jaxdepth: files <-> validated NumPy arrays, padding, atomic writes.

Readers raise :class:`InputError` naming the file, the field and what was
expected; writers are atomic (temporary file in the target folder, fsync,
rename) and raise :class:`OutputError`. Both derive from :class:`JaxdepthError`,
which the command line turns into a one-line message and exit code 1. Nothing
here runs a completion stage.
"""

from typing import TYPE_CHECKING

from jaxdepth.io.atomic import atomic_write_bytes as atomic_write_bytes
from jaxdepth.io.atomic import atomic_write_png as atomic_write_png
from jaxdepth.io.atomic import encode_png as encode_png
from jaxdepth.io.calib import read_intrinsics_txt as read_intrinsics_txt
from jaxdepth.io.calib import read_kitti_object_calib as read_kitti_object_calib
from jaxdepth.io.calib import read_kitti_raw_calib as read_kitti_raw_calib
from jaxdepth.io.depth_png import encode_depth_png as encode_depth_png
from jaxdepth.io.depth_png import encode_depth_uint16 as encode_depth_uint16
from jaxdepth.io.depth_png import png_encoder as png_encoder
from jaxdepth.io.depth_png import read_depth_png as read_depth_png
from jaxdepth.io.depth_png import write_depth_png as write_depth_png
from jaxdepth.io.errors import InputError as InputError
from jaxdepth.io.errors import JaxdepthError as JaxdepthError
from jaxdepth.io.errors import OutputError as OutputError
from jaxdepth.io.kitti_frame import KittiFrame as KittiFrame
from jaxdepth.io.kitti_frame import load_kitti_frame as load_kitti_frame
from jaxdepth.io.kitti_layout import BENCHMARK_SIZE as BENCHMARK_SIZE
from jaxdepth.io.kitti_layout import benchmark_crop_offsets as benchmark_crop_offsets
from jaxdepth.io.kitti_layout import crop_to_benchmark as crop_to_benchmark
from jaxdepth.io.kitti_layout import list_depth_completion_folder as list_depth_completion_folder
from jaxdepth.io.points import MIN_BUCKET as MIN_BUCKET
from jaxdepth.io.points import bucket_size as bucket_size
from jaxdepth.io.points import infer_point_columns as infer_point_columns
from jaxdepth.io.points import pad_points as pad_points
from jaxdepth.io.points import read_points as read_points
# jaxdepth.io.rig builds Camera / LidarSpec pytrees and so imports JAX (as does sweep_frame, through it):
# their names load on first use (PEP 562), so the rest of the I/O edge (and `jaxdepth --help`) stays JAX-free.
_LAZY = {name: "rig" for name in ('Rig', 'RigCamera', 'default_lidar_spec', 'read_rig_json', 'rig_from_kitti_raw',
                                  'rig_from_kitti_object', 'rig_from_nuscenes_calibration', 'rig_to_json_text',
                                  'write_rig_json')}
_LAZY.update({name: "sweep_frame" for name in ("SweepFrame", "prepare_sweep", "shift_rig")})

if TYPE_CHECKING:
    from jaxdepth.io.rig import Rig as Rig
    from jaxdepth.io.rig import RigCamera as RigCamera
    from jaxdepth.io.rig import default_lidar_spec as default_lidar_spec
    from jaxdepth.io.rig import read_rig_json as read_rig_json
    from jaxdepth.io.rig import rig_from_kitti_raw as rig_from_kitti_raw
    from jaxdepth.io.rig import rig_from_kitti_object as rig_from_kitti_object
    from jaxdepth.io.rig import rig_from_nuscenes_calibration as rig_from_nuscenes_calibration
    from jaxdepth.io.rig import rig_to_json_text as rig_to_json_text
    from jaxdepth.io.rig import write_rig_json as write_rig_json
    from jaxdepth.io.sweep_frame import SweepFrame as SweepFrame
    from jaxdepth.io.sweep_frame import prepare_sweep as prepare_sweep
    from jaxdepth.io.sweep_frame import shift_rig as shift_rig


def __getattr__(name):
    if name in _LAZY:
        import importlib
        value = getattr(importlib.import_module(f"jaxdepth.io.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'jaxdepth.io' has no attribute {name!r}")


__all__ = [
    "BENCHMARK_SIZE",
    "InputError",
    "JaxdepthError",
    "KittiFrame",
    "MIN_BUCKET",
    "OutputError",
    "Rig",
    "RigCamera",
    "SweepFrame",
    "atomic_write_bytes",
    "atomic_write_png",
    "benchmark_crop_offsets",
    "bucket_size",
    "crop_to_benchmark",
    "default_lidar_spec",
    "encode_depth_png",
    "encode_depth_uint16",
    "encode_png",
    "infer_point_columns",
    "list_depth_completion_folder",
    "load_kitti_frame",
    "pad_points",
    "png_encoder",
    "read_depth_png",
    "read_intrinsics_txt",
    "read_kitti_object_calib",
    "read_kitti_raw_calib",
    "read_points",
    "read_rig_json",
    "prepare_sweep",
    "shift_rig",
    "rig_from_kitti_raw",
    "rig_from_kitti_object",
    "rig_from_nuscenes_calibration",
    "rig_to_json_text",
    "write_depth_png",
    "write_rig_json",
]
