"""Several sources (LiDARs x sweeps): per-source normals and viewpoints, free space seen by other sweeps."""

from __future__ import annotations

import argparse
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdepth
from jaxdepth._src.normals import point_normals
from jaxdepth._src.outliers import outlier_keep_mask
from jaxdepth._src.sources import (_camera_view, camera_witness, complete_sources, complete_sources_stages, free_space_keep,
                                   free_space_margin, make_sources, reference_view, source_keep_mask, source_normals)
from jaxdepth._src.poses import rotation_rpy
from jaxdepth._src.scene import scene_arrays
from jaxdepth._src.synthetic import make_street_scene
from jaxdepth._src.synthetic_sequences import _cast_sweep, make_street_sequence
from jaxdepth._src.types import LidarSpec

from _harness import compiled_programs
from scenes import SMALL_LIDAR, edge_size_rig, stereo_cameras

SPEC = LidarSpec(beams=32, fov_up_deg=10.0, fov_down_deg=-25.0, columns=512)
WALL_X = 20.0


def _pose(t=(0.0, 0.0, 0.0), roll=0.0, pitch=0.0, yaw=0.0):
    T = np.eye(4)
    T[:3, :3] = rotation_rpy(roll, pitch, yaw, degrees=True)
    T[:3, 3] = t
    return T


def _sweep(scene, T, spec=SPEC):
    """Ray-cast points (reference frame) of a LiDAR posed at T."""
    pts, valid = _cast_sweep(scene, T[:3, :3], T[:3, 3], lidar=spec, max_range_m=60.0)
    return np.asarray(pts)[np.asarray(valid)]


#: Points per source of every test's Sources: one sweep of SPEC at most, so tests with the same number
#: of sources and sweeps share their compiled programs (padding rows are invalid and never judged).
P_BUCKET = SPEC.beams * SPEC.columns


def _sources(parts, sweeps, spec=SPEC):
    """Sources of [(points, T)] padded to one bucket of P_BUCKET points (more only if a part is longer)."""
    P = max([P_BUCKET] + [len(p) for p, _ in parts])
    pts = np.zeros((len(parts), P, 3), np.float32)
    valid = np.zeros((len(parts), P), bool)
    for i, (p, _) in enumerate(parts):
        pts[i, :len(p)] = p
        valid[i, :len(p)] = True
    return make_sources(pts, valid, np.stack([T for _, T in parts]), lidars=(spec,) * len(parts), sweep=sweeps)


#: One jit of each free-space function for the module: the tests below of one (sources, sweeps) count run
#: one compiled program (the eager functions themselves: test_free_space_vmap_and_jit_equal_eager).
_view = jax.jit(reference_view, static_argnames=("neighbour_sweeps", "end_sweeps"))
_keep = jax.jit(free_space_keep)


def _street(*, boxes=(), cylinders=()):
    """Ground 1.7 m below the reference origin, a wall across the street at x = 20 m."""
    return scene_arrays(planes=[[0, 0, 1, -1.7], [1, 0, 0, WALL_X]], boxes=list(boxes) or None,
                        cylinders=list(cylinders) or None)


# ---------------------------------------------------------------- Step 1 per source

@pytest.mark.xdist_group("sources_normals")  # one worker compiles their shared program once
def test_source_normals_are_the_sources_own_range_image_normals_rotated_back():
    scene = _street()
    T = _pose((0.5, 0.3, -0.4), roll=4.0, pitch=7.0, yaw=20.0)
    pts = _sweep(scene, T)
    src = _sources([(pts, T)], (0,))
    got = np.asarray(source_normals(src))[0, :len(pts)]
    local = np.zeros(src.points.shape, np.float32)              # inv(T) applied, padded as the source
    local[0, :len(pts)] = (pts - T[:3, 3]) @ T[:3, :3]
    # point_normals in the source's own frame, over a batch of one (the program source_normals runs;
    # the stage table checks point_normals' vmap against its per-input calls)
    want = np.asarray(jax.vmap(functools.partial(point_normals, lidar=SPEC))(local, src.valid))[0, :len(pts)] \
        @ T[:3, :3].T
    np.testing.assert_allclose(got, want, atol=2e-5)
    # analytic: ground points' normals are +z, wall points' -x (facing the LiDAR)
    ground = np.abs(pts[:, 2] + 1.7) < 1e-3
    wall = np.abs(pts[:, 0] - WALL_X) < 1e-3
    inner = lambda m: m & (np.abs(pts[:, 1]) < 10)
    assert np.median(got[inner(ground) & (pts[:, 0] < 15), 2]) > 0.999
    assert np.median(-got[inner(wall) & (pts[:, 2] > -1.0), 0]) > 0.999


@pytest.mark.xdist_group("sources_normals")  # one worker compiles their shared program once
def test_source_normals_vmap_equals_loop():
    # A batch of two one-source Sources of different poses (the per-source calls are the program of
    # the test above: one source of P_BUCKET points)
    scene = _street()
    Ts = [_pose((0, 0, 0)), _pose((-1.5, 0.2, 0.1), yaw=3.0)]
    one_source = [_sources([(_sweep(scene, T), T)], (0,)) for T in Ts]
    batch = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *one_source)
    out = jax.vmap(source_normals)(batch)
    for b in range(2):
        one = jax.tree_util.tree_map(lambda a: a[b], batch)
        np.testing.assert_array_equal(np.asarray(out[b]), np.asarray(source_normals(one)))


# ---------------------------------------------------------------- Step 2 per source

@functools.lru_cache(maxsize=1)
def _three_origins():
    """A street image whose pixels come from three sources at different origins, and the oracle:
    Algorithm 1 run once per source origin, each pixel taking its own source's result."""
    frame = make_street_scene(1, lidar=SPEC, cameras="kitti", image_scale=0.25)
    cam = frame.cameras[0]
    depth, index = jaxdepth.project_to_image(frame.points, frame.valid, cam.K, cam.T_cam_lidar,
                                             height=cam.height, width=cam.width)
    hit = np.asarray(index) >= 0
    safe = np.where(hit, np.asarray(index), 0)
    pc = np.asarray(frame.points)[safe] @ np.asarray(cam.T_cam_lidar)[:3, :3].T + np.asarray(cam.T_cam_lidar)[:3, 3]
    points_cam = np.where(hit[None], np.moveaxis(pc, -1, 0), 0.0).astype(np.float32)
    pixel_source = np.where(hit, safe % 3, -1).astype(np.int32)
    T3 = np.stack([np.asarray(cam.T_cam_lidar)] * 3).astype(np.float32)
    T3[1, :3, 3] += (1.2, -0.4, -1.5)                     # origins beside, above and behind the first
    T3[2, :3, 3] += (-0.8, 0.6, 0.9)
    want = hit.copy()
    for s in range(3):
        keep_s = np.asarray(outlier_keep_mask(depth, cam.K, T3[s], beams=32, points_cam=points_cam))
        want &= np.where(pixel_source == s, keep_s, True)
    assert all((hit & ~want & (pixel_source == s)).any() for s in range(3))   # each source loses points
    return np.asarray(depth), pixel_source, points_cam, np.asarray(cam.K), T3, hit, safe, want


