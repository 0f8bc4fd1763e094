"""Which programs the test suite's xdist workers compile more than once, and why: a pytest plugin that
records every persistent-compilation-cache key JAX computes, split into the parts JAX hashes, and its summary.

Record (from the repository root; one JSON line per key and per compile, one file per xdist worker)::

    JAXDEPTH_CACHE_KEYS=/tmp/keys python -m pytest -q -p benchmarks.cache_keys [-m "not slow"]

Summarise (prints the table; ``--json`` writes it, default ``results/cache_keys.json``)::

    python -m benchmarks.cache_keys /tmp/keys [--json [PATH]]

JAX's key (``jax._src.cache_key.get``, JAX 0.10) is a SHA-256 over: the lowered module without its debug
information (``computation``), the jaxlib version, the backend's platform and version (``platform``),
``XLA_FLAGS`` and any ``--xla*`` argument of the process (``xla_flags``), the serialized compile options
(``compile_options``: with the persistent cache on, they carry the cache folder's path, JAX's GPU autotune
folder ``<cache>/xla_gpu_per_fusion_autotune_cache_dir``, also on the CPU), the devices' topology
(``accelerator``: one CPU device or two hash apart) and a custom hook. The plugin wraps that function (a
private JAX module: tied to the JAX the venv holds) and records, per key, each part's own hash, the test,
``XLA_FLAGS``; and per compile (``compiler._compile_and_write_cache``: a cache miss) its key, process CPU
and wall seconds. The summary lists the keys compiled more than once (by two workers at once: the second
started before the first had stored it; or after: the cache did not serve it) and the programs (module
name and ``computation``) that got more than one key, with the parts that differ. It does nothing unless
``JAXDEPTH_CACHE_KEYS`` names a folder.
"""

from __future__ import annotations

import argparse
import collections
import glob
import hashlib
import json
import os
import pathlib
import sys
import time

ENV = "JAXDEPTH_CACHE_KEYS"
PARTS = ("computation", "platform", "xla_flags", "compile_options", "accelerator", "hook")


def _record(folder, worker, kind, row):
    with open(os.path.join(folder, f"{worker}.{kind}.jsonl"), "a") as f:
        f.write(json.dumps(row) + "\n")


def _install(folder):
    from jax._src import cache_key, compiler
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    original_get, original_compile = cache_key.get, compiler._compile_and_write_cache

    def parts(module, devices, options, backend, ignore_callbacks=cache_key.IgnoreCallbacks.NO):
        hashers = {
            "computation": lambda h: cache_key._hash_computation(h, module, ignore_callbacks),
            "platform": lambda h: cache_key._hash_platform(h, backend),
            "xla_flags": lambda h: cache_key._hash_xla_flags(h, cache_key.get_flag_prefixes()),
            "compile_options": lambda h: cache_key._hash_serialized_compile_options(
                h, options, strip_device_assignment=backend.platform == "gpu"),
            "accelerator": lambda h: cache_key._hash_accelerator_config(h, devices),
            "hook": lambda h: cache_key._hash_string(h, cache_key.custom_hook()),
        }
        out = {}
        for name, fn in hashers.items():
            h = hashlib.sha256()
            fn(h)
            out[name] = h.hexdigest()[:16]
        return out

    def get(module, devices, compile_options, backend, *args, **kwargs):
        key = original_get(module, devices, compile_options, backend, *args, **kwargs)
        ignore = kwargs.get("ignore_callbacks", args[1] if len(args) > 1 else cache_key.IgnoreCallbacks.NO)
        _record(folder, worker, "keys", dict(worker=worker, key=key, t=time.time(),
                                              test=os.environ.get("PYTEST_CURRENT_TEST", ""),
                                              xla_flags_env=os.environ.get("XLA_FLAGS", ""),
                                              **parts(module, devices, compile_options, backend, ignore)))
        return key

    def compile_and_write(*args, **kwargs):
        cpu, wall = time.process_time(), time.time()
        executable = original_compile(*args, **kwargs)
        key = kwargs.get("cache_key", args[-1] if args else "")
        _record(folder, worker, "compiles", dict(worker=worker, key=key, t=wall, wall_s=time.time() - wall,
                                                  cpu_s=time.process_time() - cpu,
                                                  test=os.environ.get("PYTEST_CURRENT_TEST", "")))
        return executable

    cache_key.get, compiler._compile_and_write_cache = get, compile_and_write


