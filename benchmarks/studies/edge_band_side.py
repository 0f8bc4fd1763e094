"""Which side an edge-band pixel takes (issue 37, the nuScenes `uncovered` gap): side rules against exact depth.

    PYTHONPATH=. python -m benchmarks.studies.edge_band_side [--twin-seeds 0 1] [--scale 1] \
        [--json benchmarks/results/edge_band_side_bandside.json]
    PYTHONPATH=. python -m benchmarks.studies.edge_band_side --twin kitti --scale 0.25 --json ...  # another twin
    PYTHONPATH=. python -m benchmarks.studies.edge_band_side --twin av2 --scale 0.25 --window scanline --json ...
    PYTHONPATH=. python -m benchmarks.studies.edge_band_side --kitti-check [RULE ...] --json ...  # KITTI's GT
    PYTHONPATH=. python -m benchmarks.studies.edge_band_side --real-check [RULE ...] --json ...   # the real sample

``--window`` (:func:`window_radii`): the seed window and the band test in pixels as set on the full-size
nuScenes twin (``pixels``, the default), or scaled with the image, the angle or the scan-line spacing. The
twins of several LiDARs (``av2``, ``raster``, ``rosette``) run the multi-source path (``complete_cloud``'s
stages). ``--real-check`` also keeps each draw's scores and method-independent parts of each rule's MAE
difference (:func:`draw_scores`); the twins split their held-out targets by the same :func:`edge_class`.

A throw-away post-process of the SGM's own stages (as ``step4_edge_rules``): in the edge band (pixels whose
7 x 7 window of ``depth_raw`` holds a depth more than max(1 m, 5 %) off their own,
:func:`benchmarks.studies.step4_edge_rules.edge_pixels`) the pixel's ``depth_raw`` is replaced by the plane of
another kept LiDAR pixel ("seed") of its window (+-RV rows, +-RU columns) evaluated at the pixel (the paper's
Delta z, :func:`plane_at`); Step 4's Gaussian and the tail then run as the library's. The rules:

- ``own``: the library (``depth_raw``: the nearest seed's plane, column bracket);
- ``nearest_plane``: the nearest seed's plane without the bracket (``seed_depth + residual``);
- ``quadrant_vote``: among the nearest seed of each image quadrant and the own seed, the one whose plane at
  the pixel agrees (within max(1 m, 5 %)) with the most of the others' planes at the pixel;
- ``visibility``: the nearest of those candidates whose plane, between it and the pixel (a corridor of
  half-width max(2 px, half their distance)), does not pass in front of a seen LiDAR pixel (a plane in front
  of a point the LiDAR saw there cannot reach the pixel unbroken);
- ``consensus``: among the k nearest window seeds, the plane that the most window seeds lie on (weight
  1 / (1 + distance to the pixel));
- ``min_residual``: among the k nearest, the plane with the smallest mean relative misfit to the window's
  seeds on its own side (depth within max(1 m, 5 %) of the candidate's);
- ``knn_side_3`` / ``knn_side_5``: the window's seeds split into near / far at the geometric mean of their
  extreme depths; the majority side of the 3 / 5 nearest seeds, then that side's nearest seed's plane;
- ``edge_line``: the same split; the pixel's side of the line halfway between the two sides' centroids
  (weights 1 / (1 + distance)), then that side's nearest seed's plane;
- ``scanline_cost``: the nearest seed by a distance that adds 4 px for each depth jump (> max(1 m, 5 %)
  between vertically consecutive seeds of one window column) between the seed's row and the pixel's;
- ``oracle``: of the quadrant candidates and the own seed, the plane nearest the exact depth (a bound).

First the share of band pixels each rule puts on the right surface (within max(1 m, 5 %) of the exact depth),
then every rule's scores: exact depth of every pixel, and on hold-out draw 0 the exact depth at the held-out
pixels and the two ``hidden-eval`` protocols. Nothing is chosen on a real set (``--real-check``: a check).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig

RULES = ("own", "nearest_plane", "quadrant_vote", "visibility", "consensus", "min_residual", "knn_side_3",
         "knn_side_5", "edge_line", "scanline_cost", "oracle")
PROTOCOLS = ("exact_held_out", "hidden_all", "hidden_uncovered")
RV, RU, TOPK, SEEDS, CHUNK = 24, 24, 8, 32, 2000
_CFG = SGMConfig()


# the window's reference: the nuScenes twin at full size (where RV = RU = 24 and the 7 x 7 band were set), its
# cameras' median focal length (px) and its HDL-32E's scan-line and column spacings (deg)
REF_F_PX, REF_LINE_DEG, REF_COLUMN_DEG = 1260.18, 41.34 / 31, 360.0 / 1088
WINDOW_MODES = ("pixels", "image", "angle", "scanline")


def window_radii(mode: str, K: np.ndarray, lidar=None, scale: float = 1.0) -> tuple:
    """(rv, ru, band size) of the seed window and the band test for a rig (``K`` (C, 3, 3), ``lidar`` its
    :class:`~jaxdepth.LidarSpec`): ``pixels`` RV, RU and 7 as set on the full-size nuScenes twin; ``image``
    those times the image ``scale``; ``angle`` the same angle as there (times median f / REF_F_PX);
    ``scanline`` the same number of scan lines (rows) and LiDAR columns (columns) as there. Half sizes
    rounded half up, at least 1; the band's half size (3 there) scales as the rows."""
    if mode not in WINDOW_MODES:
        raise ValueError(f"window mode {mode!r}: expected one of {WINDOW_MODES}")
    fu, fv = float(np.median(K[:, 0, 0])) / REF_F_PX, float(np.median(K[:, 1, 1])) / REF_F_PX
    if mode == "pixels":
        fu = fv = 1.0
    elif mode == "image":
        fu = fv = float(scale)
    elif mode == "scanline":
        line_deg = (lidar.fov_up_deg - lidar.fov_down_deg) / (lidar.beams - 1)
        fv, fu = fv * line_deg / REF_LINE_DEG, fu * (360.0 / lidar.columns) / REF_COLUMN_DEG
    half = lambda r, f: max(1, int(np.floor(r * f + 0.5)))  # noqa: E731
    return half(RV, fv), half(RU, fu), 2 * half(3, fv) + 1


