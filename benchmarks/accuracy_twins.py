"""Every method on every digital twin, scored against exact depth and through ``hidden-eval``'s protocols.

    python -m benchmarks.accuracy_twins [--rigs kitti av2 ...] [--sweeps 1 3 5] [--seeds 0]
        [--hidden-seeds 0] [--scale S] [--above-scan plane|background]
        [--json benchmarks/results/accuracy_twins.json]

Each twin runs at its own camera scale (:data:`DEFAULT_SCALES`: the real camera sizes where a
full-size run is affordable on the shared 2-core machine: today every twin); ``--scale``
sets one scale for every twin. Each case records its scale and camera sizes.

The twins (:mod:`jaxdepth.research.twins`, ``docs/twins.md``: ray-cast copies of the KITTI,
nuScenes, Argoverse 2, a merged raster and a rosette rig, exact camera depth) are written to disk
as a user has them (``write_twin``: one point file per sweep, ``rig.json``, ``sweeps.json``) and read back as ``jaxdepth complete-rig`` reads them
(:func:`read_user_input`, the reading half of :func:`jaxdepth.batch.rig_job.run_rig_job`): 1 sweep
is the reference sweep's point file, 3 and 5 sweeps the sweeps JSON. Methods, on that input:

- ``sgm``: what ``complete-rig`` computes with default options: the multi-source path
  (:func:`~jaxdepth.batch.sources_job.complete_cloud`) for a sweeps JSON or a rig with ``lidars``,
  else the single-sweep path (:func:`jaxdepth.io.prepare_sweep`, removal off where the sweep does
  not look like one spinning LiDAR);
- ``sgm_no_removal``: the same with ``outlier_removal=False``;
- ``sgm_no_free_space``: the same with ``free_space=False`` (the single-sweep path has no free-space
  rules: there it is ``sgm``, and the pair is skipped in the agreement table);
- ``sgm_one_cloud``: every point as one point file (one origin, no ``lidars``/``columns``) through
  the single-sweep path;
- ``nearest``, ``nearest_l2``, ``ip_basic``: :func:`jaxdepth._src.methods.complete_with` (city-block,
  Euclidean nearest fill, IP_Basic) without removal on that one-cloud input's z-buffer.

Scores (KITTI devkit RMSE / MAE, mm, mean over camera images): ``full``: each method on the whole
input against the exact depth of every pixel (the accuracy table). Then, per hold-out seed, a
seeded 20 % of the reference sweep's points at >= 1 m from their LiDAR is held out (as
``hidden-eval``: :func:`~jaxdepth.research.hidden.hidden_point_mask`), every method runs on the
rest, and its *same* prediction is scored four ways: ``exact_dense`` (exact depth, every pixel),
``exact_held_out`` (exact depth at the held-out points' pixels), ``hidden_all`` (the held-out
points' own z-buffer: ``hidden-eval``'s all targets) and ``hidden_uncovered`` (without the targets
:func:`~jaxdepth.research.hidden.covered_targets` drops, judged from the reference sweep as
``hidden-eval`` does). The agreement table: for each protocol, the share of method pairs it
ranks the way ``exact_dense`` does (pairs that tie under ``exact_dense`` are left out).

Oracle bound (as docs/multi_source.md): the SGM on the input without every point that the exact
depth shows wrong at its pixel in some camera (by more than 0.5 m, or seeing sky), free-space rules
off; its gain over the default SGM on 1 sweep is what more sweeps could give at best with perfect
point removal. Nothing here chooses a default. ``--above-scan`` sets ``SGMConfig.above_scan`` of every
SGM method (the baselines have no such step); ``--smoothing-sigma`` sets ``SGMConfig.smoothing_sigma_px``
(Step 4's Gaussian) the same way; the settings record both.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import tempfile
import time

import jax.numpy as jnp
import numpy as np

from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.geometry import project_to_image
from jaxdepth._src.methods import complete_with
from jaxdepth._src.metrics import depth_metrics, mean_metrics

RIGS = ("kitti", "nuscenes", "av2", "raster", "rosette")
METHODS = ("sgm", "sgm_no_removal", "sgm_no_free_space", "sgm_one_cloud", "nearest", "nearest_l2", "ip_basic")
PROTOCOLS = ("exact_dense", "exact_held_out", "hidden_all", "hidden_uncovered")
KEYS = ("rmse", "mae")
FRACTION = 0.2
MIN_RANGE_M = 1.0
TRUTH_TOLERANCE_M = 0.5
# The camera scale each twin runs at unless --scale is given (1.0: the real rig's camera sizes). Every
# twin runs at full size, Argoverse 2's 7 cameras (22 Mpx) too: a case with hold-out takes 4-10 min on
# the shared 2-core machine (run times: docs/twins.md, "Camera scale"). A rig too big for that gets < 1.
DEFAULT_SCALES = {"kitti": 1.0, "nuscenes": 1.0, "av2": 1.0, "raster": 1.0, "rosette": 1.0}


def rig_scale(rig: str, override: float | None = None) -> float:
    """The camera scale twin ``rig`` runs at: ``override`` (``--scale``) if given, else :data:`DEFAULT_SCALES`."""
    return float(DEFAULT_SCALES[rig] if override is None else override)


def twin_camera_sizes(rig: str, scale: float) -> list:
    """[[W, H], ...] of twin ``rig``'s cameras at ``scale``, as ``make_twin`` sizes them (without building it)."""
    from jaxdepth.research.twin_rigs import RIG_BUILDERS
    from jaxdepth.research.twin_sensors import SensorEffects
    return [[max(1, round(w * scale)), max(1, round(h * scale))]
            for _, _, w, h, _ in RIG_BUILDERS[rig](SensorEffects()).cameras]


