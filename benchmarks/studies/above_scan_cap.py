"""The plane extended above the top scan line, capped at one scan-line spacing (issue 37, ``above_scan``).

    PYTHONPATH=. python -m benchmarks.studies.above_scan_cap [--rigs kitti nuscenes] [--seeds 0 1]
        [--sweeps 1 5] [--phases aligned staggered] [--scale 1] [--json benchmarks/results/above_scan_cap.json]
        [--append]
    PYTHONPATH=. python -m benchmarks.studies.above_scan_cap --tables benchmarks/results/above_scan_cap.json
    PYTHONPATH=. python -m benchmarks.studies.above_scan_cap --real benchmarks/results/above_scan_cap_real.json

Each digital twin (``make_twin``; ``staggered``: ``laser_phases=True``, each laser of a spinning unit at its
own azimuth phase, as real spinning LiDARs sample) is completed through the user's path
(``accuracy_twins``: ``complete-rig``'s single-sweep path for 1 sweep, the sweeps JSON's multi-source path
for more) with ``SGMConfig.above_scan`` = ``plane`` (the default, the paper's Step 4), ``background`` and
``capped`` (:func:`jaxdepth._src.above_scan.capped_above_scan`: the seed's plane followed at most h / L
rows, one scan-line spacing, above its seed, held constant beyond), beside the city-block nearest fill of
the same points (``accuracy_twins``' ``nearest``). Scores: KITTI devkit RMSE / MAE mm against the exact
depth of every pixel (mean over cameras), and against the exact depth of only the pixels above their
column's top input pixel (``above``: where the three rules differ).

Nothing here is tuned: R = h / L is the column bracket's window, fixed before any run.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig

RULES = ("plane", "background", "capped")


def twin_case(rig: str, sweeps: int, seed: int, scale: float, staggered: bool):
    """(user input, exact depth per camera) of one twin."""
    from benchmarks.accuracy_twins import exact_truth, read_user_input
    from jaxdepth.research.twins import make_twin, write_twin
    tw = make_twin(rig, sweeps=sweeps, seed=seed, scale=scale, laser_phases=staggered)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(tw, tmp)
        inp = read_user_input(paths["sweeps_json"] if sweeps > 1 else paths["sweeps"][0], paths["rig"])
    return inp, exact_truth(tw, inp.rig)


def sgm(inp, config: SGMConfig) -> list:
    """Each camera's depth from the user's path (single-sweep or multi-source, as ``accuracy_twins``)."""
    from benchmarks.accuracy_twins import crops, single_path
    from jaxdepth.batch.sources_job import complete_cloud
    if inp.multi:
        return crops(complete_cloud(inp.cloud, inp.rig, config=config), inp.rig)
    return crops(single_path(inp.cloud.points, inp.cloud.ring, inp.rig, config)[0], inp.rig)


def city_block_and_sparse(inp) -> tuple:
    """(city-block nearest fill per camera, sparse z-buffer per camera) of every point as one cloud."""
    from benchmarks.accuracy_twins import one_cloud_rig, z_buffers
    from jaxdepth._src.methods import complete_with
    from jaxdepth.io import prepare_sweep
    frame = prepare_sweep(inp.cloud.points, one_cloud_rig(inp.rig))
    sparse = z_buffers(frame.points, frame.rig)
    cfg = SGMConfig(outlier_removal=False, distance_metric="l1")
    fill = [np.asarray(complete_with(s, c.K, c.T_cam_lidar, method="nearest", config=cfg, lidar=frame.rig.lidar))
            for s, c in zip(sparse, frame.rig.cameras)]
    return fill, sparse


def above_top_input(sparse: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels above their column's top input pixel (every pixel of an empty column)."""
    has = sparse > 0
    top = np.where(has.any(axis=0), np.argmax(has, axis=0), sparse.shape[0])
    return np.arange(sparse.shape[0])[:, None] < top[None, :]


def scores(pred: list, exact: list, above: list) -> dict:
    from benchmarks.accuracy_twins import score
    every = score(pred, exact)
    part = score(pred, [np.where(a, t, 0.0) for a, t in zip(above, exact)])
    return {"rmse": round(every["rmse"], 1), "mae": round(every["mae"], 1),
            "above": {"rmse": round(part["rmse"], 1), "mae": round(part["mae"], 1)}}


