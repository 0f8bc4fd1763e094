"""Why the twins and real data disagree at depth edges: what the twins' input leaves out (issue 37).

    PYTHONPATH=. python -m benchmarks.studies.edge_input [--part real twin exact] [--cases NAME ...]
        [--seed 0] [--scale 1] [--rig nuscenes] [size options] [--json benchmarks/results/edge_input.json]

Candidates the twins do not model, each a :class:`Distortion` of what the LiDAR reports (a function of
the true point in the unit's frame, x forward, y left, z up, and / or the scan pattern cast), applied to
every sweep the study casts (the input sweep and the KITTI-style GT's sweeps of
:mod:`benchmarks.studies.edge_truth` alike, as the real GT is built from the same scans). Cases:

- ``extrinsic``: a LiDAR-camera calibration error, a small rotation (``--yaw-mrad``, ``--pitch-mrad``);
- ``time_offset``: the LiDAR's sweep ``--time-offset-ms`` later than the camera's exposure, the ego moving
  at the twin's speed and yaw rate (the movers are not moved);
- ``sweep_motion``: motion within the sweep: a spinning LiDAR turning clockwise seen from above reaches
  azimuth ``phi`` at ``t = -phi / (2 pi / T)`` (T the sweep period; the camera fires when it faces
  forward), and reports the point in its frame at that time (KITTI's points are not motion-compensated);
- ``laser_phase``: each laser samples at its own azimuth phase (the twins' lasers share one;
  :func:`jaxdepth.research.twin_sensors.stagger_lasers`), the scan recast;
- ``laser_azimuth`` / ``azimuth_jitter``: a per-laser / per-return azimuth offset, N(0, sigma) (fixed seeds);
- ``footprint``: the nearest return over +-``--footprint-az-mrad`` along and +-``--footprint-el-mrad`` across
  the scan (a beam's divergence); ``measured``: extrinsic, sweep motion and laser phases together;
  ``phase_footprint``: laser phases and footprint together; ``none``: the twin as it is.

Sizes, from the real shared data where it can say (``--part real``):

- KITTI: the official sparse input against the raw scan projected with the raw calibration
  (:func:`raw_vs_official`: mean pixel displacement by depth and image column); the same depth edge on
  neighbouring rings of the raw scans (:func:`kitti_ring_jitter`); the city-block fill's reach past the
  official GT's steps (:func:`overhang`);
- every real LiDAR's per-laser sampling phases (:func:`real_laser_phases`: KITTI, nuScenes, Argoverse 2);
- nuScenes: the six camera timestamps against the LiDAR's (file names) and the cameras' yaws
  (:func:`nuscenes_sync`: the sweep period and each camera's residual offset from the moment the
  spinning LiDAR faces it);
- Argoverse 2: the per-point ``offset_ns`` of the two sweeps (the sweep's duration).

Per case (``--part twin``): the KITTI twin (1 sweep) with that distortion, scored as
:func:`benchmarks.studies.edge_truth.twin_part` (exact depth of every pixel, KITTI-style GT r = 0, 1) for
the side rules (default, near ``d z^0.5``, far ``d z^-0.5``, ``above:far``) and the city-block fill, plus the
fill's reach past the KITTI-style GT's steps (:func:`overhang`) and the ring-to-ring edge spread of the
input. ``--part exact``: any twin (``--rig``) with a case, the same methods against its exact depth only.
Nothing is tuned on a real set; no library default changes.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import pathlib
import time

import numpy as np

from benchmarks._common import RESULTS, write_results
from benchmarks.studies import edge_truth as et
from jaxdepth._src.config import SGMConfig

NUSCENES = pathlib.Path(__file__).resolve().parents[3] / "shared" / "data" / "nuscenes" / "sample"
AV2_LOG = (pathlib.Path(__file__).resolve().parents[3] / "shared" / "data" / "av2" / "sensor" / "val"
           / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede")
METHODS = {"sgm": (SGMConfig(), None), "near_g0.5": (SGMConfig(), "metric_g0.5"),
           "far_g-0.5": (SGMConfig(), "metric_g-0.5"), "above_far": (SGMConfig(), "above:metric_g-0.5")}
VARIANTS = tuple(v for v in et.GT_VARIANTS if v[0] in ("acc11_stereo_r0_t3", "acc11_stereo_r1_t3"))


# ------------------------------------------------------------------ distortions (pure NumPy)

@dataclasses.dataclass(frozen=True)
class Distortion:
    """What :func:`benchmarks.studies.edge_truth.accumulated_points` changes: ``unit`` (None, or ``Unit -> Unit``,
    the scan pattern cast) and ``points`` (None, or ``f(points (n, 3) unit frame, ring (n,), rdef) -> (n, 3)``)."""
    points: object = None
    unit: object = None
    footprint_el_mrad: float = 0.0


def _rot(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """(3, 3) rotation about z (yaw), then y (pitch), then x (roll), radians."""
    cz, sz, cy, sy, cx, sx = (f(a) for a in (yaw, pitch, roll) for f in (math.cos, math.sin))
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1.0]])
    Ry = np.array([[cy, 0, sy], [0, 1.0, 0], [-sy, 0, cy]])
    Rx = np.array([[1.0, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return Rz @ Ry @ Rx


def ego_at(points: np.ndarray, t: np.ndarray, *, speed: float, yaw_rate: float) -> np.ndarray:
    """(n, 3) ``points`` (true, in the sensor frame at time 0) as reported from the sensor frame at times
    ``t`` (n,) s, the ego moving forward at ``speed`` m/s and turning left at ``yaw_rate`` rad/s."""
    a = -yaw_rate * t
    x, y = points[:, 0] - speed * t, points[:, 1]
    return np.stack([np.cos(a) * x - np.sin(a) * y, np.sin(a) * x + np.cos(a) * y, points[:, 2]], axis=1)


def extrinsic(*, yaw_mrad: float = 0.0, pitch_mrad: float = 0.0, roll_mrad: float = 0.0, t_m=(0.0, 0.0, 0.0)):
    R = _rot(yaw_mrad * 1e-3, pitch_mrad * 1e-3, roll_mrad * 1e-3)
    return Distortion(points=lambda p, ring, rdef: p @ R.T + np.asarray(t_m))


def time_offset(*, ms: float):
    def f(p, ring, rdef):
        return ego_at(p, np.full(len(p), ms * 1e-3), speed=rdef.step_m / rdef.dt_s,
                      yaw_rate=math.radians(rdef.yaw_deg) / rdef.dt_s)
    return Distortion(points=f)


def sweep_motion(*, scale: float = 1.0):
    def f(p, ring, rdef):
        t = -np.arctan2(p[:, 1], p[:, 0]) / (2 * math.pi) * rdef.dt_s * scale
        return ego_at(p, t, speed=rdef.step_m / rdef.dt_s, yaw_rate=math.radians(rdef.yaw_deg) / rdef.dt_s)
    return Distortion(points=f)


def azimuth_jitter(*, sigma_mrad: float, seed: int = 0):
    """Each return's azimuth off by its own N(0, sigma) draw (fixed seed, in the order of the returns)."""
    def f(p, ring, rdef):
        d = np.random.default_rng([seed, 38, len(p)]).normal(0.0, sigma_mrad * 1e-3, len(p))
        c, s = np.cos(d), np.sin(d)
        return np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1], p[:, 2]], axis=1)
    return Distortion(points=f)


