"""The multi-source jobs' loop (jaxdepth.batch.cloud_runner.run_cloud_jobs): each frame's host work prepared on a
reader thread while the previous frame computes, frames completed in order; a bad frame at any step fails alone,
named; the same bytes as the serial loop."""

from __future__ import annotations

import collections
import threading

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth.batch.cloud_runner import CloudJob, run_cloud_jobs
from jaxdepth.batch.runner import RunSummary
from jaxdepth.io.depth_png import read_depth_png
from jaxdepth.io.errors import InputError

Camera = collections.namedtuple("Camera", "name height width")
Rig = collections.namedtuple("Rig", "cameras")
RIG = Rig((Camera("wide", 6, 9), Camera("tall", 9, 5)))     # two sizes on one (2, 9, 9) canvas


def _depth(i: int) -> np.ndarray:
    """(2, 9, 9) float32: frame ``i``'s depth, distinct per frame and camera (metres on the PNG's 1/256 grid)."""
    rows = np.arange(9, dtype=np.float32)[:, None] + np.arange(9, dtype=np.float32)[None, :]
    return np.stack([rows + 10 * i + 1, rows * 0.5 + 10 * i + 2]).astype(np.float32)


def _jobs(tmp_path, count: int) -> list:
    out = []
    for i in range(count):
        folder = tmp_path / f"f{i}"
        folder.mkdir()
        out.append(CloudJob(name=f"f{i}", outputs=tuple((c.name, folder / f"{c.name}.png") for c in RIG.cameras),
                            source=i))
    return out


def _run(jobs, **steps) -> RunSummary:
    summary = RunSummary()
    run_cloud_jobs(jobs, lambda job: (job.source, RIG), summary, lambda name, status: None, config=None,
                   png_compression=1, io_threads=2, **steps)
    return summary


def _check_outputs(jobs, good) -> None:
    for job in jobs:
        for k, (camera, path) in enumerate(job.outputs):
            if job.source not in good:
                assert not path.exists()
                continue
            cam = RIG.cameras[k]
            np.testing.assert_array_equal(read_depth_png(path), _depth(job.source)[k, :cam.height, :cam.width])


def test_the_next_frame_is_prepared_on_a_reader_while_this_one_computes(tmp_path):
    jobs = _jobs(tmp_path, 6)
    prepared = [threading.Event() for _ in range(7)]
    prepared[6].set()                                           # no frame after the last
    calls, threads = [], set()

    def prepare(cloud, rig):
        threads.add(threading.current_thread() is threading.main_thread())
        prepared[cloud].set()

        def call():                                             # waits for the next frame's host work
            calls.append((cloud, prepared[cloud + 1].wait(timeout=30)))
            return jnp.asarray(_depth(cloud)), None, None       # a device array: read back by the loop
        return call

    summary = _run(jobs, prepare=prepare)
    assert sorted(summary.done) == [j.name for j in jobs] and not summary.failed
    assert threads == {False}                                   # never on the main thread
    assert calls == [(i, True) for i in range(6)]               # in order, each beside the next one's host work
    _check_outputs(jobs, good=range(6))


class _Unreadable:
    """A program output whose read-back fails (as a failed computation's would)."""

    def __array__(self, dtype=None, copy=None):
        raise InputError("frame 2 broken at read-back")


@pytest.mark.parametrize("devices", [1, 2])
@pytest.mark.parametrize("step", ["load", "prepare", "call", "read-back"])
def test_a_bad_frame_in_the_middle_fails_alone_named_and_the_rest_is_written(tmp_path, step, devices):
    jobs = _jobs(tmp_path, 5)
    bad = 2

    def fail(where):
        raise InputError(f"frame {bad} broken at {where}")

    def load(job):
        if step == "load" and job.source == bad:
            fail("load")
        return job.source, RIG

    def prepare(cloud, rig):
        if step == "prepare" and cloud == bad:
            fail("prepare")

        def call():
            if step == "call" and cloud == bad:
                fail("call")
            unreadable = step == "read-back" and cloud == bad
            return (_Unreadable() if unreadable else jnp.asarray(_depth(cloud))), None, None
        return call

    summary = RunSummary()
    run_cloud_jobs(jobs, load, summary, lambda name, status: None, config=None, png_compression=1, prepare=prepare,
                   targets=jax.local_devices()[:1] * devices)   # 2: one device twice, two frames in flight
    assert sorted(summary.done) == ["f0", "f1", "f3", "f4"]
    prefix = "" if step == "load" else "completion failed: "
    assert summary.failed == [("f2", f"{prefix}frame 2 broken at {step}")]
    _check_outputs(jobs, good={0, 1, 3, 4})


def test_prepared_and_serial_loops_write_the_same_bytes(tmp_path):
    (tmp_path / "ahead").mkdir()
    (tmp_path / "serial").mkdir()
    ahead, serial = _jobs(tmp_path / "ahead", 4), _jobs(tmp_path / "serial", 4)
    _run(ahead, prepare=lambda cloud, rig: lambda: (jnp.asarray(_depth(cloud)), None, None))
    _run(serial, prepare=lambda cloud, rig: lambda: (_depth(cloud), None, None))   # all of it on the main thread
    for a, s in zip(ahead, serial):
        for (_, pa), (_, ps) in zip(a.outputs, s.outputs):
            assert pa.read_bytes() == ps.read_bytes()


class _Traced:
    """Frame ``i``'s depth as a program output whose read-back is recorded."""

    def __init__(self, i, events):
        self.i, self.events = i, events

    def __array__(self, dtype=None, copy=None):
        self.events.append(("read", self.i))
        return _depth(self.i)


def test_frames_dealt_to_two_devices_two_in_flight_the_first_written_before_the_second_device_compiles(tmp_path):
    """``targets`` of two devices (here the one device twice): frame k's call under ``jax.default_device`` of
    ``targets[k % 2]``, two frames in flight, each read back once the next is dispatched, except the first:
    read back before the second device's first call (its compile); the one-device loop's files."""
    events, devices = [], []
    device = jax.local_devices()[0]

    def prepare(cloud, rig):
        def call():
            events.append(("call", cloud))
            devices.append(jnp.zeros(()).devices())
            return _Traced(cloud, events), None, None
        return call

    (tmp_path / "two").mkdir()
    (tmp_path / "one").mkdir()
    two, one = _jobs(tmp_path / "two", 5), _jobs(tmp_path / "one", 5)
    summary = _run(two, prepare=prepare, targets=[device, device])
    assert sorted(summary.done) == [j.name for j in two] and not summary.failed
    assert events == [("call", 0), ("read", 0), ("call", 1), ("call", 2), ("read", 1), ("call", 3), ("read", 2),
                      ("call", 4), ("read", 3), ("read", 4)]
    assert devices == [{device}] * 5
    _run(one, prepare=lambda cloud, rig: lambda: (_depth(cloud), None, None))
    for a, b in zip(two, one):
        for (_, pa), (_, pb) in zip(a.outputs, b.outputs):
            assert pa.read_bytes() == pb.read_bytes()