def pytest_configure(config):
    folder = os.environ.get(ENV)
    if folder:
        os.makedirs(folder, exist_ok=True)
        _install(folder)


def _rows(folder, kind):
    return [json.loads(line) for path in sorted(glob.glob(os.path.join(folder, f"*.{kind}.jsonl")))
            for line in open(path) if line.strip()]


def summarise(folder, top=20):
    """The keys compiled more than once, the programs of more than one key, and their CPU seconds."""
    compiles = _rows(folder, "compiles")
    by_key = collections.defaultdict(list)
    for c in compiles:
        by_key[c["key"]].append(c)
    again = []
    for key, cs in by_key.items():
        if len(cs) < 2:
            continue
        cs.sort(key=lambda c: c["t"])
        at_once = cs[1]["t"] < cs[0]["t"] + cs[0]["wall_s"]
        again.append({"key": key, "again_cpu_s": round(sum(c["cpu_s"] for c in cs[1:]), 2),
                      "workers": [c["worker"] for c in cs], "at_once": at_once,
                      "tests": [c["test"].removesuffix(" (call)") for c in cs]})
    again.sort(key=lambda d: -d["again_cpu_s"])
    programs = collections.defaultdict(list)
    for k in _rows(folder, "keys"):
        programs[(k["key"].split("-")[0], k["computation"])].append(k)
    two_keys = []
    for (name, _), ks in programs.items():
        if len({k["key"] for k in ks}) > 1:
            two_keys.append({"program": name, "keys": len({k["key"] for k in ks}),
                             "workers": sorted({k["worker"] for k in ks}),
                             "differs_in": [p for p in PARTS if len({k[p] for k in ks}) > 1],
                             "tests": sorted({k["test"].removesuffix(" (call)") for k in ks})[:4]})
    across = [d for d in two_keys if len(d["workers"]) > 1]
    return {"compiles": len(compiles), "compile_cpu_s": round(sum(c["cpu_s"] for c in compiles), 1),
            "keys_compiled": len(by_key), "compiled_again": len(again),
            "compiled_again_cpu_s": round(sum(d["again_cpu_s"] for d in again), 1),
            "compiled_again_at_once": sum(d["at_once"] for d in again),
            "programs_of_more_than_one_key": len(two_keys), "of_them_across_workers": len(across),
            "again": again[:top], "more_than_one_key": two_keys[:top]}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("folder")
    parser.add_argument("--json", nargs="?", const=str(pathlib.Path(__file__).parent / "results" / "cache_keys.json"))
    parser.add_argument("--note", default="", help="a line on the run (command, commit, load) kept in the JSON")
    args = parser.parse_args(argv)
    s = summarise(args.folder)
    print(f"{s['compiles']} compiles ({s['compile_cpu_s']} s CPU) of {s['keys_compiled']} keys; "
          f"{s['compiled_again']} keys compiled again ({s['compiled_again_cpu_s']} s CPU, "
          f"{s['compiled_again_at_once']} by two workers at once); {s['programs_of_more_than_one_key']} programs "
          f"under more than one key ({s['of_them_across_workers']} across workers)")
    for d in s["again"]:
        print(f"  {d['again_cpu_s']:7.2f} s  {d['key'][:60]}  {d['workers']} at once={d['at_once']}")
    for d in s["more_than_one_key"]:
        print(f"  {d['program']}: {d['keys']} keys, {d['workers']}, differ in {d['differs_in']}: {d['tests'][:2]}")
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(dict(note=args.note, **s), indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
