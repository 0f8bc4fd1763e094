"""The KITTI job's batch programs as traced: did a refactor change what JAX traces or XLA compiles?

    PYTHONPATH=. python -m benchmarks.studies.job_program_trace [--compile sgm-map-full,sgm-map-listed]
        [--json benchmarks/results/job_program_trace.json] [--compare OTHER.json]

Builds :func:`jaxdepth.batch.runner.batched_completion` for one KITTI batch (4 x 352 x 1216) in 14 forms
(strategies map / vmap, distance l1 / l2, guided, extras with the sensor's and a fixed seed limit, the
baselines; full and listed programs) and records, for each, SHA-256 prefixes of its jaxpr, of its
lowered StableHLO (no debug locations) and, for the ``--compile`` names, of its optimised HLO with the
source metadata taken out (``metadata={...}``, ``stack_frame_id`` and the file / function / stack
tables, which name source lines). Each form's program cache statics are recorded too. Run it on two
checkouts (the other one from outside this folder: ``cd /tmp && PYTHONPATH=<checkout> python
<this file> --json base.json``, else the worktree's ``jaxdepth`` is imported) and ``--compare`` the
JSONs: equal hashes mean the same program. Branch frameone (one frame function for the full and listed
programs): ``results/job_program_trace_frameone.json``, compared with main 60d4bef's.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import sys


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _without_metadata(hlo: str) -> str:
    """Optimised HLO text without what names source lines (the rest decides the program)."""
    lines, skip = [], False
    for line in hlo.splitlines():
        if line in ("FileNames", "FunctionNames", "FileLocations", "StackFrames"):
            skip = True
        elif skip and not line.strip():
            skip = False
        elif not skip:
            lines.append(line)
    text = re.sub(r",? metadata=\{[^}]*\}", "", "\n".join(lines))
    return re.sub(r",? ?stack_frame_id=\d+", "", text)


def _forms():
    import numpy as np
    from jaxdepth import SGMConfig
    from jaxdepth._src import presets
    B, H, W = 4, 352, 1216
    K = np.tile(np.array([[721.5, 0, 609.6], [0, 721.5, 172.9], [0, 0, 1]], np.float32), (B, 1, 1))
    T = np.tile(np.asarray(presets.KITTI_T_CAM2_LIDAR, np.float32), (B, 1, 1))
    plain = (np.zeros((B, H, W), np.float32), K, T)
    guided = plain + (np.zeros((B, H, W), np.uint8),)
    forms = {}
    for listed in (False, True):
        tag = "listed" if listed else "full"
        for strategy in ("map", "vmap"):
            forms[f"sgm-{strategy}-{tag}"] = (dict(method="sgm", config=SGMConfig(), strategy=strategy), listed, plain)
        forms[f"sgm-l2-{tag}"] = (dict(method="sgm", config=SGMConfig(distance_metric="l2"), strategy="map"), listed,
                                  plain)
        forms[f"guided-{tag}"] = (dict(method="sgm", config=SGMConfig(guidance_weight=10.0), strategy="map"), listed,
                                  guided)
        forms[f"extras-sensor-{tag}"] = (dict(method="sgm", config=SGMConfig(), strategy="map",
                                              max_seed_distance_px="sensor"), listed, plain)
        forms[f"extras-guided-{tag}"] = (dict(method="sgm", config=SGMConfig(guidance_weight=10.0), strategy="map",
                                              max_seed_distance_px=8.0), listed, guided)
    for method in ("nearest", "ip-basic"):
        forms[f"{method}-full"] = (dict(method=method, config=SGMConfig(), strategy="map"), False, plain)
    return B, H, W, forms


def record(compile_names: set) -> dict:
    import jax
    from jaxdepth._src import presets
    from jaxdepth.batch import runner
    B, H, W, forms = _forms()
    rows = {}
    for name, (options, listed, args) in forms.items():
        more = {"listed_only": True} if listed else {}
        program = runner.batched_completion(B, H, W, lidar=presets.KITTI_HDL64, devices=1, **options, **more)
        lowered = program.jitted.lower(*args)
        row = {"statics": _sha(repr(program.statics)), "jaxpr": _sha(str(jax.make_jaxpr(program.jitted)(*args))),
               "stablehlo": _sha(lowered.as_text(debug_info=False))}
        if name in compile_names:
            row["optimised_hlo"] = _sha(_without_metadata(lowered.compile().as_text()))
        rows[name] = row
        print(name, row, flush=True)
    import jaxdepth
    return {"jaxdepth": os.path.dirname(jaxdepth.__file__), "jax": jax.__version__, "load": os.getloadavg(),
            "programs": rows}


def compare(this: dict, other: dict) -> list:
    """Per form and field: same or different (fields both runs recorded)."""
    lines = []
    for name, row in this["programs"].items():
        theirs = other["programs"].get(name, {})
        fields = [f"{k} {'same' if theirs[k] == v else 'DIFFERENT'}" for k, v in row.items() if k in theirs]
        lines.append(f"{name}: " + ", ".join(fields))
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compile", default="sgm-map-full,sgm-map-listed",
                        help="comma-separated forms whose optimised HLO is recorded (each compiles, ~5-10 s)")
    parser.add_argument("--json", help="write the record here")
    parser.add_argument("--compare", help="a record of another checkout to compare with")
    args = parser.parse_args(argv)
    result = record(set(filter(None, args.compile.split(","))))
    if args.compare:
        with open(args.compare) as f:
            result["compared_with"] = {"file": args.compare, "lines": compare(result, json.load(f))}
        print("\n".join(result["compared_with"]["lines"]))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
