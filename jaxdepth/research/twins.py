"""Digital twins of real rigs: ray-cast drives with exact camera depth (``docs/twins.md``).

:func:`make_twin` renders 1-5 sweeps of a rig (:data:`TWIN_RIGS`) driving down the twin street
(:mod:`jaxdepth.research.twin_scene`: movers, vegetation, poles, a fence) with the rig's measured
geometry (:mod:`jaxdepth.research.twin_rigs`) and sensor effects
(:mod:`jaxdepth.research.twin_sensors`), and returns the cloud as the user's data delivers it,
the rig and the exact depth of every camera at the reference sweep. :func:`write_twin` writes
what a user would have on disk (point files, rig JSON, sweeps JSON, depth PNGs).

Sweep 0 is the reference (the latest); sweep ``-k`` (signed, as every reader numbers sweeps) was taken
``k`` sweeps earlier, the ego then ``k * step_m`` further back along its path and turned ``k * yaw_deg`` to the right of the
reference heading. Deterministic in ``(rig, sweeps, seed, scale, effects)``.
"""

from __future__ import annotations

import dataclasses
import io as _io
import json
import math
import pathlib

import numpy as np

from jaxdepth._src.synthetic import scaled_intrinsics
from jaxdepth._src.types import Camera, SourceCloud
from jaxdepth.io.rig import Rig, RigCamera, RigLidar
from jaxdepth.research import twin_scene
from jaxdepth.research.twin_rigs import RIG_BUILDERS, RigDef
from jaxdepth.research.twin_sensors import NO_EFFECTS, SensorEffects, cast_unit, render_twin_depth, stagger_lasers
from jaxdepth.research.twin_tables import SENSOR_EFFECTS

TWIN_RIGS: tuple = ("kitti", "nuscenes", "av2", "raster", "rosette")
#: Camera rays without a hit within this range see sky (depth 0), metres.
CAMERA_MAX_RANGE_M = 120.0


@dataclasses.dataclass(frozen=True, eq=False)
class Twin:
    """One twin (see ``docs/twins.md``).

    Attributes:
      name: the rig (``"kitti"``, ...). sensor_class: ``"spinning"``, ``"raster"`` or ``"rosette"``.
      cloud: the input as the user's data delivers it, reference frame (one source per sweep;
        Argoverse 2: one per LiDAR and sweep, ``ring`` = laser index within its LiDAR; raster: one
        merged source per sweep, ``lidars`` None).
      rig: :class:`jaxdepth.io.Rig` of the cameras (``T_cam_lidar`` maps reference-frame points;
        ``lidars`` / ``columns`` where the real rig has them).
      dense_depth: (C, H, W) float32 exact depth of each camera at the reference sweep, 0 = nothing
        hit; cameras of different sizes (Argoverse 2's portrait camera) sit top-left on one
        (max H, max W) canvas, zero outside (``depths`` holds each at its own size).
      point_unit: (N,) int32 the emitting unit of each cloud point (oracle information).
      point_origin: (N, 3) float32 that unit's ray origin at that sweep, reference frame (oracle).
      depths: C arrays (H_c, W_c) float32, each camera's exact depth at its own size.
      sweep_poses: (K, 4, 4) float64 pose of each sweep's points frame in the reference frame
        (the sweeps JSON's ``T_ref_sweep``); ego_step_m: (K - 1,) distance the ego moved between
      consecutive sweeps, metres.
      point_exact: (N, 3) float32 each point's exact first hit (no noise, no blend).
      point_mixed: (N,) bool points that are mixed returns.
      point_ring: (N,) int32 each point's row on its unit's scan grid (laser, scan line; 0 for a rosette).
      unit_names: name of each unit index. effects: the rates used. seed, scale, layout: as given.
    """

    name: str
    sensor_class: str
    cloud: SourceCloud
    rig: Rig
    dense_depth: np.ndarray
    point_unit: np.ndarray
    point_origin: np.ndarray
    depths: tuple = ()
    sweep_poses: np.ndarray | None = None
    ego_step_m: np.ndarray | None = None
    point_exact: np.ndarray | None = None
    point_mixed: np.ndarray | None = None
    point_ring: np.ndarray | None = None
    unit_names: tuple = ()
    effects: SensorEffects = NO_EFFECTS
    seed: int = 0
    scale: float = 1.0
    layout: str = "street"


