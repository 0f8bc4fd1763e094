"""Which cover test finds the wrong ``hidden-eval`` targets on the twins (issue 37).

    PYTHONPATH=. python -m benchmarks.studies.cover_tests [--rigs kitti nuscenes av2] \
        [--scales 1 1 0.5] [--scene-seeds 0 1] [--hidden-seeds 0 1 2] [--json benchmarks/results/cover_tests.json]
    PYTHONPATH=. python -m benchmarks.studies.cover_tests --merge a.json b.json --json out.json

Each twin (1 sweep, each scene seed, the camera scale given) is read as ``complete-rig`` reads it and
held out as :mod:`benchmarks.accuracy_twins` does (20 % of the points at >= 1 m, per hold-out seed);
every method of its :data:`~benchmarks.accuracy_twins.METHODS` runs once on the rest. The held-out
points' z-buffer is then filtered by each cover-test variant below (every one reads only the sweep's
z-buffer ``full`` and the targets, never a prediction), and each variant is scored by

- ``wrong_dropped``: the share of wrong targets (off the exact depth by > max(1 m, 5 %)) it drops,
- ``right_dropped``: the share of the other targets it drops,
- the pair-ranking agreement with ``exact_dense`` (as accuracy_twins' agreement table: the share of
  method pairs, tied pairs under the exact depth left out, that its score ranks as the exact depth does),
- ``agree_kept``: the same against the exact depth at the very pixels the variant keeps (only the
  targets' own error can then flip a pair; where a run recorded it).

Variants (h = ``hidden-eval``'s half height, the scan-line spacing in rows rounded up; a point
"nearer" when nearer than the target by more than max(1 m, 5 %)): ``all`` (no test: ``hidden_all``);
``both_sides`` (today's :func:`~jaxdepth.research.hidden.covered_targets`: nearer points above and
below, rows 1..h, columns -2..2, or left and right, columns 1..h, rows -1..1); ``one_side`` (a nearer
point in any one of those four half windows); ``row_one_side`` (left or right only); ``both_or_row``
(``both_sides`` or ``row_one_side``); ``same_pixel`` (a nearer sweep point wins the target's own
pixel); ``open_5`` / ``open_9`` (a nearer point anywhere in the 5 x 5 / 9 x 9 window, the issue's
"open" test at 9); ``directed`` (a nearer point in today's cross-shaped window, rows -h..h at
columns -2..2 and columns -h..h at rows -1..1, on the side away from the LiDAR: :func:`toward_lidar`,
the parallax direction, from the camera and the LiDAR origin only); ``directed_box`` (the same in the
whole (2h + 1)^2 box); ``both_or_directed``; ``directed_toward`` (``directed`` on the side towards
the LiDAR: a control for the direction); ``oracle`` (drops exactly the wrong targets: reads the exact depth, a bound, not
a test).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import tempfile
import time

import jax.numpy as jnp
import numpy as np

from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig

VARIANTS = ("all", "both_sides", "one_side", "row_one_side", "both_or_row", "same_pixel", "open_5", "open_9",
            "directed", "directed_box", "both_or_directed", "directed_toward", "oracle")


def variant_masks(target: np.ndarray, full: np.ndarray, half: int) -> dict:
    """{variant: (H, W) bool dropped targets} of one camera (``oracle`` is added by the caller)."""
    from jaxdepth.research.hidden import _OCCLUSION_MARGIN_M, _OCCLUSION_MARGIN_REL, _window_min, covered_targets
    t = jnp.asarray(target, jnp.float32)
    near = jnp.where(jnp.asarray(full) > 0, jnp.asarray(full), jnp.inf).astype(jnp.float32)
    limit = t - jnp.maximum(_OCCLUSION_MARGIN_M, _OCCLUSION_MARGIN_REL * t)

    def nearer(rows, cols):
        return np.asarray(_window_min(near, rows, cols) < limit)

    h = int(half)
    up, down = nearer((-h, -1), (-2, 2)), nearer((1, h), (-2, 2))
    left, right = nearer((-1, 1), (-h, -1)), nearer((-1, 1), (1, h))
    has = target > 0
    out = {"all": np.zeros_like(has),
           "both_sides": np.asarray(covered_targets(t, jnp.asarray(full), half_height_px=h)),
           "one_side": has & (up | down | left | right),
           "row_one_side": has & (left | right),
           "same_pixel": has & nearer((0, 0), (0, 0)),
           "open_5": has & nearer((-2, 2), (-2, 2)),
           "open_9": has & nearer((-4, 4), (-4, 4))}
    out["both_or_row"] = out["both_sides"] | out["row_one_side"]
    return out


def toward_lidar(u, v, K, T_cam_ref, origin) -> tuple:
    """Image direction (du, dv), up to a positive factor, in which a point at pixel (u, v) moves when slid
    towards the LiDAR origin ``origin`` (reference frame), whatever its depth: (fx c_x - (u - cx) c_z,
    fy c_y - (v - cy) c_z) with c the origin in camera coordinates (d/dt of the projection of
    P + t (c - P) at t = 0, times z). An occluder that hides a point from the camera but not from the
    LiDAR covers the point's pixel and lies on the side away from this direction."""
    K, T = np.asarray(K, np.float64), np.asarray(T_cam_ref, np.float64)
    c = T[:3, :3] @ np.asarray(origin, np.float64) + T[:3, 3]
    return K[0, 0] * c[0] - (u - K[0, 2]) * c[2], K[1, 1] * c[1] - (v - K[1, 2]) * c[2]


