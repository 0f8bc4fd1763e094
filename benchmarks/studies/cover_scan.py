"""Cover tests in scan lines: which held-out targets are hidden from the camera, by edge class (issue 37, coverscan).

    PYTHONPATH=. python -m benchmarks.studies.cover_scan [--rigs nuscenes kitti] [--scales 0.5 0.5] \
        [--scene-seeds 0 1] [--hidden-seeds 0 1 2] [--json benchmarks/results/cover_scan_coverscan_half.json]
    PYTHONPATH=. python -m benchmarks.studies.cover_scan --merge a.json b.json --json out.json

The twins' hold-out, methods and scores of :mod:`benchmarks.studies.cover_tests` (1 sweep; a target is
*wrong* when its own depth is off the exact camera depth at its pixel by > max(1 m, 5 %): the held-out point
is hidden from the camera, LiDAR-camera parallax), with two additions:

- every target's class of :func:`benchmarks.studies.edge_band_side.edge_class` (edgeline2: a depth edge of
  the kept input within 9 x 9 px; only in the seed window, scaled in scan lines as edgeline2's
  ``--window scanline``; none), judged on the z-buffer of the input points (the reference sweep less the
  held-out points), and per class the targets, the wrong ones and what each variant drops of both;
- variants whose window is set in scan lines (h: ``hidden-eval``'s half height, the largest camera's
  scan-line spacing in rows rounded up; "nearer": by > max(1 m, 5 %); every one reads only the input
  sweep's z-buffer and, for the directed ones, the camera and the LiDAR origin):
  ``scan_open_c2_k`` / ``scan_open_c4_k`` (a nearer point anywhere in rows -kh..kh, columns -2..2 / -4..4:
  the issue's open 9 x 9 test stretched to reach the neighbouring scan lines), ``scan_above`` /
  ``scan_below`` (rows -h..-1 / 1..h, columns -2..2), ``scan_both_2`` (today's test with its vertical arms
  2h long), ``scan_directed_c2_k`` (rows -kh..kh, columns -2..2, on the side away from the LiDAR: the
  parallax side of :func:`benchmarks.studies.cover_tests.toward_lidar`).
"""

from __future__ import annotations

import time

import jax.numpy as jnp
import numpy as np

from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig

BASE = ("all", "both_sides", "open_9", "directed", "oracle")
SCAN = ("scan_open_c2_1", "scan_open_c2_1.5", "scan_open_c4_1", "scan_above", "scan_below", "scan_both_2",
        "scan_directed_c2_1", "scan_directed_c2_1.5")
VARIANTS = BASE + SCAN
CLOSE_M = 0.1
# per class, scored (targets each keeps, and the exact depth at those pixels): ``uncovered`` (both_sides
# with "both_sides_oracle" less the wrong targets too) and some scan variants; ``close`` keeps only the targets
# within CLOSE_M of the exact depth (reads the truth: a bound, not a test)
CLASS_VARIANTS = ("all", "both_sides", "both_sides_oracle", "scan_open_c2_1", "scan_above", "scan_directed_c2_1",
                  "oracle", "close")
CLASSES = ("edge within 9 x 9", "edge in the seed window only", "no edge in the seed window")


def scan_masks(target: np.ndarray, full: np.ndarray, half: int, K, T_cam_ref, origin) -> dict:
    """{variant: (H, W) bool dropped targets} of :data:`SCAN` for one camera (reads the input z-buffer only)."""
    from benchmarks.studies.cover_tests import directed_cover
    from jaxdepth.research.hidden import _OCCLUSION_MARGIN_M, _OCCLUSION_MARGIN_REL, _window_min, covered_targets
    t = jnp.asarray(target, jnp.float32)
    near = jnp.where(jnp.asarray(full) > 0, jnp.asarray(full), jnp.inf).astype(jnp.float32)
    limit = t - jnp.maximum(_OCCLUSION_MARGIN_M, _OCCLUSION_MARGIN_REL * t)
    has = target > 0

    def nearer(rows, cols):
        return has & np.asarray(_window_min(near, rows, cols) < limit)

    h = int(half)
    rows = {k: max(1, int(np.floor(k * h + 0.5))) for k in (1, 1.5)}
    out = {f"scan_open_c2_{k:g}": nearer((-r, r), (-2, 2)) for k, r in rows.items()}
    out["scan_open_c4_1"] = nearer((-h, h), (-4, 4))
    out["scan_above"], out["scan_below"] = nearer((-h, -1), (-2, 2)), nearer((1, h), (-2, 2))
    out["scan_both_2"] = np.asarray(covered_targets(t, jnp.asarray(full), half_height_px=2 * h, half_width_px=h))
    for k, r in rows.items():
        offsets = [(dy, dx) for dy in range(-r, r + 1) for dx in range(-2, 3)]
        out[f"scan_directed_c2_{k:g}"] = directed_cover(target, full, K, T_cam_ref, origin, offsets)
    return out