def size_label(scale: float, sizes: list) -> str:
    """``"1 (1242 x 375)"``: a twin's camera scale and its cameras' most common size."""
    w, h = max(sizes, key=lambda s: (sizes.count(s), s))
    return f"{scale:g} ({w} x {h})"


# ---------------------------------------------------------------- the user's input, read as complete-rig reads it

@dataclasses.dataclass(frozen=True)
class UserInput:
    """What ``complete-rig POINTS RIG.json`` reads: the rig, every point as a SourceCloud (one source at
    the points' origin on the single-sweep path), and which path it takes."""

    rig: object
    cloud: object
    multi: bool
    path: str


def npy_columns(path) -> int | None:
    """The values per point of a ``.npy`` point file (what a user passes as ``--point-columns``), else None."""
    path = pathlib.Path(path)
    return int(np.load(path, mmap_mode="r").shape[1]) if path.suffix == ".npy" else None


def twin_parser(description: str, *, rig: str, sweeps: int, scale: float):
    """An argument parser with the options every one-twin study takes: ``--rig``, ``--sweeps``,
    ``--scale``, ``--json``."""
    import argparse
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--rig", default=rig, choices=RIGS)
    parser.add_argument("--sweeps", type=int, default=sweeps)
    parser.add_argument("--scale", type=float, default=scale)
    parser.add_argument("--json", default=None)
    return parser


def read_user_input(points_path, rig_path) -> UserInput:
    """Reads a point file or sweeps JSON and a rig JSON the way :func:`~jaxdepth.batch.rig_job.run_rig_job`
    does, with ``--point-columns`` set to a ``.npy`` file's own column count."""
    from jaxdepth._src.types import SourceCloud
    from jaxdepth.io import infer_point_columns, read_points, read_rig_json
    from jaxdepth.io.points import ring_column
    from jaxdepth.io.sweeps import (
        is_sweeps_json,
        read_point_file_cloud,
        read_sweeps_cloud,
    )
    rig = read_rig_json(rig_path)
    if is_sweeps_json(points_path) or bool(rig.lidars):
        read = read_sweeps_cloud if is_sweeps_json(points_path) else read_point_file_cloud
        given = None
        if not is_sweeps_json(points_path):
            given = npy_columns(points_path)
        else:
            files = json.loads(pathlib.Path(points_path).read_text())["sweeps"]
            counts = {npy_columns(pathlib.Path(points_path).parent / e["file"]) for e in files}
            given = counts.pop() if len(counts) == 1 else None
        return UserInput(rig, read(points_path, rig, point_columns=given), True, str(points_path))
    columns = len(rig.columns) if rig.columns is not None else infer_point_columns(points_path,
                                                                                    npy_columns(points_path))
    points, extra = read_points(points_path, columns=columns)
    if rig.columns is not None:
        ring = extra[:, list(rig.columns[3:]).index("ring")] if "ring" in rig.columns[3:] else None
    else:
        ring = ring_column(extra, columns)
    cloud = SourceCloud(points=points[:, :3].astype(np.float32), source=np.zeros(len(points), np.int32),
                        T_ref_source=np.eye(4)[None], lidars=(None,), sweep=np.zeros(1, np.int32),
                        names=("points",), ring=None if ring is None else np.asarray(ring, np.int32))
    return UserInput(rig, cloud, False, str(points_path))


