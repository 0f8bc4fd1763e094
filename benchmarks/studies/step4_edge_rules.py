"""Step 4 smoothing rules against the exact depth of the nuScenes twin (issue 37, the nuScenes `uncovered` gap).

    PYTHONPATH=. python -m benchmarks.studies.step4_edge_rules [--twin-seeds 0 1] [--scale 1] \
        [--hidden-seed 0] [--json benchmarks/results/step4_edge_rules.json]
    PYTHONPATH=. python -m benchmarks.studies.step4_edge_rules --real-check     # then: the real sample
    PYTHONPATH=. python -m benchmarks.studies.step4_edge_rules --side-choice    # then: the edge band's sides

The candidates a Step 4 change could be, written as post-processing of the SGM's own ``depth_raw``
(Step 4a and the column bracket; kept LiDAR pixels then keep their depth and the clip is Step 4's,
as :func:`jaxdepth._src.pipeline._complete_tail` does), so every one sees the very same seeds:

- ``gaussian``: Step 4's 7 x 7 Gaussian (sigma 1.4), checked equal to the library's ``depth``;
- ``none``: no smoothing (``depth_raw``);
- ``gaussian_s1.0_r2``, ``gaussian_s2.0_r5``: a weaker and a stronger Gaussian (the strength knob);
- ``stronger_far_from_seed``: sigma 2.0 where the pixel's seed is more than 3 px away (city block),
  Step 4's Gaussian elsewhere (strength following the seed distance);
- ``stronger_off_edges``: sigma 2.0 (radius 5) where the 11 x 11 window of ``depth_raw`` holds no depth
  more than max(1 m, 5 %) off the pixel's own (:func:`edge_pixels`), Step 4's Gaussian elsewhere;
- ``edge_hard``: the 7 x 7 Gaussian without the neighbours more than max(1 m, 5 %) off the pixel's own
  depth (``nuscenes_uncovered_gap``'s throw-away ``edge_aware_blur``);
- ``edge_soft``: neighbours weighted by exp(-dz^2 / 2 s^2), s = max(1 m, 10 %) of the pixel's depth;
- ``near_side``: only the neighbours *farther* by more than max(1 m, 5 %) left out (background is not
  averaged into a near surface; near surfaces still pull a background pixel nearer);
- ``edge_hard_on_line``, ``near_side_on_line``: those two only at pixels whose seed lies on their own row
  (scan-line pixels: the held-out protocol's targets), Step 4's Gaussian elsewhere.

Each is scored on the nuScenes twin (1 sweep, the single-sweep path a user's point file takes) against
the exact depth of every pixel (``exact_dense``: the rule's criterion) and, on one hold-out draw
(``hidden-eval``'s 20 %), against the exact depth at the held-out pixels and the two ``hidden-eval``
protocols. A rule becomes a default only if it wins ``exact_dense`` in RMSE and in MAE (docs/evaluation.md);
nothing here is chosen on a real set. ``--real-check`` adds the real nuScenes sample's ``uncovered`` score of
every rule (:func:`real_check`) and ``--side-choice`` the edge band's side choices (:func:`side_choice`) to the
JSON the first run wrote.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig

RULES = ("gaussian", "none", "gaussian_s1.0_r2", "gaussian_s2.0_r5", "stronger_far_from_seed", "stronger_off_edges",
         "edge_hard",
         "edge_soft", "near_side", "edge_hard_on_line", "near_side_on_line")
PROTOCOLS = ("exact_held_out", "hidden_all", "hidden_uncovered")


def weighted_blur(raw: np.ndarray, *, sigma_px: float = 1.4, radius_px: int = 3, rule: str = "all") -> np.ndarray:
    """(C, H, W) float32 Gaussian of ``raw`` (reflect-101 border) whose taps a depth rule may drop or weigh.

    ``rule``: ``"all"`` (the plain Gaussian), ``"hard"`` (taps more than max(1 m, 5 %) off the centre
    dropped), ``"soft"`` (weight exp(-dz^2 / 2 s^2), s = max(1 m, 10 %)), ``"near_side"`` (taps farther than
    the centre by more than max(1 m, 5 %) dropped); the weights are renormalised per pixel.
    """
    from jaxdepth._src.smoothing import gaussian_kernel_1d
    k = gaussian_kernel_1d(sigma_px, radius_px)
    r = radius_px
    _, h, w = raw.shape
    pad = np.pad(raw.astype(np.float64), ((0, 0), (r, r), (r, r)), mode="reflect")
    centre = raw.astype(np.float64)
    num = np.zeros_like(centre)
    den = np.zeros_like(centre)
    for i in range(2 * r + 1):
        for j in range(2 * r + 1):
            tap = pad[:, i:i + h, j:j + w]
            dz = tap - centre
            weight = {"all": 1.0,
                      "hard": np.abs(dz) <= np.maximum(1.0, 0.05 * centre),
                      "soft": np.exp(-0.5 * (dz / np.maximum(1.0, 0.10 * centre)) ** 2),
                      "near_side": dz <= np.maximum(1.0, 0.05 * centre)}[rule] * (k[i] * k[j])
            num += weight * tap
            den += weight
    return (num / den).astype(np.float32)


def edge_pixels(raw: np.ndarray, size: int) -> np.ndarray:
    """(C, H, W) bool: pixels with a seed whose ``size`` x ``size`` window of ``raw`` holds a depth more than
    max(1 m, 5 %) off their own (a depth edge within the window; pixels without a seed, 0, ignored)."""
    from scipy.ndimage import maximum_filter, minimum_filter
    near = minimum_filter(np.where(raw > 0, raw, np.inf), size=(1, size, size), mode="mirror")
    far = maximum_filter(raw, size=(1, size, size), mode="mirror")
    tol = np.maximum(1.0, 0.05 * raw)
    return (raw > 0) & ((raw - near > tol) | (far - raw > tol))


def rule_depths(stages) -> dict:
    """{rule: (C, H, W) depth} of every rule of :data:`RULES` from one run's (C, H, W) stages."""
    raw = np.asarray(stages.depth_raw)
    kept, sparse = np.asarray(stages.inlier_mask), np.asarray(stages.sparse_depth)
    has_seed = np.asarray(stages.seed_depth) > 0
    cfg = SGMConfig()

    def finish(depth):
        depth = np.where(kept, sparse, depth)
        return np.where(has_seed, np.clip(depth, cfg.min_depth_m, cfg.max_depth_m), 0.0).astype(np.float32)

    out = {"gaussian": finish(weighted_blur(raw)), "none": finish(raw),
           "gaussian_s1.0_r2": finish(weighted_blur(raw, sigma_px=1.0, radius_px=2)),
           "gaussian_s2.0_r5": finish(weighted_blur(raw, sigma_px=2.0, radius_px=5)),
           "edge_hard": finish(weighted_blur(raw, rule="hard")), "edge_soft": finish(weighted_blur(raw, rule="soft")),
           "near_side": finish(weighted_blur(raw, rule="near_side"))}
    du, dv = np.abs(np.asarray(stages.du)), np.asarray(stages.dv)
    out["stronger_far_from_seed"] = np.where(du + np.abs(dv) > 3, out["gaussian_s2.0_r5"], out["gaussian"])
    out["stronger_off_edges"] = np.where(edge_pixels(raw, 11), out["gaussian"], out["gaussian_s2.0_r5"])
    on_line = dv == 0
    out["edge_hard_on_line"] = np.where(on_line, out["edge_hard"], out["gaussian"])
    out["near_side_on_line"] = np.where(on_line, out["near_side"], out["gaussian"])
    library = np.asarray(stages.depth)
    out["max_abs_diff_to_library_m"] = float(np.max(np.abs(out["gaussian"] - library)))
    return out


