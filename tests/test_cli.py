"""The command line: exit codes, one-line errors, resume, atomic outputs, demo."""

from __future__ import annotations

import ast
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from jaxdepth import cli
from jaxdepth.io import read_depth_png

from helpers import small_frames, write_kitti_folder


@pytest.fixture(scope="module")
def frames():
    return small_frames(3, seed=10)


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "jaxdepth.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=900)


@pytest.mark.slow  # subprocess
def test_help_version_and_usage_errors_do_not_import_jax():
    """Issue 14: the answers that need no computation come without JAX's ~0.6 s import. One process
    answers them all (``--help`` and ``--version`` with their text); ``python -m jaxdepth.cli`` runs
    the same ``main`` (its exit code is checked for a usage error)."""
    script = ("import contextlib, io, sys\n"
              "from jaxdepth import cli\n"
              "codes, texts = [], []\n"
              "for argv in (['--help'], ['--version'], [], ['complete'], ['complete', 'a', 'b', '--distance', 'l3'],\n"
              "             ['demo', '--help'], ['complete', '--help']):\n"
              "    out = io.StringIO()\n"
              "    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):\n"
              "        try:\n"
              "            codes.append(cli.main(argv))\n"
              "        except SystemExit as exit:\n"
              "            codes.append(exit.code)\n"
              "    texts.append(out.getvalue())\n"
              "print(repr(texts))\n"
              "print(codes, 'jax' in sys.modules, 'jaxlib' in sys.modules)\n")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    *_, texts, verdict = result.stdout.strip().splitlines()
    assert verdict == "[0, 0, 2, 2, 2, 0, 0] False False", result.stdout[-2000:]
    help_text, version = ast.literal_eval(texts)[:2]
    assert "complete" in help_text and "demo" in help_text
    assert version.startswith("jaxdepth ")
    assert run_cli("complete").returncode == 2  # argparse usage error, through python -m jaxdepth.cli


@pytest.mark.slow  # subprocess
@pytest.mark.parametrize("ray_loaded", [False, True])
def test_program_ends_without_interpreter_shutdown_unless_ray(tmp_path, ray_loaded):
    """The program (``main()`` without argv) ends by ``os._exit`` once its command returned: an ``atexit``
    handler does not run, the exit code and the buffered output are kept; with Ray loaded (a stand-in
    module) the interpreter's shutdown runs, so Ray's own ``atexit`` can stop its processes."""
    script = ("import atexit, sys\n"
              "atexit.register(lambda: print('atexit ran'))\n"
              f"if {ray_loaded}: sys.modules['ray'] = type(sys)('ray')\n"
              "print('before')\n"
              f"sys.argv = ['jaxdepth', 'complete', {str(tmp_path / 'missing')!r}, {str(tmp_path / 'out')!r}]\n"
              "from jaxdepth.cli import main\n"
              "sys.exit(main())\n")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                            env={**os.environ, "JAXDEPTH_COMPILE_CACHE": "0"})
    assert result.returncode == 1, result.stderr[-2000:]
    assert "input folder not found" in result.stderr
    assert result.stdout.splitlines() == (["before", "atexit ran"] if ray_loaded else ["before"])


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_complete_folder_resume_and_bad_frame(tmp_path, frames, capsys):
    items, T = frames
    src = write_kitti_folder(tmp_path / "src", items)
    (src / "velodyne_raw" / "frame_bad.png").write_bytes(b"not a png at all")
    (src / "intrinsics" / "frame_bad.txt").write_text("1 0 0 0 1 0 0 0 1\n")
    dst = tmp_path / "out"
    code = cli.main(["complete", str(src), str(dst), "--batch-size", "2", "--method", "nearest", "-q"])
    err = capsys.readouterr().err
    assert code == 1
    assert "FAILED frame_bad:" in err and "frame_bad.png" in err and "Traceback" not in err
    assert sorted(p.name for p in dst.iterdir()) == ["frame_000.png", "frame_001.png", "frame_002.png",
                                                     "jaxdepth_run.json"]  # the outputs and the run record
    stamps = {p.name: p.stat().st_mtime_ns for p in dst.iterdir()}
    code = cli.main(["complete", str(src), str(dst), "--batch-size", "2", "--method", "nearest"])
    err = capsys.readouterr().err
    assert code == 1 and "0 completed, 3 skipped" in err
    assert stamps == {p.name: p.stat().st_mtime_ns for p in dst.iterdir()}
    # nothing but finished PNGs and the run record in the output folder (no temp files)
    assert all(p.suffix == ".png" or p.name == "jaxdepth_run.json" for p in dst.iterdir())


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_complete_single_image_matches_library(tmp_path, frames):
    """A single PNG through the CLI (``--method`` and ``--no-outlier-removal`` reaching the run) equals
    the library's batch completion of that frame, the same bytes: ``complete_batch`` at the CLI's batch
    shape (one compiled program for both; ``tests/test_runner.py`` checks ``complete_batch`` against
    per-frame calls, SGM included). The nearest fill without outlier removal compiles in a fraction of
    SGM's time; the default configuration would differ (outliers removed)."""
    items, T = frames
    src = write_kitti_folder(tmp_path / "src", items[:1])
    out = tmp_path / "one.png"
    code = cli.main(["complete", str(src / "velodyne_raw" / "frame_000.png"), str(out),
                     "--intrinsics", str(src / "intrinsics" / "frame_000.txt"), "--method", "nearest",
                     "--no-outlier-removal", "-q"])
    assert code == 0
    import cv2

    from jaxdepth import SGMConfig
    from jaxdepth.batch.runner import complete_batch
    from jaxdepth.io import encode_depth_uint16, read_intrinsics_txt
    depth = read_depth_png(src / "velodyne_raw" / "frame_000.png")[None]
    K = read_intrinsics_txt(src / "intrinsics" / "frame_000.txt")[None]
    expected = complete_batch(depth, K, config=SGMConfig(outlier_removal=False), batch_size=1, strategy="map",
                              method="nearest")[0]
    np.testing.assert_array_equal(cv2.imread(str(out), cv2.IMREAD_UNCHANGED), encode_depth_uint16(expected))
    with_removal = complete_batch(depth, K, batch_size=1, strategy="map", method="nearest")[0]
    assert not np.array_equal(encode_depth_uint16(with_removal), encode_depth_uint16(expected))  # the option counted


