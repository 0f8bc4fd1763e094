"""The on-disk program cache (jaxdepth.batch.program_cache): a warm start runs the stored jax.export program.

Oracles: the plain ``jit`` call of the same program (the same bytes), a Python-side trace counter (a
program loaded from disk is not traced), and the key's inputs changed one at a time (a new key: traced
again). Corrupt entries are ignored, logged and rewritten.
"""

from __future__ import annotations

import logging

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdepth.batch import devices, program_cache
from jaxdepth.batch.program_cache import Program


@pytest.fixture
def cache_on(tmp_path, monkeypatch):
    """The program cache on, in ``tmp_path / "programs"`` (the suite turns the CLI's compile cache off)."""
    monkeypatch.delenv("JAXDEPTH_COMPILE_CACHE", raising=False)
    monkeypatch.delenv("JAXDEPTH_PROGRAM_CACHE", raising=False)
    monkeypatch.setattr(devices, "compile_cache_folder", lambda: str(tmp_path))
    return tmp_path / "programs"


def _counted(traces: list, scale: float = 2.0):
    """A jitted pytree program that appends to ``traces`` each time it is traced."""
    @jax.jit
    def fn(tree, k):
        traces.append(1)
        return {"sum": tree["a"] * scale + tree["b"][0], "pair": (jnp.cumsum(tree["b"][1]), k * 3)}
    return fn


def _inputs():
    rng = np.random.default_rng(0)
    return ({"a": rng.normal(size=(5, 7)).astype(np.float32),
             "b": (rng.normal(size=(5, 7)).astype(np.float32), rng.normal(size=(11,)).astype(np.float32))},
            np.arange(4, dtype=np.int32))


def _same(a, b) -> bool:
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    return ta == tb and all(np.asarray(x).tobytes() == np.asarray(y).tobytes() for x, y in zip(la, lb))


@pytest.fixture
def exports(monkeypatch):
    """The programs exported (traced and lowered) by :class:`Program`, by name."""
    names, real = [], Program._export

    def counted(self, *args):
        names.append(self.name)
        return real(self, *args)

    monkeypatch.setattr(Program, "_export", counted)
    return names


def test_a_stored_program_runs_without_tracing_and_gives_the_jit_bytes(cache_on, exports):
    traces = []
    fn = _counted(traces)
    args = _inputs()
    first = Program(fn, name="toy", statics=("s", 1))(*args)           # exported (traced), stored
    assert exports == ["toy"] and len(traces) == 1
    assert len(list(cache_on.glob("toy-*.jaxprog"))) == 1
    again = Program(fn, name="toy", statics=("s", 1))(*args)           # as a new process: loaded, not traced
    assert exports == ["toy"] and len(traces) == 1
    expected = fn(*args)
    assert _same(first, expected) and _same(again, expected)
    other = (dict(args[0], a=args[0]["a"] + 1), args[1])               # new values, same shapes: same program
    assert _same(Program(fn, name="toy", statics=("s", 1))(*other), fn(*other)) and exports == ["toy"]


def test_an_entry_jit_program_runs_from_disk_with_its_compile_options(cache_on, exports, monkeypatch):
    """A Program of an ``xla_tuning.entry_jit`` function (the rig / sources / nuScenes programs): the ``jit`` that
    calls the stored Exported is given the function's compile options, exported or loaded; a plain ``jit``'s is
    given none; the bytes are the plain ``jit`` call's (an in-place loop, where the options change the copies)."""
    from jaxdepth._src import xla_tuning

    def sweep(x):
        return jax.lax.fori_loop(1, x.shape[0], lambda i, b: b.at[i].set(jnp.minimum(b[i], b[i - 1] + 2)), x)

    given, real_jit = [], jax.jit

    def recorded(fun, **kwargs):
        if getattr(fun, "__name__", "") == "call":          # Exported.call: the jit that runs a stored program
            given.append(kwargs.get("compiler_options"))
        return real_jit(fun, **kwargs)

    monkeypatch.setattr(jax, "jit", recorded)
    x = jnp.asarray(np.random.default_rng(0).integers(0, 50, (40, 7)), jnp.int32)
    want = real_jit(sweep)(x)
    runs = [Program(xla_tuning.entry_jit(sweep), name="sweep")(x) for _ in range(2)]   # exported, then loaded
    assert exports == ["sweep"] and given == [xla_tuning.COMPILER_OPTIONS] * 2
    assert all(_same(got, want) for got in runs)
    assert _same(Program(real_jit(sweep), name="sweep_plain")(x), want) and given[2:] == [None]


