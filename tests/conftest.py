"""Shared fixtures. The real data in ../shared/data is used by path, never copied.

When it is missing, tests that need it skip locally and fail when CI is set.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import shutil
import sys
import tempfile

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parent.parent

# The CLI keeps compiled functions in ~/.cache/jaxdepth/xla; the suite (and the CLI
# subprocesses it starts) must not write there. test_cli's compile-cache test turns it
# on for its own subprocesses, with a temporary XDG_CACHE_HOME.
os.environ["JAXDEPTH_COMPILE_CACHE"] = "0"

# Instead, one persistent compilation cache per test session, in a temporary folder
# removed at the end: a program compiled once (by this process, by a CLI / notebook /
# Ray subprocess, or by another xdist worker) is read back instead of compiled again.
# Set through the environment before JAX is imported, so subprocesses inherit it; every
# program is stored (no minimum compile time or size). Outputs are the same bytes with
# or without it (test_cli checks this for the CLI). An inherited folder (the xdist
# controller's) is shared; JAXDEPTH_TEST_COMPILE_CACHE=0 turns it off.
_SESSION_CACHE_OWNER = False
if os.environ.get("JAXDEPTH_TEST_COMPILE_CACHE", "1") != "0":
    if not os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="jaxdepth-test-xla-")
        _SESSION_CACHE_OWNER = True
    os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    os.environ["JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES"] = "-1"
    if "jax" in sys.modules:  # imported before this file (a plugin): set the options directly too
        import jax
        jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)

# Cheaper compiles for the suite: XLA_FLAGS gains SUITE_XLA_FLAGS (optimisation level 0: about half
# the compile CPU of a pipeline program, runs 3-5x slower) before JAX starts its backend, here in the first
# process of the session; xdist workers and every subprocess inherit it. The flags the user had (the
# production flags) are kept in JAXDEPTH_TEST_PRODUCTION_XLA_FLAGS: tests marked production_flags run
# in a subprocess under them (below). JAXDEPTH_TEST_XLA=production runs the whole suite at them.
# Importing xla_tuning imports JAX but does not start its backend. See docs/testing.md, "Compile flags".
from jaxdepth._src.xla_tuning import SUITE_XLA_FLAGS  # noqa: E402

PRODUCTION_FLAGS_ENV = "JAXDEPTH_TEST_PRODUCTION_XLA_FLAGS"
if PRODUCTION_FLAGS_ENV not in os.environ:
    os.environ[PRODUCTION_FLAGS_ENV] = os.environ.get("XLA_FLAGS", "")
    if os.environ.get("JAXDEPTH_TEST_XLA", "suite") != "production":
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {SUITE_XLA_FLAGS}".strip()
#: True when this process compiles at the suite's flags, not the production ones.
AT_SUITE_FLAGS = os.environ.get("XLA_FLAGS", "") != os.environ[PRODUCTION_FLAGS_ENV]

# Hypothesis draws new examples on every local run (it keeps exploring), but the same ones under CI
# (derandomize: examples derived from each test's source), so CI's verdict on a commit does not depend
# on the draw. A failure found locally becomes an @example of its test.
from hypothesis import settings as _hypothesis_settings  # noqa: E402

_hypothesis_settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    _hypothesis_settings.load_profile("ci")


#: Doctests that compile a whole pipeline: slow like the tests that do (docs/testing.md).
SLOW_DOCTESTS = ("jaxdepth._src.pipeline.complete",)


class ProductionFlagsItem(pytest.Item):
    """A ``production_flags`` test, run by itself in a pytest subprocess at the production XLA flags.

    Stands in for the test when this process compiles at the suite's flags: it requests no fixture,
    so nothing of the test is computed here; it carries the test's markers (``slow``,
    ``xdist_group``) and passes, fails or skips as the subprocess's run of the test does.
    """

    def __init__(self, *, test_id: str, **kwargs):
        super().__init__(**kwargs)
        self.test_id = test_id

    def runtest(self):
        import subprocess
        env = dict(os.environ, XLA_FLAGS=os.environ[PRODUCTION_FLAGS_ENV])
        command = [sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider", "-rs", self.test_id]
        proc = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True)
        self.child_output = proc.stdout[-6000:] + proc.stderr[-3000:]
        if proc.returncode != 0:
            raise RuntimeError(f"{self.test_id} at the production XLA flags: exit {proc.returncode}")
        if " passed" not in proc.stdout:
            lines = proc.stdout.strip().splitlines()
            reason = next((line for line in lines if line.startswith("SKIPPED")), lines[-1])
            pytest.skip(f"at the production XLA flags: {reason}")

    def repr_failure(self, excinfo):
        return f"{excinfo.value}\n{getattr(self, 'child_output', '')}"

    def reportinfo(self):
        return self.path, None, f"{self.test_id} [production XLA flags, subprocess]"


@pytest.hookimpl(tryfirst=True)  # before xdist tags groups and `-m` deselects: the stand-ins carry the markers
def pytest_collection_modifyitems(config, items):
    for item in items:
        if isinstance(item, pytest.DoctestItem) and item.name in SLOW_DOCTESTS:
            item.add_marker(pytest.mark.slow)
    for i, item in enumerate(items if AT_SUITE_FLAGS else ()):
        if item.get_closest_marker("production_flags") is not None:
            stand_in = ProductionFlagsItem.from_parent(item.parent, name=item.name, test_id=item.nodeid)
            stand_in.own_markers.extend(item.own_markers)
            stand_in.keywords.update(item.keywords)
            items[i] = stand_in
    # loadgroup hands out the groups first (largest first), then single tests in this order: the stand-ins (each
    # one long subprocess), then the other slow tests, then the quick ones, so that no worker ends the run alone on
    # a long test while the other has none left (sorted is stable: collection order within each class)
    items[:] = sorted(items, key=lambda item: (not isinstance(item, ProductionFlagsItem),
                                               item.get_closest_marker("slow") is None))


def pytest_sessionfinish(session, exitstatus):
    if _SESSION_CACHE_OWNER and not hasattr(session.config, "workerinput"):
        shutil.rmtree(os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)


def _shared_data_dir() -> pathlib.Path:
    env = os.environ.get("JAXDEPTH_SHARED_DATA")
    if env:
        return pathlib.Path(env)
    return REPO.parent / "shared" / "data"


def require_shared(*parts: str) -> pathlib.Path:
    """Path under ../shared/data; skips (or fails under CI) when it is absent."""
    path = _shared_data_dir().joinpath(*parts)
    if not path.exists():
        message = f"shared data not found: {path}"
        if os.environ.get("CI"):
            pytest.fail(message + " (CI is set: missing data is a failure, not a skip)")
        pytest.skip(message)
    return path


@pytest.fixture(scope="session")
def shared_data() -> pathlib.Path:
    return require_shared()


@pytest.fixture(scope="session")
def kitti_frame(shared_data) -> pathlib.Path:
    return require_shared("kitti", "drive_0001_frame05")


@dataclasses.dataclass(frozen=True)
class KittiFrame:
    """The shared KITTI frame, decoded once per session (arrays are read-only).

    ``sparse``, ``truth``: camera (2, 3) -> (352, 1216) float32 metres, 0 = empty
    (benchmark crop of ``velodyne_raw_image_0X.png`` / ``groundtruth_image_0X.png``).
    ``frame_sparse``, ``frame_truth``: the same, uncropped (375, 1242).
    ``K``: camera -> (3, 3) float32 intrinsics of the crop; ``T_cam_lidar``: camera ->
    (4, 4) float32. ``scan``: (N, 3) float32 LiDAR points of ``lidar_data.bin``, metres.
    """

    path: pathlib.Path
    sparse: dict
    truth: dict
    frame_sparse: dict
    frame_truth: dict
    K: dict
    T_cam_lidar: dict
    scan: np.ndarray


def _read_only(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@pytest.fixture(scope="session")
def kitti(kitti_frame) -> KittiFrame:
    """The one KITTI loader of the suite (through the library's own readers)."""
    from jaxdepth.io import crop_to_benchmark, read_depth_png, read_kitti_raw_calib
    calib = read_kitti_raw_calib(kitti_frame / "calib_cam_to_cam.txt", kitti_frame / "calib_velo_to_cam.txt")
    fields = {name: {} for name in ("sparse", "truth", "frame_sparse", "frame_truth", "K", "T_cam_lidar")}
    for cam in (2, 3):
        K_full = calib["cameras"][cam]["K"]
        for kind, name in (("sparse", "velodyne_raw"), ("truth", "groundtruth")):
            full = np.asarray(read_depth_png(kitti_frame / f"{name}_image_0{cam}.png"), np.float32)
            crop, K = crop_to_benchmark(full, K_full)
            fields[kind][cam] = _read_only(np.asarray(crop, np.float32))
            fields["frame_" + kind][cam] = _read_only(full)
        fields["K"][cam] = _read_only(np.asarray(K, np.float32))
        fields["T_cam_lidar"][cam] = _read_only(np.asarray(calib["cameras"][cam]["T_cam_lidar"], np.float32))
    scan = np.fromfile(kitti_frame / "lidar_data.bin", np.float32).reshape(-1, 4)[:, :3]
    return KittiFrame(path=kitti_frame, scan=_read_only(scan), **fields)


@pytest.fixture(scope="session")
def nuscenes_sample(shared_data) -> pathlib.Path:
    return require_shared("nuscenes", "sample")


#: Compiled programs a test process may keep alive across modules (see below).
MAX_LIVE_EXECUTABLES = int(os.environ.get("JAXDEPTH_TEST_MAX_LIVE_EXECUTABLES", "500"))


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after a module once more than ``MAX_LIVE_EXECUTABLES`` are alive.

    Eager, op-by-op runs alone compile hundreds of small programs per module. Kept for the
    whole session, the suite's programs once ended a full run with a crash inside XLA:CPU (SIGSEGV while unwinding, not reproducible module by module). Below the cap, the
    next module reuses what the previous ones compiled (the shared scenes of ``scenes.py``);
    above it every cache is cleared and programs still needed come back from the session's
    persistent compilation cache (read from disk, not compiled again).
    ``JAXDEPTH_TEST_MAX_LIVE_EXECUTABLES=0`` clears after every module.

    JAX's backend starts here, before a process's first test: a test process keeps JAX's one CPU device
    whatever runs first (a multi-frame ``complete`` run in process, e.g. ``cli.main``, would otherwise split
    an unstarted backend into ``os.cpu_count()`` devices, so a machine's core count and the test order
    would set the device count of every later test of that process).
    """
    import jax
    from jax.extend.backend import get_backend
    backend = get_backend()
    yield
    live = len(backend.live_executables())
    if os.environ.get("JAXDEPTH_TEST_REPORT_LIVE"):
        print(f"\n[live executables after module: {live}]", file=sys.stderr)
    if live > MAX_LIVE_EXECUTABLES:
        jax.clear_caches()
