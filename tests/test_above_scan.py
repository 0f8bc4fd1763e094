"""Above the top scan line (Step 4c, beyond the paper): a per-pixel NumPy oracle, analytic cases,
the config field and its CLI flag; jit == eager, vmap == loop via _harness (stage_table row
``background_above_scan``)."""

import argparse
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdepth
from jaxdepth._src.above_scan import background_above_scan, capped_above_scan, top_line_keep
from jaxdepth.options import add_config_options, config_changes

#: The stage, compiled: these tests check values (the oracle, analytic cases); jit == eager is the stage
#: table's row. Called plainly, each new shape runs op by op and compiles ~100 primitives (3.4 s of CPU
#: per test against one compile).
_above_scan = jax.jit(background_above_scan, static_argnames=("beams", "max_half_width_px"))


def numpy_above_scan(depth_raw, seed_depth, keep, valid, *, beams, max_half_width_px):
    """Pixel by pixel: N, the window |du| < W L / N, the top kept row of each window column, the farthest seed."""
    H, W = depth_raw.shape
    n = int(valid.sum())
    k_max = 0
    while n > 0 and k_max + 1 < W * beams / n and k_max + 1 <= min(max_half_width_px, W - 1):
        k_max += 1
    out = depth_raw.astype(np.float32).copy()
    for v in range(H):
        for u in range(W):
            cols = [c for c in range(u - k_max, u + k_max + 1) if 0 <= c < W]
            if seed_depth[v, u] > 0 and not any(keep[:v + 1, c].any() for c in cols):
                out[v, u] = max(seed_depth[v, c] for c in cols)
    return out


def above_scan_inputs(seed: int, *, H: int = 24, W: int = 40, points: int = 200):
    """(depth_raw, seed_depth, keep, valid) with scan lines in the lower part and ragged tops; ``points``
    pixels with depth set N (W L / N with L = 16: 3.2 px at 200, 1.6 at 400)."""
    rng = np.random.default_rng(seed)
    valid = np.zeros((H, W), bool)
    flat = rng.choice(np.arange(8 * W, H * W), points, replace=False)  # no point in the top 8 rows
    valid.flat[flat] = True
    keep = valid & (rng.random((H, W)) < 0.9)
    seed_depth = np.where(rng.random((H, W)) < 0.95, rng.uniform(2, 60, (H, W)), 0.0).astype(np.float32)
    depth_raw = np.where(seed_depth > 0, seed_depth * rng.uniform(0.7, 1.3, (H, W)), 0.0).astype(np.float32)
    return depth_raw, seed_depth, keep, valid


@pytest.mark.parametrize("points, cap", [(200, 12), (400, 12), (200, 1), (640, 12)])
def test_matches_the_per_pixel_oracle(points, cap):
    """Window from N at run time (|du| <= 3, 1, capped at 1, 0): the library equals the walk exactly."""
    depth_raw, seed_depth, keep, valid = above_scan_inputs(points, points=points)
    got = np.asarray(_above_scan(jnp.asarray(depth_raw), jnp.asarray(seed_depth), jnp.asarray(keep),
                                           jnp.asarray(valid), beams=16, max_half_width_px=cap))
    want = numpy_above_scan(depth_raw, seed_depth, keep, valid, beams=16, max_half_width_px=cap)
    np.testing.assert_array_equal(got, want)
    assert (got != depth_raw).mean() > 0.1  # the rule changed something


