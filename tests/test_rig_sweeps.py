"""``complete-rig`` over several sweeps in one process, and ``jaxdepth warmup``.

Oracles: the sweep list against the files written (brute-force listing); the outputs of one
multi-sweep call against one single-sweep call per sweep (:func:`jaxdepth.batch.rig_job.run_rig_job`,
byte for byte); file modification times for resume; a persistent compile cache folder of the test's
own for the warm-up (the run after it adds no program of its own; rigs of several LiDARs and the
Argoverse 2 job: test_warmup_sources).
"""

from __future__ import annotations

import os
import pathlib

import numpy as np
import pytest

from jaxdepth import cli
from jaxdepth.batch import extras
from jaxdepth.io.errors import InputError
from jaxdepth.io.sweep_list import list_sweeps, sweep_stem

from helpers import WALL_CAMERAS, wall_sweep, warm_then_run, write_wall_rig


def _touch(*paths):
    for p in paths:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"")


def test_a_single_point_file_or_sweeps_json_keeps_todays_layout(tmp_path):
    _touch(tmp_path / "a.bin", tmp_path / "s.json")
    assert list_sweeps(tmp_path / "a.bin") is None
    assert list_sweeps(str(tmp_path / "s.json")) is None
    assert list_sweeps(tmp_path / "missing.bin") is None      # the reader names the missing file, as today


def test_folder_glob_and_list_file_name_the_sweeps(tmp_path):
    logs = tmp_path / "log"
    _touch(logs / "000002.bin", logs / "000001.pcd.bin", logs / "000003.npz", logs / "notes.json",
           logs / "sub" / "000009.bin", logs / "readme.md")
    folder = list_sweeps(logs)
    assert folder == sorted(p for p in logs.iterdir() if p.is_file() and p.suffix in (".bin", ".npz"))
    assert [sweep_stem(p) for p in folder] == ["000001", "000002", "000003"]
    assert list_sweeps(str(logs / "00000[12]*.bin")) == [logs / "000001.pcd.bin", logs / "000002.bin"]
    listing = tmp_path / "lists" / "sweeps.txt"
    listing.parent.mkdir()
    listing.write_text("# a log\n../log/000003.npz\n\n  ../log/sub/000009.bin  \n")
    expected = [listing.parent / "../log/000003.npz", listing.parent / "../log/sub/000009.bin"]
    assert list_sweeps(listing) == expected
    other = tmp_path / "lists" / "sweeps.lst"
    other.write_text(listing.read_text())
    assert list_sweeps("@" + str(other)) == expected


@pytest.mark.parametrize("make, match", [
    (lambda d: (d / "empty").mkdir(), "no sweep in this folder"),
    (lambda d: None, "no sweep file matches"),
    (lambda d: (d / "list.txt").write_text("# nothing\n"), "names no file"),
])
def test_empty_selections_are_refused_naming_the_argument(tmp_path, make, match):
    make(tmp_path)
    arg = {"no sweep in this folder": tmp_path / "empty", "no sweep file matches": tmp_path / "*.bin",
           "names no file": tmp_path / "list.txt"}[match]
    with pytest.raises(InputError, match=match) as err:
        list_sweeps(str(arg))
    assert str(arg).lstrip("@") in str(err.value)


def test_two_sweeps_with_one_stem_are_refused_naming_both(tmp_path, capsys):
    a, b = tmp_path / "a" / "000001.bin", tmp_path / "b" / "000001.pcd.bin"
    _touch(a, b)
    (tmp_path / "list.txt").write_text(f"{a}\n{b}\n")
    with pytest.raises(InputError) as err:
        list_sweeps(tmp_path / "list.txt")
    assert str(a) in str(err.value) and str(b) in str(err.value) and "'000001'" in str(err.value)
    rig = tmp_path / "rig.json"
    write_wall_rig(rig)
    assert cli.main(["complete-rig", str(tmp_path / "list.txt"), str(rig), str(tmp_path / "out")]) == 1
    assert str(b) in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_guided_seeds_take_one_sweep(tmp_path, capsys):
    _touch(tmp_path / "log" / "1.npy")
    rig = tmp_path / "rig.json"
    write_wall_rig(rig)
    code = cli.main(["complete-rig", str(tmp_path / "log"), str(rig), str(tmp_path / "out"), "--guidance-weight", "1"])
    assert code == 2 and "one sweep per call" in capsys.readouterr().err


