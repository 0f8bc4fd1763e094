"""Which truth is wrong at depth edges: the twins' exact depth or KITTI's ground truth? (issue 37)

    PYTHONPATH=. python -m benchmarks.studies.edge_truth [--part real twin band] [--seed 0] [--scale 1]
        [--variants NAME ...] [--no-effects] [--footprint-mrad 0] [--json benchmarks/results/edge_truth.json]

Two referees, independent of every method under test (and of the ground truth they judge):

1. **Real KITTI against its RGB image** (``--part real``). A *depth step* of the ground truth is a pair of
   valid GT pixels on one row (or column) at most ``MAX_GAP`` px apart with no valid pixel between, whose
   depths differ by more than max(1 m, 10 % of the nearer); it is oriented from the near pixel to the
   far one. The *image edge* next to it is the boundary, within ``WINDOW`` px either side of the step's
   gap, of the largest colour difference between adjacent pixels (sum of the absolute RGB
   differences), kept where it is a clear peak (>= ``MIN_PEAK`` and >= twice the window's median).
   Reported as **dilation, px: how far a depth's foreground reaches past the image edge** (positive:
   dilated, negative: eroded; 0 if the edge lies in the gap) for (a) the GT itself and (b) each
   completion at the same steps, its boundary being the count of window pixels nearer than the mean
   of the step's two GT depths; (c) the GT pixels of the windows that a completion puts on the other
   side than the GT (nearer or farther than that mean): which side the image gives them and how much
   of the completion's squared error under the GT they hold. Beside it: the squared error by region
   of the *input* alone (:func:`input_regions`: above the column's top input pixel, near an input depth
   step, rest) and a colour-only side referee (:func:`colour_sides`; its accuracy on the input's own
   pixels is reported: it leans to the nearest input pixel's side, so it is a weak referee).
2. **The KITTI twin scored like KITTI** (``--part twin``). KITTI-style ground truth: the twin's LiDAR
   cast at sweeps -5..+5 (ego and movers moving; sweep 0 is the user's input sweep itself),
   accumulated in the reference frame, projected into each camera and filtered point by point
   against a stereo disparity map (disparity = f B / depth, B the twin's camera 2 - 3 baseline):
   a point is dropped when its disparity differs from the stereo's at its pixel by more than
   ``tau`` px; then the nearest kept point per pixel. The stereo is the exact depth's disparity,
   either as is (``r = 0``) or with block-matching *foreground fattening* (maximum disparity over a
   (2r + 1)^2 window); the variants are :data:`GT_VARIANTS`. Each method (1 sweep, the user path) is
   scored against the exact depth of every pixel, the exact depth at the KITTI-style GT's pixels and
   the KITTI-style GT's values (also by input region); the GT's own errors against the exact depth
   and part 1's referee with the exact depth as the "image" (``100 log z``) are reported beside.
   ``--no-effects``: the twin without range noise, dropouts or mixed returns; ``--footprint-mrad M``: every
   LiDAR ray (input and GT sweeps) returns the nearest of itself and the rays M mrad to either side.
3. ``--part band``: in the input's edge band, the share of the GT's pixels on the near side
   (:func:`band_near_share`), real KITTI against the twin's exact depth and KITTI-style GTs.

Methods everywhere: the SGM default, ``seed_horizontal_cost = 3``, the near-side Step 3 rule
(``d z^0.5``) and the far-side rule (``d z^-0.5``) of ``benchmarks.studies.edge_side``, the city-block
and Euclidean nearest fills and IP_Basic (no outlier removal), all on the same input. Nothing here
is tuned; no library default changes.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from jaxdepth._src.config import SGMConfig

WINDOW = 6          # px either side of a step searched for the image edge / the completion's step
MIN_PEAK = 30.0     # sum of |dR| + |dG| + |dB| (0-765) for a clear image edge
STEP_ABS_M, STEP_REL = 1.0, 0.10
COLOUR_CONTRAST = 30.0   # RGB distance between a window's near and far mean colours for the colour referee
MAX_GAP = 4         # px: GT steps between valid pixels at most this far apart (KITTI GT is semi-dense)
_X = np.arange(1 - WINDOW, WINDOW + MAX_GAP)[None, :]     # window positions from the step's near pixel
SGM_VARIANTS = {"sgm": (SGMConfig(), None), "c3": (SGMConfig(seed_horizontal_cost=3), None),
                "near_g0.5": (SGMConfig(), "metric_g0.5"), "far_g-0.5": (SGMConfig(), "metric_g-0.5")}
FILLS = ("nearest", "nearest_l2", "ip_basic")
#: KITTI-style GT variants on the twin: (name, sweeps either side, fattening radius r px, tau px or None).
GT_VARIANTS = (("acc11_raw", 5, 0, None), ("acc11_stereo_r0_t3", 5, 0, 3.0), ("acc11_stereo_r1_t3", 5, 1, 3.0),
               ("acc11_stereo_r3_t3", 5, 3, 3.0), ("acc11_stereo_r3_t1", 5, 3, 1.0))


# ------------------------------------------------------------------ the referee (pure NumPy)

def steps(depth: np.ndarray, *, max_gap: int = MAX_GAP) -> tuple:
    """Depth steps along the rows of (H, W) ``depth`` (0 = none) between consecutive valid pixels at most
    ``max_gap`` apart: (rows, near columns, direction +-1 towards the far pixel, gap in px (1 = adjacent))."""
    r_all, c_all = np.nonzero(depth > 0)
    same = r_all[1:] == r_all[:-1]
    gap = c_all[1:] - c_all[:-1]
    a, b = depth[r_all[:-1], c_all[:-1]], depth[r_all[1:], c_all[1:]]
    step = same & (gap <= max_gap) & (np.abs(a - b) > np.maximum(STEP_ABS_M, STEP_REL * np.minimum(a, b)))
    i = np.flatnonzero(step)
    left_near = a[i] < b[i]
    return (r_all[i], np.where(left_near, c_all[i], c_all[i + 1]), np.where(left_near, 1, -1), gap[i],
            np.minimum(a[i], b[i]), np.maximum(a[i], b[i]))


def _windows(values: np.ndarray, r, near, s, gap, *, fill) -> tuple:
    """((n, 2 WINDOW + MAX_GAP - 1) values at ``near + s x``, x = 1-WINDOW..WINDOW+MAX_GAP-1 (``fill`` outside
    the image and beyond ``gap + WINDOW - 1``: WINDOW pixels each side of the step's gap), columns, inside)."""
    x = _X
    cols = near[:, None] + s[:, None] * x
    inside = (cols >= 0) & (cols < values.shape[1]) & (x <= (gap + WINDOW - 1)[:, None])
    cols = np.clip(cols, 0, values.shape[1] - 1)
    return np.where(inside, values[r[:, None], cols], fill), cols, inside


def image_edge(values: np.ndarray, r, near, s, gap, *, min_peak: float) -> np.ndarray:
    """(n,) offset of the referee's edge from each step's boundary, or NaN where no clear edge.

    The edge is the boundary j + 0.5 (j = -WINDOW..WINDOW-1) of the largest difference between adjacent
    pixels of ``values`` ((H, W[, C]); summed over channels), kept if >= ``min_peak`` and twice the window's
    median. Offset: ``j`` if the edge lies before the step's near pixel's far border (j < 0: inside the
    depth's near side), 0 inside the gap, ``j - gap + 1`` beyond the first far pixel."""
    v = values.reshape(values.shape[0], values.shape[1], -1).astype(np.float32)
    w = np.stack([_windows(v[..., c], r, near, s, gap, fill=np.nan)[0] for c in range(v.shape[-1])], axis=-1)
    g = np.abs(np.diff(w, axis=1)).sum(axis=-1)
    g = np.where(np.isnan(g), -1.0, g)
    e = np.argmax(g, axis=1)
    peak = g[np.arange(len(e)), e]
    med = np.median(np.maximum(g, 0), axis=1)
    j = (e + _X[0, 0]).astype(np.float64)
    off = np.where(j < 0, j, np.where(j < gap, 0.0, j - gap + 1))
    return np.where((peak >= min_peak) & (peak >= 2 * med), -off, np.nan)


def side_boundary(depth: np.ndarray, r, near, s, gap, mid) -> np.ndarray:
    """(n,) where ``depth`` (a completion) puts each step, in :func:`image_edge`'s offsets: the count of window
    pixels nearer than ``mid`` (the mean of the step's two depths) less the near side's WINDOW + 1, with the
    gap counted as at :func:`image_edge` (offsets inside the gap are 0)."""
    w = _windows(depth, r, near, s, gap, fill=np.nan)[0]
    j = (np.sum(w < mid[:, None], axis=1) - WINDOW).astype(np.float64)
    return np.where(j < 0, j, np.where(j < gap, 0.0, j - gap + 1))


def offset_stats(off: np.ndarray) -> dict:
    """Counts and shares of negative (dilated foreground), zero and positive offsets; mean (and its standard
    error) of the decided."""
    d = off[np.isfinite(off)]
    n = max(len(d), 1)
    return {"steps": int(len(off)), "decided": int(len(d)), "mean_px": float(d.mean()) if len(d) else None,
            "se_px": float(d.std() / math.sqrt(n)) if len(d) > 1 else None,
            "share_negative": float((d < 0).sum() / n), "share_zero": float((d == 0).sum() / n),
            "share_positive": float((d > 0).sum() / n)}


ZONE = ("image_with_gt", "image_with_method", "undecided")


def referee(truth: np.ndarray, edges: np.ndarray, completions: dict, *, min_peak: float = MIN_PEAK) -> dict:
    """Part 1's statistics of one camera: GT steps against ``edges`` ((H, W[, C]) values whose adjacent
    differences mark the referee's edges), each completion's step at those GT steps against them, and the
    completion's squared error under ``truth`` on the GT pixels (within the steps' windows) that the
    completion gives the other side of the step than the GT (the side: nearer or farther than the mean of
    the step's two GT depths); the referee's edge decides which of the two is right."""
    gt_off, comp_off = [], {m: [] for m in completions}
    zone = {m: {k: np.zeros(truth.shape, bool) for k in ZONE} for m in completions}
    for transpose in (False, True):
        tr = (lambda a: np.swapaxes(a, 0, 1)) if transpose else (lambda a: a)  # noqa: E731
        t = tr(truth)
        r, near, s, gap, zn, zf = steps(t)
        mid = 0.5 * (zn + zf)
        img = image_edge(tr(edges), r, near, s, gap, min_peak=min_peak)
        gt_off.append(img)
        tw, cols, inside = _windows(t, r, near, s, gap, fill=0.0)
        # the referee's side of each window pixel: near up to the edge (gap pixels: the edge's side in the gap)
        e_raw = np.where(np.isfinite(img), np.where(img < 0, -img + gap - 1, np.minimum(-img, 0)), np.nan)
        img_near = _X <= np.where(np.isfinite(e_raw), e_raw, 0)[:, None]
        decided = np.isfinite(e_raw)[:, None]
        gt_near = tw < mid[:, None]
        valid = (tw > 0) & inside
        rows = np.broadcast_to(r[:, None], cols.shape)
        for m, depth in completions.items():
            d = tr(depth)
            comp_off[m].append(side_boundary(d, r, near, s, gap, mid) + img)
            dw = _windows(d, r, near, s, gap, fill=np.nan)[0]
            disagree = valid & ((dw < mid[:, None]) != gt_near)
            for key, sel in (("image_with_gt", disagree & decided & (img_near == gt_near)),
                             ("image_with_method", disagree & decided & (img_near != gt_near)),
                             ("undecided", disagree & ~decided)):
                rr, cc = (cols[sel], rows[sel]) if transpose else (rows[sel], cols[sel])
                zone[m][key][rr, cc] = True
    out = {"gt_steps_vs_edges": offset_stats(np.concatenate(gt_off)), "methods": {}}
    for m, depth in completions.items():
        sq = np.where(truth > 0, (depth - truth) ** 2, 0.0)
        z = zone[m]
        z["image_with_method"] &= ~z["image_with_gt"]                    # a pixel of two windows: counted once
        z["undecided"] &= ~(z["image_with_gt"] | z["image_with_method"])
        out["methods"][m] = {"step_minus_edge_at_gt_steps": offset_stats(np.concatenate(comp_off[m])),
                             "sq_total": float(sq.sum()), "gt_pixels": int((truth > 0).sum()),
                             **{f"px_{k}": int(z[k].sum()) for k in ZONE},
                             **{f"sq_{k}": float(sq[z[k]].sum()) for k in ZONE}}
    return out


def pooled(per_camera: list) -> dict:
    """Part 1's statistics pooled over cameras (counts summed; shares, means weighted by the decided)."""
    def pool(stats):
        dec = sum(s["decided"] for s in stats)
        w = lambda k: sum((s[k] or 0) * s["decided"] for s in stats) / max(dec, 1)  # noqa: E731
        se = math.sqrt(sum(((s["se_px"] or 0) * s["decided"]) ** 2 for s in stats)) / max(dec, 1)
        return {"steps": sum(s["steps"] for s in stats), "decided": dec, "mean_px": w("mean_px"), "se_px": se,
                "share_negative": w("share_negative"), "share_zero": w("share_zero"),
                "share_positive": w("share_positive")}
    out = {"gt_steps_vs_edges": pool([c["gt_steps_vs_edges"] for c in per_camera]), "methods": {}}
    for m in per_camera[0]["methods"]:
        rows = [c["methods"][m] for c in per_camera]
        agg = {k: sum(r[k] for r in rows) for k in rows[0] if k != "step_minus_edge_at_gt_steps"}
        agg["step_minus_edge_at_gt_steps"] = pool([r["step_minus_edge_at_gt_steps"] for r in rows])
        agg.update({f"share_sq_{k}": agg[f"sq_{k}"] / max(agg["sq_total"], 1e-9) for k in ZONE})
        out["methods"][m] = agg
    return out

def input_regions(sparse: np.ndarray, *, half: int = 4) -> dict:
    """Method-independent (H, W) bool regions from the sparse input: ``above`` (above the topmost input pixel
    of the column), ``edge`` (else, within ``half`` px (Chebyshev) of input depths differing by more than
    max(1 m, 10 %)), ``rest``."""
    from scipy.ndimage import maximum_filter, minimum_filter
    has = sparse > 0
    top = np.where(has.any(axis=0), np.argmax(has, axis=0), sparse.shape[0])
    above = np.arange(sparse.shape[0])[:, None] < top[None, :]
    hi = maximum_filter(np.where(has, sparse, 0.0), size=2 * half + 1)
    lo = minimum_filter(np.where(has, sparse, np.inf), size=2 * half + 1)
    edge = ~above & np.isfinite(lo) & (hi - lo > np.maximum(STEP_ABS_M, STEP_REL * lo))
    return {"above": above, "edge": edge, "rest": ~above & ~edge}


def region_mse(truth: list, regions: list, completions: dict) -> dict:
    """{region: {"gt_pixels", "share", method: squared error summed over the region / all GT pixels (m^2)}}."""
    n = sum(int((t > 0).sum()) for t in truth)
    out = {}
    for key in regions[0]:
        sel = [(t > 0) & r[key] for t, r in zip(truth, regions)]
        row = {"gt_pixels": int(sum(x.sum() for x in sel))}
        row["share"] = row["gt_pixels"] / n
        for m, d in completions.items():
            row[m] = float(sum(np.sum((dd[x] - t[x]) ** 2) for dd, t, x in zip(d, truth, sel)) / n)
        out[key] = row
    return out


def colour_sides(sparse: np.ndarray, image: np.ndarray, *, half: int = 4, min_contrast: float = COLOUR_CONTRAST) -> tuple:
    """The image's side of each pixel of the input's edge band (:func:`input_regions`), from colour alone.

    In each pixel's (2 half + 1)^2 window the input pixels split at ``mid`` (the mean of the window's
    smallest and largest input depth) into a near and a far group; the pixel belongs to the group whose mean
    colour (RGB, 3 x 3 box-smoothed) is nearer its own. Decided where the two means differ by >=
    ``min_contrast`` (Euclidean, 0-255 units). The input pixel at the centre is left out of the groups (so an
    input pixel's own depth can check the referee). Returns ((H, W) bool near, (H, W) bool decided, (H, W) mid).
    """
    from scipy.ndimage import maximum_filter, minimum_filter, uniform_filter
    img = uniform_filter(image.astype(np.float32), size=(3, 3, 1))
    has = sparse > 0
    hi = maximum_filter(np.where(has, sparse, 0.0), size=2 * half + 1)
    lo = minimum_filter(np.where(has, sparse, np.inf), size=2 * half + 1)
    mid = 0.5 * (hi + lo)
    h, w = sparse.shape
    pad = np.pad(np.where(has, sparse, 0.0), half)
    ipad = np.pad(img, ((half, half), (half, half), (0, 0)))
    sums = {k: np.zeros((h, w, 3), np.float32) for k in ("near", "far")}
    counts = {k: np.zeros((h, w), np.float32) for k in ("near", "far")}
    for dv in range(-half, half + 1):
        for du in range(-half, half + 1):
            if dv == 0 and du == 0:
                continue
            z = pad[half + dv:half + dv + h, half + du:half + du + w]
            c = ipad[half + dv:half + dv + h, half + du:half + du + w]
            for key, sel in (("near", (z > 0) & (z < mid)), ("far", (z > 0) & (z >= mid))):
                sums[key] += np.where(sel[..., None], c, 0.0)
                counts[key] += sel
    mean = {k: sums[k] / np.maximum(counts[k], 1)[..., None] for k in sums}
    dn, df = (np.linalg.norm(img - mean[k], axis=-1) for k in ("near", "far"))
    decided = ((counts["near"] > 0) & (counts["far"] > 0)
               & (np.linalg.norm(mean["near"] - mean["far"], axis=-1) >= min_contrast))
    return dn < df, decided, mid


def colour_agreement(sparse, image, truth, completions: dict) -> dict:
    """How often the image's colour side (:func:`colour_sides`) agrees with: the input's own depth at input
    pixels of the edge band (the referee's accuracy), the GT's side at GT pixels of the band, and each
    completion's side at the band's GT pixels and at every band pixel; plus, at band pixels where the GT and
    a completion take different sides, the share the image gives the GT."""
    band = input_regions(sparse)["edge"]
    near, decided, mid = colour_sides(sparse, image)
    sel = band & decided

    def agree(depth, where):
        m = where & (depth > 0)
        return {"pixels": int(m.sum()), "agree": int(((depth < mid) == near)[m].sum())}

    out = {"band_pixels": int(band.sum()), "decided": int(sel.sum()), "input": agree(sparse, sel),
           "gt": agree(truth, sel), "methods": {}}
    for name, d in completions.items():
        dis = sel & (truth > 0) & ((d < mid) != (truth < mid))
        out["methods"][name] = {"at_gt": agree(d, sel & (truth > 0)), "all": agree(d, sel),
                                "gt_disagree": {"pixels": int(dis.sum()),
                                                "image_with_gt": int(((truth < mid) == near)[dis].sum())}}
    return out


def band_near_share(sparse: np.ndarray, truth: np.ndarray, *, half: int = 4) -> dict:
    """In the input's edge band (:func:`input_regions`), the truth's pixels and the share of them on the near
    side (depth below the mean of the window's smallest and largest input depth): a GT biased to the
    foreground where it has one side only shows a larger share than the exact depth has."""
    band = input_regions(sparse, half=half)["edge"]
    _, _, mid = colour_sides(sparse, np.zeros(sparse.shape + (3,), np.uint8), half=half)
    m = band & (truth > 0)
    return {"pixels": int(m.sum()), "near": int((truth[m] < mid[m]).sum())}


def band_part(seed: int, scale: float) -> dict:
    """:func:`band_near_share` of the real GT, and of the KITTI twin's exact depth and KITTI-style GTs."""
    from benchmarks._common import load_frames
    from benchmarks.accuracy_twins import z_buffers
    from benchmarks.studies.edge_side import twin_input
    pool = lambda rows: {"pixels": sum(r["pixels"] for r in rows), "near": sum(r["near"] for r in rows)}  # noqa: E731
    out = {"real_gt": pool([band_near_share(s, g) for s, g, _, _ in load_frames().values()])}
    inp, exact = twin_input("kitti", 1, seed, scale)
    sparse = z_buffers(inp.cloud.points, inp.rig)
    out["twin_exact"] = pool([band_near_share(s, e) for s, e in zip(sparse, exact)])
    points = accumulated_points("kitti", seed, 5)
    for name, half, radius, tau in GT_VARIANTS:
        gt = kitti_style_gt(points, inp.rig, exact, radius=radius, tau=tau)
        out[name] = pool([band_near_share(s, g) for s, g in zip(sparse, gt)])
        out[f"{name}_exact_at_pixels"] = pool([band_near_share(s, np.where(g > 0, e, 0.0)) for s, g, e in zip(sparse, gt, exact)])
    for v in out.values():
        v["share_near"] = v["near"] / max(v["pixels"], 1)
    return out


# ------------------------------------------------------------------ the methods

def _seed_rule(rule):
    from benchmarks.studies.edge_side import seed_rule
    return seed_rule(rule) if rule else contextlib.nullcontext()


def real_methods(frames: dict) -> dict:
    """{method: {camera: (H, W) depth}} on the real KITTI frame's official sparse input."""
    import jaxdepth
    out = {}
    for name, (config, rule) in SGM_VARIANTS.items():
        with _seed_rule(rule):
            out[name] = {cam: np.asarray(jaxdepth.complete(s, K, T, config=config)) for cam, (s, _, K, T) in frames.items()}
    plain = SGMConfig(outlier_removal=False)
    for name, method, cfg in (("nearest", "nearest", plain), ("nearest_l2", "nearest", plain.replace(distance_metric="l2")),
                              ("ip_basic", "ip-basic", plain)):
        out[name] = {cam: np.asarray(jaxdepth.complete_with(s, K, T, method=method, config=cfg))
                     for cam, (s, _, K, T) in frames.items()}
    return out


def devkit(pred: list, truth: list) -> dict:
    from benchmarks.accuracy_twins import score
    sc = score(pred, truth)
    return {"rmse": sc["rmse"], "mae": sc["mae"]}


def real_part() -> dict:
    from benchmarks._common import load_frames, load_images
    frames, images = load_frames(), load_images()
    t = time.time()
    runs = real_methods(frames)
    print(f"real methods: {time.time() - t:.0f} s", flush=True)
    scores = {m: devkit([runs[m][c] for c in frames], [frames[c][1] for c in frames]) for m in runs}
    per_cam = {c: referee(frames[c][1], images[c], {m: runs[m][c] for m in runs}) for c in frames}
    regions = region_mse([frames[c][1] for c in frames], [input_regions(frames[c][0]) for c in frames],
                         {m: [runs[m][c] for c in frames] for m in runs})
    colour = {c: colour_agreement(frames[c][0], images[c], frames[c][1], {m: runs[m][c] for m in runs}) for c in frames}
    return {"scores_gt": scores, "regions_mse": regions, "colour_referee": colour,
            "referee": pooled(list(per_cam.values())), "referee_per_camera": per_cam}


# ------------------------------------------------------------------ the twin scored like KITTI

def _pose(rdef, k: int) -> np.ndarray:
    """``twins.ego_pose`` extended to future sweeps (k < 0: the ego ``-k`` sweeps ahead on the same left curve)."""
    from jaxdepth.research.twins import ego_pose
    if k >= 0:
        return ego_pose(rdef, k)
    x = y = 0.0
    for j in range(-k):
        h = math.radians(rdef.yaw_deg) * (j + 0.5)
        x += rdef.step_m * math.cos(h)
        y += rdef.step_m * math.sin(h)
    a = math.radians(rdef.yaw_deg) * (-k)
    T = np.eye(4)
    T[:3, :3] = [[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = (x, y, 0.0)
    return T


def _footprint(cast, T: np.ndarray, out: dict, footprint_mrad: float) -> np.ndarray:
    """(n, 3) ``out``'s points with each valid ray's range replaced by the smallest of its own and of the same
    ray cast ``footprint_mrad`` to either side in azimuth (a beam returning the nearer surface over its width)."""
    pts = out["points"].astype(np.float64)
    origin = out["origin"]
    r = np.linalg.norm(pts - origin, axis=1)
    best = np.where(out["valid"], r, np.inf)
    for sign in (-1.0, 1.0):
        a = sign * footprint_mrad * 1e-3
        Rz = np.eye(4)
        Rz[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
        side = cast(T @ Rz)
        rs = np.linalg.norm(side["points"].astype(np.float64) - origin, axis=1)
        best = np.minimum(best, np.where(side["valid"], rs, np.inf))
    scale = np.where(out["valid"], best / np.maximum(r, 1e-9), 1.0)
    return origin + (pts - origin) * scale[:, None]


def _footprint_el(cast_with, unit, out: dict, footprint_mrad: float) -> np.ndarray:
    """:func:`_footprint` across the scan lines: the smallest range of each ray and the same ray tilted
    ``footprint_mrad`` up and down in elevation (``cast_with(unit)`` casts a unit at the sweep's pose)."""
    import dataclasses
    pts = out["points"].astype(np.float64)
    origin = out["origin"]
    r = np.linalg.norm(pts - origin, axis=1)
    best = np.where(out["valid"], r, np.inf)
    d = unit.directions.astype(np.float64)
    el, rho = np.arcsin(np.clip(d[:, 2], -1, 1)), np.hypot(d[:, 0], d[:, 1])
    for sign in (-1.0, 1.0):
        e = el + sign * footprint_mrad * 1e-3
        k = np.cos(e) / np.maximum(rho, 1e-12)
        side = cast_with(dataclasses.replace(unit, directions=np.c_[d[:, 0] * k, d[:, 1] * k, np.sin(e)].astype(np.float32)))
        rs = np.linalg.norm(side["points"].astype(np.float64) - origin, axis=1)
        best = np.minimum(best, np.where(side["valid"], rs, np.inf))
    return origin + (pts - origin) * np.where(out["valid"], best / np.maximum(r, 1e-9), 1.0)[:, None]


def accumulated_points(rig: str, seed: int, half: int, *, effects: bool = True, footprint_mrad: float = 0.0,
                       ks=None, distort=None, with_ring: bool = False):
    """(N, 3) float32 returns of sweeps -half..half (or ``ks``) of the twin's LiDAR (effects on: the twin's
    rates) in the reference points frame; sweep 0 draws exactly as ``make_twin`` (the input sweep's own points,
    in its order). ``footprint_mrad``: see :func:`_footprint` (0: thin rays, as the twin). ``distort``: None, or an
    object with ``unit`` (None, or ``Unit -> Unit``: the scan pattern cast in place of the twin's) and ``points``
    (None, or ``f(points (n, 3) in the unit's frame, ring (n,), rdef) -> (n, 3)``: what the sensor reports in
    place of the true point), applied to every sweep (``benchmarks.studies.edge_input``). ``with_ring``: also
    the (N,) int32 ring (laser index) of each return."""
    from jaxdepth.research import twin_scene
    from jaxdepth.research.twin_rigs import RIG_BUILDERS
    from jaxdepth.research.twin_sensors import NO_EFFECTS, SensorEffects, cast_unit
    from jaxdepth.research.twin_tables import SENSOR_EFFECTS
    rates = SensorEffects(**SENSOR_EFFECTS[rig]) if effects else NO_EFFECTS
    rdef = RIG_BUILDERS[rig](rates)
    T_ref_world = np.linalg.inv(_pose(rdef, 0) @ rdef.T_ego_points)
    spheres = twin_scene.twin_spheres(seed)
    pts, rings = [], []
    for k in (range(-half, half + 1) if ks is None else ks):
        scene = twin_scene.twin_scene(seed, k, dt_s=rdef.dt_s)
        T_world_k = _pose(rdef, k) @ rdef.T_ego_points
        for u, (make_unit, T_points_unit) in enumerate(rdef.units):
            key = [seed, k, u, 37] if k >= 0 else [seed, 1000 - k, u, 37]
            unit, T = make_unit(k), T_world_k @ T_points_unit
            if distort is not None and distort.unit is not None:
                unit = distort.unit(unit)
            cast = lambda T_, unit=unit, scene=scene, key=key: cast_unit(scene, spheres, unit, T_, rates, key)  # noqa: E731
            out = cast(T)
            p = _footprint(cast, T, out, footprint_mrad) if footprint_mrad else out["points"].astype(np.float64)
            if getattr(distort, "footprint_el_mrad", 0.0):
                p = _footprint_el(lambda u, T=T, scene=scene, key=key: cast_unit(scene, spheres, u, T, rates, key), unit,
                                  {**out, "points": p}, distort.footprint_el_mrad)
            p = p[out["valid"]]
            if distort is not None and distort.points is not None:     # in the unit's frame, where the sensor errs
                p = (p - T[:3, 3]) @ T[:3, :3]
                p = distort.points(p, out["ring"][out["valid"]], rdef) @ T[:3, :3].T + T[:3, 3]
            pts.append((p @ T_ref_world[:3, :3].T + T_ref_world[:3, 3]).astype(np.float32))
            rings.append(np.asarray(out["ring"])[out["valid"]].astype(np.int32))
    return (np.concatenate(pts), np.concatenate(rings)) if with_ring else np.concatenate(pts)


def kitti_style_gt(points: np.ndarray, rig, exact: list, *, radius: int, tau: float | None) -> list:
    """Each camera's KITTI-style GT: ``points`` filtered against the stereo (see the module docstring), nearest per pixel."""
    from scipy.ndimage import maximum_filter

    from benchmarks.accuracy_twins import z_buffers
    t2, t3 = (np.linalg.inv(np.asarray(c.T_cam_lidar, np.float64))[:3, 3] for c in rig.cameras[:2])
    out = []
    for cam, ex in zip(rig.cameras, exact):
        fb = float(cam.K[0, 0]) * float(np.linalg.norm(t2 - t3))
        if tau is None:
            out.append(z_buffers(points, _one(rig, cam))[0])
            continue
        disp = np.where(ex > 0, fb / np.maximum(ex, 1e-3), 0.0)
        stereo = maximum_filter(disp, size=2 * radius + 1, mode="nearest") if radius else disp
        T = np.asarray(cam.T_cam_lidar, np.float64)
        pc = points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        z = pc[:, 2]
        front = z > 0.1
        uv = pc[front] @ np.asarray(cam.K, np.float64).T
        u, v = np.floor(uv[:, 0] / uv[:, 2] + 0.5).astype(int), np.floor(uv[:, 1] / uv[:, 2] + 0.5).astype(int)
        inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        sd = np.zeros(len(u))
        sd[inside] = stereo[v[inside], u[inside]]
        keep = inside & (sd > 0) & (np.abs(fb / z[front] - sd) <= tau)
        out.append(z_buffers(points[np.flatnonzero(front)[keep]], _one(rig, cam))[0])
    return out


def _one(rig, cam):
    import dataclasses
    return dataclasses.replace(rig, cameras=(cam,))


def gt_errors(gt: list, exact: list) -> dict:
    """The KITTI-style GT against the exact depth at its pixels: density, and shares wrong by more than
    max(0.3 m, 3 %) nearer (a nearer surface's depth: foreground on background) and farther."""
    n = wrong_near = wrong_far = total = 0
    for g, e in zip(gt, exact):
        m = (g > 0) & (e > 0)
        bad = np.abs(g - e) > np.maximum(0.3, 0.03 * e)
        n += int(m.sum())
        total += g.size
        wrong_near += int((m & bad & (g < e)).sum())
        wrong_far += int((m & bad & (g > e)).sum())
    return {"density": n / total, "pixels": n, "share_wrong_nearer": wrong_near / max(n, 1),
            "share_wrong_farther": wrong_far / max(n, 1)}


def twin_part(seed: int, scale: float, *, effects: bool = True, variants=GT_VARIANTS, footprint_mrad: float = 0.0,
              distort=None, methods=None, fills=FILLS) -> dict:
    from benchmarks.accuracy_twins import predictions, z_buffers
    from benchmarks.studies.edge_side import run_sgm, twin_input
    t0 = time.time()
    inp, exact = twin_input("kitti", 1, seed, scale, effects=effects)
    if footprint_mrad or distort:            # the input sweep with footprints / distortion (same rays, same order)
        import dataclasses
        pts = accumulated_points("kitti", seed, 0, effects=effects, footprint_mrad=footprint_mrad, ks=[0],
                                 distort=distort)
        assert inp.cloud.ring is None and len(inp.cloud.T_ref_source) == 1      # one source: a recast may add points
        inp = dataclasses.replace(inp, cloud=dataclasses.replace(inp.cloud, points=pts,
                                                                 source=np.zeros(len(pts), np.int32)))
    runs = {}
    for name, (config, rule) in (SGM_VARIANTS if methods is None else methods).items():
        with _seed_rule(rule):
            runs[name] = run_sgm(inp, config)
    filled = predictions(inp, np.ones(inp.cloud.points.shape[0], bool), SGMConfig())
    runs.update({m: filled[m] for m in fills})
    print(f"twin methods: {time.time() - t0:.0f} s", flush=True)
    regions = [input_regions(sp) for sp in z_buffers(inp.cloud.points, inp.rig)]
    out = {"rig": "kitti", "sweeps_input": 1, "seed": seed, "scale": scale, "effects": effects,
           "footprint_mrad": footprint_mrad,
           "exact_dense": {m: devkit(d, exact) for m, d in runs.items()},
           "exact_dense_regions_mse": region_mse(exact, regions, runs), "gt_variants": {}}
    cache = {}
    for name, half, radius, tau in variants:
        if half not in cache:
            cache[half] = accumulated_points("kitti", seed, half, effects=effects, footprint_mrad=footprint_mrad,
                                             distort=distort)
        gt = kitti_style_gt(cache[half], inp.rig, exact, radius=radius, tau=tau)
        at_gt = [np.where(g > 0, e, 0.0).astype(np.float32) for g, e in zip(gt, exact)]
        # the referee's "image" is the exact depth: 100 log z (sky at 120 m), a clear edge = a step of 10 %
        per_cam = [referee(g, 100 * np.log(np.where(e > 0, np.maximum(e, 0.1), 120.0)), {m: d[i] for m, d in runs.items()},
                           min_peak=100 * math.log(1 + STEP_REL)) for i, (g, e) in enumerate(zip(gt, exact))]
        out["gt_variants"][name] = {
            "sweeps_each_side": half, "fattening_radius_px": radius, "tau_px": tau,
            "points": int(cache[half].shape[0]), "gt_vs_exact": gt_errors(gt, exact),
            "exact_at_gt_pixels": {m: devkit(d, at_gt) for m, d in runs.items()},
            "kitti_style_gt": {m: devkit(d, gt) for m, d in runs.items()},
            "exact_at_gt_regions_mse": region_mse(at_gt, regions, runs),
            "kitti_style_gt_regions_mse": region_mse(gt, regions, runs),
            "referee_exact_edges": pooled(per_cam)}
        row = out["gt_variants"][name]
        print(f"  {name}: {row['gt_vs_exact']}", flush=True)
        for m in runs:
            print(f"    {m:12s} exact {out['exact_dense'][m]['rmse']:8.1f} / {out['exact_dense'][m]['mae']:6.1f}  "
                  f"at-gt {row['exact_at_gt_pixels'][m]['rmse']:8.1f} / {row['exact_at_gt_pixels'][m]['mae']:6.1f}  "
                  f"gt {row['kitti_style_gt'][m]['rmse']:8.1f} / {row['kitti_style_gt'][m]['mae']:6.1f}", flush=True)
    return out


def main(argv=None) -> int:
    import json
    import pathlib
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", nargs="+", default=["real", "twin"], choices=["real", "twin", "band"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--json", default=str(RESULTS / "edge_truth.json"))
    parser.add_argument("--no-effects", action="store_true", help="twin: no range noise, dropouts or mixed returns")
    parser.add_argument("--variants", nargs="+", default=None, help="twin: only these GT variants (names)")
    parser.add_argument("--footprint-mrad", type=float, default=0.0,
                        help="twin: every LiDAR ray returns the nearest of itself and the rays this far to either side")
    args = parser.parse_args(argv)
    t0 = time.time()
    path = pathlib.Path(args.json)
    doc = json.loads(path.read_text()) if path.exists() else {}
    doc = {k: v for k, v in doc.items() if k not in ("config", "seconds", "environment")}
    doc["settings"] = {"window_px": WINDOW, "min_peak": MIN_PEAK, "step": [STEP_ABS_M, STEP_REL],
                       "gt_variants": [list(v) for v in GT_VARIANTS]}
    if "real" in args.part:
        doc["real_kitti"] = real_part()
        write_results(args.json, doc, SGMConfig(), t0)
    if "band" in args.part:
        doc[f"band_near_share_seed{args.seed}"] = band_part(args.seed, args.scale)
        print(doc[f"band_near_share_seed{args.seed}"])
        write_results(args.json, doc, SGMConfig(), t0)
    if "twin" in args.part:
        variants = [v for v in GT_VARIANTS if args.variants is None or v[0] in args.variants]
        key = (f"twin_kitti_seed{args.seed}" + ("_no_effects" if args.no_effects else "")
               + (f"_footprint{args.footprint_mrad:g}" if args.footprint_mrad else ""))
        new = twin_part(args.seed, args.scale, effects=not args.no_effects, variants=variants,
                        footprint_mrad=args.footprint_mrad)
        if key in doc:                                   # a run of other variants: keep the earlier ones
            new["gt_variants"] = {**doc[key]["gt_variants"], **new["gt_variants"]}
        doc[key] = new
        write_results(args.json, doc, SGMConfig(), t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
