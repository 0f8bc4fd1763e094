"""Points from several origins: the host-side container every multi-source reader fills.

A *source* is one LiDAR of a rig in one sweep. Readers of merged rigs (Argoverse 2's two
VLP-32C), of accumulated sweeps (KITTI raw drives with OXTS poses, nuScenes sweeps) and of
the rig JSON's ``lidars`` / the sweeps JSON all return a :class:`SourceCloud`; the core
(:mod:`jaxdepth._src`) turns it into fixed-shape arrays and runs Steps 1 and 2 per source.

Frames. Every point is in the *reference frame*: the points' frame of the reference sweep
(the frame the rig's ``T_cam_lidar`` maps from). ``T_ref_source[s]`` is the pose of source
``s``'s LiDAR in that frame: its translation is where that LiDAR sat when it measured the
points of source ``s``, its rotation the LiDAR's own axes (its z axis is the spin axis).
So ``p_source = inv(T_ref_source[s]) @ p_ref`` puts a point back in its own LiDAR's frame.
"""

from __future__ import annotations

# The container is defined once, in the core (the synthetic drives fill it too).
from jaxdepth._src.types import POSE_RIGID_TOL, SourceCloud, rigid_pose_problem  # noqa: E402,F401

__all__ = ["SourceCloud", "rigid_pose_problem", "POSE_RIGID_TOL"]