@pytest.mark.parametrize("args,pattern", [
    (["complete", "/nonexistent/folder", "OUT"], "nonexistent"),
    (["complete", "/nonexistent/x.png", "OUT.png", "--intrinsics", "K.txt"], "x.png"),
    (["eval", "/nonexistent/pred", "/nonexistent/gt"], "nonexistent"),
])
def test_user_errors_are_one_line_without_traceback(args, pattern, capsys):
    code = cli.main(args)
    err = capsys.readouterr().err
    assert code == 1
    assert pattern in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_single_image_without_intrinsics_is_a_clear_error(tmp_path, frames, capsys):
    items, _ = frames
    src = write_kitti_folder(tmp_path / "src", items[:1])
    code = cli.main(["complete", str(src / "velodyne_raw" / "frame_000.png"), str(tmp_path / "o.png")])
    assert code == 1 and "--intrinsics" in capsys.readouterr().err


def test_unwritable_output_folder(tmp_path, frames, capsys):
    items, _ = frames
    src = write_kitti_folder(tmp_path / "src", items[:1])
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code = cli.main(["complete", str(src), str(blocker / "sub"), "-q"])
    err = capsys.readouterr().err
    assert code == 1 and str(blocker) in err and "Traceback" not in err


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_interrupt_leaves_no_partial_png_and_rerun_completes(tmp_path, frames, monkeypatch, capsys):
    items, T = frames
    src = write_kitti_folder(tmp_path / "src", items)
    dst = tmp_path / "out"
    from jaxdepth.io import atomic as atomic_mod
    real_replace = os.replace
    calls = {"n": 0}

    def interrupted_replace(a, b):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real_replace(a, b)

    monkeypatch.setattr(atomic_mod.os, "replace", interrupted_replace)
    code = cli.main(["complete", str(src), str(dst), "--batch-size", "2", "--method", "nearest", "-q"])
    monkeypatch.undo()
    assert code == 130
    names = sorted(p.name for p in dst.iterdir() if p.name != "jaxdepth_run.json")
    assert all(n.endswith(".png") and n.startswith("frame_") for n in names), names  # no temp file left
    for p in dst.glob("*.png"):
        read_depth_png(p)  # every file present is a complete PNG
    code = cli.main(["complete", str(src), str(dst), "--batch-size", "2", "--method", "nearest", "-q"])
    assert code == 0
    assert sorted(p.name for p in dst.glob("*.png")) == ["frame_000.png", "frame_001.png", "frame_002.png"]


