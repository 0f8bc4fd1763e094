"""Research commands of the command line: the paper's ablations, sparsity study, hidden-point scores.

``register(subparsers)`` adds three subcommands to the ``jaxdepth`` parser
(:func:`jaxdepth.cli.build_parser` calls it):

``jaxdepth ablation SRC [GT_DIR] [--json OUT] [--distance l1|l2] [--epsilon M]``
    Tables 1, 5 and 6 of the paper (:func:`jaxdepth.research.ablation.frame_ablation`)
    on a KITTI-layout folder: ``SRC/velodyne_raw/*.png`` with
    ``SRC/intrinsics/*.txt`` (or ``--intrinsics K.txt`` for every frame). The
    ground truth of ``X.png`` is ``GT_DIR/X.png`` or, KITTI's own naming,
    ``X`` with ``velodyne_raw`` replaced by ``groundtruth_depth``; ``GT_DIR``
    defaults to ``SRC/groundtruth_depth``. LiDAR angles use KITTI camera 2's
    extrinsics (benchmark folders carry none). Frames that cannot be read are
    reported on stderr and skipped (exit code 1 if any).

``jaxdepth sparsity SWEEP CALIB_DIR GT.png [--camera 2] [--beams 64 32 16] [--json OUT]``
    The paper's Fig. 6 on one KITTI raw frame: the beam of every point is
    estimated from its elevation (:mod:`jaxdepth.research.sparsity`), every 2nd / 4th
    beam is kept, the sweep is projected into camera ``--camera`` (calibration
    from ``CALIB_DIR/calib_cam_to_cam.txt`` and ``calib_velo_to_cam.txt``),
    cropped to the 352 x 1216 benchmark window, completed with SGM and with the
    nearest fill, and scored against ``GT.png`` (full frame, or already cropped
    to 352 x 1216). ``--lidar-beams`` gives the recording sensor's beam count
    (default 64); every entry of ``--beams`` must divide it.

``jaxdepth hidden-eval POINTS RIG.json [--fraction 0.2] [--seeds 0 1 2 3 4] [--scale 1] [--json OUT]``
    Hidden-point evaluation of what ``complete-rig`` computes for every camera of a rig JSON:
    a seeded share of the points is held out, the rest completed, and the SGM, the SGM
    without outlier removal, both nearest fills and IP_Basic are scored against the held-out
    points' own z-buffer (filtered by nothing any method does), all targets and ``uncovered``
    side by side. ``POINTS`` and the rig are read as ``complete-rig`` reads them: one sweep
    (:func:`jaxdepth.hidden_point_scores`), or, with the rig's ``lidars`` or a sweeps JSON, the
    multi-source path (:func:`hidden_eval_cloud`: reference-sweep points held out, each target's
    cover judged from its own LiDAR). Each seed is one draw; the table averages the draws.
    ``--point-columns`` defaults to the rig's ``columns``, else 5 for ``*.pcd.bin``
    (nuScenes) and, for a plain ``.bin``, 4 or 5 from its size; ``--scale`` scales every camera's K and image
    size (pixel-centre convention); ``--min-range-m`` (default 1.0) drops
    returns closer to their LiDAR (no-return placeholders, the vehicle itself).

Every command prints a table on stdout, writes ``--json`` atomically, raises
:class:`jaxdepth.io.errors.JaxdepthError` for bad input (the CLI prints one line
and exits with 1) and returns its exit code.
"""

from __future__ import annotations

import json
import pathlib
import sys

import numpy as np

from jaxdepth.options import add_config_options, config_changes
from jaxdepth.io.errors import InputError, JaxdepthError


def _config(args):
    from jaxdepth._src.config import SGMConfig
    return SGMConfig(**config_changes(args))


def _write_json(path, payload):
    from jaxdepth.io.atomic import atomic_write_bytes
    text = json.dumps(payload, indent=2, sort_keys=True, allow_nan=True)
    atomic_write_bytes(pathlib.Path(path), text.encode("utf-8"))


# ---------------------------------------------------------------- ablation


def _gt_path(gt_dir: pathlib.Path, png: pathlib.Path) -> pathlib.Path | None:
    names = [png.name]
    if "velodyne_raw" in png.name:
        names.append(png.name.replace("velodyne_raw", "groundtruth_depth", 1))
    for name in names:
        if (gt_dir / name).is_file():
            return gt_dir / name
    return None


