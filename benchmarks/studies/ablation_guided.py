"""Issue 16's ablation: LiDAR-only SGM, + blending, + image guidance, + both, nearest fill, IP_Basic.

    PYTHONPATH=. python -m benchmarks.studies.ablation_guided [--quick] [--json PATH] [--repeats N]

Writes benchmarks/results/ablation_guided.json (``--quick``: ablation_guided_quick.json) atomically.

Every dev set that has camera images, scored with KITTI devkit metrics (RMSE / MAE mm,
iRMSE / iMAE 1/km, the mean over camera images as the devkit averages):

* **KITTI GT**: the two ground-truth images of ../shared/data/kitti/drive_0001_frame05
  (official sparse input, 352 x 1216 benchmark crop, image path ``complete``), as
  benchmarks/accuracy_kitti.py does.
* **hidden-point sets** (raw sweeps, ``complete_points`` per camera): 20 % of the valid
  points held out (``hidden_point_mask``, draws 0..2; ``--quick``: draw 0), the rest
  completed, every method scored at the held-out points' own per-pixel z-buffer,
  **unfiltered** (:mod:`jaxdepth.research.hidden`: nothing a method under test does
  touches the targets). The raw KITTI sweeps raw_2011_09_26_scene2 and drive_0001_frame05
  (cameras 2 and 3), the 3 KITTI object frames (``image_2``) and the nuScenes sample
  (6 cameras; until ``complete_rig`` takes images, one ``complete_points`` per camera,
  which gives the same result). Each sweep goes through ``prepare_sweep`` as
  ``jaxdepth hidden-eval`` does (points within 1 m dropped).
* **synthetic**: the procedural street (:func:`jaxdepth.make_street_scene`, images=True:
  per-object albedos, Lambertian shading, texture, pixel noise; KITTI-like stereo
  cameras 352 x 1216, HDL-64E sweep), scored against the exact dense depth.

Rows: nearest fill (the SGM's own city-block seeds) and IP_Basic, both on the same
input without outlier removal (as in accuracy_rigs.py); then the SGM rows from
:data:`SGM_ROWS`, a table of (key, label, SGMConfig changes). Rows that need an
SGMConfig field this version lacks (``blend_hypotheses``, issue 16 part 2) are skipped
and the skip is printed.

Weight selection: the guidance weight (grid :data:`WEIGHTS` or ``--weights``,
``guidance_sweeps`` default) of each guided row is chosen on the **choose** sets only
(synthetic seeds 0-1 and raw_2011_09_26_scene2's hidden points), by the lowest mean over
those sets of RMSE / RMSE of the LiDAR-only SGM on the same set (``--criterion worst``: the
lowest worst case, max over those sets); every other set only reports.

``--noise-floor F`` sets ``guidance_noise_floor`` in the guided rows (default: the
SGMConfig default, 0). Its run: ``--noise-floor 1 --criterion worst --weights 0.5 1 2 5 10
20 50 100 200 --json benchmarks/results/ablation_guided_noise_floor.json`` (with the mean
criterion the clean synthetic renders pulled the weight to the grid's edge).

Time per frame: per set, its first frame (all its camera images), each row's calls in
sequence, median of ``--repeats`` interleaved runs after a compile run, with
``block_until_ready``; the ratio is to the LiDAR-only SGM timed in the same process.
The nearest fill and IP_Basic on the sweep sets include the projection of the sweep.
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np


import jaxdepth  # noqa: E402
from jaxdepth import SGMConfig  # noqa: E402
from jaxdepth._src.geometry import project_to_image  # noqa: E402
from jaxdepth._src.metrics import depth_metrics, mean_metrics  # noqa: E402
from jaxdepth._src.types import Camera, LidarSpec  # noqa: E402
from jaxdepth.io.guidance_images import decode_camera_image  # noqa: E402
from jaxdepth.research.hidden import hidden_point_mask  # noqa: E402

from benchmarks._common import DATA, ROOT, load_frames, load_images, write_results  # noqa: E402

KEYS = ("rmse", "mae", "irmse", "imae")
WEIGHTS = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)   # 20 and 50 added when 10, the edge of the first grid, won
QUICK_WEIGHTS = (1.0, 5.0)
CHOSEN = "chosen"   # placeholder for the guidance weight chosen on the choose sets
#: (key, label, SGMConfig changes); CHOSEN stands for the weight chosen for that row.
SGM_ROWS = (
    ("sgm", "SGM, LiDAR only (default)", {}),
    ("sgm_blend", "+ blending", {"blend_hypotheses": True}),
    ("sgm_guided", "+ image guidance", {"guidance_weight": CHOSEN}),
    ("sgm_both", "+ both", {"blend_hypotheses": True, "guidance_weight": CHOSEN}),
)
BASELINES = (("nearest", "nearest fill (city block, no removal)"), ("ip_basic", "IP_Basic (no removal)"))
CHOOSE_SETS = ("synthetic seeds 0-1", "KITTI raw scene2, hidden points")


def available_rows():
    """SGM_ROWS whose config fields exist in this version, and the names of the skipped ones."""
    fields = SGMConfig.__dataclass_fields__
    rows, skipped = [], []
    for key, label, changes in SGM_ROWS:
        missing = [f for f in changes if f not in fields]
        (skipped if missing else rows).append((key, label, changes) if not missing else f"{label} (needs {missing})")
    return rows, skipped


# ---------------------------------------------------------------- data


@dataclasses.dataclass
class Item:
    """One camera image to complete and score."""

    name: str
    gt: jax.Array                      # (H, W) metres, 0 = no target
    image: jax.Array                   # (H, W, 3) uint8 RGB
    K: jax.Array
    T: jax.Array
    lidar: LidarSpec
    removal: bool                      # outlier removal trusted (sweep check)
    sparse: jax.Array | None = None    # image path (KITTI GT)
    points: jax.Array | None = None    # sweep path: padded points, the given (not held-out) mask, camera
    given: jax.Array | None = None
    camera: Camera | None = None


def kitti_gt_frames():
    images = load_images()
    frames = []
    for name, (sparse, gt, K, T) in load_frames().items():
        image = images[name]
        frames.append([Item(name, jnp.asarray(gt), jnp.asarray(image), jnp.asarray(K, jnp.float32),
                            jnp.asarray(T, jnp.float32), _hdl64(), True,
                            sparse=jnp.asarray(sparse, jnp.float32))])
    return frames


def _hdl64():
    from jaxdepth._src.presets import KITTI_HDL64
    return KITTI_HDL64


def hidden_frames(points, rig, images, draws, *, ring=None, min_range_m=1.0, fraction=0.2):
    """One frame per draw: every camera of the rig, held-out points as targets (unfiltered)."""
    from jaxdepth.io import pad_points, prepare_sweep
    frame = prepare_sweep(points, rig, ring=ring)
    padded, valid = pad_points(frame.points)
    with np.errstate(invalid="ignore", over="ignore"):
        valid &= np.linalg.norm(padded.astype(np.float64), axis=1) >= min_range_m
    frames = []
    for draw in draws:
        hidden = hidden_point_mask(valid, fraction=fraction, seed=draw)
        items = []
        for cam in frame.rig.cameras:
            gt, _ = project_to_image(padded, hidden, cam.K, cam.T_cam_lidar, height=cam.height, width=cam.width)
            image = images[cam.name]
            if image.shape[:2] != (cam.height, cam.width):
                raise ValueError(f"image of {cam.name}: expected {cam.height}x{cam.width}, got {image.shape[:2]}")
            items.append(Item(f"{cam.name} draw {draw}", jnp.asarray(gt), jnp.asarray(image), jnp.asarray(cam.K),
                              jnp.asarray(cam.T_cam_lidar), frame.rig.lidar, frame.outlier_removal_trusted,
                              points=jnp.asarray(padded), given=jnp.asarray(valid & ~hidden),
                              camera=cam.as_camera()))
        frames.append(items)
    return frames, list(frame.notes)


def kitti_raw_frames(scene, draws):
    from jaxdepth.io import read_points, rig_from_kitti_raw
    d = DATA / "kitti" / scene
    rig = rig_from_kitti_raw(d / "calib_cam_to_cam.txt", d / "calib_velo_to_cam.txt")
    points, _ = read_points(d / "lidar_data.bin")
    images = {f"image_0{i}": decode_camera_image(d / f"image_0{i}.png") for i in (2, 3)}
    return hidden_frames(points, rig, images, draws)


def kitti_object_frames(draws):
    from jaxdepth.io import read_points, rig_from_kitti_object
    d = DATA / "kitti" / "object"
    frames, notes = [], []
    for stem in ("000000", "000001", "000002"):
        image = decode_camera_image(d / "image_2" / f"{stem}.png")
        rig = rig_from_kitti_object(d / "calib" / f"{stem}.txt", width=image.shape[1], height=image.shape[0])
        points, _ = read_points(d / "velodyne" / f"{stem}.bin")
        f, n = hidden_frames(points, rig, {"image_02": image}, draws)
        for items in f:
            for item in items:
                item.name = f"{stem} {item.name}"
        frames += f
        notes += n
    # One frame = the three object frames of one draw (so "time per frame" is per KITTI frame x 3).
    return [sum((frames[i] for i in range(k, len(frames), len(draws))), []) for k in range(len(draws))], notes


def nuscenes_frames(draws):
    from jaxdepth.io import read_points, rig_from_nuscenes_calibration
    from jaxdepth.io.points import ring_column
    d = DATA / "nuscenes" / "sample"
    rig = rig_from_nuscenes_calibration(d / "calibration.json")
    sweep = glob.glob(str(d / "*LIDAR_TOP*.pcd.bin"))[0]
    points, extra = read_points(sweep, columns=5)
    images = {}
    for cam in rig.cameras:
        (path,) = glob.glob(str(d / f"*__{cam.name}__*.jpg"))
        images[cam.name] = decode_camera_image(path)
    return hidden_frames(points, rig, images, draws, ring=ring_column(extra, 5))


def synthetic_frames(seeds):
    frames = []
    for seed in seeds:
        f = jaxdepth.make_street_scene(seed, cameras="stereo", images=True)
        padded, valid = jaxdepth.io.pad_points(f.points)
        valid &= np.asarray(np.pad(f.valid, (0, len(valid) - len(f.valid))))
        items = []
        for i, (cam, depth, image) in enumerate(zip(f.cameras, f.dense_depth, f.images)):
            items.append(Item(f"seed {seed} camera {i}", jnp.asarray(depth), jnp.asarray(image), cam.K,
                              cam.T_cam_lidar, f.lidar, True, points=jnp.asarray(padded), given=jnp.asarray(valid),
                              camera=cam))
        frames.append(items)
    return frames, [f"exact dense depth, seeds {list(seeds)}, KITTI-like stereo 352x1216, HDL-64E sweep at the "
                    "origin (LiDAR 0.3 m behind and above camera 2)"]


# ---------------------------------------------------------------- methods


def sgm_call(item: Item, config: SGMConfig):
    """() -> depth of the SGM with ``config`` on ``item`` (image passed only when guided)."""
    image = item.image if config.guidance_weight > 0 else None
    if item.sparse is not None:
        return lambda: jaxdepth.complete(item.sparse, item.K, item.T, config=config, lidar=item.lidar, image=image)
    return lambda: jaxdepth.complete_points(item.points, item.given, item.camera, config=config, lidar=item.lidar,
                                            image=image)


@jax.jit
def _project(points, given, K, T, shape_like):
    sparse, _ = project_to_image(points, given, K, T, height=shape_like.shape[0], width=shape_like.shape[1])
    return sparse


def baseline_call(item: Item, method: str, config: SGMConfig):
    plain = config.replace(outlier_removal=False)
    name = {"nearest": "nearest", "ip_basic": "ip-basic"}[method]

    def call():
        sparse = item.sparse if item.sparse is not None else _project(item.points, item.given, item.K, item.T,
                                                                      item.gt)
        return jaxdepth.complete_with(sparse, item.K, item.T, method=name, config=plain, lidar=item.lidar)
    return call


def base_config(item: Item) -> SGMConfig:
    return SGMConfig() if item.removal else SGMConfig(outlier_removal=False)


def row_config(item: Item, changes: dict, weight) -> SGMConfig:
    changes = {k: (weight if v == CHOSEN else v) for k, v in changes.items()}
    return base_config(item).replace(**changes)


def score(frames, make_call) -> dict:
    """Mean devkit metrics over every image of every frame of ``make_call(item)()``'s prediction."""
    rows = []
    for items in frames:
        for item in items:
            m = depth_metrics(make_call(item)(), item.gt)
            rows.append({k: float(v) for k, v in m.items()})
    mean = mean_metrics(rows)
    return {k: float(mean[k]) for k in KEYS} | {"images": int(mean["images"])}