def single_path(points, ring, rig, config: SGMConfig, *, force_removal: bool = False, stages: bool = False):
    """(C, H_max, W_max) depth and the prepared frame: ``complete-rig``'s single-sweep path
    (``force_removal``: keep the configured removal where the sweep check would turn it off; ``stages``:
    every (C, H_max, W_max) :class:`~jaxdepth.Stages` field instead of the depth)."""
    import jaxdepth
    from jaxdepth.io import pad_points, prepare_sweep
    frame = prepare_sweep(points, rig, ring=ring)
    if not frame.outlier_removal_trusted and not force_removal:
        config = config.replace(outlier_removal=False)
    padded, valid = pad_points(frame.points)
    cams = jaxdepth.stack_cameras([c.as_camera() for c in frame.rig.cameras])
    out = jaxdepth.complete_rig_stages(padded, valid, cams, config=config, lidar=frame.rig.lidar)
    return (out if stages else np.asarray(out.depth)), frame


def one_cloud_rig(rig):
    """The rig a user gives with every point in one file: no ``lidars``, no ``columns``."""
    return dataclasses.replace(rig, lidars=(), columns=None)


def crops(canvas, rig) -> list:
    """Camera ``i``'s (H_i, W_i) image from a (C, H_max, W_max) canvas, for each camera."""
    return [np.asarray(canvas[i, :c.height, :c.width]) for i, c in enumerate(rig.cameras)]


def z_buffers(points, rig) -> list:
    """Each camera's (H_i, W_i) nearest-point z-buffer of ``points`` (reference frame)."""
    from jaxdepth.io import pad_points
    padded, valid = pad_points(np.asarray(points, np.float32))
    return [np.asarray(project_to_image(jnp.asarray(padded), jnp.asarray(valid), jnp.asarray(c.K),
                                        jnp.asarray(c.T_cam_lidar), height=c.height, width=c.width)[0])
            for c in rig.cameras]


def predictions(inp: UserInput, keep, config: SGMConfig, *, free_space_rules: bool = True) -> dict:
    """{method: [camera image]} of every method of :data:`METHODS` on the input's points where ``keep``."""
    from jaxdepth.batch.sources_job import complete_cloud
    cloud = inp.cloud.take(keep)
    plain = config.replace(outlier_removal=False)
    if inp.multi:
        runs = {"sgm": complete_cloud(cloud, inp.rig, config=config),
                "sgm_no_removal": complete_cloud(cloud, inp.rig, config=plain),
                "sgm_no_free_space": complete_cloud(cloud, inp.rig, config=config, free_space=False)}
    else:
        runs = {"sgm": single_path(cloud.points, cloud.ring, inp.rig, config)[0],
                "sgm_no_removal": single_path(cloud.points, cloud.ring, inp.rig, plain)[0]}
        runs["sgm_no_free_space"] = runs["sgm"]        # no free-space rules on this path
    one_rig = one_cloud_rig(inp.rig)
    runs["sgm_one_cloud"], frame = single_path(cloud.points, None, one_rig, config)
    out = {name: crops(depth, inp.rig) for name, depth in runs.items()}
    sparse = z_buffers(frame.points, frame.rig)
    for name, method, metric in (("nearest", "nearest", "l1"), ("nearest_l2", "nearest", "l2"),
                                 ("ip_basic", "ip-basic", "l1")):
        cfg = plain.replace(distance_metric=metric)
        out[name] = [np.asarray(complete_with(s, c.K, c.T_cam_lidar, method=method, config=cfg,
                                              lidar=frame.rig.lidar)) for s, c in zip(sparse, frame.rig.cameras)]
    return out


# ---------------------------------------------------------------- scoring

def score(pred: list, truth: list) -> dict:
    """KITTI devkit RMSE / MAE (mm) of each camera image and their mean over images with truth."""
    per = [{k: float(v) for k, v in depth_metrics(jnp.asarray(p), jnp.asarray(t)).items()}
           for p, t in zip(pred, truth)]
    mean = mean_metrics([dict(r, count=int(r["count"])) for r in per])
    return {"rmse": float(mean["rmse"]), "mae": float(mean["mae"]),
            "per_camera": [{"rmse": r["rmse"], "mae": r["mae"], "count": int(r["count"])} for r in per]}


def exact_truth(twin, rig) -> list:
    """Each camera's (H_i, W_i) exact depth."""
    return [np.asarray(twin.dense_depth[i, :c.height, :c.width], np.float32) for i, c in enumerate(rig.cameras)]


def hold_out(inp: UserInput, seed: int):
    """(hidden (N,) bool, targets, full): ``hidden-eval``'s draw over the reference sweep's points at
    >= 1 m from their LiDAR, the held-out points' z-buffers and every reference point's, per camera."""
    from jaxdepth.research.hidden import hidden_point_mask
    c = inp.cloud
    ref = c.sweep[c.source] == 0
    far = np.linalg.norm(c.points.astype(np.float64) - c.origins_m[c.source], axis=1) >= MIN_RANGE_M
    valid = ref & np.all(np.isfinite(c.points), axis=1) & far
    hidden = hidden_point_mask(valid, fraction=FRACTION, seed=seed)
    return hidden, z_buffers(c.points[hidden], inp.rig), z_buffers(c.points[valid], inp.rig)


