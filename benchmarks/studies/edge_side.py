"""Which side of a depth edge a pixel's seed comes from (Step 3), against the twins' exact depth (issue 37).

    PYTHONPATH=. python -m benchmarks.studies.edge_side [--rigs nuscenes kitti av2 raster rosette] \
        [--sweeps 1 5] [--seed 0] [--scale 1] [--rules ...] [--json benchmarks/results/edge_side.json]

Step 3 gives each pixel its nearest kept LiDAR pixel (city block). At a depth edge that puts the edge
half way between the last point of one surface and the first of the other. The candidates here choose
the seed among the nearest kept pixel of each *quadrant* (above-left, above-right, below-left,
below-right, own row and column included: the nearest of the four is the nearest seed), with fixed-shape
``lax.fori_loop`` passes like :mod:`jaxdepth._src.distance`:

- ``nearest``: the smallest pixel distance (the library's seed; checked equal, bit for bit);
- ``metric_gG``: the smallest ``d * z**G`` (d the city-block pixel distance, z the seed's depth). ``G = 1``
  is the lateral distance in metres at the seed's depth (the distance "measured in 3D" across the ray):
  a near surface reaches farther into the image than a far one; ``G < 0`` favours the far side;
- ``updown_gG``: the same, but only between the nearest seed above (rows <= v) and below (rows >= v)
  (the choice across the gap between scan lines; within a row the nearer side, as now);
- ``aniso_hP_vQ``: the smallest ``P |du| + Q |dv|`` (a seed on the own scan line against one across the
  gap between scan lines: ``Q < P`` reaches across the gap sooner);
- ``cost_P``: ``SGMConfig(seed_horizontal_cost=P)``, the library's option (``aniso_hP_v1`` up to the tie order);
- ``combo_hP_vQ_gG``: the smallest ``(P |du| + Q |dv|) * z**G`` (both at once);
- ``up`` / ``down``: always the nearest seed above / below (where there is one), only for the oracle;
- ``above:R``: rule ``R`` above the topmost kept pixel of each column, ``nearest`` elsewhere
  (``benchmarks.studies.edge_truth``: the twins' far-side win sits above the top scan line).

Each rule replaces :func:`jaxdepth._src.pipeline._seeds` for a whole run (the twins' user path:
``complete-rig``'s single-sweep path at 1 sweep, the multi-source path at 5), so the seed's plane, the
column bracket and the Gaussian all start from the chosen seed. Scored against the exact depth of every
pixel (the referee of docs/twins.md), RMSE / MAE in mm, mean over images. ``oracle_updown``: per pixel,
the output of ``up`` or ``down`` nearer the exact depth (reads the truth, only to bound what a better
choice between the two sides could gain; never a rule).
"""

from __future__ import annotations

import argparse
import contextlib
import tempfile
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig

RULES = ("nearest", "metric_g0.5", "metric_g1", "metric_g-0.5", "updown_g0.5", "updown_g1", "aniso_h2_v1",
         "aniso_h1_v2", "up", "down")
_CONTEXT: dict = {}


class Seeds(NamedTuple):
    """What :func:`jaxdepth._src.pipeline._complete_tail` reads of Step 3: (H, W) int32 offsets."""
    du: jax.Array
    dv: jax.Array


def _row_side(mask_t: jax.Array, *, left: bool) -> jax.Array:
    """(W, H) int32 distance along each row to the nearest seed at or left (right) of each pixel; ``far`` none."""
    w, h = mask_t.shape
    far = jnp.int32(1 << 20)

    def step(k, state):
        carry, buf = state
        i = k if left else w - 1 - k
        carry = jnp.where(mask_t[i], 0, jnp.minimum(carry + 1, far))
        return carry, lax.dynamic_update_index_in_dim(buf, carry, i, 0)

    return lax.fori_loop(0, w, step, (jnp.full((h,), far, jnp.int32), jnp.zeros((w, h), jnp.int32)))[1]