def edge_band(stages, depths: dict, exact: list, rig) -> dict:
    """Where the Gaussian's gain and cost lie, against the exact depth of every pixel: the edge band (pixels
    whose 7 x 7 window of ``depth_raw`` holds a depth more than max(1 m, 5 %) off their own, i.e. where
    ``edge_hard`` drops a tap) and the rest; in the band, which side the exact depth is on: the pixel's own
    ``depth_raw`` (its seed's surface), the window's nearest or farthest depth, or none of them (each within
    max(1 m, 5 %)); and the squared / absolute error sums of ``gaussian`` and ``none`` in and out of the band
    (shares of the image's, pooled over cameras)."""
    from scipy.ndimage import maximum_filter, minimum_filter
    raw = np.asarray(stages.depth_raw)
    band = edge_pixels(raw, 7)
    near = minimum_filter(np.where(raw > 0, raw, np.inf), size=(1, 7, 7), mode="mirror")
    far = maximum_filter(raw, size=(1, 7, 7), mode="mirror")
    cut = lambda a: np.concatenate([np.asarray(a)[i, :cam.height, :cam.width].ravel()  # noqa: E731
                                    for i, cam in enumerate(rig.cameras)])
    ex = np.concatenate([e.ravel() for e in exact])
    seen = ex > 0
    band, r, n, f = (cut(a)[seen] for a in (band, raw, near, far))
    ex = ex[seen]
    right = lambda d: np.abs(d - ex) <= np.maximum(1.0, 0.05 * ex)  # noqa: E731
    out = {"band_share": float(band.mean()),
           "in_band_right_side": {"own_seed": float(right(r)[band].mean()), "nearest": float(right(n)[band].mean()),
                                  "farthest": float(right(f)[band].mean()),
                                  "none": float((~right(r) & ~right(n) & ~right(f))[band].mean())}}
    for rule in ("gaussian", "none"):
        err = cut(depths[rule])[seen] - ex
        out[rule] = {"sse_share_in_band": float(np.sum(err[band] ** 2) / np.sum(err ** 2)),
                     "sae_share_in_band": float(np.sum(np.abs(err[band])) / np.sum(np.abs(err))),
                     "sse_m2": float(np.sum(err ** 2)), "sae_m": float(np.sum(np.abs(err))),
                     "sse_in_band_m2": float(np.sum(err[band] ** 2)), "sae_in_band_m": float(np.sum(np.abs(err[band])))}
    return out