def cover_half_height(inp: UserInput) -> int:
    """``hidden-eval``'s covered-test half height: from the reference sweep prepared as one file."""
    from jaxdepth.io import prepare_sweep
    from jaxdepth.research.hidden import default_cover_half_height_px
    c = inp.cloud
    frame = prepare_sweep(c.points[c.sweep[c.source] == 0], one_cloud_rig(inp.rig))
    return default_cover_half_height_px(np.stack([cam.K for cam in frame.rig.cameras]), frame.rig.lidar)


def protocol_truths(exact: list, targets: list, full: list, half_height: int) -> tuple:
    """({protocol: [camera image]}, target statistics) of one hold-out."""
    from jaxdepth.research.hidden import covered_targets
    covered = [np.asarray(covered_targets(jnp.asarray(t), jnp.asarray(f), half_height_px=half_height))
               for t, f in zip(targets, full)]
    truths = {"exact_dense": exact,
              "exact_held_out": [np.where(t > 0, e, 0.0).astype(np.float32) for e, t in zip(exact, targets)],
              "hidden_all": targets,
              "hidden_uncovered": [np.where(cv, 0.0, t).astype(np.float32) for cv, t in zip(covered, targets)]}
    n = sum(int((t > 0).sum()) for t in targets)
    wrong = [(t > 0) & (np.abs(t - e) > np.maximum(1.0, 0.05 * e)) for t, e in zip(targets, exact)]
    n_wrong = sum(int(w.sum()) for w in wrong)
    n_cov = sum(int(cv.sum()) for cv in covered)
    stats = {"targets": n, "wrong_target_share": n_wrong / max(n, 1), "covered_share": n_cov / max(n, 1),
             "covered_precision": sum(int((w & cv).sum()) for w, cv in zip(wrong, covered)) / max(n_cov, 1),
             "cover_half_height_px": int(half_height)}
    return truths, stats


def truth_filtered_keep(cloud, rig, exact: list, *, tolerance_m: float = TRUTH_TOLERANCE_M) -> np.ndarray:
    """(N,) bool, a diagnosis that reads the truth: False for points that some camera sees at a pixel
    whose exact depth differs from theirs by more than ``tolerance_m`` (or is sky)."""
    keep = np.ones(len(cloud.points), bool)
    p = cloud.points.astype(np.float64)
    for cam, truth in zip(rig.cameras, exact):
        T, K = np.asarray(cam.T_cam_lidar, np.float64), np.asarray(cam.K, np.float64)
        q = p @ T[:3, :3].T + T[:3, 3]
        ahead = q[:, 2] > 0.1
        z = np.where(ahead, q[:, 2], 1.0)
        uv = np.round((q @ K.T)[:, :2] / z[:, None]).astype(np.int64)
        inside = ahead & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        seen = np.zeros(len(p))
        seen[inside] = truth[uv[inside, 1], uv[inside, 0]]
        keep &= ~(inside & ((seen == 0) | (np.abs(seen - q[:, 2]) > tolerance_m)))
    return keep


# ---------------------------------------------------------------- one case, the summaries

def removal_diagnosis(inp: UserInput, exact: list, config: SGMConfig) -> dict:
    """Where the single-sweep path turns removal off (its own input, or every point as one file), the
    SGM with removal forced on from the points' origin, full input (a diagnosis, not a method)."""
    from jaxdepth.io import prepare_sweep
    out = {}
    c = inp.cloud
    runs = {"one_cloud": (c.points, None, one_cloud_rig(inp.rig))}
    if not inp.multi:
        runs["input"] = (c.points, c.ring, inp.rig)
    for name, (points, ring, rig) in runs.items():
        frame = prepare_sweep(points, rig, ring=ring)
        row = {"removal_trusted": bool(frame.outlier_removal_trusted), "origin_m": frame.origin_m.tolist()}
        if not frame.outlier_removal_trusted:
            depth = single_path(points, ring, rig, config, force_removal=True)[0]
            row["sgm_forced_removal"] = score(crops(depth, inp.rig), exact)
        out[name] = row
    return out