def cmd_ablation(args) -> int:
    from jaxdepth.research.ablation import format_ablation, frame_ablation, mean_ablation
    from jaxdepth.io.calib import read_intrinsics_txt
    from jaxdepth.io.kitti_layout import list_depth_completion_folder
    from jaxdepth.io.plausibility import read_checked_depth_png

    src = pathlib.Path(args.src)
    frames = list_depth_completion_folder(src)
    gt_dir = pathlib.Path(args.gt) if args.gt else src / "groundtruth_depth"
    if not gt_dir.is_dir():
        raise InputError(f"{gt_dir}: ground-truth folder not found (give GT_DIR or SRC/groundtruth_depth/)")
    K_all = read_intrinsics_txt(args.intrinsics) if args.intrinsics else None
    config = _config(args)
    per_frame, failed = {}, {}
    for name, png, k_path in frames:
        try:
            gt_path = _gt_path(gt_dir, png)
            if gt_path is None:
                raise InputError(f"no ground truth {png.name} in {gt_dir}")
            if K_all is None and k_path is None:
                raise InputError("no intrinsics (expected SRC/intrinsics/<name>.txt or --intrinsics K.txt)")
            K = K_all if K_all is not None else read_intrinsics_txt(k_path)
            sparse = read_checked_depth_png(png, role="LiDAR input")
            gt = read_checked_depth_png(gt_path, role="ground truth")
            if sparse.shape != gt.shape:
                raise InputError(f"sparse input {sparse.shape} and ground truth {gt.shape} differ in shape")
            per_frame[name] = frame_ablation(sparse, gt, K, config=config)
        except JaxdepthError as err:
            failed[name] = str(err)
            print(f"FAILED {name}: {err}", file=sys.stderr)
    if not per_frame:
        raise InputError(f"{src}: no frame could be evaluated ({len(failed)} failed)")
    mean = mean_ablation(per_frame)
    for line in format_ablation(mean):
        print(line)
    if args.json:
        _write_json(args.json, {"mean": mean, "per_frame": per_frame, "failed": failed,
                                "config": {"distance_metric": config.distance_metric,
                                           "epsilon_m": config.epsilon_m}})
    if failed:
        print(f"{len(per_frame)} frames evaluated, {len(failed)} failed", file=sys.stderr)
    return 1 if failed else 0


# ---------------------------------------------------------------- sparsity


def _kitti_camera(calib_dir: pathlib.Path, index: int, gt: np.ndarray):
    """(Camera, gt cropped to the benchmark window) for KITTI camera ``index``."""
    import jax.numpy as jnp

    from jaxdepth._src.types import Camera
    from jaxdepth.io.calib import read_kitti_raw_calib
    from jaxdepth.io.kitti_layout import BENCHMARK_SIZE, benchmark_crop_offsets, crop_to_benchmark

    if not calib_dir.is_dir():
        raise InputError(f"{calib_dir}: calibration folder not found")
    calib = read_kitti_raw_calib(calib_dir / "calib_cam_to_cam.txt", calib_dir / "calib_velo_to_cam.txt")
    cam = calib["cameras"][index]
    K, full = np.asarray(cam["K"], np.float32), (cam["height"], cam["width"])
    if gt.shape == tuple(BENCHMARK_SIZE) and full != tuple(BENCHMARK_SIZE):
        top, left = benchmark_crop_offsets(*full)
        K = K.copy()
        K[0, 2] -= left
        K[1, 2] -= top
        gt_c = gt
    elif gt.shape == full:
        gt_c, K = crop_to_benchmark(gt, K)
    else:
        raise InputError(f"ground truth shape {gt.shape} expected the camera's {full} (S_rect_0{index}) "
                         f"or the benchmark crop {tuple(BENCHMARK_SIZE)}")
    h, w = gt_c.shape
    return Camera(K=jnp.asarray(K), T_cam_lidar=jnp.asarray(cam["T_cam_lidar"]), height=h, width=w), gt_c


def _point_columns(path: pathlib.Path, given):
    from jaxdepth.io.points import infer_point_columns
    return infer_point_columns(path, given)


