"""What stands above the top scan line: real KITTI ground truth against the KITTI twin (issue 37, a study).

    PYTHONPATH=. python -m benchmarks.studies.above_truth [--seeds 0 1] [--phases aligned staggered]
        [--accumulated 5] [--consistency 0.05] [--json benchmarks/results/above_truth.json]

The same statistics on both, over the target pixels above their column's top input pixel (columns with
no input left out): the real frame's official semi-dense ground truth (cameras 2 and 3, 352 x 1216, as
``accuracy_kitti``) and the KITTI twin's exact depth (full size, 1 sweep, ``aligned`` and ``staggered``
laser phases, as ``above_scan_cap``). Per pixel, from truth and input only (never from a method's output):
``rows_up`` = its column's top input row minus its row; ``ratio`` = truth depth / the depth of that top
input pixel (the top seed); class ``nearer`` (ratio < 0.95), ``same`` (within 5 %), ``farther`` (> 1.05);
``elevation`` = the pixel's ray elevation in the LiDAR frame (degrees; the scan's top laser ~ +2 deg).
Each rule of ``SGMConfig.above_scan`` (``plane`` default, ``background``, ``capped``) is scored per class
(MAE / RMSE mm, signed mean error, share of the above pixels' absolute and squared error) and per
``rows_up`` band and within the real ground truth's reach (elevation <= ``REACH_DEG``); ``coverage`` = the share of above pixels that have a target, by band and by top-seed
depth (the real ground truth is accumulated from 11 scans and stereo-checked; the twin's is every pixel
with a surface). Each twin is scored a second time with its exact depth kept only where a KITTI-style
accumulation reaches (:func:`accumulated_mask`: the z-buffer of ``--accumulated`` sweeps, the reference
and the ones before it, within 5 % of the exact depth), i.e. the twin judged as KITTI's ground truth is built.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from benchmarks.studies.above_scan_cap import RULES, above_top_input
from jaxdepth._src.config import SGMConfig

ROW_BANDS = (1, 3, 6, 11, 21, 41, 81, 10**6)  # rows_up in [a, b)
SEED_BANDS_M = (0.0, 10.0, 20.0, 40.0, 1e9)
CLASSES = ("nearer", "same", "farther")
#: The real ground truth's reach: the 99th percentile of its above-scan pixels' elevation (measured
#: here, 3.0 deg; the HDL-64E's top laser is at about +2 deg); the twin is also scored within it.
REACH_DEG = 3.0


def pixel_table(sparse: np.ndarray, truth: np.ndarray, K: np.ndarray, T_cam_lidar: np.ndarray) -> dict:
    """Per-pixel arrays of one (H, W) image over every pixel above its column's top input pixel in a
    column with input: row, col, rows_up, seed depth, truth (0 = no target), elevation (deg)."""
    has = sparse > 0
    h, w = sparse.shape
    top = np.argmax(has, axis=0)
    above = above_top_input(sparse) & has.any(axis=0)[None, :]
    row, col = np.nonzero(above)
    seed = sparse[top[col], col].astype(np.float64)
    t = np.where(np.isfinite(truth[row, col]), truth[row, col], 0.0).astype(np.float64)
    rays = np.linalg.solve(np.asarray(K, np.float64), np.stack([col + 0.5, row + 0.5, np.ones_like(row, float)]))
    R_lidar_cam = np.asarray(T_cam_lidar, np.float64)[:3, :3].T
    d = R_lidar_cam @ rays
    elev = np.degrees(np.arctan2(d[2], np.hypot(d[0], d[1])))
    return {"rows_up": top[col] - row, "seed": seed, "truth": t, "elevation": elev, "row": row, "col": col}


def _q(x: np.ndarray, qs=(10, 50, 90, 99)) -> dict:
    return {f"p{q}": round(float(np.percentile(x, q)), 3) for q in qs} if x.size else {}


def _err(pred: np.ndarray, truth: np.ndarray, total_abs: float, total_sq: float) -> dict:
    e = (pred - truth) * 1000.0
    if not e.size:
        return {"n": 0}
    return {"n": int(e.size), "mae": round(float(np.abs(e).mean()), 1), "rmse": round(float(np.sqrt((e ** 2).mean())), 1),
            "bias": round(float(e.mean()), 1), "abs_share": round(float(np.abs(e).sum() / total_abs), 3),
            "sq_share": round(float((e ** 2).sum() / total_sq), 3)}


def study(tables: list, preds: dict, total_targets: int) -> dict:
    """Pooled statistics of the per-image ``tables`` (:func:`pixel_table`) and each rule's depth images."""
    cat = {k: np.concatenate([t[k] for t in tables]) for k in tables[0]}
    pr = {r: np.concatenate([np.asarray(p[i], np.float64)[t["row"], t["col"]] for i, t in enumerate(tables)])
          for r, p in preds.items()}
    tgt = cat["truth"] > 0
    up, seed, truth, elev = cat["rows_up"], cat["seed"], cat["truth"], cat["elevation"]
    ratio = np.where(tgt, truth / seed, np.nan)
    cls = {"nearer": tgt & (ratio < 0.95), "same": tgt & (ratio >= 0.95) & (ratio <= 1.05), "farther": tgt & (ratio > 1.05)}
    bands = [(a, b) for a, b in zip(ROW_BANDS[:-1], ROW_BANDS[1:])]
    out = {"above_pixels": int(up.size), "above_targets": int(tgt.sum()),
           "above_share_of_targets": round(float(tgt.sum() / total_targets), 4),
           "rows_up_targets": _q(up[tgt].astype(float)), "elevation_targets_deg": _q(elev[tgt]),
           "elevation_top_seed_deg": _q(elev[up == 1]),
           "truth_m": _q(truth[tgt]), "seed_m": _q(seed[tgt]), "classes": {}, "bands": {}, "coverage_by_seed_m": {}}
    err = {r: (pr[r][tgt] - truth[tgt]) * 1000.0 for r in pr}
    totals = {r: (float(np.abs(e).sum()), float((e ** 2).sum())) for r, e in err.items()}
    out["rules"] = {r: _err(pr[r][tgt], truth[tgt], *totals[r]) for r in pr}
    for name, m in cls.items():
        out["classes"][name] = {"share": round(float(m.sum() / max(tgt.sum(), 1)), 3), "ratio": _q(ratio[m]),
                                "rows_up": _q(up[m].astype(float)),
                                "rules": {r: _err(pr[r][m], truth[m], *totals[r]) for r in pr}}
    m = tgt & (elev <= REACH_DEG)
    out["within_reach"] = {"targets": int(m.sum()), "share_of_above_targets": round(float(m.sum() / max(tgt.sum(), 1)), 3),
                           "class_share": {c: round(float((cls[c] & m).sum() / max(m.sum(), 1)), 3) for c in CLASSES},
                           "rules": {r: _err(pr[r][m], truth[m], *totals[r]) for r in pr}}
    for a, b in bands:
        m = (up >= a) & (up < b)
        mt = m & tgt
        out["bands"][f"{a}-{b - 1}" if b < 10**6 else f">={a}"] = {
            "pixels": int(m.sum()), "coverage": round(float(mt.sum() / max(m.sum(), 1)), 3),
            "targets": int(mt.sum()),
            "class_share": {c: round(float((cls[c] & m).sum() / max(mt.sum(), 1)), 3) for c in CLASSES},
            "rules": {r: _err(pr[r][mt], truth[mt], *totals[r]) for r in pr}}
    gain = {b: v["targets"] * (v["rules"]["plane"]["mae"] - v["rules"]["background"]["mae"])
            for b, v in out["bands"].items() if v["targets"]}
    out["plane_minus_background_abs_error_m"] = {"all": round(sum(gain.values()) / 1e6, 1), "rows_up_ge_41": round(
        sum(g for b, g in gain.items() if b in ("41-80", ">=81")) / 1e6, 1)}
    for a, b in zip(SEED_BANDS_M[:-1], SEED_BANDS_M[1:]):
        m = (seed >= a) & (seed < b)
        out["coverage_by_seed_m"][f"{a:g}-{b:g}"] = {"pixels": int(m.sum()),
                                                     "coverage": round(float((m & tgt).sum() / max(m.sum(), 1)), 3),
                                                     "near_3_rows": round(float((m & tgt & (up < 4)).sum()
                                                                                / max((m & (up < 4)).sum(), 1)), 3)}
    return out