def run_case(make_twin, write_twin, rig_name: str, sweeps: int, seed: int, *, hidden_seeds, scale: float,
             config: SGMConfig, oracle: bool = True, diagnose: bool = False) -> dict:
    """Every method on one twin: full-input scores, each hold-out's four protocols, the oracle bound
    (and with ``diagnose`` :func:`removal_diagnosis`)."""
    twin = make_twin(rig_name, sweeps=sweeps, seed=seed, scale=scale)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(twin, tmp)
        points = paths["sweeps_json"] if sweeps > 1 else paths["sweeps"][0]
        inp = read_user_input(points, paths["rig"])
    exact = exact_truth(twin, inp.rig)
    everything = np.ones(len(inp.cloud.points), bool)
    full = predictions(inp, everything, config)
    case = {"rig": rig_name, "sensor_class": twin.sensor_class, "sweeps": sweeps, "seed": seed,
            "scale": float(scale), "camera_sizes": [[int(c.width), int(c.height)] for c in inp.rig.cameras],
            "path": "multi-source" if inp.multi else "single-sweep", "points": len(inp.cloud.points),
            "cameras": [c.name for c in inp.rig.cameras],
            "full": {m: score(full[m], exact) for m in METHODS}, "held_out": []}
    if oracle:
        keep = truth_filtered_keep(inp.cloud, inp.rig, exact)
        cloud = inp.cloud.take(keep)
        if inp.multi:
            from jaxdepth.batch.sources_job import complete_cloud
            depth = complete_cloud(cloud, inp.rig, config=config, free_space=False)
        else:
            depth = single_path(cloud.points, cloud.ring, inp.rig, config)[0]
        case["oracle_truth_filtered"] = dict(score(crops(depth, inp.rig), exact),
                                             points_removed=int((~keep).sum()))
    if diagnose:
        case["removal_diagnosis"] = removal_diagnosis(inp, exact, config)
    half = cover_half_height(inp)
    for hs in hidden_seeds:
        hidden, targets, full_z = hold_out(inp, hs)
        truths, stats = protocol_truths(exact, targets, full_z, half)
        preds = predictions(inp, ~hidden, config)
        case["held_out"].append({"hidden_seed": hs, **stats, "scores": {
            p: {m: score(preds[m], truths[p]) for m in METHODS} for p in PROTOCOLS}})
    return case


def _sign(a: float, b: float, tol: float = 1e-6) -> int:
    if abs(a - b) <= tol * max(abs(a), abs(b), 1e-12):
        return 0
    return 1 if a > b else -1


def agreement(cases: list, *, reference: str = "exact_dense") -> dict:
    """{metric: {protocol: {rig: {"agree_pct", "pairs"}, "overall": ...}}}: the share of method pairs each
    protocol ranks as ``reference`` does, over every hold-out of every case (pairs tied under the
    reference, e.g. identical predictions, left out; a tie under the protocol counts as a disagreement)."""
    out = {}
    for metric in KEYS:
        tally = {}
        for case in cases:
            for draw in case["held_out"]:
                ref = draw["scores"][reference]
                for p in PROTOCOLS:
                    got = draw["scores"][p]
                    for i, a in enumerate(METHODS):
                        for b in METHODS[i + 1:]:
                            s = _sign(ref[a][metric], ref[b][metric])
                            if s == 0:
                                continue
                            same = int(_sign(got[a][metric], got[b][metric]) == s)
                            for key in (case["rig"], "overall"):
                                agree, n = tally.get((p, key), (0, 0))
                                tally[(p, key)] = (agree + same, n + 1)
        out[metric] = {}
        for (p, key), (agree, n) in tally.items():
            out[metric].setdefault(p, {})[key] = {"agree_pct": 100.0 * agree / n, "pairs": n}
    return out


def _mean(rows: list, key: str) -> float:
    return float(np.mean([r[key] for r in rows]))


def scales(cases: list) -> dict:
    """{rig: camera scale} of the cases; a ValueError if one twin's cases mix scales (their scores
    are not comparable: one table row per twin and sweep count)."""
    out = {}
    for c in cases:
        if out.setdefault(c["rig"], c["scale"]) != c["scale"]:
            raise ValueError(f"accuracy_twins: field 'scale' of the {c['rig']} cases expected one value, got "
                             f"{sorted({x['scale'] for x in cases if x['rig'] == c['rig']})}")
    return out


def summary(cases: list) -> dict:
    """{rig: {sweeps: {method: {rmse, mae}}}}: full-input scores, mean over seeds (and the oracle row)."""
    scales(cases)
    out = {}
    for rig in dict.fromkeys(c["rig"] for c in cases):
        for n in sorted({c["sweeps"] for c in cases if c["rig"] == rig}):
            mine = [c for c in cases if c["rig"] == rig and c["sweeps"] == n]
            row = {m: {k: _mean([c["full"][m] for c in mine], k) for k in KEYS} for m in METHODS}
            if all("oracle_truth_filtered" in c for c in mine):
                row["oracle_truth_filtered"] = {k: _mean([c["oracle_truth_filtered"] for c in mine], k)
                                                for k in KEYS}
            out.setdefault(rig, {})[str(n)] = row
    return out