def _sweeps(folder: pathlib.Path) -> list[pathlib.Path]:
    folder.mkdir()
    wall_sweep(folder / "000001.npy")
    wall_sweep(folder / "000002.npy", up_deg=4.0, down_deg=-9.0)    # same point count: one program
    wall_sweep(folder / "000003.npy", up_deg=3.0, down_deg=-8.0)
    return sorted(folder.iterdir())


@pytest.mark.slow  # a job run: the wall rig's program, shared with test_extras_cli (docs/testing.md)
def test_sweeps_in_one_call_equal_single_calls_a_bad_one_is_skipped_and_a_rerun_resumes(tmp_path, capsys):
    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch.rig_job import run_rig_job

    rig = tmp_path / "rig.json"
    write_wall_rig(rig)
    good = _sweeps(tmp_path / "log")
    bad = tmp_path / "log" / "000004.npy"
    bad.write_bytes(b"not an array")
    out = tmp_path / "out"
    args = ["complete-rig", str(tmp_path / "log"), str(rig), str(out), "--no-estimate"]
    assert cli.main(args) == 1
    err = capsys.readouterr().err
    assert f"FAILED {bad}: {bad}: not a readable .npy array" in err
    assert "3 completed, 0 skipped (already done), 1 failed" in err
    assert "compiles another program" not in err                         # one bucket, one LiDAR spec
    assert not (out / "000004").exists()
    for sweep in good:
        single = tmp_path / f"single_{sweep.stem}"
        run_rig_job(sweep, rig, single, config=SGMConfig(), extras=extras.NONE, estimate=False)
        for name in WALL_CAMERAS:
            assert (out / sweep.stem / f"{name}.png").read_bytes() == (single / f"{name}.png").read_bytes()
    assert len({(out / s.stem / "CAM_A.png").read_bytes() for s in good}) == 3   # three different sweeps
    # Resume: the finished sweeps are skipped unread, the bad one fails again, then its fixed file completes.
    mtimes = {p: p.stat().st_mtime_ns for p in out.rglob("*.png")}
    assert cli.main(args) == 1
    assert "0 completed, 3 skipped (already done), 1 failed" in capsys.readouterr().err
    wall_sweep(bad, up_deg=2.0, down_deg=-7.0)
    assert cli.main(args + ["-q"]) == 0
    assert {p: p.stat().st_mtime_ns for p in mtimes} == mtimes
    assert sorted(p.name for p in (out / "000004").iterdir()) == sorted(f"{n}.png" for n in WALL_CAMERAS)
    # A changed sweep is recomputed (per-output run record), the others are not.
    wall_sweep(good[0], up_deg=1.0, down_deg=-6.0)
    os.utime(good[0], ns=(1, 1))
    assert cli.main(args + ["-q"]) == 0
    changed = {p for p in mtimes if p.stat().st_mtime_ns != mtimes[p]}
    assert changed == {out / "000001" / f"{n}.png" for n in WALL_CAMERAS}


@pytest.mark.slow  # two subprocesses: the warm-up compiles the wall rig's program (docs/testing.md)
def test_warmup_stores_the_program_that_complete_rig_then_loads(tmp_path):
    rig = tmp_path / "rig.json"
    write_wall_rig(rig)
    sweep = tmp_path / "000001.npy"
    wall_sweep(sweep)
    warmed, added, warm = warm_then_run(tmp_path / "xla", [rig, "--points", "2560"],
                                          ["complete-rig", sweep, rig, tmp_path / "out", "--no-estimate", "-q"],
                                          program="jit_rig_depth_program")   # complete-rig without seed extras: depth alone
    assert "compiled for 4096 padded points" in warm.stdout
    assert "field of view is left open" not in warm.stderr                 # the wall rig states it
    assert warmed and not added
    assert np.count_nonzero(cv2_read(tmp_path / "out" / "CAM_A.png")) > 0


def cv2_read(path):
    import cv2
    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED)


def test_warmup_refuses_image_guided_seeds(tmp_path, capsys):
    rig = tmp_path / "rig.json"
    write_wall_rig(rig)
    assert cli.main(["warmup", str(rig), "--guidance-weight", "10"]) == 1
    assert "--guidance-weight" in capsys.readouterr().err
