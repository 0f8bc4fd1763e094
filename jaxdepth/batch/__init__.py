"""Offline jobs over whole datasets: the batched, resumable runner and what it needs around it.

* :mod:`~jaxdepth.batch.runner`: frame jobs (sparse PNGs or LiDAR sweeps) completed in
  compiled batches, one compile per image size and point bucket, I/O in threads, atomic writes,
  bad frames reported and skipped, finished outputs skipped on a re-run.
* :mod:`~jaxdepth.batch.scale`: the same jobs on a Ray cluster (optional extra ``ray``).
* :mod:`~jaxdepth.batch.nuscenes_job`: every sample of a nuScenes dataroot, all cameras at once.
* :mod:`~jaxdepth.batch.rig_job`: one sweep for every camera of a rig JSON (``jaxdepth complete-rig``).
* :mod:`~jaxdepth.batch.extras`: the optional outputs beside each depth PNG (preview, validity,
  seed distance).
* :mod:`~jaxdepth.batch.devices`: host devices, the persistent compile cache, JAX's start.

Importing this package does not import JAX.
"""