@pytest.mark.parametrize("change", ["statics", "name", "shape", "source", "xla_flags", "tuning_env"])
def test_a_changed_key_traces_again(cache_on, exports, monkeypatch, change):
    traces = []
    fn = _counted(traces)
    args = _inputs()
    Program(fn, name="toy", statics=("s", 1))(*args)
    name, statics = "toy", ("s", 1)
    if change == "statics":
        statics = ("s", 2)
    elif change == "name":
        name = "toy2"
    elif change == "shape":
        args = (args[0], np.arange(5, dtype=np.int32))
    elif change == "source":
        monkeypatch.setattr(program_cache, "source_hash", lambda: "another version of the code")
    elif change == "xla_flags":
        monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_xnnpack=false")     # read by the key only, never compiled here
    else:
        monkeypatch.setenv("JAXDEPTH_XLA_TUNING", "plain")
    out = Program(fn, name=name, statics=statics)(*args)
    assert exports == ["toy", name]
    assert _same(out, fn(*args))
    assert len(list(cache_on.glob("toy*.jaxprog"))) == 2


def test_the_key_is_the_same_for_the_same_program(cache_on):
    leaves, treedef = jax.tree_util.tree_flatten(_inputs())
    signature = program_cache._signature(leaves)
    key = program_cache.program_key("toy", ("s", 1), treedef, signature)
    assert key == program_cache.program_key("toy", ("s", 1), treedef, signature)
    assert len(key) == 64 and key != program_cache.program_key("toy", ("s", 1.0 + 1e-9), treedef, signature)


