"""Lowered pipeline programs kept on disk (``jax.export``), so that a warm start skips tracing.

JAX's persistent compile cache (:func:`jaxdepth.batch.devices.use_compile_cache`) keys an executable by
the *lowered* module, so even a warm process traces and lowers the whole pipeline before it can look
the executable up (2-3 s of CPU for the KITTI program, 7-10 s for the Argoverse 2 rig program,
docs/speed.md). :class:`Program` wraps a jitted job program: the first call for a set of input shapes
exports it (:func:`jax.export.export`: one trace and lowering, as the plain ``jit`` would do), writes
the serialised :class:`jax.export.Exported` into ``<compile cache>/programs/`` (atomic,
:func:`jaxdepth.io.atomic.atomic_write_bytes`) and runs it; a later process with the same key reads
the file and calls it (:meth:`jax.export.Exported.call` under ``jit``), and the compile cache then
serves the executable. Both processes run the same wrapped module, so both hit the same compile cache
entry, and the outputs are the bytes of the plain ``jit`` call (tests/test_program_cache.py).

The key (:func:`program_key`) is a SHA-256 of everything that decides the program: its name and
static options (config, job options), the inputs' tree structure (with every pytree's static data) and
each leaf's shape and dtype, the jax / jaxlib versions, the backend and device count, ``XLA_FLAGS``
and the ``JAXDEPTH_*`` environment (e.g. ``JAXDEPTH_XLA_TUNING``), JAX's options, and a hash of every
file of the installed ``jaxdepth`` package (:func:`source_hash`): any change of code makes new keys.
An entry that cannot be read, is corrupt (its own SHA-256 is checked), belongs to another key or does
not match the inputs is ignored, logged and rewritten; a program is never run from a wrong entry.
Old entries are never matched again and go with the folder's size cap (:data:`MAX_BYTES`, oldest first).

Off (the plain ``jit`` call, as before) when the compile cache is off (``--no-compile-cache``,
``JAXDEPTH_COMPILE_CACHE=0``: the test suite's setting), when ``JAXDEPTH_PROGRAM_CACHE=0``, or when JAX
cannot serialise (its ``flatbuffers`` package is missing).
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import pathlib
import pickle
from typing import Callable

log = logging.getLogger("jaxdepth")

#: Bumped when the file format or the key's contents change.
FORMAT = b"jaxdepth-program-1\n"
#: Size cap of the programs folder (trimmed once per process, oldest entries first).
MAX_BYTES = 256 << 20
_SUFFIX = ".jaxprog"
#: ``JAXDEPTH_*`` variables that decide no program (this cache's switch; the host allocator's,
#: :func:`jaxdepth.batch.devices.keep_freed_memory`): left out of the key.
_NOT_PROGRAM = ("JAXDEPTH_PROGRAM_CACHE", "JAXDEPTH_KEEP_MEMORY")
#: JAX options that only concern caches, logs and dumps: left out of the key.
_OPTION_WORDS = ("cache", "dump", "log", "traceback", "pprint")


@functools.lru_cache(maxsize=1)
def source_hash() -> str:
    """SHA-256 of every file of the ``jaxdepth`` package (relative paths and bytes; ``__pycache__`` skipped)."""
    root = pathlib.Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def _environment() -> str:
    """What of the process decides a program besides its code and inputs (part of :func:`program_key`)."""
    import jax
    import jaxlib
    options = sorted((name, repr(value)) for name, value in jax.config.values.items()
                     if not any(word in name for word in _OPTION_WORDS))
    env = sorted((name, value) for name, value in os.environ.items()
                 if name == "XLA_FLAGS" or (name.startswith("JAXDEPTH_") and name not in _NOT_PROGRAM))
    return repr((jax.__version__, jaxlib.__version__, jax.default_backend(), len(jax.devices()), env, options))


def _signature(leaves) -> tuple:
    """(shape, dtype, weak type) of every input leaf."""
    import jax
    return tuple((tuple(aval.shape), str(aval.dtype), bool(aval.weak_type))
                 for aval in (jax.typeof(leaf) for leaf in leaves))


def _shapes(signature) -> tuple:
    return tuple(item[:2] for item in signature)


def program_key(name: str, statics, treedef, signature: tuple) -> str:
    """The hex SHA-256 that names a program's entry (module docs): ``name``, ``statics`` (their ``repr``),
    the inputs' ``treedef`` and ``signature``, the environment and :func:`source_hash`."""
    text = repr((name, statics, str(treedef), signature, _environment(), source_hash()))
    return hashlib.sha256(text.encode()).hexdigest()