def test_thin_post_gives_way_to_the_wall_above_the_scan():
    """A wall at 20 m, a post at 5 m one pixel wide and a box at 8 m six pixels wide, scanned in the lower
    rows; seeds as the nearest fill gives them (straight up). Above the top scan line the post's column
    takes the wall (farthest seed within |du| < W L / N = 2 px), the wide box keeps its own depth inside,
    and nothing changes at or below the top scan line."""
    H, W, beams = 20, 32, 8
    scene = np.full(W, 20.0, np.float32)
    scene[10] = 5.0
    scene[18:24] = 8.0
    keep = np.zeros((H, W), bool)
    keep[[12, 15, 18]] = True
    valid = keep.copy()  # N = 96: W L / N = 2.67, |du| <= 2
    seed_depth = np.broadcast_to(scene, (H, W)).astype(np.float32)
    depth_raw = seed_depth * 1.1  # the plane's extrapolation, whatever it was
    got = np.asarray(_above_scan(jnp.asarray(depth_raw), jnp.asarray(seed_depth), jnp.asarray(keep),
                                           jnp.asarray(valid), beams=beams))
    np.testing.assert_array_equal(got[12:], depth_raw[12:])
    np.testing.assert_array_equal(got[:12, 10], 20.0)
    np.testing.assert_array_equal(got[:12, 20:22], 8.0)
    np.testing.assert_array_equal(got[:12, 16:18], 20.0)   # within 2 px of the box's edge: the wall behind
    np.testing.assert_array_equal(got[:12, 0:8], 20.0)


def test_a_column_without_points_is_not_open_to_the_top():
    """Every other column holds no point (sparse horizontal sampling): its pixels below the neighbours'
    top scan line keep Step 4's prediction."""
    H, W = 16, 24
    keep = np.zeros((H, W), bool)
    keep[8:, ::2] = True
    seed_depth = np.full((H, W), 10.0, np.float32)
    seed_depth[:, 5] = 3.0
    depth_raw = seed_depth + 0.5
    got = np.asarray(_above_scan(jnp.asarray(depth_raw), jnp.asarray(seed_depth), jnp.asarray(keep),
                                           jnp.asarray(keep), beams=16))  # N = 96: W L / N = 4, |du| <= 3
    np.testing.assert_array_equal(got[8:], depth_raw[8:])
    np.testing.assert_array_equal(got[:8], 10.0)


def test_no_seed_stays_empty():
    depth_raw, seed_depth, keep, valid = above_scan_inputs(7)
    seed_depth[:4] = 0.0
    depth_raw[:4] = 0.0
    got = np.asarray(_above_scan(jnp.asarray(depth_raw), jnp.asarray(seed_depth), jnp.asarray(keep),
                                           jnp.asarray(valid), beams=16))
    assert (got[:4] == 0).all()


def test_config_field_and_cli_flag():
    with pytest.raises(ValueError, match="'above_scan' expected one of"):
        jaxdepth.SGMConfig(above_scan="sky")
    p = argparse.ArgumentParser()
    add_config_options(p)
    assert config_changes(p.parse_args(["--above-scan", "background"]))["above_scan"] == "background"
    assert config_changes(p.parse_args(["--above-scan", "plane"]))["above_scan"] == "plane"
    assert jaxdepth.SGMConfig().replace(**config_changes(p.parse_args([]))) == jaxdepth.SGMConfig()


def numpy_top_line_keep(reference, depth, *, beams, max_half_width_px, epsilon_m=1.0):
    """Pixel by pixel: N the reference pixels, the window |du| < W L / N (capped); kept when some reference
    pixel lies at or above the row in a window column, or no window column holds one, or the depth is not
    nearer by more than epsilon than the farthest of the window columns' top reference pixels."""
    H, W = reference.shape
    n = int(reference.sum())
    k_max = 0
    while n > 0 and k_max + 1 < W * beams / n and k_max + 1 <= min(max_half_width_px, W - 1):
        k_max += 1
    out = np.zeros((H, W), bool)
    for u in range(W):
        cols = [c for c in range(u - k_max, u + k_max + 1) if 0 <= c < W and reference[:, c].any()]
        far = max((depth[np.argmax(reference[:, c]), c] for c in cols), default=0.0)
        for v in range(H):
            out[v, u] = (not cols or any(reference[:v + 1, c].any() for c in cols)
                         or depth[v, u] >= far - epsilon_m)
    return out