def laser_azimuth(*, sigma_mrad: float, seed: int = 0):
    def f(p, ring, rdef):
        d = np.random.default_rng([seed, 37]).normal(0.0, sigma_mrad * 1e-3, int(ring.max()) + 1)[ring]
        c, s = np.cos(d), np.sin(d)
        return np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1], p[:, 2]], axis=1)
    return Distortion(points=f)


def laser_phase(*, seed: int = 0):
    """Each laser samples at its own azimuth phase (:func:`jaxdepth.research.twin_sensors.stagger_lasers`, as
    measured by :func:`real_laser_phases`; the twins' lasers share one): the scan recast."""
    from jaxdepth.research.twin_sensors import stagger_lasers
    return Distortion(unit=lambda u: stagger_lasers(u, seed=seed))


# ------------------------------------------------------------------ referee-free overhang

def overhang(depth: np.ndarray, truth: np.ndarray) -> dict:
    """How far ``depth``'s foreground reaches past ``truth``'s steps (:func:`edge_truth.side_boundary`, px;
    positive: past the step), at every step of ``truth`` along rows and along columns, by the side the
    foreground is on (``first``: left / above the far pixel), with the pooled mean."""
    out, allv = {}, []
    for axis, tr in (("rows", lambda a: a), ("cols", lambda a: np.swapaxes(a, 0, 1))):
        r, near, s, gap, zn, zf = et.steps(tr(truth))
        b = et.side_boundary(tr(depth), r, near, s, gap, 0.5 * (zn + zf))
        allv.append(b)
        for side, sel in (("first", s > 0), ("second", s < 0)):
            out[f"{axis}_{side}"] = {"steps": int(sel.sum()), "mean_px": float(b[sel].mean()) if sel.any() else None}
    b = np.concatenate(allv)
    out["all"] = {"steps": int(len(b)), "mean_px": float(b.mean()), "se_px": float(b.std() / math.sqrt(max(len(b), 1)))}
    return out


