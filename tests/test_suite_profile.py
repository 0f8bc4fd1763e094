"""benchmarks/suite_profile.py: the plugin records each test's JAX compiles; the summary adds them up."""

from __future__ import annotations

import collections
import json
import os
import pathlib
import subprocess
import sys
import time

import pytest

from conftest import REPO
from benchmarks import suite_profile


def _record(nodeid, worker, start, wall, compile_s=0.0, compile_n=0, big=(), cpu=None, slow=None):
    record = {"id": nodeid, "worker": worker, "start": start, "wall_s": wall, "compile_s": compile_s,
              "compile_n": compile_n, "big_compiles": [list(b) for b in big]}
    if cpu is not None:  # (own, subprocesses'); records of older profiles have neither
        record["cpu_s"], record["child_cpu_s"] = cpu
    if slow is not None:  # the slow marker; older profiles have none
        record["slow"] = slow
    return record


def test_summary_totals_spans_and_orders_against_hand_sums():
    records = [
        _record("tests/a.py::t1", "gw0", 100.0, 4.0, 3.0, 2, [("jit(f)", 2.5)], cpu=(5.0, 0.0)),
        _record("tests/a.py::t2", "gw0", 104.0, 1.0, 0.5, 1, cpu=(0.5, 2.0)),
        _record("tests/b.py::t3", "gw1", 101.0, 6.0, 5.0, 3, [("jit(f)", 1.0), ("jit(g)", 3.5)]),
    ]
    s = suite_profile.summarise(records, top=10)
    assert s["totals"]["tests"] == 3 and s["totals"]["wall_s"] == 11.0 and s["totals"]["compile_s"] == 8.5
    assert s["totals"]["cpu_s"] == 5.5 and s["totals"]["child_cpu_s"] == 2.0 and s["totals"]["has_cpu"]
    assert not suite_profile.summarise(records[2:])["totals"]["has_cpu"]    # an older profile: no CPU times
    assert {m["module"]: m["cpu_s"] for m in s["by_module"]} == {"tests/a.py": 7.5, "tests/b.py": 0.0}
    assert [t["cpu_s"] for t in s["by_test"]] == [0.0, 5.0, 2.5]
    assert s["totals"]["compiles"] == 6
    assert s["workers"] == {"gw0": {"tests": 2, "span_s": 5.0, "busy_s": 5.0},
                            "gw1": {"tests": 1, "span_s": 6.0, "busy_s": 6.0}}
    assert [m["module"] for m in s["by_module"]] == ["tests/b.py", "tests/a.py"]     # 6 s before 5 s
    assert [t["test"] for t in s["by_test"]] == ["tests/b.py::t3", "tests/a.py::t1", "tests/a.py::t2"]
    assert s["by_function"] == [{"function": "jit(f)", "compile_s": 3.5, "compiles": 2},
                                {"function": "jit(g)", "compile_s": 3.5, "compiles": 1}]
    assert s["same_shapes_compiled_again"] == []  # records without shapes (older profiles) are read too
    assert "subsets" not in s["totals"]  # no slow markers recorded: no split


def test_quick_and_slow_subsets_add_up_to_the_totals():
    records = [
        _record("tests/a.py::t1", "gw0", 100.0, 4.0, 3.0, 2, cpu=(5.0, 1.0), slow=True),
        _record("tests/a.py::t2", "gw0", 104.0, 1.0, 0.5, 1, cpu=(0.5, 0.0), slow=False),
        _record("tests/b.py::t3", "gw1", 101.0, 6.0, 2.0, 3, cpu=(2.5, 0.0), slow=False),
    ]
    t = suite_profile.summarise(records)["totals"]
    assert t["subsets"] == {"quick": {"tests": 2, "cpu_s": 3.0, "compile_s": 2.5},
                            "slow": {"tests": 1, "cpu_s": 6.0, "compile_s": 3.0}}
    assert sum(p["cpu_s"] for p in t["subsets"].values()) == t["cpu_s"] + t["child_cpu_s"]


def test_same_function_and_shapes_compiled_twice_are_listed():
    records = [
        _record("tests/a.py::t1", "gw0", 100.0, 4.0, big=[("jit(f)", 2.5, "f32[8,12] f32[3,3]")]),
        _record("tests/b.py::t2", "gw1", 100.0, 4.0, big=[("jit(f)", 2.0, "f32[8,12] f32[3,3]"),
                                                          ("jit(f)", 1.0, "f32[2,8,12] f32[2,3,3]")]),
        _record("tests/b.py::t3", "gw1", 104.0, 1.0, big=[("jit(g)", 1.5, "f32[8,12] f32[3,3]")]),
    ]
    (row,) = suite_profile.summarise(records, top=10)["same_shapes_compiled_again"]
    assert (row["function"], row["shapes"], row["compile_s"]) == ("jit(f)", "f32[8,12] f32[3,3]", 4.5)
    assert [(c["test"], c["worker"]) for c in row["compiles"]] == [("tests/a.py::t1", "gw0"), ("tests/b.py::t2", "gw1")]