@pytest.mark.xdist_group("sources_keep_mask")  # one worker compiles their shared program once
@pytest.mark.parametrize("label", [np.int32, np.int8])     # int8: the rigs' source label canvas
def test_source_keep_mask_tests_each_pixel_from_its_own_origin(label):
    """One pass over the image for all sources equals one pass of Algorithm 1 per source origin."""
    depth, pixel_source, points_cam, K, T3, _, _, want = _three_origins()
    got = source_keep_mask(depth, pixel_source.astype(label), points_cam, K, T3, beams=32)
    np.testing.assert_array_equal(np.asarray(got), want)


@pytest.mark.xdist_group("sources_keep_mask")  # one worker compiles their shared program once
def test_keep_mask_origins_as_table_equal_origin_maps():
    """Each pixel's origin as the sources' (S, 3) table and the pixel's source (what ``source_keep_mask`` passes)
    gives the mask of the (3, H, W) map of each pixel's origin, bit for bit, with and without shadow pixels."""
    from jaxdepth._src.outliers import _keep_mask, window_half_sizes
    depth, _, points_cam, K, T3, hit, safe, want = _three_origins()
    table = T3[:, :3, 3]
    maps = np.moveaxis(table[safe % 3 * hit], -1, 0)
    src = (safe % 3 * hit).astype(np.int32)
    hw, hh = window_half_sizes(*depth.shape, beams=32, max_half_width_px=12, max_half_height_px=24)
    # epsilon as source_keep_mask passes it (a float32 array: a Python float is weakly typed, another program),
    # so the table form's two programs are the ones the tests above and below compile through source_keep_mask
    opts = dict(beams=32, half_width=hw, half_height=hh)
    eps = jnp.float32(1.0)
    for nearer in (None, hit & (safe % 7 == 0)):
        a = _keep_mask(depth, K, T3[0], points_cam, eps, origins=maps, nearer=nearer, **opts)
        b = _keep_mask(depth, K, T3[0], points_cam, eps, origins=table, pixel_source=src, nearer=nearer, **opts)
        assert (hit & ~np.asarray(a)).any()
        np.testing.assert_array_equal(np.asarray(b), np.asarray(a))


