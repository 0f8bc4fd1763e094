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
        d = np.diff(az)
        step = np.median(d)
        k = np.rint(d / step)
        same = _similar(r[:-1], r[1:], 0.05, 0.3)
        gap = (k >= 2) & (k <= 10) & same
        lost += int((k[gap] - 1).sum())
        kept += int(((k == 1) & same).sum())
        tight = (k[:-1] == 1) & (k[1:] == 1)
        a, m, c = r[:-2], r[1:-1], r[2:]
        edge = tight & ~_similar(a, c, 0.10, 1.0)
        lo, hi = np.minimum(a, c), np.maximum(a, c)
        mid = edge & (m > lo) & (m < hi) & ~_similar(m, lo, 0.03, 0.3) & ~_similar(m, hi, 0.03, 0.3)
        spans += int(edge.sum())
        between += int(mid.sum())
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
    hist, edges = np.histogram(p[band, 2], bins=np.arange(-4.0, 0.0, 0.05))
    z0 = edges[np.argmax(hist)] + 0.025
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
    return out


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