def tol(z):
    return np.maximum(1.0, 0.05 * z)


def plane_at(zc, nc, cu, cv, pu, pv, K):
    """Depth at pixel (pu, pv) of the plane through seed pixel (cu, cv) (depth zc, normal nc (..., 3)): the
    paper's z' + Delta z, with the library's guard and clip (``plane_residual``)."""
    fu, fv, ku, kv = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    numer = zc * ((cu - pu) * nc[..., 0] / fu + (cv - pv) * nc[..., 1] / fv)
    denom = (pu - ku) / fu * nc[..., 0] + (pv - kv) / fv * nc[..., 1] + nc[..., 2]
    ok = (np.abs(denom) > _CFG.min_abs_denom) & (zc > 0)
    res = np.where(ok, numer / np.where(ok, denom, 1.0), 0.0)
    return zc + np.clip(res, -_CFG.max_residual_ratio * zc, _CFG.max_residual_ratio * zc)


def _window(kept, normals, v, u, rv=RV, ru=RU):
    """(n, M) depth, (n, M, 3) normal, (n, M) row / column of every offset of the (2 rv + 1) x (2 ru + 1)
    window of pixels (v, u) (outside the image: depth 0)."""
    h, w = kept.shape
    ov, ou = np.meshgrid(np.arange(-rv, rv + 1), np.arange(-ru, ru + 1), indexing="ij")
    qv, qu = v[:, None] + ov.ravel()[None], u[:, None] + ou.ravel()[None]
    inside = (qv >= 0) & (qv < h) & (qu >= 0) & (qu < w)
    qv, qu = np.clip(qv, 0, h - 1), np.clip(qu, 0, w - 1)
    z = np.where(inside, kept[qv, qu], 0.0)
    n = np.moveaxis(normals[:, qv, qu], 0, -1)
    return z, n, qv.astype(np.float64), qu.astype(np.float64)


def _take(a, idx):
    return np.take_along_axis(a, idx[:, None] if idx.ndim == 1 else idx, axis=1)