def pool_overhang(rows: list) -> dict:
    out = {}
    for k in rows[0]:
        n = sum(r[k]["steps"] for r in rows)
        out[k] = {"steps": n, "mean_px": sum((r[k]["mean_px"] or 0) * r[k]["steps"] for r in rows) / max(n, 1)}
    return out


# ------------------------------------------------------------------ real data

def raw_vs_official(frames: dict) -> dict:
    """Per camera: each official input pixel against the raw scan's point projected with the raw calibration
    that lies within 3 px and nearest in depth (kept within 0.5 % + 1 cm): mean (du, dv) = official - raw, px,
    by depth band and by image column band."""
    from scipy.spatial import cKDTree

    from benchmarks._common import FRAME
    raw = np.fromfile(FRAME / "lidar_data.bin", np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
    out = {}
    for cam, (sp, _, K, T) in frames.items():
        pc = raw @ T[:3, :3].T + T[:3, 3]
        pc = pc[pc[:, 2] > 0.5]
        uvw = pc @ K.T
        u, v, z = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2], pc[:, 2]
        rr, cc = np.nonzero(sp > 0)
        d, idx = cKDTree(np.c_[u, v]).query(np.c_[cc, rr], k=8, distance_upper_bound=3.0)
        ok = np.isfinite(d)
        ii = np.where(ok, idx, 0)
        dz = np.where(ok, np.abs(z[ii] - sp[rr, cc][:, None]), np.inf)
        j = np.argmin(dz, axis=1)
        best, bd = ii[np.arange(len(rr)), j], dz[np.arange(len(rr)), j]
        m = bd < 0.005 * sp[rr, cc] + 0.01
        du, dv, zz, uc = cc[m] - u[best[m]], rr[m] - v[best[m]], sp[rr[m], cc[m]], u[best[m]] - K[0, 2]
        row = {"pixels": int(len(rr)), "matched": int(m.sum()), "du": float(du.mean()), "dv": float(dv.mean())}
        for lo, hi in ((0, 10), (10, 20), (20, 40), (40, 200)):
            s = (zz >= lo) & (zz < hi)
            row[f"z_{lo}_{hi}m"] = {"n": int(s.sum()), "du": float(du[s].mean()), "dv": float(dv[s].mean())}
        for lo, hi in ((-700, -300), (-300, -100), (-100, 100), (100, 300), (300, 700)):
            s = (uc >= lo) & (uc < hi)
            row[f"u_minus_cx_{lo}_{hi}"] = {"n": int(s.sum()), "du": float(du[s].mean()), "dv": float(dv[s].mean())}
        out[cam] = row
    return out


def ring_edges(points: np.ndarray, *, fov_deg: float = 45.0, max_range_m: float = 40.0) -> np.ndarray:
    """(n, 4) depth steps along the HDL-64E's rings of a KITTI scan (LiDAR frame): (ring, azimuth rad of the
    step's middle, +-1 range up / down with azimuth, near range m). A point's ring is the nearest of the twin's
    measured elevations (about the cone apex); a step: azimuth neighbours < 0.3 deg apart whose ranges differ
    by more than max(1 m, 10 %), the nearer within ``max_range_m``, azimuth within +-``fov_deg`` (the cameras)."""
    from jaxdepth.research import twin_tables as tt
    el_table = np.radians(np.asarray(tt.KITTI_ELEVATIONS_DEG))
    rho = np.hypot(points[:, 0], points[:, 1])
    ring = np.argmin(np.abs(np.arctan2(points[:, 2] - tt.KITTI_APEX_M, rho)[:, None] - el_table[None, :]), axis=1)
    az, rng = np.arctan2(points[:, 1], points[:, 0]), np.linalg.norm(points, axis=1)
    out = []
    for k in range(len(el_table)):
        m = (ring == k) & (np.abs(az) < math.radians(fov_deg))
        o = np.argsort(az[m])
        a, r = az[m][o], rng[m][o]
        lo = np.minimum(r[1:], r[:-1])
        i = np.flatnonzero((np.diff(a) < math.radians(0.3)) & (np.abs(np.diff(r)) > np.maximum(et.STEP_ABS_M, et.STEP_REL * lo))
                           & (lo < max_range_m))
        out.append(np.c_[np.full(len(i), k), 0.5 * (a[i] + a[i + 1]), np.sign(r[i + 1] - r[i]), lo[i]])
    return np.concatenate(out)


