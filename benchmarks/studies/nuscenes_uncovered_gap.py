"""Where the SGM's ``uncovered`` MAE trails the city-block fill on nuScenes (issue 37 (b)).

    PYTHONPATH=. python -m benchmarks.studies.nuscenes_uncovered_gap \
        [--seeds 0 1 2 3 4] [--twin-seeds 0 1] [--twin-scale 1] [--skip-twin] \
        [--json benchmarks/results/nuscenes_uncovered_gap.json]
    PYTHONPATH=. python -m benchmarks.studies.nuscenes_uncovered_gap --kitti-only \
        --json benchmarks/results/nuscenes_uncovered_gap_kitti.json

Runs ``hidden-eval``'s single-sweep protocol (:func:`jaxdepth.research.cli.hidden_eval`'s steps:
``prepare_sweep`` of the whole sweep, 20 % of the points at >= 1 m held out per draw, the SGM and the
SGM without removal on the rest, the city-block fill = the latter's seeds) on

- the real nuScenes sample (6 cameras, draws ``--seeds``, as ``benchmarks.accuracy_rigs``), and
- the nuScenes digital twin (1 sweep, the point file and rig JSON a user has, ``--twin-seeds`` scenes,
  draws ``--seeds``), whose exact depth is known,

and splits the mean-over-images MAE difference SGM minus city block at the ``uncovered`` targets
(:func:`jaxdepth.research.hidden.covered_targets` dropped) into additive parts: each target pixel
carries 1 / (images x its image's targets), so the parts of a split sum to the scored difference.
Splits: camera; target depth; the fill's seed distance (city block) and whether the seed lies on the
target's own row; whether the two predictions differ by more than max(1 m, 5 %) (another surface) and
whether the SGM's seed there is another pixel (removal moved it); with each part, what Step 4's
Gaussian adds to the SGM's error there. Scored besides the SGM and the fill (MAE and the devkit's
mean-over-images RMSE): the seed's plane alone (``sgm_plane``: Step 4a, before the column bracket),
the SGM without the Gaussian (``sgm_raw``: ``depth_raw``, kept pixels and clip
as Step 4) and a throw-away edge-aware Gaussian (``sgm_edge``, :func:`edge_aware_blur`: neighbours
more than max(1 m, 5 %) off the pixel's own depth left out; not a library option). On the twin also:
scored against the exact depth at the same pixels, and split by whether the target itself is off the
exact depth by more than max(1 m, 5 %) (a wrong target).

A diagnosis: nothing here chooses a default; the twin's exact depth is read only to score.
"""

from __future__ import annotations

import argparse
import glob
import tempfile
import time

import jax.numpy as jnp
import numpy as np

from benchmarks._common import DATA, RESULTS, write_results
from jaxdepth._src.config import SGMConfig

FRACTION = 0.2
MIN_RANGE_M = 1.0
DEPTH_BINS = (0.0, 10.0, 20.0, 40.0, np.inf)
SEED_BINS = (1, 2, 3, 5, 9, 17, 10**9)      # city-block seed distance bins [a, b)


def _off(a, b):
    """|a - b| > max(1 m, 5 % of b) (another surface)."""
    return np.abs(a - b) > np.maximum(1.0, 0.05 * b)