def _nearer_oracle(depth, candidates, *, beams, eps=1.0):
    """Brute-force condition 2 alone: a candidate is removed when a pixel of S(i) is nearer by more than eps."""
    from jaxdepth._src.config import DEFAULT_CONFIG
    from jaxdepth._src.outliers import window_half_sizes
    height, width = depth.shape
    hw, hh = window_half_sizes(height, width, beams=beams, max_half_width_px=DEFAULT_CONFIG.outlier_max_half_width_px,
                               max_half_height_px=DEFAULT_CONFIG.outlier_max_half_height_px)
    valid = depth > 0
    k = min((width * beams - 1) // max(int(valid.sum()), 1), hw)
    z = np.pad(np.where(valid, depth, np.inf), ((hh, hh), (k, k)), constant_values=np.inf)
    near = np.full(depth.shape, np.inf)
    for dv in range(2 * hh + 1):
        for du in range(2 * k + 1):
            near = np.minimum(near, z[dv:dv + height, du:du + width])
    return ~(candidates & valid & (depth > near + eps))


@pytest.mark.xdist_group("sources_keep_mask")  # one worker compiles their shared program once
def test_source_keep_mask_shadow_pixels_also_fall_to_a_nearer_pixel():
    """Shadow pixels are also removed by condition 2 alone (brute-force window oracle)."""
    depth, pixel_source, points_cam, K, T3, hit, safe, want = _three_origins()
    shadow = hit & (safe % 7 == 0)
    got = np.asarray(source_keep_mask(depth, pixel_source, points_cam, K, T3, beams=32, pixel_shadow=shadow))
    extra = ~_nearer_oracle(depth, shadow, beams=32)
    assert (extra & want).any()                            # the shadow rule removes something more
    np.testing.assert_array_equal(got, want & ~extra)


def _per_sweep_oracle(depth, pixel_sweep, points_cam, K, origins, *, beams, eps=1.0, tol=1e-6):
    """Brute force, float64: sweep s's pixels judged by the footprint form of Algorithm 1 (as
    ``test_outliers.footprint_double_loop``) from their own origin against the reference sweep's pixels and
    sweep s's own (the reference: its own alone), with the window and cells of N = the reference's pixels.
    Returns (keep, unsure: a decision within ``tol`` of a threshold)."""
    from jaxdepth._src.config import DEFAULT_CONFIG as D
    height, width = depth.shape
    valid = depth > 0
    n = int((valid & (pixel_sweep == 0)).sum()) or int(valid.sum())
    cell_u, cell_v = width * beams / n, height / beams
    vs, us = np.nonzero(valid)
    p, z, sw = points_cam[:, vs, us].astype(np.float64), depth[vs, us].astype(np.float64), pixel_sweep[vs, us]
    K = K.astype(np.float64)
    bu, bv = (K[0, 0] * p[0] + K[0, 1] * p[1]) / p[2] + K[0, 2], K[1, 1] * p[1] / p[2] + K[1, 2]
    keep, unsure = valid.copy(), np.zeros_like(valid)
    for i in range(len(vs)):
        q = p - origins[i][:, None]
        ok = q[2] > 1e-3
        qz = np.where(ok, q[2], 1.0)
        au, av = (K[0, 0] * q[0] + K[0, 1] * q[1]) / qz + K[0, 2], K[1, 1] * q[1] / qz + K[1, 2]
        du, dv = np.abs(us - us[i]), np.abs(vs - vs[i])
        js = np.nonzero(((sw == 0) | (sw == sw[i])) & (du < cell_u) & (du <= D.outlier_max_half_width_px)
                        & (dv < cell_v) & (dv <= D.outlier_max_half_height_px) & (np.arange(len(vs)) != i)
                        & ok & ok[i] & (z[i] > z + eps))[0]
        ra = np.stack([(au[i] - au[js]) / cell_u, (av[i] - av[js]) / cell_v])
        rb = np.stack([(bu[i] - bu[js]) / cell_u, (bv[i] - bv[js]) / cell_v])
        m = rb - ra
        mm = np.sum(m * m, 0)
        margins = np.stack([-np.sum(ra * m, 0), np.sum(rb * m, 0), mm - 4 * (ra[0] * m[1] - ra[1] * m[0]) ** 2])
        margins = np.where(mm * cell_u * cell_v > 1e-6, margins, -1.0)
        scale = np.maximum(mm, 1e-300)
        if np.all(margins > tol * scale, 0).any():
            keep[vs[i], us[i]] = False
        elif np.all(margins > -tol * scale, 0).any():
            unsure[vs[i], us[i]] = True
    return keep, unsure


@pytest.mark.xdist_group("sources_keep_mask")  # one worker compiles their shared program once
def test_each_sweep_is_also_judged_with_one_sweeps_window():
    """outlier_sweeps="each": the merged pass (one pass per origin, as above) AND, per sweep, Algorithm 1 against the
    reference sweep's pixels and the sweep's own with N = the reference's pixels (brute-force oracle); "merged" and
    one sweep: the merged pass alone."""
    depth, pixel_source, points_cam, K, T3, hit, safe, want = _three_origins()
    sweep = (0, -1, -2)
    per, unsure = _per_sweep_oracle(depth, np.asarray(sweep)[np.maximum(pixel_source, 0)], points_cam, K,
                                    T3[np.maximum(pixel_source, 0), :3, 3][hit], beams=32)
    assert (hit & ~per & (pixel_source == 0)).any() and (want & ~per & ~unsure).any()   # each pass removes
    got = np.asarray(source_keep_mask(depth, pixel_source, points_cam, K, T3, beams=32, source_sweep=sweep))
    sure = ~unsure
    np.testing.assert_array_equal(got[sure], (want & per)[sure])
    assert unsure.sum() <= 2
    for kw in (dict(source_sweep=(0, 0, 0)), {}):
        np.testing.assert_array_equal(np.asarray(source_keep_mask(depth, pixel_source, points_cam, K, T3, beams=32,
                                                                  **kw)), want)


def test_each_sweep_is_judged_alone_for_a_scan_without_scan_lines():
    """outlier_sweeps="auto" runs the per-sweep passes where a reference source has a witness grid of its own
    (a rosette), not for a LiDAR on its spec's grid; "each" / "merged" force it; one sweep never."""
    from jaxdepth._src.sources import per_sweep_applies
    pts, valid = np.zeros((2, 4, 3), np.float32), np.ones((2, 4), bool)
    own = LidarSpec(beams=96, fov_up_deg=35.0, fov_down_deg=-35.0, columns=512)

    def src(sweep, witnesses=None):
        return make_sources(pts, valid, np.stack([np.eye(4)] * 2), lidars=(SPEC, SPEC), sweep=sweep,
                            witnesses=witnesses)
    rosette, spinning = src((0, -1), (own, own)), src((0, -1))
    assert per_sweep_applies(rosette) and not per_sweep_applies(spinning)
    assert per_sweep_applies(spinning, "each") and not per_sweep_applies(rosette, "merged")
    assert not any(per_sweep_applies(src((0, 0), (own, own)), m) for m in ("auto", "each"))
    assert jaxdepth.SGMConfig().outlier_sweeps == "auto"
    from jaxdepth.options import add_config_options, config_changes
    p = argparse.ArgumentParser()
    add_config_options(p)
    assert config_changes(p.parse_args(["--outlier-sweeps", "each"]))["outlier_sweeps"] == "each"
    assert "outlier_sweeps" not in config_changes(p.parse_args([]))
    with pytest.raises(ValueError, match="outlier_sweeps"):
        jaxdepth.SGMConfig(outlier_sweeps="all")


def test_one_sweep_as_complete_rig_takes_it():
    """rig.one_sweep_lidar, the entry points' host dispatch: one source of the reference sweep at the origin, rows
    from elevation, Step 2's L its beams; anything else (a pose off the origin or known only under a trace, laser
    rows, another L, another sweep, two sources) keeps the multi-source program. A dispatched call checks its
    images as complete_sources (no compile: the check is an eval_shape)."""
    import dataclasses

    from jaxdepth._src.rig import one_sweep_lidar
    pts, valid = np.zeros((1, 8, 3), np.float32), np.ones((1, 8), bool)
    one = make_sources(pts, valid, np.eye(4)[None], lidars=(SPEC,))
    assert one_sweep_lidar(one) == SPEC and one_sweep_lidar(one, SPEC.beams) == SPEC
    moved = np.eye(4)[None].copy()
    moved[0, 0, 3] = 1e-3
    assert one_sweep_lidar(make_sources(pts, valid, moved, lidars=(SPEC,))) is None
    assert one_sweep_lidar(one, SPEC.beams + 1) is None
    assert one_sweep_lidar(make_sources(pts, valid, np.eye(4)[None], lidars=(SPEC,), rows=np.zeros((1, 8)))) is None
    assert one_sweep_lidar(make_sources(pts, valid, np.eye(4)[None], lidars=(SPEC,), sweep=(1,))) is None
    two = make_sources(np.concatenate([pts] * 2), np.concatenate([valid] * 2), np.stack([np.eye(4)] * 2),
                       lidars=(SPEC,) * 2)
    assert one_sweep_lidar(two) is None
    traced = []
    jax.jit(lambda T: traced.append(one_sweep_lidar(dataclasses.replace(one, T_ref_source=T))) or T)(one.T_ref_source)
    assert traced == [None]
    cams = jaxdepth.stack_cameras(edge_size_rig()[2])
    with pytest.raises(ValueError, match="complete_sources.*images"):
        complete_sources(one, cams, config=jaxdepth.SGMConfig(guidance_weight=1.0))


@pytest.mark.slow  # complete_rig's whole program (test_rig_sizes' edge rig)
@pytest.mark.xdist_group("rig_mixed_sizes")  # on the worker of test_rig_sizes' edge-rig tests: compiled once
def test_one_source_at_the_origin_runs_complete_rigs_program():
    """complete_sources and complete_sources_stages of one source at the origin run complete_rig's (and
    complete_rig_stages') own programs: nothing compiles after the rig's calls, and the bytes are the rig's at any
    XLA level (the suite's level 0 too, where the multi-source program rounded Step 4's blur 1 ulp apart)."""
    points, valid, cameras = edge_size_rig()        # scenes.edge_size_rig: three turned cameras, edge points
    cams = jaxdepth.stack_cameras(cameras)
    want = jaxdepth.complete_rig(points, valid, cams, lidar=SMALL_LIDAR)
    stages = jaxdepth.complete_rig_stages(points, valid, cams, lidar=SMALL_LIDAR)
    assert (np.asarray(want) > 0).mean() > 0.5
    src = make_sources(points[None], valid[None], np.eye(4)[None], lidars=(SMALL_LIDAR,))
    with compiled_programs() as compiled:
        got, got_stages = complete_sources(src, cams), complete_sources_stages(src, cams)
    assert compiled == []
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    jax.tree.map(np.testing.assert_array_equal, jax.tree.map(np.asarray, got_stages), jax.tree.map(np.asarray, stages))


# ---------------------------------------------------------------- free space

def test_a_car_that_moved_leaves_no_ghost():
    car_then = [10.0, -0.5, -1.7 + 0.75, 2.2, 0.9, 0.75, 0.0]          # where the car was one sweep ago
    car_now = [15.0, -0.5, -1.7 + 0.75, 2.2, 0.9, 0.75, 0.0]          # (centre, half sizes, yaw)
    T_ref, T_old = _pose(), _pose((-1.5, 0.0, 0.0))
    ref = _sweep(_street(boxes=[car_now]), T_ref)
    old = _sweep(_street(boxes=[car_then]), T_old)
    src = _sources([(ref, T_ref), (old, T_old)], (0, 1))
    keep = np.asarray(_keep(src))
    on_old_car = np.zeros(src.points.shape[1], bool)
    # points of the old car more than 0.4 m above the road (nearer the road the rays bracketing them
    # include the slanted road itself, within the margin: kept, as documented)
    on_old_car[:len(old)] = (np.abs(old[:, 0] - 10.0) <= 2.2 + 1e-3) & (np.abs(old[:, 1] + 0.5) <= 0.9 + 1e-3) \
        & (old[:, 2] > -1.3)
    assert on_old_car.sum() > 50
    seen_now = on_old_car.copy()           # ghost points in front of what the reference sweep saw there
    assert not keep[1][seen_now].any(), "ghost points of the car's old place survive"
    assert keep[0, :len(ref)].all(), "points of the reference sweep are never removed"
    static = np.zeros_like(on_old_car)
    static[:len(old)] = (old[:, 0] < 7.0) & (np.abs(old[:, 2] + 1.7) < 1e-3)     # ground in front of the old car
    assert keep[1][static].mean() > 0.99


def test_free_space_is_judged_by_the_rays_that_bracket_the_point():
    # Analytic oracle on a flat road 1.7 m below the reference LiDAR. A point q a quarter of a beam
    # spacing above beam b, at a column centre: the rays bracketing q are beams b - 1 and b (and
    # the columns either side, at the same elevations), and the nearest of them is beam b, which
    # hits the road at R = 1.7 / sin(-elevation_b). q lies in free space iff |q| < R - margin(R):
    # a ray farther below q (the next row of a 3 x 3 block) is no witness of the space at q.
    T_ref = _pose()
    ref = _sweep(_street(), T_ref)
    dv = np.radians(35.0) / 31
    beam = np.arange(14, 25)
    el_b = np.radians(10.0) - beam * dv
    R = 1.7 / np.sin(-el_b)
    azimuth = np.pi - 2 * np.pi * (np.arange(250, 262) + 0.5) / 512
    el_q = el_b + 0.25 * dv
    inside = R - free_space_margin(R, SPEC) - 0.3                   # free
    outside = R - free_space_margin(R, SPEC) + 0.3                  # within the margin: kept
    q = []
    for r in (inside, outside):
        d = np.stack([np.cos(el_q)[:, None] * np.cos(azimuth), np.cos(el_q)[:, None] * np.sin(azimuth),
                      np.broadcast_to(np.sin(el_q)[:, None], (beam.size, azimuth.size))], -1)
        q.append((d * r[:, None, None]).reshape(-1, 3))
    q = np.concatenate(q).astype(np.float32)
    src = _sources([(ref, T_ref), (q, _pose((-1.5, 0.0, 0.0)))], (0, 1))
    free = np.asarray(_view(src)[0])[1, :len(q)]
    n = beam.size * azimuth.size
    assert free[:n].all(), f"{int((~free[:n]).sum())} of {n} points every bracketing ray passed are kept"
    assert not free[n:].any(), "points within the margin of the bracketing ray's road hit are kept"


def test_a_car_the_reference_lidar_could_not_check_is_judged_by_another_sweep():
    # A box hides the car's old place from the reference LiDAR (and from a camera beside it); the
    # car stood there one sweep ago and not two sweeps ago. The sweep before saw through that space.
    # (Sweep 1's scene holds only the car: the box is off its line of sight to the car's visible
    # side, and one box per scene shares the ray caster's compilation with the tests above.)
    occluder = [6.0, 0.0, -1.7 + 1.1, 0.2, 0.8, 1.1, 0.0]
    car = [12.0, 0.0, -1.7 + 0.75, 1.0, 1.0, 0.75, 0.0]
    T0, T1, T2 = _pose(), _pose((-1.5, 3.0, 0.0)), _pose((-3.0, 4.0, 0.0))
    parts = [(_sweep(_street(boxes=[occluder]), T0), T0), (_sweep(_street(boxes=[car]), T1), T1),
             (_sweep(_street(boxes=[occluder]), T2), T2)]
    src = _sources(parts, (0, 1, 2))
    old = parts[1][0]
    on_car = (np.abs(old[:, 0] - 12.0) <= 1.0 + 1e-3) & (np.abs(old[:, 1]) <= 1.0 + 1e-3) & (old[:, 2] > -1.3)
    static = ~((np.abs(old[:, 0] - 12.0) <= 1.0 + 1e-3) & (np.abs(old[:, 1]) <= 1.0 + 1e-3))
    assert on_car.sum() > 30
    free, shadow, _ = (np.asarray(a)[..., 1, :len(old)] for a in _view(src))
    assert shadow[on_car].all(), "the reference LiDAR cannot see the car's old place: its rays stop at the box"
    assert free[on_car].mean() > 0.9, "the sweep before saw that space empty"
    by_all = free
    assert not by_all[static].any(), "road, wall and occluder are static: never free"


def test_bounded_witnesses_equal_every_sweep_when_they_cover_every_other_sweep():
    # Sweeps 0, 1, 2: the non-reference sweeps 1 and 2 are one apart and are the window's ends, so
    # one neighbour on each side, or the end sweeps as witnesses, is every other sweep (sweep 0's
    # points are never judged): the verdicts must equal the every-sweep rule's. Reference witnesses
    # alone differ: sweep 2 is what removes the car hidden from sweep 0.
    occluder = [6.0, 0.0, -1.7 + 1.1, 0.2, 0.8, 1.1, 0.0]
    car = [12.0, 0.0, -1.7 + 0.75, 1.0, 1.0, 0.75, 0.0]
    T0, T1, T2 = _pose(), _pose((-1.5, 3.0, 0.0)), _pose((-3.0, 4.0, 0.0))
    src = _sources([(_sweep(_street(boxes=[occluder]), T0), T0), (_sweep(_street(boxes=[car]), T1), T1),
                    (_sweep(_street(boxes=[occluder]), T2), T2)], (0, 1, 2))
    view = _view
    every = view(src, neighbour_sweeps=None, end_sweeps=False)
    for k, ends in ((1, False), (0, True)):
        for a, b in zip(view(src, neighbour_sweeps=k, end_sweeps=ends), every):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    ref_only = view(src, neighbour_sweeps=0, end_sweeps=False)
    np.testing.assert_array_equal(np.asarray(ref_only[1]), np.asarray(every[1]))       # shadow: reference only
    assert np.asarray(every[0][1] & ~ref_only[0][1]).sum() > 30


def test_a_neighbour_or_end_sweep_removes_a_ghost_and_no_other_sweep_does():
    # Analytic: sweep 1's LiDAR sees a flat road (the reference sweep holds no point, so it has
    # no evidence). Sweeps 2, 3 and 4 hold the same points, each in front of the road hit of the
    # beam below it by more than the margin (as in the bracketing test): in sweep 1's free space.
    # With one neighbour on each side sweep 1 judges sweep 2 (removed) but not sweeps 3 and 4;
    # as an end of the window (sweeps 1 and 4) it judges them all. The copies of the floating
    # points are no free-space evidence against each other.
    T = _pose()
    dv = np.radians(35.0) / 31
    el = (np.radians(10.0) - np.arange(32) * dv)[:, None]          # SPEC's beams, as the ray caster casts them
    az = np.pi - 2 * np.pi * (np.arange(512) + 0.5) / 512
    rng = np.where(el < -0.03, 1.7 / np.sin(-np.minimum(el, -0.03)), np.inf) + 0 * az
    ray = np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), -1)
    road = (ray * rng[..., None])[np.isfinite(rng) & (rng < 60.0)].astype(np.float32)
    el_b = np.radians(10.0) - np.arange(14, 25) * dv
    R = 1.7 / np.sin(-el_b)
    azimuth = np.pi - 2 * np.pi * (np.arange(250, 262) + 0.5) / 512
    el_q = (el_b + 0.25 * dv)[:, None]
    r = (R - free_space_margin(R, SPEC) - 0.3)[:, None, None]
    d = np.stack(np.broadcast_arrays(np.cos(el_q) * np.cos(azimuth), np.cos(el_q) * np.sin(azimuth), np.sin(el_q)), -1)
    q = (d * r).reshape(-1, 3).astype(np.float32)
    src = _sources([(np.zeros((0, 3), np.float32), T), (road, T), (q, T), (q, T), (q, T)], (0, 1, 2, 3, 4))
    view = _view
    free = {(k, e): np.asarray(view(src, neighbour_sweeps=k, end_sweeps=e)[0])[:, :len(q)]
            for k, e in ((0, False), (1, False), (0, True))}
    assert not free[0, False].any(), "the empty reference sweep is no witness"
    assert free[1, False][2].all() and not free[1, False][3:].any()
    assert free[0, True][2:].all()
    assert not free[0, True][1].any(), "the road lies behind the floating points: never free"