def quadrant_seeds(keep: jax.Array, *, h_weight: int = 1, v_weight: int = 1) -> list:
    """The nearest kept pixel of each quadrant under ``h_weight |du| + v_weight |dv|``.

    Returns four (distance (H, W) int32, du, dv) for above-left, below-left, above-right, below-right
    (own row and column included); distance ``>= 2**18`` where the quadrant has none. Ties: the smaller
    seed row, as the library's key.
    """
    h, w = keep.shape
    rows = jnp.arange(h, dtype=jnp.int32)[:, None]
    rb = max(h - 1, 1).bit_length()
    big = 1 << 18
    out = []
    for left in (True, False):
        hd = _row_side(keep.T, left=left).T                                     # (H, W)
        d0 = jnp.where(hd >= big, big, h_weight * hd)
        key = (d0 << rb) | rows                                                 # distance, then seed row
        for down in (False, True):
            step = v_weight << rb

            def body(k, state, key=key, down=down, step=step):
                carry, buf = state
                i = h - 1 - k if down else k
                carry = jnp.minimum(key[i], jnp.minimum(carry + step, big << rb))
                return carry, lax.dynamic_update_index_in_dim(buf, carry, i, 0)

            best = lax.fori_loop(0, h, body, (jnp.full((w,), big << rb, jnp.int32), key))[1]
            dist, srow = best >> rb, best & ((1 << rb) - 1)
            dv = srow - rows
            du_abs = (dist - v_weight * jnp.abs(dv)) // h_weight
            out.append((dist, jnp.where(left, -du_abs, du_abs), dv))
    return out


def _choose(cands: list, score) -> Seeds:
    """The candidate of the smallest ``score(distance, du, dv)`` (ties: the first); 0 offsets if none."""
    best_s, best_du, best_dv, found = None, None, None, None
    for dist, du, dv in cands:
        valid = dist < (1 << 18)
        s = score(dist, du, dv)
        s = jnp.where(valid, s, jnp.iinfo(s.dtype).max if jnp.issubdtype(s.dtype, jnp.integer) else jnp.inf)
        if best_s is None:
            best_s, best_du, best_dv, found = s, du, dv, valid
            continue
        take = s < best_s
        best_s, best_du, best_dv = (jnp.where(take, s, best_s), jnp.where(take, du, best_du),
                                    jnp.where(take, dv, best_dv))
        found = found | valid
    return Seeds(jnp.where(found, best_du, 0), jnp.where(found, best_dv, 0))


def _pixel_key(dist, du, dv):
    """The library's order: city-block distance, then the smaller seed row, then the left seed."""
    v = jnp.arange(dist.shape[0], dtype=jnp.int32)[:, None]
    return (dist << 12) | ((v + dv) << 1) | (du > 0).astype(jnp.int32)


def _seed_depth(kept_depth, du, dv):
    h, w = kept_depth.shape
    v = jnp.arange(h, dtype=jnp.int32)[:, None]
    u = jnp.arange(w, dtype=jnp.int32)[None, :]
    return kept_depth[jnp.clip(v + dv, 0, h - 1), jnp.clip(u + du, 0, w - 1)]


def rule_seeds(rule: str, keep: jax.Array, kept_depth: jax.Array) -> Seeds:
    """(du, dv) of ``rule`` (see the module docstring) for an (H, W) keep mask and the kept depth."""
    if rule.startswith("above:"):
        # ``above:R``: rule R above the topmost kept pixel of each column, the library's nearest seed elsewhere
        inner, base = rule_seeds(rule[6:], keep, kept_depth), rule_seeds("nearest", keep, kept_depth)
        h = keep.shape[0]
        top = jnp.where(keep.any(axis=0), jnp.argmax(keep, axis=0), h)
        above = jnp.arange(h, dtype=jnp.int32)[:, None] < top[None, :]
        return Seeds(jnp.where(above, inner.du, base.du), jnp.where(above, inner.dv, base.dv))
    if rule.startswith(("aniso_", "combo_")):
        fields = {t[0]: t[1:] for t in rule.split("_")[1:]}
        p, q, gamma = int(fields["h"]), int(fields["v"]), float(fields.get("g", 0))
        cands = quadrant_seeds(keep, h_weight=p, v_weight=q)

        def weighted(d, du, dv):
            z = jnp.maximum(_seed_depth(kept_depth, du, dv), 0.1)
            return (p * jnp.abs(du) + q * jnp.abs(dv)).astype(jnp.float32) * z ** gamma

        return _choose([cands[i] for i in (0, 2, 1, 3)], weighted)
    al, bl, ar, br = quadrant_seeds(keep)
    pixel = _pixel_key
    if rule == "nearest":
        return _choose([al, ar, bl, br], pixel)
    if rule in ("up", "down"):
        pair = (al, ar) if rule == "up" else (bl, br)
        first = _choose(list(pair), pixel)
        other = _choose([bl, br] if rule == "up" else [al, ar], pixel)
        has = jnp.minimum(pair[0][0], pair[1][0]) < (1 << 18)
        return Seeds(jnp.where(has, first.du, other.du), jnp.where(has, first.dv, other.dv))
    kind, g = rule.split("_g")
    gamma = float(g)

    def metric(d, du, dv):
        z = jnp.maximum(_seed_depth(kept_depth, du, dv), 0.1)
        return d.astype(jnp.float32) * z ** gamma

    if kind == "metric":
        return _choose([al, ar, bl, br], metric)
    up, down = _choose([al, ar], pixel), _choose([bl, br], pixel)
    has_up = jnp.minimum(al[0], ar[0]) < (1 << 18)
    has_dn = jnp.minimum(bl[0], br[0]) < (1 << 18)
    d_up, d_dn = (jnp.abs(s.du) + jnp.abs(s.dv) for s in (up, down))
    cands = [(jnp.where(has_up, d_up, 1 << 18), up.du, up.dv), (jnp.where(has_dn, d_dn, 1 << 18), down.du, down.dv)]
    return _choose(cands, metric)