def time_frame(items, calls: dict, repeats: int) -> dict:
    """Median ms per frame of each row (interleaved repeats after a compile run)."""
    runs = {name: [make(item) for item in items] for name, make in calls.items()}
    for fns in runs.values():
        for fn in fns:
            fn().block_until_ready()
    samples = {name: [] for name in runs}
    for _ in range(repeats):
        for name, fns in runs.items():
            t0 = time.perf_counter()
            for fn in fns:
                fn().block_until_ready()
            samples[name].append(time.perf_counter() - t0)
    return {name: 1e3 * float(np.median(s)) for name, s in samples.items()}


# ---------------------------------------------------------------- the ablation


def load_sets(quick: bool):
    draws = (0,) if quick else (0, 1, 2)
    loaders = {
        "synthetic seeds 0-1": lambda: synthetic_frames((0,) if quick else (0, 1)),
        "KITTI raw scene2, hidden points": lambda: kitti_raw_frames("raw_2011_09_26_scene2", draws),
        "KITTI GT frame05 (2 images, 352x1216)": lambda: (kitti_gt_frames(), ["official semi-dense ground truth"]),
        "KITTI raw frame05, hidden points": lambda: kitti_raw_frames("drive_0001_frame05", draws),
        "KITTI object 000000-000002, hidden points": lambda: kitti_object_frames(draws),
        "nuScenes sample (6 cameras), hidden points": lambda: nuscenes_frames(draws),
        "synthetic seeds 2-3": lambda: synthetic_frames((2,) if quick else (2, 3)),
    }
    sets = {}
    for name, load in loaders.items():
        try:
            frames, notes = load()
        except Exception as err:  # a missing or bad set is reported and the rest carries on
            print(f"[skip] {name}: {type(err).__name__}: {err}", file=sys.stderr, flush=True)
            sets[name] = {"error": f"{type(err).__name__}: {err}"}
            continue
        sets[name] = {"frames": frames, "notes": notes}
        print(f"[load] {name}: {sum(len(f) for f in frames)} images", file=sys.stderr, flush=True)
    return sets