def run_case(rig: str, sweeps: int, seed: int, scale: float, staggered: bool) -> dict:
    inp, exact = twin_case(rig, sweeps, seed, scale, staggered)
    fill, sparse = city_block_and_sparse(inp)
    above = [above_top_input(s) for s in sparse]
    rows = {rule: scores(sgm(inp, SGMConfig(above_scan=rule)), exact, above) for rule in RULES}
    rows["city_block"] = scores(fill, exact, above)
    share = sum(int((a & (t > 0)).sum()) for a, t in zip(above, exact)) / sum(int((t > 0).sum()) for t in exact)
    return {"rig": rig, "sweeps": sweeps, "seed": seed, "scale": scale, "phases": "staggered" if staggered else
            "aligned", "path": "multi-source" if inp.multi else "single-sweep",
            "camera_sizes": [[int(c.width), int(c.height)] for c in inp.rig.cameras],
            "exact_pixels_above_top_input": round(share, 4), "scores": rows}


def nuscenes_scan_lines(rules=("plane", "capped")) -> dict:
    """The shared nuScenes sample with its odd rings held out (the scan-line hold-out of
    ``accuracy_multisource``'s Argoverse 2 rows): each rule's SGM and the city-block fill on the even
    rings, scored against the held-out points' own z-buffer, all targets and ``uncovered`` (RMSE / MAE
    mm, mean over the 6 camera images). The sweep is put in its LiDAR's frame first, as ``hidden-eval``."""
    import glob

    import jax.numpy as jnp

    import jaxdepth
    from benchmarks._common import DATA
    from benchmarks.studies.av2_job_rows import _z_buffers
    from jaxdepth._src.methods import complete_with
    from jaxdepth._src.metrics import depth_metrics, mean_metrics
    from jaxdepth.io import pad_points, prepare_sweep, read_points, rig_from_nuscenes_calibration
    from jaxdepth.io.points import ring_column
    from jaxdepth.research.hidden import default_cover_half_height_px
    nus = DATA / "nuscenes" / "sample"
    points, extra = read_points(glob.glob(str(nus / "*LIDAR_TOP*.pcd.bin"))[0], columns=5)
    ring = ring_column(extra, 5)
    frame = prepare_sweep(points, rig_from_nuscenes_calibration(nus / "calibration.json"), ring=ring)
    pts, rig = np.asarray(frame.points), frame.rig
    with np.errstate(invalid="ignore"):
        near = np.linalg.norm(pts.astype(np.float64), axis=1) < 1.0
    pts, ring = pts[~near], np.asarray(ring)[~near]
    hidden = ring % 2 == 1
    half = default_cover_half_height_px(np.stack([c.K for c in rig.cameras]), rig.lidar)
    targets = _z_buffers(pts, hidden, rig, half)
    padded, valid = pad_points(pts[~hidden])
    cams = jaxdepth.stack_cameras([c.as_camera() for c in rig.cameras])
    preds = {}
    for rule in rules:
        config = SGMConfig(above_scan=rule)
        if not frame.outlier_removal_trusted:
            config = config.replace(outlier_removal=False)
        preds[rule] = np.asarray(jaxdepth.complete_rig(padded, valid, cams, config=config, lidar=rig.lidar))
    sparse = [np.asarray(jaxdepth.project_to_image(jnp.asarray(padded), jnp.asarray(valid), jnp.asarray(c.K),
                                                   jnp.asarray(c.T_cam_lidar), height=c.height,
                                                   width=c.width)[0]) for c in rig.cameras]
    plain = SGMConfig(outlier_removal=False)
    preds["city_block"] = [np.asarray(complete_with(z, c.K, c.T_cam_lidar, method="nearest", config=plain,
                                                    lidar=rig.lidar)) for z, c in zip(sparse, rig.cameras)]
    out = {}
    for name, pred in preds.items():
        for i, which in enumerate(("all", "uncovered")):
            rows = [depth_metrics(jnp.asarray(pred[k][:c.height, :c.width]), jnp.asarray(targets[k][i]))
                    for k, c in enumerate(rig.cameras)]
            m = mean_metrics(rows)
            out.setdefault(which, {})[name] = {"rmse": round(float(m["rmse"]), 1), "mae": round(float(m["mae"]), 1)}
    return {"held_out_points": int(hidden.sum()), "input_points": int((~hidden).sum()), "scores": out}


def kitti_above_split(rules=RULES) -> dict:
    """The real KITTI frame's ground truth (cameras 2 and 3, as ``accuracy_kitti``) split into the pixels
    above their column's top input pixel and the rest: {camera: {"above_share", rule: {above, rest}}}."""
    import jax.numpy as jnp

    import jaxdepth
    from benchmarks._common import load_frames
    from jaxdepth._src.metrics import depth_metrics
    out = {}
    for name, (sparse, gt, K, T) in load_frames().items():
        above, gt = above_top_input(np.asarray(sparse)), np.asarray(gt)
        row = {"above_share": round(float((above & (gt > 0)).sum() / (gt > 0).sum()), 4)}
        for rule in rules:
            depth = jaxdepth.complete_stages(sparse, K, T, config=jaxdepth.SGMConfig(above_scan=rule)).depth
            row[rule] = {part: {k: round(float(v), 1) for k, v in depth_metrics(depth, jnp.asarray(
                np.where(above == (part == "above"), gt, 0.0))).items() if k in ("rmse", "mae")}
                for part in ("above", "rest")}
        out[name] = row
    return out