def cmd_sparsity(args) -> int:
    from jaxdepth.research import sparsity
    from jaxdepth.io.plausibility import read_checked_depth_png
    from jaxdepth.io.points import read_points
    from jaxdepth.io.rig import default_lidar_spec

    sweep = pathlib.Path(args.sweep)
    points, _ = read_points(sweep, columns=_point_columns(sweep, args.point_columns))
    gt = read_checked_depth_png(args.gt, role="ground truth")
    camera, gt_c = _kitti_camera(pathlib.Path(args.calib_dir), args.camera, gt)
    lidar = default_lidar_spec(args.lidar_beams)
    try:
        for b in args.beams:
            sparsity.keep_every_for(lidar, b)
    except ValueError as err:
        raise InputError(f"--beams: {err}") from None
    model = sparsity.beam_model(points, lidar=lidar)
    counts = np.bincount(model.index[model.index >= 0], minlength=model.beams_found)
    print(f"beams found from elevation: {model.beams_found} (apex {model.apex_height_m:+.2f} m); points per beam "
          f"min {counts.min()}, median {int(np.median(counts))}, max {counts.max()}")
    result = sparsity.sparsity_study(points, None, camera, gt_c, lidar=lidar, beams=args.beams,
                                     config=_config(args), beam=model.index)
    result["beams_found"] = model.beams_found
    result["apex_height_m"] = model.apex_height_m
    result["points_per_beam"] = counts.tolist()
    result["camera"] = args.camera
    for line in sparsity.format_sparsity(result):
        print(line)
    if args.json:
        _write_json(args.json, result)
    return 0


# ---------------------------------------------------------------- hidden-point evaluation


def scaled_camera(camera, scale: float):
    """A :class:`Camera` with image size ``round(size * scale)`` and K scaled with the pixel-centre convention.

    Pixel ``i`` covers ``[i - 0.5, i + 0.5]``, so ``x' + 0.5 = scale (x + 0.5)``.
    """
    import jax.numpy as jnp

    from jaxdepth._src.types import Camera
    if scale == 1.0:
        return camera
    K = np.array(camera.K, np.float64)
    S = np.array([[scale, 0.0, 0.5 * (scale - 1.0)], [0.0, scale, 0.5 * (scale - 1.0)], [0.0, 0.0, 1.0]])
    return Camera(K=jnp.asarray((S @ K).astype(np.float32)), T_cam_lidar=camera.T_cam_lidar,
                  height=max(1, round(camera.height * scale)), width=max(1, round(camera.width * scale)))


def hidden_eval(points: np.ndarray, rig, *, fraction: float = 0.2, seeds=(0,), scale: float = 1.0,
                min_range_m: float = 1.0, config=None, ring: np.ndarray | None = None,
                estimate: bool = True, on_progress=None) -> dict:
    """Per-camera hidden-point scores of one sweep (host wrapper of :func:`jaxdepth.hidden_point_scores`).

    The sweep is first put in its LiDAR's frame (:func:`jaxdepth.io.prepare_sweep`:
    the rig's ``lidar_origin_m``, else an estimate from the sweep, ``ring``
    sharpening it); where the sweep does not look like one spinning LiDAR,
    outlier removal is turned off (reported in ``"sweep_notes"``).
    Every seed draws its own held-out set; per-camera metrics are the mean over
    the draws, the "mean" row the mean over every camera image of every draw
    (the devkit's data-set score, :func:`jaxdepth.mean_metrics`).

    ``on_progress(name, status)`` is called with ``("seed <s>", "done")`` after each draw.

    Returns:
      {"cameras": {name: {"hidden_pixels", method: {rmse, mae, irmse, imae}, ...}},
       "mean": {method: {...}}, "methods", "points", "hidden_points", "fraction", "seeds", "scale"},
      methods as :data:`jaxdepth.research.hidden.METHODS`.
    """
    import jax.numpy as jnp

    from jaxdepth._src.config import SGMConfig
    from jaxdepth.research.hidden import hidden_point_mask, hidden_point_scores
    from jaxdepth._src.rig import stack_cameras
    from jaxdepth.io.points import pad_points

    from jaxdepth.io.sweep_frame import prepare_sweep

    config = SGMConfig() if config is None else config
    seeds = _seeds(seeds)
    frame = prepare_sweep(points, rig, ring=ring, estimate=estimate)
    rig = frame.rig
    if not frame.outlier_removal_trusted and config.outlier_removal:
        config = config.replace(outlier_removal=False)
    padded, valid = pad_points(frame.points)
    with np.errstate(invalid="ignore", over="ignore"):
        valid &= np.linalg.norm(padded.astype(np.float64), axis=1) >= min_range_m
    cameras = stack_cameras([scaled_camera(c.as_camera(), scale) for c in rig.cameras])
    draws, hidden_total = [], 0
    for seed in seeds:
        hidden = hidden_point_mask(valid, fraction=fraction, seed=seed)
        hidden_total += int(hidden.sum())
        draws.append(hidden_point_scores(jnp.asarray(padded), jnp.asarray(valid), jnp.asarray(hidden), cameras,
                                         config=config, lidar=rig.lidar))
        if on_progress is not None:
            on_progress(f"seed {seed}", "done")
    return dict(_summarise(draws, [c.name for c in rig.cameras]), points=int(valid.sum()),
                hidden_points=hidden_total // len(seeds), fraction=fraction, seeds=seeds, scale=scale,
                min_range_m=min_range_m, sweep_notes=list(frame.notes), outlier_removal=bool(config.outlier_removal),
                **_TARGETS)


