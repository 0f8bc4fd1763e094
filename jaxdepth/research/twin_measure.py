"""What the digital twins take from the real sweeps and calibrations (host side, NumPy).

The twins (:mod:`jaxdepth.research.twins`) are built from numbers measured here on the shared
real data, stored in :mod:`jaxdepth.research.twin_tables` (written by :func:`tables_source`, so
a twin needs no data to build) and re-measured by the tests when the data is present:

- laser elevations: KITTI's HDL-64E from the beam groups of a real sweep
  (:func:`jaxdepth.research.sparsity.beam_model`, about its fitted cone apex), nuScenes' HDL-32E
  from the sweep's ring column, each Argoverse 2 VLP-32C per ``laser_number`` about that LiDAR's
  own origin and axes (``egovehicle_SE3_<lidar>``; ``down_lidar`` is upside down);
- calibrations: nuScenes' six cameras (``calibration.json``), Argoverse 2's LiDAR mounts and
  seven ring cameras (``calibration/*.feather``); KITTI's cameras 2 and 3 are the library's
  presets (:mod:`jaxdepth._src.presets`);
- sensor rates (range noise, dropouts, mixed returns): :func:`sensor_rates`, see its docstring
  for how each is measured and what it over- or under-counts.
"""

from __future__ import annotations

import glob
import json
import pathlib
from typing import NamedTuple

import numpy as np

from jaxdepth._src.presets import KITTI_HDL64
from jaxdepth.io import av2

#: Points nearer than this are left out of elevation medians (the lasers' own offsets show there), metres.
_MIN_RANGE_M = 2.0


def _elevation_deg(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, np.float64)
    return np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))


def _medians(el: np.ndarray, ring: np.ndarray, rng: np.ndarray, count: int) -> np.ndarray:
    out = np.full(count, np.nan)
    for b in range(count):
        sel = (ring == b) & (rng > _MIN_RANGE_M)
        if sel.any():
            out[b] = np.median(el[sel])
    return out


