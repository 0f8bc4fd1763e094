"""CI checks product bytes: part of benchmarks/results/output_fingerprint.json, recomputed at the production flags.

The suite compiles at cheaper XLA flags (``SUITE_XLA_FLAGS``, tests/conftest.py) whose floating-point
code differs in the last bits, so this test is marked ``production_flags``: it runs in a subprocess at
the flags users compile with. It recomputes the synthetic street's outputs of
``benchmarks/output_fingerprint.py`` (the CLI's ``demo``, the scene itself, ``complete_points_stages``
with and without guidance, the stereo ``complete_rig_stages`` and a rig of two camera sizes: no shared
data needed) and compares
their SHA-256 with the recorded file, the same file ``python -m benchmarks.output_fingerprint --check``
compares all 116 outputs with.
"""

from __future__ import annotations

import json
import os
import pathlib
import platform

import pytest

from benchmarks import output_fingerprint

RECORDED = pathlib.Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "output_fingerprint.json"


def _recorded_isa() -> bool:
    """Whether this CPU computes the recorded bytes: x86-64 with AVX2 and FMA. The file was written on an
    AVX-512 machine; ``python -m benchmarks.output_fingerprint --check`` at ``XLA_FLAGS=--xla_cpu_max_isa=AVX2``
    reports 0 of 116 changed, but at ``AVX`` (no FMA) XLA's ``exp`` and ``tanh`` already round apart."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    try:
        flags = next(line for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags"))
    except (OSError, StopIteration):
        return True  # not Linux: nothing to tell; compare
    return {"avx2", "fma"} <= set(flags.split(":", 1)[1].split())


@pytest.mark.slow  # a job run: the demo and three pipeline programs at the production flags (docs/testing.md)
@pytest.mark.production_flags  # compares with the hashes recorded at the production flags
def test_synthetic_outputs_match_the_recorded_fingerprint(tmp_path):
    assert os.environ.get("XLA_FLAGS", "") == os.environ.get("JAXDEPTH_TEST_PRODUCTION_XLA_FLAGS", "")
    if not _recorded_isa():
        pytest.skip("the recorded hashes are those of an x86-64 CPU with AVX2 and FMA")
    recorded = {k: v for k, v in json.loads(RECORDED.read_text()).items() if k.startswith("synthetic.")}
    got = output_fingerprint.synthetic(tmp_path)
    assert len(recorded) >= 30 and set(got) == set(recorded)
    changed = sorted(k for k in recorded if got[k] != recorded[k])
    assert not changed, f"outputs changed against {RECORDED.name}: {changed}"