def choose(kept, normals, K, v, u, own_raw, seed, exact, rv=RV, ru=RU):
    """{rule: (n,) depth} for band pixels (v, u) of one camera (``seed``: the own seed's (z, n (n, 3), row,
    column); ``exact`` (n,) for the oracle; ``rv`` / ``ru``: the window's half height / width)."""
    z, n, qv, qu = _window(kept, normals, v, u, rv, ru)
    has = z > 0
    pv, pu = v[:, None].astype(np.float64), u[:, None].astype(np.float64)
    d = np.where(has, np.hypot(qv - pv, qu - pu), np.inf)
    at_p = plane_at(z, n, qu, qv, pu, pv, K)                       # (n, M): each seed's plane at the pixel
    any_seed = has.any(axis=1)
    out = {"own": own_raw}
    sz, sn, sv, su = seed
    out["nearest_plane"] = plane_at(sz, sn, su, sv, u, v, K)

    # scan-line crossings: depth jumps between vertically consecutive seeds of one window column
    zc = z.reshape(len(v), 2 * rv + 1, 2 * ru + 1)
    jumps = np.zeros_like(zc)
    last = np.zeros(zc[:, 0].shape)
    for r in range(2 * rv + 1):
        cur = zc[:, r]
        jump = (cur > 0) & (last > 0) & (np.abs(cur - last) > tol(np.minimum(cur, last)))
        jumps[:, r] = (jumps[:, r - 1] if r else 0) + jump
        last = np.where(cur > 0, cur, last)
    crossings = np.abs(jumps - jumps[:, rv:rv + 1, :]).reshape(len(v), -1)
    cost = d + 4.0 * crossings
    out["scanline_cost"] = np.where(any_seed, _take(at_p, np.argmin(cost, axis=1)[:, None])[:, 0],
                                    out["nearest_plane"])
    # the S nearest seeds of the window (every rule below but the scan-line one reads only these)
    order = np.argsort(d, axis=1)[:, :SEEDS]
    z, qv, qu, d, at_p = (_take(a, order) for a in (z, qv, qu, d, at_p))
    n = np.stack([_take(n[..., i], order) for i in range(3)], axis=-1)
    has = np.isfinite(d)

    # quadrant candidates: the nearest seed of each quadrant (rows above incl. own row / below, left / right)
    quad = [(qv <= pv) & (qu < pu), (qv <= pv) & (qu >= pu), (qv > pv) & (qu < pu), (qv > pv) & (qu >= pu)]
    cand_idx = np.stack([np.argmin(np.where(q, d, np.inf), axis=1) for q in quad], axis=1)   # (n, 4)
    cand_ok = np.stack([np.isfinite(np.min(np.where(q, d, np.inf), axis=1)) for q in quad], axis=1)
    cz, cd = _take(at_p, cand_idx), _take(d, cand_idx)
    cz = np.concatenate([cz, out["nearest_plane"][:, None]], axis=1)   # own seed last
    cd = np.concatenate([cd, np.hypot(sv - v, su - u)[:, None]], axis=1)
    cand_ok = np.concatenate([cand_ok, (sz > 0)[:, None]], axis=1)
    agree = (np.abs(cz[:, :, None] - cz[:, None, :]) <= tol(np.minimum(cz[:, :, None], cz[:, None, :]))) \
        & cand_ok[:, None, :] & cand_ok[:, :, None]
    cd = np.where(cand_ok, cd, 0.0)
    votes = agree.sum(axis=2) - 1.0 - 1e-3 * cd / (1 + cd.max())           # ties: the nearer
    votes = np.where(cand_ok, votes, -np.inf)
    out["quadrant_vote"] = _take(cz, np.argmax(votes, axis=1)[:, None])[:, 0]
    out["oracle"] = _take(cz, np.argmin(np.where(cand_ok, np.abs(cz - exact[:, None]), np.inf), axis=1)[:, None])[:, 0]

    # visibility: candidate c (quadrant's nearest) is broken if a seen seed q in the corridor from c to the
    # pixel lies behind c's plane (c's plane at q nearer than q by more than the tolerance)
    vis_cost = np.full(cand_idx.shape, np.inf)
    for j in range(4):
        c = cand_idx[:, j]
        cu_, cv_ = _take(qu, c[:, None]), _take(qv, c[:, None])
        czs, cns = _take(z, c[:, None]), n[np.arange(len(c)), c][:, None, :]
        plane_q = plane_at(czs, cns, cu_, cv_, qu, qv, K)
        ax, ay = pu - cu_, pv - cv_
        length = np.maximum(np.hypot(ax, ay), 1e-6)
        t = ((qu - cu_) * ax + (qv - cv_) * ay) / length ** 2
        perp = np.abs((qu - cu_) * ay - (qv - cv_) * ax) / length
        corridor = has & (t > 0) & (t <= 1.0) & (perp <= np.maximum(2.0, 0.5 * length))
        broken = (corridor & (plane_q < z - tol(z))).any(axis=1)
        vis_cost[:, j] = np.where(cand_ok[:, j] & ~broken, cd[:, j], np.inf)
    best = np.argmin(vis_cost, axis=1)
    out["visibility"] = np.where(np.isfinite(vis_cost.min(axis=1)), _take(cz, best[:, None])[:, 0],
                                 out["nearest_plane"])

    # the k nearest window seeds as candidates: consensus and minimum residual
    k = np.argsort(d, axis=1)[:, :TOPK]
    kz, kd = _take(z, k), _take(d, k)
    kok = np.isfinite(kd)
    kn = np.stack([_take(n[..., i], k) for i in range(3)], axis=-1)
    ku, kv = _take(qu, k), _take(qv, k)
    plane_kq = plane_at(kz[:, :, None], kn[:, :, None, :], ku[:, :, None], kv[:, :, None],
                        qu[:, None, :], qv[:, None, :], K)                  # (n, k, M)
    on = has[:, None, :] & (np.abs(plane_kq - z[:, None, :]) <= tol(z[:, None, :]))
    weight = 1.0 / (1.0 + np.where(has, d, 0.0))
    support = np.where(kok, (on * weight[:, None, :]).sum(axis=2), -np.inf)
    kp = _take(at_p, k)
    out["consensus"] = _take(kp, np.argmax(support, axis=1)[:, None])[:, 0]
    side = has[:, None, :] & (np.abs(z[:, None, :] - kz[:, :, None]) <= tol(kz[:, :, None]))
    mis = np.abs(plane_kq - z[:, None, :]) / np.maximum(z[:, None, :], 1e-3)
    cnt = side.sum(axis=2)
    mean_mis = np.where(kok & (cnt >= 3), (mis * side).sum(axis=2) / np.maximum(cnt, 1), np.inf)
    out["min_residual"] = np.where(np.isfinite(mean_mis.min(axis=1)),
                                   _take(kp, np.argmin(mean_mis, axis=1)[:, None])[:, 0], out["nearest_plane"])

    # near / far split of the window's seeds
    zmin = np.min(np.where(has, z, np.inf), axis=1, keepdims=True)
    zmax = np.max(np.where(has, z, 0.0), axis=1, keepdims=True)
    near = has & (z < np.sqrt(np.where(has.any(axis=1, keepdims=True), zmin * zmax, 0.0)))
    far = has & ~near

    def side_plane(take_near):
        dd = np.where(np.where(take_near[:, None], near, far), d, np.inf)
        j = np.argmin(dd, axis=1)
        ok = np.isfinite(dd.min(axis=1))
        return np.where(ok, _take(at_p, j[:, None])[:, 0], out["nearest_plane"])

    for kk in (3, 5):
        k_near = _take(near, k[:, :kk]) & _take(np.isfinite(d), k[:, :kk])
        k_all = _take(np.isfinite(d), k[:, :kk])
        out[f"knn_side_{kk}"] = side_plane(2 * k_near.sum(axis=1) > k_all.sum(axis=1))
    wgt = np.where(has, 1.0 / (1.0 + d), 0.0)
    cen = lambda m: (np.sum(wgt * m * qu, 1) / np.maximum(np.sum(wgt * m, 1), 1e-9),  # noqa: E731
                     np.sum(wgt * m * qv, 1) / np.maximum(np.sum(wgt * m, 1), 1e-9))
    (nu, nv), (fu, fv) = cen(near), cen(far)
    proj = (u - (nu + fu) / 2) * (nu - fu) + (v - (nv + fv) / 2) * (nv - fv)
    split = near.any(axis=1) & far.any(axis=1)
    out["edge_line"] = np.where(split, side_plane(proj > 0), out["nearest_plane"])

    for r in out:
        out[r] = np.where(any_seed | (r in ("own", "nearest_plane")), out[r], own_raw).astype(np.float32)
    return out


