"""Which input points are wrong at their pixel on a digital twin, why, and which the free-space rules keep.

    python -m benchmarks.twins_wrong_points [--rig rosette] [--sweeps 5] [--seed 0] [--scale 0.25]
        [--witness-cell 2.0] [--json benchmarks/results/twins_wrong_points_rosette_5.json]

One twin (:func:`jaxdepth.research.twins.make_twin`), read back as ``complete-rig`` reads it
(:func:`benchmarks.accuracy_twins.read_user_input`). A point is *wrong* when some camera sees it at a
pixel whose exact depth differs from its own by more than 0.5 m or is sky (as
:func:`benchmarks.accuracy_twins.truth_filtered_keep`). Each wrong point gets one class, from the twin's
oracle information (read, never given to the method):

- ``reference``: a point of the reference sweep (parallax between LiDAR and camera, a pixel that
  straddles a depth edge, a mixed return);
- ``mover``: an older sweep's point whose exact hit lies on a car or pedestrian at that sweep's time
  (its ghost now);
- ``mixed``: an older sweep's mixed return;
- ``behind``: an older sweep's static point behind what the camera sees there (an older origin saw
  past a surface), or seeing sky;
- ``in_front``: an older sweep's static point in front of what the camera sees there (a thin or edge
  surface at a pixel whose centre sees the background).

Per class: the wrong points, those the free-space and occlusion rules remove
(:func:`jaxdepth._src.sources.reference_view`: ``free``, or ``hidden`` for the camera's witness
LiDAR), those kept with and without *evidence* (at least ``free_space_min_cells`` of the bracketing
2 x 2 cells measured by a reference-sweep LiDAR, on its witness grid), those in a reference LiDAR's
shadow, and the pixels they *spoil*: pixels of the Step-2-kept z-buffer whose point is that wrong
point (also per camera). Then, per camera, the SGM on the reference sweep alone (one sweep), on
every sweep (the default) and on every sweep without the older sweeps' wrong points, with and
without the free-space rules (:func:`sweep_loss`): which cameras carry the loss of extra sweeps and
what perfect removal of older points would give back. Last, the rules' own removals split by the truth
(rules off, every sweep without the removed points the truth shows wrong, or right; rule 5's layers OR-ed
over the rig's cameras) and the largest image region the wrong removals make worse (:func:`worst_region`). A diagnosis: it reads the truth, and chooses
nothing.
"""

from __future__ import annotations

import tempfile
import time

import jax.numpy as jnp
import numpy as np

from benchmarks import accuracy_twins as bench
from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig

CLASSES = ("reference", "mover", "mixed", "behind", "in_front")
ON_MOVER_M = 0.03


def on_movers(world, scene, *, tol_m: float = ON_MOVER_M) -> np.ndarray:
    """(N,) bool: world points inside or within ``tol_m`` of a mover's box or cylinder."""
    hit = np.zeros(len(world), bool)
    for cx, cy, cz, hx, hy, hz, yaw in np.asarray(scene.boxes, np.float64):
        c, s = np.cos(yaw), np.sin(yaw)
        dx, dy = world[:, 0] - cx, world[:, 1] - cy
        local = np.abs(np.stack([c * dx + s * dy, c * dy - s * dx, world[:, 2] - cz], 1))
        hit |= np.all(local <= np.array([hx, hy, hz]) + tol_m, axis=1)
    for cx, cy, r, z0, z1 in np.asarray(scene.cylinders, np.float64):
        hit |= ((np.hypot(world[:, 0] - cx, world[:, 1] - cy) <= r + tol_m)
                & (world[:, 2] >= z0 - tol_m) & (world[:, 2] <= z1 + tol_m))
    return hit


