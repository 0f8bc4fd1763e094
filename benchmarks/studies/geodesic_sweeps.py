"""How many sweeps the geodesic seed search needs on real data (issue 16).

On the shared KITTI frame (cameras 2 and 3, 352 x 1216 crop, the SGM's inlier
mask of the official sparse input, the colour image in [0, 1]) this compares
``geodesic_seed`` with s sweeps to the converged result (``--reference``
sweeps): the share of pixels whose distance is still larger, of pixels whose
seed differs, and the mean excess distance in pixels.

    python -m benchmarks.studies.geodesic_sweeps [--json benchmarks/results/geodesic_sweeps.json]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

from jaxdepth import complete_stages
from jaxdepth._src.geodesic import geodesic_seed

from benchmarks._common import FRAME, ROOT, load_frames, load_images

WEIGHTS = (1.0, 2.0, 10.0, 50.0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "geodesic_sweeps.json"))
    parser.add_argument("--reference", type=int, default=16)
    args = parser.parse_args(argv)
    if not FRAME.exists():
        print(f"shared data not found: {FRAME}", file=sys.stderr)
        return 1
    result = {"reference_sweeps": args.reference, "rows": []}
    images = load_images()
    for name, (sparse, _, K, T) in load_frames().items():
        image = images[name]
        keep = np.asarray(complete_stages(sparse, K, T).inlier_mask)
        img = image.astype(np.float32) / 255.0
        for w in WEIGHTS:
            ref = geodesic_seed(keep, img, color_weight=w, sweeps=args.reference)
            ref_d = np.asarray(ref.distance)
            for s in (1, 2, 3, 4, 8):
                got = geodesic_seed(keep, img, color_weight=w, sweeps=s)
                d = np.asarray(got.distance)
                row = {"frame": name, "weight": w, "sweeps": s,
                       "longer_pct": 100.0 * float(np.mean(d > ref_d * (1 + 1e-6))),
                       "other_seed_pct": 100.0 * float(np.mean((np.asarray(got.du) != np.asarray(ref.du))
                                                               | (np.asarray(got.dv) != np.asarray(ref.dv)))),
                       "mean_excess_px": float(np.mean(d - ref_d))}
                result["rows"].append(row)
                print(f"{name} w={w:g} sweeps={s}: {row['longer_pct']:.3f} % longer, "
                      f"{row['other_seed_pct']:.3f} % other seed, mean excess {row['mean_excess_px']:.4f} px")
    out = pathlib.Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result, indent=2, sort_keys=True))
    tmp.replace(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
