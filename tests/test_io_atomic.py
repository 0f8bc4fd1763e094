"""Atomic writes: a finished file or nothing, under injected failures."""

from __future__ import annotations

import errno
import os
import pathlib

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxdepth.io import OutputError, atomic_write_bytes, atomic_write_png, encode_png


def _leftovers(folder: pathlib.Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def test_write_new_file_and_contents(tmp_path):
    target = tmp_path / "a.bin"
    out = atomic_write_bytes(target, b"hello")
    assert out == target
    assert target.read_bytes() == b"hello"
    assert _leftovers(tmp_path) == []


@settings(deadline=None, max_examples=25)
@given(data=st.binary(max_size=4096), old=st.binary(max_size=64))
def test_round_trip_random_bytes(tmp_path_factory, data, old):
    folder = tmp_path_factory.mktemp("rt")
    target = folder / "x.dat"
    target.write_bytes(old)
    atomic_write_bytes(target, data)
    assert target.read_bytes() == data
    assert _leftovers(folder) == []


def test_accepts_bytearray_and_memoryview(tmp_path):
    atomic_write_bytes(tmp_path / "a", bytearray(b"xy"))
    atomic_write_bytes(tmp_path / "b", memoryview(np.arange(3, dtype=np.uint16)))
    assert (tmp_path / "a").read_bytes() == b"xy"
    assert (tmp_path / "b").read_bytes() == np.arange(3, dtype=np.uint16).tobytes()


def test_new_file_gets_umask_permissions(tmp_path):
    umask = os.umask(0o022)
    os.umask(umask)
    target = tmp_path / "p.bin"
    atomic_write_bytes(target, b"x")
    assert (target.stat().st_mode & 0o777) == (0o666 & ~umask)


def test_overwrite_false_keeps_existing(tmp_path):
    target = tmp_path / "a.bin"
    target.write_bytes(b"old")
    with pytest.raises(OutputError, match=r"a\.bin: already exists.*overwrite"):
        atomic_write_bytes(target, b"new", overwrite=False)
    assert target.read_bytes() == b"old"
    assert _leftovers(tmp_path) == []
    atomic_write_bytes(tmp_path / "b.bin", b"new", overwrite=False)
    assert (tmp_path / "b.bin").read_bytes() == b"new"


def test_overwrite_false_race_is_detected_by_link(tmp_path, monkeypatch):
    """Another writer creates the target between the check and the rename: not clobbered."""
    target = tmp_path / "a.bin"
    real_fsync = os.fsync

    def fsync_then_race(fd):
        real_fsync(fd)
        if not target.exists():
            target.write_bytes(b"other writer")

    monkeypatch.setattr(os, "fsync", fsync_then_race)
    with pytest.raises(OutputError, match="already exists"):
        atomic_write_bytes(target, b"mine", overwrite=False)
    assert target.read_bytes() == b"other writer"
    assert _leftovers(tmp_path) == []


def test_missing_folder(tmp_path):
    with pytest.raises(OutputError, match=r"nope.*output folder .* does not exist"):
        atomic_write_bytes(tmp_path / "nope" / "a.bin", b"x")


def test_target_is_folder(tmp_path):
    (tmp_path / "d").mkdir()
    with pytest.raises(OutputError, match=r"d: is a folder"):
        atomic_write_bytes(tmp_path / "d", b"x")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root ignores folder permissions")
def test_read_only_folder(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(OutputError, match=r"ro/a\.bin: cannot write: permission denied"):
            atomic_write_bytes(folder / "a.bin", b"x")
    finally:
        folder.chmod(0o700)


def test_permission_denied_on_create(tmp_path, monkeypatch):
    """Same as the read-only folder, simulated (works as root too)."""
    real_open = os.open

    def deny(path, flags, mode=0o777, **kw):
        if flags & os.O_CREAT:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, flags, mode, **kw)

    monkeypatch.setattr(os, "open", deny)
    with pytest.raises(OutputError, match=r"a\.bin: cannot write: permission denied"):
        atomic_write_bytes(tmp_path / "a.bin", b"x")
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("existing", [None, b"previous contents"])
def test_disk_full_leaves_nothing(tmp_path, monkeypatch, existing):
    target = tmp_path / "depth.png"
    if existing is not None:
        target.write_bytes(existing)
    real_write = os.write
    calls = []

    def write_some_then_fail(fd, data):
        calls.append(len(data))
        if len(calls) == 1:  # a short first write, as a nearly full disk does
            return real_write(fd, bytes(data[:10]))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "write", write_some_then_fail)
    with pytest.raises(OutputError, match=r"depth\.png: cannot write: no space left on device") as info:
        atomic_write_bytes(target, b"x" * 1000)
    monkeypatch.undo()
    assert isinstance(info.value.__cause__, OSError) and info.value.__cause__.errno == errno.ENOSPC
    assert len(calls) == 2, "the short write must be continued, not treated as complete"
    assert _leftovers(tmp_path) == []
    if existing is None:
        assert not target.exists()
    else:
        assert target.read_bytes() == existing