def targets_check(table: dict) -> dict:
    """The issue's targets per rig: default SGM vs city-block fill (>= 10 % in RMSE and MAE, 1 and 5
    sweeps), 5 sweeps vs 1 (>= 5 %, or half the oracle bound where that is below 5 %).

    Two bounds: ``oracle_gain_5_vs_1_pct``, the truth-filtered 5 sweeps against the default SGM on 1 sweep
    (``met``), and ``oracle_like_for_like_5_vs_1_pct``, the truth-filtered 5 sweeps against the truth-filtered
    1 sweep (``met_like_for_like``): the first also credits 5 sweeps with removing the reference sweep's own
    wrong points, which 1 sweep would gain as much from (docs/multi_source.md, "At full camera size")."""
    def gain(a, b, k):
        return 100.0 * (1.0 - a[k] / b[k])
    out = {}
    for rig, rows in table.items():
        r = {"sgm_vs_nearest_pct": {n: {k: gain(rows[n]["sgm"], rows[n]["nearest"], k) for k in KEYS}
                                    for n in rows}}
        met = all(v >= 10.0 for n in ("1", "5") if n in rows for v in r["sgm_vs_nearest_pct"][n].values())
        if "1" in rows and "5" in rows:
            r["gain_5_vs_1_pct"] = {k: gain(rows["5"]["sgm"], rows["1"]["sgm"], k) for k in KEYS}
            if "oracle_truth_filtered" in rows["5"]:
                r["oracle_gain_5_vs_1_pct"] = {k: gain(rows["5"]["oracle_truth_filtered"], rows["1"]["sgm"], k)
                                               for k in KEYS}
            if "oracle_truth_filtered" in rows["1"] and "oracle_truth_filtered" in rows["5"]:
                r["oracle_like_for_like_5_vs_1_pct"] = {
                    k: gain(rows["5"]["oracle_truth_filtered"], rows["1"]["oracle_truth_filtered"], k) for k in KEYS}

            def reached(bound):
                need = {k: min(5.0, 0.5 * bound[k]) if k in bound else 5.0 for k in KEYS}
                return all(r["gain_5_vs_1_pct"][k] >= need[k] for k in KEYS)
            like = r.get("oracle_like_for_like_5_vs_1_pct")
            met_like = met and like is not None and reached(like)
            met = met and reached(r.get("oracle_gain_5_vs_1_pct", {}))
            r["met_like_for_like"] = bool(met_like)
        r["met"] = bool(met)
        out[rig] = r
    return out


def describe_part(cases: list) -> str:
    """A one-line description of a result file's cases: each twin's scale, sweep counts, seeds, hold-outs."""
    out = []
    for rig in dict.fromkeys(c["rig"] for c in cases):
        mine = [c for c in cases if c["rig"] == rig]
        draws = sorted({d["hidden_seed"] for c in mine for d in c["held_out"]})
        out.append(f"{rig} at camera scale {mine[0]['scale']:g}, sweeps "
                   + " ".join(str(n) for n in sorted({c["sweeps"] for c in mine}))
                   + ", seeds " + " ".join(str(x) for x in sorted({c["seed"] for c in mine}))
                   + (", hold-out seeds " + " ".join(map(str, draws)) if draws else ", no hold-out"))
    return "; ".join(out)


