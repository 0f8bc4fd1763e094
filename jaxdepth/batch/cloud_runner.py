"""Run multi-source completions (one :class:`~jaxdepth.io.sources.SourceCloud` + rig per frame) over many frames.

The shared loop of the dataset jobs that complete several sources at once (Argoverse 2
logs, KITTI raw drives with ``--sweeps``): a reader thread pool loads frames ahead (each
job's ``load`` returns the frame's cloud and rig), :func:`complete_sources` completes every
camera of the rig, and writer threads write one KITTI depth PNG per camera, atomically. A
frame that cannot be read or completed is reported and the rest carries on; a frame is
recorded done once all its PNGs are in place.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import pathlib
from typing import Callable

import numpy as np

#: Frames loaded ahead of the device.
READ_AHEAD = 2


@dataclasses.dataclass(frozen=True)
class CloudJob:
    """One frame: its name (progress, failures), ``outputs`` ((camera name, PNG path), ...) still to write,
    and ``source``: whatever the job's loader needs to read the frame."""

    name: str
    outputs: tuple
    source: object


def complete_sources(cloud, rig, *, config, images=None, window: tuple | None = None) -> np.ndarray:
    """(C, H, W) float32 depth of every camera of ``rig`` (on the largest camera's canvas) from a SourceCloud.

    The one completion call of the multi-source jobs:
    :func:`jaxdepth.batch.sources_job.complete_cloud` with free space on (range image, normals and
    Algorithm 1's viewpoint per source; other sweeps' points in the reference sweep's free space
    removed). ``images``: (C, H, W[, 3]) uint8 camera images on the canvas for image-guided seeds
    (``config.guidance_weight > 0``), else None. ``window``: the sweep numbers of a frame with all its
    neighbours, so that frames with fewer share its compiled program
    (:func:`jaxdepth.batch.sources_job.fit_to_window`).
    """
    from jaxdepth.batch.sources_job import complete_cloud

    return complete_cloud(cloud, rig, config=config, free_space=True, images=images, window=window)


def run_cloud_jobs(todo, load: Callable, summary, notify, *, config, png_compression: int,
                   io_threads: int = 2, complete: Callable | None = None, extras=None,
                   overwrite: bool = True) -> None:
    """Completes ``todo`` (:class:`CloudJob` s, output folders existing) into their PNGs.

    ``load(job) -> (SourceCloud, Rig)``; every output's camera name must be a camera of the rig.
    ``complete(cloud, rig) -> (depth, valid, distance)``, each (C, H, W) on the rig's canvas
    (``valid`` and ``distance`` None unless ``extras`` needs them); default: :func:`complete_sources`.
    ``extras``: :class:`jaxdepth.batch.extras.ExtraOutputs` written beside each PNG (default none);
    ``overwrite``: replace files that exist (default True: the jobs list only outputs to write).
    Records each job in ``summary`` as done or failed (never raises for a bad frame).
    """
    from jaxdepth.batch import extras as extra_outputs
    from jaxdepth.batch.runner import Ledger, read_ahead, write_failure
    from jaxdepth.io.errors import JaxdepthError

    ledger = Ledger(summary, notify)
    extras = extra_outputs.NONE if extras is None else extras
    if complete is None:
        def complete(cloud, rig):
            return complete_sources(cloud, rig, config=config), None, None

    def write(job, rig, depth, valid, distance):
        index = {c.name: i for i, c in enumerate(rig.cameras)}
        for camera, path in job.outputs:
            cam = rig.cameras[index[camera]]
            window = (index[camera], slice(0, cam.height), slice(0, cam.width))
            message = write_failure(path, lambda path=path, window=window: extra_outputs.write_outputs(
                pathlib.Path(path), depth[window], extras=extras, overwrite=overwrite,
                valid=None if valid is None else valid[window],
                distance=None if distance is None else distance[window], compression=png_compression))
            if message is not None:
                ledger.fail(job.name, message)
                return
        ledger.done(job.name)

    with cf.ThreadPoolExecutor(io_threads) as readers, cf.ThreadPoolExecutor(io_threads) as writers:
        written = []
        for job, (loaded, message) in read_ahead(todo, readers, window=READ_AHEAD, load=load,
                                                 os_error=lambda job, err: f"cannot read: {err}"):
            if message is not None:
                ledger.fail(job.name, message)
                continue
            cloud, rig = loaded
            try:
                outputs = complete(cloud, rig)
            except (JaxdepthError, ValueError) as err:
                ledger.fail(job.name, f"completion failed: {err}")
                continue
            written.append(writers.submit(write, job, rig, *outputs))
        for f in written:
            f.result()


__all__ = ["CloudJob", "complete_sources", "run_cloud_jobs"]
