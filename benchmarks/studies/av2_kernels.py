"""The Argoverse 2 job's compiled sweep program kernel by kernel, by stage and by camera size group.

One fresh ``jaxdepth complete LOG OUT --lidar-time`` process per checkout on the shared log cut to its first
sweep (symbolic links, as :mod:`benchmarks.bench_av2_coldstart`), an empty compile cache and
``XLA_FLAGS=--xla_dump_to``: XLA:CPU writes one optimised LLVM module (``ir-with-opt.ll``) per kernel. Each
kernel is the HLO instruction of its name in the program's ``cpu_after_optimizations.txt``: its stage (the
innermost ``jit(sources_stage_*)`` of its ``op_name``) and its camera group read off the leading axis of
its output shape (the vmaps: 6 = the landscape group, 1 = the portrait camera, 7 = every camera, 2 = the
two LiDARs; flattened batches 3072 / 512 / 917504 = 6 / 1 / 7 x 512 or 131072; anything else, scalars
included: "shared / other"). The PNGs are hashed (per checkout, to compare bytes). ``--checkout PATH``:
each further checkout's library is the one imported (its folder is the child's working directory).

    python -m benchmarks.studies.av2_kernels [--checkout PATH ...] [--json PATH]
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

from benchmarks._common import RESULTS, write_results
from benchmarks.bench_av2_coldstart import LOG, _log_of

GROUPS = {"6": "landscape group (6)", "3072": "landscape group (6)", "1": "portrait camera (1)",
          "512": "portrait camera (1)", "7": "all cameras (7)", "917504": "all cameras (7)", "2": "sources (2)"}


def _instructions(hlo: str) -> dict:
    """HLO instruction name -> (output shape, op_name) of an optimised module's text."""
    out = {}
    for line in hlo.splitlines():
        head = re.match(r"\s*(?:ROOT )?%([\w.\-]+) = (\S+) ", line)
        if head:
            name = re.search(r'op_name="([^"]*)"', line)
            out[head.group(1)] = (head.group(2), name.group(1) if name else "")
    return out


def kernel_map(dump: pathlib.Path) -> dict:
    """Kernels of the dump's largest module: count and IR bytes per (stage, group), and the list."""
    modules = collections.Counter(re.match(r"module_\d+\.([\w\-]+?)\.", p.name).group(1)
                                  for p in dump.glob("*ir-with-opt.ll"))
    module = modules.most_common(1)[0][0]
    info = _instructions(next(dump.glob(f"*.{module}.cpu_after_optimizations.txt")).read_text())
    table, kernels = collections.defaultdict(lambda: [0, 0]), []
    for path in sorted(dump.glob(f"*.{module}.*ir-with-opt.ll")):
        name = re.sub(r"^module_\d+\.[\w\-]+\.(__compute_module_)?", "", path.name)
        name = name.replace(".ir-with-opt.ll", "").replace("_kernel_module", "")
        shape, op_name = info.get(name, ("?", ""))
        stages = re.findall(r"jit\((\w+_stage_\w+)\)", op_name)
        lead = re.match(r"\w+\[(\d+)[,\]]", shape)
        key = (stages[-1] if stages else "(none)", GROUPS.get(lead.group(1) if lead else "", "shared / other"))
        table[key][0] += 1
        table[key][1] += path.stat().st_size
        kernels.append({"kernel": name, "shape": shape, "stage": key[0], "group": key[1], "op_name": op_name})
    rows = [{"stage": s, "group": g, "kernels": n, "ir_bytes": b} for (s, g), (n, b) in sorted(table.items())]
    return {"module": module, "kernels": len(kernels), "by_stage_and_group": rows, "list": kernels}


def one(checkout: str, log: pathlib.Path, tmp: pathlib.Path) -> dict:
    out, dump = tmp / "out", tmp / "dump"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "JAXDEPTH_COMPILE"))}
    env.update(XDG_CACHE_HOME=str(tmp / "cache"), XLA_FLAGS=f"--xla_dump_to={dump} --xla_dump_hlo_as_text")
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "jaxdepth.cli", "complete", str(log), str(out), "--lidar-time", "-q"],
                   env=env, cwd=checkout, check=True, capture_output=True)
    doc = kernel_map(dump) | {"checkout": checkout, "wall_s_with_dump": time.perf_counter() - start}
    doc["png_sha256"] = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(out.rglob("*.png"))}
    return doc


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkout", nargs="*", default=[], help="further checkouts (e.g. main's worktree)")
    parser.add_argument("--json", default=str(RESULTS / "av2_kernels.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    runs = []
    with tempfile.TemporaryDirectory(prefix="jaxdepth-av2-kernels-") as tmp:
        tmp = pathlib.Path(tmp)
        log = _log_of(tmp / "log", sorted((LOG / "sensors" / "lidar").glob("*.feather"))[:1])
        for i, checkout in enumerate(["."] + args.checkout):
            runs.append(one(os.path.abspath(checkout), log, tmp / f"run{i}"))
            print(f"{checkout}: {runs[-1]['kernels']} kernels", flush=True)
            for row in runs[-1]["by_stage_and_group"]:
                print(f"  {row['stage']:28s} {row['group']:22s} {row['kernels']:4d}")
    same = len({tuple(r["png_sha256"].values()) for r in runs}) == 1
    print("PNGs identical across checkouts:", same)
    write_results(args.json, {"what": "the Argoverse 2 --lidar-time sweep program's kernels by stage and camera "
                                      "group, per checkout (XLA dump of a fresh job process)", "runs": runs,
                              "pngs_identical": same}, None, t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