#: What the two target sets are (recorded in the result).
_TARGETS = {"targets": "held-out points' own per-pixel z-buffer, unfiltered",
            "targets_uncovered": "the same without the targets that full-sweep points nearer by "
                                 "max(1 m, 5 %) cover on both sides (jaxdepth.research.hidden.covered_targets)"}


def _seeds(seeds) -> list:
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise InputError("hidden_eval: 'seeds' expected at least one seed, got none")
    return seeds


def _summarise(draws: list, names: list) -> dict:
    """The per-camera and pooled tables of one score dict per draw (:func:`jaxdepth.hidden_point_scores`' layout)."""
    from jaxdepth._src.metrics import mean_metrics
    from jaxdepth.research.hidden import METHODS

    keys = ("rmse", "mae", "irmse", "imae")
    rows = {name: [] for name in names}
    for scores in draws:
        for i, name in enumerate(names):
            row = {"hidden_pixels": int(scores["hidden_pixels"][i]),
                   "covered_pixels": int(scores["covered_pixels"][i]), "uncovered": {}}
            for method in METHODS:
                row[method] = {k: float(scores[method][k][i]) for k in keys}
                row["uncovered"][method] = {k: float(scores["uncovered"][method][k][i]) for k in keys}
            rows[name].append(row)
    every = [d for per in rows.values() for d in per]
    plain, uncovered = (lambda d: d), (lambda d: d["uncovered"])

    def draw_mean(per, pick):        # one camera: the mean over its draws
        return {method: {k: float(np.mean([pick(d)[method][k] for d in per])) for k in keys} for method in METHODS}

    def pooled(pick, count):         # every camera image of every draw (the devkit's data-set score)
        means = {method: mean_metrics([dict(pick(d)[method], count=count(d)) for d in every]) for method in METHODS}
        return {method: {k: float(m[k]) for k in keys} for method, m in means.items()}

    per_camera = {name: {"hidden_pixels": int(round(np.mean([d["hidden_pixels"] for d in per]))),
                         "covered_pixels": int(round(np.mean([d["covered_pixels"] for d in per]))),
                         **draw_mean(per, plain), "uncovered": draw_mean(per, uncovered)}
                  for name, per in rows.items()}
    hidden = sum(d["hidden_pixels"] for d in every)
    return {"cameras": per_camera, "mean": pooled(plain, lambda d: d["hidden_pixels"]),
            "mean_uncovered": pooled(uncovered, lambda d: d["hidden_pixels"] - d["covered_pixels"]),
            "covered_share": float(sum(d["covered_pixels"] for d in every) / max(hidden, 1)),
            "methods": list(METHODS)}


def scaled_rig(rig, scale: float):
    """``rig`` with every camera's image size and K scaled as :func:`scaled_camera` does."""
    import dataclasses

    from jaxdepth.io.rig import RigCamera
    if scale == 1.0:
        return rig
    cameras = []
    for c in rig.cameras:
        cam = scaled_camera(c.as_camera(), scale)
        cameras.append(RigCamera(c.name, cam.width, cam.height, np.asarray(cam.K, np.float32), c.T_cam_lidar,
                                 image=c.image))
    return dataclasses.replace(rig, cameras=tuple(cameras))