def directed_cover(target, full, K, T_cam_ref, origin, offsets, *, side: int = -1) -> np.ndarray:
    """(H, W) bool: targets with a nearer sweep point (by > max(1 m, 5 %)) at one of ``offsets`` (dy, dx)
    on the side away from the LiDAR (:func:`toward_lidar` . offset < 0; ``side=1``: towards it, a control).
    Brute force over targets."""
    out = np.zeros(target.shape, bool)
    v, u = np.nonzero(target > 0)
    z = target[v, u].astype(np.float64)
    limit = z - np.maximum(1.0, 0.05 * z)
    du, dv = toward_lidar(u, v, K, T_cam_ref, origin)
    hit = np.zeros(len(v), bool)
    H, W = target.shape
    for dy, dx in offsets:
        qy, qx = v + dy, u + dx
        inside = (qy >= 0) & (qy < H) & (qx >= 0) & (qx < W) & (side * (dx * du + dy * dv) > 0)
        f = np.where(inside, full[np.clip(qy, 0, H - 1), np.clip(qx, 0, W - 1)], 0.0)
        hit |= inside & (f > 0) & (f < limit)
    out[v, u] = hit
    return out


def run_twin(rig: str, scale: float, scene_seed: int, hidden_seeds, config: SGMConfig, variants=VARIANTS,
             extra=None) -> dict:
    """One twin case. ``extra(masks, targets, full, wrong, inp, hidden, half, draw, preds, exact)``, if given, may
    add variant masks (to each camera's dict of ``masks``) and records (to ``draw``) before ``variants`` are
    scored."""
    from benchmarks.accuracy_twins import (METHODS, cover_half_height, exact_truth, hold_out, predictions,
                                           read_user_input, score)
    from jaxdepth.research.twins import make_twin, write_twin
    twin = make_twin(rig, sweeps=1, seed=scene_seed, scale=scale)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(twin, tmp)
        inp = read_user_input(paths["sweeps"][0], paths["rig"])
    exact = exact_truth(twin, inp.rig)
    half = cover_half_height(inp)
    case = {"rig": rig, "scene_seed": scene_seed, "scale": float(scale), "camera_sizes": [[int(c.width), int(c.height)] for c in inp.rig.cameras],
            "cover_half_height_px": int(half), "held_out": []}
    for hs in hidden_seeds:
        hidden, targets, full = hold_out(inp, hs)
        preds = predictions(inp, ~hidden, config)
        masks = [variant_masks(t, f, half) for t, f in zip(targets, full)]
        cross = {(dy, dx) for dy in range(-half, half + 1) for dx in range(-2, 3)}
        cross |= {(dy, dx) for dy in range(-1, 2) for dx in range(-half, half + 1)}
        box = [(dy, dx) for dy in range(-half, half + 1) for dx in range(-half, half + 1)]
        origin = inp.cloud.origins_m[0]
        for m, t, f, cam in zip(masks, targets, full, inp.rig.cameras):
            m["directed"] = directed_cover(t, f, cam.K, cam.T_cam_lidar, origin, sorted(cross))
            m["directed_box"] = directed_cover(t, f, cam.K, cam.T_cam_lidar, origin, box)
            m["both_or_directed"] = m["both_sides"] | m["directed"]
            m["directed_toward"] = directed_cover(t, f, cam.K, cam.T_cam_lidar, origin, sorted(cross), side=1)
        wrong = [(t > 0) & (np.abs(t - e) > np.maximum(1.0, 0.05 * e)) for t, e in zip(targets, exact)]
        for m, w in zip(masks, wrong):
            m["oracle"] = w
        n = sum(int((t > 0).sum()) for t in targets)
        n_wrong = sum(int(w.sum()) for w in wrong)
        draw = {"hidden_seed": hs, "targets": n, "wrong_targets": n_wrong,
                "scores": {"exact_dense": {m: score(preds[m], exact) for m in METHODS}}, "variants": {}}
        if extra is not None:
            extra(masks, targets, full, wrong, inp, hidden, half, draw, preds, exact)
        for v in variants:
            drop = [m[v] for m in masks]
            d_wrong = sum(int((d & w).sum()) for d, w in zip(drop, wrong))
            d_all = sum(int(d.sum()) for d in drop)
            truth = [np.where(d, 0.0, t).astype(np.float32) for d, t in zip(drop, targets)]
            draw["variants"][v] = {"dropped": d_all, "dropped_share": d_all / max(n, 1),
                                   "wrong_dropped": d_wrong / max(n_wrong, 1),
                                   "right_dropped": (d_all - d_wrong) / max(n - n_wrong, 1),
                                   "wrong_left_share": (n_wrong - d_wrong) / max(n - d_all, 1)}
            draw["scores"][v] = {m: score(preds[m], truth) for m in METHODS}
            kept = [np.where(t > 0, e, 0.0).astype(np.float32) for t, e in zip(truth, exact)]
            draw["scores"][f"exact_kept/{v}"] = {m: score(preds[m], kept) for m in METHODS}
        case["held_out"].append(draw)
    return case


