"""Shared fixtures. The real data in ../shared/data is used by path, never copied.

When it is missing, tests that need it skip locally and fail when CI is set.
"""

from __future__ import annotations

import os
import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parent.parent

# The CLI keeps compiled functions in ~/.cache/jaxdepth/xla; the suite (and the CLI
# subprocesses it starts) must not write there. test_cli's compile-cache test turns it
# on for its own subprocesses, with a temporary XDG_CACHE_HOME.
os.environ["JAXDEPTH_COMPILE_CACHE"] = "0"


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


@pytest.fixture(scope="session")
def nuscenes_sample(shared_data) -> pathlib.Path:
    return require_shared("nuscenes", "sample")


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after each test module.

    The suite compiles a few hundred programs; kept for the whole session they
    once ended a full run with a crash inside XLA:CPU (SIGSEGV while unwinding,
    not reproducible module by module). Modules do not share compilations
    that matter for time, so each starts clean.
    """
    yield
    import jax
    jax.clear_caches()