def _column_seed(kept: np.ndarray, *, upward: bool) -> np.ndarray:
    """(C, H, W): the nearest kept LiDAR depth at or above (``upward``; else at or below) each pixel in its
    column, 0 where there is none."""
    a = kept if upward else kept[:, ::-1]
    out = np.zeros_like(a)
    current = np.zeros((a.shape[0], a.shape[2]), a.dtype)
    for v in range(a.shape[1]):
        current = np.where(a[:, v] > 0, a[:, v], current)
        out[:, v] = current
    return out if upward else out[:, ::-1]


def side_choice(scene_seed: int, scale: float) -> dict:
    """In the edge band (:func:`edge_pixels`, 7 x 7) at pixels with a kept LiDAR pixel straight above and below
    in their column: how often each simple choice of side is within max(1 m, 5 %) of the exact depth (the
    SGM's ``depth_raw``; its seed's depth; the column seed above, below, the nearer or farther of the two);
    also where those two column seeds lie on different surfaces."""
    from benchmarks.accuracy_twins import single_path
    from benchmarks.studies.nuscenes_uncovered_gap import twin_input
    inp, exact = twin_input(scene_seed, scale)
    st = single_path(inp.cloud.points, inp.cloud.ring, inp.rig, SGMConfig(), stages=True)[0]
    raw = np.asarray(st.depth_raw)
    kept = np.where(np.asarray(st.inlier_mask), np.asarray(st.sparse_depth), 0.0)
    above, below = _column_seed(kept, upward=True), _column_seed(kept, upward=False)
    ex = np.zeros_like(raw)
    for i, e in enumerate(exact):
        ex[i, :e.shape[0], :e.shape[1]] = e
    both = edge_pixels(raw, 7) & (ex > 0) & (above > 0) & (below > 0)
    split = both & (np.abs(above - below) > np.maximum(1.0, 0.05 * np.minimum(above, below)))
    choices = {"depth_raw": raw, "seed_depth": np.asarray(st.seed_depth), "column_above": above,
               "column_below": below, "column_nearer_depth": np.minimum(above, below),
               "column_farther_depth": np.maximum(above, below)}
    right = {k: np.abs(d - ex) <= np.maximum(1.0, 0.05 * ex) for k, d in choices.items()}
    return {"scene_seed": scene_seed, "band_pixels_with_both": int(both.sum()), "split": int(split.sum()),
            "right_share": {k: float(r[both].mean()) for k, r in right.items()},
            "right_share_split": {k: float(r[split].mean()) for k, r in right.items()}}