def add_scan(masks, targets, full, wrong, inp, hidden, half, draw, preds, exact, *, variants=VARIANTS,
             class_variants=CLASS_VARIANTS) -> None:
    """``cover_tests.run_twin``'s hook: the :data:`SCAN` masks and the per-class counts of one hold-out (of
    ``variants``, already in ``masks`` but for :data:`SCAN`), and per class every method's score on the targets
    each of ``class_variants`` keeps (``V``) and on the exact depth at those pixels (``exact/V``)."""
    from benchmarks.accuracy_twins import METHODS, score, z_buffers
    from benchmarks.studies.edge_band_side import edge_class, window_radii
    K = np.stack([np.asarray(c.K, np.float64) for c in inp.rig.cameras])
    rv, ru, _ = window_radii("scanline", K, inp.rig.lidar)
    c = inp.cloud
    kept = z_buffers(c.points[(c.sweep[c.source] == 0) & ~hidden], inp.rig)
    origin = c.origins_m[0]
    counts = {name: {"targets": 0, "wrong": 0, "dropped_wrong": {}, "dropped_right": {}} for name in CLASSES}
    classes = []
    for m, t, f, w, s, cam in zip(masks, targets, full, wrong, kept, inp.rig.cameras):
        m.update(scan_masks(t, f, half, cam.K, cam.T_cam_lidar, origin))
        m["both_sides_oracle"] = m["both_sides"] | w
        cls = edge_class(np.asarray(s, np.float64)[None], np.asarray(t, np.float64)[None], rv, ru)[0]
        classes.append(cls)
        for k, name in enumerate(CLASSES):
            at = cls == k
            r = counts[name]
            r["targets"] += int(at.sum())
            r["wrong"] += int((at & w).sum())
            for v in variants:
                r["dropped_wrong"][v] = r["dropped_wrong"].get(v, 0) + int((at & w & m[v]).sum())
                r["dropped_right"][v] = r["dropped_right"].get(v, 0) + int((at & ~w & m[v]).sum())
    for m, t, e in zip(masks, targets, exact):
        m["close"] = (t > 0) & (np.abs(t - e) > CLOSE_M)
    for k, name in enumerate(CLASSES):
        if not counts[name]["targets"]:
            continue
        truths = {}
        for v in class_variants:
            keep = [(c == k) & ~m[v] for c, m in zip(classes, masks)]
            truths[v] = [np.where(a, t, 0.0) for a, t in zip(keep, targets)]
            truths[f"exact/{v}"] = [np.where(a, e, 0.0) for a, e in zip(keep, exact)]
        counts[name]["scores"] = {p: {mt: {key: score(preds[mt], tr)[key] for key in ("rmse", "mae")}
                                      for mt in METHODS} for p, tr in truths.items()}
    draw["seed_window_rows_cols"] = [2 * rv + 1, 2 * ru + 1]
    draw["by_class"] = counts


def class_table(cases: list, variants=VARIANTS) -> str:
    """Per rig and class, summed over draws: share of targets, wrong share, and the share of the wrong ones
    ``both_sides`` (today's ``uncovered``) keeps, then wrong / right dropped by each scan variant."""
    lines = []
    for rig in dict.fromkeys(c["rig"] for c in cases):
        draws = [d for c in cases if c["rig"] == rig for d in c["held_out"]]
        n_all = sum(d["targets"] for d in draws)
        lines.append(f"{rig}:")
        for name in CLASSES:
            tot = {k: sum(d["by_class"][name][k] for d in draws) for k in ("targets", "wrong")}
            drop = {v: (sum(d["by_class"][name]["dropped_wrong"][v] for d in draws),
                        sum(d["by_class"][name]["dropped_right"][v] for d in draws)) for v in variants}
            nt, nw = max(tot["targets"], 1), max(tot["wrong"], 1)
            lines.append(f"  {name}: {100 * tot['targets'] / max(n_all, 1):.1f} % of targets, "
                         f"{100 * tot['wrong'] / nt:.1f} % wrong, uncovered keeps "
                         f"{100 * (tot['wrong'] - drop['both_sides'][0]) / nw:.0f} % of those; "
                         + ", ".join(f"{v} {100 * a / nw:.0f}/{100 * b / max(nt - tot['wrong'], 1):.1f}"
                                     for v, (a, b) in drop.items() if v not in ("all", "oracle")))
    return "\n".join(lines)