@pytest.mark.xdist_group("above_scan_top_line")  # the cases' op-by-op runs compile the same ~125 primitives: one worker
@pytest.mark.parametrize("points, cap, gap", [(200, 12, False), (400, 12, False), (200, 1, False),
                                              (640, 12, False), (0, 12, False), (200, 12, True)])
def test_top_line_keep_matches_the_per_pixel_oracle(points, cap, gap):
    """The reference sweep's top scan line over the paper's window (|du| <= 3, 1, capped at 1, 0; no
    reference pixel, or none within the window (``gap``: 16 empty columns): no line, every pixel of
    those columns kept); above it only pixels not nearer than the window's farthest top reference pixel
    by more than epsilon; jit equals eager."""
    _, depth, reference, _ = above_scan_inputs(points + 1, points=max(points, 1))
    reference = reference & (points > 0)
    if gap:
        reference[:, 12:28] = False
    fn = functools.partial(top_line_keep, beams=16, max_half_width_px=cap)
    got = np.asarray(fn(jnp.asarray(reference), jnp.asarray(depth)))
    np.testing.assert_array_equal(got, numpy_top_line_keep(reference, depth, beams=16, max_half_width_px=cap))
    np.testing.assert_array_equal(np.asarray(jax.jit(fn)(jnp.asarray(reference), jnp.asarray(depth))), got)
    assert 0 < got.mean() < 1 or (points == 0 and got.all())


def test_reference_top_line_flag():
    p = argparse.ArgumentParser()
    add_config_options(p)
    for mode in ("auto", "on", "off"):
        assert config_changes(p.parse_args(["--reference-top-line", mode]))["reference_top_line"] == mode
    assert "reference_top_line" not in config_changes(p.parse_args([]))
    assert jaxdepth.SGMConfig().reference_top_line == "auto"
    with pytest.raises(SystemExit):
        p.parse_args(["--reference-top-line", "yes"])
    with pytest.raises(ValueError, match="reference_top_line"):
        jaxdepth.SGMConfig(reference_top_line=True)


# ---------------------------------------------------------------- above_scan="capped"

_capped = jax.jit(capped_above_scan, static_argnames=("beams", "max_half_width_px", "min_abs_denom",
                                                      "max_residual_ratio"))


def numpy_capped_above_scan(depth_raw, seed_depth, seed_normal, du, dv, keep, valid, K, *, beams, rows_px,
                            max_half_width_px=jaxdepth.SGMConfig().outlier_max_half_width_px,
                            min_abs_denom=jaxdepth.SGMConfig().min_abs_denom,
                            max_residual_ratio=jaxdepth.SGMConfig().max_residual_ratio):
    """Pixel by pixel, float64: above the window's top scan line and more than R rows from its seed, the
    plane through the seed (point z' K^-1 (u + du, v + dv, 1), normal n) met by the ray of (u, v_e),
    v_e = v + dv - R sign(dv), by ray-plane intersection; z' where the ray is within min_abs_denom of
    grazing the plane; the change clipped to max_residual_ratio z'."""
    H, W = depth_raw.shape
    n_points = int(valid.sum())
    k_max = 0
    while n_points > 0 and k_max + 1 < W * beams / n_points and k_max + 1 <= min(max_half_width_px, W - 1):
        k_max += 1
    Kinv = np.linalg.inv(np.asarray(K, np.float64))
    out = depth_raw.astype(np.float32).copy()
    for v in range(H):
        for u in range(W):
            cols = [c for c in range(u - k_max, u + k_max + 1) if 0 <= c < W]
            z0 = float(seed_depth[v, u])
            if z0 <= 0 or any(keep[:v + 1, c].any() for c in cols) or abs(dv[v, u]) <= rows_px:
                continue
            n = seed_normal[:, v, u].astype(np.float64)
            seed_point = z0 * Kinv @ np.array([u + du[v, u], v + dv[v, u], 1.0])
            ray = Kinv @ np.array([u, v + dv[v, u] - np.sign(dv[v, u]) * rows_px, 1.0])   # z component 1
            z = z0 if abs(n @ ray) <= min_abs_denom else (n @ seed_point) / (n @ ray)
            out[v, u] = np.clip(z, z0 * (1 - max_residual_ratio), z0 * (1 + max_residual_ratio))
    return out


