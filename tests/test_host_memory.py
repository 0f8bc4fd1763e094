"""jaxdepth.batch.devices.keep_freed_memory: freed host memory is reused, not faulted in again.

Oracle: the kernel's count of minor page faults (``getrusage``). A 96 MB block allocated, touched,
freed and allocated again in a worker thread (XLA:CPU allocates on its own threads) faults its
~24,000 pages in twice under glibc's defaults (``mmap`` / ``munmap`` per block) and once with the
setting on. Each case runs in a fresh interpreter: the setting is process-wide.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

_CHILD = r"""
import ctypes, json, resource, sys, threading
from jaxdepth.batch.devices import keep_freed_memory
on = keep_freed_memory(enabled=sys.argv[1] == "1")
libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, (ctypes.c_size_t,)
libc.free.argtypes = (ctypes.c_void_p,)
faults = []
def work():         # plain malloc / write / free, as XLA:CPU's buffers (NumPy would ask for huge pages)
    for _ in range(3):
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        block = libc.malloc(96 * 2**20)
        ctypes.memset(block, 1, 96 * 2**20)             # every page written
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
        libc.free(block)
thread = threading.Thread(target=work)
thread.start(); thread.join()
print(json.dumps({"on": on, "faults": faults}))
"""

glibc = pytest.mark.skipif(not (sys.platform.startswith("linux") and
                                (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc")),
                           reason="glibc's mallopt only")


def _child(enabled: bool, **env) -> dict:
    run = subprocess.run([sys.executable, "-c", _CHILD, "1" if enabled else "0"], capture_output=True, text=True,
                         env={**os.environ, **env}, check=True)
    return json.loads(run.stdout)


@glibc
def test_freed_blocks_are_reused_without_page_faults():
    pages = 96 * 2**20 // os.sysconf("SC_PAGE_SIZE")
    default = _child(False)
    kept = _child(True)
    assert not default["on"] and kept["on"]
    # glibc's defaults: every allocation faults the block in again
    assert all(f >= 0.9 * pages for f in default["faults"]), default
    # kept: the first allocation grows the heap, the later ones reuse its pages
    assert kept["faults"][0] >= 0.9 * pages, kept
    assert all(f < 0.05 * pages for f in kept["faults"][1:]), kept


@glibc
def test_environment_switch_turns_it_off():
    assert _child(True, JAXDEPTH_KEEP_MEMORY="0")["on"] is False


def test_the_switch_is_not_part_of_the_program_key(monkeypatch):
    """JAXDEPTH_KEEP_MEMORY decides no program: a run with it off loads the traced program of a run with
    it on (while another JAXDEPTH_* variable, the tuning mode, changes the key)."""
    import jax
    import numpy as np

    from jaxdepth.batch import program_cache
    leaves, treedef = jax.tree_util.tree_flatten((np.zeros(3, np.float32),))
    signature = program_cache._signature(leaves)

    def key():
        return program_cache.program_key("toy", (), treedef, signature)

    monkeypatch.delenv("JAXDEPTH_KEEP_MEMORY", raising=False)
    base = key()
    monkeypatch.setenv("JAXDEPTH_KEEP_MEMORY", "0")
    assert key() == base
    monkeypatch.setenv("JAXDEPTH_XLA_TUNING", "plain")
    assert key() != base