def held_out_agreement(cases: list, variants=VARIANTS) -> dict:
    """{rig or "overall": {variant: {"agree_{rmse,mae}_pct", "pairs"}}}: pairs each variant ranks as the exact
    depth at every held-out pixel (``exact_kept/all``) does (tied pairs there left out)."""
    from benchmarks.studies.cover_tests import pair_agreement
    out = {}
    for key in list(dict.fromkeys(c["rig"] for c in cases)) + ["overall"]:
        draws = [d for c in cases if key in (c["rig"], "overall") for d in c["held_out"]]
        out[key] = {}
        for v in variants:
            r = {}
            for metric in ("rmse", "mae"):
                agree, pairs = pair_agreement(((d["scores"]["exact_kept/all"], d["scores"][v]) for d in draws), metric)
                r[f"agree_{metric}_pct"], r["pairs"] = 100.0 * agree / max(pairs, 1), pairs
            out[key][v] = r
    return out


def class_agreement(cases: list, class_variants=CLASS_VARIANTS) -> dict:
    """{rig: {class: {variant: {"agree_{rmse,mae}_pct": against the exact depth at the class's every target,
    "agree_kept_{rmse,mae}_pct": at the pixels the variant keeps, "pairs", "sgm_minus_nearest_mae_mm":
    {"targets", "exact_kept"} (mean over draws)}}}} (pairs tied under the reference left out)."""
    from benchmarks.studies.cover_tests import pair_agreement
    out = {}
    for rig in dict.fromkeys(c["rig"] for c in cases):
        draws = [d for c in cases if c["rig"] == rig for d in c["held_out"]]
        out[rig] = {}
        for name in CLASSES:
            sc = [d["by_class"][name]["scores"] for d in draws if "scores" in d["by_class"][name]]
            if not sc:
                continue
            row = {}
            for v in class_variants:
                r = {"sgm_minus_nearest_mae_mm": {
                    w: float(np.mean([s[p]["sgm"]["mae"] - s[p]["nearest"]["mae"] for s in sc]))
                    for w, p in (("targets", v), ("exact_kept", f"exact/{v}"))}}
                for ref_name, ref_key in (("agree", "exact/all"), ("agree_kept", f"exact/{v}")):
                    for metric in ("rmse", "mae"):
                        agree, pairs = pair_agreement(((s[ref_key], s[v]) for s in sc), metric)
                        r[f"{ref_name}_{metric}_pct"] = 100.0 * agree / max(pairs, 1)
                        r["pairs"] = pairs
                row[v] = r
            out[rig][name] = row
    return out


def print_report(doc: dict, cases: list, variants=VARIANTS) -> None:
    """Print the summary table, the agreement at the held-out pixels and the per-class drops."""
    from benchmarks.studies.cover_tests import table
    print("cells: wrong dropped / right dropped ; agreement with the exact dense depth, RMSE / MAE")
    print(table(doc["summary"]))
    print("agreement with the exact depth at every held-out pixel, RMSE / MAE:")
    for key, row in doc["held_out_agreement"].items():
        print(f"  {key}: " + ", ".join(f"{v} {r['agree_rmse_pct']:.0f} / {r['agree_mae_pct']:.0f}" for v, r in row.items()))
    print("by class (wrong dropped / right dropped, %):")
    print(class_table(cases, variants))


def main(argv=None) -> int:
    from benchmarks.studies.cover_tests import collect_cases, study_parser, summarise
    parser = study_parser(__doc__.splitlines()[0], ("nuscenes", "kitti"), (0.5, 0.5),
                          RESULTS / "cover_scan_coverscan_half.json")
    args = parser.parse_args(argv)
    t0 = time.time()
    config = SGMConfig()
    cases, merged_from = collect_cases(args, parser, config, t0, VARIANTS, add_scan)
    doc = {"settings": {"sweeps": 1, "fraction": 0.2, "min_range_m": 1.0, "variants": list(VARIANTS),
                        "scales": {c["rig"]: c["scale"] for c in cases}},
           "summary": summarise(cases, VARIANTS), "held_out_agreement": held_out_agreement(cases),
           "class_agreement": class_agreement(cases), "cases": cases}
    if merged_from:
        doc["merged_from"] = merged_from
    print_report(doc, cases)
    print("by class: agreement with the exact depth at the class's targets / at the kept pixels (RMSE / MAE), "
          "SGM - city block MAE, mm, targets / exact at the kept pixels:")
    for rig, rows in doc["class_agreement"].items():
        for name, row in rows.items():
            print(f"  {rig}, {name}:")
            for v, r in row.items():
                d = r["sgm_minus_nearest_mae_mm"]
                print(f"    {v:22s} {r['agree_rmse_pct']:3.0f} / {r['agree_mae_pct']:3.0f} %, kept "
                      f"{r['agree_kept_rmse_pct']:3.0f} / {r['agree_kept_mae_pct']:3.0f} % ({r['pairs']} pairs); "
                      f"{d['targets']:+.1f} / {d['exact_kept']:+.1f}")
    write_results(args.json, doc, config, t0, indent=None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