def band_choices(stages: dict, K: np.ndarray, sizes, exact: list | None = None, only=None,
                 window: tuple = (RV, RU, 7)) -> tuple:
    """(band mask (C, H, W), {rule: (n,) depth}, (cam, v, u)) over every camera's edge band (``only``: (C, H, W)
    bool, the band's pixels elsewhere keep ``depth_raw``; ``window``: the seed window's half height and width
    and the band test's size, :func:`window_radii`)."""
    from benchmarks.studies.step4_edge_rules import edge_pixels
    raw = stages["depth_raw"]
    rv, ru, band_size = window
    band = edge_pixels(raw, band_size)
    for i, (h, w) in enumerate(sizes):
        band[i, h:], band[i, :, w:] = False, False
    if only is not None:
        band &= only
    kept_all = np.where(stages["inlier_mask"], stages["sparse_depth"], 0.0).astype(np.float64)
    cams, vs, us = np.nonzero(band)
    rules = {r: np.zeros(len(vs), np.float32) for r in RULES}
    for i in range(raw.shape[0]):
        h, w = sizes[i]
        kept, normals = kept_all[i, :h, :w], stages["normals"][i, :, :h, :w].astype(np.float64)
        ex = np.zeros((h, w)) if exact is None else exact[i]
        sel = np.nonzero(cams == i)[0]
        for s in range(0, len(sel), CHUNK):
            j = sel[s:s + CHUNK]
            v, u = vs[j], us[j]
            sv, su = v + stages["dv"][i, v, u], u + stages["du"][i, v, u]
            seed = (stages["seed_depth"][i, v, u].astype(np.float64), normals[:, sv, su].T, sv, su)
            got = choose(kept, normals, K[i], v, u, raw[i, v, u].astype(np.float64), seed, ex[v, u], rv, ru)
            for r in RULES:
                rules[r][j] = got[r]
    return band, rules, (cams, vs, us)