def reweighted(case: dict, ref: dict) -> dict:
    """Each rule's MAE / RMSE (mm) of ``case`` over its above targets with the ``rows_up`` bands weighted as
    ``ref``'s targets are (the twin scored with the real ground truth's reach); bands ``case`` lacks drop out."""
    w = {b: v["targets"] for b, v in ref["bands"].items() if case["bands"][b]["targets"]}
    tot = sum(w.values())
    return {r: {"mae": round(sum(w[b] * case["bands"][b]["rules"][r]["mae"] for b in w) / tot, 1),
                "rmse": round(float(np.sqrt(sum(w[b] * case["bands"][b]["rules"][r]["rmse"] ** 2 for b in w) / tot)), 1)}
            for r in case["rules"]}


def real_case() -> dict:
    """The real frame's ground truth (cameras 2 and 3 pooled)."""
    import jaxdepth
    from benchmarks._common import load_frames
    tables, preds, total = [], {r: [] for r in RULES}, 0
    for sparse, gt, K, T in load_frames().values():
        sparse, gt = np.asarray(sparse), np.asarray(gt)
        tables.append(pixel_table(sparse, gt, K, T))
        total += int((gt > 0).sum())
        for r in RULES:
            preds[r].append(np.asarray(jaxdepth.complete_stages(sparse, K, T, config=SGMConfig(above_scan=r)).depth))
    return {"set": "KITTI frame, cameras 2+3, official ground truth", **study(tables, preds, total)}