def hidden_eval_cloud(cloud, rig, *, complete_cloud, fraction: float = 0.2, seeds=(0,), scale: float = 1.0,
                      min_range_m: float = 1.0, config=None, estimate: bool = True, on_progress=None) -> dict:
    """Hidden-point scores of what ``complete-rig`` computes for a multi-source cloud (``lidars``, sweeps JSON).

    The cloud gets ``complete-rig``'s sweep check (:func:`jaxdepth.io.sweep_frame.prepare_cloud`:
    outlier removal off where it is not trusted); each seed holds out a share of the reference
    sweep's points (points closer than ``min_range_m`` to their own LiDAR dropped first); the methods
    run ``complete_cloud`` (:func:`jaxdepth.batch.sources_job.complete_cloud`, passed in: the job
    layer's function, so that the scores are of exactly what ``complete-rig`` runs) on the rest:
    the SGM, the SGM without removal, its nearest fill, the Euclidean nearest fill
    (:func:`jaxdepth.research.hidden.euclidean_fill` of the run without removal) and IP_Basic on
    its merged sparse image. ``uncovered`` judges each target's cover from its own source
    (:func:`jaxdepth.research.hidden.own_origin_targets`).

    ``on_progress`` as in :func:`hidden_eval`.

    Returns:
      the layout of :func:`hidden_eval`, plus "sources" (the cloud's source names).
    """
    import jax
    import jax.numpy as jnp

    from jaxdepth._src.config import SGMConfig
    from jaxdepth._src.ip_basic import ip_basic
    from jaxdepth._src.rig import stack_cameras
    from jaxdepth.io.sweep_frame import prepare_cloud, source_spec
    from jaxdepth.research.hidden import (default_cover_half_height_px, euclidean_fill_jit, hidden_point_mask,
                                          own_origin_targets, score_predictions)

    config = SGMConfig() if config is None else config
    seeds = _seeds(seeds)
    frame = prepare_cloud(cloud, rig, estimate=estimate)
    if not frame.outlier_removal_trusted and config.outlier_removal:
        config = config.replace(outlier_removal=False)
    rig = scaled_rig(frame.rig, scale)
    cloud = frame.cloud
    origin = cloud.T_ref_source[cloud.source, :3, 3]
    with np.errstate(invalid="ignore", over="ignore"):
        valid = np.all(np.isfinite(cloud.points), axis=1) & (
            np.linalg.norm(cloud.points.astype(np.float64) - origin, axis=1) >= min_range_m)
    cloud = cloud.take(valid)
    cameras = stack_cameras([c.as_camera() for c in rig.cameras])
    reference = np.asarray(cloud.sweep)[cloud.source] == 0
    # each reference source's cover window: its own scan-line spacing, from the spec complete_cloud uses
    heights = {s: default_cover_half_height_px(cameras.K, source_spec(cloud, s, rig.lidar)[0])
               for s in range(cloud.num_sources) if cloud.sweep[s] == 0}
    plain = config.replace(outlier_removal=False)
    draws, hidden_total = [], 0
    for seed in seeds:
        hidden = hidden_point_mask(reference, fraction=fraction, seed=seed)
        hidden_total += int(hidden.sum())
        given = cloud.take(~hidden)
        sgm = complete_cloud(given, rig, config=config, stages=True)
        base = complete_cloud(given, rig, config=plain, stages=True)
        euclid = base.seed_depth if config.distance_metric == "l2" else euclidean_fill_jit(base.inlier_mask,
                                                                                        base.sparse_depth)
        predictions = {"sgm": sgm.depth, "sgm_no_removal": base.depth, "nearest": base.seed_depth,
                       "nearest_l2": euclid, "ip_basic": jax.vmap(ip_basic)(jnp.asarray(base.sparse_depth))}
        target, covered = own_origin_targets(cloud.points, np.ones(len(hidden), bool), hidden, cloud.source,
                                             cameras, half_heights=heights)
        draws.append(score_predictions(predictions, target, covered))
        if on_progress is not None:
            on_progress(f"seed {seed}", "done")
    return dict(_summarise(draws, [c.name for c in rig.cameras]), points=int(valid.sum()),
                hidden_points=hidden_total // len(seeds), fraction=fraction, seeds=seeds, scale=scale,
                min_range_m=min_range_m, sweep_notes=list(frame.notes), outlier_removal=bool(config.outlier_removal),
                sources=list(cloud.names), **_TARGETS)


_SHORT = {"sgm": "SGM", "sgm_no_removal": "SGM-noOR", "nearest": "nearest", "nearest_l2": "nearest-L2",
          "ip_basic": "IP_Basic"}