def rule_depths(stages: dict, band, rules: dict, where) -> dict:
    """{rule: (C, H, W) final depth}: the band's chosen depths into ``depth_raw``, then Step 4's Gaussian and
    tail (``step4_edge_rules``' own); the library's depth where that tail does not reproduce it."""
    from benchmarks.studies.step4_edge_rules import weighted_blur
    kept, sparse = stages["inlier_mask"], stages["sparse_depth"]
    has_seed = stages["seed_depth"] > 0

    def finish(raw):
        depth = np.where(kept, sparse, weighted_blur(raw))
        return np.where(has_seed, np.clip(depth, _CFG.min_depth_m, _CFG.max_depth_m), 0.0).astype(np.float32)
    # where the library's tail does more than Step 4 (the multi-source path's capped rule above the top scan
    # line), every rule keeps the library's depth
    other = np.abs(finish(stages["depth_raw"]) - stages["depth"]) > 1e-3
    out = {}
    for r, chosen in rules.items():
        raw = stages["depth_raw"].copy()
        raw[where] = chosen
        out[r] = np.where(other, stages["depth"], finish(raw))
    return out


FIELDS = ("sparse_depth", "normals", "inlier_mask", "seed_depth", "du", "dv", "depth_raw", "depth")


def _stages(cloud, rig, multi: bool = False) -> dict:
    """The default SGM's stages of the path ``complete-rig`` takes: the single-sweep one, or (``multi``: several
    LiDARs or sweeps) the multi-source one (``complete_cloud``)."""
    from benchmarks.accuracy_twins import single_path
    from jaxdepth.batch.sources_job import complete_cloud
    if multi:
        st = complete_cloud(cloud, rig, config=SGMConfig(), stages=True)
    else:
        st = single_path(cloud.points, cloud.ring, rig, SGMConfig(), stages=True)[0]
    return {f: np.asarray(getattr(st, f)) for f in FIELDS}


def right_shares(rules: dict, where, exact: list) -> dict:
    """Share of the band's pixels (with exact depth) each rule puts within max(1 m, 5 %) of the exact depth."""
    c, v, u = where
    ex = np.array([exact[ci][vi, ui] for ci, vi, ui in zip(c, v, u)], np.float64)
    seen = ex > 0
    return {"band_pixels": int(seen.sum()),
            **{r: float(np.mean(np.abs(d[seen] - ex[seen]) <= tol(ex[seen]))) for r, d in rules.items()}}


def twin_input(name: str, scene_seed: int, scale: float) -> tuple:
    """(the user's input, each camera's exact depth) of a twin at 1 sweep (``inp.multi``: several LiDARs)."""
    import tempfile

    from benchmarks.accuracy_twins import exact_truth, read_user_input
    from jaxdepth.research.twins import make_twin, write_twin
    tw = make_twin(name, sweeps=1, seed=scene_seed, scale=scale)
    with tempfile.TemporaryDirectory(prefix="twin_") as tmp:
        paths = write_twin(tw, tmp)
        inp = read_user_input(paths["sweeps"][0], paths["rig"])
    return inp, exact_truth(tw, inp.rig)


def twin_case(name: str, scene_seed: int, hidden_seed: int, scale: float, window: str = "pixels",
              band_size: int | None = None) -> dict:
    from benchmarks.accuracy_twins import cover_half_height, crops, hold_out, protocol_truths, score
    inp, exact = twin_input(name, scene_seed, scale)
    K = np.stack([np.asarray(c.K, np.float64) for c in inp.rig.cameras])
    rv, ru, band = window_radii(window, K, inp.rig.lidar, scale)
    win = (rv, ru, band if band_size is None else band_size)
    sizes = [(c.height, c.width) for c in inp.rig.cameras]
    strip = lambda s: {"rmse": s["rmse"], "mae": s["mae"]}  # noqa: E731
    st = _stages(inp.cloud, inp.rig, inp.multi)
    band, rules, where = band_choices(st, K, sizes, exact, window=win)
    depths = rule_depths(st, band, rules, where)
    case = {"twin": name, "scale": scale, "scene_seed": scene_seed, "hidden_seed": hidden_seed,
            "window_rows_cols_band": [2 * win[0] + 1, 2 * win[1] + 1, win[2]], "band_share": float(band.mean()),
            "right_share": right_shares(rules, where, exact),
            "own_vs_library_max_abs_m": float(np.max(np.abs(depths["own"] - st["depth"]))),
            "exact_dense": {r: strip(score(crops(depths[r], inp.rig), exact)) for r in RULES}}
    print(f"scene seed {scene_seed}: right share " + ", ".join(f"{r} {v:.4f}" for r, v in case["right_share"].items()),
          flush=True)
    del st, depths
    hidden, targets, full_z = hold_out(inp, hidden_seed)
    truths, _ = protocol_truths(exact, targets, full_z, cover_half_height(inp))
    kept = inp.cloud.take(~hidden)
    st = _stages(kept, inp.rig, inp.multi)
    band, rules, where = band_choices(st, K, sizes, exact, window=win)
    depths = rule_depths(st, band, rules, where)
    for p in PROTOCOLS:
        case[p] = {r: strip(score(crops(depths[r], inp.rig), truths[p])) for r in RULES}
    z = np.zeros(st["sparse_depth"].shape, np.float64)
    for i, t in enumerate(targets):
        z[i, :t.shape[0], :t.shape[1]] = t
    cls = crops(edge_class(st["sparse_depth"].astype(np.float64), z, win[0], win[1]), inp.rig)
    n = [sum(int((c == k).sum()) for c in cls) for k in range(len(EDGE_CLASSES))]
    case["by_edge_class"] = {name: {"share": n[k] / max(sum(n), 1),
                                    **{p: {r: strip(score(crops(depths[r], inp.rig),
                                                          [np.where(c == k, t, 0.0) for c, t in zip(cls, truths[p])]))
                                           for r in SPLIT_RULES} for p in PROTOCOLS if n[k]}}
                             for k, name in enumerate(EDGE_CLASSES)}
    return case