def ring_jitter(points: np.ndarray) -> dict:
    """How far apart (mrad) the same depth edge lies on consecutive rings: each step of :func:`ring_edges` and the
    next ring's nearest step of the same sign within 0.5 deg and 10 % range; their azimuth differences' standard
    deviation, robust sigma (1.4826 MAD) and the share of their variance that the ring pair's mean explains
    (a per-laser constant offset) rather than the spread within a pair (a per-return one)."""
    e = ring_edges(points)
    d, pair = [], []
    for k in np.unique(e[:, 0])[:-1]:
        A, B = e[e[:, 0] == k], e[e[:, 0] == k + 1]
        for row in A:
            m = (B[:, 2] == row[2]) & (np.abs(B[:, 1] - row[1]) < math.radians(0.5)) & (np.abs(B[:, 3] - row[3]) < 0.1 * row[3])
            if m.any():
                d.append((B[m][np.argmin(np.abs(B[m, 1] - row[1])), 1] - row[1]) * 1e3)
                pair.append(k)
    d, pair = np.asarray(d), np.asarray(pair)
    within = np.concatenate([d[pair == k] - d[pair == k].mean() for k in np.unique(pair)]) if len(d) else d
    return {"steps": int(len(e)), "pairs": int(len(d)), "std_mrad": float(d.std()),
            "robust_sigma_mrad": float(1.4826 * np.median(np.abs(d - np.median(d)))),
            "within_pair_var_share": float(within.var() / max(d.var(), 1e-12)), "_diffs": d, "_pair": pair}


def kitti_ring_jitter() -> dict:
    """:func:`ring_jitter` of the two real KITTI raw scans, apart and pooled (ring-pair means over both)."""
    from benchmarks._common import FRAME
    out, ds, ps = {}, [], []
    for name, path in (("drive_0001_frame05", FRAME / "lidar_data.bin"),
                       ("raw_2011_09_26_scene2", FRAME.parent / "raw_2011_09_26_scene2" / "lidar_data.bin")):
        j = ring_jitter(np.fromfile(path, np.float32).reshape(-1, 4)[:, :3].astype(np.float64))
        ds.append(j.pop("_diffs"))
        ps.append(j.pop("_pair"))
        out[name] = j
    d, pair = np.concatenate(ds), np.concatenate(ps)
    within = np.concatenate([d[pair == k] - d[pair == k].mean() for k in np.unique(pair)])
    out["pooled"] = {"pairs": int(len(d)), "var_mrad2": float(d.var()), "within_pair_var_mrad2": float(within.var())}
    return out


def laser_phases(points: np.ndarray, ring: np.ndarray) -> dict:
    """Each ring's sampling phase in columns (-0.5..0.5: the circular mean of azimuth / step, the step the ring's
    median azimuth step) of one real sweep ((n, 3) points about the LiDAR, (n,) ring), the median step, mrad, and
    the phases' resultant length (1: every laser samples at one phase, as the twins' do; about 1 / sqrt(rings)
    when they are spread uniformly over a column)."""
    az = np.arctan2(points[:, 1], points[:, 0])
    far = np.linalg.norm(points, axis=1) > 5
    phases, spacing = [], []
    for k in np.unique(ring):
        a = np.sort(az[(ring == k) & far])
        if len(a) < 200:
            continue
        d = np.diff(a)
        step = float(np.median(d[d > 0.5 * np.median(d)]))
        spacing.append(step)
        phases.append(float(np.angle(np.mean(np.exp(2j * np.pi * a / step))) / (2 * np.pi)))
    ph = np.asarray(phases)
    return {"rings": len(ph), "median_step_mrad": float(np.median(spacing) * 1e3), "phases": [round(x, 3) for x in ph],
            "resultant": float(np.abs(np.mean(np.exp(2j * np.pi * ph)))), "uniform_expected": 1 / math.sqrt(len(ph))}