def format_hidden(result: dict) -> list:
    methods = result["methods"]
    head = f"{'camera':16s}{'px':>6s}" + "".join(f"{_SHORT[m] + ' RMSE/MAE':>22s}" for m in methods)
    lines = [head]

    def cells(row):
        return "".join(f"{row[m]['rmse']:>13.1f} /{row[m]['mae']:>7.1f}" for m in methods)

    for name, row in result["cameras"].items():
        lines.append(f"{name[:16]:16s}{row['hidden_pixels']:6d}" + cells(row))
    lines.append(f"{'mean':16s}{'':6s}" + cells(result["mean"]))
    lines.append(f"{'uncovered':16s}{'':6s}" + cells(result["mean_uncovered"]))
    lines.append("")
    lines.append(f"{'method':12s}{'all targets RMSE / MAE':>26s}{'uncovered RMSE / MAE':>26s}")
    for m in methods:
        a, u = result["mean"][m], result["mean_uncovered"][m]
        lines.append(f"{_SHORT[m]:12s}{a['rmse']:>15.1f} /{a['mae']:>8.1f}{u['rmse']:>17.1f} /{u['mae']:>8.1f}")
    lines.append(f"{result['hidden_points']} of {result['points']} points hidden per draw (fraction "
                 f"{result['fraction']}, seeds {result['seeds']}); mm at the held-out points' own z-buffer "
                 f"(unfiltered); SGM-noOR = SGM without outlier removal; nearest = the SGM's own seeds (its metric), "
                 f"nearest-L2 = Euclidean nearest; nearest and IP_Basic without removal")
    lines.append(f"uncovered: the mean without the {100 * result['covered_share']:.1f} % of targets that nearer "
                 f"sweep points cover on both sides (hidden from the camera; a test independent of every method)"
                 + ("; each target judged with its own LiDAR's points" if "sources" in result else ""))
    return lines


def cmd_hidden_eval(args) -> int:
    from jaxdepth.io.points import read_points, ring_column
    from jaxdepth.io.rig import read_rig_json
    from jaxdepth.io.sweeps import is_sweeps_json, read_point_file_cloud, read_sweeps_cloud

    if not 0.0 < args.fraction < 1.0:
        raise InputError(f"--fraction expected a number in (0, 1), got {args.fraction}")
    if not 0.0 < args.scale <= 4.0:
        raise InputError(f"--scale expected a number in (0, 4], got {args.scale}")
    path = pathlib.Path(args.points)
    rig = read_rig_json(args.rig)
    from jaxdepth.progress import Progress
    progress = Progress(len(args.seeds), unit="seeds", label="hidden-eval",
                        verbose=bool(getattr(args, "verbose", False)))
    try:
        options = dict(fraction=args.fraction, seeds=args.seeds, scale=args.scale, estimate=not args.no_estimate,
                       min_range_m=args.min_range_m, config=_config(args))
        # complete-rig's two paths (jaxdepth.batch.rig_job), chosen and read as it does
        if is_sweeps_json(path) or rig.lidars:
            read = read_sweeps_cloud if is_sweeps_json(path) else read_point_file_cloud
            cloud = read(path, rig, point_columns=args.point_columns)
            if getattr(args, "complete_cloud", None) is None:
                raise InputError(f"{path}: a multi-source input (lidars / sweeps JSON) needs the jaxdepth command line's "
                                 "complete_cloud (register(..., complete_cloud=))")
            result = hidden_eval_cloud(cloud, rig, complete_cloud=args.complete_cloud, on_progress=progress.update,
                                       **options)
        else:
            columns = len(rig.columns) if rig.columns is not None else _point_columns(path, args.point_columns)
            points, extra = read_points(path, columns=columns)
            if rig.columns is not None:
                names = list(rig.columns[3:])
                ring = extra[:, names.index("ring")] if "ring" in names else None
            else:
                ring = ring_column(extra, columns)
            result = hidden_eval(points, rig, ring=ring, on_progress=progress.update, **options)
    finally:
        progress.close()
    if result["hidden_points"] == 0:
        raise InputError(f"{path}: no valid point to hide (all closer than {args.min_range_m} m or invalid)")
    for note in result["sweep_notes"]:
        print(f"sweep: {note}", file=sys.stderr)
    for line in format_hidden(result):
        print(line)
    if args.json:
        _write_json(args.json, result)
    return 0


# ---------------------------------------------------------------- registration


