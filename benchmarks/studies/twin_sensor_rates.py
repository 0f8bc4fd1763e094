"""Range noise, dropouts and mixed returns of the real sweeps: the rates the digital twins use.

    PYTHONPATH=. python -m benchmarks.studies.twin_sensor_rates [--json benchmarks/results/twin_sensor_rates.json]
        [--write-tables]

Measured on every shared real sweep, each LiDAR in its own frame with its rings (KITTI: the beam
groups of ``beam_model``; nuScenes: the ring column; Argoverse 2: ``laser_number``), with
:func:`jaxdepth.research.twin_measure.ring_rates` (dropouts where a surface continues along a
ring; the share of edge triples whose middle return lies between the two layers) and
:func:`~jaxdepth.research.twin_measure.ground_noise` (range residuals on planar ground patches).

The twin's rates are *calibrated*, not copied (:func:`calibrate`): both estimators are biased
(the edge statistic also counts sloped surfaces; the ground plane fits add a grazing-angle error),
so each rate is set until the same estimator on the twin (sweep 0, seed 0) gives the real median:
the noise by rescaling (3 rounds), the mixed-return probability by bisection (7 rounds; 0 when the
twin's geometry alone already gives more than the real share). Dropouts are used as measured.

No raster-scan or rosette sweep is shared: those twins take the median of the spinning sensors'
rates (said so in the JSON and in docs/twins.md). ``--write-tables`` regenerates
``jaxdepth/research/twin_tables.py`` (laser tables, calibrations and these rates).
"""

from __future__ import annotations

import argparse
import glob
import time

import numpy as np

from benchmarks._common import DATA, ROOT, write_results
from jaxdepth.research import twin_measure as tm
from jaxdepth.research.twin_rigs import RIG_BUILDERS
from jaxdepth.research.twin_sensors import NO_EFFECTS, SensorEffects
from jaxdepth.research.twins import make_twin

KEYS = ("noise_m", "dropout", "mixed_share")


def real_sweeps():
    """Yields (name, points in the LiDAR's own frame, rings, points in a z-up frame, LiDAR origin there)."""
    for scene in ("drive_0001_frame05", "raw_2011_09_26_scene2"):
        path = DATA / "kitti" / scene / "lidar_data.bin"
        ring, _, _ = tm.kitti_sweep_lasers(path)
        p = np.fromfile(path, np.float32).reshape(-1, 4)[:, :3]
        yield "kitti", f"kitti {scene}", p, ring, p, np.zeros(3)
    pcd = glob.glob(str(DATA / "nuscenes" / "sample" / "*LIDAR_TOP*.pcd.bin"))[0]
    n = np.fromfile(pcd, np.float32).reshape(-1, 5)
    yield "nuscenes", "nuscenes sample", n[:, :3], n[:, 4].astype(np.int32), n[:, :3], np.zeros(3)
    log = DATA / "av2" / "sensor" / "val" / tm.AV2_LOG
    cal = tm.av2_calibration(log)
    from jaxdepth.io import av2

    for ts in av2.read_log(log).sweeps:
        for name, (q, ring, _) in tm.av2_sweep_lasers(log, ts).items():
            T = cal["lidars"][name]
            yield "av2", f"av2 {name} {ts}", q, ring, q @ T[:3, :3].T + T[:3, 3], T[:3, 3]


def measure(points, ring, points_up, origin) -> dict:
    rates = tm.ring_rates(points, ring)
    noise = tm.ground_noise(points_up, origin)
    return {"noise_m": noise["noise_m"], "dropout": rates["dropout"], "mixed_share": rates["mixed_share"],
            "edge_triples": rates["edge_triples"], "ground_points": noise["points"]}


