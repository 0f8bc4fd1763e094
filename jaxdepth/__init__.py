"""jaxdepth: non-learning LiDAR depth completion (Surface Geometry Model) in JAX.

Zhao, Bai, Zhang, Huang, "A Surface Geometry Model for LiDAR Depth Completion",
IEEE RA-L 2021. Every stage is a pure, jit-compiled, fixed-shape JAX function,
so completion vmaps over frames and cameras.

The public names load on first use (PEP 562 ``__getattr__``): ``import jaxdepth`` and
``jaxdepth --help`` do not import JAX, and ``from jaxdepth import complete`` works as usual.
"""

from typing import TYPE_CHECKING

__version__ = "0.1.0"

#: Changes whenever completion outputs change (``__version__`` need not): the first 12 hex digits of
#: the SHA-256 of ``benchmarks/results/output_fingerprint.json`` as canonical JSON (sorted keys, no
#: spaces). Run records store it and refuse to resume a folder written by another one
#: (:mod:`jaxdepth.batch.run_record`); tests/test_run_records.py fails when the two disagree.
__output_version__ = "80b54ef3747d"

if TYPE_CHECKING:  # the names of _LAZY below, imported eagerly, for type checkers and IDEs
    from jaxdepth._src.config import SGMConfig as SGMConfig
    from jaxdepth._src.types import Camera as Camera, LidarSpec as LidarSpec, Stages as Stages
    from jaxdepth._src.presets import (KITTI_HDL64 as KITTI_HDL64, NUSCENES_HDL32 as NUSCENES_HDL32,
                                       KITTI_T_CAM2_LIDAR as KITTI_T_CAM2_LIDAR, KITTI_K_CAM2 as KITTI_K_CAM2,
                                       KITTI_T_CAM3_LIDAR as KITTI_T_CAM3_LIDAR)
    from jaxdepth._src.geometry import project_to_image as project_to_image, unproject_depth as unproject_depth
    from jaxdepth._src.range_image import range_image as range_image
    from jaxdepth._src.normals import point_normals as point_normals, range_image_normals as range_image_normals
    from jaxdepth._src.outliers import outlier_keep_mask as outlier_keep_mask
    from jaxdepth._src.distance import nearest_seed as nearest_seed, gather_at_seed as gather_at_seed
    from jaxdepth._src.geodesic import geodesic_seed as geodesic_seed
    from jaxdepth._src.residual import plane_residual as plane_residual
    from jaxdepth._src.hypotheses import column_hypotheses as column_hypotheses
    from jaxdepth._src.smoothing import gaussian_blur as gaussian_blur, gaussian_blur_traced as gaussian_blur_traced
    from jaxdepth._src.pipeline import (complete as complete, complete_stages as complete_stages,
                                        complete_points as complete_points,
                                        complete_points_stages as complete_points_stages)
    from jaxdepth._src.rig import (RigCameras as RigCameras, stack_cameras as stack_cameras,
                                   stack_images as stack_images, complete_rig as complete_rig,
                                   complete_rig_stages as complete_rig_stages)
    from jaxdepth._src.sources import (Sources as Sources, make_sources as make_sources,
                                       complete_sources as complete_sources,
                                       complete_sources_stages as complete_sources_stages,
                                       free_space_keep as free_space_keep)
    from jaxdepth._src.methods import complete_with as complete_with
    from jaxdepth._src.ip_basic import ip_basic as ip_basic
    from jaxdepth._src.metrics import (depth_metrics as depth_metrics, interpolate_background as interpolate_background,
                                       mean_metrics as mean_metrics, pair_errors as pair_errors)
    from jaxdepth.research.hidden import hidden_point_mask as hidden_point_mask, hidden_point_scores as hidden_point_scores
    from jaxdepth._src.colorize import (colorize_depth as colorize_depth, colorize_normals as colorize_normals,
                                       overlay_depth as overlay_depth, overlay_mask as overlay_mask,
                                       depth_preview as depth_preview)
    from jaxdepth._src.validity import (ray_elevation as ray_elevation, fov_mask as fov_mask,
                                       seed_distance as seed_distance, validity_mask as validity_mask,
                                       validity_and_distance as validity_and_distance)
    from jaxdepth._src.synthetic import make_street_scene as make_street_scene, SyntheticFrame as SyntheticFrame

# module -> public names it provides (loaded by __getattr__ on first access)
_LAZY = {
    'jaxdepth._src.config': ('SGMConfig',),
    'jaxdepth._src.types': ('Camera', 'LidarSpec', 'Stages'),
    'jaxdepth._src.presets': ('KITTI_HDL64', 'NUSCENES_HDL32', 'KITTI_T_CAM2_LIDAR', 'KITTI_T_CAM3_LIDAR',
                              'KITTI_K_CAM2'),
    'jaxdepth._src.geometry': ('project_to_image', 'unproject_depth'),
    'jaxdepth._src.range_image': ('range_image',),
    'jaxdepth._src.normals': ('point_normals', 'range_image_normals'),
    'jaxdepth._src.outliers': ('outlier_keep_mask',),
    'jaxdepth._src.distance': ('nearest_seed', 'gather_at_seed'),
    'jaxdepth._src.geodesic': ('geodesic_seed',),
    'jaxdepth._src.residual': ('plane_residual',),
    'jaxdepth._src.hypotheses': ('column_hypotheses',),
    'jaxdepth._src.smoothing': ('gaussian_blur', 'gaussian_blur_traced'),
    'jaxdepth._src.pipeline': ('complete', 'complete_stages', 'complete_points', 'complete_points_stages'),
    'jaxdepth._src.rig': ('RigCameras', 'stack_cameras', 'stack_images', 'complete_rig', 'complete_rig_stages'),
    'jaxdepth._src.sources': ('Sources', 'make_sources', 'complete_sources', 'complete_sources_stages',
                              'free_space_keep'),
    'jaxdepth._src.methods': ('complete_with',),
    'jaxdepth._src.ip_basic': ('ip_basic',),
    'jaxdepth._src.metrics': ('depth_metrics', 'interpolate_background', 'mean_metrics', 'pair_errors'),
    'jaxdepth.research.hidden': ('hidden_point_mask', 'hidden_point_scores'),
    'jaxdepth._src.colorize': ('colorize_depth', 'colorize_normals', 'overlay_depth', 'overlay_mask', 'depth_preview'),
    'jaxdepth._src.validity': ('ray_elevation', 'fov_mask', 'seed_distance', 'validity_mask', 'validity_and_distance'),
    'jaxdepth._src.synthetic': ('make_street_scene', 'SyntheticFrame'),
}
_MODULE_OF = {name: module for module, names in _LAZY.items() for name in names}


def __getattr__(name):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module 'jaxdepth' has no attribute {name!r}")
    import importlib
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_MODULE_OF))


#: The public names: exactly the names of ``_LAZY`` (the TYPE_CHECKING block above lists the same
#: imports for type checkers; tests/test_layers.py checks the two agree).
__all__ = [name for names in _LAZY.values() for name in names]
