"""One compiled program for a whole ``--sweeps`` job: frames with fewer sources spread over the job's sweep window.

:func:`jaxdepth.batch.sources_job.fit_to_window` places a frame's sources (a drive's or a scene's first
frames hold fewer neighbouring sweeps) into the slots of the full window, empty sources in the rest.
Oracles: the placement rule worked by hand (reference, end and inner sweeps of the free-space test, order
kept), and the frame's own program (``complete_cloud`` without a window): bit-identical depth. Compiles are
counted through ``jax.monitoring``'s backend-compile event.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from jaxdepth._src.sources import make_sources
from jaxdepth._src.synthetic_sequences import make_street_sequence
from jaxdepth._src.types import LidarSpec, SourceCloud
from jaxdepth.batch.kitti_sweeps_job import window as kitti_window
from jaxdepth.batch.sources_job import complete_cloud, fit_to_window
from jaxdepth.io.rig import Rig, RigCamera

SPEC = LidarSpec(beams=16, fov_up_deg=10.0, fov_down_deg=-20.0, columns=256)


def _tiny(sweep):
    """Sources of 8 points each, source i's points all equal to i + 1 (to see where each went)."""
    s = len(sweep)
    points = np.repeat(np.arange(1, s + 1, dtype=np.float32)[:, None, None], 8, axis=1) * np.ones(3, np.float32)
    T = np.tile(np.eye(4, dtype=np.float32), (s, 1, 1))
    T[:, 0, 3] = np.arange(s) + 0.5
    return make_sources(points, np.ones((s, 8), bool), T, lidars=(SPEC,) * s, sweep=sweep)


def _slots(fitted, s):
    """Slot of each of the ``s`` original sources (by its points' value), -1 for none."""
    sources, index = fitted
    pts = np.asarray(sources.points)[:, 0, 0]
    valid = np.asarray(sources.valid).any(axis=1)
    return [int(np.flatnonzero(valid & (pts == i + 1))[0]) for i in range(s)]


def test_kitti_window_is_the_drive_clouds_order():
    assert kitti_window(1) == (0, -1, 1)
    assert kitti_window(2) == (0, -1, 1, -2, 2)


@pytest.mark.parametrize("window, sweep, want", [
    ((0, -1, 1, -2, 2), (0, 1, 2), [0, 3, 4]),           # drive start: both neighbours are the ends
    ((0, -1, 1, -2, 2), (0, -1, 1, -2), [0, 1, 3, 4]),   # one short at the end: -1 inner, 1 and -2 the ends
    ((0, -1, 1, -2, 2), (0, -1, -2), [0, 3, 4]),         # drive end
    ((0, -1, 1), (0, 1), [0, 1]),                        # -1 and 1 are both ends of this window
    ((0, -1, -2, -3), (0, -1, -2), [0, 1, 3]),           # nuScenes: a scene's third sample, two earlier sweeps
    ((0, -1, -2, -3), (0,), [0]),                        # a scene's first sample
    ((0, -1, -2, -3), (0, -1, -2, -3), [0, 1, 2, 3]),
])
def test_fit_to_window_keeps_each_sources_part_and_order(window, sweep, want):
    src = _tiny(sweep)
    index = np.arange(len(sweep) * 8, dtype=np.int64).reshape(len(sweep), 8)
    fitted = fit_to_window(src, index, window)
    got, got_index = fitted
    assert got.sweep == window and got.count == len(window) and got.lidars == (SPEC,) * len(window)
    assert _slots(fitted, len(sweep)) == want
    empty = [k for k in range(len(window)) if k not in want]
    T = np.asarray(got.T_ref_source)
    for i, k in enumerate(want):        # each source's points, validity, pose and cloud rows moved as a whole
        np.testing.assert_array_equal(np.asarray(got.points)[k], np.asarray(src.points)[i])
        np.testing.assert_array_equal(T[k], np.asarray(src.T_ref_source)[i])
        np.testing.assert_array_equal(got_index[k], index[i])
    assert not np.asarray(got.valid)[empty].any() and (got_index[empty] == -1).all()
    np.testing.assert_array_equal(T[empty], np.broadcast_to(np.eye(4), (len(empty), 4, 4)))


@pytest.mark.parametrize("window, sweep", [
    ((0, -1, 1, -2, 2), (0, -1, 1, 2)),    # its end -1 comes before its inner 1: no slot order fits
    ((0, -1, 1), (0, -1, 1, -2)),          # more sources than slots
])
def test_fit_to_window_refuses_what_does_not_fit(window, sweep):
    src = _tiny(sweep)
    assert fit_to_window(src, np.zeros((len(sweep), 8), np.int64), window) is None


def test_fit_to_window_refuses_mixed_specs():
    src = _tiny((0, -1))
    other = make_sources(src.points, src.valid, src.T_ref_source, sweep=(0, -1),
                         lidars=(SPEC, dataclasses.replace(SPEC, beams=8)))
    assert fit_to_window(other, np.zeros((2, 8), np.int64), (0, -1, -2)) is None


def _subset(sq, keep: int, drop_every: int = 0) -> SourceCloud:
    """The first ``keep`` sweeps (0, -1, ...) of a one-LiDAR sequence; ``drop_every``: drop every n-th point
    (another point count, the same bucket)."""
    mine = sq.source < keep
    if drop_every:
        mine &= np.arange(sq.source.size) % drop_every != 0
    return SourceCloud(points=sq.points[mine], source=sq.source[mine], T_ref_source=sq.T_ref_source[:keep],
                       lidars=tuple(sq.lidars[:keep]), sweep=sq.sweep[:keep], names=tuple(sq.names[:keep]))


_COMPILES = []


def _on_compile(event, secs, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration" and "_program" in str(kwargs.get("fun_name", "")):
        _COMPILES.append(kwargs.get("fun_name"))


jax.monitoring.register_event_duration_secs_listener(_on_compile)


@pytest.mark.slow  # three small whole-pipeline programs: the window's, and the two- and one-sweep frames' own
@pytest.mark.production_flags  # bit for bit at the production codegen; at the suite's level 0 the one-source rig's tail (nusc14: no window, the seed search's scalar masks) rounds Step 4's blur 1 ulp apart from the sources path's
def test_frames_of_fewer_sweeps_run_the_windows_program_with_the_same_bytes():
    sq = make_street_sequence(1, sweeps=3, lidars=1, image_scale=0.125, noise_std_m=0.0)
    cam = sq.camera
    rig = Rig(lidar=sq.lidars[0], cameras=(RigCamera("cam", cam.width, cam.height, np.asarray(cam.K),
                                                     np.asarray(cam.T_cam_lidar)),), lidar_origin_m=(0.0, 0.0, 0.0))
    window = (0, -1, -2)
    frames = [_subset(sq, 3), _subset(sq, 3, drop_every=7), _subset(sq, 2), _subset(sq, 1)]
    assert len({f.points.shape[0] for f in frames}) == 4          # four point counts, one bucket
    _COMPILES.clear()
    got = [complete_cloud(f, rig, window=window) for f in frames]
    windowed = list(_COMPILES)
    assert len(windowed) == 1, windowed                                # one program for every frame
    for frame, depth in zip(frames, got):
        want = complete_cloud(frame, rig)                              # the frame's own program
        assert (want > 0).mean() > 0.3
        np.testing.assert_array_equal(depth, want)
    assert len(_COMPILES) == 3, _COMPILES    # without the window the 2- and 1-sweep frames compiled their own
