"""Progress lines (jaxdepth/progress.py): a live line on a terminal, timed lines in a log (issue 39 item 6)."""

from __future__ import annotations

import io
import os
import pathlib
import re
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from jaxdepth.io import write_depth_png
from jaxdepth.progress import Progress, interval_from_env

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _wait_for(predicate, timeout_s: float = 10.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        threading.Event().wait(0.01)
    return False


def test_off_a_terminal_timed_lines_come_while_the_job_runs_with_counts_rate_eta_and_failures():
    stream = io.StringIO()
    progress = Progress(10, unit="sweeps", label="complete", interval_s=0.02, stream=stream, tty=False)
    assert _wait_for(lambda: "starting" in stream.getvalue())  # before the first item: still a sign of life
    assert re.search(r"^complete: 0/10 sweeps \(0 %\), starting \(loading, compiling\), 0 failed, \d+ s elapsed$",
                     stream.getvalue().splitlines()[0])
    for i in range(4):
        progress.update(f"s{i}", "done")
    progress.update("s4", "skipped")
    progress.update("s5", "failed: s5.bin: bad")
    assert "complete: s5: failed: s5.bin: bad\n" in stream.getvalue()  # a failure at once, whole
    assert _wait_for(lambda: "6/10 sweeps" in stream.getvalue())
    line = [x for x in stream.getvalue().splitlines() if "6/10 sweeps" in x][0]
    match = re.fullmatch(r"complete: 6/10 sweeps \(60 %\), ([\d.]+) sweeps/s, ETA (\d+) s, 1 skipped, 1 failed, "
                         r"(\d+) s elapsed", line)
    assert match, line
    rate = float(match[1])
    assert rate > 0 and int(match[2]) == pytest.approx(4 / rate, abs=1)  # ETA: the 4 left at the computed rate
    assert "frames" not in stream.getvalue() and "\r" not in stream.getvalue()
    progress.close()
    after = stream.getvalue()
    threading.Event().wait(0.1)
    assert stream.getvalue() == after  # closed: no more lines


def test_on_a_terminal_the_line_is_rewritten_and_no_timed_lines_are_printed():
    stream = io.StringIO()
    progress = Progress(3, unit="images", interval_s=0.01, stream=stream, tty=True)
    threading.Event().wait(0.1)
    assert stream.getvalue() == ""
    progress.update("a.png", "done")
    progress.update("b.png", "failed: b.png: unreadable")
    progress.close()
    text = stream.getvalue()
    assert text.startswith("\r\033[K[1/3]") and "images/s ETA" in text and "a.png: done" in text
    assert "\r\033[Kb.png: failed: b.png: unreadable\n" in text and text.endswith("\n")


def test_verbose_adds_a_line_per_item_and_quiet_prints_nothing():
    stream = io.StringIO()
    progress = Progress(2, unit="samples", label="complete", verbose=True, interval_s=60, stream=stream, tty=False)
    progress.update("tok1", "done")
    progress.update("tok2", "skipped")
    progress.close()
    assert stream.getvalue().splitlines() == ["complete: [1/2] tok1: done", "complete: [2/2] tok2: skipped"]
    assert "last tok2" in progress.line()
    quiet = io.StringIO()
    silent = Progress(2, enabled=False, interval_s=0.01, stream=quiet, tty=False)
    silent.update("x", "failed: x: bad")
    threading.Event().wait(0.05)
    silent.close()
    assert quiet.getvalue() == "" and silent.failed == 1


def test_interval_from_the_environment(monkeypatch):
    monkeypatch.setenv("JAXDEPTH_PROGRESS_INTERVAL", "0.5")
    assert interval_from_env() == 0.5
    for bad in ("0", "-1", "x"):
        monkeypatch.setenv("JAXDEPTH_PROGRESS_INTERVAL", bad)
        assert interval_from_env() == 5.0


@pytest.mark.slow  # a job run in a subprocess: cold compile of a batch program (docs/testing.md)
def test_a_job_with_stderr_to_a_file_writes_progress_lines_before_it_ends(tmp_path):
    """The log is read while the process still runs: a progress line must be there before the job's end
    (and before its summary line in the file). The compile cache is empty, so the job takes seconds."""
    src = tmp_path / "src"
    src.mkdir()
    rng = np.random.default_rng(0)
    for i in range(6):
        depth = np.where(rng.random((64, 128)) < 0.08, rng.uniform(4.0, 40.0, (64, 128)), 0.0).astype(np.float32)
        write_depth_png(src / f"f{i}.png", depth)
    K = tmp_path / "K.txt"
    K.write_text("60 0 64\n0 60 32\n0 0 1\n")
    log = tmp_path / "job.log"
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "cache"), JAXDEPTH_PROGRESS_INTERVAL="0.2",
               PYTHONPATH=str(ROOT))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    with open(log, "w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "jaxdepth.cli", "complete", str(src), str(tmp_path / "out"),
                                 "--intrinsics", str(K), "--method", "nearest", "--batch-size", "2"],
                                env=env, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        try:
            seen = _wait_for(lambda: re.search(r"^complete: \d/6 images", log.read_text(), re.M) is not None, 240)
            running = proc.poll() is None
            proc.wait(timeout=240)
        finally:
            proc.kill()
    text = log.read_text()
    assert seen and running, text  # a progress line in the file while the job still ran
    assert proc.returncode == 0 and "6 completed, 0 skipped" in text
    first = re.search(r"^complete: \d/6 images", text, re.M).start()
    assert first < text.index("6 completed"), text


def test_a_progress_never_closed_stops_its_timed_lines_when_it_is_gone():
    import gc
    stream = io.StringIO()
    progress = Progress(3, interval_s=0.02, stream=stream, tty=False)
    ticker = progress._ticker
    assert _wait_for(lambda: "starting" in stream.getvalue())
    del progress  # e.g. the job raised before close()
    gc.collect()
    ticker.join(timeout=2.0)
    assert not ticker.is_alive()