def pair_agreement(ref_got, metric: str) -> tuple:
    """(agreeing, pairs) over ``ref_got`` ((reference, scored) {method: {metric}} dicts, e.g. one per draw): the
    method pairs the reference does not tie, and those the scored dict ranks the same way."""
    from benchmarks.accuracy_twins import METHODS, _sign
    agree = pairs = 0
    for ref, got in ref_got:
        for i, a in enumerate(METHODS):
            for b in METHODS[i + 1:]:
                s = _sign(ref[a][metric], ref[b][metric])
                if s:
                    pairs += 1
                    agree += int(_sign(got[a][metric], got[b][metric]) == s)
    return agree, pairs


def summarise(cases: list, variants=None) -> dict:
    """{rig or "overall": {variant: {wrong_dropped, right_dropped, dropped_share (means over hold-outs),
    agree_rmse_pct, agree_mae_pct, pairs}}} (``variants``: default those the first draw scored)."""
    variants = list(cases[0]["held_out"][0]["variants"]) if variants is None else variants
    out = {}
    for key in list(dict.fromkeys(c["rig"] for c in cases)) + ["overall"]:
        mine = [d for c in cases if key in (c["rig"], "overall") for d in c["held_out"]]
        row = {}
        for v in variants:
            r = {k: float(np.mean([d["variants"][v][k] for d in mine]))
                 for k in ("wrong_dropped", "right_dropped", "dropped_share", "wrong_left_share")}
            for metric, ref_key, name in [(m, r, n) for r, n in (("exact_dense", "agree"), ("exact_kept", "agree_kept"))
                                          for m in ("rmse", "mae")]:
                if any(f"exact_kept/{v}" not in d["scores"] for d in mine) and ref_key == "exact_kept":
                    continue
                agree, pairs = pair_agreement(((d["scores"]["exact_dense" if ref_key == "exact_dense"
                                                          else f"exact_kept/{v}"], d["scores"][v]) for d in mine), metric)
                r[f"{name}_{metric}_pct"] = 100.0 * agree / max(pairs, 1)
                r["pairs" if name == "agree" else "pairs_kept"] = pairs
            row[v] = r
        out[key] = row
    return out