def choose_weights(sets, rows, weights, criterion="mean") -> dict:
    """Per guided row: {weight: mean over choose sets of RMSE / LiDAR-only RMSE}, and the chosen weight."""
    out = {}
    base = {name: score(sets[name]["frames"], lambda it: sgm_call(it, base_config(it)))
            for name in CHOOSE_SETS if "frames" in sets[name]}
    if not base:
        raise SystemExit("no choose set could be loaded: cannot choose the guidance weight")
    for key, label, changes in rows:
        if CHOSEN not in changes.values():
            continue
        grid = {}
        for w in weights:
            per = {name: score(sets[name]["frames"], lambda it: sgm_call(it, row_config(it, changes, w)))
                   for name in base}
            ratios = [per[n]["rmse"] / base[n]["rmse"] for n in base]
            grid[str(w)] = {"worst_rmse_ratio": float(np.max(ratios)), "mean_rmse_ratio": float(np.mean(ratios)),
                            "per_set": per}
            print(f"[choose] {label} weight {w:g}: worst RMSE ratio {grid[str(w)]['worst_rmse_ratio']:.4f}, "
                  f"mean {grid[str(w)]['mean_rmse_ratio']:.4f}", file=sys.stderr, flush=True)
        chosen = min(weights, key=lambda w: grid[str(w)][f"{criterion}_rmse_ratio"])
        out[key] = {"chosen": chosen, "grid": grid}
    return {"lidar_only_on_choose_sets": base, "rows": out}