def test_a_pole_in_front_of_a_wall_seen_from_two_origins():
    pole = [8.0, 0.0, 0.15, -1.7, 3.0]
    scene = _street(cylinders=[pole])
    T_ref, T_other = _pose(), _pose((0.0, 1.5, 0.0))
    ref, other = _sweep(scene, T_ref), _sweep(scene, T_other)
    src = _sources([(ref, T_ref), (other, T_other)], (0, 1))
    free, shadow, _ = (np.asarray(a)[..., 1, :len(other)] for a in _view(src))
    # wall points the other origin sees behind the pole (hidden from the reference LiDAR)
    d = other - np.array([0.0, 0.0, 0.0])
    behind = (np.abs(other[:, 0] - WALL_X) < 1e-3) & (np.abs(np.arctan2(d[:, 1], d[:, 0])) < 0.15 / 8.0 * 0.8) \
        & (other[:, 2] > -1.5) & (other[:, 2] < 2.0)
    assert behind.sum() >= 3
    assert not free[behind].any(), "wall points behind the pole are behind, not in front: kept"
    assert shadow[behind].all(), "and they lie in the reference LiDAR's shadow"
    assert not free.any(), "a static scene has no free-space points"


def test_a_post_hides_wall_points_an_origin_5_m_behind_saw():
    # Analytic oracle: a post (radius 0.5 m at x = 4 m) in front of the wall; the reference LiDAR (and a
    # camera beside it) at the origin, an earlier sweep's LiDAR 5 m behind. That origin sees the wall in
    # a band on each side of the post's narrower shadow that the reference LiDAR cannot see. Such a point
    # is ``hidden`` when every ray of the reference LiDAR bracketing it hits the post: its azimuth more
    # than 1.5 column spacings inside the post's silhouette (its elevation a beam spacing inside the
    # silhouette and the reference LiDAR's field of view).
    # No point of the old sweep that the reference origin sees (its line of sight misses the post) is
    # hidden, nor any point in the silhouette's edge columns.
    cx, radius = 4.0, 0.5
    scene = _street(cylinders=[[cx, 0.0, radius, -1.7, 3.0]])
    T_ref, T_old = _pose(), _pose((-5.0, 0.0, 0.0))
    old = _sweep(scene, T_old)
    src = _sources([(_sweep(scene, T_ref), T_ref), (old, T_old)], (0, 1))
    hidden = np.asarray(_view(src)[2])
    assert hidden.shape == (1, 2, src.points.shape[1])
    assert not hidden[0, 0].any(), "points of the reference sweep are never judged"
    h = hidden[0, 1, :len(old)]
    az = np.abs(np.arctan2(old[:, 1], old[:, 0]))
    half = np.arcsin(radius / cx)                                       # the post's half silhouette
    col, row = 2 * np.pi / SPEC.columns, np.radians(35.0) / 32
    el = np.arctan2(old[:, 2], np.hypot(old[:, 0], old[:, 1]))
    top = min(np.arctan2(3.0, cx + radius), np.radians(SPEC.fov_up_deg))     # post top or field of view
    on_wall = np.abs(old[:, 0] - WALL_X) < 1e-3
    deep = on_wall & (az < half - 1.5 * col) & (el < top - row) & (np.linalg.norm(old, axis=1) > cx + radius)
    # 2-D distance from the post's axis to the segment origin -> q: the line of sight misses the post
    t = np.clip(old[:, 0] * cx / np.maximum(np.sum(old[:, :2] ** 2, axis=1), 1e-9), 0.0, 1.0)
    seen = np.hypot(t * old[:, 0] - cx, t * old[:, 1]) > radius + 1e-3
    assert deep.sum() >= 20 and seen.sum() > 1000
    assert h[deep].all(), f"{int((deep & ~h).sum())} of {int(deep.sum())} wall points behind the post kept"
    assert not h[seen].any(), "a point the reference origin (and the camera) sees is never hidden"
    assert not h[on_wall & (az > half - 0.5 * col)].any(), "edge columns: a bracketing ray passes the post"