def edge_aware_blur(raw: np.ndarray, *, at=None, sigma_px: float = 1.4, radius_px: int = 3) -> np.ndarray:
    """Step 4's 7 x 7 Gaussian of ``raw`` (C, H, W) that leaves out, at each pixel, the neighbours more than
    max(1 m, 5 %) off its own depth (a throw-away variant, not in the library; reflect-101 border as
    OpenCV's). ``at``: (cam, row, col) index arrays: the result at those pixels only, (n,)."""
    from jaxdepth._src.smoothing import gaussian_kernel_1d
    k = gaussian_kernel_1d(sigma_px, radius_px)
    r = radius_px
    pad = np.pad(raw, ((0, 0), (r, r), (r, r)), mode="reflect").astype(np.float64)
    c, v, u = at if at is not None else np.indices(raw.shape).reshape(3, -1)
    centre = raw[c, v, u].astype(np.float64)
    tol = np.maximum(1.0, 0.05 * centre)
    num = np.zeros_like(centre)
    den = np.zeros_like(centre)
    for i in range(2 * r + 1):
        for j in range(2 * r + 1):
            nb = pad[c, v + i, u + j]
            g = (np.abs(nb - centre) <= tol) * (k[i] * k[j])
            num += g * nb
            den += g
    out = (num / den).astype(np.float32)
    return out if at is not None else out.reshape(raw.shape)


def _finish(depth: np.ndarray, stages, keep: np.ndarray) -> np.ndarray:
    """Step 4's last lines at the ``keep`` pixels: kept LiDAR pixels keep their depth, clipped to [0.1, 150] m."""
    cfg = SGMConfig()
    kept = np.asarray(stages.inlier_mask)[keep]
    depth = np.where(kept, np.asarray(stages.sparse_depth)[keep], depth)
    return np.clip(depth, cfg.min_depth_m, cfg.max_depth_m)


def draw_pixels(points, ring, rig, seed: int, config: SGMConfig, exact=None, extra=None,
                all_targets: bool = False) -> dict:
    """Per target pixel of one draw (every camera): the columns the splits read.

    Follows :func:`jaxdepth.research.cli.hidden_eval` (one draw) step by step, keeping the stages.
    ``extra``: optional function of (the SGM's (C, H, W) stages, the (C, H, W) target mask) giving more
    columns ({name: (n,) array}). ``all_targets``: every target, not only the uncovered ones, with a
    ``covered`` column (the ``weight`` column then counts every target).
    """
    import jax

    from jaxdepth._src.rig import complete_rig_stages, stack_cameras
    from jaxdepth.io import pad_points, prepare_sweep
    from jaxdepth.research.hidden import covered_targets, default_cover_half_height_px, hidden_point_mask
    from jaxdepth.research.hidden import _z_buffers

    frame = prepare_sweep(points, rig, ring=ring)
    if not frame.outlier_removal_trusted:
        config = config.replace(outlier_removal=False)
    padded, valid = pad_points(frame.points)
    with np.errstate(invalid="ignore", over="ignore"):
        valid &= np.linalg.norm(padded.astype(np.float64), axis=1) >= MIN_RANGE_M
    cams = stack_cameras([c.as_camera() for c in frame.rig.cameras])
    hidden = hidden_point_mask(valid, fraction=FRACTION, seed=seed)
    given = jnp.asarray(valid & ~hidden)
    pts = jnp.asarray(padded)
    sgm = complete_rig_stages(pts, given, cams, config=config, lidar=frame.rig.lidar)
    plain = complete_rig_stages(pts, given, cams, config=config.replace(outlier_removal=False),
                                lidar=frame.rig.lidar)
    size = dict(height=cams.height, width=cams.width)
    zb = lambda m: _z_buffers(pts, jnp.asarray(m), cams.K, cams.T_cam_lidar, cams.image_size, **size)  # noqa: E731
    target, full = zb(hidden), zb(valid)
    half = default_cover_half_height_px(cams.K, frame.rig.lidar)
    covered = np.asarray(jax.vmap(lambda t, f: covered_targets(t, f, half_height_px=half))(target, full))
    target = np.asarray(target)
    keep = (target > 0) if all_targets else (target > 0) & ~covered
    cam, v, u = np.nonzero(keep)
    counts = keep.sum(axis=(1, 2))
    out = {"cam": cam, "row": v, "z": target[keep],
           "weight": 1.0 / counts[cam],                     # per image; divided by the image count later
           "sgm": np.asarray(sgm.depth)[keep], "sgm_raw": _finish(np.asarray(sgm.depth_raw)[keep], sgm, keep),
           "sgm_plane": _finish(np.asarray(sgm.seed_depth + sgm.residual)[keep], sgm, keep),
           "sgm_edge": _finish(edge_aware_blur(np.asarray(sgm.depth_raw), at=(cam, v, u)), sgm, keep),
           "nearest": np.asarray(plain.seed_depth)[keep],
           "seed_dist": (np.abs(np.asarray(plain.du)) + np.abs(np.asarray(plain.dv)))[keep],
           "seed_same_row": (np.asarray(plain.dv) == 0)[keep],
           "seed_moved": ((np.asarray(sgm.du) != np.asarray(plain.du))
                          | (np.asarray(sgm.dv) != np.asarray(plain.dv)))[keep],
           "removal": bool(config.outlier_removal), "cover_half_height_px": int(half),
           "covered_share": float(covered.sum() / max((target > 0).sum(), 1))}
    if exact is not None:
        ex = np.zeros(target.shape, np.float32)
        for i, e in enumerate(exact):
            ex[i, :e.shape[0], :e.shape[1]] = e
        out["exact"] = ex[keep]
    if all_targets:
        out["covered"] = covered[keep]
    if extra is not None:
        out.update(extra(sgm, keep))
    return out


