"""Scan-line and parallax cover tests on every twin (issue 37, coverscan2).

    PYTHONPATH=. python -m benchmarks.studies.cover_scan2 [--rigs kitti nuscenes av2 raster rosette] \
        [--scales 0.5 0.5 0.5 0.5 0.5] [--scene-seeds 0 1] [--hidden-seeds 0 1 2] \
        [--json benchmarks/results/cover_scan2_coverscan2_half.json]
    PYTHONPATH=. python -m benchmarks.studies.cover_scan2 --merge a.json b.json --json out.json

:mod:`benchmarks.studies.cover_scan` (its hold-out, methods, scores, edge classes and variants) with these
tests added; each reads only the sweep's z-buffer ``full``, the targets, the camera and the LiDAR origin
(the reference sweep's first source: :func:`benchmarks.studies.cover_tests.run_twin`'s), never a
prediction or the exact depth; "nearer" is by > max(1 m, 5 %) as ``uncovered``:

- ``rule_c2`` / ``rule_c4``: coverscan's per-rig rule, ``scan_open_c2_1`` / ``scan_open_c4_1`` where
  ``hidden-eval``'s half height h exceeds 4 px (the 9 x 9 test's reach), else ``both_sides`` (``uncovered``);
- ``parallax_w{w}_k{k}`` (w = 1, 2; k = 0.5, 1): the parallax test. A point Q of depth z_Q on the LiDAR ray
  of a target P (depth z_P, pixel (u, v)) appears in the camera displaced from P's pixel by exactly
  t / z_Q * (fx c_x - (u - cx) c_z, fy c_y - (v - cy) c_z), t = (z_P - z_Q) / (z_P - c_z) (c the LiDAR origin in
  camera coordinates; the vector is :func:`benchmarks.studies.cover_tests.toward_lidar`): its parallax
  ``shift`` towards the LiDAR. A nearer surface the LiDAR sees beside P hides P from the camera when its
  edge, so shifted, passes P's pixel. Along each line parallel to that direction through the pixel's
  neighbours -w..w px across it, on each side, the first sweep point met (within 3 h px) drops the target
  when it is nearer and lies between ``shift`` towards the LiDAR and k ``shift`` away from it (+- 0.5 px):
  for k = 1, the unseen edge between that point and P's ray is more likely than not across the pixel. Only
  the first point counts, so a surface sloping up to the target (the ground before a wall) does not;
- ``uncovered_or_parallax_w{w}_k{k}``: ``uncovered`` or the parallax test;
- ``local_open`` / ``local_directed``: rows -s..s, columns -2..2 (``local_directed``: on the side away from
  the LiDAR only), s the scan-line spacing at the target's own row, rounded up: the median over columns of the
  gap between consecutive sweep points in the column that spans the row (gaps > 3 h left out).
"""

from __future__ import annotations

import time

import jax.numpy as jnp
import numpy as np

from benchmarks._common import RESULTS, write_results
from benchmarks.studies import cover_scan
from jaxdepth._src.config import SGMConfig

PARALLAX = tuple(f"{pre}parallax_w{w}_k{k}" for pre in ("", "uncovered_or_") for w in (1, 2) for k in ("0.5", "1"))
NEW = ("rule_c2", "rule_c4") + PARALLAX + ("local_open", "local_directed")
VARIANTS = cover_scan.VARIANTS + NEW
CLASS_VARIANTS = cover_scan.CLASS_VARIANTS + ("rule_c2", "uncovered_or_parallax_w1_k0.5", "uncovered_or_parallax_w2_k0.5",
                                              "uncovered_or_parallax_w2_k1")
RULE_MIN_PX = 4
WIDTH_PX = 2