def real_laser_phases() -> dict:
    """:func:`laser_phases` of KITTI's raw scan (rings from the elevations, as :func:`ring_edges`), the nuScenes
    sweep (its ring column) and each Argoverse 2 LiDAR (laser_number; about each LiDAR's origin)."""
    import pyarrow.feather as feather

    from benchmarks._common import FRAME
    from jaxdepth.research import twin_tables as tt
    p = np.fromfile(FRAME / "lidar_data.bin", np.float32).reshape(-1, 4)[:, :3].astype(np.float64)
    el_table = np.radians(np.asarray(tt.KITTI_ELEVATIONS_DEG))
    ring = np.argmin(np.abs(np.arctan2(p[:, 2] - tt.KITTI_APEX_M, np.hypot(p[:, 0], p[:, 1]))[:, None]
                            - el_table[None, :]), axis=1)
    out = {"kitti": laser_phases(p, ring)}
    nu = np.fromfile(next(NUSCENES.glob("*__LIDAR_TOP__*")), np.float32).reshape(-1, 5)
    out["nuscenes"] = laser_phases(nu[:, :3].astype(np.float64), nu[:, 4].astype(int))
    t = feather.read_table(sorted((AV2_LOG / "sensors" / "lidar").glob("*.feather"))[0]).to_pandas()
    xyz, laser = t[["x", "y", "z"]].to_numpy(np.float64), t["laser_number"].to_numpy().astype(int)
    for name, origin, sel in (("av2_up_lidar", (1.35, 0.0, 1.64), laser < 32), ("av2_down_lidar", (1.35, 0.0, 1.53), laser >= 32)):
        out[name] = laser_phases(xyz[sel] - np.asarray(origin), laser[sel])
    return out


def nuscenes_sync() -> dict:
    """Camera minus LiDAR timestamps (file names) against each camera's yaw in the LiDAR frame: a least-squares
    line t = t0 - yaw / omega (a clockwise spin) gives the sweep period 2 pi / omega and each camera's residual."""
    calib = json.loads((NUSCENES / "calibration.json").read_text())
    t_lidar = int(next(NUSCENES.glob("*__LIDAR_TOP__*")).name.split("__")[2].split(".")[0])
    rows = {}
    for name, c in calib["cameras"].items():
        t = int(next(NUSCENES.glob(f"*__{name}__*")).name.split("__")[2].split(".")[0])
        T = np.asarray(c["lidar2cam"], np.float64)
        axis = np.linalg.inv(T)[:3, 2]                      # the camera's optical axis in the LiDAR frame
        rows[name] = {"dt_ms": (t - t_lidar) / 1e3, "yaw_deg": math.degrees(math.atan2(axis[1], axis[0]))}
    names = list(rows)
    yaw = np.unwrap(np.radians([rows[n]["yaw_deg"] for n in names]))
    order = np.argsort(-np.array([rows[n]["dt_ms"] for n in names]))
    yaw = np.radians([rows[n]["yaw_deg"] for n in names])
    # unwrap along the firing order (latest first going back in time: yaw grows as time goes back)
    y_sorted = np.unwrap(yaw[order])
    t_sorted = np.array([rows[names[i]]["dt_ms"] for i in order])
    A = np.c_[np.ones(len(order)), y_sorted]
    coef, *_ = np.linalg.lstsq(A, t_sorted, rcond=None)
    res = t_sorted - A @ coef
    for k, i in enumerate(order):
        rows[names[i]]["residual_ms"] = float(res[k])
    return {"cameras": rows, "ms_per_rad": float(coef[1]), "period_ms": float(abs(coef[1]) * 2 * math.pi),
            "residual_rms_ms": float(np.sqrt(np.mean(res ** 2)))}


def av2_sweep_times() -> dict:
    """Per sweep: the span of the points' ``offset_ns`` (ms) and its correlation with azimuth."""
    import pyarrow.feather as feather
    out = {}
    for f in sorted((AV2_LOG / "sensors" / "lidar").glob("*.feather")):
        t = feather.read_table(f).to_pandas()
        off = t["offset_ns"].to_numpy() / 1e6
        out[f.name] = {"points": int(len(t)), "offset_ms_min": float(off.min()), "offset_ms_max": float(off.max())}
    return out