def _concat(draws: list) -> dict:
    n_images = sum(int(len(np.unique(d["cam"]))) for d in draws)
    cols = [k for k, v in draws[0].items() if isinstance(v, np.ndarray)]
    out = {k: np.concatenate([d[k] for d in draws]) for k in cols}
    out["image"] = np.concatenate([i * 1000 + d["cam"] for i, d in enumerate(draws)])
    out["weight"] = out["weight"] / n_images
    return out


def _parts(diff: np.ndarray, weight: np.ndarray, labels: np.ndarray, names: list, gauss=None) -> dict:
    """{name: targets, share, mae_diff_mm (and gaussian_part_mm: what Step 4's Gaussian adds to the SGM's
    MAE there)} of each label."""
    out = {}
    for i, name in enumerate(names):
        sel = labels == i
        out[name] = {"targets": int(sel.sum()), "share": float(sel.mean()),
                     "mae_diff_mm": float(1000 * np.sum((diff * weight)[sel]))}
        if gauss is not None:
            out[name]["gaussian_part_mm"] = float(1000 * np.sum((gauss * weight)[sel]))
    return out


def splits(p: dict, truth: np.ndarray, cameras: list) -> dict:
    """MAE and RMSE (mm, mean over images) of the SGM, its raw and edge-aware forms and the fill against
    ``truth``, and the MAE difference SGM minus fill split into additive parts."""
    w = p["weight"]
    err = {m: np.abs(p[m] - truth) for m in ("sgm", "sgm_plane", "sgm_raw", "sgm_edge", "nearest")}
    diff = err["sgm"] - err["nearest"]
    gauss = err["sgm"] - err["sgm_raw"]
    dbin = np.digitize(p["z"], DEPTH_BINS[1:-1])
    sbin = np.digitize(p["seed_dist"], SEED_BINS[1:-1])
    other = _off(p["sgm"], p["nearest"])
    _, inverse = np.unique(p["image"], return_inverse=True)
    count = np.bincount(inverse)
    rmse = {m: float(1000 * np.mean(np.sqrt(np.bincount(inverse, e ** 2) / count))) for m, e in err.items()}
    out = {"mae_mm": {m: float(1000 * np.sum(e * w)) for m, e in err.items()}, "rmse_mm": rmse,
           "mae_diff_mm": float(1000 * np.sum(diff * w)),
           "by_camera": _parts(diff, w, p["cam"], cameras),
           "by_target_depth_m": _parts(diff, w, dbin, [f"{a:g}-{b:g}" for a, b in zip(DEPTH_BINS, DEPTH_BINS[1:])]),
           "by_seed_distance_px": _parts(diff, w, sbin, [f"{a}-{b - 1}" if b < 10**9 else f">={a}"
                                                         for a, b in zip(SEED_BINS, SEED_BINS[1:])]),
           "by_seed_row": _parts(diff, w, p["seed_same_row"].astype(int), ["other row", "same row"], gauss),
           "by_surface": _parts(diff, w, other.astype(int) * 2 + p["seed_moved"].astype(int),
                                ["same surface, same seed", "same surface, seed moved",
                                 "other surface, same seed", "other surface, seed moved"], gauss),
           "by_depth_and_surface": _parts(diff, w, (dbin >= 2).astype(int) * 2 + other.astype(int),
                                          ["< 20 m, same surface", "< 20 m, other surface",
                                           ">= 20 m, same surface", ">= 20 m, other surface"], gauss),
           "gaussian_part_mm": float(1000 * np.sum(gauss * w))}
    return out