def program_folder() -> pathlib.Path | None:
    """``<compile cache>/programs`` (created, trimmed to :data:`MAX_BYTES` once per process), or None when
    the program cache is off (module docs)."""
    from jaxdepth.batch.devices import compile_cache_folder
    if "0" in (os.environ.get("JAXDEPTH_PROGRAM_CACHE", "1"), os.environ.get("JAXDEPTH_COMPILE_CACHE", "1")):
        return None
    cache = compile_cache_folder()
    if cache is None:
        return None
    try:
        import flatbuffers  # noqa: F401  (JAX's serialisation needs it)
    except ImportError:
        log.info("program cache off: the 'flatbuffers' package is not installed")
        return None
    return _prepared_folder(pathlib.Path(cache) / "programs")


@functools.lru_cache(maxsize=4)
def _prepared_folder(folder: pathlib.Path) -> pathlib.Path | None:
    from jaxdepth.batch.devices import trim_compile_cache
    try:
        folder.mkdir(parents=True, exist_ok=True)
        trim_compile_cache(folder, MAX_BYTES)
    except OSError as err:
        log.info("program cache off: %s (%s)", folder, err.strerror or err)
        return None
    return folder if os.access(folder, os.W_OK | os.X_OK) else None


def encode_entry(key: str, exported, out_tree) -> bytes:
    """An entry's bytes: :data:`FORMAT`, the key, the SHA-256 of the rest, the pickled output tree
    structure (its length first) and the serialised Exported."""
    meta = pickle.dumps(out_tree)
    body = len(meta).to_bytes(8, "little") + meta + bytes(exported.serialize())
    return FORMAT + key.encode() + b"\n" + hashlib.sha256(body).hexdigest().encode() + b"\n" + body


def decode_entry(data: bytes, key: str):
    """``(exported, out_tree)`` of an entry written by :func:`encode_entry` for ``key``.

    Raises:
      ValueError: another format or key, a checksum that does not match, a truncated entry.
    """
    import jax
    head = FORMAT + key.encode() + b"\n"
    if not data.startswith(head):
        raise ValueError("another format or key")
    digest, _, body = data[len(head):].partition(b"\n")
    if hashlib.sha256(body).hexdigest().encode() != digest:
        raise ValueError("checksum mismatch (truncated or corrupt)")
    size = int.from_bytes(body[:8], "little")
    out_tree = pickle.loads(body[8:8 + size])
    return jax.export.deserialize(bytearray(body[8 + size:])), out_tree