def twin_case(scene_seed: int, hidden_seed: int, scale: float) -> dict:
    from benchmarks.accuracy_twins import (
        cover_half_height,
        crops,
        hold_out,
        protocol_truths,
        score,
        single_path,
    )
    from benchmarks.studies.nuscenes_uncovered_gap import twin_input
    inp, exact = twin_input(scene_seed, scale)
    strip = lambda s: {"rmse": s["rmse"], "mae": s["mae"]}  # noqa: E731
    stages = single_path(inp.cloud.points, inp.cloud.ring, inp.rig, SGMConfig(), stages=True)[0]
    full = rule_depths(stages)
    case = {"scene_seed": scene_seed, "hidden_seed": hidden_seed,
            "gaussian_vs_library_max_abs_m": {"full": full.pop("max_abs_diff_to_library_m")},
            "exact_dense": {r: strip(score(crops(full[r], inp.rig), exact)) for r in RULES},
            "edge_band": edge_band(stages, full, exact, inp.rig)}
    del stages
    hidden, targets, full_z = hold_out(inp, hidden_seed)
    truths, stats = protocol_truths(exact, targets, full_z, cover_half_height(inp))
    kept = inp.cloud.take(~hidden)
    held = rule_depths(single_path(kept.points, kept.ring, inp.rig, SGMConfig(), stages=True)[0])
    case["gaussian_vs_library_max_abs_m"]["held_out"] = held.pop("max_abs_diff_to_library_m")
    case["targets"] = stats
    for p in PROTOCOLS:
        case[p] = {r: strip(score(crops(held[r], inp.rig), truths[p])) for r in RULES}
    return case


def real_check(seeds) -> dict:
    """The real nuScenes sample under ``hidden-eval``'s ``uncovered`` score (draws ``seeds``, the targets of
    ``nuscenes_uncovered_gap``): RMSE / MAE (mm, mean over images) of every rule and the city-block fill.
    A check of a rule that won the twin, never a choice."""
    from benchmarks.studies import nuscenes_uncovered_gap as gap
    from jaxdepth.io import read_points, rig_from_nuscenes_calibration
    from jaxdepth.io.points import ring_column
    nus = gap.DATA / "nuscenes" / "sample"
    rig = rig_from_nuscenes_calibration(nus / "calibration.json")
    points, more = read_points(sorted(nus.glob("*LIDAR_TOP*.pcd.bin"))[0], columns=5)
    extra = lambda st, keep: {r: d[keep] for r, d in rule_depths(st).items() if r in RULES}  # noqa: E731
    p = gap._concat([gap.draw_pixels(points, ring_column(more, 5), rig, s, SGMConfig(), extra=extra)
                     for s in seeds])
    _, image = np.unique(p["image"], return_inverse=True)
    out = {}
    for m in RULES + ("sgm", "nearest"):
        err = np.abs(p[m] - p["z"])
        out[m] = {"rmse": float(1000 * np.mean(np.sqrt(np.bincount(image, err ** 2) / np.bincount(image)))),
                  "mae": float(1000 * np.sum(err * p["weight"]))}
    return out


