"""Why image guidance loses on the nuScenes sample: the guide image changed, the seeds' protocol fixed.

Issue 16's ablation protocol on its nuScenes set (benchmarks/ablation_guided.py: 20 % of the
sweep held out, draws 0-2, every camera through ``complete_points``, unfiltered targets,
RMSE / MAE mm over the 18 camera images). Rows: LiDAR-only; guided at weight 50 (the weight
the choose sets picked) with the JPEG as it is, as grey, blurred (Gaussian sigma 1.5 px),
shifted 6 px left or right (a misalignment test: if the image were offset from the LiDAR, one
shift would help); and guided at weight 5. Diagnostic only: this is a report set, so nothing
here chooses a default or a weight.

    PYTHONPATH=. python -m benchmarks.studies.guided_nuscenes_diagnostics [--json benchmarks/results/guided_nuscenes_diagnostics.json]
"""

from __future__ import annotations

import argparse
import sys
import time

import cv2
import jax.numpy as jnp
import numpy as np


from benchmarks.studies import ablation_guided as ag  # noqa: E402
from benchmarks._common import ROOT, write_results  # noqa: E402
from jaxdepth import SGMConfig  # noqa: E402

GUIDED = SGMConfig(guidance_weight=50.0)
ROWS = {
    "LiDAR only": (SGMConfig(), None),
    "guided, weight 50": (GUIDED, None),
    "guided, weight 50, grey image": (GUIDED, lambda im: cv2.cvtColor(im, cv2.COLOR_RGB2GRAY)),
    "guided, weight 50, image blurred (sigma 1.5 px)": (GUIDED, lambda im: cv2.GaussianBlur(im, (0, 0), 1.5)),
    "guided, weight 50, image shifted 6 px left": (GUIDED, lambda im: np.roll(im, -6, axis=1)),
    "guided, weight 50, image shifted 6 px right": (GUIDED, lambda im: np.roll(im, 6, axis=1)),
    "guided, weight 5": (SGMConfig(guidance_weight=5.0), None),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "guided_nuscenes_diagnostics.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    frames, notes = ag.nuscenes_frames((0, 1, 2))
    rows = {}
    for label, (config, transform) in ROWS.items():
        def make(item, config=config, transform=transform):
            if transform is not None:
                item = ag.Item(**{**item.__dict__, "image": jnp.asarray(transform(np.asarray(item.image)))})
            return ag.sgm_call(item, config)
        rows[label] = ag.score(frames, make)
        print(f"{label:50s} {rows[label]['rmse']:8.1f} {rows[label]['mae']:7.1f}", flush=True)
    write_results(args.json, {"protocol": "ablation_guided.py's nuScenes set: 20 % held out, draws 0-2, unfiltered",
                              "notes": notes, "rows": rows}, SGMConfig(), t0)
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