def ego_pose(rig: RigDef, sweep: int) -> np.ndarray:
    """(4, 4) ego pose of sweep ``sweep`` in the world frame (the reference sweep's ego frame)."""
    a = -math.radians(rig.yaw_deg) * sweep
    # Driving back along an arc: heading a, positions integrated per sweep.
    x = y = 0.0
    for j in range(sweep):
        h = -math.radians(rig.yaw_deg) * (j + 0.5)
        x -= rig.step_m * math.cos(h)
        y -= rig.step_m * math.sin(h)
    T = np.eye(4)
    T[:3, :3] = [[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = (x, y, 0.0)
    return T


def _check(rig: str, sweeps, seed, scale):
    if rig not in RIG_BUILDERS:
        raise ValueError(f"make_twin: field 'rig' expected one of {TWIN_RIGS}, got {rig!r}")
    if isinstance(sweeps, bool) or not isinstance(sweeps, (int, np.integer)) or not 1 <= sweeps <= 5:
        raise ValueError(f"make_twin: field 'sweeps' expected an integer in 1..5, got {sweeps!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"make_twin: field 'seed' expected an integer >= 0, got {seed!r}")
    if not (isinstance(scale, (int, float)) and 0 < scale <= 1):
        raise ValueError(f"make_twin: field 'scale' expected a float in (0, 1], got {scale!r}")


def _cameras(rig: RigDef, scale: float, T_points_ref: np.ndarray):
    """(RigCameras for reference-frame points, Cameras for world-frame rays)."""
    rig_cams, world_cams = [], []
    T_ref_world = np.linalg.inv(T_points_ref)
    for name, K, w, h, T_cam_points in rig.cameras:
        Ks = scaled_intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], scale)
        hs, ws = max(1, round(h * scale)), max(1, round(w * scale))
        rig_cams.append(RigCamera(name, ws, hs, Ks.astype(np.float32), T_cam_points.astype(np.float32)))
        T_world = np.asarray(rig_cams[-1].T_cam_lidar, np.float64) @ T_ref_world
        world_cams.append(Camera(K=Ks.astype(np.float32), T_cam_lidar=T_world.astype(np.float32), height=hs, width=ws))
    return tuple(rig_cams), world_cams


def _user_rig(rig: RigDef, cams) -> Rig:
    if rig.per_unit_sources:
        lidars = tuple(RigLidar(unit(0).name, np.asarray(T, np.float32), spec)
                       for (unit, T), spec in zip(rig.units, rig.stated))
        return Rig(lidar=rig.lidar, cameras=cams, lidars=lidars, columns=("x", "y", "z", "intensity", "lidar", "ring"))
    columns = ("x", "y", "z", "intensity", "ring") if rig.ring_column else None
    if rig.stated[0] is None:
        # Nothing a user could state about the scanner: one entry without a spec (estimated from the points).
        return Rig(lidar=rig.lidar, cameras=cams, lidars=(RigLidar(_source_name(rig), np.eye(4, dtype=np.float32)),),
                   columns=columns)
    return Rig(lidar=rig.lidar, cameras=cams, columns=columns)


def _source_name(rig: RigDef) -> str:
    """The name of a one-source-per-sweep rig's source (``lidar`` as the rig JSON reader names it)."""
    return {"raster": "roof", "rosette": "rosette"}.get(rig.name, "lidar")


def _moved(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return (np.asarray(p, np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)


def ego_returns(unit, table) -> np.ndarray:
    """(rows * cols, 3) float64: for each of ``unit``'s rays that returns the ego's body, that return (the
    unit's frame); nan elsewhere.

    ``table``: a real sweep's returns per ring in the LiDAR's own frame
    (:func:`jaxdepth.research.twin_measure.ego_table`); a ray returns the ego when the real return nearest in
    azimuth on its ring is nearer than :data:`~jaxdepth.research.twin_measure.EGO_M`, and then returns that
    very point (the ego moves with the sensor: the same rays every sweep). Invalid returns (inf in the
    table) are no ego: the twin's ray keeps what it hits.
    """
    from jaxdepth.research.twin_measure import EGO_M
    d = np.asarray(unit.directions, np.float64)
    az = np.arctan2(d[:, 1], d[:, 0])
    out = np.full((len(d), 3), np.nan)
    for b, (a_real, r_real, p_real) in table.items():
        sel = np.flatnonzero(unit.ring == b)
        if not sel.size or not len(a_real):
            continue
        i = np.searchsorted(a_real, az[sel]) % len(a_real)
        j = (i - 1) % len(a_real)
        gap = lambda k: np.abs(np.angle(np.exp(1j * (a_real[k] - az[sel]))))  # noqa: E731
        k = np.where(gap(i) <= gap(j), i, j)
        near = r_real[k] < EGO_M
        out[sel[near]] = p_real[k[near]]
    return out


def _with_ego(out: dict, ego: np.ndarray, T_world_unit: np.ndarray) -> dict:
    """``cast_unit``'s output with the ego rays (``ego`` finite) returning the ego's body (those points)."""
    hit = np.isfinite(ego[:, 0])
    T = np.asarray(T_world_unit, np.float64)
    p = (ego[hit] @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    out = dict(out, points=out["points"].copy(), valid=out["valid"].copy(), exact=out["exact"].copy(),
               mixed=out["mixed"].copy())
    out["points"][hit], out["exact"][hit], out["valid"][hit], out["mixed"][hit] = p, p, True, False
    return out


def _cast_sweeps(rdef: RigDef, T_world_points: list, seed: int, rates: SensorEffects, layout: str = "street",
                 ego=None):
    """(SourceCloud in the reference frame, per-point oracle arrays) of every sweep of every unit."""
    T_ref_world = np.linalg.inv(T_world_points[0])
    parts = {"points": [], "source": [], "ring": [], "unit": [], "origin": [], "exact": [], "mixed": []}
    poses, specs, sweep_ids, names = [], [], [], []
    spheres = twin_scene.twin_spheres(seed, layout)
    for k, T_world_k in enumerate(T_world_points):
        scene = twin_scene.twin_scene(seed, k, dt_s=rdef.dt_s, layout=layout)
        T_ref_points = T_ref_world @ T_world_k
        if not rdef.per_unit_sources:
            poses.append(T_ref_points)
            specs.append(rdef.stated[0])
            sweep_ids.append(-k)                      # signed: -k was taken k sweeps earlier
            names.append(f"{_source_name(rdef)}@{-k}")
        for u, (make_unit, T_points_unit) in enumerate(rdef.units):
            unit = make_unit(k)
            out = cast_unit(scene, spheres, unit, T_world_k @ T_points_unit, rates, [seed, k, u, 37])
            if ego is not None:
                out = _with_ego(out, ego_returns(unit, ego), T_world_k @ T_points_unit)
            if rdef.per_unit_sources:
                poses.append(T_ref_points @ T_points_unit)
                specs.append(rdef.stated[u])
                sweep_ids.append(-k)
                names.append(f"{unit.name}@{-k}")
            keep = out["valid"]
            n = int(keep.sum())
            parts["points"].append(_moved(T_ref_world, out["points"][keep]))
            parts["exact"].append(_moved(T_ref_world, out["exact"][keep]))
            parts["source"].append(np.full(n, len(poses) - 1, np.int32))
            parts["ring"].append(out["ring"][keep])
            parts["unit"].append(np.full(n, u, np.int32))
            parts["origin"].append(np.repeat(_moved(T_ref_world, out["origin"][None]), n, axis=0))
            parts["mixed"].append(out["mixed"][keep])
    cat = {key: np.concatenate(v) for key, v in parts.items()}
    cloud = SourceCloud(points=cat["points"], source=cat["source"], T_ref_source=np.stack(poses), lidars=tuple(specs),
                        sweep=np.asarray(sweep_ids, np.int32), names=tuple(names),
                        ring=cat["ring"] if rdef.ring_column else None, path=f"twin:{rdef.name}")
    return cloud, cat


def make_twin(rig: str, *, sweeps: int = 1, seed: int = 0, scale: float = 1.0, effects: bool | SensorEffects = True,
              step_m: float | None = None, laser_phases: bool = False, layout: str = "street", ego=None) -> Twin:
    """A digital twin of a real rig (see the module docstring and ``docs/twins.md``).

    Args:
      rig: one of :data:`TWIN_RIGS`.
      sweeps: 1-5 sweeps (sweep 0 = reference = latest).
      seed: scene seed (street, movers, clutter, the effects' draws).
      scale: shrinks every camera (K and size), e.g. 0.25 for small CI runs; the LiDARs are unchanged.
      effects: True (the rig's measured rates, :data:`~jaxdepth.research.twin_tables.SENSOR_EFFECTS`),
        False (exact returns: every point on a surface) or a :class:`SensorEffects`.
      step_m: ego motion per sweep, metres (default: the rig's, 0.5-1.26 m).
      laser_phases: each laser of a spinning unit samples at its own azimuth phase
        (:func:`~jaxdepth.research.twin_sensors.stagger_lasers`, unit ``u`` drawn from seed ``u``), as real
        spinning LiDARs do; False (default): the lasers share one phase, as the published results.
      layout: the street's layout (:data:`~jaxdepth.research.twin_scene.LAYOUTS`): ``"street"`` (default)
        ``"open"`` (the right side open to 20-60 m, as the real nuScenes sample) or ``"cluttered"``
        (``"open"`` with near clutter within 10 m and denser far vegetation).
      ego: None (default: no ego body) or a real sweep's returns per ring
        (:func:`~jaxdepth.research.twin_measure.ego_table`, the rig's one spinning unit): the rays whose real
        return is the ego's body or the sensor's housing (nearer than 2 m, not an invalid return) return that real
        point instead of the scene (:func:`ego_returns`; nusc13). The cameras' exact depth is unchanged (no real
        camera sees them).

    Returns:
      :class:`Twin`.
    """
    _check(rig, sweeps, seed, scale)
    twin_scene.check_layout(layout)
    rates = SensorEffects(**SENSOR_EFFECTS[rig]) if effects is True else NO_EFFECTS if effects is False else effects
    if not isinstance(rates, SensorEffects):
        raise ValueError(f"make_twin: field 'effects' expected a bool or SensorEffects, got {type(effects).__name__}")
    rdef = RIG_BUILDERS[rig](rates)
    if step_m is not None:
        if not 0 <= step_m <= 5:
            raise ValueError(f"make_twin: field 'step_m' expected metres in [0, 5], got {step_m!r}")
        rdef = dataclasses.replace(rdef, step_m=float(step_m))
    if laser_phases and rdef.sensor_class == "spinning":
        units = tuple((lambda k, mk=mk, u=u: stagger_lasers(mk(k), seed=u), T) for u, (mk, T) in enumerate(rdef.units))
        rdef = dataclasses.replace(rdef, units=units)
    T_world_points = [ego_pose(rdef, k) @ rdef.T_ego_points for k in range(int(sweeps))]
    if ego is not None and (rdef.sensor_class != "spinning" or len(rdef.units) != 1):
        raise ValueError(f"make_twin: field 'ego' expected a rig with one spinning LiDAR, got {rig!r}")
    cloud, cat = _cast_sweeps(rdef, T_world_points, int(seed), rates, layout, ego)
    T_ref_world = np.linalg.inv(T_world_points[0])
    rig_cams, world_cams = _cameras(rdef, float(scale), T_world_points[0])
    scene0 = twin_scene.twin_scene(seed, 0, dt_s=rdef.dt_s, layout=layout)
    spheres = twin_scene.twin_spheres(int(seed), layout)
    depths = tuple(np.asarray(render_twin_depth(cam, scene0, spheres, np.float32(CAMERA_MAX_RANGE_M)))
                   for cam in world_cams)
    H, W = max(d.shape[0] for d in depths), max(d.shape[1] for d in depths)
    canvas = np.zeros((len(depths), H, W), np.float32)
    for c, d in enumerate(depths):
        canvas[c, :d.shape[0], :d.shape[1]] = d
    sweep_poses = np.stack([T_ref_world @ T for T in T_world_points])
    steps = np.linalg.norm(np.diff([ego_pose(rdef, k)[:3, 3] for k in range(int(sweeps))], axis=0), axis=1)
    return Twin(name=rig, sensor_class=rdef.sensor_class, cloud=cloud, rig=_user_rig(rdef, rig_cams),
                dense_depth=canvas, point_unit=cat["unit"], point_origin=cat["origin"], depths=depths,
                sweep_poses=sweep_poses, ego_step_m=steps, point_exact=cat["exact"], point_mixed=cat["mixed"],
                point_ring=cat["ring"],
                unit_names=tuple(unit(0).name for unit, _ in rdef.units), effects=rates, seed=int(seed), scale=float(scale),
                layout=layout)


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = _io.BytesIO()
    np.save(buf, np.ascontiguousarray(array, np.float32), allow_pickle=False)
    return buf.getvalue()


def _sweep_file_rows(twin: Twin, k: int) -> np.ndarray:
    """The float32 rows of the point file of the sweep taken ``k`` sweeps before the reference (``cloud.sweep``
    ``-k``), in its own points frame."""
    cloud = twin.cloud
    sources = np.flatnonzero(cloud.sweep == -k)
    sel = np.isin(cloud.source, sources)
    T = np.linalg.inv(twin.sweep_poses[k])
    pts = cloud.points[sel].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    cols = [pts, np.zeros((pts.shape[0], 1))]   # no reflectance modelled: intensity 0
    if twin.rig.columns is not None and "lidar" in twin.rig.columns:
        cols.append((cloud.source[sel] - sources[0])[:, None])
    if cloud.ring is not None:
        cols.append(cloud.ring[sel][:, None])
    return np.concatenate(cols, axis=1).astype(np.float32)


def write_twin(twin: Twin, folder) -> dict:
    """Writes what a user would have on disk, atomically, into ``folder`` (created).

    Files: ``sweep_<k>.npy`` (float32 rows ``x, y, z, intensity`` (0: reflectance is not modelled)
    plus ``lidar`` / ``ring`` where the rig's ``columns`` name them, each sweep in its own points
    frame), ``rig.json``
    (:func:`jaxdepth.io.write_rig_json`), ``sweeps.json`` (``T_ref_sweep`` of each sweep, in time
    order: the reference, ``sweep_0``, last) and ``depth/<camera>.png`` (the exact depth, KITTI uint16 format, at the
    camera's own size).

    Returns:
      dict: ``"sweeps"`` (list of paths), ``"rig"``, ``"sweeps_json"``, ``"depth"`` (camera -> path).
    """
    from jaxdepth.io import atomic_write_bytes, write_depth_png, write_rig_json

    if not isinstance(twin, Twin):
        raise ValueError(f"write_twin: field 'twin' expected a Twin, got {type(twin).__name__}")
    folder = pathlib.Path(folder)
    (folder / "depth").mkdir(parents=True, exist_ok=True)
    sweep_paths, entries = [], []
    for k in range(twin.sweep_poses.shape[0]):
        path = atomic_write_bytes(folder / f"sweep_{k}.npy", _npy_bytes(_sweep_file_rows(twin, k)))
        sweep_paths.append(path)
        entries.append({"file": path.name, "T_ref_sweep": [[float(x) for x in row] for row in twin.sweep_poses[k]]})
    entries[0]["T_ref_sweep"] = np.eye(4).tolist()
    entries = entries[::-1]                           # a sweeps JSON lists its sweeps in time order
    sweeps_json = atomic_write_bytes(folder / "sweeps.json", (json.dumps({"sweeps": entries}, indent=1) + "\n").encode())
    rig_path = write_rig_json(folder / "rig.json", twin.rig)
    depth = {cam.name: write_depth_png(folder / "depth" / f"{cam.name}.png", d)
             for cam, d in zip(twin.rig.cameras, twin.depths)}
    return {"sweeps": sweep_paths, "rig": rig_path, "sweeps_json": sweeps_json, "depth": depth}


__all__ = ["TWIN_RIGS", "Twin", "make_twin", "write_twin", "ego_pose", "ego_returns"]