@contextlib.contextmanager
def seed_rule(rule: str):
    """Every SGM run inside uses ``rule``'s seeds (jit caches cleared on entry and exit)."""
    from jaxdepth._src import pipeline, rig
    original_tail, original_seeds = pipeline._complete_tail, pipeline._seeds

    def tail(sparse_depth, normals_cam, points_cam, K, T_cam_lidar, **kw):
        _CONTEXT["depth"] = sparse_depth
        return original_tail(sparse_depth, normals_cam, points_cam, K, T_cam_lidar, **kw)

    def seeds(keep, image, config):
        return rule_seeds(rule, keep, jnp.where(keep, _CONTEXT["depth"], 0.0))

    jax.clear_caches()
    pipeline._complete_tail, rig._complete_tail, pipeline._seeds = tail, tail, seeds
    try:
        yield
    finally:
        pipeline._complete_tail, rig._complete_tail, pipeline._seeds = original_tail, original_tail, original_seeds
        jax.clear_caches()


def twin_input(rig_name: str, sweeps: int, seed: int, scale: float, *, effects: bool = True):
    from benchmarks.accuracy_twins import exact_truth, read_user_input
    from jaxdepth.research.twins import make_twin, write_twin
    tw = make_twin(rig_name, sweeps=sweeps, seed=seed, scale=scale, effects=effects)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(tw, tmp)
        inp = read_user_input(paths["sweeps_json"] if sweeps > 1 else paths["sweeps"][0], paths["rig"])
    return inp, exact_truth(tw, inp.rig)


def run_sgm(inp, config: SGMConfig = SGMConfig()) -> list:
    """The SGM's depth per camera (default: the default SGM), on the path ``complete-rig`` takes for this input."""
    from benchmarks.accuracy_twins import crops, single_path
    from jaxdepth.batch.sources_job import complete_cloud
    if inp.multi:
        return crops(complete_cloud(inp.cloud, inp.rig, config=config), inp.rig)
    return crops(single_path(inp.cloud.points, inp.cloud.ring, inp.rig, config)[0], inp.rig)


def case(rig_name: str, sweeps: int, seed: int, scale: float, rules) -> dict:
    from benchmarks.accuracy_twins import score
    inp, exact = twin_input(rig_name, sweeps, seed, scale)
    strip = lambda s: {"rmse": s["rmse"], "mae": s["mae"]}  # noqa: E731
    library = run_sgm(inp)
    out = {"rig": rig_name, "sweeps": sweeps, "seed": seed, "scale": scale,
           "path": "multi-source" if inp.multi else "single-sweep", "library": strip(score(library, exact)),
           "exact_dense": {}}
    depths = {}
    for rule in rules:
        t = time.time()
        if rule.startswith("cost_"):          # the library's option itself, no patch
            depths[rule] = run_sgm(inp, SGMConfig(seed_horizontal_cost=int(rule[5:])))
        else:
            with seed_rule(rule):
                depths[rule] = run_sgm(inp)
        out["exact_dense"][rule] = strip(score(depths[rule], exact))
        print(f"  {rig_name} {sweeps} {rule:14s} {out['exact_dense'][rule]['rmse']:8.1f} / "
              f"{out['exact_dense'][rule]['mae']:6.1f} ({time.time() - t:.0f} s)", flush=True)
        if rule != "nearest":
            depths.pop(rule) if rule not in ("up", "down") else None
    if "nearest" in depths:
        out["nearest_equals_library"] = bool(all(np.array_equal(a, b) for a, b in zip(depths["nearest"], library)))
    if "up" in depths and "down" in depths:
        oracle = [np.where(np.abs(u - e) <= np.abs(d - e), u, d) for u, d, e in zip(depths["up"], depths["down"], exact)]
        out["exact_dense"]["oracle_updown"] = strip(score(oracle, exact))
    return out