def twin_case_stats(seed: int, staggered: bool) -> dict:
    """The KITTI twin (full size, 1 sweep): both cameras pooled, exact depth as the target."""
    from benchmarks.studies.above_scan_cap import city_block_and_sparse, sgm, twin_case
    inp, exact = twin_case("kitti", 1, seed, 1.0, staggered)
    _, sparse = city_block_and_sparse(inp)
    tables = [pixel_table(np.asarray(s), e, c.K, c.T_cam_lidar) for s, e, c in zip(sparse, exact, inp.rig.cameras)]
    preds = {r: sgm(inp, SGMConfig(above_scan=r)) for r in RULES}
    total = sum(int((e > 0).sum()) for e in exact)
    return {"set": f"KITTI twin, 1 sweep, seed {seed}, {'staggered' if staggered else 'aligned'}",
            **study(tables, preds, total)}


def accumulated_mask(seed: int, staggered: bool, sweeps: int, exact: list, *, rel: float = 0.05) -> list:
    """Each camera's (H, W) bool: a KITTI-style ground-truth footprint on the twin: the pixels that the
    z-buffer of ``sweeps`` twin sweeps (the reference and the ones before it, ego moving back, all in the
    reference frame) hits within ``rel`` of the exact depth (the consistency filter; movers' smears drop out;
    ``rel`` 0: no filter)."""
    from benchmarks.accuracy_twins import z_buffers
    from jaxdepth.research.twins import make_twin
    tw = make_twin("kitti", sweeps=sweeps, seed=seed, scale=1.0, laser_phases=staggered)
    acc = z_buffers(tw.cloud.points, tw.rig)
    ref = [np.asarray(d, np.float32) for d in tw.depths] if tw.depths else list(tw.dense_depth)
    assert all(np.array_equal(r[:e.shape[0], :e.shape[1]], e) for r, e in zip(ref, exact)), "reference sweep differs"
    return [(a > 0) & (e > 0) & ((rel <= 0) | (np.abs(a - e) <= rel * e)) for a, e in zip(acc, exact)]


def twin_accumulated_stats(seed: int, staggered: bool, sweeps: int = 5, *, rel: float = 0.05) -> dict:
    """:func:`twin_case_stats` with the exact depth kept only on :func:`accumulated_mask`."""
    from benchmarks.studies.above_scan_cap import city_block_and_sparse, sgm, twin_case
    inp, exact = twin_case("kitti", 1, seed, 1.0, staggered)
    mask = accumulated_mask(seed, staggered, sweeps, exact, rel=rel)
    truth = [np.where(m, e, 0.0).astype(np.float32) for m, e in zip(mask, exact)]
    _, sparse = city_block_and_sparse(inp)
    tables = [pixel_table(np.asarray(s), t, c.K, c.T_cam_lidar) for s, t, c in zip(sparse, truth, inp.rig.cameras)]
    preds = {r: sgm(inp, SGMConfig(above_scan=r)) for r in RULES}
    return {"set": f"KITTI twin, 1 sweep, seed {seed}, {'staggered' if staggered else 'aligned'}, truth only where "
            f"{sweeps} sweeps accumulate (filter {rel:g})", "truth_pixels_kept": round(sum(int(m.sum()) for m in mask) / sum(
                int((e > 0).sum()) for e in exact), 4), **study(tables, preds, sum(int((t > 0).sum()) for t in truth))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--phases", nargs="+", choices=("aligned", "staggered"), default=["aligned", "staggered"])
    parser.add_argument("--no-real", action="store_true")
    parser.add_argument("--accumulated", type=int, default=5, metavar="K",
                        help="also score each twin with truth only where K sweeps accumulate (1-5, make_twin's limit; 0: not)")
    parser.add_argument("--consistency", type=float, default=0.05, help="accumulated_mask's rel (0: no filter)")
    parser.add_argument("--json", default=str(RESULTS / "above_truth.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    doc = {"cases": []}
    jobs = ([] if args.no_real else [real_case]) + [
        (lambda s=s, p=p: twin_case_stats(s, p == "staggered")) for s in args.seeds for p in args.phases] + [
        (lambda s=s, p=p: twin_accumulated_stats(s, p == "staggered", args.accumulated, rel=args.consistency))
        for s in args.seeds for p in args.phases if args.accumulated]
    for job in jobs:
        t = time.time()
        case = job()
        case["run_seconds"] = round(time.time() - t, 1)
        doc["cases"].append(case)
        print(case["set"], f"({case['run_seconds']:.0f} s):", {c: v["share"] for c, v in case["classes"].items()},
              {r: (v.get("rmse"), v.get("mae")) for r, v in case["rules"].items()}, flush=True)
        if not args.no_real and len(doc["cases"]) > 1:
            case["reweighted_to_real_bands"] = reweighted(case, doc["cases"][0])
        write_results(args.json, doc, SGMConfig(), t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