def test_a_camera_takes_the_nearest_reference_lidar_as_witness():
    # Reference LiDARs at x = 0 and x = 1.2 (sweep 0) and one of sweep 1 right at the camera: the witness
    # is the nearest reference-sweep LiDAR, usable within the baseline bound.
    Ts = np.stack([_pose(), _pose((1.2, 0.0, -0.9)), _pose((0.9, 0.0, 0.0))]).astype(np.float32)
    sweep = (0, 0, 1)
    for cam_x, want, usable in ((0.3, 0, True), (1.0, 1, True), (3.0, 1, False)):
        T_cam_ref = _pose((-cam_x, 0.0, 0.0)).astype(np.float32)       # camera centre at (cam_x, 0, 0)
        rank, ok = camera_witness(T_cam_ref, Ts, sweep=sweep)
        assert (int(rank), bool(ok)) == (want, usable)
    T_cams = np.stack([_pose((-x, 0.0, 0.0)) for x in (0.3, 1.0, 3.0)]).astype(np.float32)
    loop = [tuple(np.asarray(a) for a in camera_witness(T, Ts, sweep=sweep)) for T in T_cams]
    vm = jax.jit(jax.vmap(lambda T: camera_witness(T, Ts, sweep=sweep)))(T_cams)   # one program, not op by op
    jt = jax.jit(lambda T: camera_witness(T, Ts, sweep=sweep))
    for i, (r, ok) in enumerate(loop):
        assert (int(vm[0][i]), bool(vm[1][i])) == (int(r), bool(ok)) == tuple(
            (int(a) if a.dtype != bool else bool(a)) for a in (np.asarray(x) for x in jt(T_cams[i])))