def parallax_cover(target, full, K, T_cam_ref, origin, ks, reach: int, width: int, source=None) -> dict:
    """{k: (H, W) bool} of the parallax test with factor k, for each k of ``ks`` (see the module docstring):
    along each of the 2 ``width`` + 1 lines parallel to the target's parallax direction (offset -width..width px
    across it), on each side, the first sweep point met within ``reach`` px (the target's own pixel left out).
    ``origin``: one LiDAR origin (3,), or with ``source`` ((H, W) int, the LiDAR each target pixel came from)
    the (S, 3) origins, each target's direction and shift then from its own LiDAR (coverscan3)."""
    T, K = np.asarray(T_cam_ref, np.float64), np.asarray(K, np.float64)
    cams = np.stack([T[:3, :3] @ o + T[:3, 3] for o in np.atleast_2d(np.asarray(origin, np.float64))])
    H, W = target.shape
    v, u = np.nonzero(target > 0)
    c = cams[np.zeros(len(v), np.int64) if source is None else np.asarray(source)[v, u]]
    cz = c[:, 2]
    zp = target[v, u].astype(np.float64)
    limit = zp - np.maximum(1.0, 0.05 * zp)
    du, dv = K[0, 0] * c[:, 0] - (u - K[0, 2]) * cz, K[1, 1] * c[:, 1] - (v - K[1, 2]) * cz
    norm = np.hypot(du, dv)
    ux, uy = du / np.maximum(norm, 1e-12), dv / np.maximum(norm, 1e-12)
    hits = {k: np.zeros(len(v), bool) for k in ks}
    for p in range(-width, width + 1):
        for side in (-1, 1):
            seen = np.zeros(len(v), bool)
            for a in range(1, reach + 1):
                s = side * a
                qx = np.rint(u + s * ux - p * uy).astype(np.int64)
                qy = np.rint(v + s * uy + p * ux).astype(np.int64)
                inside = (qy >= 0) & (qy < H) & (qx >= 0) & (qx < W)
                zq = np.where(inside, full[np.clip(qy, 0, H - 1), np.clip(qx, 0, W - 1)], 0.0).astype(np.float64)
                first = inside & (zq > 0) & ((qx != u) | (qy != v)) & ~seen
                near = first & (zq < limit)
                shift = np.where(near, norm * (zp - zq) / np.maximum(zp - cz, 1e-9) / np.maximum(zq, 1e-9), 0.0)
                for k in ks:
                    hits[k] |= near & (s <= shift + 0.5) & (s >= -k * shift - 0.5)
                seen |= first
    out = {}
    for k in ks:
        m = np.zeros(target.shape, bool)
        m[v, u] = hits[k]
        out[k] = m
    return out


def row_spacing(full: np.ndarray, max_gap: int) -> np.ndarray:
    """(H,) the scan-line spacing at each row: the median over columns of the gap (in rows) between the
    consecutive sweep points of the column that spans the row (gaps > ``max_gap`` left out; rows no gap
    spans take the median of all gaps)."""
    H, W = full.shape
    per_row = [[] for _ in range(H)]
    every = []
    for x in range(W):
        rows = np.nonzero(full[:, x] > 0)[0]
        for a, b in zip(rows[:-1], rows[1:]):
            g = int(b - a)
            if 1 < g <= max_gap:
                every.append(g)
                for y in range(a, b + 1):
                    per_row[y].append(g)
    fallback = float(np.median(every)) if every else 1.0
    return np.array([float(np.median(r)) if r else fallback for r in per_row])


def local_masks(target, full, half: int, K, T_cam_ref, origin) -> dict:
    """``local_open`` / ``local_directed`` of one camera."""
    from benchmarks.studies.cover_tests import directed_cover
    from jaxdepth.research.hidden import _OCCLUSION_MARGIN_M, _OCCLUSION_MARGIN_REL, _window_min
    spacing = np.maximum(1, np.ceil(row_spacing(full, 3 * half))).astype(int)
    t = jnp.asarray(target, jnp.float32)
    near = jnp.where(jnp.asarray(full) > 0, jnp.asarray(full), jnp.inf).astype(jnp.float32)
    limit = np.asarray(t - jnp.maximum(_OCCLUSION_MARGIN_M, _OCCLUSION_MARGIN_REL * t))
    has = target > 0
    opened = np.zeros(target.shape, bool)
    directed = np.zeros(target.shape, bool)
    for s in np.unique(spacing[np.nonzero(has.any(axis=1))[0]]):
        rows = (spacing == s)[:, None] & has
        opened |= rows & (np.asarray(_window_min(near, (-int(s), int(s)), (-2, 2))) < limit)
        offsets = [(dy, dx) for dy in range(-int(s), int(s) + 1) for dx in range(-2, 3)]
        directed |= rows & directed_cover(np.where(rows, target, 0.0), full, K, T_cam_ref, origin, offsets)
    return {"local_open": opened, "local_directed": directed}