@pytest.mark.slow  # a full-size (352 x 1216) synthetic frame, compiled for the SGM and the nearest fill
def test_demo_writes_outputs_and_scores(tmp_path, capsys):
    """``jaxdepth demo`` (in this process: the command, not the process, is under test; the CLI as a
    process is covered by the compile-cache and no-JAX-import tests)."""
    assert cli.main(["demo", "--out", str(tmp_path / "demo")]) == 0
    out = capsys.readouterr().out
    assert "RMSE" in out and "sgm" in out
    depth = read_depth_png(tmp_path / "demo" / "depth.png")
    assert depth.shape == (352, 1216) and np.all(depth > 0)
    for name in ("depth_preview.png", "sparse_preview.png"):
        assert (tmp_path / "demo" / name).stat().st_size > 1000
    # a warm run (every program already compiled in this process) says so, not "including compilation"
    assert cli.main(["demo", "--out", str(tmp_path / "demo")]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert "no compile" in last and "compiling" not in last, last


def _cache_files(folder: pathlib.Path) -> dict:
    return {p.name: p.stat().st_mtime_ns for p in folder.rglob("*-cache")} if folder.exists() else {}


@pytest.mark.slow  # subprocess
def test_compile_cache_is_reused_by_the_next_run_with_the_same_bytes(tmp_path, frames):
    """The CLI's compile cache: the first run stores the compiled completion, the next reads it back
    (no file written again), a run with ``--no-compile-cache`` writes no cache; all three write the
    same bytes. The cache holds whatever the run compiles: ``--method nearest`` compiles in a
    fraction of the SGM's time. The third run also is the verbose one (issue 14): JAX's
    "Unable to initialize backend 'tpu'" note never reaches the user, even with ``-v``."""
    items, _ = frames
    src = write_kitti_folder(tmp_path / "src", items[:1])
    png, K = src / "velodyne_raw" / "frame_000.png", src / "intrinsics" / "frame_000.txt"
    # as a user runs it: without the suite's own session cache (conftest) or its options, and with
    # JAX probing every backend (no JAX_PLATFORMS)
    env = {k: v for k, v in os.environ.items() if k not in ("JAXDEPTH_COMPILE_CACHE", "JAX_COMPILATION_CACHE_DIR",
                                                             "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS",
                                                             "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES",
                                                             "JAX_PLATFORMS")}

    # As after a plain `pip install jaxdepth`: without the optional `filelock`
    # package, which JAX needs for its own size cap.
    without_filelock = ("import runpy, sys; sys.modules['filelock'] = None; sys.argv[0] = 'jaxdepth'; "
                        "runpy.run_module('jaxdepth.cli', run_name='__main__')")

    def run(out, cache_home, *options, quiet=("-q",)):
        result = subprocess.run(
            [sys.executable, "-c", without_filelock, *options, "complete", str(png), str(out), "--intrinsics",
             str(K), "--method", "nearest", *quiet], env=dict(env, XDG_CACHE_HOME=str(cache_home)),
            capture_output=True, text=True, timeout=900)
        assert result.returncode == 0, result.stderr[-2000:]
        assert "cache" not in result.stderr, result.stderr[-2000:]
        assert "Unable to initialize backend" not in result.stderr, result.stderr[-2000:]
        return out.read_bytes(), result.stderr

    folder = tmp_path / "cache" / "jaxdepth" / "xla"
    first, _ = run(tmp_path / "first.png", tmp_path / "cache")
    stored = _cache_files(folder)
    assert stored, "the compiled completion was not stored"
    second, _ = run(tmp_path / "second.png", tmp_path / "cache")
    assert _cache_files(folder) == stored  # read back, not compiled and written again
    off, verbose = run(tmp_path / "off.png", tmp_path / "cache_off", "-v", "--no-compile-cache", quiet=())
    assert "1 completed" in verbose  # -v: the run's own messages do reach stderr
    assert not (tmp_path / "cache_off").exists()
    assert first == second == off


def test_compile_cache_trim_deletes_the_oldest_files_beyond_the_cap(tmp_path):
    from jaxdepth.batch.devices import trim_compile_cache

    sizes = {"a-cache": 300, "b-cache": 200, "c-cache": 400, "d-cache": 100, "e-cache": 250}
    written = {"a-cache": 5, "b-cache": 1, "c-cache": 3, "d-cache": 3, "e-cache": 9}  # c, d: same time
    for name, size in sizes.items():
        path = tmp_path / name
        path.write_bytes(b"x" * size)
        os.utime(path, ns=(written[name] * 10**9, written[name] * 10**9))
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "big").write_bytes(b"x" * 5000)  # folders are not entries

    def files():
        return sorted(p.name for p in tmp_path.iterdir() if p.is_file())

    # Oldest first: b (t=1), then c before d (t=3, by name), then a (t=5), e (t=9).
    assert trim_compile_cache(tmp_path, 1250) == 1250
    assert files() == sorted(sizes)
    assert trim_compile_cache(tmp_path, 1000) == 1250 - 200 - 400
    assert files() == ["a-cache", "d-cache", "e-cache"]
    assert trim_compile_cache(tmp_path, 400) == 250
    assert files() == ["e-cache"]
    assert (tmp_path / "sub" / "big").exists()
    assert trim_compile_cache(tmp_path, 0) == 0
    assert not any(p.is_file() for p in tmp_path.iterdir())