def merge_parts(parts: list, notes: list) -> tuple:
    """(cases, merged_from) of result documents merged in order. A case without a ``scale`` (a file
    written before scales were per twin) takes its file's ``settings.scale``. A later file's cases
    replace earlier cases of the same (twin, sweeps, seed), and every earlier case of a twin that the
    later file runs at another scale. Cases come out in :data:`RIGS` order, then by sweeps and seed.
    ``merged_from``: per file, what it contributed (no paths)."""
    kept = []                                           # (part index, case)
    for i, doc in enumerate(parts):
        new = [dict(c, scale=float(c.get("scale", doc["settings"]["scale"]))) for c in doc["cases"]]
        new = [c if "camera_sizes" in c else dict(c, camera_sizes=twin_camera_sizes(c["rig"], c["scale"]))
               for c in new]
        ids = {(c["rig"], c["sweeps"], c["seed"]) for c in new}
        scale_of = {c["rig"]: c["scale"] for c in new}
        kept = [(j, c) for j, c in kept if (c["rig"], c["sweeps"], c["seed"]) not in ids
                and scale_of.get(c["rig"], c["scale"]) == c["scale"]]
        kept += [(i, c) for c in new]
    merged_from = []
    for i, (doc, note) in enumerate(zip(parts, notes)):
        mine = [c for j, c in kept if j == i]
        if mine:
            entry = {"cases": describe_part(mine), "run_seconds": doc.get("run_seconds", doc["seconds"])}
            merged_from.append(dict(entry, note=note) if note else entry)
    order = sorted(kept, key=lambda jc: (RIGS.index(jc[1]["rig"]), jc[1]["sweeps"], jc[1]["seed"]))
    return [c for _, c in order], merged_from


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rigs", nargs="+", default=list(RIGS), choices=RIGS)
    parser.add_argument("--sweeps", nargs="+", type=int, default=[1, 3, 5])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--hidden-seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--scale", type=float, default=None,
                        help="camera scale of every twin (1: real sizes; default: each twin's DEFAULT_SCALES)")
    parser.add_argument("--json", default=str(RESULTS / "accuracy_twins.json"))
    parser.add_argument("--diagnose", action="store_true",
                        help="also the SGM with removal forced on where the sweep check turns it off")
    parser.add_argument("--no-hold-out", action="store_true", help="full-input scores only (no protocols)")
    parser.add_argument("--laser-phases", action="store_true",
                        help="spinning twins' lasers each at their own azimuth phase (make_twin(laser_phases=True))")
    parser.add_argument("--above-scan", choices=("plane", "background", "capped"), default=SGMConfig().above_scan,
                        help="SGMConfig.above_scan of every SGM method (default: the library's)")
    parser.add_argument("--smoothing-sigma", type=float, default=SGMConfig().smoothing_sigma_px,
                        help="SGMConfig.smoothing_sigma_px of every SGM method (default: the library's)")
    parser.add_argument("--tables", metavar="JSON", help="print the docs' tables of a result file and exit")
    parser.add_argument("--merge", nargs="+", metavar="JSON",
                        help="write --json from the cases of these result files and exit; a later file's cases "
                             "replace earlier ones of the same twin, sweeps and seed, or of that twin at another scale")
    parser.add_argument("--notes", nargs="+", metavar="TEXT", default=(),
                        help="with --merge: one note per file (what its run was), recorded in merged_from")
    args = parser.parse_args(argv)
    if args.tables:
        print(markdown(json.loads(pathlib.Path(args.tables).read_text())))
        return 0
    t0 = time.time()
    if args.merge:
        if args.notes and len(args.notes) != len(args.merge):
            parser.error(f"--notes: expected one note per --merge file ({len(args.merge)}), got {len(args.notes)}")
        parts = [json.loads(pathlib.Path(f).read_text()) for f in args.merge]
        cases, merged_from = merge_parts(parts, list(args.notes) or [None] * len(parts))
        args.rigs = list(dict.fromkeys(c["rig"] for c in cases))
        args.sweeps = sorted({c["sweeps"] for c in cases})
        args.seeds = sorted({c["seed"] for c in cases})
        args.hidden_seeds = sorted({d["hidden_seed"] for c in cases for d in c["held_out"]})
        args.scale = None
        doc = document(cases, args, complete=all(d["complete"] for d in parts))
        write_results(args.json, dict(doc, merged_from=merged_from), SGMConfig(), t0)
        return 0
    config = SGMConfig(above_scan=args.above_scan, smoothing_sigma_px=args.smoothing_sigma)
    from jaxdepth.research.twins import make_twin, write_twin
    if args.laser_phases:
        import functools
        make_twin = functools.partial(make_twin, laser_phases=True)
    cases = []
    for n in args.sweeps:
        for rig in args.rigs:
            for seed in args.seeds:
                case = run_case(make_twin, write_twin, rig, n, seed, config=config,
                                scale=rig_scale(rig, args.scale),
                                hidden_seeds=() if args.no_hold_out else args.hidden_seeds, diagnose=args.diagnose)
                cases.append(case)
                print(f"{rig} scale={case['scale']:g} sweeps={n} seed={seed} ({case['path']}, {time.time() - t0:.0f} s): " + ", ".join(
                    f"{m} {case['full'][m]['rmse']:.0f}/{case['full'][m]['mae']:.0f}" for m in METHODS), flush=True)
                write_results(args.json, document(cases, args, complete=False), config, t0)
    doc = document(cases, args, complete=True)
    write_results(args.json, doc, config, t0)
    for metric, rows in doc["agreement"].items():
        for p, per in rows.items():
            print(f"agreement {metric} {p}: " + ", ".join(f"{k} {v['agree_pct']:.0f} % ({v['pairs']})"
                                                           for k, v in per.items()))
    print(f"wrote {args.json} ({time.time() - t0:.0f} s)")
    return 0