def pixel_errors(cloud, rig, exact: list) -> tuple:
    """((N,) signed error of each point at its pixel, the largest in size over cameras (NaN unseen, +inf
    sky), [(inside (N,), uv (N, 2), z (N,))] per camera)."""
    err = np.full(len(cloud.points), np.nan)
    p = cloud.points.astype(np.float64)
    views = []
    for cam, truth in zip(rig.cameras, exact):
        T, K = np.asarray(cam.T_cam_lidar, np.float64), np.asarray(cam.K, np.float64)
        q = p @ T[:3, :3].T + T[:3, 3]
        z = np.where(q[:, 2] > 0.1, q[:, 2], 1.0)
        uv = np.round((q @ K.T)[:, :2] / z[:, None]).astype(np.int64)
        inside = (q[:, 2] > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        seen = np.zeros(len(p))
        seen[inside] = truth[uv[inside, 1], uv[inside, 0]]
        e = np.where(inside, np.where(seen == 0, np.inf, q[:, 2] - seen), np.nan)
        larger = np.isnan(err) | (np.abs(np.nan_to_num(e)) > np.abs(np.nan_to_num(err)))
        err = np.where(inside & larger, e, err)
        views.append((inside, uv, q[:, 2]))
    return err, views


def point_classes(twin, inp, err) -> np.ndarray:
    """(N,) class name of each input point (see the module docstring), wrong or not."""
    from jaxdepth.research.twin_rigs import RIG_BUILDERS
    from jaxdepth.research.twin_scene import mover_scene
    from jaxdepth.research.twin_sensors import NO_EFFECTS
    c = inp.cloud
    sweep = c.sweep[c.source]
    own = twin.cloud.sweep[twin.cloud.source]
    order = np.zeros(len(sweep), np.int64)          # the input keeps each sweep's points in the twin's order
    for v in np.unique(sweep):
        order[sweep == v] = np.flatnonzero(own == v)
    rdef = RIG_BUILDERS[twin.name](NO_EFFECTS)
    T = rdef.T_ego_points
    world = twin.point_exact[order].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    mover = np.zeros(len(sweep), bool)
    for v in np.unique(sweep):
        mover[sweep == v] = on_movers(world[sweep == v], mover_scene(twin.seed, -int(v), dt_s=rdef.dt_s))
    behind = np.nan_to_num(err, posinf=np.inf, nan=0.0) > 0
    return np.where(sweep == 0, "reference", np.where(mover, "mover", np.where(
        twin.point_mixed[order], "mixed", np.where(behind, "behind", "in_front"))))


def rule_verdicts(inp, config: SGMConfig) -> dict:
    """{"removed", "shadow", "evidence"}: (N,) bool per input point, as the default multi-source path judges."""
    from jaxdepth._src import sources as S
    from jaxdepth.batch.sources_job import cloud_sources
    c = inp.cloud
    src, index = cloud_sources(c, fallback=inp.rig.lidar, witness_cell_spacings=config.free_space_witness_cell,
                               min_cells=config.free_space_min_cells)
    free, shadow, hidden = S.reference_view(src, noise_m=config.free_space_noise_m, slope=config.free_space_slope,
                                            min_cells=config.free_space_min_cells,
                                            neighbour_sweeps=config.free_space_neighbour_sweeps)
    ok = index >= 0

    def back(a):
        out = np.zeros(len(c.points), bool)
        out[index[ok]] = np.asarray(a)[ok]
        return out

    removed = back(free)
    for layer in hidden:
        removed |= back(layer)
    evidence = np.zeros(len(c.points), bool)
    grids = src.lidars if src.witnesses is None else src.witnesses
    for r in [i for i, s in enumerate(src.sweep) if s == 0]:
        spec, T = grids[r], S.invert_rigid(src.T_ref_source[r])
        rows = () if src.rows is None else (src.rows[r],)
        ri, _ = S.range_image_and_slots(S.transform_points(T, src.points[r]), src.valid[r], spec, *rows)
        q = S.transform_points(T, jnp.asarray(c.points))
        _, th, ph, good = S.angles_xyz(q[:, 0], q[:, 1], q[:, 2], jnp.ones(q.shape[:1], bool))
        row, col = (S._row_of_elevation(ri, ph), S.row_col(th, ph, spec)[1]) if rows else S.row_col(th, ph, spec)
        n_cells = S._bracket_2x2(ri, row, col, th, ph, spec)[2]
        evidence |= np.asarray(good & (n_cells >= config.free_space_min_cells))
    return {"removed": removed, "shadow": back(shadow), "evidence": evidence}


def spoiled_pixels(inp, config, views, removed, wrong, classes) -> tuple:
    """({class: pixels of the Step-2-kept z-buffers (every camera) whose point is a wrong point of that class},
    [the same, per camera])."""
    from jaxdepth.batch.sources_job import complete_cloud
    stages = complete_cloud(inp.cloud, inp.rig, config=config, stages=True)
    per = []
    for i, (cam, (inside, uv, z)) in enumerate(zip(inp.rig.cameras, views)):
        sparse = np.asarray(stages.sparse_depth[i, :cam.height, :cam.width])
        kept = np.asarray(stages.inlier_mask[i, :cam.height, :cam.width])
        cand = np.flatnonzero(inside & ~removed & wrong)
        u, v = uv[cand, 0], uv[cand, 1]
        won = cand[(np.abs(sparse[v, u] - z[cand]) < 1e-3) & kept[v, u]]
        per.append({k: int(np.sum(classes[won] == k)) for k in CLASSES})
    return {k: sum(row[k] for row in per) for k in CLASSES}, per


def wrong_per_camera(views, exact, *, tolerance_m: float = bench.TRUTH_TOLERANCE_M) -> list:
    """[(N,) bool per camera]: points that camera sees at a pixel whose exact depth differs from theirs
    by more than ``tolerance_m`` (or is sky); :func:`benchmarks.accuracy_twins.truth_filtered_keep`
    removes the union of these."""
    out = []
    for (inside, uv, z), truth in zip(views, exact):
        seen = np.zeros(len(z))
        seen[inside] = truth[uv[inside, 1], uv[inside, 0]]
        out.append(inside & ((seen == 0) | (np.abs(seen - z) > tolerance_m)))
    return out


def sweep_loss(inp, exact, config, wrong, views, removed=None) -> dict:
    """Per-camera SGM scores (RMSE / MAE mm) of the reference sweep alone (what one sweep gives: the same
    scores as the single-sweep path, docs/multi_source.md), every sweep (the default), and every sweep
    without the older sweeps' wrong points (an oracle of point removal that leaves the reference sweep
    alone), with and without the free-space rules: where extra sweeps lose, and what perfect removal
    of older points could give back. ``*_per_camera`` rows remove, for each camera's image, only the
    points wrong in that camera (one run per camera): the accuracy table's oracle removes a point
    wrong in any camera from every camera, which opens holes where cameras overlap. With ``removed``
    ((N,) bool, the points rules 3 and 5 remove, :func:`rule_verdicts`), the rules' removals split by the
    truth, rules off: every sweep, without the removed points the truth shows wrong, without the removed
    points it shows right (what the rules' right and wrong verdicts each cost or gain)."""
    from jaxdepth.batch.sources_job import complete_cloud
    c = inp.cloud
    older = c.sweep[c.source] != 0

    def run(keep, rules):
        return bench.crops(complete_cloud(c.take(keep), inp.rig, config=config, free_space=rules), inp.rig)

    runs = {"reference_sweep_alone": run(~older, True), "every_sweep": run(np.ones_like(older), True),
            "older_wrong_removed": run(~(older & wrong), True),
            "older_wrong_removed_no_rules": run(~(older & wrong), False)}
    if removed is not None:
        runs.update(every_sweep_no_rules=run(np.ones_like(older), False),
                    rules_wrong_removals_no_rules=run(~(removed & wrong), False),
                    rules_right_removals_no_rules=run(~(removed & ~wrong), False))
    per_cam = wrong_per_camera(views, exact)
    for name, base, only_older, rules in (("reference_wrong_removed_per_camera", ~older, False, True),
                                          ("older_wrong_removed_per_camera", True, True, True),
                                          ("every_wrong_removed_per_camera", True, False, False)):
        runs[name] = [run(base & ~(w & older if only_older else w), rules)[i] for i, w in enumerate(per_cam)]
    scores = {name: bench.score(pred, exact) for name, pred in runs.items()}
    if removed is not None:
        scores["worst_region_of_wrong_removals"] = worst_region(runs["rules_wrong_removals_no_rules"],
                                                                runs["every_sweep_no_rules"], exact)
    return scores


def worst_region(pred: list, base: list, exact: list, *, worse_m: float = 2.0) -> list:
    """Per camera, the largest connected region (by added squared error) of pixels where ``pred``'s error
    exceeds ``base``'s by more than ``worse_m`` in squared-error terms: its pixels, bounding box, share of
    the camera's whole squared-error change, and the median exact, ``base`` and ``pred`` depth there (m).
    Errors as the devkit's (a pixel without prediction counts its whole depth)."""
    from scipy import ndimage
    out = []
    for p, b, e in zip(pred, base, exact):
        t = e > 0
        dse = np.where(t, np.where(p > 0, p - e, e) ** 2 - np.where(b > 0, b - e, e) ** 2, 0.0).astype(np.float64)
        label, n = ndimage.label(dse > worse_m ** 2)
        if n == 0:
            out.append(None)
            continue
        sums = ndimage.sum(dse, label, np.arange(1, n + 1))
        m = label == int(np.argmax(sums)) + 1
        rows, cols = np.nonzero(m)
        out.append({"pixels": int(m.sum()), "pixels_with_truth": int(t.sum()),
                    "rows": [int(rows.min()), int(rows.max())], "cols": [int(cols.min()), int(cols.max())],
                    "share_of_squared_error_change": float(sums.max() / dse.sum()),
                    "median_exact_m": float(np.median(e[m])), "median_base_m": float(np.median(b[m])),
                    "median_pred_m": float(np.median(p[m]))})
    return out


def main(argv=None) -> int:
    parser = bench.twin_parser(__doc__.splitlines()[0], rig="rosette", sweeps=5, scale=0.25)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--witness-cell", type=float, default=SGMConfig().free_space_witness_cell,
                        help="SGMConfig.free_space_witness_cell (0: the rig's LiDAR spec grid)")
    args = parser.parse_args(argv)
    t0 = time.time()
    from jaxdepth.research.twins import make_twin, write_twin
    config = SGMConfig(free_space_witness_cell=args.witness_cell)
    twin = make_twin(args.rig, sweeps=args.sweeps, seed=args.seed, scale=args.scale)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(twin, tmp)
        inp = bench.read_user_input(paths["sweeps_json"] if args.sweeps > 1 else paths["sweeps"][0], paths["rig"])
    exact = bench.exact_truth(twin, inp.rig)
    err, views = pixel_errors(inp.cloud, inp.rig, exact)
    wrong = np.abs(np.nan_to_num(err, nan=0.0)) > bench.TRUTH_TOLERANCE_M
    classes = point_classes(twin, inp, err)
    rules = rule_verdicts(inp, config)
    spoiled, spoiled_per_camera = spoiled_pixels(inp, config, views, rules["removed"], wrong, classes)
    table = {}
    for k in CLASSES:
        m = wrong & (classes == k)
        kept = m & ~rules["removed"]
        table[k] = {"wrong": int(m.sum()), "removed": int((m & rules["removed"]).sum()), "kept": int(kept.sum()),
                    "kept_with_evidence": int((kept & rules["evidence"]).sum()),
                    "kept_without_evidence": int((kept & ~rules["evidence"]).sum()),
                    "kept_in_shadow": int((kept & rules["shadow"]).sum()), "pixels_spoiled": spoiled[k]}
    older = inp.cloud.sweep[inp.cloud.source] != 0
    result = {"rig": args.rig, "sweeps": args.sweeps, "seed": args.seed, "scale": args.scale,
              "witness_cell": args.witness_cell, "points": int(len(wrong)), "wrong": int(wrong.sum()),
              "right_older_points_removed": int((~wrong & older & rules["removed"]).sum()),
              "right_older_points": int((~wrong & older).sum()), "classes": table,
              "cameras": [c.name for c in inp.rig.cameras], "pixels_spoiled_per_camera": spoiled_per_camera,
              "scores": sweep_loss(inp, exact, config, wrong, views, removed=rules["removed"])}
    print(f"{args.rig}, {args.sweeps} sweeps, seed {args.seed}, witness cell {args.witness_cell}: "
          f"{len(wrong)} points, {int(wrong.sum())} wrong; right older points removed "
          f"{result['right_older_points_removed']} of {result['right_older_points']}")
    for k, row in table.items():
        print(f"  {k:10s} " + "  ".join(f"{n} {v}" for n, v in row.items()))
    for name, row in zip(result["cameras"], spoiled_per_camera):
        print(f"  {name}: pixels spoiled " + "  ".join(f"{k} {v}" for k, v in row.items()))
    for k, region in enumerate(result["scores"].pop("worst_region_of_wrong_removals", [])):
        print(f"  {result['cameras'][k]}: worst region of the rules' wrong removals {region}")
        result.setdefault("worst_region_of_wrong_removals", []).append(region)
    for name, sc in result["scores"].items():
        print(f"  {name:30s} {sc['rmse']:7.1f} / {sc['mae']:6.1f} | "
              + " ".join(f"{r['rmse']:.0f}/{r['mae']:.0f}" for r in sc["per_camera"]))
    write_results(args.json or RESULTS / f"twins_wrong_points_{args.rig}_{args.sweeps}.json", result, config, t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