def _draw(points, ring, rig, seed: int, rules, K, sizes) -> dict:
    """One ``hidden-eval`` draw of the real sample (``nuscenes_uncovered_gap.draw_pixels``), every target: its
    camera, depth, whether the cover test drops it, every rule's depth, the library's SGM and the city-block fill
    (the seeds of the run without removal), and its :func:`edge_class`."""
    from scipy.ndimage import maximum_filter

    from benchmarks.studies.nuscenes_uncovered_gap import draw_pixels

    def extra(sgm, keep):
        st = {f: np.asarray(getattr(sgm, f)) for f in FIELDS}
        only = maximum_filter(keep, size=(1, 7, 7))                  # the Gaussian's reach of a target
        band, chosen, where = band_choices(st, K, sizes, None, only=only)
        out = {r: d[keep] for r, d in rule_depths(st, band, {r: chosen[r] for r in rules}, where).items()}
        seen.append((st["sparse_depth"].astype(np.float64), keep))
        return out

    seen = []
    p = draw_pixels(points, ring, rig, seed, SGMConfig(), extra=extra, all_targets=True)
    sparse, keep = seen[0]
    z = np.zeros(keep.shape, np.float64)
    z[keep] = p["z"]
    p["edge"] = edge_class(sparse, z)[keep]
    return {k: p[k] for k in ("cam", "z", "covered", "edge", "sgm", "nearest", *rules)}


EDGE_CLASSES = ("edge within 9 x 9", "edge in the seed window only", "no edge in the seed window")
SPLIT_RULES = ("own", "quadrant_vote", "edge_line")


def edge_class(sparse: np.ndarray, z: np.ndarray, rv: int = RV, ru: int = RU) -> np.ndarray:
    """(C, H, W) int8 for targets of depth ``z`` (C, H, W; 0: no target) against the kept LiDAR depth
    ``sparse`` (the input's z-buffer, no method's output): 0 a kept depth within 9 x 9 px off the target's by
    more than max(1 m, 5 %), 1 such a depth only in the (2 rv + 1) x (2 ru + 1) seed window, 2 none; -1 no
    target."""
    from scipy.ndimage import maximum_filter, minimum_filter
    t = tol(z)

    def edge(h, w):
        near = minimum_filter(np.where(sparse > 0, sparse, np.inf), size=(1, h, w), mode="constant", cval=np.inf)
        far = maximum_filter(sparse, size=(1, h, w), mode="constant", cval=0.0)
        return (z - near > t) | (far - z > t)
    out = np.where(edge(9, 9), 0, np.where(edge(2 * rv + 1, 2 * ru + 1), 1, 2)).astype(np.int8)
    return np.where(z > 0, out, -1).astype(np.int8)


def target_classes(d: dict) -> dict:
    """Method-independent splits of a draw's targets ({split: (labels (n,), names)}): ``cover`` (dropped by the
    cover test, or left and :func:`edge_class`'s class), ``depth`` (< 20 m / >= 20 m, the target's own depth),
    ``camera``."""
    z = d["z"].astype(np.float64)
    cover = np.where(d["covered"], 0, 1 + d["edge"])
    cams = [f"camera {c}" for c in range(int(d["cam"].max()) + 1)]
    return {"cover": (cover, ["covered", *("uncovered, " + c for c in EDGE_CLASSES)]),
            "depth": ((z >= 20).astype(int), ["< 20 m", ">= 20 m"]), "camera": (d["cam"], cams)}