def analyse(points, ring, rig, seeds, config, exact=None) -> dict:
    draws = [draw_pixels(points, ring, rig, s, config, exact) for s in seeds]
    p = _concat(draws)
    cameras = [c.name for c in rig.cameras]
    row = {"targets": int(len(p["z"])), "removal": draws[0]["removal"],
           "cover_half_height_px": draws[0]["cover_half_height_px"],
           "covered_share": float(np.mean([d["covered_share"] for d in draws])),
           "against_targets": splits(p, p["z"], cameras)}
    if exact is not None:
        ex = p["exact"]
        seen = ex > 0
        wrong = seen & _off(p["z"], ex)
        q = {k: v[seen] for k, v in p.items()}
        row["exact_seen_share"] = float(seen.mean())
        row["wrong_target_share"] = float(wrong[seen].mean())
        row["against_exact"] = splits(q, q["exact"], cameras)
        row["against_targets_seen"] = splits(q, q["z"], cameras)
        off = np.abs(q["z"] - q["exact"]) * q["weight"]
        rows = q["seed_same_row"]
        row["target_off_exact_mm"] = {           # the protocol's own error: |target - exact depth|, MAE parts
            "all": float(1000 * off.sum()), "same row": float(1000 * off[rows].sum()),
            "other row": float(1000 * off[~rows].sum()),
            "same row, target within max(1 m, 5 %)": float(1000 * off[rows & ~wrong[seen]].sum())}
        for key, truth in (("against_targets_seen", q["z"]), ("against_exact", q["exact"])):
            err = {m: np.abs(q[m] - truth) for m in ("sgm", "sgm_plane", "sgm_raw", "sgm_edge", "nearest")}
            other = _off(q["sgm"], q["nearest"]).astype(int)
            row[key]["by_target"] = _parts(err["sgm"] - err["nearest"], q["weight"], wrong[seen].astype(int) * 2 + other,
                                           ["target right, same surface", "target right, other surface",
                                            "target wrong, same surface", "target wrong, other surface"],
                                           err["sgm"] - err["sgm_raw"])
    return row


def real_sample(seeds, config) -> dict:
    from jaxdepth.io import read_points, rig_from_nuscenes_calibration
    from jaxdepth.io.points import ring_column
    nus = DATA / "nuscenes" / "sample"
    rig = rig_from_nuscenes_calibration(nus / "calibration.json")
    sweep = glob.glob(str(nus / "*LIDAR_TOP*.pcd.bin"))[0]
    points, extra = read_points(sweep, columns=5)
    return analyse(points, ring_column(extra, 5), rig, seeds, config)


def twin_input(scene_seed: int, scale: float) -> tuple:
    """(the user's input, each camera's exact depth) of the nuScenes twin, 1 sweep: its point file and rig
    JSON read back as ``complete-rig`` reads them (the single-sweep path)."""
    from benchmarks.accuracy_twins import exact_truth, read_user_input
    from jaxdepth.research.twins import make_twin, write_twin
    tw = make_twin("nuscenes", sweeps=1, seed=scene_seed, scale=scale)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(tw, tmp)
        inp = read_user_input(paths["sweeps"][0], paths["rig"])
    assert not inp.multi, "the nuScenes twin at 1 sweep takes the single-sweep path"
    return inp, exact_truth(tw, inp.rig)


