"""Where the SGM loses on a digital twin: error against exact depth, split by image region.

    python -m benchmarks.twins_regions [--rig kitti] [--sweeps 1] [--scale 0.5]
        [--ratios 0.25 0.1] [--json benchmarks/results/twins_regions_kitti_1.json]

One twin (:func:`jaxdepth.research.twins.make_twin`, seed 0), read back as ``complete-rig`` reads
it (:func:`benchmarks.accuracy_twins.read_user_input`); the SGM default, the SGM without removal
(and without the free-space rules on the multi-source path) and the city-block nearest fill on the
whole input (:func:`benchmarks.accuracy_twins.predictions`), and, with ``--ratios``, the SGM with
``max_residual_ratio`` set to each value. Each camera pixel with exact depth falls in one region:

- ``above_scan``: above the top scan line (rows above the highest reference-sweep point of the
  column, min over 9 columns): outside the LiDAR's vertical field of view, pure extrapolation;
- ``below_scan``: below the lowest scan line of the column;
- ``edge``: within 2 px of an exact-depth step of more than 10 % (|log z| difference > 0.1);
- ``near`` (< 10 m), ``mid`` (10-30 m), ``far`` (>= 30 m): the rest, by exact depth.

Per region: its share of the pixels, RMSE / MAE (mm, pooled over pixels and cameras; a pixel
without a prediction counts its whole depth) and its share of the total squared / absolute error.
Also the count of input points that the exact depth shows wrong at their pixel in some camera
(:func:`benchmarks.accuracy_twins.truth_filtered_keep`: ghosts of moving objects, points a camera
cannot see, mixed returns). A diagnosis: nothing here chooses a default.
"""

from __future__ import annotations

import tempfile
import time

import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter1d

from benchmarks import accuracy_twins as bench
from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig

EDGE_LOG_STEP = 0.1
EDGE_DILATION_PX = 5
TOP_WINDOW_COLUMNS = 9


def region_masks(exact: np.ndarray, reference_z: np.ndarray) -> dict:
    """{region: (H, W) bool} of one camera (see the module docstring); ``reference_z`` is the
    (H, W) z-buffer of the reference sweep (0 = no point)."""
    H, _ = exact.shape
    has = reference_z > 0
    rows = np.arange(H)[:, None]
    top = minimum_filter1d(np.where(has.any(0), has.argmax(0), H), TOP_WINDOW_COLUMNS)
    bottom = np.where(has.any(0), H - 1 - has[::-1].argmax(0), -1)
    above, below = rows < top[None, :], rows > bottom[None, :]
    log_z = np.log(np.maximum(exact, 1e-3))
    step = np.zeros_like(has)
    vertical = (np.abs(log_z[1:] - log_z[:-1]) > EDGE_LOG_STEP) & (exact[1:] > 0) & (exact[:-1] > 0)
    horizontal = (np.abs(log_z[:, 1:] - log_z[:, :-1]) > EDGE_LOG_STEP) & (exact[:, 1:] > 0) & (exact[:, :-1] > 0)
    step[1:] |= vertical
    step[:-1] |= vertical
    step[:, 1:] |= horizontal
    step[:, :-1] |= horizontal
    edge = maximum_filter(step, EDGE_DILATION_PX) & ~above & ~below
    t = exact > 0
    rest = t & ~above & ~below & ~edge
    return {"above_scan": t & above, "below_scan": t & below & ~above, "edge": t & edge,
            "near": rest & (exact < 10), "mid": rest & (exact >= 10) & (exact < 30), "far": rest & (exact >= 30)}


def region_errors(pred: list, exact: list, masks: list) -> dict:
    """{region: {share, rmse, mae, se_share, ae_share}} pooled over cameras (mm)."""
    sums = {}
    for p, e, m in zip(pred, exact, masks):
        for name, mask in m.items():
            d = np.where(p[mask] > 0, p[mask] - e[mask], e[mask]).astype(np.float64) * 1000.0
            se, ae, n = sums.get(name, (0.0, 0.0, 0))
            sums[name] = (se + float((d ** 2).sum()), ae + float(np.abs(d).sum()), n + int(mask.sum()))
    n_all = sum(v[2] for v in sums.values())
    se_all, ae_all = sum(v[0] for v in sums.values()), sum(v[1] for v in sums.values())
    out = {name: {"share": n / n_all, "rmse": (se / max(n, 1)) ** 0.5, "mae": ae / max(n, 1),
                  "se_share": se / se_all, "ae_share": ae / ae_all} for name, (se, ae, n) in sums.items()}
    out["all"] = {"share": 1.0, "rmse": (se_all / n_all) ** 0.5, "mae": ae_all / n_all}
    return out


def main(argv=None) -> int:
    parser = bench.twin_parser(__doc__.splitlines()[0], rig="kitti", sweeps=1, scale=0.5)
    parser.add_argument("--ratios", nargs="*", type=float, default=[], help="extra SGM max_residual_ratio values")
    args = parser.parse_args(argv)
    t0 = time.time()
    from jaxdepth.research.twins import make_twin, write_twin
    twin = make_twin(args.rig, sweeps=args.sweeps, seed=0, scale=args.scale)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(twin, tmp)
        inp = bench.read_user_input(paths["sweeps_json"] if args.sweeps > 1 else paths["sweeps"][0], paths["rig"])
    exact = bench.exact_truth(twin, inp.rig)
    everything = np.ones(len(inp.cloud.points), bool)
    full = bench.predictions(inp, everything, SGMConfig())
    names = ["sgm", "sgm_no_removal", "nearest"] + (["sgm_no_free_space"] if inp.multi else [])
    for r in args.ratios:
        full[f"sgm_ratio_{r:g}"] = bench.predictions(inp, everything, SGMConfig(max_residual_ratio=r))["sgm"]
        names.append(f"sgm_ratio_{r:g}")
    c = inp.cloud
    reference_z = bench.z_buffers(c.points[c.sweep[c.source] == 0], inp.rig)
    masks = [region_masks(e, z) for e, z in zip(exact, reference_z)]
    wrong = int((~bench.truth_filtered_keep(c, inp.rig, exact)).sum())
    result = {"rig": args.rig, "sweeps": args.sweeps, "scale": args.scale, "points": len(c.points),
              "points_wrong_at_pixel": wrong, "methods": {m: region_errors(full[m], exact, masks) for m in names}}
    print(f"{args.rig}, {args.sweeps} sweep(s), scale {args.scale}: {len(c.points)} points, {wrong} wrong at their pixel")
    for m in names:
        rows = result["methods"][m]
        print(f"{m}: RMSE {rows['all']['rmse']:.0f} MAE {rows['all']['mae']:.0f}")
        for k, v in rows.items():
            if k != "all":
                print(f"  {k:10s} {100 * v['share']:5.1f} % px  RMSE {v['rmse']:7.0f}  MAE {v['mae']:6.0f}"
                      f"  {100 * v['se_share']:5.1f} % of SE  {100 * v['ae_share']:5.1f} % of AE")
    write_results(args.json or RESULTS / f"twins_regions_{args.rig}_{args.sweeps}.json", result, SGMConfig(), t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