def summary(cases: list) -> dict:
    """Per rule, protocol: the mean over scene seeds of RMSE / MAE and the change against ``gaussian`` (%),
    and whether the rule beats the Gaussian in both metrics on every seed."""
    out = {}
    for p in ("exact_dense",) + PROTOCOLS:
        rows = {}
        for r in RULES:
            mean = {m: float(np.mean([c[p][r][m] for c in cases])) for m in ("rmse", "mae")}
            base = {m: float(np.mean([c[p]["gaussian"][m] for c in cases])) for m in ("rmse", "mae")}
            rows[r] = {**mean, **{f"{m}_change_pct": 100 * (mean[m] / base[m] - 1) for m in ("rmse", "mae")},
                       "wins_both_every_seed": all(c[p][r][m] < c[p]["gaussian"][m] for c in cases
                                                   for m in ("rmse", "mae"))}
        out[p] = rows
    return out


def print_summary(summary: dict, width: int = 24) -> None:
    """Print a :func:`summary` (per protocol, per rule: mean RMSE / MAE, change, wins); lists of other
    entries (no ``rmse``) as one line."""
    for p, rows in summary.items():
        print(p)
        for r, v in rows.items():
            if not isinstance(v, dict):
                print(f"  {r:{width}s} {v:.4f}")
                continue
            print(f"  {r:{width}s} {v['rmse']:8.1f} / {v['mae']:6.1f}  ({v['rmse_change_pct']:+.2f} / "
                  f"{v['mae_change_pct']:+.2f} %){'  wins both' if v['wins_both_every_seed'] else ''}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--twin-seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--hidden-seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--real-check", nargs="*", type=int, default=None, metavar="SEED",
                        help="only the real nuScenes sample's uncovered score of every rule (draws SEED, default "
                             "0-4), to the JSON's real_check (kept: the twin's cases)")
    parser.add_argument("--side-choice", action="store_true",
                        help="only the edge band's side choices on the twin (--twin-seeds), to the JSON's side_choice")
    parser.add_argument("--json", default=str(RESULTS / "step4_edge_rules.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    if args.side_choice:
        import json
        import pathlib
        doc = json.loads(pathlib.Path(args.json).read_text())
        if "real_check" in doc:                 # the seconds of the run before (the real check's)
            doc["real_check"].setdefault("seconds", doc.get("seconds"))
        doc["side_choice"] = [side_choice(seed, args.scale) for seed in args.twin_seeds]
        print(json.dumps(doc["side_choice"], indent=1))
        write_results(args.json, {k: v for k, v in doc.items() if k not in ("config", "environment")}, SGMConfig(), t0)
        return 0
    if args.real_check is not None:
        import json
        import pathlib
        doc = json.loads(pathlib.Path(args.json).read_text())
        seeds = args.real_check or [0, 1, 2, 3, 4]
        doc.setdefault("twin_seconds", doc.get("seconds"))
        doc["real_check"] = {"seeds": seeds, "uncovered": real_check(seeds)}
        for m, v in doc["real_check"]["uncovered"].items():
            print(f"  {m:24s} {v['rmse']:8.1f} / {v['mae']:6.1f}")
        write_results(args.json, {k: v for k, v in doc.items() if k not in ("config", "seconds", "environment")},
                      SGMConfig(), t0)
        return 0
    cases = []
    for s in args.twin_seeds:
        cases.append(twin_case(s, args.hidden_seed, args.scale))
        print(f"scene seed {s} ({time.time() - t0:.0f} s)", flush=True)
        for p in ("exact_dense",) + PROTOCOLS:
            print(f"  {p}: " + ", ".join(f"{r} {v['rmse']:.1f} / {v['mae']:.1f}" for r, v in cases[-1][p].items()),
                  flush=True)
    doc = {"settings": {"twin": "nuscenes", "sweeps": 1, "twin_seeds": args.twin_seeds, "scale": args.scale,
                        "hidden_seed": args.hidden_seed, "rules": list(RULES)},
           "cases": cases, "summary": summary(cases)}
    write_results(args.json, doc, SGMConfig(), t0)
    print_summary(doc["summary"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