def twin(scene_seed: int, seeds, scale: float, config) -> dict:
    inp, exact = twin_input(scene_seed, scale)
    return analyse(inp.cloud.points, inp.cloud.ring, inp.rig, seeds, config, exact)


def kitti_frame() -> dict:
    """The shared KITTI frame's dense ground truth (cameras 2 and 3, devkit means): the SGM, without its
    Gaussian, and with :func:`edge_aware_blur` in its place (the gate any Step 4 change must pass)."""
    import jaxdepth
    from benchmarks._common import load_frames
    from jaxdepth._src.metrics import depth_metrics, mean_metrics
    rows = {"sgm": [], "sgm_raw": [], "sgm_edge": []}
    for sparse, gt, K, T in load_frames().values():
        st = jaxdepth.complete_stages(sparse, K, T)
        every = np.ones(np.shape(st.depth), bool)
        raw = np.asarray(st.depth_raw)
        has = np.asarray(st.seed_depth) > 0
        preds = {"sgm": np.asarray(st.depth), "sgm_raw": _finish(raw[every], st, every).reshape(raw.shape),
                 "sgm_edge": _finish(edge_aware_blur(raw[None])[0][every], st, every).reshape(raw.shape)}
        for m, pred in preds.items():
            rows[m].append(depth_metrics(jnp.asarray(np.where(has, pred, 0.0)), jnp.asarray(gt)))
    return {m: {k: float(mean_metrics(r)[k]) for k in ("rmse", "mae")} for m, r in rows.items()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--twin-seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--twin-scale", type=float, default=1.0)
    parser.add_argument("--skip-twin", action="store_true")
    parser.add_argument("--skip-real", action="store_true")
    parser.add_argument("--kitti-only", action="store_true",
                        help="only the KITTI frame's ground truth for the three Step 4 forms (kitti_frame)")
    parser.add_argument("--json", default=str(RESULTS / "nuscenes_uncovered_gap.json"))
    args = parser.parse_args(argv)
    config = SGMConfig()
    t0 = time.time()
    doc = {"settings": {"seeds": args.seeds, "twin_seeds": args.twin_seeds, "twin_scale": args.twin_scale,
                        "fraction": FRACTION, "min_range_m": MIN_RANGE_M,
                        "weights": "each target 1 / (images x its image's uncovered targets): parts sum to "
                                   "the mean-over-images MAE difference SGM minus city-block fill"}}
    if args.kitti_only:
        doc["kitti_frame"] = kitti_frame()
        print(doc["kitti_frame"])
        write_results(args.json, doc, config, t0)
        return 0
    if not args.skip_real:
        doc["real_sample"] = real_sample(args.seeds, config)
        a = doc["real_sample"]["against_targets"]
        print(f"real ({time.time() - t0:.0f} s): MAE sgm {a['mae_mm']['sgm']:.1f} raw {a['mae_mm']['sgm_raw']:.1f} "
              f"nearest {a['mae_mm']['nearest']:.1f}", flush=True)
        write_results(args.json, doc, config, t0)
    if not args.skip_twin:
        doc["twin"] = {str(s): twin(s, args.seeds, args.twin_scale, config) for s in args.twin_seeds}
        for s, row in doc["twin"].items():
            for key in ("against_targets", "against_exact"):
                a = row[key]
                print(f"twin seed {s} {key}: MAE sgm {a['mae_mm']['sgm']:.1f} raw {a['mae_mm']['sgm_raw']:.1f} "
                      f"nearest {a['mae_mm']['nearest']:.1f}", flush=True)
    write_results(args.json, doc, config, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
