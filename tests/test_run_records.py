"""Run records (jaxdepth/batch/run_record.py): a re-run resumes only outputs made from the same inputs by
the same algorithm version (issue 39 items 3 and 4)."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import pathlib
import re
import sys

import numpy as np
import pytest

import jaxdepth
from jaxdepth import cli
from jaxdepth._src.config import SGMConfig
from jaxdepth.batch import run_record
from jaxdepth.io import write_depth_png
from tests.helpers import wall_sweep, write_wall_rig

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _sparse_folder(root, *, seed, n=2, shape=(64, 128)):
    """``n`` random sparse depths f0.png.. (64 x 128, the size test_bad_inputs uses: a shared compile)."""
    rng = np.random.default_rng(seed)
    root.mkdir()
    for i in range(n):
        d = np.where(rng.random(shape) < 0.08, rng.uniform(4.0, 40.0, shape), 0.0).astype(np.float32)
        write_depth_png(root / f"f{i}.png", d)
    return root


def _pngs(folder):
    return {p.name: p.read_bytes() for p in sorted(pathlib.Path(folder).glob("*.png"))}


# ------------------------------------------------------------------ output version (item 4)


def test_shipped_output_version_is_the_hash_of_the_output_fingerprint_file():
    """The oracle: SHA-256 of the fingerprint JSON as canonical JSON, recomputed here. When outputs change
    (benchmarks/output_fingerprint.py --json rewrites the file) this fails until the package says so."""
    doc = json.loads((ROOT / "benchmarks" / "results" / "output_fingerprint.json").read_text())
    expected = hashlib.sha256(json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:12]
    assert jaxdepth.__output_version__ == expected, (
        f"benchmarks/results/output_fingerprint.json changed: set __output_version__ = {expected!r} in "
        "jaxdepth/__init__.py (outputs of the old version are then refused on resume)")
    assert run_record.make_record({}, inputs=[], command=["x"])["output_version"] == expected


def _folder_with_record(tmp_path, **record_changes):
    out = tmp_path / "out"
    out.mkdir()
    write_depth_png(out / "f0.png", np.full((4, 4), 5.0, np.float32))
    record = run_record.make_record(run_record.settings_of(SGMConfig(), method="sgm"), inputs=[tmp_path],
                                    command=["x", "complete"])
    old = dict(record, **record_changes)
    for key in [k for k, v in record_changes.items() if v is None]:
        del old[key]
    (out / run_record.RUN_FILE).write_text(json.dumps(old))
    return out, record


@pytest.mark.parametrize("old_version", ["0123456789ab", None])
def test_outputs_of_another_output_version_are_refused_and_overwrite_recomputes(tmp_path, old_version):
    out, record = _folder_with_record(tmp_path, output_version=old_version)
    with pytest.raises(run_record.RunSettingsError) as err:
        run_record.claim_folder(out, record, overwrite=False)
    line = str(err.value)
    assert "\n" not in line and "another jaxdepth algorithm version" in line and "--overwrite" in line
    assert (old_version or "none recorded") in line and jaxdepth.__output_version__ in line
    assert (out / "f0.png").exists()  # nothing removed by a refusal
    run_record.claim_folder(out, record, overwrite=True)
    assert json.loads((out / run_record.RUN_FILE).read_text())["output_version"] == jaxdepth.__output_version__
    run_record.claim_folder(out, record, overwrite=False)  # now the same version: resumes


# ------------------------------------------------------------------ changed inputs (item 3)


def test_an_output_whose_input_changed_is_removed_with_its_extras_and_named(tmp_path, caplog):
    src = _sparse_folder(tmp_path / "src", seed=1)
    out = tmp_path / "out"
    record = run_record.make_record({"method": "sgm"}, inputs=[src], command=["x"])

    def identities():
        return {out / p.name: run_record.input_identity([p], values=(np.eye(3),)) for p in sorted(src.glob("*.png"))}

    run_record.claim_folder(out, record, overwrite=False, outputs=identities())
    for name in ("f0.png", "f0_preview.png", "f1.png", "f1_validity.png"):
        (out / name).write_bytes(b"made from the first inputs")
    assert run_record.claim_folder(out, record, overwrite=False, outputs=identities()) == []  # unchanged: resume
    assert len(_pngs(out)) == 4

    (src / "f1.png").write_bytes((src / "f1.png").read_bytes() + b"\0")  # f1 changes size
    with caplog.at_level(logging.WARNING, logger="jaxdepth"):
        changed = run_record.claim_folder(out, record, overwrite=False, outputs=identities())
    size = (src / "f1.png").stat().st_size
    assert changed == [f"f1.png: {src / 'f1.png'} changed size ({size - 1} -> {size} bytes)"]
    assert sorted(_pngs(out)) == ["f0.png", "f0_preview.png"]  # f1 and its extra removed, f0 kept
    assert "1 output made from inputs that changed" in caplog.text and "f1.png" in caplog.text
    stamp = (src / "f0.png").stat().st_mtime_ns
    os.utime(src / "f0.png", ns=(stamp + 10**9, stamp + 10**9))  # same size, touched
    assert run_record.what_changed(json.loads((out / run_record.RUN_FILE).read_text())["outputs"]["f0.png"],
                                   identities()[out / "f0.png"]).endswith("modified since (mtime_ns "
                                                                          f"{stamp} -> {stamp + 10**9})")
    other = {out / "f0.png": run_record.input_identity([src / "f0.png"], values=(2 * np.eye(3),))}
    assert "calibration" in run_record.what_changed(identities()[out / "f0.png"], other[out / "f0.png"])


def test_a_job_without_per_output_inputs_is_refused_when_its_input_roots_differ(tmp_path):
    out, record = _folder_with_record(tmp_path)
    run_record.claim_folder(out, record, overwrite=False)  # same inputs: resumes
    other = dict(record, inputs=[str(tmp_path / "other_log")])
    with pytest.raises(run_record.RunSettingsError, match="made from other inputs.*other_log"):
        run_record.claim_folder(out, other, overwrite=False)


@pytest.mark.slow  # a job run: whole-pipeline batch programs (docs/testing.md)
def test_complete_into_a_folder_made_from_another_input_folder_recomputes_it(tmp_path, capsys, caplog):
    first, second = _sparse_folder(tmp_path / "a", seed=1), _sparse_folder(tmp_path / "b", seed=2)
    K = tmp_path / "K.txt"
    K.write_text("60 0 64\n0 60 32\n0 0 1\n")
    out, fresh = tmp_path / "out", tmp_path / "fresh"
    nearest = ("--intrinsics", K, "--method", "nearest")  # the records are the same for every method
    assert _run(capsys, "complete", first, out, *nearest)[0] == 0
    assert _run(capsys, "complete", second, fresh, *nearest)[0] == 0
    with caplog.at_level(logging.WARNING, logger="jaxdepth"):
        code, _, err = _run(capsys, "complete", second, out, *nearest)  # was: "0 completed, 2 skipped"
    assert code == 0 and "2 completed, 0 skipped" in err, err
    assert "2 outputs made from inputs that changed" in caplog.text and "a/f0.png -> " in caplog.text
    assert _pngs(out) == _pngs(fresh)
    record = json.loads((out / run_record.RUN_FILE).read_text())
    assert record["inputs"] == [str(second.resolve())]
    assert record["outputs"]["f0.png"]["files"][0][0] == str((second / "f0.png").resolve())
    assert "0 completed, 2 skipped" in _run(capsys, "complete", second, out, *nearest)[2]  # resume


@pytest.mark.slow  # a job run: whole-pipeline rig program (docs/testing.md)
def test_complete_rig_with_another_sweep_into_the_same_folder_recomputes_it(tmp_path, capsys, caplog):
    rig = tmp_path / "rig.json"
    write_wall_rig(rig)
    near, far = tmp_path / "near.npy", tmp_path / "far.npy"
    wall_sweep(near)
    np.save(far, np.load(near) * np.float32(1.5))  # the wall at 30 m
    out, fresh = tmp_path / "out", tmp_path / "fresh"
    assert _run(capsys, "complete-rig", near, rig, out, "--no-estimate")[0] == 0
    assert _run(capsys, "complete-rig", far, rig, fresh, "--no-estimate")[0] == 0
    with caplog.at_level(logging.WARNING, logger="jaxdepth"):
        code, _, err = _run(capsys, "complete-rig", far, rig, out, "--no-estimate")
    assert code == 0 and "exists, skipped" not in err, err  # was: both cameras "exists, skipped"
    assert "2 outputs made from inputs that changed" in caplog.text and "near.npy -> " in caplog.text
    assert _pngs(out) == _pngs(fresh)
    assert json.loads((out / run_record.RUN_FILE).read_text())["inputs"][0] == str(far.resolve())


def test_a_single_file_whose_input_changed_is_recomputed_not_skipped(tmp_path, capsys, caplog):
    """``complete a.png out.png`` again after a.png changed, or with another input: recomputed (it printed
    "1 skipped (already done)" and kept the old output); the same input again: skipped. Oracle: a fresh
    run of the new input into another file (same bytes: deterministic)."""
    first, second = _sparse_folder(tmp_path / "a", seed=1, n=1), _sparse_folder(tmp_path / "b", seed=2, n=1)
    K = tmp_path / "K.txt"
    K.write_text("60 0 64\n0 60 32\n0 0 1\n")
    nearest = ("--intrinsics", K, "--method", "nearest")
    src, other, out, fresh = first / "f0.png", second / "f0.png", tmp_path / "out.png", tmp_path / "fresh.png"
    assert _run(capsys, "complete", other, fresh, *nearest)[0] == 0
    assert _run(capsys, "complete", src, out, *nearest)[0] == 0
    record = json.loads(run_record.output_record_path(out).read_text())
    assert record["outputs"]["out.png"]["files"][0][0] == str(src.resolve())
    assert "0 completed, 1 skipped" in _run(capsys, "complete", src, out, *nearest)[2]  # resume: the same input
    old = out.read_bytes()
    src.write_bytes(other.read_bytes())  # a.png changed in place
    with caplog.at_level(logging.WARNING, logger="jaxdepth"):
        code, _, err = _run(capsys, "complete", src, out, *nearest)
    assert code == 0 and "1 completed, 0 skipped" in err, err
    assert f"{out}: made from other inputs: {src.resolve()}" in caplog.text
    assert out.read_bytes() == fresh.read_bytes() != old
    _sparse_folder(tmp_path / "c", seed=3, n=1)
    code, _, err = _run(capsys, "complete", tmp_path / "c" / "f0.png", out, *nearest)  # another input file
    assert code == 0 and "1 completed, 0 skipped" in err, err
    assert "0 completed, 1 skipped" in _run(capsys, "complete", tmp_path / "c" / "f0.png", out, *nearest)[2]


def test_a_single_output_without_its_record_is_refused_unless_overwrite(tmp_path, capsys):
    _sparse_folder(tmp_path / "a", seed=1, n=1)
    K = tmp_path / "K.txt"
    K.write_text("60 0 64\n0 60 32\n0 0 1\n")
    out = tmp_path / "out.png"
    out.write_bytes((tmp_path / "a" / "f0.png").read_bytes())  # another tool's file
    code, _, err = _run(capsys, "complete", tmp_path / "a" / "f0.png", out, "--intrinsics", K, "--method", "nearest")
    assert code == 1 and "out.jaxdepth_run.json beside it is missing" in err and "--overwrite" in err, err
    assert not run_record.output_record_path(out).exists()


def test_complete_rig_tracks_the_files_a_sweeps_json_names(tmp_path, caplog):
    """Changing one member file of a sweeps JSON removes the rig's outputs (so the run recomputes them):
    before, only the JSON itself was an input, and the outputs of the old member resumed."""
    from jaxdepth.batch.rig_job import _output_identities
    from jaxdepth.io import read_rig_json
    rig_path = tmp_path / "rig.json"
    write_wall_rig(rig_path)
    rig = read_rig_json(rig_path)
    ref, earlier = tmp_path / "s0.npy", tmp_path / "s1.npy"
    wall_sweep(ref)
    wall_sweep(earlier, beams=8)
    T = np.eye(4)
    T[0, 3] = -1.0
    sweeps = tmp_path / "sweeps.json"
    sweeps.write_text(json.dumps({"sweeps": [{"file": "s1.npy", "T_ref_sweep": T.tolist()},
                                             {"file": "s0.npy", "T_ref_sweep": np.eye(4).tolist()}]}))
    out = tmp_path / "out"
    record = run_record.make_record(run_record.settings_of(SGMConfig(), method="sgm"), inputs=[sweeps, rig_path])

    def claim():
        return run_record.claim_folder(out, record, overwrite=False, outputs=_output_identities(
            rig, sweeps, rig_path, out, None, guided=False))

    assert claim() == []
    for camera in rig.cameras:  # the run's outputs
        write_depth_png(out / f"{camera.name}.png", np.ones((camera.height, camera.width), np.float32))
    assert claim() == []  # nothing changed: resume
    ident = json.loads((out / run_record.RUN_FILE).read_text())["outputs"][f"{rig.cameras[0].name}.png"]
    assert [f[0] for f in ident["files"]] == [str(p.resolve()) for p in (sweeps, ref, earlier, rig_path)]  # reference first
    wall_sweep(earlier, beams=12)  # one member rewritten: another size
    with caplog.at_level(logging.WARNING, logger="jaxdepth"):
        changed = claim()
    assert len(changed) == len(rig.cameras) and f"{earlier.resolve()} changed size" in changed[0]
    assert not list(out.glob("*.png"))


# ------------------------------------------------------------------ Ctrl-C during a cold compile (item 5)


def _interrupt_demo_while_compiling(folder: pathlib.Path, delay_s: float):
    """(exit code, stderr, whether a compile was running at the interrupt) of ``jaxdepth demo`` with an empty
    compile cache, sent SIGINT ``delay_s`` after JAX starts lowering the scene renderer for XLA (JAX_LOG_COMPILES
    logs where each compile starts and ends; the renderer's, 1.5-3 s under load here, then the pipeline's)."""
    import signal
    import subprocess
    import sys
    import threading

    env = dict(os.environ, XDG_CACHE_HOME=str(folder / "cache"), JAX_LOG_COMPILES="1", PYTHONPATH=str(ROOT))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    proc = subprocess.Popen([sys.executable, "-m", "jaxdepth.cli", "demo", "--out", str(folder / "demo")],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines, compiling, running = [], threading.Event(), [0]

    def read():
        for line in proc.stderr:
            lines.append(line)
            running[0] += ("Compiling " in line and " with global shapes" in line) - ("Finished XLA compilation of " in line)
            if "Compiling jit(_render_frame)" in line:
                compiling.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert compiling.wait(timeout=240), "".join(lines[-20:])
        threading.Event().wait(delay_s)
        in_flight = running[0] > 0
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    finally:
        proc.kill()
    reader.join(timeout=10)
    return proc.returncode, "".join(lines), in_flight


@pytest.mark.slow  # job runs: compile the demo's programs in subprocesses (docs/testing.md)
@pytest.mark.parametrize("delay_s", [2.5, 3.0])
def test_ctrl_c_during_a_cold_compile_exits_130_not_a_crash(tmp_path, delay_s):
    """Before the fix the process printed the message and then died of SIGSEGV in the interpreter's
    shutdown (-11: 4 of 5 tries here with an interrupt 2.5 s into the compile), or the interrupt was
    swallowed by JAX's gc callback and the run went on to exit 0. Where the interrupt lands between two
    compiles or after them (a faster machine), the test tries again ``delay_s / 4`` of the renderer's compile
    time that run logged into its compile (half that once more), so it lands in a compile on any machine, and
    fails if it never does."""
    delay = delay_s
    for attempt in range(3):
        tried = delay
        code, err, in_flight = _interrupt_demo_while_compiling(tmp_path / f"try{attempt}", tried)
        took = re.search(r"Finished XLA compilation of jit\(_render_frame\) in ([\d.]+) sec", err)
        if in_flight or took is None:
            break
        delay = float(took[1]) * (delay_s / 4.0) / 2 ** attempt  # 0.62 / 0.75 of it, then half that
    assert in_flight, f"the interrupt ({tried:.2f} s) came between compiles: {err[-2000:]}"
    assert code == 130, (code, err[-2000:])
    assert err.rstrip().endswith("jaxdepth: interrupted; finished outputs are complete, re-run to resume")
    assert "Traceback" not in err and "Fatal Python error" not in err


def test_a_swallowed_interrupt_prints_no_traceback():
    """A Ctrl-C that lands in a callback which cannot raise (JAX's gc callback) reaches Python's
    unraisable hook: once jaxdepth's handler counted it, the hook in place before (Python's default
    prints a traceback) does not see it; any other unraisable exception still goes to it."""
    import signal

    from jaxdepth import interrupts

    seen = []
    old_handler, old_hook, old_count = signal.getsignal(signal.SIGINT), sys.unraisablehook, interrupts._COUNT[0]
    try:
        sys.unraisablehook = seen.append              # stands in for the default hook
        interrupts.catch()

        class Info:
            exc_type, exc_traceback, err_msg, object = KeyboardInterrupt, None, "Exception ignored in", None
            exc_value = KeyboardInterrupt()

        interrupts._COUNT[0] = 1                      # on_sigint counted it
        sys.unraisablehook(Info)
        assert seen == []
        other = type("Other", (), dict(vars(Info), exc_type=ValueError, exc_value=ValueError("boom")))
        sys.unraisablehook(other)
        assert seen == [other]
        interrupts._COUNT[0] = 0                      # a KeyboardInterrupt jaxdepth did not count: passed on
        sys.unraisablehook(Info)
        assert seen == [other, Info]
    finally:
        signal.signal(signal.SIGINT, old_handler)
        sys.unraisablehook, interrupts._COUNT[0] = old_hook, old_count