def real_checks(rules=("plane", "capped")) -> dict:
    """Every real-set check of the rules (run once, after the twins): ``accuracy_rigs.real_rows`` (the KITTI
    frame's ground truth; ``hidden-eval``, seeds 0-4, random 20 %, all and ``uncovered``, on the two KITTI
    sweeps and the nuScenes sample, with both nearest fills and IP_Basic), :func:`kitti_above_split`,
    :func:`nuscenes_scan_lines` and the Argoverse 2 job's rows (``av2_job_rows.run``: random 20 % and odd
    lasers held out, all and ``uncovered``, 7 ring cameras x 2 sweeps)."""
    from benchmarks.accuracy_rigs import real_rows
    from benchmarks.studies.av2_job_rows import run as av2_rows
    from jaxdepth.io.av2 import RING_CAMERAS
    return {"real_rows": {r: real_rows(SGMConfig(above_scan=r), [0, 1, 2, 3, 4]) for r in rules},
            "kitti_above_split": kitti_above_split(rules),
            "nuscenes_scan_lines": nuscenes_scan_lines(rules),
            "av2_job_rows": {r: av2_rows(tuple(RING_CAMERAS), fraction=0.2, seed=0,
                                         config=SGMConfig(above_scan=r))["mean"] for r in rules}}


def markdown(doc: dict) -> str:
    """The docs' table: one row per case, RMSE / MAE mm of each rule and the fill, capped vs plane in %."""
    lines = ["| twin, sweeps, seed, phases | `plane` | `background` | `capped` | city-block fill "
             "| capped vs plane, RMSE / MAE |", "|---|---|---|---|---|---|"]
    for c in doc["cases"]:
        s = c["scores"]
        best = min(RULES, key=lambda r: s[r]["rmse"])

        def cell(k):
            text = f"{s[k]['rmse']:.1f} / {s[k]['mae']:.1f}"
            return f"**{text}**" if k == best else text
        pct = [100 * (s["capped"][m] / s["plane"][m] - 1) for m in ("rmse", "mae")]
        lines.append(f"| {c['rig']}, {c['sweeps']}, {c['seed']}, {c['phases']} | " + " | ".join(
            cell(k) for k in (*RULES, "city_block")) + f" | {pct[0]:+.1f} / {pct[1]:+.1f} % |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rigs", nargs="+", default=["kitti", "nuscenes"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--sweeps", nargs="+", type=int, default=[1, 5])
    parser.add_argument("--phases", nargs="+", choices=("aligned", "staggered"), default=["aligned", "staggered"])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--json", default=str(RESULTS / "above_scan_cap.json"))
    parser.add_argument("--append", action="store_true", help="add the cases to an existing --json")
    parser.add_argument("--real", metavar="JSON", help="run the real-set checks (real_checks) into JSON and exit")
    parser.add_argument("--tables", metavar="JSON", help="print the docs' table of a result file and exit")
    args = parser.parse_args(argv)
    t0 = time.time()
    if args.real:
        write_results(args.real, real_checks(), SGMConfig(), t0)
        return 0
    if args.tables:
        import json
        import pathlib
        print(markdown(json.loads(pathlib.Path(args.tables).read_text())))
        return 0
    doc = {"rules": list(RULES), "cases": []}
    if args.append:
        import json
        import pathlib
        if pathlib.Path(args.json).exists():
            doc["cases"] = json.loads(pathlib.Path(args.json).read_text())["cases"]
    for sweeps in args.sweeps:
        for rig in args.rigs:
            for seed in args.seeds:
                for phases in args.phases:
                    t = time.time()
                    case = run_case(rig, sweeps, seed, args.scale, phases == "staggered")
                    case["run_seconds"] = round(time.time() - t, 1)
                    doc["cases"].append(case)
                    print(f"{rig} sweeps={sweeps} seed={seed} {phases} ({case['run_seconds']:.0f} s): " + ", ".join(
                        f"{k} {v['rmse']:.0f}/{v['mae']:.0f} (above {v['above']['rmse']:.0f}/{v['above']['mae']:.0f})"
                        for k, v in case["scores"].items()), flush=True)
                    write_results(args.json, doc, SGMConfig(), t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