def test_one_program_compiled_twice_is_found_by_its_cache_key():
    records = [
        _record("tests/a.py::t1", "gw0", 100.0, 4.0, big=[("jit(f)", 2.5, "f32[8]", "jit_f-k1"),
                                                          ("jit(f)", 1.5, "f32[8]", "jit_f-k2")]),
        _record("tests/b.py::t2", "gw1", 100.5, 4.0, big=[("jit(f)", 2.0, "f32[8]", "jit_f-k1"),
                                                          ("jit(g)", 1.0, "f32[8]", "")]),  # cache off: no key
        _record("tests/b.py::t3", "gw1", 104.5, 1.0, big=[("jit(f)", 0.5, "f32[8]", "jit_f-k1")]),
    ]
    s = suite_profile.summarise(records)
    (row,) = s["same_program_compiled_again"]
    assert (row["key"], row["function"], row["again_s"]) == ("jit_f-k1", "jit(f)", 2.5)  # 2.0 + 0.5 after the first
    assert [c["test"] for c in row["compiles"]] == ["tests/a.py::t1", "tests/b.py::t2", "tests/b.py::t3"]
    assert s["totals"]["compiled_again_s"] == 2.5
    # the shapes table sees all four jit(f) f32[8] compiles (two programs), the key table only the one program
    assert s["same_shapes_compiled_again"][0]["compile_s"] == 6.5


def test_signature_reads_jax_compiling_messages():
    message = ("Compiling jit(_complete_depth) with global shapes and types (ShapedArray(float32[2,32,48]), "
               "ShapedArray(float32[2,3,3]), ShapedArray(uint8[2,32,48,3]), ShapedArray(bool[]), "
               "ShapedArray(float32[], weak_type=True)). Argument mapping: ...")
    # a Python scalar (weakly typed) is a program apart from a float32 array: marked
    assert suite_profile.signature(message) == "f32[2,32,48] f32[2,3,3] u8[2,32,48,3] pred[] ~f32[]"


@pytest.mark.slow  # a pytest subprocess (Python and JAX start-up)
def test_plugin_writes_one_record_per_test_with_its_compiles(tmp_path):
    tests = tmp_path / "test_tiny.py"
    tests.write_text(
        "import jax, jax.numpy as jnp\n"
        "def test_compiles():\n"
        "    assert float(jax.jit(lambda x: jnp.sin(x) * 3.0)(jnp.float32(1.0))) != 0.0\n"
        "import pytest\n"
        "@pytest.mark.slow\n"
        "def test_plain():\n"
        "    assert 1 + 1 == 2\n"
        "def test_subprocess():\n"
        "    import subprocess, sys\n"
        "    subprocess.run([sys.executable, '-c', 'sum(range(2 * 10 ** 7))'], check=True)\n")
    folder = tmp_path / "profile"
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_XDIST")}  # not this session's worker
    env.update(JAXDEPTH_SUITE_PROFILE=str(folder), JAXDEPTH_SUITE_PROFILE_MIN_S="0",
               JAX_COMPILATION_CACHE_DIR=str(tmp_path / "cache"))  # an empty cache of its own: every program compiles
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider",
                          "-p", "benchmarks.suite_profile", "--rootdir", str(tmp_path), "-c", os.devnull, str(tests)],
                         cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    records = {r["id"].split("::")[-1]: r for r in suite_profile.load(folder)}
    assert sorted(records) == ["test_compiles", "test_plain", "test_subprocess"]
    assert records["test_compiles"]["compile_n"] >= 1 and records["test_compiles"]["compile_s"] > 0
    # CPU seconds: compiling costs this process's CPU; a subprocess's CPU is its parent test's (children)
    assert records["test_compiles"]["cpu_s"] > 0 and records["test_plain"]["child_cpu_s"] == 0
    assert records["test_subprocess"]["child_cpu_s"] > 0.2 > records["test_subprocess"]["cpu_s"]
    # every compile listed (MIN_S=0), each with its argument shapes: the lambda's one float32 scalar
    listed = {name: (shapes, key) for name, _, shapes, key in records["test_compiles"]["big_compiles"]}
    assert listed["jit(<lambda>)"][0] == "f32[]", listed
    # with its persistent-cache key (the cache-miss message JAX logs at DEBUG), one of the cache's file names
    key = listed["jit(<lambda>)"][1]
    assert key.startswith("jit__lambda") and any(p.name.startswith(key) for p in (tmp_path / "cache").iterdir()), key
    assert records["test_plain"].get("compile_n", 0) == 0
    assert records["test_plain"]["slow"] and not records["test_compiles"]["slow"]  # the marker, recorded
    assert all(r["worker"] == "main" and r["wall_s"] >= 0 for r in records.values())
    out = tmp_path / "summary.json"
    assert suite_profile.main([str(folder), "--json", str(out)]) == 0
    assert json.loads(out.read_text())["totals"]["tests"] == 3