def capped_inputs(seed: int, *, H: int = 24, W: int = 40, points: int = 200):
    """(depth_raw, seed_depth, seed_normal, du, dv, keep, valid, K): :func:`above_scan_inputs` with
    seed offsets of up to 20 rows, normals facing the camera (the denominators far from the guard)."""
    depth_raw, seed_depth, keep, valid = above_scan_inputs(seed, H=H, W=W, points=points)
    rng = np.random.default_rng(seed + 100)
    normal = np.concatenate([rng.uniform(-0.6, 0.6, (2, H, W)), -np.ones((1, H, W))]).astype(np.float32)
    normal /= np.linalg.norm(normal, axis=0, keepdims=True)
    du = rng.integers(-3, 4, (H, W)).astype(np.int32)
    dv = rng.integers(-20, 21, (H, W)).astype(np.int32)
    K = np.array([[30.0, 0, W / 2 - 0.5], [0, 28.0, H / 2 + 1.5], [0, 0, 1]], np.float32)
    return depth_raw, seed_depth, normal, du, dv, keep, valid, K


@pytest.mark.parametrize("points, rows_px", [(200, 3.0), (400, 1.5), (640, 6.0)])
def test_capped_matches_the_per_pixel_oracle(points, rows_px):
    """The float64 ray-plane walk: equal to float32 rounding; only pixels above the top scan line with a
    seed more than R rows away change, and many do."""
    args = capped_inputs(points, points=points)
    got = np.asarray(_capped(*map(jnp.asarray, args), beams=16, rows_px=rows_px))
    want = numpy_capped_above_scan(*args, beams=16, rows_px=rows_px)
    np.testing.assert_allclose(got, want, rtol=2e-6)
    changed = got != args[0]
    assert changed.mean() > 0.05
    assert (np.abs(args[4])[changed] > rows_px).all()


def test_capped_builds_the_window_top_line_alone():
    """The capped rule reads the window's top scan line only: its program (tricks on, as on CPU) holds the
    windowed minimum of the (1, W) int32 top line and no windowed maximum of a (1, W) float32 row (the
    background rule's farthest seed, which it never reads), and fences that one row alone; the values are
    the oracle's (test above)."""
    from jaxdepth._src import xla_tuning
    args = tuple(map(jnp.asarray, capped_inputs(200)))
    width = args[0].shape[1]

    def row_ops(jaxpr, name, dtype):
        return sum(e.primitive.name == name and any(tuple(v.aval.shape) == (1, width) and v.aval.dtype == dtype
                                                    for v in e.outvars) for e in jaxpr.eqns)

    with xla_tuning.forced("cpu"):
        jaxpr = jax.make_jaxpr(functools.partial(capped_above_scan, beams=16, rows_px=3.0))(*args).jaxpr
    assert row_ops(jaxpr, "min", jnp.int32) >= 2          # |du| = 1 on both sides at least
    assert row_ops(jaxpr, "max", jnp.float32) == 0
    fenced = [e for e in jaxpr.eqns if e.primitive.name in ("custom_vmap_call", "custom_jvp_call", "cond")]
    assert [[(tuple(v.aval.shape), v.aval.dtype) for v in e.outvars] for e in fenced] == [[((1, width), jnp.int32)]]


