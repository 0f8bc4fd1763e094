"""Process set-up of the batch jobs: host devices, the persistent compile cache, JAX's start, host memory reuse.

Nothing here imports JAX at module level: the command line calls these before JAX starts
(a device count can only be set then) and ``jaxdepth --help`` must not pay for the import.
"""

from __future__ import annotations

import logging
import pathlib
import stat
import sys

log = logging.getLogger("jaxdepth")

_DEVICE_COUNT_FLAG = "--xla_force_host_platform_device_count"


def split_cpu_into_devices(count: int | None = None) -> int:
    """Asks XLA for one host (CPU) device per core, so the runner shards a batch over
    the cores: each core completes its own frames (more frames/s than one device using
    both cores on each frame, benchmarks/results/batching.json; same bytes out).

    Only possible before JAX starts its backends; does nothing (returns 0) if they
    already run or ``XLA_FLAGS`` already sets a device count. Returns the count set.
    Accelerators are unaffected (the runner uses the default backend's devices).
    """
    import os
    count = (os.cpu_count() or 1) if count is None else int(count)
    flags = os.environ.get("XLA_FLAGS", "")
    if count < 2 or _DEVICE_COUNT_FLAG in flags:
        return 0
    if "jax" in sys.modules:  # JAX is loaded: its public option, which refuses once backends run
        import jax
        try:
            jax.config.update("jax_num_cpu_devices", count)
        except (RuntimeError, AttributeError):  # backends already running (or a JAX without the option)
            return 0
        return count
    os.environ["XLA_FLAGS"] = f"{flags} {_DEVICE_COUNT_FLAG}={count}".strip()
    return count