def add_all(masks, targets, full, wrong, inp, hidden, half, draw, preds, exact) -> None:
    """``cover_tests.run_twin``'s hook: :data:`NEW`'s masks, then :func:`cover_scan.add_scan` (its scan masks,
    the per-class counts of every variant and the per-class scores of :data:`CLASS_VARIANTS`)."""
    origin = inp.cloud.origins_m[0]
    reach = max(3, 3 * int(half))
    for m, t, f, cam in zip(masks, targets, full, inp.rig.cameras):
        m.update(cover_scan.scan_masks(t, f, half, cam.K, cam.T_cam_lidar, origin))
        wide = half > RULE_MIN_PX
        m["rule_c2"] = m["scan_open_c2_1"] if wide else m["both_sides"]
        m["rule_c4"] = m["scan_open_c4_1"] if wide else m["both_sides"]
        for width in (1, 2):
            for k, p in parallax_cover(t, f, cam.K, cam.T_cam_lidar, origin, (0.5, 1), reach, width).items():
                m[f"parallax_w{width}_k{k:g}"] = p
                m[f"uncovered_or_parallax_w{width}_k{k:g}"] = p | m["both_sides"]
        m.update(local_masks(t, f, half, cam.K, cam.T_cam_lidar, origin))
    cover_scan.add_scan(masks, targets, full, wrong, inp, hidden, half, draw, preds, exact, variants=VARIANTS,
                        class_variants=CLASS_VARIANTS)


def seed_agreement(cases: list, variants=VARIANTS) -> dict:
    """{rig: {variant: {scene seed: [agree RMSE %, agree MAE %, pairs]}}}: pairs each variant ranks as the exact
    dense depth does, per scene seed (its draws pooled): the seeds' spread."""
    from benchmarks.studies.cover_tests import pair_agreement
    out = {}
    for c in cases:
        row = out.setdefault(c["rig"], {})
        for v in variants:
            got = []
            for metric in ("rmse", "mae"):
                agree, pairs = pair_agreement(((d["scores"]["exact_dense"], d["scores"][v]) for d in c["held_out"]),
                                              metric)
                got.append(100.0 * agree / max(pairs, 1))
            row.setdefault(v, {})[str(c["scene_seed"])] = got + [pairs]
    return out


def twin_table(doc: dict, variants) -> str:
    """Per twin and variant: wrong / right dropped %, agreement with the exact dense depth (RMSE / MAE %,
    per scene seed in brackets) and with the exact depth at every held-out pixel."""
    lines = []
    for rig, row in doc["summary"].items():
        if rig == "overall":
            continue
        lines.append(f"{rig}:")
        for v in variants:
            r, h = row[v], doc["held_out_agreement"][rig][v]
            seeds = "; ".join(f"{a:.0f} / {b:.0f}" for a, b, _ in doc["seed_agreement"][rig][v].values())
            lines.append(f"  {v:32s} {100 * r['wrong_dropped']:3.0f} / {100 * r['right_dropped']:4.1f} %; dense "
                         f"{r['agree_rmse_pct']:3.0f} / {r['agree_mae_pct']:3.0f} % ({seeds}); held-out "
                         f"{h['agree_rmse_pct']:3.0f} / {h['agree_mae_pct']:3.0f} % ({r['pairs']} pairs)")
    return "\n".join(lines)


def slim(obj):
    """``obj`` without the per-camera scores (the pooled ones stay): the five twins' cases in a few MB."""
    if isinstance(obj, dict):
        return {k: slim(v) for k, v in obj.items() if k != "per_camera"}
    if isinstance(obj, list):
        return [slim(v) for v in obj]
    return obj


def main(argv=None) -> int:
    from benchmarks.studies.cover_tests import collect_cases, study_parser, summarise
    parser = study_parser(__doc__.splitlines()[0], ("kitti", "nuscenes", "av2", "raster", "rosette"),
                          (0.5,) * 5, RESULTS / "cover_scan2_coverscan2_half.json")
    args = parser.parse_args(argv)
    t0 = time.time()
    config = SGMConfig()
    cases, merged_from = collect_cases(args, parser, config, t0, VARIANTS, add_all)
    doc = {"settings": {"sweeps": 1, "fraction": 0.2, "min_range_m": 1.0, "variants": list(VARIANTS),
                        "scales": {c["rig"]: c["scale"] for c in cases},
                        "scene_seeds": sorted({c["scene_seed"] for c in cases}),
                        "hidden_seeds": sorted({d["hidden_seed"] for c in cases for d in c["held_out"]})},
           "summary": summarise(cases, VARIANTS),
           "held_out_agreement": cover_scan.held_out_agreement(cases, VARIANTS),
           "class_agreement": cover_scan.class_agreement(cases, CLASS_VARIANTS),
           "seed_agreement": seed_agreement(cases, VARIANTS), "cases": cases}
    if merged_from:
        doc["merged_from"] = merged_from
    cover_scan.print_report(doc, cases, VARIANTS)
    print("per twin: wrong / right dropped; agreement, dense (per scene seed) and at the held-out pixels:")
    print(twin_table(doc, VARIANTS))
    write_results(args.json, slim(doc), config, t0, indent=None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