def test_compile_cache_stays_on_when_the_folder_cannot_be_trimmed(tmp_path, monkeypatch):
    import jax

    from jaxdepth.batch import devices

    def refuse(folder, max_bytes):
        raise PermissionError(13, "Permission denied", str(folder))

    monkeypatch.setattr(devices, "trim_compile_cache", refuse)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv("JAXDEPTH_COMPILE_CACHE", raising=False)
    before = jax.config.jax_compilation_cache_dir  # the suite's session cache (conftest), or None
    jax.config.update("jax_compilation_cache_dir", None)  # as in a process without JAX_COMPILATION_CACHE_DIR
    try:
        assert devices.use_compile_cache(True) == tmp_path / "jaxdepth" / "xla"
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "jaxdepth" / "xla")
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


@pytest.mark.parametrize("user_value", [None, "2.5"])
def test_compile_cache_keeps_fast_compiles_unless_the_user_sets_a_threshold(tmp_path, monkeypatch, user_value):
    """JAX keeps only programs that took over 1 s to compile; the CLI's cache keeps every one, so
    that a fast compile (the nearest fill's, 0.9-1.4 s on 2-core machines) is stored on every
    machine. A threshold the user sets in JAX's own variable is left alone."""
    import jax

    from jaxdepth.batch import devices

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv("JAXDEPTH_COMPILE_CACHE", raising=False)
    if user_value is None:
        monkeypatch.delenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", raising=False)
    else:
        monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", user_value)
    before = jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs
    jax.config.update("jax_compilation_cache_dir", None)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)  # JAX's default
    try:
        assert devices.use_compile_cache(True) == tmp_path / "jaxdepth" / "xla"
        expected = 0.0 if user_value is None else 1.0  # JAX itself reads the variable at import
        assert jax.config.jax_persistent_cache_min_compile_time_secs == expected
    finally:
        jax.config.update("jax_compilation_cache_dir", before[0])
        jax.config.update("jax_persistent_cache_min_compile_time_secs", before[1])


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_png_compression_option_changes_size_not_values_and_summary_has_timings(tmp_path, frames, capsys):
    """Issue 14: --png-compression 0-9; the decoded depth is the same at every level; the summary
    reports start-up and first-frame latency."""
    items, _ = frames
    src = write_kitti_folder(tmp_path / "src", items[:2])
    outs = {}
    for level in ("0", "9", None):
        dst = tmp_path / f"out_{level}"
        extra = [] if level is None else ["--png-compression", level]
        code = cli.main(["complete", str(src), str(dst), "--method", "nearest", "--batch-size", "2", *extra])
        err = capsys.readouterr().err
        assert code == 0, err
        assert "2 completed" in err and "start-up" in err and "first output written at" in err
        outs[level] = {p.name: p for p in sorted(dst.glob("*.png"))}
    for name in outs["0"]:
        np.testing.assert_array_equal(read_depth_png(outs["0"][name]), read_depth_png(outs["9"][name]))
        np.testing.assert_array_equal(read_depth_png(outs["0"][name]), read_depth_png(outs[None][name]))
        assert outs["0"][name].stat().st_size > outs["9"][name].stat().st_size
    with pytest.raises(SystemExit):
        cli.main(["complete", str(src), str(tmp_path / "bad"), "--png-compression", "10"])