def real_part() -> dict:
    from benchmarks._common import load_frames
    frames = load_frames()
    import jaxdepth
    plain = SGMConfig(outlier_removal=False)
    nearest = {c: np.asarray(jaxdepth.complete_with(s, K, T, method="nearest", config=plain))
               for c, (s, _, K, T) in frames.items()}
    return {"kitti_raw_vs_official": raw_vs_official(frames),
            "kitti_ring_jitter": kitti_ring_jitter(), "laser_phases": real_laser_phases(),
            "kitti_fill_overhang_at_gt_steps": pool_overhang([overhang(nearest[c], frames[c][1]) for c in frames]),
            "nuscenes_sync": nuscenes_sync(), "av2_sweep_times": av2_sweep_times()}


# ------------------------------------------------------------------ the twin with each candidate

def case_distortion(name: str, sizes: dict):
    """The distortion of case ``name`` at the measured ``sizes`` (see ``main``)."""
    if name == "none":
        return None
    if name == "extrinsic":
        return extrinsic(yaw_mrad=sizes["yaw_mrad"], pitch_mrad=sizes["pitch_mrad"])
    if name == "time_offset":
        return time_offset(ms=sizes["time_offset_ms"])
    if name == "sweep_motion":
        return sweep_motion()
    if name == "laser_azimuth":
        return laser_azimuth(sigma_mrad=sizes["laser_sigma_mrad"])
    if name == "azimuth_jitter":
        return azimuth_jitter(sigma_mrad=sizes["jitter_sigma_mrad"])
    if name == "laser_phase":
        return laser_phase()
    if name == "footprint":            # half the beam's divergence to either side, across and along the scan
        return Distortion(footprint_el_mrad=sizes["footprint_el_mrad"])
    if name == "phase_footprint":      # the measured laser phases and the published footprint together
        return Distortion(unit=laser_phase().unit, footprint_el_mrad=sizes["footprint_el_mrad"])
    if name == "measured":             # every candidate at its measured size at once
        parts = [extrinsic(yaw_mrad=sizes["yaw_mrad"], pitch_mrad=sizes["pitch_mrad"]).points, sweep_motion().points]
        return Distortion(points=lambda p, ring, rdef: parts[1](parts[0](p, ring, rdef), ring, rdef),
                          unit=laser_phase().unit)
    raise ValueError(name)


def twin_case(name: str, sizes: dict, seed: int, scale: float) -> dict:
    from benchmarks.accuracy_twins import z_buffers
    from benchmarks.studies.edge_side import twin_input
    distort = case_distortion(name, sizes)
    fp = sizes["footprint_az_mrad"] if "footprint" in name else 0.0
    res = et.twin_part(seed, scale, variants=VARIANTS, distort=distort, methods=METHODS, fills=("nearest",),
                       footprint_mrad=fp)
    inp, exact = twin_input("kitti", 1, seed, scale)
    pts = et.accumulated_points("kitti", seed, 0, ks=[0], distort=distort, footprint_mrad=fp)
    fill = _fill(pts, inp)
    cache = et.accumulated_points("kitti", seed, 5, distort=distort, footprint_mrad=fp)
    res["fill_overhang"] = {}
    for vname, _, radius, tau in VARIANTS:
        gt = et.kitti_style_gt(cache, inp.rig, exact, radius=radius, tau=tau)
        res["fill_overhang"][vname] = pool_overhang([overhang(f, g) for f, g in zip(fill, gt)])
    res["input_px"] = int(sum((s > 0).sum() for s in z_buffers(pts, inp.rig)))
    res["ring_jitter"] = {k: v for k, v in ring_jitter(pts.astype(np.float64)).items() if not k.startswith("_")}
    return res


