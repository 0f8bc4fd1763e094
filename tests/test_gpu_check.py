"""benchmarks/gpu_check.py runs on the CPU at its tiny size and writes every documented field."""

from __future__ import annotations

import importlib.util
import json
import pathlib

import jax
import pytest

REPO = pathlib.Path(__file__).resolve().parent.parent


def _gpu_check():
    spec = importlib.util.spec_from_file_location("gpu_check", REPO / "benchmarks" / "gpu_check.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_tiny_inputs_are_sparse_depth_of_the_requested_size():
    gpu_check = _gpu_check()
    sparse, K, T = gpu_check.frame_inputs(64, 128, 3)
    assert sparse.shape == (3, 64, 128) and K.shape == (3, 3, 3) and T.shape == (3, 4, 4)
    filled = (sparse > 0).mean(axis=(1, 2))
    assert ((filled > 0.01) & (filled < 0.9)).all(), filled  # a sweep (64 beams on 64 rows: dense-ish), not empty
    points, valid, rig, sizes = gpu_check.rig_inputs(2, 0.08)
    assert sizes == [(72, 128), (72, 128)] and valid.sum() > 1000 and rig.K.shape == (2, 3, 3)


@pytest.mark.slow
def test_tiny_run_on_cpu_writes_the_json(tmp_path, capsys):
    out = tmp_path / "gpu_check.json"
    assert _gpu_check().main(["--size", "tiny", "--repeats", "2", "--cpu-repeats", "2", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["default_backend"] == jax.default_backend() and len(doc["load_average_at_start"]) == 3
    cpu = doc["cpu"]
    assert cpu["platform"] == "cpu" and cpu["size"] == "tiny"
    assert set(cpu["complete"]) == {"batch_1", "batch_2"}
    for row in [*cpu["complete"].values(), cpu["rig"]]:
        assert row["frames_per_s"] > 0 and row["median_ms"] > 0 and row["compile_s"] > 0
        assert row["peak_bytes_in_use"] is None or row["peak_bytes_in_use"] > 0  # CPU: n/a
        assert row["process_max_rss_mb"] > 0
    b2 = cpu["complete"]["batch_2"]
    assert (b2["height"], b2["width"], b2["batch"]) == (64, 128, 2)
    assert b2["frames_per_s"] == pytest.approx(2 / (b2["median_ms"] / 1e3), rel=0.01)
    assert cpu["rig"]["cameras"] == 2 and cpu["rig"]["sweeps_per_s"] == pytest.approx(
        cpu["rig"]["frames_per_s"] / 2, rel=0.01)
    assert "frames/s" in capsys.readouterr().out