def kitti_sweep_lasers(bin_path) -> tuple[np.ndarray, np.ndarray, float]:
    """(ring (N,) int32, elevations (64,) deg top first, apex height m) of a KITTI HDL-64E sweep.

    Rings are :func:`~jaxdepth.research.sparsity.beam_model`'s groups; each elevation is the
    median about the fitted cone apex (``apex`` m above the LiDAR origin).
    """
    from jaxdepth.research.sparsity import beam_model

    p = np.fromfile(bin_path, np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
    model = beam_model(p, lidar=KITTI_HDL64)
    q = p - np.array([0.0, 0.0, model.apex_height_m])
    el = _medians(_elevation_deg(q), model.index, np.linalg.norm(q, axis=1), KITTI_HDL64.beams)
    return model.index, el, float(model.apex_height_m)


def nuscenes_sweep_lasers(pcd_path) -> tuple[np.ndarray, np.ndarray]:
    """(ring (N,) int32, elevations (32,) deg by ring index) of a nuScenes ``.pcd.bin`` sweep."""
    n = np.fromfile(pcd_path, np.float32).reshape(-1, 5)
    ring = n[:, 4].astype(np.int32)
    return ring, _medians(_elevation_deg(n[:, :3]), ring, np.linalg.norm(n[:, :3], axis=1), 32)


def av2_sweep_lasers(log_folder, timestamp_ns: int | None = None) -> dict:
    """Per LiDAR of an Argoverse 2 sweep: ``{name: (points in its own frame (n, 3), laser (n,), elevations (32,))}``.

    Each LiDAR's points (``laser_number // 32``) are moved into its own frame with
    ``inv(egovehicle_SE3_<lidar>)``; ``laser = laser_number mod 32``; each elevation is the median
    about that origin.
    """
    log = av2.read_log(log_folder)
    ts = log.sweeps[0] if timestamp_ns is None else int(timestamp_ns)
    xyz, laser = av2.read_sweep(log.sweep_path(ts))
    out = {}
    for j, (name, _) in enumerate(av2.LIDARS):
        T = np.linalg.inv(log.sensor_pose(name))
        keep = laser // av2.LASERS_PER_LIDAR == j
        q = xyz[keep].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        ring = laser[keep] % av2.LASERS_PER_LIDAR
        out[name] = (q, ring, _medians(_elevation_deg(q), ring, np.linalg.norm(q, axis=1), av2.LASERS_PER_LIDAR))
    return out


def av2_calibration(log_folder) -> dict:
    """``{"lidars": {name: (4, 4)}, "cameras": {name: (K (3, 3), width, height, egovehicle_SE3_cam (4, 4))}}``."""
    log = av2.read_log(log_folder)
    cams = {}
    for name in av2.RING_CAMERAS:
        K, w, h = log.intrinsics[name]
        cams[name] = (np.asarray(K, np.float64), int(w), int(h), log.sensor_pose(name))
    return {"lidars": {name: log.sensor_pose(name) for name, _ in av2.LIDARS}, "cameras": cams}


def nuscenes_calibration(path) -> dict:
    """``{name: (K (3, 3), T_cam_lidar (4, 4))}`` of the six cameras, plus ``"lidar2ego"`` (4, 4)."""
    doc = json.loads(pathlib.Path(path).read_text())
    out = {name: (np.asarray(c["cam2img"], np.float64)[:3, :3], np.asarray(c["lidar2cam"], np.float64))
           for name, c in doc["cameras"].items()}
    out["lidar2ego"] = np.asarray(doc["lidar2ego"], np.float64)
    return out


# ---------------------------------------------------------------- sensor rates


def ring_sequences(points: np.ndarray, ring: np.ndarray, *, min_points: int = 200):
    """Yields ``(azimuth (n,) rad ascending, range (n,) m, index (n,))`` of each ring's points, in
    scan order about the frame's origin (points in the LiDAR's own frame)."""
    p = np.asarray(points, np.float64)
    az = np.arctan2(p[:, 1], p[:, 0])
    rng = np.linalg.norm(p, axis=1)
    for b in np.unique(ring[ring >= 0]):
        idx = np.flatnonzero((ring == b) & (rng > 1.0))
        if idx.size < min_points:
            continue
        order = idx[np.argsort(az[idx], kind="stable")]
        yield az[order], rng[order], order


def _similar(a, b, rel, abs_m):
    return np.abs(a - b) <= np.maximum(abs_m, rel * np.minimum(a, b))


class _RingSteps(NamedTuple):
    k: np.ndarray        # (n - 1,) azimuth steps between consecutive returns
    same: np.ndarray     # (n - 1,) the two on one surface: within max(0.3 m, 5 %)
    lost: np.ndarray     # (n - 1,) returns lost in the gap (k - 1 where 2 <= k <= 10 and same, else 0)
    kept: np.ndarray     # (n - 1,) one step apart on one surface (a continuing stretch)
    tight: np.ndarray    # (n - 2,) the triple a, m, c one step apart each
    edge: np.ndarray     # (n - 2,) tight, ends differing by more than max(1 m, 10 %): a depth edge
    between: np.ndarray  # (n - 2,) edge, the middle strictly between, more than max(0.3 m, 3 %) from both


def _ring_steps(az: np.ndarray, r: np.ndarray) -> _RingSteps:
    """One ring's consecutive pairs and triples (:func:`ring_rates`' and :func:`near_statistics`' counts)."""
    k = np.rint(np.diff(az) / np.median(np.diff(az)))
    same = _similar(r[:-1], r[1:], 0.05, 0.3)
    gap = (k >= 2) & (k <= 10) & same
    tight = (k[:-1] == 1) & (k[1:] == 1)
    a, m, c = r[:-2], r[1:-1], r[2:]
    edge = tight & ~_similar(a, c, 0.10, 1.0)
    lo, hi = np.minimum(a, c), np.maximum(a, c)
    between = edge & (m > lo) & (m < hi) & ~_similar(m, lo, 0.03, 0.3) & ~_similar(m, hi, 0.03, 0.3)
    return _RingSteps(k, same, np.where(gap, k - 1, 0), (k == 1) & same, tight, edge, between)


def _ground_height(z: np.ndarray) -> tuple[float, int]:
    """The densest 0.05 m band of heights ``z`` between -4 and 0 m (the ground, z up): its centre (the lowest
    band's with no height there) and how many heights fell between -4 and 0 m."""
    hist, edges = np.histogram(z, bins=np.arange(-4.0, 0.0, 0.05))
    return edges[np.argmax(hist)] + 0.025, int(hist.sum())


def ring_rates(points: np.ndarray, ring: np.ndarray) -> dict:
    """Dropouts and mixed returns along the rings of one LiDAR's sweep (its own frame).

    - ``dropout``: along a ring, a gap of ``k`` azimuth steps (``k = round(gap / median step)``,
      2 <= k <= 10) between two returns on one surface (ranges within max(0.3 m, 5 %)) holds
      ``k - 1`` lost returns; the rate is lost / (lost + returns inside such continuing stretches).
      Counts only losses where the surface continues (not sky, not a window with nothing behind).
    - ``mixed_share``: triples of consecutive returns (no gap) whose ends differ by more than
      max(1 m, 10 %) span a depth edge; the share whose middle return lies strictly between the two
      layers, more than max(0.3 m, 3 %) from both. Sloped surfaces seen at grazing angles also
      count (an upper bound); :func:`jaxdepth.research.twins` is calibrated by measuring the same
      statistic on the twin.
    """
    lost = kept = spans = between = 0
    for az, r, _ in ring_sequences(points, ring):
        s = _ring_steps(az, r)
        lost += int(s.lost.sum())
        kept += int(s.kept.sum())
        spans += int(s.edge.sum())
        between += int(s.between.sum())
    return {"dropout": lost / max(1, lost + kept), "lost": lost, "continuing": kept,
            "mixed_share": between / max(1, spans), "edge_triples": spans}


def ground_noise(points_up: np.ndarray, origin: np.ndarray, *, cell_m: float = 1.0, near_m: float = 3.0,
                 far_m: float = 12.0) -> dict:
    """Range noise from planar ground patches: points in a z-up frame, ``origin`` (3,) the LiDAR there.

    Ground candidates: within 0.25 m of the lowest dense height band, ``near_m``-``far_m`` from the
    origin horizontally. Per ``cell_m`` cell with >= 15 points a least-squares plane; each point's
    residual is measured along its own ray (range minus the range at which the ray meets the
    plane); the rate is 1.4826 x the median absolute residual (robust to kerbs and objects). The
    cell's fit absorbs a little of the noise; road roughness and laser-to-laser range offsets count
    as noise (the SGM sees both).
    """
    p = np.asarray(points_up, np.float64) - origin
    horiz = np.hypot(p[:, 0], p[:, 1])
    band = (horiz > near_m) & (horiz < far_m)
    z0, _ = _ground_height(p[band, 2])
    g = p[band & (np.abs(p[:, 2] - z0) < 0.25)]
    cells = np.floor(g[:, :2] / cell_m).astype(np.int64)
    _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    residuals = []
    for c in np.flatnonzero(counts >= 15):
        q = g[inverse.ravel() == c]
        centre = q.mean(axis=0)
        normal = np.linalg.svd(q - centre)[2][-1]
        rng = np.linalg.norm(q, axis=1)
        cos = np.abs((q / rng[:, None]) @ normal)
        ok = cos > 0.05
        # The ray from the origin meets the plane at range (normal . centre) / (normal . ray).
        t = np.abs(centre @ normal) / cos[ok]
        residuals.append(rng[ok] - t)
    res = np.concatenate(residuals) if residuals else np.zeros(0)
    mad = float(np.median(np.abs(res - np.median(res)))) if res.size else float("nan")
    return {"noise_m": 1.4826 * mad, "points": int(res.size), "cells": len(residuals)}


# ---------------------------------------------------------------- scene statistics

#: Depth bins (m) of :func:`scene_statistics`: camera depth of the points, range of an edge's far side.
SCENE_DEPTH_BINS_M = (0.0, 5.0, 10.0, 20.0, 30.0, 40.0, 60.0, 80.0, np.inf)
SCENE_EDGE_BINS_M = (0.0, 10.0, 20.0, 40.0, np.inf)


def camera_depths(points: np.ndarray, K: np.ndarray, T_cam_lidar: np.ndarray, width: int, height: int) -> np.ndarray:
    """Camera-frame depth (m) of the points that project into the (width, height) image (z > 0.1 m)."""
    p = np.asarray(points, np.float64)
    T, K = np.asarray(T_cam_lidar, np.float64), np.asarray(K, np.float64)
    q = p @ T[:3, :3].T + T[:3, 3]
    ahead = q[:, 2] > 0.1
    uv = (q @ K.T)[:, :2] / np.where(ahead, q[:, 2], 1.0)[:, None]
    inside = ahead & (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
    return q[inside, 2]


def scene_statistics(points: np.ndarray, ring: np.ndarray, cameras) -> dict:
    """The far-structure statistics of one spinning LiDAR's sweep (its own frame) seen by ``cameras``
    (objects with ``name``, ``K``, ``T_cam_lidar``, ``width``, ``height``).

    - ``cameras``: per camera, the points projecting into it: ``count``, ``depth_share`` (the share per
      :data:`SCENE_DEPTH_BINS_M` bin of camera depth), ``share_ge_20m``, ``share_ge_40m``; ``all``: the same
      over every camera's points (a point seen by two cameras counts twice).
    - ``edges``: along each ring (:func:`ring_sequences`), consecutive returns one azimuth step apart
      (no gap: step < 1.5 x the ring's median) whose ranges differ by more than max(1 m, 5 % of the
      nearer): per :data:`SCENE_EDGE_BINS_M` bin of the farther return's range, ``per_line`` (edges
      per ring) and ``per_1000_pairs`` (edges per 1000 such neighbour pairs whose farther return lies
      in the bin); ``lines``: rings counted.
    - ``near``: :func:`near_statistics` (range noise, ground roughness, spikes, mixed returns and
      dropouts per near range band; nusc13).
    """
    out = {"cameras": {}}
    every = []
    for cam in cameras:
        z = camera_depths(points, cam.K, cam.T_cam_lidar, cam.width, cam.height)
        every.append(z)
        out["cameras"][cam.name] = _depth_shares(z)
    out["all"] = _depth_shares(np.concatenate(every))
    bins = np.asarray(SCENE_EDGE_BINS_M)
    edges = np.zeros(len(bins) - 1)
    pairs = np.zeros(len(bins) - 1)
    lines = 0
    for az, r, _ in ring_sequences(points, ring):
        lines += 1
        d = np.diff(az)
        tight = d < 1.5 * np.median(d)
        far = np.maximum(r[:-1], r[1:])
        edge = tight & ~_similar(r[:-1], r[1:], 0.05, 1.0)
        b = np.digitize(far, bins[1:-1])
        edges += np.bincount(b[edge], minlength=len(edges))
        pairs += np.bincount(b[tight], minlength=len(pairs))
    names = [f"{a:g}-{c:g}" for a, c in zip(bins, bins[1:])]
    out["edges"] = {"lines": lines,
                    "per_line": dict(zip(names, (edges / max(lines, 1)).tolist())),
                    "per_1000_pairs": dict(zip(names, (1000 * edges / np.maximum(pairs, 1)).tolist()))}
    out["near"] = near_statistics(points, ring)
    return out


#: Range bands (m) of :func:`near_statistics` (range about the LiDAR origin).
NEAR_BANDS_M = (0.0, 5.0, 10.0, 20.0)
#: Points nearer than this are counted apart (:func:`near_statistics`' ``within_ego_m``: the ego's body,
#: the sensor's housing, invalid returns), metres.
EGO_M = 2.0


def _spread(x: np.ndarray) -> float:
    """1.4826 x the median absolute deviation (a robust standard deviation), nan if empty."""
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if x.size else float("nan")


def near_statistics(points: np.ndarray, ring: np.ndarray) -> dict:
    """Near-range return statistics of one spinning LiDAR's sweep (its own frame, z up), per
    :data:`NEAR_BANDS_M` band of range about the origin. Along each ring (:func:`ring_sequences`, returns
    beyond 1 m; azimuth steps ``k = round(gap / the ring's median step)``), for consecutive triples
    ``a, m, c`` one step apart, binned by the middle return's range:

    - ``smooth``: triples whose ends agree within max(1 m, 10 %) (no depth edge); ``second_diff_m``: the
      robust spread (1.4826 MAD) of ``a - 2 m + c`` over them (range noise x sqrt(6) on a surface whose
      range changes linearly along the ring), ``second_diff_p90_m``: the 90th percentile of its magnitude
      (the tails: roughness, clutter);
    - the same on the ground (``ground_*``): all three within 0.2 m of the ground height (the densest
      0.05 m height band between -4 and 0 m of the points 3-12 m out horizontally, as :func:`ground_noise`);
    - ``spike_near_share`` / ``spike_far_share``: smooth triples whose middle is nearer / farther than
      both ends by more than max(1 m, 10 %) of the nearer (isolated returns: spray, thin clutter; holes);
    - ``edge_triples``, ``mixed_share``: triples whose ends differ by more than max(1 m, 10 %) and the
      share whose middle lies strictly between, more than max(0.3 m, 3 %) from both (:func:`ring_rates`);
    - ``dropout``: :func:`ring_rates`' dropout, each pair binned by its nearer return.

    Also ``points_share`` (the band's share of all points) and ``within_ego_m``: the share of all points
    nearer than :data:`EGO_M` (no scene surface is: the ego's body, housing or invalid returns).
    """
    p = np.asarray(points, np.float64)
    rng_all = np.linalg.norm(p, axis=1)
    horiz = np.hypot(p[:, 0], p[:, 1])
    band = (horiz > 3.0) & (horiz < 12.0)
    z0, heights = _ground_height(p[band, 2])
    z0 = z0 if heights else -np.inf
    ground_all = np.abs(p[:, 2] - z0) < 0.2
    bins = np.asarray(NEAR_BANDS_M)
    nb = len(bins) - 1
    acc = {k: [[] for _ in range(nb)] for k in ("sd", "gsd")}
    cnt = {k: np.zeros(nb) for k in ("smooth", "ground", "near", "far", "edge", "between", "lost", "kept")}

    def binned(r):
        b = np.digitize(r, bins) - 1
        return np.where((r >= bins[0]) & (r < bins[-1]), b, -1)

    for az, r, order in ring_sequences(p, ring):
        st = _ring_steps(az, r)
        pb = binned(np.minimum(r[:-1], r[1:]))
        for j in range(nb):
            cnt["lost"][j] += st.lost[pb == j].sum()
            cnt["kept"][j] += (st.kept & (pb == j)).sum()
        a, m, c = r[:-2], r[1:-1], r[2:]
        smooth, edge, between = st.tight & ~st.edge, st.edge, st.between
        lo, hi = np.minimum(a, c), np.maximum(a, c)
        near = smooth & (m < lo) & ~_similar(m, lo, 0.10, 1.0)
        far = smooth & (m > hi) & ~_similar(m, hi, 0.10, 1.0)
        g = ground_all[order]
        on_ground = smooth & g[:-2] & g[1:-1] & g[2:]
        sd = a - 2.0 * m + c
        mb = binned(m)
        for j in range(nb):
            sel = mb == j
            acc["sd"][j].append(sd[smooth & sel])
            acc["gsd"][j].append(sd[on_ground & sel])
            for key, mask in (("smooth", smooth), ("ground", on_ground), ("near", near), ("far", far),
                              ("edge", edge), ("between", between)):
                cnt[key][j] += (mask & sel).sum()
    out = {"within_ego_m": float(np.mean(rng_all < EGO_M)) if len(p) else 0.0, "ground_z_m": float(z0), "bands": {}}
    for j, (lo_m, hi_m) in enumerate(zip(bins, bins[1:])):
        sd, gsd = np.concatenate(acc["sd"][j]), np.concatenate(acc["gsd"][j])
        out["bands"][f"{lo_m:g}-{hi_m:g}"] = {
            "points_share": float(np.mean((rng_all >= lo_m) & (rng_all < hi_m))) if len(p) else 0.0,
            "smooth": int(cnt["smooth"][j]), "second_diff_m": _spread(sd),
            "second_diff_p90_m": float(np.percentile(np.abs(sd), 90)) if sd.size else float("nan"),
            "ground": int(cnt["ground"][j]), "ground_second_diff_m": _spread(gsd),
            "ground_second_diff_p90_m": float(np.percentile(np.abs(gsd), 90)) if gsd.size else float("nan"),
            "spike_near_share": float(cnt["near"][j] / max(cnt["smooth"][j], 1)),
            "spike_far_share": float(cnt["far"][j] / max(cnt["smooth"][j], 1)),
            "edge_triples": int(cnt["edge"][j]), "mixed_share": float(cnt["between"][j] / max(cnt["edge"][j], 1)),
            "dropout": float(cnt["lost"][j] / max(cnt["lost"][j] + cnt["kept"][j], 1))}
    return out


#: A near return this far (deg) in azimuth from its column is an invalid return, not the ego (:func:`ego_table`).
INVALID_DEG = 5.0
#: Lasers aimed below this (deg) see the road unless the ego hides it (:func:`ego_table`).
GROUND_LASER_DEG = -10.0


def ego_table(points: np.ndarray, ring: np.ndarray) -> dict:
    """``{ring: (azimuth (n,) rad ascending, range (n,) m, point (n, 3) m)}`` of every return of one spinning
    LiDAR's sweep (its own frame) **in firing order** (the file's order, as nuScenes stores it: one return per
    laser and column), for :func:`jaxdepth.research.twins.ego_returns` (which rays return the ego's body).

    A return's azimuth is its column's (the k-th return of its ring is in column k): the circular mean of
    the column's returns beyond :data:`EGO_M`, interpolated over columns without one. A return nearer than
    :data:`EGO_M` whose own azimuth lies more than :data:`INVALID_DEG` from its column's is an invalid return
    (stored at a fixed point near the sensor). On a laser aimed below :data:`GROUND_LASER_DEG` (the median
    elevation of its returns beyond :data:`EGO_M`) it stands for the ego too (the road would have echoed);
    on the others it means no echo (sky, a black surface), not the ego: its range is given as inf (the
    twin's ray then keeps what it hits).
    """
    p = np.asarray(points, np.float64)
    ring = np.asarray(ring)
    az, rng = np.arctan2(p[:, 1], p[:, 0]), np.linalg.norm(p, axis=1)
    col = np.zeros(len(p), np.int64)
    for b in np.unique(ring):
        sel = ring == b
        col[sel] = np.arange(int(sel.sum()))
    n = int(col.max()) + 1 if len(p) else 0
    ok = rng > EGO_M
    z = np.bincount(col[ok], np.cos(az[ok]), minlength=n) + 1j * np.bincount(col[ok], np.sin(az[ok]), minlength=n)
    has = np.abs(z) > 0
    k = np.arange(n)
    unwrapped = np.unwrap(np.angle(z[has]))
    col_az = np.angle(np.exp(1j * np.interp(k, k[has], unwrapped)))
    off = np.degrees(np.abs(np.angle(np.exp(1j * (az - col_az[col])))))
    low = np.isin(ring, [b for b, e in enumerate(_medians(_elevation_deg(p), ring, rng, int(ring.max()) + 1))
                         if e < GROUND_LASER_DEG])
    rng = np.where((rng < EGO_M) & (off > INVALID_DEG) & ~low, np.inf, rng)
    out = {}
    for b in np.unique(ring[ring >= 0]):
        sel = np.flatnonzero(ring == b)
        a = col_az[col[sel]]
        order = np.argsort(a, kind="stable")
        out[int(b)] = (a[order], rng[sel][order], p[sel][order])
    return out


def band_effects(near: dict, base):
    """``base`` (a :class:`~jaxdepth.research.twin_sensors.SensorEffects`) with range bands measured by
    :func:`near_statistics` (``near``, on a real sweep): per :data:`NEAR_BANDS_M` band the noise
    ``ground_second_diff_m / sqrt(6)`` (the second difference of three independent draws has sqrt(6)
    times their spread) and the band's ``dropout``; beyond the last band ``base``'s rates."""
    import dataclasses

    names = [f"{a:g}-{c:g}" for a, c in zip(NEAR_BANDS_M, NEAR_BANDS_M[1:])]
    b = [near["bands"][n] for n in names]
    return dataclasses.replace(base, band_upper_m=tuple(float(x) for x in NEAR_BANDS_M[1:]),
                               band_noise_m=tuple(round(float(x["ground_second_diff_m"]) / 6.0 ** 0.5, 5) for x in b),
                               band_dropout=tuple(round(float(x["dropout"]), 4) for x in b))


def _depth_shares(z: np.ndarray) -> dict:
    bins = np.asarray(SCENE_DEPTH_BINS_M)
    hist = np.histogram(z, bins)[0] / max(len(z), 1)
    return {"count": int(len(z)), "share_ge_20m": float(np.mean(z >= 20.0)) if len(z) else 0.0,
            "share_ge_40m": float(np.mean(z >= 40.0)) if len(z) else 0.0,
            "depth_share": {f"{a:g}-{c:g}": float(h) for a, c, h in zip(bins, bins[1:], hist)}}


def _fmt(a) -> str:
    a = np.asarray(a, np.float64)
    if a.ndim == 1:
        return "(" + ", ".join(f"{x:.6g}" for x in a) + ("," if a.size == 1 else "") + ")"
    return "(" + ", ".join(_fmt(row) for row in a) + ")"


def _laser_tables(data) -> list:
    _, k_el, apex = kitti_sweep_lasers(data / "kitti" / "drive_0001_frame05" / "lidar_data.bin")
    _, n_el = nuscenes_sweep_lasers(glob.glob(str(data / "nuscenes" / "sample" / "*LIDAR_TOP*.pcd.bin"))[0])
    a = av2_sweep_lasers(data / "av2" / "sensor" / "val" / AV2_LOG)
    return [
        "#: KITTI HDL-64E laser elevations (deg, top first) about the cone apex, and the apex height (m).",
        f"KITTI_ELEVATIONS_DEG = {_fmt(np.round(k_el, 3))}",
        f"KITTI_APEX_M = {apex:.3f}",
        "#: nuScenes HDL-32E laser elevations (deg) by the sweep's ring index.",
        f"NUSCENES_ELEVATIONS_DEG = {_fmt(np.round(n_el, 3))}",
        "#: Argoverse 2 VLP-32C laser elevations (deg) by laser_number mod 32, about each LiDAR's own origin.",
        "AV2_ELEVATIONS_DEG = {" + ", ".join(f"{json.dumps(k)}: {_fmt(np.round(v[2], 3))}" for k, v in a.items()) + "}",
    ]


def _calibration_tables(data) -> list:
    nus = nuscenes_calibration(data / "nuscenes" / "sample" / "calibration.json")
    cal = av2_calibration(data / "av2" / "sensor" / "val" / AV2_LOG)
    lines = ["#: nuScenes cameras: name -> (K, T_cam_lidar) (calibration.json); the LiDAR's pose in the ego frame.",
             "NUSCENES_CAMERAS = {"]
    lines += [f"    {json.dumps(n)}: ({_fmt(v[0])},\n        {_fmt(v[1])})," for n, v in nus.items() if n != "lidar2ego"]
    lines += ["}", f"NUSCENES_LIDAR2EGO = {_fmt(nus['lidar2ego'])}",
              "#: Argoverse 2 LiDAR mounts (egovehicle_SE3_<lidar>).", "AV2_LIDARS = {"]
    lines += [f"    {json.dumps(n)}: {_fmt(T)}," for n, T in cal["lidars"].items()]
    lines += ["}", "#: Argoverse 2 ring cameras: name -> (K, width, height, egovehicle_SE3_camera).",
              "AV2_CAMERAS = {"]
    lines += [f"    {json.dumps(n)}: ({_fmt(K)}, {w}, {h},\n        {_fmt(T)})," for n, (K, w, h, T) in cal["cameras"].items()]
    return lines + ["}"]


#: The shared Argoverse 2 log.
AV2_LOG = "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"


def tables_source(data, effects: dict) -> str:
    """The text of :mod:`jaxdepth.research.twin_tables`, measured from the shared data folder ``data``,
    with ``effects`` (rig -> {"noise_m", "dropout", "mixed"}) from ``benchmarks/studies/twin_sensor_rates.py``."""
    data = pathlib.Path(data)
    head = ['"""Numbers the digital twins take from the real data (written by',
            "``python -m benchmarks.studies.twin_sensor_rates --write-tables``; do not edit by hand).",
            "",
            "Measured from ../shared/data (KITTI drive_0001 frame 5, the nuScenes sample, the Argoverse 2",
            'log); the tests re-measure the tables when the data is present."""', ""]
    rates = ["#: Sensor effects per twin (benchmarks/results/twin_sensor_rates.json; docs/twins.md says where",
             "#: each comes from).", "SENSOR_EFFECTS = {"]
    rates += [f"    {json.dumps(rig)}: {{" + ", ".join(f"{json.dumps(k)}: {float(v):.4g}" for k, v in e.items()) + "},"
              for rig, e in effects.items()]
    return "\n".join(head + _laser_tables(data) + _calibration_tables(data) + rates + ["}"]) + "\n"