def exact_case(rig: str, name: str, sizes: dict, seed: int, scale: float) -> dict:
    """Any twin (1 sweep) recast with case ``name``'s distortion: the side rules and the city-block fill against
    the exact depth of every pixel (the input sweep recast even for ``none``: the same draws as ``make_twin``)."""
    from benchmarks.studies.edge_side import run_sgm, twin_input
    distort = case_distortion(name, sizes)
    fp = sizes["footprint_az_mrad"] if "footprint" in name else 0.0
    inp, exact = twin_input(rig, 1, seed, scale)
    pts, ring = et.accumulated_points(rig, seed, 0, ks=[0], distort=distort, footprint_mrad=fp, with_ring=True)
    assert len(inp.cloud.T_ref_source) == 1
    same = bool(np.array_equal(pts, inp.cloud.points))            # True for ``none``: the recast is the twin's input
    inp = dataclasses.replace(inp, cloud=dataclasses.replace(
        inp.cloud, points=pts, source=np.zeros(len(pts), np.int32), ring=None if inp.cloud.ring is None else ring))
    runs = {}
    for m, (config, rule) in METHODS.items():
        with et._seed_rule(rule):
            runs[m] = run_sgm(inp, config)
    runs["nearest"] = _fill(pts, inp)
    out = {"rig": rig, "seed": seed, "scale": scale, "sizes": sizes, "input_points": int(len(pts)), "recast_is_twin_input": same,
           "exact_dense": {m: et.devkit(d, exact) for m, d in runs.items()}}
    print(rig, name, {m: (round(v["rmse"], 1), round(v["mae"], 1)) for m, v in out["exact_dense"].items()}, flush=True)
    return out


def _fill(points, inp) -> list:
    """The city-block fill of each camera from ``points`` (as ``accuracy_twins.predictions``)."""
    import jaxdepth
    from benchmarks.accuracy_twins import z_buffers
    plain = SGMConfig(outlier_removal=False)
    return [np.asarray(jaxdepth.complete_with(s, c.K, c.T_cam_lidar, method="nearest", config=plain,
                                              lidar=inp.rig.lidar)) for s, c in zip(z_buffers(points, inp.rig), inp.rig.cameras)]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", nargs="+", default=["real", "twin"], choices=["real", "twin", "exact"])
    parser.add_argument("--rig", default="nuscenes", help="--part exact: the twin")
    parser.add_argument("--cases", nargs="+", default=["none", "extrinsic", "time_offset", "sweep_motion",
                                                       "laser_azimuth"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--yaw-mrad", type=float, default=0.0)
    parser.add_argument("--pitch-mrad", type=float, default=0.0)
    parser.add_argument("--time-offset-ms", type=float, default=0.0)
    parser.add_argument("--laser-sigma-mrad", type=float, default=0.0)
    parser.add_argument("--jitter-sigma-mrad", type=float, default=0.0)
    parser.add_argument("--footprint-el-mrad", type=float, default=0.0)
    parser.add_argument("--footprint-az-mrad", type=float, default=0.0)
    parser.add_argument("--json", default=str(RESULTS / "edge_input.json"))
    args = parser.parse_args(argv)
    t0 = time.time()
    path = pathlib.Path(args.json)
    doc = json.loads(path.read_text()) if path.exists() else {}
    doc = {k: v for k, v in doc.items() if k not in ("config", "seconds", "environment")}
    if "real" in args.part:
        doc["real"] = real_part()
        print(json.dumps(doc["real"], indent=1), flush=True)
        write_results(args.json, doc, SGMConfig(), t0)
    sizes = {"yaw_mrad": args.yaw_mrad, "pitch_mrad": args.pitch_mrad, "time_offset_ms": args.time_offset_ms,
             "laser_sigma_mrad": args.laser_sigma_mrad, "jitter_sigma_mrad": args.jitter_sigma_mrad,
             "footprint_el_mrad": args.footprint_el_mrad, "footprint_az_mrad": args.footprint_az_mrad}
    if "twin" in args.part:
        for name in args.cases:
            t = time.time()
            row = twin_case(name, sizes, args.seed, args.scale)
            row["sizes"] = sizes
            doc.setdefault("twin", {})[f"{name}_seed{args.seed}"] = row
            print(name, "fill overhang", json.dumps(row["fill_overhang"]), f"{time.time() - t:.0f} s", flush=True)
            write_results(args.json, doc, SGMConfig(), t0)
    if "exact" in args.part:
        for name in args.cases:
            doc.setdefault("exact", {})[f"{args.rig}_{name}_seed{args.seed}"] = exact_case(args.rig, name, sizes, args.seed,
                                                                                          args.scale)
            write_results(args.json, doc, SGMConfig(), t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