def _sample(t, runnable, idle, load1=1.0, group=None):
    sample = {"t": t, "idle": idle, "iowait": 0.0, "load1": load1, "runnable": runnable}
    if group is not None:
        sample["group_cpu_s"] = group
    return sample


def test_idle_core_seconds_tail_and_estimate_against_hand_sums():
    # gw0 runs t1 over [100, 104); gw1 runs t2 over [100, 102) and then nothing (its tail)
    records = [_record("tests/a.py::t1", "gw0", 100.0, 4.0, cpu=(4.0, 0.0)),
               _record("tests/b.py::t2", "gw1", 100.0, 2.0, cpu=(1.0, 0.5))]
    samples = [_sample(99.0, {"1": 1}, 10.0, group=0.0),           # [99, 100): collection, 1 short
               _sample(100.0, {"1": 2, "2": 1}, 10.0, group=1.0),  # [100, 101): 3 runnable, none short
               _sample(101.0, {"2": 1}, 10.5, 3.0, group=3.0),     # [101, 102): t2 waits on a child, 1 short
               _sample(102.0, {"1": 1}, 11.5, group=4.0),          # [102, 104): gw1 done, 1 short each second
               _sample(104.0, {}, 13.0, group=6.0)]
    d = suite_profile.idle(records, samples, cores=2)
    assert d["wall_s"] == 5.0 and d["first_test_after_s"] == 1.0
    assert d["idle_core_s"] == 1 + 0 + 1 + 2
    assert d["demand_s"] == {"1 runnable": 4.0, ">= 2 runnable": 1.0}
    assert d["tail_s"] == 2.0 and d["worker_ends_s"] == {"gw0": 5.0, "gw1": 3.0}
    assert d["cpu_s"] == 6.0 and d["cpu_source"] == "control group"
    assert d["estimated_idle_wall_s"] == round(6.0 / (2 - 4 / 5), 1)
    assert d["machine_idle_core_s"] == 3.0 and d["machine_load1"] == {"min": 1.0, "max": 3.0, "mean": 1.4}
    charged = {r["test"]: r["idle_core_s"] for r in d["idle_by_test"]}
    # [99, 100): nothing running (2 workers, none busy): 1 core-s between tests; [101, 102): t1 and t2
    # share 1; [102, 104): t1 and gw1's "between tests" share 2
    assert charged == {"(between tests)": 2.0, "tests/a.py::t1": 1.5, "tests/b.py::t2": 0.5}
    assert sum(charged.values()) == d["idle_core_s"]
    no_group = [{k: v for k, v in s.items() if k != "group_cpu_s"} for s in samples]
    assert suite_profile.idle(records, no_group)["cpu_s"] == 5.5  # the tests' own CPU (and children's)


@pytest.mark.slow  # three Python subprocesses (docs/testing.md)
def test_run_processes_counts_runnable_threads_of_the_run_only(tmp_path):
    """A busy child that carries the run's marker counts, a sleeping one and an unmarked busy one do not."""
    spin = "import time\nprint(flush=True)\nt = time.time()\nwhile time.time() - t < 20: pass\n"
    sleep = "import time\nprint(flush=True)\ntime.sleep(20)\n"
    marked = dict(os.environ, JAXDEPTH_SUITE_PROFILE=str(tmp_path))
    other = dict(os.environ, JAXDEPTH_SUITE_PROFILE=str(tmp_path / "another run"))
    procs = [subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE)
             for code, env in ((spin, marked), (sleep, marked), (spin, other))]
    try:
        for proc in procs:  # each has started (Python's own start-up is runnable too)
            proc.stdout.readline()
        # the sleeping child is runnable between its print and time.sleep: wait until it sleeps (on a loaded
        # machine it may wait for a core longer than any fixed pause)
        stat = pathlib.Path(f"/proc/{procs[1].pid}/stat")
        deadline = time.monotonic() + 60
        while stat.read_text().rsplit(")", 1)[1].split()[0] != "S" and time.monotonic() < deadline:
            time.sleep(0.05)
        run = suite_profile._RunProcesses(str(tmp_path))
        seen = collections.Counter()
        for _ in range(20):  # the spinning child may be descheduled at one sample on a loaded machine
            seen.update(run.runnable())
            time.sleep(0.05)
        assert seen[str(procs[0].pid)] >= 5, seen
        assert str(procs[1].pid) not in seen and str(procs[2].pid) not in seen, seen
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()