def markdown(doc: dict) -> str:
    """The docs' tables (docs/evaluation.md, "Digital twins") from a result document."""
    short = {"sgm": "SGM", "sgm_no_removal": "no removal", "sgm_no_free_space": "no free space",
             "sgm_one_cloud": "one cloud", "nearest": "city block", "nearest_l2": "Euclidean", "ip_basic": "IP_Basic",
             "oracle_truth_filtered": "oracle bound"}
    sizes = doc["settings"]["camera_sizes"]
    label = {rig: size_label(scale, sizes[rig]) for rig, scale in doc["settings"]["scales"].items()}
    lines = ["| twin | camera scale | sweeps | " + " | ".join(short[m] for m in METHODS) + " | oracle bound |",
             "|---|---|---|" + "---|" * (len(METHODS) + 1)]
    for rig, rows in doc["summary"].items():
        for n in sorted(rows, key=int):
            row = rows[n]
            best = min(METHODS, key=lambda m: row[m]["mae"])
            cells = [(f"**{row[m]['rmse']:.0f} / {row[m]['mae']:.0f}**" if m == best
                      else f"{row[m]['rmse']:.0f} / {row[m]['mae']:.0f}") for m in METHODS]
            orc = row.get("oracle_truth_filtered")
            cells.append("-" if orc is None else f"{orc['rmse']:.0f} / {orc['mae']:.0f}")
            lines.append(f"| {rig} | {label[rig]} | {n} | " + " | ".join(cells) + " |")
    lines += ["", "| twin | camera scale | SGM vs city block, 1 sweep | 5 sweeps | 5 sweeps vs 1 | "
              "oracle bound 5 vs 1 | met | like-for-like bound | met |", "|---|---|---|---|---|---|---|---|---|"]
    for rig, t in doc["targets"].items():
        def pct(d):
            return "-" if d is None else f"{d['rmse']:+.1f} / {d['mae']:+.1f} %"
        vs = t["sgm_vs_nearest_pct"]
        lines.append(f"| {rig} | {label[rig]} | {pct(vs.get('1'))} | {pct(vs.get('5'))} | {pct(t.get('gain_5_vs_1_pct'))} | "
                     f"{pct(t.get('oracle_gain_5_vs_1_pct'))} | {'yes' if t['met'] else 'no'} | "
                     f"{pct(t.get('oracle_like_for_like_5_vs_1_pct'))} | {'yes' if t.get('met_like_for_like') else 'no'} |")
    agree = doc["agreement"]
    if not agree["rmse"]:                               # no hold-out (--no-hold-out): no agreement table
        return "\n".join(lines)
    rigs = [r for r in doc["summary"] if r in agree["rmse"].get("hidden_all", {})] + ["overall"]
    head = [f"{r} ({doc['settings']['scales'][r]:g})" if r != "overall" else r for r in rigs]
    lines += ["", "| protocol | " + " | ".join(head) + " |", "|---|" + "---|" * len(rigs)]
    for p in PROTOCOLS[1:]:
        cells = []
        for r in rigs:
            a, b = agree["rmse"][p][r], agree["mae"][p][r]
            cells.append(f"{a['agree_pct']:.0f} / {b['agree_pct']:.0f} % ({a['pairs']})")
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def document(cases: list, args, *, complete: bool) -> dict:
    """The JSON document of the cases run so far (``complete`` False while the run goes on)."""
    table = summary(cases)
    sizes = {c["rig"]: c["camera_sizes"] for c in cases if "camera_sizes" in c}
    return {"settings": {"rigs": args.rigs, "sweeps": args.sweeps, "seeds": args.seeds,
                        "hidden_seeds": args.hidden_seeds, "scale": args.scale, "scales": scales(cases),
                        "camera_sizes": sizes, "fraction": FRACTION,
                        "min_range_m": MIN_RANGE_M,
                        "defaults_chosen_on": "none (every option is the library default but --above-scan and "
                                              "--smoothing-sigma, recorded here)",
                        "above_scan": getattr(args, "above_scan", SGMConfig().above_scan),
                        "smoothing_sigma_px": getattr(args, "smoothing_sigma", SGMConfig().smoothing_sigma_px),
                        "laser_phases": bool(getattr(args, "laser_phases", False))},
           "methods": list(METHODS), "protocols": list(PROTOCOLS), "summary": table,
           "targets": targets_check(table), "agreement": agreement(cases), "complete": complete, "cases": cases}


if __name__ == "__main__":
    raise SystemExit(main())