def draw_scores(d: dict, methods, sel) -> dict:
    """{method: rmse, mae (mm, mean over the draw's images)} of the targets ``sel``, and per split and class
    each method's part of the MAE difference against the library's SGM (mm; a split's parts add up to it)."""
    cams = np.unique(d["cam"][sel])
    out, weight = {}, np.zeros(len(d["z"]))
    for cam in cams:
        at = sel & (d["cam"] == cam)
        weight[at] = 1.0 / at.sum() / len(cams)
    for m in methods:
        e = [np.abs(d[m][sel & (d["cam"] == c)].astype(np.float64) - d["z"][sel & (d["cam"] == c)]) for c in cams]
        out[m] = {"rmse": float(1000 * np.mean([np.sqrt(np.mean(x ** 2)) for x in e])),
                  "mae": float(1000 * np.mean([np.mean(x) for x in e]))}
    err = {m: np.abs(d[m].astype(np.float64) - d["z"]) for m in methods}
    parts = {}
    for split, (labels, names) in target_classes(d).items():
        parts[split] = {name: {"share": float(np.sum(weight[sel & (labels == i)])),
                               **{m: float(1000 * np.sum(((err[m] - err["sgm"]) * weight)[sel & (labels == i)]))
                                  for m in methods if m != "sgm"}} for i, name in enumerate(names)}
    out["mae_diff_parts_mm"] = parts
    return out


def real_check(seeds, rules=None) -> dict:
    """The real nuScenes sample under ``hidden-eval``'s protocols (draws ``seeds``): RMSE / MAE (mm, mean over
    images, every draw's images pooled) of ``rules`` (default: every one but the oracle), the library's SGM
    and the city-block fill; all targets and ``uncovered``; each draw's own scores and parts
    (:func:`draw_scores`) and the spread over draws of each method's difference to the SGM. A check of rules
    chosen on the twins, never a choice."""
    from benchmarks.studies import nuscenes_uncovered_gap as gap
    from jaxdepth.io import read_points, rig_from_nuscenes_calibration
    from jaxdepth.io.points import ring_column
    nus = gap.DATA / "nuscenes" / "sample"
    rig = rig_from_nuscenes_calibration(nus / "calibration.json")
    K = np.stack([np.asarray(c.K, np.float64) for c in rig.cameras])
    sizes = [(c.height, c.width) for c in rig.cameras]
    rules = [r for r in (rules or RULES) if r != "oracle"]
    methods = ["sgm", "nearest", *rules]
    points, more = read_points(sorted(nus.glob("*LIDAR_TOP*.pcd.bin"))[0], columns=5)
    draws = [_draw(points, ring_column(more, 5), rig, s, rules, K, sizes) for s in seeds]
    out = {"cameras": [c.name for c in rig.cameras]}
    for protocol in ("all", "uncovered"):
        sels = [np.ones(len(d["z"]), bool) if protocol == "all" else ~d["covered"] for d in draws]
        errs = {m: [] for m in methods}
        for d, sel in zip(draws, sels):
            for cam in np.unique(d["cam"][sel]):
                at = sel & (d["cam"] == cam)
                for m in errs:
                    e = np.abs(d[m][at].astype(np.float64) - d["z"][at])
                    errs[m].append((np.sqrt(np.mean(e ** 2)), np.mean(e)))
        out[protocol] = {m: {"rmse": float(1000 * np.mean([a for a, _ in v])),
                             "mae": float(1000 * np.mean([b for _, b in v]))} for m, v in errs.items()}
        per = [draw_scores(d, methods, sel) for d, sel in zip(draws, sels)]
        out[protocol + "_per_draw"] = per
        out[protocol + "_spread"] = {m: {k: {"mean": float(np.mean(x)), "sd": float(np.std(x, ddof=1)),
                                             "min": float(np.min(x)), "max": float(np.max(x))}
                                         for k, x in (("rmse_diff_mm", [p[m]["rmse"] - p["sgm"]["rmse"] for p in per]),
                                                      ("mae_diff_mm", [p[m]["mae"] - p["sgm"]["mae"] for p in per]),
                                                      ("mae_mm", [p[m]["mae"] for p in per]))}
                                     for m in methods}
    return out


def kitti_check(rules=None, window: str = "pixels") -> dict:
    """The shared KITTI frame's dense ground truth (cameras 2 and 3, devkit means over the two images) of
    ``rules`` (default every one but the oracle; ``window``: :func:`window_radii`'s mode, the default
    LiDAR spec, an HDL-64E): a check, never a choice."""
    import jax.numpy as jnp

    import jaxdepth
    from benchmarks._common import load_frames
    from jaxdepth._src.metrics import depth_metrics, mean_metrics
    rules = [r for r in (rules or RULES) if r != "oracle"]
    rows = {r: [] for r in rules}
    for sparse, gt, K, T in load_frames().values():
        st = jaxdepth.complete_stages(sparse, K, T)
        st = {f: np.asarray(getattr(st, f))[None] for f in FIELDS}
        Ks = np.asarray(K, np.float64)[None]
        band, chosen, where = band_choices(st, Ks, [st["depth"].shape[1:]],
                                           window=window_radii(window, Ks, jaxdepth.LidarSpec()))
        depths = rule_depths(st, band, {r: chosen[r] for r in rules}, where)
        for r in rules:
            rows[r].append(depth_metrics(jnp.asarray(depths[r][0]), jnp.asarray(gt)))
    return {r: {k: float(mean_metrics(v)[k]) for k in ("rmse", "mae")} for r, v in rows.items()}