@pytest.mark.slow  # the one-source program of the test above (test_rig_sizes' edge rig)
@pytest.mark.xdist_group("rig_mixed_sizes")  # on the worker of test_rig_sizes' edge-rig tests: compiled once
def test_occlusion_never_touches_one_sweep_or_the_reference_sweep():
    # One sweep: the option changes nothing (bit-identical; the edge rig, complete_rig's program, which one source
    # at the origin runs: the rule needs two sweeps). Two sweeps: every point it removes is an earlier sweep's.
    points, valid, cameras = edge_size_rig()
    cams = jaxdepth.stack_cameras(cameras)
    one = make_sources(points[None], valid[None], np.eye(4)[None], lidars=(SMALL_LIDAR,))
    np.testing.assert_array_equal(np.asarray(complete_sources(one, cams, occlusion=True)),
                                  np.asarray(complete_sources(one, cams, occlusion=False)))
    scene = _street(cylinders=[[4.0, 0.0, 0.5, -1.7, 3.0]])
    T_ref, T_old = _pose(), _pose((-5.0, 0.0, 0.0))
    src = _sources([(_sweep(scene, T_ref), T_ref), (_sweep(scene, T_old), T_old)], (0, 1))
    hidden = np.asarray(_view(src)[2])
    assert hidden[:, 1].any() and not hidden[:, 0].any()


def test_two_lidars_at_different_heights():
    low_box = [6.0, 0.0, -1.7 + 0.25, 0.3, 3.0, 0.25, 0.0]      # a 0.5 m high wall across the street (half sizes)
    ghost = [13.0, 0.0, -1.7 + 0.5, 0.5, 0.5, 0.5, 0.0]         # only there one sweep ago
    T_high, T_low = _pose((0.0, 0.0, 0.0)), _pose((0.5, 0.0, -1.0), pitch=5.0)
    scene_now = _street(boxes=[low_box])
    scene_then = _street(boxes=[low_box, ghost])
    shift = _pose((-1.0, 0.0, 0.0))
    parts = [(_sweep(scene_now, T_high), T_high), (_sweep(scene_now, T_low), T_low),
             (_sweep(scene_then, shift @ T_high), shift @ T_high), (_sweep(scene_then, shift @ T_low), shift @ T_low)]
    src = _sources(parts, (0, 0, 1, 1))
    keep = np.asarray(_keep(src))
    for s in (2, 3):
        pts = parts[s][0]
        k = keep[s, :len(pts)]
        on_ghost = (np.abs(pts[:, 0] - 12.5) < 1e-3) & (np.abs(pts[:, 1]) < 0.5) & (pts[:, 2] > -1.3)
        # ground behind the wall: hidden from the low LiDAR (0.2 m above the wall's top), seen by the high one
        behind_wall = (pts[:, 0] > 10.0) & (pts[:, 0] < 12.0) & (np.abs(pts[:, 2] + 1.7) < 1e-3) \
            & (np.abs(pts[:, 1]) < 1.0)
        assert not k[on_ghost].any()
        if s == 2:
            assert on_ghost.sum() > 0 and behind_wall.sum() > 0
        assert k[behind_wall].all()


def test_free_space_margin_grows_with_range_and_cell_size():
    coarse = LidarSpec(beams=16, fov_up_deg=15, fov_down_deg=-15, columns=1024)
    assert free_space_margin(40.0, SPEC) > free_space_margin(10.0, SPEC) > free_space_margin(0.0, SPEC)
    assert free_space_margin(20.0, coarse) > free_space_margin(20.0, SPEC)
    delta = np.radians(35.0) / 32
    assert free_space_margin(10.0, SPEC, noise_m=0.1, slope=1.0) == pytest.approx(0.1 + 10.0 * delta)
    gaps = jnp.asarray([0.001, 0.02])                                  # a measured gap; below the column step
    np.testing.assert_allclose(free_space_margin(10.0, SPEC, noise_m=0.1, slope=1.0, gap_rad=gaps),
                               [0.1 + 10.0 * 2 * np.pi / 512, 0.1 + 10.0 * 0.02], rtol=1e-6)


