"""``jaxdepth warmup`` for multi-source rigs (``lidars``) and the Argoverse 2 job, and the two choices that let
one compiled program serve a whole log: power-of-two source buckets and estimated fields of view on a grid.

Oracles: a persistent compile cache folder of the test's own (a run after the warm-up adds no program of its own,
as the single-LiDAR warm-up test in test_rig_sweeps checks); :func:`jaxdepth.io.bucket_size` and the
laser table of a synthetic spinning LiDAR (the estimate before the grid); the same cloud completed with two
paddings (padding slots are invalid: identical depth).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxdepth import cli
from jaxdepth._src.types import LidarSpec
from jaxdepth.batch.sources_job import POINT_BUCKET, cloud_sources
from jaxdepth.io import bucket_size
from jaxdepth.io.sources import SourceCloud
from jaxdepth.io.sweep_frame import FOV_GRID_DEG, source_spec

from helpers import wall_sweep, warm_then_run, write_wall_rig

#: The multi-source rig's depth-only program (its persistent-cache entries start with this name): what the
#: Argoverse 2 job and ``complete-rig`` without seed extras run (they write depth alone).
DEPTH_PROGRAM = "jit_sources_depth_program"
SPEC = LidarSpec(beams=16, fov_up_deg=5.0, fov_down_deg=-10.0, columns=720)
TWO_LIDARS = [{"name": "left", "T_points_lidar": np.eye(4).tolist(), "beams": 16, "fov_up_deg": 5.0,
               "fov_down_deg": -10.0},
              {"name": "right", "T_points_lidar": [[1, 0, 0, 0], [0, 1, 0, -0.5], [0, 0, 1, 0], [0, 0, 0, 1]],
               "beams": 16, "fov_up_deg": 5.0, "fov_down_deg": -10.0}]


def _cloud(counts, *, ring=None, elevation_offset_deg=0.0):
    """A SourceCloud of ``len(counts)`` sources at the origin; with ``ring``: one spinning 16-laser LiDAR."""
    n = sum(counts)
    rng = np.random.default_rng(n)
    laser = np.arange(n) % 16
    el = np.radians(np.linspace(-10.0, 5.0, 16)[laser] + elevation_offset_deg)
    az = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(5.0, 30.0, n)
    points = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)
    S = len(counts)
    return SourceCloud(points=points.astype(np.float32), source=np.repeat(np.arange(S), counts).astype(np.int32),
                       T_ref_source=np.stack([np.eye(4)] * S), lidars=(None,) * S if ring else (SPEC,) * S,
                       sweep=np.zeros(S, np.int32), names=tuple(f"l{s}@0" for s in range(S)),
                       ring=laser.astype(np.int32) if ring else None)


@pytest.mark.parametrize("counts", [(100,), (8192, 10), (8193, 3000), (57600, 51785)])
def test_sources_pad_to_the_power_of_two_that_holds_the_largest(counts):
    sources, index = cloud_sources(_cloud(counts), fallback=SPEC)
    P = sources.points.shape[1]
    assert P == max(POINT_BUCKET, bucket_size(max(counts)))
    assert P & (P - 1) == 0
    for s, n in enumerate(counts):
        assert int(np.asarray(sources.valid)[s].sum()) == n and np.all(index[s, n:] == -1)


def test_estimated_field_of_view_lies_on_the_grid_outside_the_lasers():
    """The raw estimate (outermost lasers plus half a spacing) lies inside the gridded bounds, less than one
    grid step away; two sweeps whose lasers differ by 0.01 degree give one spec (one program) unless a raw
    bound straddles a grid line (here it lies mid-step)."""
    spacing = 15.0 / 15
    specs = []
    for offset in (0.1, 0.11):
        cloud = _cloud((4000,), ring=True, elevation_offset_deg=offset)
        spec, rows = source_spec(cloud, 0, SPEC)
        raw_up, raw_down = 5.0 + offset + spacing / 2, -10.0 + offset - spacing / 2
        assert spec.beams == 16 and rows is not None
        assert raw_up <= spec.fov_up_deg < raw_up + FOV_GRID_DEG + 1e-3
        assert raw_down - FOV_GRID_DEG - 1e-3 < spec.fov_down_deg <= raw_down
        for bound in (spec.fov_up_deg, spec.fov_down_deg):
            assert bound / FOV_GRID_DEG == pytest.approx(round(bound / FOV_GRID_DEG), abs=1e-9)
        specs.append(spec)
    assert specs[0] == specs[1]


@pytest.mark.slow  # compiles the multi-source program twice, one per padding (docs/testing.md)
def test_padding_a_source_further_leaves_the_depth_unchanged():
    import jaxdepth
    from jaxdepth._src.sources import complete_sources_stages
    cloud = _cloud((3000, 2000))
    cloud = SourceCloud(points=cloud.points, source=cloud.source,
                        T_ref_source=np.stack([np.eye(4), np.asarray(TWO_LIDARS[1]["T_points_lidar"], float)]),
                        lidars=cloud.lidars, sweep=cloud.sweep, names=cloud.names)
    K = np.array([[30.0, 0, 24], [0, 30, 16], [0, 0, 1]], np.float32)
    T = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], np.float32)
    cameras = jaxdepth.stack_cameras([jaxdepth.Camera(K=K, T_cam_lidar=T, height=32, width=48)])
    depths = []
    for bucket in (POINT_BUCKET, 2 * POINT_BUCKET):
        sources, _ = cloud_sources(cloud, fallback=SPEC, bucket=bucket)
        depths.append(np.asarray(complete_sources_stages(sources, cameras, free_space=True).depth))
    assert np.count_nonzero(depths[0]) > 0
    assert depths[0].tobytes() == depths[1].tobytes()


def _two_lidar_rig(path, *, lidars=TWO_LIDARS, columns=("x", "y", "z", "lidar")):
    write_wall_rig(path)
    data = json.loads(path.read_text())
    data.update(lidars=lidars, columns=list(columns))
    path.write_text(json.dumps(data))


def _two_lidar_sweep(path):
    wall_sweep(path)
    points = np.load(path)
    points[1::2, 3] = 1.0                  # every other point is the right LiDAR's
    np.save(path, points)


@pytest.mark.slow  # two subprocesses: the warm-up compiles the two-LiDAR wall rig's program (docs/testing.md)
def test_warmup_of_a_rig_of_two_lidars_serves_complete_rig(tmp_path):
    rig = tmp_path / "rig.json"
    _two_lidar_rig(rig)
    sweep = tmp_path / "000001.npy"
    _two_lidar_sweep(sweep)
    warmed, added, warm = warm_then_run(tmp_path / "xla", [rig, "--points", "1280"],
                                          ["complete-rig", sweep, rig, tmp_path / "out", "-q"], program=DEPTH_PROGRAM)
    assert f"compiled for {POINT_BUCKET} padded points per LiDAR" in warm.stdout
    assert warmed and not added
    import cv2
    assert np.count_nonzero(cv2.imread(str(tmp_path / "out" / "CAM_A.png"), cv2.IMREAD_UNCHANGED)) > 0


def test_warmup_asks_for_a_sample_when_each_sweep_estimates_its_lidars(tmp_path, capsys):
    rig = tmp_path / "rig.json"
    _two_lidar_rig(rig, lidars=[{k: v for k, v in lidar.items() if k in ("name", "T_points_lidar")}
                                for lidar in TWO_LIDARS], columns=("x", "y", "z", "lidar", "ring"))
    assert cli.main(["warmup", str(rig)]) == 1
    err = capsys.readouterr().err
    assert "field 'lidars'" in err and "left, right" in err and "--sample" in err


@pytest.mark.parametrize("argv, match", [
    ([], "a rig JSON or --av2"),
    (["RIG", "--av2", "LOG"], "a rig JSON or --av2"),
    (["--av2", "LOG", "--points", "10"], "--av2 takes no"),
    (["RIG", "--sweeps", "1"], "go with --av2"),
    (["--av2", "LOG", "--sweeps", "-1"], "--sweeps expected"),
])
def test_warmup_usage_errors(argv, match, capsys):
    assert cli.main(["warmup", *argv]) == 2
    assert match in capsys.readouterr().err


@pytest.mark.slow  # two subprocesses: the warm-up compiles the synthetic Argoverse 2 log's program
def test_warmup_av2_serves_every_sweep_of_the_log(tmp_path):
    """Both sweeps of the synthetic log (the car 1 m further on) run on the program warmed on one of them."""
    pytest.importorskip("pyarrow")
    from test_av2_synthetic import CAMERA, write_log
    log = write_log(tmp_path / "synthetic-log")
    warmed, added, warm = warm_then_run(tmp_path / "xla", ["--av2", log, "--cameras", CAMERA],
                                          ["complete", log, tmp_path / "out", "--cameras", CAMERA, "-q"],
                                          program=DEPTH_PROGRAM)
    assert "compiled for synthetic-log/" in warm.stdout
    assert warmed and not added
    assert len(list((tmp_path / "out" / "synthetic-log" / CAMERA).glob("*.png"))) == 2


@pytest.mark.slow  # two subprocesses: the warm-up compiles the two-LiDAR wall rig's program (docs/testing.md)
def test_warmup_on_a_sample_sweep_serves_complete_rig_of_estimated_lidars(tmp_path):
    """LiDARs without beams and a ring column: the warm-up reads the sample sweep as complete-rig does."""
    rig = tmp_path / "rig.json"
    _two_lidar_rig(rig, lidars=[{k: v for k, v in lidar.items() if k in ("name", "T_points_lidar")}
                                for lidar in TWO_LIDARS], columns=("x", "y", "z", "lidar", "ring"))
    sweep = tmp_path / "000001.npy"
    _two_lidar_sweep(sweep)
    points = np.load(sweep)
    np.save(sweep, np.concatenate([points, (np.arange(len(points)) // 160)[:, None].astype(np.float32)], 1))
    warmed, added, warm = warm_then_run(tmp_path / "xla", [rig, "--sample", sweep],
                                          ["complete-rig", sweep, rig, tmp_path / "out", "-q"], program=DEPTH_PROGRAM)
    assert f"compiled for the sweep {sweep}" in warm.stdout
    assert warmed and not added