@pytest.mark.parametrize("damage", ["flip", "truncate", "other_key", "garbage"])
def test_a_corrupt_entry_is_ignored_and_rewritten(cache_on, exports, caplog, damage):
    traces = []
    fn = _counted(traces)
    args = _inputs()
    Program(fn, name="toy")(*args)
    (path,) = cache_on.glob("toy-*.jaxprog")
    data = bytearray(path.read_bytes())
    if damage == "flip":
        data[len(data) // 2] ^= 0xFF
    elif damage == "truncate":
        data = data[:len(data) // 2]
    elif damage == "other_key":
        data = data.replace(data.split(b"\n")[1], b"0" * 64, 1)
    else:
        data = bytearray(b"not a program")
    path.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING, logger="jaxdepth"):
        out = Program(fn, name="toy")(*args)
    assert "ignoring" in caplog.text and path.name in caplog.text
    assert exports == ["toy", "toy"] and _same(out, fn(*args))   # traced again, never run from the bad entry
    assert path.read_bytes() != bytes(data)                     # rewritten: the next one loads it
    assert _same(Program(fn, name="toy")(*args), out) and exports == ["toy", "toy"]


def test_a_program_that_cannot_be_exported_runs_as_plain_jit(cache_on, monkeypatch):
    def refuse(self, *args):
        raise RuntimeError("not exportable")

    monkeypatch.setattr(Program, "_export", refuse)
    fn = _counted([])
    args = _inputs()
    assert _same(Program(fn, name="toy")(*args), fn(*args))
    assert not list(cache_on.glob("*.jaxprog"))


def test_off_without_the_compile_cache(tmp_path, monkeypatch):
    monkeypatch.setattr(devices, "compile_cache_folder", lambda: str(tmp_path))
    monkeypatch.setenv("JAXDEPTH_COMPILE_CACHE", "0")
    assert program_cache.program_folder() is None
    monkeypatch.delenv("JAXDEPTH_COMPILE_CACHE")
    monkeypatch.setenv("JAXDEPTH_PROGRAM_CACHE", "0")
    assert program_cache.program_folder() is None
    traces = []
    fn = _counted(traces)
    Program(fn, name="toy")(*_inputs())
    assert not (tmp_path / "programs").exists()
    monkeypatch.delenv("JAXDEPTH_PROGRAM_CACHE")
    monkeypatch.setattr(devices, "compile_cache_folder", lambda: None)
    assert program_cache.program_folder() is None


@pytest.mark.slow  # compiles the KITTI batch program twice, as jit and as the exported call (docs/testing.md)
def test_the_runner_batch_program_from_disk_equals_jit(cache_on, monkeypatch):
    """The KITTI job's first program, the listed one (``listed_only``: depth and ``fits``), on frames that fit it
    (``helpers.fitting``: the batch test_extras_cli's job runs): exported, stored and loaded, the jit's bytes."""
    from jaxdepth.batch import runner
    from helpers import fitting, small_frames
    frames, T = small_frames(2)
    frames = fitting(frames)
    count = len(jax.local_devices())
    depths = np.stack([d for d, _ in frames] * count)
    Ks = np.stack([K for _, K in frames] * count)
    Ts = np.tile(np.asarray(T, np.float32), (len(depths), 1, 1))
    options = dict(method="sgm", config=runner.SGMConfig(), lidar=runner.presets.KITTI_HDL64, strategy="map",
                   devices=count, listed_only=True)
    runner.batched_completion.cache_clear()
    fn = runner.batched_completion(len(depths), *depths.shape[1:], **options)
    assert isinstance(fn, Program)
    expected = fn.jitted(depths, Ks, Ts)
    assert np.asarray(expected[1]).all() and np.asarray(expected[0]).any()       # every frame fits, depth written
    assert _same(fn(depths, Ks, Ts), expected)                                     # exported, stored
    runner.batched_completion.cache_clear()

    def no_export(*args):
        raise AssertionError("traced although the program was stored")

    monkeypatch.setattr(Program, "_export", no_export)
    fn = runner.batched_completion(len(depths), *depths.shape[1:], **options)
    assert _same(fn(depths, Ks, Ts), expected)                                     # loaded from disk
    runner.batched_completion.cache_clear()


@pytest.mark.slow  # compiles a rig program twice, cache off and through the stored program (docs/testing.md)
@pytest.mark.parametrize("lidars", [1, 2])
def test_complete_rig_writes_the_same_bytes_from_a_stored_program(tmp_path, monkeypatch, lidars):
    """complete-rig's job (one LiDAR: the rig program; two: the multi-source program), cache off, then cold
    and warm through the program cache: the same PNG bytes, and the warm run traces nothing."""
    import json

    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch import extras
    from jaxdepth.batch.rig_job import run_rig_job
    from helpers import WALL_CAMERAS, wall_sweep, write_wall_rig
    rig, sweep = tmp_path / "rig.json", tmp_path / "000001.npy"
    write_wall_rig(rig)
    wall_sweep(sweep)
    if lidars == 2:
        data = json.loads(rig.read_text())
        spec = {key: data["lidar"][key] for key in ("beams", "fov_up_deg", "fov_down_deg")}
        data.update(columns=["x", "y", "z", "lidar"], lidars=[
            {"name": "left", "T_points_lidar": np.eye(4).tolist(), **spec},
            {"name": "right", "T_points_lidar": [[1, 0, 0, 0], [0, 1, 0, -0.5], [0, 0, 1, 0], [0, 0, 0, 1]], **spec}])
        rig.write_text(json.dumps(data))
        points = np.load(sweep)
        points[1::2, 3] = 1.0
        np.save(sweep, points)

    def run(out):
        run_rig_job(sweep, rig, tmp_path / out, config=SGMConfig(), extras=extras.NONE, estimate=False)
        return {name: (tmp_path / out / f"{name}.png").read_bytes() for name in WALL_CAMERAS}

    monkeypatch.setenv("JAXDEPTH_COMPILE_CACHE", "0")
    off = run("off")
    monkeypatch.delenv("JAXDEPTH_COMPILE_CACHE")
    monkeypatch.setattr(devices, "compile_cache_folder", lambda: str(tmp_path / "cache"))
    program_cache._stages_program.cache_clear()
    cold = run("cold")
    assert len(list((tmp_path / "cache" / "programs").glob("*_program-*.jaxprog"))) == 1
    program_cache._stages_program.cache_clear()

    def no_export(*args):
        raise AssertionError("traced although the program was stored")

    monkeypatch.setattr(Program, "_export", no_export)
    warm = run("warm")
    program_cache._stages_program.cache_clear()
    assert off == cold == warm
    assert any(np.frombuffer(png, np.uint8).size for png in off.values())
