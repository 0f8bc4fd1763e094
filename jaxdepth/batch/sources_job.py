"""Complete a :class:`~jaxdepth.io.sources.SourceCloud` (several LiDARs x sweeps) for a rig's cameras.

The entry point the dataset jobs (Argoverse 2, KITTI raw ``--sweeps``, nuScenes sweeps) and
``complete-rig`` with ``lidars`` / a sweeps JSON call: :func:`complete_cloud`. Host side it
fills in each source's :class:`~jaxdepth.LidarSpec` (the stated one, else an estimate from the
source's own points and rings, its field of view on a 0.25 degree grid, else the rig's), pads every
source to one power-of-two point bucket (so that one compiled program serves every sweep of a LiDAR
model: a VLP-32C's 57,600-cell sweeps all pad to 65,536) and hands
a :class:`~jaxdepth._src.sources.Sources` pytree to the core
(:func:`~jaxdepth._src.sources.complete_sources`).
"""

from __future__ import annotations

import logging

import numpy as np

from jaxdepth._src.config import DEFAULT_CONFIG, SGMConfig
from jaxdepth._src.types import LidarSpec
from jaxdepth.io.sweep_frame import source_spec

log = logging.getLogger("jaxdepth")

#: The smallest padded source: sources are padded to ``max(POINT_BUCKET, bucket_size(largest source))``,
#: a power of two (one compilation per bucket; padding slots are invalid and leave every output unchanged).
POINT_BUCKET = 8192


def cloud_sources(cloud, *, fallback: LidarSpec, bucket: int = POINT_BUCKET):
    """The :class:`~jaxdepth._src.sources.Sources` pytree of a SourceCloud: each source padded to one bucket,
    the power of two (:func:`jaxdepth.io.bucket_size`) that holds the largest source, at least ``bucket``.

    Returns:
      (sources, index): ``index`` (S, P) int64, the cloud row of each padded slot (-1 for padding).
    """
    from jaxdepth._src.sources import make_sources
    from jaxdepth.io import bucket_size
    S = cloud.num_sources
    counts = np.bincount(cloud.source, minlength=S)
    P = max(int(bucket), bucket_size(int(counts.max())))
    points = np.zeros((S, P, 3), np.float32)
    valid = np.zeros((S, P), bool)
    index = np.full((S, P), -1, np.int64)
    rows = np.full((S, P), -1, np.int32)
    specs = []
    for s in range(S):
        mine = np.nonzero(cloud.source == s)[0]
        points[s, :mine.size] = cloud.points[mine]
        valid[s, :mine.size] = np.all(np.isfinite(cloud.points[mine]), axis=1)
        index[s, :mine.size] = mine
        spec, rank = source_spec(cloud, s, fallback)
        specs.append(spec)
        if rank is not None:
            rows[s, :mine.size] = rank
    sources = make_sources(points, valid, cloud.T_ref_source.astype(np.float32), lidars=tuple(specs),
                           sweep=tuple(int(x) for x in cloud.sweep), rows=rows if np.any(rows >= 0) else None)
    return sources, index


def _single_origin(cloud) -> bool:
    return cloud.num_sources == 1 and np.allclose(cloud.T_ref_source[0], np.eye(4), atol=1e-9)


def complete_cloud(cloud, rig, *, config: SGMConfig = DEFAULT_CONFIG, free_space: bool = True, images=None,
                   beams: int | None = None, stages: bool = False, neighbour_sweeps="default", occlusion: bool = True):
    """Dense depth for every camera of ``rig`` from every point of ``cloud``.

    Args:
      cloud: :class:`~jaxdepth.io.sources.SourceCloud`, points in the reference frame.
      rig: :class:`~jaxdepth.io.rig.Rig`; ``rig.cameras[i].T_cam_lidar`` maps reference-frame
        points into camera ``i``; ``rig.lidar`` is the fallback spec of sources whose spec is
        neither given nor estimable (and gives the range-image columns of estimated ones).
      config: :class:`SGMConfig`.
      free_space: remove other sweeps' points that lie in space another sweep's LiDARs saw empty.
      images: optional (C, H_max, W_max[, 3]) camera images on the rig's canvas
        (:func:`~jaxdepth.stack_images`), used only when ``config.guidance_weight > 0``.
      beams: L of Step 2's window bounds; default: the reference sweep's LiDARs' beams together.
      stages: return the :class:`~jaxdepth.Stages` (C leading axis) instead of the depth.
      neighbour_sweeps: sweeps on each side whose points a non-reference sweep's LiDARs judge for
        free space (None: every sweep); "default": ``config.free_space_neighbour_sweeps`` (the other
        free-space and occlusion constants are ``config`` fields too).
      occlusion: with ``free_space``, also remove for each camera the other sweeps' points hidden
        from the reference-sweep LiDAR next to it (see :func:`~jaxdepth._src.sources.reference_view`).

    Returns:
      (C, H_max, W_max) float32 NumPy depth, metres, 0 = no depth: camera ``i``'s image in the
      top-left ``rig.cameras[i].height x width`` corner of the canvas, zeros beyond (one array,
      as :func:`~jaxdepth.complete_rig`). A cloud of one source at the reference origin gives
      exactly :func:`~jaxdepth.complete_rig`'s result (with the rig's LiDAR spec).
    """
    import jaxdepth
    from jaxdepth._src.sources import complete_sources_stages
    if neighbour_sweeps != "default":
        config = config.replace(free_space_neighbour_sweeps=neighbour_sweeps)
    cameras = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras])
    if _single_origin(cloud):
        from jaxdepth.io import pad_points
        padded, valid = pad_points(cloud.points)
        spec = cloud.lidars[0] if cloud.lidars[0] is not None else rig.lidar
        out = jaxdepth.complete_rig_stages(padded, valid, cameras, config=config, lidar=spec, images=images)
    else:
        sources, _ = cloud_sources(cloud, fallback=rig.lidar)
        out = complete_sources_stages(sources, cameras, config=config, free_space=free_space, beams=beams,
                                      images=images, occlusion=occlusion)
    return out if stages else np.asarray(out.depth)


def checked_cloud(cloud, rig, config: SGMConfig = DEFAULT_CONFIG, *, estimate: bool = True):
    """The sweep check of a cloud read from a rig JSON (``complete-rig``, ``hidden-eval``): ``(frame, config)``.

    ``frame``: :func:`jaxdepth.io.sweep_frame.prepare_cloud`'s :class:`~jaxdepth.io.sweep_frame.CloudFrame`
    (complete ``frame.cloud`` with ``frame.rig``); ``config`` with outlier removal off when the check
    does not trust it, as the single-file path (:func:`jaxdepth.io.prepare_sweep`) decides.
    """
    from jaxdepth.io.sweep_frame import prepare_cloud
    frame = prepare_cloud(cloud, rig, estimate=estimate)
    if not frame.outlier_removal_trusted and config.outlier_removal:
        config = config.replace(outlier_removal=False)
    return frame, config


__all__ = ["complete_cloud", "checked_cloud", "cloud_sources", "source_spec", "POINT_BUCKET"]