def summary(cases: list) -> dict:
    """Per protocol and rule: the mean over scene seeds, the change against ``own`` (%), and whether the rule
    beats ``own`` in RMSE and MAE on every seed; the right shares' means."""
    out = {"right_share": {r: float(np.mean([c["right_share"][r] for c in cases])) for r in RULES}}
    for p in ("exact_dense",) + PROTOCOLS:
        rows = {}
        base = {m: float(np.mean([c[p]["own"][m] for c in cases])) for m in ("rmse", "mae")}
        for r in RULES:
            mean = {m: float(np.mean([c[p][r][m] for c in cases])) for m in ("rmse", "mae")}
            rows[r] = {**mean, **{f"{m}_change_pct": 100 * (mean[m] / base[m] - 1) for m in ("rmse", "mae")},
                       "wins_both_every_seed": all(c[p][r][m] < c[p]["own"][m] for c in cases for m in ("rmse", "mae"))}
        out[p] = rows
    return out


def main(argv=None) -> int:
    import json
    import pathlib

    from benchmarks.studies.step4_edge_rules import print_summary
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--twin", default="nuscenes", help="the twin (1 sweep): nuscenes, kitti (single-sweep "
                        "path), av2, raster, rosette (the multi-source path)")
    parser.add_argument("--twin-seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--hidden-seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--window", choices=WINDOW_MODES, default="pixels",
                        help="the seed window and band test (window_radii): pixels (49 x 49, 7 x 7 at any size), "
                             "image (times --scale), angle, scanline (both from the twin's rig)")
    parser.add_argument("--band-size", type=int, default=None, help="the band test's size instead of the window's")
    parser.add_argument("--real-check", nargs="*", default=None, metavar="RULE",
                        help="only the real nuScenes sample (draws 0-4, all targets and uncovered) of RULE (default "
                             "every rule), to the JSON's real_check (kept: the twin's cases)")
    parser.add_argument("--kitti-check", nargs="*", default=None, metavar="RULE",
                        help="only the KITTI frame's ground truth of RULE (default every rule), to the JSON's kitti_check")
    parser.add_argument("--json", default=str(RESULTS / "edge_band_side_bandside.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    if args.kitti_check is not None or args.real_check is not None:
        if args.kitti_check is not None:
            key, tables = "kitti_check", {"ground truth": kitti_check(args.kitti_check or None, args.window)}
            value = {**tables["ground truth"], "window": args.window, "seconds": time.time() - t0}
        else:
            key, value = "real_check", real_check([0, 1, 2, 3, 4], args.real_check or None)
            tables = {p: value[p] for p in ("all", "uncovered")}
            value = {"seeds": [0, 1, 2, 3, 4], **value, "seconds": time.time() - t0}
        for name, rows in tables.items():
            print(name + "\n" + "\n".join(f"  {m:16s} {v['rmse']:8.1f} / {v['mae']:6.1f}" for m, v in rows.items()))
        path = pathlib.Path(args.json)
        doc = json.loads(path.read_text()) if path.exists() else {}    # kept: what the runs before wrote
        doc[key] = value
        write_results(args.json, {k: v for k, v in doc.items() if k not in ("config", "seconds", "environment")},
                      SGMConfig(), t0)
        return 0
    cases = []
    for s in args.twin_seeds:
        cases.append(twin_case(args.twin, s, args.hidden_seed, args.scale, args.window, args.band_size))
        print(f"scene seed {s} ({time.time() - t0:.0f} s)", flush=True)
        for p in ("exact_dense",) + PROTOCOLS:
            print(f"  {p}: " + ", ".join(f"{r} {v['rmse']:.1f} / {v['mae']:.1f}" for r, v in cases[-1][p].items()),
                  flush=True)
    doc = {"settings": {"twin": args.twin, "sweeps": 1, "twin_seeds": args.twin_seeds, "scale": args.scale,
                        "hidden_seed": args.hidden_seed, "rules": list(RULES), "window": args.window,
                        "band_size": args.band_size, "window_rows_cols_band": cases[0]["window_rows_cols_band"],
                        "seeds_read": SEEDS, "k_nearest": TOPK},
           "cases": cases, "summary": summary(cases)}
    write_results(args.json, doc, SGMConfig(), t0)
    print_summary(doc["summary"], 16)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