def check_device_count(count, *, where: str) -> int:
    """A job's ``devices`` (its ``where`` names it in the ValueError), an integer >= 1."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"{where}: field 'devices' expected an integer >= 1, got {count!r}")
    return count


def first_devices(count: int) -> list:
    """The first ``count`` local devices a job or batch deals its work to (all there are when fewer: the CLI's
    ``--cpu-devices N`` asks for N host devices, :func:`split_cpu_into_devices`, and a job uses those there are)."""
    import jax
    return jax.local_devices()[:count]


_COMPILE_CACHE_MAX_BYTES = 1 << 30


def trim_compile_cache(folder: pathlib.Path, max_bytes: int) -> int:
    """Deletes the files of ``folder`` written longest ago until at most ``max_bytes`` remain.

    JAX's own size cap (``jax_compilation_cache_max_size``) needs the optional
    ``filelock`` package, which a plain ``pip install jaxdepth`` does not bring,
    and without it JAX refuses every cache read and write; so the cap is kept
    here, once per run, by modification time (ties: file name). Files that
    vanish or cannot be deleted meanwhile are skipped. Returns the bytes left.
    """
    entries = []
    for path in folder.iterdir():
        try:
            info = path.stat()
        except OSError:
            continue
        if stat.S_ISREG(info.st_mode):
            entries.append((info.st_mtime_ns, path.name, info.st_size, path))
    total = sum(entry[2] for entry in entries)
    for _, _, size, path in sorted(entries):
        if total <= max_bytes:
            break
        try:
            path.unlink()
        except OSError:
            continue
        total -= size
    return total


def use_compile_cache(enabled: bool = True) -> pathlib.Path | None:
    """Keeps compiled XLA executables on disk (JAX's persistent compilation cache), so a
    later run for the same image size, config and JAX version skips compilation
    (measured here: a new process's first KITTI-sized ``complete`` 9.8 s -> 3.1 s, the rest
    being imports and tracing). Outputs are the same bytes with or without it.

    The folder is ``$XDG_CACHE_HOME/jaxdepth/xla`` (default ``~/.cache/jaxdepth/xla``),
    capped at 1 GiB (at the start of each run the entries written longest ago are
    deleted beyond that, see :func:`trim_compile_cache`). Every program the run compiles is
    kept, however fast it compiled (JAX's default keeps only those over 1 s; a set
    ``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS`` is respected). Left off when
    ``enabled`` is False (``--no-compile-cache``), when ``JAXDEPTH_COMPILE_CACHE=0``, when
    JAX already has a cache folder (``JAX_COMPILATION_CACHE_DIR``), or when the folder
    cannot be created or written. Returns the folder in use, or None. Processes running at
    once (Ray workers, parallel runs) share the folder; JAX writes entries in place, so one
    read while another process writes it fails, and JAX warns ("Error reading persistent
    compilation cache entry": the truncated entry does not decompress) and compiles that
    program again. The jobs' traced programs go to its ``programs`` subfolder
    (:mod:`jaxdepth.batch.program_cache`, capped apart), so a warm start skips tracing too.
    """
    import os
    if not enabled or os.environ.get("JAXDEPTH_COMPILE_CACHE", "1") == "0":
        return None
    import jax
    if jax.config.jax_compilation_cache_dir:
        return None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    folder = pathlib.Path(base) / "jaxdepth" / "xla"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        log.info("compile cache off: cannot create %s (%s)", folder, err.strerror or err)
        return None
    if not os.access(folder, os.W_OK | os.X_OK):
        log.info("compile cache off: %s is not writable", folder)
        return None
    try:
        trim_compile_cache(folder, _COMPILE_CACHE_MAX_BYTES)
    except OSError as err:  # e.g. a folder that cannot be listed: the cache still works
        log.info("compile cache not trimmed: %s (%s)", folder, err.strerror or err)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        # JAX stores only programs that took over 1 s to compile; whether a small one (the
        # nearest fill: 0.9-1.4 s on 2-core machines) is kept must not hang on the machine's speed
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return folder


def compile_cache_folder() -> str | None:
    """The persistent compile cache folder JAX uses now (:func:`use_compile_cache`, or the user's
    ``JAX_COMPILATION_CACHE_DIR``); None when it is off."""
    import jax
    return jax.config.jax_compilation_cache_dir or None


def io_threads() -> int:
    """Decode / encode threads of the local runner: one per core, at least 2."""
    import os
    return max(2, os.cpu_count() or 1)


def accelerator_plugin_installed() -> bool:
    """Whether a JAX accelerator plugin could be installed (checked without importing JAX):
    an entry point of group ``jax_plugins`` (jax-cuda12-plugin, ...), a ``jax_plugins``
    namespace package, or ``libtpu``."""
    import importlib.metadata
    import importlib.util
    try:
        if importlib.metadata.entry_points(group="jax_plugins"):
            return True
    except Exception:  # a broken distribution's metadata: assume a plugin may be there
        return True
    return any(importlib.util.find_spec(name) is not None for name in ("jax_plugins", "libtpu"))


class _HideBackendProbes(logging.Filter):
    """Drops JAX's "Unable to initialize backend 'tpu'" notes (JAX probes every platform it knows)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("Unable to initialize backend")


#: glibc's ``mallopt`` parameters (``<malloc.h>``).
_M_TRIM_THRESHOLD, _M_MMAP_MAX, _M_ARENA_MAX = -1, -4, -8


def keep_freed_memory(enabled: bool = True) -> bool:
    """Lets the process reuse the host memory it frees instead of handing it back to the OS (glibc's malloc).

    XLA:CPU allocates each call's output and temporary buffers with ``malloc`` and frees them after
    the call. glibc serves a block over 32 MB by ``mmap`` and returns it by ``munmap`` on ``free``
    (and a thread's own arena falls back to ``mmap`` for any block larger than its 64 MB heap), so
    every call of a large program faults its buffers' pages in anew: on one Argoverse 2 sweep (7
    cameras, 22 Mpx) ~615,000 page faults (2.5 GB zeroed by the kernel), ~35 % of the job's CPU per
    sweep (docs/speed.md, "The job's memory"). Set here: one malloc arena for every thread, no ``mmap``
    for large blocks and no trimming of the heap's top (threshold -1; with 2**31 - 1 the top the
    Argoverse 2 program frees, over 2 GB, was still trimmed and faulted in again), so the heap grows to
    the run's peak once and later calls reuse its pages (no faults from the job's third sweep on, bar
    a few). Cost: the process keeps its peak heap resident (the Argoverse 2 sweeps: 4.3 GB, as without).
    The outputs are the same bytes (where a buffer lives decides no value).

    Process-wide: the ``jaxdepth`` process calls it (``cli.main(argv)`` from tests or scripts does not,
    nor does library code), before JAX starts its threads (a thread keeps the arena it already has),
    so a long test session does not keep every worker's peak heap. Does nothing (returns False) when
    ``enabled`` is False, when ``JAXDEPTH_KEEP_MEMORY=0``, or when the C library is not glibc.
    Returns True when glibc accepted the three settings.
    """
    import ctypes
    import os
    if not enabled or os.environ.get("JAXDEPTH_KEEP_MEMORY", "1") == "0":
        return False
    try:
        if not (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc"):
            return False
        mallopt = ctypes.CDLL(None).mallopt
    except (ValueError, OSError, AttributeError):   # no confstr name, no C library handle, no mallopt
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    settings = ((_M_ARENA_MAX, 1), (_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, -1))
    return all([mallopt(param, value) == 1 for param, value in settings])


def quiet_jax_start():
    """The CLI's JAX start-up, set before JAX is imported (never in library code).

    With ``JAX_PLATFORMS`` unset and no accelerator plugin installed, JAX would only
    find the CPU anyway: say so (``JAX_PLATFORMS=cpu``), which skips the probes of
    other platforms and their "Unable to initialize backend" messages. A user's own
    ``JAX_PLATFORMS`` (even empty) is kept. The probe messages are filtered as well.
    """
    import os
    logging.getLogger("jax._src.xla_bridge").addFilter(_HideBackendProbes())
    if "jax" in sys.modules or "JAX_PLATFORMS" in os.environ:
        return
    if not accelerator_plugin_installed():
        os.environ["JAX_PLATFORMS"] = "cpu"


__all__ = ["split_cpu_into_devices", "use_compile_cache", "compile_cache_folder", "trim_compile_cache", "io_threads",
           "accelerator_plugin_installed", "quiet_jax_start", "keep_freed_memory"]
