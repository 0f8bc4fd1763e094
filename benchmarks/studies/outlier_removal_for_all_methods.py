"""Does the paper's outlier removal help other methods? Each method with and without it on the real
KITTI frame (cameras 2 and 3, 352x1216 crop, devkit metrics averaged over both).

    python -m benchmarks.studies.outlier_removal_for_all_methods [--json benchmarks/results/outlier_removal_methods.json]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

from jaxdepth import SGMConfig, complete_with, depth_metrics

from benchmarks._common import FRAME, ROOT, load_frames


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "outlier_removal_methods.json"))
    args = parser.parse_args(argv)
    if not FRAME.exists():
        print(f"shared data not found: {FRAME}", file=sys.stderr)
        return 1
    frames = load_frames()
    table = {}
    for method in ("sgm", "nearest", "ip-basic"):
        for removal in (False, True):
            rows = [depth_metrics(complete_with(s, K, T, method=method, config=SGMConfig(outlier_removal=removal)), g)
                    for s, g, K, T in frames.values()]
            table[f"{method}{' + outlier removal' if removal else ''}"] = {
                k: float(np.mean([float(r[k]) for r in rows])) for k in ("rmse", "mae", "irmse", "imae")}
    print(f"{'method':28s}{'RMSE mm':>10s}{'MAE mm':>10s}{'iRMSE':>8s}{'iMAE':>8s}")
    for name, r in table.items():
        print(f"{name:28s}{r['rmse']:10.1f}{r['mae']:10.1f}{r['irmse']:8.2f}{r['imae']:8.2f}")
    out = pathlib.Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(table, indent=2, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