def twin_statistics(rig: str, effects: SensorEffects) -> dict:
    """The same statistics on sweep 0 of the twin (each unit in its own frame, its rings)."""
    twin = make_twin(rig, sweeps=1, seed=0, scale=0.05, effects=effects)
    rdef = RIG_BUILDERS[rig](NO_EFFECTS)
    out = []
    for u, (_, T_points_unit) in enumerate(rdef.units):
        sel = twin.point_unit == u
        T = np.linalg.inv(T_points_unit)
        q = twin.cloud.points[sel].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        up = twin.cloud.points[sel].astype(np.float64) @ rdef.T_ego_points[:3, :3].T + rdef.T_ego_points[:3, 3]
        origin = (rdef.T_ego_points @ T_points_unit)[:3, 3]
        out.append(measure(q, twin.point_ring[sel], up, origin))
    return {k: float(np.mean([o[k] for o in out])) for k in KEYS}


def calibrate(rig: str, target: dict, *, noise_rounds: int = 3, mixed_rounds: int = 7):
    """(effects, report): the twin's rates whose measured statistics match ``target`` (the real median).

    Noise: the ground-patch estimator is biased (plane fits in 1 m cells at grazing angles), so the
    twin's noise is scaled until the *same estimator* on the twin gives the real value. Dropouts
    as measured. Mixed returns: bisection on the probability (the statistic rises with it).
    """
    noise, dropout = target["noise_m"], target["dropout"]
    for _ in range(noise_rounds):
        got = twin_statistics(rig, SensorEffects(noise_m=noise, dropout=dropout, mixed=0.0))
        noise *= target["noise_m"] / max(got["noise_m"], 1e-6)
    s0 = twin_statistics(rig, SensorEffects(noise_m=noise, dropout=dropout, mixed=0.0))
    s1 = twin_statistics(rig, SensorEffects(noise_m=noise, dropout=dropout, mixed=1.0))
    lo, hi = 0.0, 1.0
    if s0["mixed_share"] >= target["mixed_share"]:
        hi = 0.0
    for _ in range(mixed_rounds if hi > 0 else 0):
        mid = 0.5 * (lo + hi)
        got = twin_statistics(rig, SensorEffects(noise_m=noise, dropout=dropout, mixed=mid))
        lo, hi = (mid, hi) if got["mixed_share"] < target["mixed_share"] else (lo, mid)
    effects = {"noise_m": noise, "dropout": dropout, "mixed": 0.5 * (lo + hi)}
    check = twin_statistics(rig, SensorEffects(**effects))
    return effects, {"real_median": target, "twin_mixed_0": s0, "twin_mixed_1": s1, "twin_calibrated": check}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "twin_sensor_rates.json"))
    parser.add_argument("--write-tables", action="store_true")
    args = parser.parse_args(argv)
    t0 = time.time()
    real, per_rig = {}, {}
    for rig, name, points, ring, up, origin in real_sweeps():
        real[name] = measure(points, ring, up, origin)
        per_rig.setdefault(rig, []).append(real[name])
        print(name, {k: round(v, 4) for k, v in real[name].items()})
    effects, twins = {}, {}
    for rig, rows in per_rig.items():
        target = {k: float(np.median([r[k] for r in rows])) for k in KEYS}
        effects[rig], twins[rig] = calibrate(rig, target)
        print(rig, effects[rig], "twin:", {k: round(v, 4) for k, v in twins[rig]["twin_calibrated"].items()})
    spinning = list(effects.values())
    for rig in ("raster", "rosette"):
        effects[rig] = {k: float(np.median([e[k] for e in spinning])) for k in ("noise_m", "dropout", "mixed")}
    doc = {"real_sweeps": real, "twins": twins, "effects": effects,
           "not_measured": {"raster": "no shared raster-scan sweep: median of the spinning sensors' rates",
                            "rosette": "no shared rosette sweep: median of the spinning sensors' rates"}}
    write_results(args.json, doc, None, t0)
    if args.write_tables:
        out = ROOT / "jaxdepth" / "research" / "twin_tables.py"
        out.write_text(tm.tables_source(DATA, effects))
        print("wrote", out)


if __name__ == "__main__":
    main()