class Program:
    """A jitted job program, called through its on-disk :class:`jax.export.Exported` (module docs).

    ``jitted``: a ``jax.jit`` function of positional array pytrees (its static options already bound);
    ``name`` and ``statics`` (hashable, with a stable ``repr``): what, beyond the inputs' structure and
    shapes, selects the program (part of the key). ``in_shardings``: ``in_shardings(exported)`` -> the
    ``in_shardings`` of the ``jit`` that calls an Exported of several devices (None: one device). The ``jit``
    that calls an Exported compiles with ``jitted.compiler_options`` when it has them
    (:func:`jaxdepth._src.xla_tuning.entry_jit`'s), as the plain call would.
    Calling returns what ``jitted`` returns, the same bytes.
    """

    def __init__(self, jitted: Callable, *, name: str, statics=(), in_shardings: Callable | None = None):
        self.jitted, self.name, self.statics, self.in_shardings = jitted, name, statics, in_shardings
        self._calls: dict = {}

    def __call__(self, *args):
        import jax
        folder = program_folder()
        if folder is None:
            return self.jitted(*args)
        leaves, treedef = jax.tree_util.tree_flatten(args)
        signature = _signature(leaves)
        call = self._calls.get((treedef, signature))
        if call is None:
            call = self._calls[(treedef, signature)] = self._load_or_export(folder, treedef, signature, leaves)
        return call(*leaves)

    def _load_or_export(self, folder: pathlib.Path, treedef, signature: tuple, leaves) -> Callable:
        import jax
        key = program_key(self.name, self.statics, treedef, signature)
        path = folder / f"{self.name}-{key[:32]}{_SUFFIX}"
        loaded = _read_entry(path, key, signature)
        if loaded is None:
            try:
                exported, out_tree = self._export(treedef, leaves)
            except Exception as err:  # not exportable (or a trace error, which the plain call raises again)
                log.info("program cache: %s not stored (%s: %s); traced on every start", self.name,
                         type(err).__name__, err)
                return lambda *flat: self.jitted(*jax.tree_util.tree_unflatten(treedef, flat))
            _write_entry(path, encode_entry(key, exported, out_tree))
        else:
            exported, out_tree = loaded
        shardings = self.in_shardings(exported) if self.in_shardings is not None and exported.nr_devices > 1 else None
        options = getattr(self.jitted, "compiler_options", None)
        options = {} if options is None else dict(compiler_options=options)
        called = jax.jit(exported.call, **options, **({} if shardings is None else dict(in_shardings=shardings)))

        def call(*flat):
            return jax.tree_util.tree_unflatten(out_tree, called(*flat))
        return call

    def _export(self, treedef, leaves):
        """``(Exported, output tree structure)`` of ``jitted`` on inputs shaped as ``leaves``."""
        import jax
        trees = []

        def flat(*flat_args):
            out_leaves, out_tree = jax.tree_util.tree_flatten(self.jitted(*jax.tree_util.tree_unflatten(treedef, flat_args)))
            trees.append(out_tree)
            return out_leaves

        specs = [jax.ShapeDtypeStruct(aval.shape, aval.dtype, weak_type=aval.weak_type)
                 for aval in (jax.typeof(leaf) for leaf in leaves)]
        exported = jax.export.export(jax.jit(flat))(*specs)
        return exported, trees[-1]


@functools.lru_cache(maxsize=32)
def _stages_program(stage: Callable, statics: tuple) -> Program:
    """The :class:`Program` of a public ``jit`` of :mod:`jaxdepth._src.rig` / :mod:`jaxdepth._src.sources`
    (``rig_program``, ``sources_program``, or one of their stage programs, e.g. ``rig_stage_projection``),
    its static options ``statics`` ((name, value), ...) bound; named after it (entry and compile cache names)."""
    from jaxdepth._src.xla_tuning import entry_jit

    options = dict(statics)

    def program(*args):
        return stage(*args, **options)

    program.__name__ = program.__qualname__ = stage.__name__   # the compile cache entry's name
    return Program(entry_jit(program), name=stage.__name__, statics=statics)


def cached_stage(stage: Callable, *args, **statics):
    """Calls a public program of ``_src`` through its :class:`Program`: ``stage(*args, **statics)``, the same
    bytes, a warm start without tracing (also a ``call`` for ``run_rig_stages`` / ``run_sources_stages``, which
    then stores each stage program apart)."""
    return _stages_program(stage, tuple(sorted(statics.items())))(*args)