def test_short_writes_are_completed(tmp_path, monkeypatch):
    real_write = os.write
    monkeypatch.setattr(os, "write", lambda fd, data: real_write(fd, bytes(data[:7])))
    payload = bytes(range(256)) * 5
    atomic_write_bytes(tmp_path / "a", payload)
    monkeypatch.undo()
    assert (tmp_path / "a").read_bytes() == payload


@pytest.mark.parametrize("where", ["write", "fsync", "replace"])
@pytest.mark.parametrize("exc", [KeyboardInterrupt(), OSError(errno.EIO, "I/O error")])
def test_failure_at_each_step_cleans_up(tmp_path, monkeypatch, where, exc):
    target = tmp_path / "a.bin"
    target.write_bytes(b"old")

    def boom(*args, **kwargs):
        raise exc

    monkeypatch.setattr(os, where, boom)
    expected = KeyboardInterrupt if isinstance(exc, KeyboardInterrupt) else OutputError
    with pytest.raises(expected):
        atomic_write_bytes(target, b"new contents")
    monkeypatch.undo()
    assert target.read_bytes() == b"old"
    assert _leftovers(tmp_path) == []


def test_png_matches_cv2_and_is_deterministic(tmp_path):
    rng = np.random.default_rng(0)
    for array in (rng.integers(0, 65536, (7, 5), dtype=np.uint16),
                  rng.integers(0, 256, (4, 6, 3), dtype=np.uint8)):
        path = tmp_path / "img.png"
        atomic_write_png(path, array)
        np.testing.assert_array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), array)
        assert path.read_bytes() == encode_png(array) == encode_png(array.copy())


def test_png_rejects_bad_arrays_and_suffix(tmp_path):
    with pytest.raises(ValueError, match=r"'array' expected dtype uint8 or uint16, got float32"):
        atomic_write_png(tmp_path / "a.png", np.zeros((2, 2), np.float32))
    with pytest.raises(ValueError, match=r"'array' expected shape"):
        atomic_write_png(tmp_path / "a.png", np.zeros((2, 2, 2), np.uint8))
    with pytest.raises(OutputError, match=r"a\.jpg: expected a file name ending in \.png"):
        atomic_write_png(tmp_path / "a.jpg", np.zeros((2, 2), np.uint8))
    assert list(tmp_path.iterdir()) == []


def test_no_fd_leak_on_failure(tmp_path, monkeypatch):
    closed = []
    real_close = os.close

    def tracking_close(fd):
        closed.append(fd)
        real_close(fd)

    monkeypatch.setattr(os, "close", tracking_close)
    monkeypatch.setattr(os, "fsync", lambda fd: (_ for _ in ()).throw(OSError(errno.EIO, "I/O error")))
    with pytest.raises(OutputError):
        atomic_write_bytes(tmp_path / "a.bin", b"x")
    assert len(closed) == 1