_POINT_COLUMNS = ("--point-columns", dict(type=int, default=None,
                                          help="float32 values per point in a .bin (default: 5 for *.pcd.bin; "
                                               "a plain .bin's size decides between 4 and 5, refused when both fit)"))

# subcommand -> (help, handler, arguments as (name, add_argument keywords)); every one also takes
# the SGM options of jaxdepth.options.add_config_options.
_SUBCOMMANDS = {
    "ablation": ("the paper's Tables 1, 5, 6 on a KITTI-layout folder with ground truth", cmd_ablation, (
        ("src", dict(help="folder with velodyne_raw/*.png and intrinsics/*.txt")),
        ("gt", dict(nargs="?", default=None,
                    help="folder of ground-truth PNGs with the same names (default: SRC/groundtruth_depth)")),
        ("--intrinsics", dict(help="K.txt for every frame (instead of SRC/intrinsics/)")),
        ("--json", dict(help="write {'mean': ..., 'per_frame': ...} to this file")),
    )),
    "sparsity": ("the paper's sparsity study: 64 / 32 / 16 simulated beams vs ground truth", cmd_sparsity, (
        ("sweep", dict(help="LiDAR sweep (.bin float32 records, .npy, .npz)")),
        ("calib_dir", dict(help="folder with KITTI raw calib_cam_to_cam.txt and calib_velo_to_cam.txt")),
        ("gt", dict(help="ground-truth depth PNG of the camera (full frame or 352x1216 benchmark crop)")),
        ("--camera", dict(type=int, choices=(0, 1, 2, 3), default=2, help="KITTI camera index (default 2)")),
        ("--beams", dict(type=int, nargs="+", default=[64, 32, 16],
                         help="simulated beam counts, divisors of --lidar-beams (default: 64 32 16)")),
        ("--lidar-beams", dict(type=int, default=64, help="beams of the recording LiDAR (default 64)")),
        _POINT_COLUMNS,
        ("--json", dict(help="write the table as JSON to this file")),
    )),
    "hidden-eval": ("hidden-point scores of what complete-rig computes, for every camera of a rig JSON",
                    cmd_hidden_eval, (
        ("points", dict(help="LiDAR sweep (.bin, .pcd.bin, .npy, .npz) or a sweeps JSON (docs/multi_source.md)")),
        ("rig", dict(help="rig JSON (docs/rig_json.md; with lidars / columns as complete-rig reads them)")),
        ("--point-columns", dict(type=int, default=None, help=(
            "float32 values per point in a .bin (default: the rig JSON's columns when it names them; else 5 for "
            "*.pcd.bin, and a plain .bin's size decides between 4 and 5, refused when both fit)"))),
        ("--fraction", dict(type=float, default=0.2, help="share of the points held out (default 0.2)")),
        ("--no-estimate", dict(action="store_true", help="do not estimate the LiDAR's position / field of view "
                                                         "from the sweep (see docs/rig_json.md)")),
        ("--seeds", dict(type=int, nargs="+", default=[0, 1, 2, 3, 4],
                         help="one held-out draw per seed, scores averaged (default 0 1 2 3 4)")),
        ("--scale", dict(type=float, default=1.0, help="scale of every camera's image size and K (default 1)")),
        ("--min-range-m", dict(type=float, default=1.0,
                               help="drop points closer to the LiDAR than this, metres (default 1.0)")),
        ("--json", dict(help="write the per-camera table as JSON to this file")),
    )),
}


def register(subparsers, *, complete_cloud=None) -> None:
    """Adds ``ablation``, ``sparsity`` and ``hidden-eval`` to an argparse subparsers object.

    ``complete_cloud``: the job layer's :func:`jaxdepth.batch.sources_job.complete_cloud`, which
    ``hidden-eval`` runs on a multi-source input (passed in by :func:`jaxdepth.cli.build_parser`:
    research code sits below the jobs and imports none); None: such inputs are refused.
    """
    for command, (help_text, handler, arguments) in _SUBCOMMANDS.items():
        p = subparsers.add_parser(command, help=help_text)
        for name, options in arguments:
            p.add_argument(name, **options)
        add_config_options(p)
        p.set_defaults(func=handler)
        if command == "hidden-eval":
            p.set_defaults(complete_cloud=complete_cloud)


__all__ = ["register", "cmd_ablation", "cmd_sparsity", "cmd_hidden_eval", "hidden_eval", "hidden_eval_cloud",
           "scaled_camera", "scaled_rig", "format_hidden"]