def rig_stages(points, valid, cameras, *, config, lidar, images=None, depth_only: bool = False, seen: bool = False):
    """:func:`jaxdepth.complete_rig_stages` (same arguments, same bytes): its program
    (:func:`jaxdepth._src.rig.rig_program`) through the program cache (when the cache is off, the plain
    ``jit`` call). ``depth_only``: the (C, H, W) depth alone, from :func:`jaxdepth._src.rig.rig_depth_program`
    (the same depth bytes; the other fields never written); with ``seen``, ``(depth, seen)`` (its ``seen``)."""
    from jaxdepth._src.rig import rig_depth_program, rig_program
    program = rig_depth_program if depth_only else rig_program
    call = program if program_folder() is None else functools.partial(cached_stage, program)
    return call(points, valid, cameras, images, config=config, lidar=lidar, **_seen(depth_only, seen))


def _seen(depth_only: bool, seen: bool) -> dict:
    """The depth programs' ``seen`` option, passed only when set (the other programs' cache keys unchanged)."""
    return dict(seen=True) if depth_only and seen else {}


def sources_stages(sources, cameras, *, config, free_space: bool = True, beams: int | None = None, images=None,
                   occlusion: bool = True, depth_only: bool = False, seen: bool = False):
    """:func:`jaxdepth._src.sources.complete_sources_stages` (same arguments, same bytes): its program
    (:func:`jaxdepth._src.sources.sources_program`) through the program cache (when the cache is off, the
    plain ``jit`` call). ``depth_only``: the depth alone, from
    :func:`jaxdepth._src.sources.sources_depth_program` (and ``seen``: as :func:`rig_stages`). One sweep as
    ``complete_rig`` takes it (:func:`jaxdepth._src.rig.one_sweep_lidar`): :func:`rig_stages`, as the entry points."""
    from jaxdepth._src.above_scan import resolved_config
    from jaxdepth._src.rig import one_sweep_lidar
    from jaxdepth._src.sources import default_beams, sources_depth_program, sources_program
    lidar = one_sweep_lidar(sources, beams)
    if lidar is not None:        # one sweep as complete_rig takes it: its program, as complete_sources runs
        return rig_stages(sources.points[0], sources.valid[0], cameras, config=config, lidar=lidar, images=images,
                          depth_only=depth_only, seen=seen)
    program = sources_depth_program if depth_only else sources_program
    call = program if program_folder() is None else functools.partial(cached_stage, program)
    beams = default_beams(sources) if beams is None else int(beams)
    return call(sources, cameras, images, config=resolved_config(config, sources), free_space=bool(free_space),
                beams=beams, occlusion=bool(occlusion), **_seen(depth_only, seen))


def _read_entry(path: pathlib.Path, key: str, signature: tuple):
    """``(exported, out_tree)`` from ``path``, or None (missing, or unusable: logged, then rewritten)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as err:
        log.info("program cache: cannot read %s (%s); tracing instead", path, err.strerror or err)
        return None
    try:
        exported, out_tree = decode_entry(data, key)
        shapes = tuple((tuple(aval.shape), str(aval.dtype)) for aval in exported.in_avals)
        if shapes != _shapes(signature) or out_tree.num_leaves != len(exported.out_avals):
            raise ValueError("its inputs or outputs differ from the key's")
    except Exception as err:  # any unusable entry (format, pickle, flatbuffer): never run it
        log.warning("program cache: ignoring %s (%s); tracing and rewriting it", path, err)
        return None
    return exported, out_tree


def _write_entry(path: pathlib.Path, data: bytes) -> None:
    """Writes an entry atomically; a failure only costs the next process a trace (logged)."""
    from jaxdepth.io.atomic import atomic_write_bytes
    from jaxdepth.io.errors import OutputError
    try:
        atomic_write_bytes(path, data)
    except OutputError as err:
        log.info("program cache: not stored (%s)", err)


__all__ = ["Program", "rig_stages", "sources_stages", "cached_stage", "program_key", "program_folder", "source_hash", "encode_entry", "decode_entry", "MAX_BYTES",
           "FORMAT"]