def test_capped_holds_a_tilted_plane_one_scan_line_above_its_seed():
    """A plane seen by the camera at depths 1/(0.2 + 0.015 (v - 10)) m (tilted about the x axis), scanned
    on rows 12, 15 and 18 of every column, each pixel above seeded from row 12 straight below it and
    predicted on the plane (the paper's Step 4, exact here). With R = 3 rows: rows 9-11 keep the
    plane, rows 0-8 take the plane's depth at row 9; at and below the top scan line nothing changes."""
    H, W, R = 20, 32, 3.0
    K = np.array([[20.0, 0, 15.5], [0, 20.0, 10.0], [0, 0, 1]], np.float32)
    v = np.arange(H, dtype=np.float64)[:, None] * np.ones((1, W))
    plane = 1.0 / (0.2 + 0.015 * (v - 10))            # n . X = 1 with n = (0, 0.3, 0.2): n . K^-1 (u, v, 1) z = 1
    n = np.array([0.0, 0.3, 0.2]) / np.linalg.norm([0.0, 0.3, 0.2])
    keep = np.zeros((H, W), bool)
    keep[[12, 15, 18]] = True
    dv = np.where(v < 12, 12 - v, 0).astype(np.int32)
    seed_depth = np.where(v < 12, plane[12], plane).astype(np.float32)
    normal = np.broadcast_to(n[:, None, None], (3, H, W)).astype(np.float32)
    got = np.asarray(_capped(jnp.asarray(plane.astype(np.float32)), jnp.asarray(seed_depth), jnp.asarray(normal),
                             jnp.zeros((H, W), jnp.int32), jnp.asarray(dv), jnp.asarray(keep), jnp.asarray(keep),
                             jnp.asarray(K), beams=8, rows_px=R))
    np.testing.assert_array_equal(got[9:], plane[9:].astype(np.float32))
    np.testing.assert_allclose(got[:9], np.broadcast_to(plane[9], (9, W)), rtol=1e-6)
    assert plane[0, 0] > 1.4 * got[0, 0]                # the plane itself climbs far above: the cap bites


@pytest.mark.slow  # two whole-pipeline programs (docs/testing.md); the plane one is the complete_stages row's
def test_capped_through_the_pipeline_changes_only_above_the_scan():
    """complete_stages with "capped" and with "plane" (the default): Step 4's prediction equal to the bit
    at and below the top scan line (three full rows of points), different above it; jit == eager is
    the stage table's row ``capped_above_scan``, vmap == loop too. On the 32 x 48 camera and SMALL_LIDAR of
    the stage table's pipeline rows (their default program; K and T are arguments), not one of its own."""
    from scenes import SMALL_LIDAR, small_camera
    H, W = 32, 48
    camera = small_camera(h=H, w=W, f=40.0)
    sparse = np.zeros((H, W), np.float32)
    sparse[16, ::2], sparse[22, 1::2], sparse[28, ::2] = 6.0, 5.0, 4.0
    K, T = np.asarray(camera.K), np.asarray(camera.T_cam_lidar)
    plane = jaxdepth.complete_stages(sparse, K, T, lidar=SMALL_LIDAR)
    capped = jaxdepth.complete_stages(sparse, K, T, lidar=SMALL_LIDAR, config=jaxdepth.SGMConfig(above_scan="capped"))
    np.testing.assert_array_equal(np.asarray(capped.depth_raw)[16:], np.asarray(plane.depth_raw)[16:])
    assert not np.array_equal(np.asarray(capped.depth_raw)[:16], np.asarray(plane.depth_raw)[:16])


def test_capped_flag():
    p = argparse.ArgumentParser()
    add_config_options(p)
    assert config_changes(p.parse_args(["--above-scan", "capped"]))["above_scan"] == "capped"
    assert jaxdepth.SGMConfig(above_scan="capped").above_scan == "capped"