def test_free_space_margin_is_the_gap_between_the_bracketing_lasers():
    # Analytic oracle. A witness with uneven lasers (0.5 deg apart near the horizon, 4 deg at the edges;
    # one range-image row per laser by its ring) sees a wall at x = 20 m. A query point between two of
    # its lasers, at a column centre, is free iff |q| < R_lo - margin(R_lo), with R_lo the nearest wall
    # range of the 4 bracketing rays and margin = 0.3 + 2 R max(gap, 2 pi / columns), ``gap`` the two
    # lasers' own gap: not the field of view over the beam count (2 deg here), which would keep the
    # first points below and flag the second ones.
    elevations = np.array([8.0, 4.0, 1.0, 0.5, 0.0, -0.5, -1.0, -4.0, -8.0])
    spec = LidarSpec(beams=9, fov_up_deg=9.0, fov_down_deg=-9.0, columns=512)
    cols = np.arange(236, 276)                                          # azimuths within about +-14 deg
    theta = np.pi - 2 * np.pi * (cols + 0.5) / spec.columns

    def rays(el_deg, az):
        el = np.radians(el_deg)
        return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el) + 0 * az], -1)

    wall = np.concatenate([rays(e, theta) * (20.0 / rays(e, theta)[:, :1]) for e in elevations])
    rows = np.repeat(np.arange(elevations.size, dtype=np.int32), cols.size)
    az_q = theta[5:-5]
    step = 2 * np.pi / spec.columns
    queries, want = [], []
    # (elevation of q, its two lasers, slack, what the uniform margin would say)
    for el_q, pair, slack, old_free in ((0.25, (0.5, 0.0), -0.25, False), (0.25, (0.5, 0.0), 0.25, False),
                                        (6.0, (8.0, 4.0), 0.25, True)):
        # bracketing rays: the two lasers, at q's column and a neighbour (q sits on a column centre;
        # the wall's range changes by under 0.07 m from one column to the next, within the slack)
        r_lo = np.min([20.0 / (np.cos(np.radians(e)) * np.cos(az_q + k * step)) for e in pair for k in (-1, 0, 1)], 0)
        gap = np.radians(abs(pair[0] - pair[1]))
        margin = 0.3 + 2.0 * max(gap, step) * r_lo
        uniform = 0.3 + 2.0 * max(np.radians(18.0) / 9, step) * r_lo
        r_q = r_lo - margin + slack
        queries.append(rays(el_q, az_q) * r_q[:, None])
        want.append(np.full(az_q.size, slack < 0))
        assert np.all((r_q < r_lo - uniform) == old_free)
    q = np.concatenate(queries).astype(np.float32)
    P = max(len(wall), len(q))
    pts = np.zeros((2, P, 3), np.float32)
    valid = np.zeros((2, P), bool)
    pts[0, :len(wall)], valid[0, :len(wall)] = wall, True
    pts[1, :len(q)], valid[1, :len(q)] = q, True
    all_rows = np.full((2, P), -1, np.int32)
    all_rows[0, :len(wall)] = rows
    src = make_sources(pts, valid, np.stack([_pose(), _pose((-1.0, 0.0, 0.0))]), lidars=(spec, spec), sweep=(0, 1),
                       rows=all_rows)
    free = np.asarray(_view(src)[0])[1, :len(q)]  # compiled: called plainly it compiles every primitive op by op
    np.testing.assert_array_equal(free, np.concatenate(want))


def test_free_space_vmap_and_jit_equal_eager():
    scene = _street(boxes=[[10.0, -0.5, -0.95, 2.2, 0.9, 0.75, 0.0]])
    Ts = [_pose(), _pose((-1.5, 0.1, 0.0))]
    src = _sources([(_sweep(_street(), Ts[0]), Ts[0]), (_sweep(scene, Ts[1]), Ts[1])], (0, 1))
    eager = np.asarray(free_space_keep(src))
    np.testing.assert_array_equal(np.asarray(_keep(src)), eager)
    batch = jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), src)
    np.testing.assert_array_equal(np.asarray(jax.jit(jax.vmap(free_space_keep))(batch))[1], eager)  # one program
    assert (~eager[1] & np.asarray(src.valid[1])).sum() > 20


# ---------------------------------------------------------------- synthetic sequences

def test_sequence_reference_points_lie_on_the_camera_truth():
    sq = make_street_sequence(0, sweeps=2, lidars=2, image_scale=0.25, noise_std_m=0.0)
    assert sq.T_ref_source.shape == (4, 4, 4) and list(sq.sweep) == [0, 0, -1, -1]  # signed: -1 is one sweep earlier
    cam = sq.camera
    ref = sq.points[sq.sweep[sq.source] == 0]
    depth, _ = jaxdepth.project_to_image(ref, np.ones(len(ref), bool), cam.K, cam.T_cam_lidar,
                                         height=cam.height, width=cam.width)
    depth = np.asarray(depth)
    m = (depth > 0) & (sq.dense_depth > 0)
    assert np.median(np.abs(depth[m] - sq.dense_depth[m])) < 0.05
    again = make_street_sequence(0, sweeps=2, lidars=2, image_scale=0.25, noise_std_m=0.0)
    np.testing.assert_array_equal(again.points, sq.points)


# ---------------------------------------------------------------- the job: complete-rig with a sweeps JSON

@pytest.mark.slow  # the job's whole-pipeline program of its own (four sources of two LiDARs)
def test_complete_rig_job_with_a_sweeps_json(tmp_path):
    import json

    from jaxdepth._src.config import SGMConfig
    from jaxdepth.batch.extras import ExtraOutputs
    from jaxdepth.batch.rig_job import run_rig_job
    from jaxdepth.batch.sources_job import complete_cloud
    from jaxdepth.io import read_depth_png, read_rig_json
    from jaxdepth.io.sweeps import read_sweeps_cloud

    sq = make_street_sequence(2, sweeps=2, lidars=2, image_scale=0.125, noise_std_m=0.0)
    cam = sq.camera
    ego = [sq.T_ref_source[2 * k] for k in range(2)]                   # "top" sits at the ego origin
    mount = np.linalg.inv(ego[0]) @ sq.T_ref_source[1]
    entries = []
    for k in range(2):
        mine = sq.sweep[sq.source] == -k
        inv = np.linalg.inv(ego[k])
        local = sq.points[mine] @ inv[:3, :3].T + inv[:3, 3]
        rows = np.concatenate([local, (sq.source[mine] % 2)[:, None]], axis=1).astype(np.float32)
        rows.tofile(tmp_path / f"sweep{k}.bin")
        entries.append({"file": f"sweep{k}.bin", "T_ref_sweep": ego[k].tolist()})
    (tmp_path / "sweeps.json").write_text(json.dumps({"sweeps": entries[::-1]}))
    lidars = [{"name": "top", "T_points_lidar": np.eye(4).tolist(), "beams": 32, "fov_up_deg": 10.0,
               "fov_down_deg": -25.0},
              {"name": "front_low", "T_points_lidar": mount.tolist(), "beams": 16, "fov_up_deg": 15.0,
               "fov_down_deg": -15.0}]
    doc = {"lidar": {"beams": 32, "columns": 1024}, "lidars": lidars, "columns": ["x", "y", "z", "lidar"],
           "cameras": [{"name": "cam", "width": cam.width, "height": cam.height,
                        "K": np.asarray(cam.K).tolist(), "T_cam_lidar": np.asarray(cam.T_cam_lidar).tolist()}]}
    (tmp_path / "rig.json").write_text(json.dumps(doc))
    rig = read_rig_json(tmp_path / "rig.json")
    cloud = read_sweeps_cloud(tmp_path / "sweeps.json", rig)
    np.testing.assert_allclose(cloud.T_ref_source, sq.T_ref_source, atol=1e-5)
    np.testing.assert_allclose(cloud.points, sq.points, atol=1e-4)
    summary = run_rig_job(tmp_path / "sweeps.json", tmp_path / "rig.json", tmp_path / "out", config=SGMConfig(),
                          extras=ExtraOutputs())
    assert [p.name for p in summary.written] == ["cam.png"]
    want = complete_cloud(cloud, rig)[0]
    got = read_depth_png(tmp_path / "out" / "cam.png")
    np.testing.assert_allclose(got, want, atol=1.0 / 256 + 1e-6)
    # The same sweeps JSON twice in one multi-sweep call (a list file; one program): the single call's bytes.
    from jaxdepth.batch.rig_sweeps import run_rig_sweeps
    (tmp_path / "again.json").write_text((tmp_path / "sweeps.json").read_text())
    (tmp_path / "list.txt").write_text("sweeps.json\nagain.json\n")
    from jaxdepth.io.sweep_list import list_sweeps
    many = run_rig_sweeps(list_sweeps(tmp_path / "list.txt"), tmp_path / "rig.json", tmp_path / "many",
                          config=SGMConfig(), extras=ExtraOutputs())
    assert sorted(many.done) == sorted(str(tmp_path / n) for n in ("sweeps.json", "again.json")) and not many.failed
    for stem in ("sweeps", "again"):
        assert (tmp_path / "many" / stem / "cam.png").read_bytes() == (tmp_path / "out" / "cam.png").read_bytes()
    gt = sq.dense_depth
    m = gt > 0
    assert np.sqrt(np.mean((got[m] - gt[m]) ** 2)) < 5.0              # a sane depth map of the street


