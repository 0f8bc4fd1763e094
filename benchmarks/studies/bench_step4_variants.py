"""Time per frame of the Step-4 variants and image guidance, interleaved in one process.

KITTI drive_0001 frame 5, camera 2, 352x1216 benchmark crop, through ``jaxdepth.complete``:
the paper's Step 4 (``column_bracket=False``), the default (column bracket), the blend, image
guidance (weight 1 and 50, 2 sweeps) with and without the bracket, with the noise floor, guidance with the blend,
and IP_Basic's OpenCV fast mode
(Gaussian). Every variant is compiled first (compile time apart), then all are called in turn
``--rounds`` times (``block_until_ready`` before every clock read), so each sees the same machine
state; medians and the ratio to the default are reported.

    PYTHONPATH=. python -m benchmarks.studies.bench_step4_variants [--rounds 100] [--json benchmarks/results/step4_variants.json]
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import numpy as np


import jaxdepth  # noqa: E402
from benchmarks._common import FRAME, ROOT, load_frames, load_images, write_results  # noqa: E402
from jaxdepth.research.baselines import ip_basic_opencv  # noqa: E402

VARIANTS = {
    "paper Step 4 (column_bracket=False)": dict(column_bracket=False),
    "default (column bracket)": dict(),
    "blend_hypotheses": dict(blend_hypotheses=True),
    "guided, weight 1, without the bracket": dict(guidance_weight=1.0, column_bracket=False),
    "guided, weight 1": dict(guidance_weight=1.0),
    "guided, weight 50": dict(guidance_weight=50.0),
    "guided, weight 50, noise floor 1": dict(guidance_weight=50.0, guidance_noise_floor=1.0),
    "guided, weight 50, blend": dict(guidance_weight=50.0, blend_hypotheses=True),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=100)
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "step4_variants.json"))
    args = parser.parse_args(argv)
    if not FRAME.exists():
        print(f"shared data not found: {FRAME}", file=sys.stderr)
        return 1
    sparse, _, K, T = load_frames()["image_02"]
    image = load_images()["image_02"]
    d, k, t, im = (jax.device_put(a) for a in (sparse, K, T, image))
    calls = {}
    compile_s = {}
    for name, changes in VARIANTS.items():
        config = jaxdepth.SGMConfig(**changes)
        guided = config.guidance_weight > 0
        calls[name] = (lambda c=config, g=guided: jaxdepth.complete(d, k, t, config=c, image=im if g else None)
                       .block_until_ready())
        t0 = time.perf_counter()
        calls[name]()
        compile_s[name] = time.perf_counter() - t0
    calls["IP_Basic fast, OpenCV (Gaussian)"] = lambda: ip_basic_opencv(sparse, blur_type="gaussian")
    calls["IP_Basic fast, OpenCV (Gaussian)"]()
    times = {name: [] for name in calls}
    t_start = time.time()
    for _ in range(args.rounds):
        for name, call in calls.items():
            t0 = time.perf_counter()
            call()
            times[name].append(time.perf_counter() - t0)
    base = float(np.median(times["default (column bracket)"]))
    rows = {}
    print(f"{'variant':40s}{'median ms':>11s}{'x default':>11s}")
    for name, ts in times.items():
        med = float(np.median(ts))
        rows[name] = {"median_ms": 1e3 * med, "p10_ms": 1e3 * float(np.percentile(ts, 10)),
                      "ratio_to_default": med / base, "first_call_s": compile_s.get(name)}
        print(f"{name:40s}{1e3 * med:11.2f}{med / base:11.2f}")
    write_results(args.json, {"frame": "drive_0001_frame05 camera 2, 352x1216", "rounds": args.rounds,
                              "rows": rows}, jaxdepth.SGMConfig(), t_start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