def test_auto_rule_is_capped_for_a_reference_sweep_of_several_line_scanning_lidars():
    """``above_scan="auto"`` (the default): capped for two or more reference-sweep LiDARs scanning in lines
    (the Argoverse 2 rig), the paper's plane for one LiDAR (any number of sweeps) and for a reference
    LiDAR scanning without lines (a rosette's witness grid differs from its spec); an explicit mode wins."""
    from jaxdepth._src.above_scan import above_scan_rule
    a, b = jaxdepth.LidarSpec(beams=32), jaxdepth.LidarSpec(beams=16, fov_up_deg=15.0, fov_down_deg=-15.0)
    assert jaxdepth.SGMConfig().above_scan == "auto"
    assert above_scan_rule("auto", sweep=(0, 0), lidars=(a, b)) == "capped"
    assert above_scan_rule("auto", sweep=(0, 0, 1, 1), lidars=(a, a, a, a)) == "capped"
    assert above_scan_rule("auto", sweep=(0,), lidars=(a,)) == "plane"
    assert above_scan_rule("auto", sweep=(0, 1, 2), lidars=(a, a, a)) == "plane"
    assert above_scan_rule("auto", sweep=(0, 0), lidars=(a, a), witnesses=(a, b)) == "plane"
    for mode in ("plane", "background", "capped"):
        assert above_scan_rule(mode, sweep=(0, 0), lidars=(a, a)) == mode
        assert above_scan_rule(mode, sweep=(0,), lidars=(a,)) == mode


def test_run_record_holds_the_rule_the_run_uses(tmp_path):
    """The run record holds the rule, not "auto": "plane" for one LiDAR, "capped" for a rig of two LiDARs that
    state their scan lines, undecided (None) without a sweep when they state none, an explicit choice as given."""
    import json

    from jaxdepth.batch import run_record
    from jaxdepth.io import read_rig_json
    rig = {"lidar": {"beams": 32, "fov_up_deg": 10.0, "fov_down_deg": -25.0, "columns": 1024},
           "cameras": [{"name": "cam", "width": 64, "height": 48, "K": [[50, 0, 32], [0, 50, 24], [0, 0, 1]],
                        "T_cam_lidar": np.eye(4).tolist()}]}
    (tmp_path / "one.json").write_text(json.dumps(rig))
    rig["lidars"] = [{"name": n, "T_points_lidar": np.eye(4).tolist()} for n in ("up", "down")]
    rig["columns"] = ["x", "y", "z", "lidar"]
    (tmp_path / "open.json").write_text(json.dumps(rig))
    for lidar in rig["lidars"]:
        lidar["beams"] = 32
    (tmp_path / "two.json").write_text(json.dumps(rig))
    one, two, open_ = (read_rig_json(tmp_path / f"{n}.json") for n in ("one", "two", "open"))
    config = jaxdepth.SGMConfig()
    assert run_record.settings_of(config, method="sgm")["above_scan"] == "plane"
    assert run_record.settings_of(config.replace(above_scan="background"), method="sgm")["above_scan"] == "background"
    assert run_record.rig_above_scan("auto", one) == "plane"
    assert run_record.rig_above_scan("auto", two) == "capped"
    assert run_record.rig_above_scan("auto", open_) is None
    assert run_record.rig_above_scan("plane", two) == "plane" and run_record.rig_above_scan("capped", open_) == "capped"


