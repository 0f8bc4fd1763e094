"""One frame of the KITTI jobs' batch programs: the full program's and the listed program's (issue 38).

:func:`jaxdepth.batch.runner.batched_completion` maps :func:`frame_function` over a batch. Its static
``listed_only`` chooses Step 1: the full program (``False``: ``pixel_normals`` with its dense fallback,
what :func:`jaxdepth.complete`, :func:`jaxdepth.complete_stages` and :func:`jaxdepth.complete_with`
trace) or the listed one (``True``: the fast path alone, one more output ``fits``;
:mod:`jaxdepth.batch.listed`). Both are one function, so that the listed program of a fitting frame
keeps the full program's bytes (docs/speed.md, "The cold first frame without the dense fallback").
"""

from __future__ import annotations

from typing import Callable

from jaxdepth._src.config import SGMConfig
from jaxdepth._src.types import LidarSpec


def frame_function(*, method: str, config: SGMConfig, lidar: LidarSpec, max_seed_distance_px=None,
                   listed_only: bool = False) -> Callable:
    """One frame's program: ``(depth (H, W), K (3, 3), T (4, 4)[, image]) -> outputs``.

    The outputs: the (H, W) depth, or with ``max_seed_distance_px`` (method "sgm") the depth,
    validity and seed distance (:func:`validity`); with ``listed_only`` (method "sgm") one more,
    the scalar bool ``fits`` (where False, the frame's outputs are not meaningful). The depth is
    :func:`jaxdepth.complete` of ``image`` when guided (``config.guidance_weight > 0``), else
    :func:`jaxdepth.complete_with` by ``method``; the extras read :func:`jaxdepth.complete_stages`.
    Without ``listed_only`` the function traces exactly those public functions; with it, their private
    entries with the flag (unguided without extras: ``_complete_stages``' depth, which is
    ``complete_with``'s "sgm" less its own clean-up of the input, which ``_complete_stages`` repeats).
    """
    from jaxdepth._src import pipeline
    from jaxdepth._src.methods import complete_with
    guided = config.guidance_weight > 0

    def one(depth, K, T, image=None):
        if max_seed_distance_px is None and guided:  # jaxdepth.complete(image=...)
            return pipeline._complete_depth(depth, K, T, image, config=config, lidar=lidar, listed_only=listed_only)
        if max_seed_distance_px is None and not listed_only:  # the baselines, and "sgm" (_complete_stages' depth)
            return complete_with(depth, K, T, method=method, config=config, lidar=lidar)
        out = pipeline._complete_stages(depth, K, T, image, config=config, lidar=lidar, listed_only=listed_only)
        stages, fits = out if listed_only else (out, None)
        outputs = (stages.depth,) if max_seed_distance_px is None else (stages.depth,) + validity(
            stages, K, T, config=config, lidar=lidar, max_seed_distance_px=max_seed_distance_px)
        return outputs + (fits,) if listed_only else outputs

    return one


def validity(stages, K, T, *, config: SGMConfig, lidar: LidarSpec, max_seed_distance_px) -> tuple:
    """(valid, seed distance), each (H, W), of a frame's Stages (:func:`jaxdepth._src.validity.validity_and_distance`);
    ``max_seed_distance_px`` pixels or ``"sensor"`` (the camera's own limit)."""
    from jaxdepth._src.validity import validity_and_distance
    limit = None if max_seed_distance_px == "sensor" else max_seed_distance_px
    return validity_and_distance(stages, K, T, lidar=lidar, metric=config.distance_metric,
                                 max_seed_distance_px=limit)