def real_check(costs, seeds, *, av2_seeds, rules=(), kitti_only=False) -> dict:
    """A check, never a choice: each ``seed_horizontal_cost`` on the real sets. The KITTI frame's dense ground
    truth (cameras 2 and 3, devkit means); ``hidden-eval`` on the nuScenes sample (draws ``seeds``) and on the
    Argoverse 2 log's first sweep with both LiDARs (``complete-rig``'s multi-source path, draws ``av2_seeds``):
    all targets and ``uncovered``, the SGM and the city-block fill (RMSE / MAE, mm)."""
    import glob

    from benchmarks._common import DATA, load_frames
    from jaxdepth.io import av2, read_points, rig_from_nuscenes_calibration
    frames = load_frames()
    nus = DATA / "nuscenes" / "sample"
    nus_rig = rig_from_nuscenes_calibration(nus / "calibration.json")
    points, extra = read_points(glob.glob(str(nus / "*LIDAR_TOP*.pcd.bin"))[0], columns=5)
    log = av2.read_log(DATA / "av2" / "sensor" / "val" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede")
    av2_rig, av2_cloud = av2.read_rig(log), av2.read_cloud(log)
    out = {}
    variants = [(str(c), SGMConfig(seed_horizontal_cost=c), None) for c in costs]
    variants += [(r, SGMConfig(), r) for r in rules]
    for name, config, rule in variants:
        t = time.time()
        with seed_rule(rule) if rule else contextlib.nullcontext():
            row = _real_row(config, frames, points, extra, nus_rig, av2_rig, av2_cloud, seeds,
                            av2_seeds=[] if kitti_only else av2_seeds, kitti_only=kitti_only)
        out[name] = row
        print(f"  {name} ({time.time() - t:.0f} s): {row}", flush=True)
    return out


def _real_row(config, frames, points, extra, nus_rig, av2_rig, av2_cloud, seeds, *, av2_seeds, kitti_only):
    import jaxdepth
    from jaxdepth._src.metrics import depth_metrics, mean_metrics
    from jaxdepth.batch.sources_job import complete_cloud
    from jaxdepth.io.points import ring_column
    from jaxdepth.research.cli import hidden_eval, hidden_eval_cloud
    rm = lambda m: {"rmse": float(m["rmse"]), "mae": float(m["mae"])}  # noqa: E731
    kitti = [depth_metrics(jaxdepth.complete(sparse, K, T, config=config), gt) for sparse, gt, K, T in frames.values()]
    row = {"kitti_frame_gt": rm(mean_metrics(kitti))}
    if kitti_only:
        return row
    res = hidden_eval(points, nus_rig, seeds=seeds, config=config, ring=ring_column(extra, 5))
    row["nuscenes"] = {p: {m: rm(res[key][m]) for m in ("sgm", "nearest")}
                       for p, key in (("all", "mean"), ("uncovered", "mean_uncovered"))}
    if av2_seeds:
        res = hidden_eval_cloud(av2_cloud, av2_rig, complete_cloud=complete_cloud, seeds=av2_seeds, config=config)
        row["av2"] = {p: {m: rm(res[key][m]) for m in ("sgm", "nearest")}
                      for p, key in (("all", "mean"), ("uncovered", "mean_uncovered"))}
    return row


def speed(costs, *, rounds: int, scale: float) -> dict:
    """What the option costs on the rig path: ``complete_rig``'s depth on the nuScenes twin (1 sweep, 6 cameras)
    per ``seed_horizontal_cost``, compiled first (apart), then ``rounds`` interleaved calls of each (order
    alternating), ``block_until_ready`` before each clock; medians of wall and process CPU seconds."""
    import os

    import jaxdepth
    from jaxdepth.io import pad_points, prepare_sweep
    inp, _ = twin_input("nuscenes", 1, 0, scale)
    frame = prepare_sweep(inp.cloud.points, inp.rig, ring=inp.cloud.ring)
    padded, valid = (jnp.asarray(a) for a in pad_points(frame.points))
    cams = jaxdepth.stack_cameras([c.as_camera() for c in frame.rig.cameras])
    fns, compile_s, outs = {}, {}, {}
    for c in costs:
        config = SGMConfig(seed_horizontal_cost=c, outlier_removal=frame.outlier_removal_trusted)
        t = time.perf_counter()
        fns[c] = jax.jit(lambda p, v, k, config=config: jaxdepth.complete_rig(p, v, k, config=config,
                                                                              lidar=frame.rig.lidar))
        outs[c] = fns[c](padded, valid, cams).block_until_ready()
        compile_s[c] = time.perf_counter() - t
    wall, cpu = {c: [] for c in costs}, {c: [] for c in costs}
    for r in range(rounds):
        for c in (costs if r % 2 == 0 else costs[::-1]):
            t, p = time.perf_counter(), time.process_time()
            fns[c](padded, valid, cams).block_until_ready()
            wall[c].append(time.perf_counter() - t)
            cpu[c].append(time.process_time() - p)
    base = costs[0]
    return {"twin": "nuscenes", "scale": scale, "rounds": rounds, "load_average": list(os.getloadavg()),
            "first_call_s": compile_s,
            "median_wall_s": {c: float(np.median(wall[c])) for c in costs},
            "median_cpu_s": {c: float(np.median(cpu[c])) for c in costs},
            "cpu_ratio_to_cost_1": {c: float(np.median(cpu[c]) / np.median(cpu[base])) for c in costs}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rigs", nargs="+", default=["nuscenes", "kitti", "av2", "raster", "rosette"])
    parser.add_argument("--sweeps", nargs="+", type=int, default=[1, 5])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--rules", nargs="+", default=list(RULES))
    parser.add_argument("--json", default=str(RESULTS / "edge_side.json"))
    parser.add_argument("--real-check", nargs="*", type=int, default=None, metavar="COST",
                        help="only the real sets' check of these seed_horizontal_cost values (to the JSON's real_check)")
    parser.add_argument("--real-seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--real-rules", nargs="*", default=[], help="seed rules (patched) for --real-check too")
    parser.add_argument("--kitti-only", action="store_true", help="--real-check: only the KITTI frame")
    parser.add_argument("--av2-seeds", nargs="*", type=int, default=[0, 1])
    parser.add_argument("--speed", nargs="+", type=int, default=None, metavar="COST",
                        help="only the rig path's run time per seed_horizontal_cost (to the JSON's speed)")
    parser.add_argument("--rounds", type=int, default=9)
    args = parser.parse_args(argv)
    t0 = time.time()
    if args.speed is not None:
        import json
        import pathlib
        path = pathlib.Path(args.json)
        doc = json.loads(path.read_text()) if path.exists() else {}
        doc["speed"] = speed(args.speed, rounds=args.rounds, scale=args.scale)
        print(doc["speed"])
        write_results(args.json, {k: v for k, v in doc.items() if k not in ("config", "seconds", "environment")},
                      SGMConfig(), t0)
        return 0
    if args.real_check is not None:
        import json
        import pathlib
        path = pathlib.Path(args.json)
        doc = json.loads(path.read_text()) if path.exists() else {}
        doc["real_check"] = {"costs": args.real_check, "nuscenes_seeds": args.real_seeds,
                             "av2_seeds": args.av2_seeds,
                             "rules": args.real_rules, "kitti_only": args.kitti_only,
                             "rows": real_check(args.real_check, args.real_seeds, av2_seeds=args.av2_seeds,
                                                rules=args.real_rules, kitti_only=args.kitti_only)}
        write_results(args.json, {k: v for k, v in doc.items() if k not in ("config", "seconds", "environment")},
                      SGMConfig(), t0)
        return 0
    cases = []
    for rig_name in args.rigs:
        for sweeps in args.sweeps:
            cases.append(case(rig_name, sweeps, args.seed, args.scale, args.rules))
            doc = {"settings": {"rigs": args.rigs, "sweeps": args.sweeps, "seed": args.seed, "scale": args.scale,
                                "rules": args.rules}, "cases": cases}
            write_results(args.json, doc, SGMConfig(), t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