def _two_lidar_rig(tmp_path, *, stated: bool, sweep: str = "sweep.bin", on_grid: bool = False):
    """A rig JSON of two LiDARs 0.6 m apart looking along +x at a wall 20 m ahead and a point file ``sweep``
    (x, y, z, lidar): each LiDAR's 8000 points uniform in a 35 deg cone (a rosette's scan: no laser rows), or
    ``on_grid`` one point in every cell of the rig's 64 x 2048 grid within 30 deg (rows and columns), its spec
    stated (``beams``: a spinning LiDAR's rows) or not (the rig's grid its fallback)."""
    import json
    poses = [np.eye(4), np.eye(4)]
    poses[1][1, 3] = 0.6
    rng = np.random.default_rng(5)
    points = []
    for i, T in enumerate(poses):
        if on_grid:
            el, az = np.meshgrid(np.radians(35.0 - 70.0 / 64 * (np.arange(64) + 0.5)),
                                 2 * np.pi / 2048 * (np.arange(-170, 171) + 0.5), indexing="ij")
            keep = np.abs(el.ravel()) < np.radians(30.0)
            ray = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)[keep]
        else:
            cos_t = 1.0 - rng.random(8000) * (1.0 - np.cos(np.radians(35.0)))
            phi, sin_t = rng.random(8000) * 2 * np.pi, np.sqrt(1.0 - cos_t ** 2)
            ray = np.stack([cos_t, sin_t * np.cos(phi), sin_t * np.sin(phi)], 1)
        local = ray * (20.0 / ray[:, :1])
        points.append(np.column_stack([local + T[:3, 3], np.full(len(local), i)]))
    np.concatenate(points).astype(np.float32).tofile(tmp_path / sweep)
    lidars = [{"name": f"unit{i}", "T_points_lidar": T.tolist()} for i, T in enumerate(poses)]
    if stated:
        for lidar in lidars:
            lidar.update(beams=64, fov_up_deg=35.0, fov_down_deg=-35.0)
    K = [[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]]
    cam_from_lidar = [[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]]
    rig = {"lidar": {"beams": 64, "fov_up_deg": 35.0, "fov_down_deg": -35.0, "columns": 2048}, "lidars": lidars,
           "columns": ["x", "y", "z", "lidar"],
           "cameras": [{"name": "front", "width": 160, "height": 120, "K": K, "T_cam_lidar": cam_from_lidar}]}
    (tmp_path / "rig.json").write_text(json.dumps(rig))
    return tmp_path / sweep, tmp_path / "rig.json"


def _rules_the_pipeline_resolves(monkeypatch):
    """``(ran, reads)``: the multi-source program replaced by run_sources_stages with its stages stubbed (no
    JAX; zero depth), ``ran`` the above-scan rule of each tail it configured; ``reads`` each rig JSON read."""
    from jaxdepth._src import sources as S
    from jaxdepth.batch import program_cache
    from jaxdepth.io import rig as rig_io
    ran, reads = [], []

    def stages(sources, cameras, *, config, beams=None, seen=False, **options):
        def call(stage, *args, **statics):
            if stage is S.sources_stage_tail:
                ran.append(statics["config"].above_scan)
        S.run_sources_stages(sources, cameras, config=config, free_space=True,
                             beams=beams or S.default_beams(sources), call=call)
        depth = np.zeros((cameras.K.shape[0], 120, 160), np.float32)
        return (depth, np.ones(cameras.K.shape[0], np.int64)) if seen else depth

    read = rig_io.read_rig_json
    monkeypatch.setattr(program_cache, "sources_stages", stages)
    for module in (jaxdepth.io, rig_io):         # the names the CLI, the job and the record import it by
        monkeypatch.setattr(module, "read_rig_json", lambda path: reads.append(path) or read(path))
    return ran, reads


@pytest.mark.parametrize("stated, rule", [(False, "plane"), (True, "capped")])
def test_complete_rig_records_the_rule_its_sources_resolve(tmp_path, monkeypatch, stated, rule):
    """complete-rig on two rosette LiDARs (no stated spec: each judged on a grid of its own points' spacing)
    records "plane", on two LiDARs stating their scan lines "capped": each time the rule the multi-source
    pipeline resolved for that sweep (run_sources_stages' tail config, its stages stubbed: no JAX), and
    the rig JSON is read once."""
    import json

    from jaxdepth import cli
    ran, reads = _rules_the_pipeline_resolves(monkeypatch)
    sweep, rig = _two_lidar_rig(tmp_path, stated=stated)
    assert cli.main(["complete-rig", str(sweep), str(rig), str(tmp_path / "out"), "-q"]) == 0
    recorded = json.loads((tmp_path / "out" / "jaxdepth_run.json").read_text())["settings"]["above_scan"]
    assert ran == [rule] and recorded == rule
    assert len(reads) == 1