@pytest.mark.slow  # a whole pipeline program of its own (docs/testing.md)
def test_older_sweeps_give_no_seed_above_the_reference_top_scan_line():
    # A LiDAR whose top laser is at +2 deg (as KITTI's); a wall at 20 m, which the reference LiDAR at the
    # origin scans up to 20 tan(2 deg) = 0.7 m and an older sweep's LiDAR 5 m behind up to 0.87 m, and a
    # post at 8 m, scanned up to 0.28 m and 0.45 m: the older sweep's pixels of both lie above the
    # reference sweep's top scan line in the cameras, the post's 12 m nearer than the wall's. With reference_top_line the kept pixels are
    # Step 2's (the mask without it) less the older sweeps' pixels above the kept reference pixels' top
    # line over the paper's window that are nearer than its farthest top pixel by more than epsilon: the
    # per-pixel NumPy walk of tests/test_above_scan.py, L = 32 beams.
    from test_above_scan import numpy_top_line_keep
    spec = LidarSpec(beams=SPEC.beams, fov_up_deg=2.0, fov_down_deg=-25.0, columns=SPEC.columns)
    scene = _street(cylinders=[[8.0, 1.0, 0.3, -1.7, 6.0]])
    T_ref, T_old = _pose(), _pose((-5.0, 0.0, 0.0))
    ref = _sweep(scene, T_ref, spec)
    src = _sources([(ref, T_ref), (_sweep(scene, T_old, spec), T_old)], (0, 1), spec)
    cams = stereo_cameras()
    on = complete_sources_stages(src, jaxdepth.stack_cameras(cams), config=jaxdepth.SGMConfig(reference_top_line="on"))
    off = complete_sources_stages(src, jaxdepth.stack_cameras(cams), config=jaxdepth.SGMConfig(reference_top_line="off"))
    removed = 0
    for i, cam in enumerate(cams):
        keep_on, keep_off = np.asarray(on.inlier_mask[i]), np.asarray(off.inlier_mask[i])
        z_ref = np.asarray(jaxdepth.project_to_image(jnp.asarray(ref), jnp.ones(len(ref), bool), jnp.asarray(cam.K),
                                                     jnp.asarray(cam.T_cam_lidar), height=cam.height,
                                                     width=cam.width)[0])
        sparse = np.asarray(off.sparse_depth[i, :cam.height, :cam.width])
        is_ref = (z_ref > 0) & np.isclose(sparse, z_ref, rtol=1e-6, atol=0)     # the pixel's point is a reference one
        keep_off, keep_on = keep_off[:cam.height, :cam.width], keep_on[:cam.height, :cam.width]
        allowed = numpy_top_line_keep(keep_off & is_ref, sparse, beams=SPEC.beams, max_half_width_px=12)
        np.testing.assert_array_equal(keep_on, keep_off & (is_ref | allowed))
        gone = keep_off & ~keep_on
        assert (sparse[gone] < 9.0).all(), "only the post's pixels go, never the wall's"
        removed += int(gone.sum())
    assert removed >= 2


def test_rule_6_runs_by_default_for_one_reference_scan_filling_its_rows():
    # "auto" (the default) decides from the static sources alone: never with one sweep; on for ONE
    # reference-sweep source whose free-space grid is its own spec; off with two reference LiDARs or
    # when the reference source has a witness grid of its own (a rosette-like scan); "on"/"off" force it.
    from jaxdepth._src.sources import make_sources, top_line_applies
    other = LidarSpec(beams=8, fov_up_deg=10.0, fov_down_deg=-10.0, columns=64)

    def sources(sweep, witnesses=None):
        n = len(sweep)
        return make_sources(np.zeros((n, 4, 3)), np.ones((n, 4), bool), np.tile(np.eye(4), (n, 1, 1)),
                            lidars=(SPEC,) * n, sweep=sweep, witnesses=witnesses)

    one_lidar = sources((0, -1, -2))
    assert top_line_applies(one_lidar) and top_line_applies(one_lidar, "auto")
    assert not top_line_applies(one_lidar, "off")
    assert not top_line_applies(sources((0,)), "auto") and not top_line_applies(sources((0,)), "on")
    assert not top_line_applies(sources((0, 0, -1, -1)))                       # two reference LiDARs
    assert top_line_applies(sources((0, 0, -1, -1)), "on")
    assert not top_line_applies(sources((0, -1), witnesses=(other, other)))   # a grid of its own
    assert top_line_applies(sources((0, -1), witnesses=(SPEC, other)))        # the reference fills its rows


@pytest.mark.parametrize("n_sources, label", [(3, np.int8), (130, np.int32)])   # int8 while the sources fit
def test_camera_view_source_label_equals_numpy_and_vmap_equals_loop(n_sources, label):
    h, w, per_source = 6, 7, 2
    n = n_sources * per_source
    rng = np.random.default_rng(n_sources)
    slots = np.full((2, n), h * w, np.int32)      # two cameras; each pixel won by one point at most, H W = none
    for c in range(2):
        won = rng.permutation(n)[:min(n, h * w) // 2]
        slots[c, won] = rng.permutation(h * w)[:len(won)]
    channels = rng.normal(size=(2, 6, n)).astype(np.float32)
    won = lambda c: (jnp.asarray(slots[c]), *(jnp.asarray(x) for x in channels[c]))
    view = lambda *a: _camera_view(a, n, per_source, None, height=h, width=w).pixel_source
    batched = np.asarray(jax.vmap(view)(*(jnp.stack(x) for x in zip(won(0), won(1)))))
    assert batched.dtype == label
    for c in range(2):
        want = np.full(h * w + 1, -1, np.int64)
        want[slots[c]] = np.arange(n) // per_source
        np.testing.assert_array_equal(batched[c], want[:h * w].reshape(h, w))
        np.testing.assert_array_equal(np.asarray(view(*won(c))), batched[c])