def table(summary: dict) -> str:
    lines = ["| variant | " + " | ".join(summary) + " |", "|---|" + "---|" * len(summary)]
    for v in next(iter(summary.values())):
        cells = [f"{r[v]['wrong_dropped'] * 100:.0f} / {r[v]['right_dropped'] * 100:.1f} % ; "
                 f"{r[v]['agree_rmse_pct']:.0f} / {r[v]['agree_mae_pct']:.0f} %" for r in summary.values()]
        lines.append(f"| `{v}` | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def study_parser(description: str, rigs, scales, json_path) -> argparse.ArgumentParser:
    """The command line of this study and of those that reuse its runs (:mod:`benchmarks.studies.cover_scan`)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--rigs", nargs="+", default=list(rigs))
    parser.add_argument("--scales", nargs="+", type=float, default=list(scales),
                        help="camera scale of each rig of --rigs, in order")
    parser.add_argument("--scene-seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--hidden-seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--merge", nargs="+", metavar="JSON", help="write --json from these files' cases and exit")
    parser.add_argument("--json", default=str(json_path))
    return parser


def collect_cases(args, parser, config: SGMConfig, t0: float, variants=VARIANTS, extra=None) -> tuple:
    """(cases, merged_from): ``--merge``'s files' cases, else one :func:`run_twin` per rig and scene seed."""
    if args.merge:
        parts = [json.loads(pathlib.Path(f).read_text()) for f in args.merge]
        return ([c for part in parts for c in part["cases"]],
                [{"rigs": sorted({c["rig"] for c in part["cases"]}), "seconds": part["seconds"]} for part in parts])
    if len(args.scales) != len(args.rigs):
        parser.error(f"--scales: expected one per rig ({len(args.rigs)}), got {len(args.scales)}")
    cases = []
    for rig, scale in zip(args.rigs, args.scales):
        for scene in args.scene_seeds:
            cases.append(run_twin(rig, scale, scene, args.hidden_seeds, config, variants, extra))
            print(f"{rig} scale {scale:g} scene {scene} done ({time.time() - t0:.0f} s)", flush=True)
    return cases, []


def main(argv=None) -> int:
    parser = study_parser(__doc__.splitlines()[0], ("kitti", "nuscenes", "av2"), (1.0, 1.0, 0.5),
                          RESULTS / "cover_tests.json")
    args = parser.parse_args(argv)
    t0 = time.time()
    config = SGMConfig()
    cases, merged_from = collect_cases(args, parser, config, t0)
    doc = {"settings": {"sweeps": 1, "fraction": 0.2, "min_range_m": 1.0,
                        "variants": list(VARIANTS)},
           "summary": summarise(cases), "cases": cases}
    if merged_from:
        doc["merged_from"] = merged_from
    print("cells: wrong dropped / right dropped ; agreement RMSE / MAE")
    print(table(doc["summary"]))
    write_results(args.json, doc, config, t0, indent=None)   # per-target records: 1.5 MB on one line
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