@pytest.mark.slow  # four whole-pipeline programs (test_rig_sizes' edge rig)
@pytest.mark.xdist_group("rig_mixed_sizes")  # its complete_rig and one-source programs are test_sources' edge-rig test's
def test_multi_source_default_follows_the_rule_and_one_lidar_equals_the_single_path():
    """The same cloud: as one source its default is the single-sweep path's (``complete_rig``'s program, both the
    plane); as two LiDARs of one sweep (the same points twice) its default equals explicit ``capped``, and is
    its program (resolved on the host, before the ``jit``: no trace of its own), and an explicit ``plane``
    there resolves to the plane."""
    from jaxdepth._src.above_scan import resolved_config
    from jaxdepth._src.sources import complete_sources, make_sources

    from _harness import _top_level_traces
    from scenes import SMALL_LIDAR, edge_size_rig
    points, valid, cameras = edge_size_rig()
    cams = jaxdepth.stack_cameras(cameras)
    single = np.asarray(jaxdepth.complete_rig(points, valid, cams, lidar=SMALL_LIDAR))
    one = make_sources(points[None], valid[None], np.eye(4)[None], lidars=(SMALL_LIDAR,))
    np.testing.assert_array_equal(np.asarray(complete_sources(one, cams)), single)
    two = make_sources(np.stack([points] * 2), np.stack([valid] * 2), np.stack([np.eye(4)] * 2),
                       lidars=(SMALL_LIDAR,) * 2, sweep=(0, 0))
    capped = np.asarray(complete_sources(two, cams, config=jaxdepth.SGMConfig(above_scan="capped")))
    traces = _top_level_traces[0]
    np.testing.assert_array_equal(np.asarray(complete_sources(two, cams)), capped)
    assert _top_level_traces[0] == traces                    # the default ran explicit capped's program
    # The explicit plane stays the plane (its own rule, resolved on the host). On this rig the two rules' depths
    # differ only by rounding (63 pixels by 1 ulp at the production flags, none at level 0 since the whole-window
    # tail, rigtail14): their outputs cannot tell the rules apart here (test_capped_through_the_pipeline_changes_only_above_the_scan does).
    assert resolved_config(jaxdepth.SGMConfig(), two).above_scan == "capped"
    assert resolved_config(jaxdepth.SGMConfig(above_scan="plane"), two).above_scan == "plane"
    assert resolved_config(jaxdepth.SGMConfig(), one).above_scan == "plane"


def test_complete_rig_sweeps_record_the_first_sweeps_rule_and_fail_a_sweep_that_resolves_another(tmp_path, monkeypatch,
                                                                                                    capsys):
    """complete-rig over a folder of sweeps whose LiDARs state no spec: the record holds the rule of the first
    sweep (two rosettes: "plane", as the pipeline resolved it); a sweep whose points fill the rig's grid (its
    LiDARs judged in lines: "capped") is not completed under that record: it fails, named."""
    import json

    from jaxdepth import cli
    ran, reads = _rules_the_pipeline_resolves(monkeypatch)
    (tmp_path / "sweeps").mkdir()
    _two_lidar_rig(tmp_path / "sweeps", stated=False, sweep="a.bin")
    _, rig = _two_lidar_rig(tmp_path / "sweeps", stated=False, sweep="b.bin", on_grid=True)
    (tmp_path / "rig.json").write_text(rig.read_text())
    rig.unlink()
    code = cli.main(["complete-rig", str(tmp_path / "sweeps"), str(tmp_path / "rig.json"), str(tmp_path / "out")])
    err = capsys.readouterr().err
    recorded = json.loads((tmp_path / "out" / "jaxdepth_run.json").read_text())["settings"]["above_scan"]
    assert code == 1 and ran == ["plane"] and recorded == "plane" and len(reads) == 1
    assert "b.bin" in err and "'capped'" in err and (tmp_path / "out" / "a" / "front.png").exists()
    assert not (tmp_path / "out" / "b").exists()