def run_set(entry, rows, chosen, repeats) -> dict:
    frames = entry["frames"]
    scores, calls = {}, {}
    for key, _ in BASELINES:
        make = (lambda k: lambda it: baseline_call(it, k, base_config(it)))(key)
        scores[key], calls[key] = score(frames, make), make
    for key, _, changes in rows:
        w = chosen.get(key)
        make = (lambda c, w: lambda it: sgm_call(it, row_config(it, c, w)))(changes, w)
        scores[key], calls[key] = score(frames, make), make
    timing = time_frame(frames[0], calls, repeats)
    return {"scores": scores, "time_ms": timing, "time_ratio": {k: v / timing["sgm"] for k, v in timing.items()},
            "images": scores["sgm"]["images"], "images_per_frame": len(frames[0]), "notes": entry["notes"]}


def print_table(name, role, result, labels):
    print(f"\n{name}  [{role}]  ({result['images']} images; time per frame = {result['images_per_frame']} images)")
    print(f"  {'method':40s} {'RMSE':>8s} {'MAE':>7s} {'iRMSE':>6s} {'iMAE':>6s} {'ms/frame':>9s} {'x SGM':>6s}")
    for key, label in labels:
        s = result["scores"][key]
        print(f"  {label:40s} {s['rmse']:8.1f} {s['mae']:7.1f} {s['irmse']:6.2f} {s['imae']:6.2f} "
              f"{result['time_ms'][key]:9.1f} {result['time_ratio'][key]:6.2f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=None,
                        help="output (default benchmarks/results/ablation_guided.json, with --quick "
                             "ablation_guided_quick.json so a smoke run never replaces the full result)")
    parser.add_argument("--quick", action="store_true",
                        help="a small run: one draw, one synthetic seed per role, weights 1 and 5, 3 timing repeats")
    parser.add_argument("--repeats", type=int, default=None, help="timing repeats (default 7, --quick 3)")
    parser.add_argument("--weights", type=float, nargs="+", default=None, help="guidance weight grid")
    parser.add_argument("--criterion", choices=("mean", "worst"), default="mean",
                        help="weight choice: lowest mean (default) or worst RMSE ratio over the choose sets")
    parser.add_argument("--noise-floor", type=float, default=SGMConfig().guidance_noise_floor,
                        help="guidance_noise_floor of the guided rows (default: SGMConfig's)")
    args = parser.parse_args(argv)
    if args.json is None:
        args.json = str(ROOT / "benchmarks" / "results" / f"ablation_guided{'_quick' if args.quick else ''}.json")
    t0 = time.time()
    repeats = args.repeats or (3 if args.quick else 7)
    weights = args.weights or (QUICK_WEIGHTS if args.quick else WEIGHTS)
    rows, skipped = available_rows()
    rows = [(k, lab, {**c, "guidance_noise_floor": args.noise_floor} if CHOSEN in c.values() else c)
            for k, lab, c in rows]
    for s in skipped:
        print(f"[skip] row {s}: this SGMConfig has no such field yet", flush=True)
    sets = load_sets(args.quick)
    selection = choose_weights(sets, rows, weights, args.criterion)
    chosen = {k: v["chosen"] for k, v in selection["rows"].items()}
    print(f"guidance weight chosen on {list(CHOOSE_SETS)}: {chosen} (grid {list(weights)}, "
          f"{SGMConfig().guidance_sweeps} sweeps)", flush=True)
    labels = list(BASELINES) + [(k, lab + (f", weight {chosen[k]:g}" if k in chosen else "")) for k, lab, _ in rows]
    results = {}
    for name, entry in sets.items():
        if "frames" not in entry:
            results[name] = {"error": entry["error"]}
            continue
        role = "choose (chose the weight)" if name in CHOOSE_SETS else "report"
        res = run_set(entry, rows, chosen, repeats)
        res["role"] = role
        results[name] = res
        print_table(name, role, res, labels)
    verdict = {}
    for key in (k for k, _, _ in rows if k != "sgm"):
        verdict[key] = {name: r["scores"][key]["rmse"] < r["scores"]["sgm"]["rmse"]
                        for name, r in results.items() if "scores" in r}
    print("\nbetter RMSE than LiDAR-only SGM:", {k: sum(v.values()) for k, v in verdict.items()}, "of",
          sum("scores" in r for r in results.values()), "sets")
    doc = {"quick": args.quick, "rows": [{"key": k, "label": lab} for k, lab in labels], "skipped_rows": skipped,
           "weight_selection": {"grid": list(weights), "guidance_sweeps": SGMConfig().guidance_sweeps,
                                "chosen_on": list(CHOOSE_SETS),
                                "reported_on": [n for n in sets if n not in CHOOSE_SETS],
                                "criterion": {"mean": "lowest mean", "worst": "lowest worst (max)"}[args.criterion]
                                + " over the choose sets of RMSE / LiDAR-only SGM RMSE",
                                "guidance_noise_floor": args.noise_floor,
                                "chosen": chosen, **selection},
           "better_rmse_than_lidar_only": verdict,
           "protocol": {"hidden_fraction": 0.2, "hidden_draws": [0] if args.quick else [0, 1, 2],
                        "hidden_targets": "held-out points' own per-pixel z-buffer, unfiltered",
                        "timing": f"median of {repeats} interleaved runs per frame, compile excluded, "
                                  "block_until_ready"},
           "sets": results}
    write_results(args.json, doc, SGMConfig(), t0)
    print(f"wrote {args.json} ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
