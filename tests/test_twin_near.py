"""Near-range return statistics (:func:`jaxdepth.research.twin_measure.near_statistics`) against a plain
count on an analytic scene, and the twins' optional range bands (``SensorEffects.band_*``, nusc13)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from jaxdepth.research.twin_measure import NEAR_BANDS_M, band_effects, near_statistics
from jaxdepth.research.twin_sensors import SensorEffects
from jaxdepth.research.twin_tables import SENSOR_EFFECTS
from jaxdepth.research.twins import make_twin

pytestmark = pytest.mark.xdist_group("twins")
GROUND_Z = -1.8


def _scene():
    """Four rings of 720 returns: three on flat ground (z = -1.8 m, 3.6, 5.3 and 10.4 m out) with 1 cm
    range noise, one level ring on a wall at 8 m with two posts at 5 m and one mixed return beside a
    post; one near spike and one far spike on the ground, and two gaps (2 and 3 lost returns)."""
    rng = np.random.default_rng(3)
    az = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    pts, ring = [], []
    for b, el_deg in enumerate((-30.0, -20.0, -10.0, 0.0)):
        el = math.radians(el_deg)
        keep = np.ones(az.size, bool)
        if el_deg < 0:
            r = GROUND_Z / math.sin(el) + rng.normal(0.0, 0.01, az.size)
        else:
            r = np.full(az.size, 8.0)
            r[100:104] = 5.0
            r[300:303] = 5.0
            r[104] = 6.5                                  # strictly between the post and the wall
        if el_deg == -20.0:
            r[400] = 2.5                                  # a near spike (spray)
            r[500] = 9.0                                  # a far spike (a hole)
            keep[200:202] = False                         # 2 lost returns
            keep[600:603] = False                         # 3 lost returns
        p = np.stack([r * math.cos(el) * np.cos(az), r * math.cos(el) * np.sin(az), r * math.sin(el)], 1)
        pts.append(p[keep])
        ring.append(np.full(int(keep.sum()), b))
    return np.concatenate(pts), np.concatenate(ring)


def _plain(points, ring):
    """The statistics one triple at a time (plain Python), the ground taken as |z + 1.8| < 0.15."""
    bins = NEAR_BANDS_M
    band = lambda r: next((j for j in range(len(bins) - 1) if bins[j] <= r < bins[j + 1]), -1)  # noqa: E731
    same = lambda a, c, rel, m: abs(a - c) <= max(m, rel * min(a, c))  # noqa: E731
    out = [{"sd": [], "gsd": [], "near": 0, "far": 0, "edge": 0, "between": 0, "lost": 0, "kept": 0}
           for _ in range(len(bins) - 1)]
    for b in sorted(set(ring.tolist())):
        p = [q for q, k in zip(points, ring) if k == b and np.linalg.norm(q) > 1.0]
        p.sort(key=lambda q: math.atan2(q[1], q[0]))
        az = [math.atan2(q[1], q[0]) for q in p]
        r = [float(np.linalg.norm(q)) for q in p]
        ground = [abs(q[2] - GROUND_Z) < 0.15 for q in p]
        step = float(np.median(np.diff(az)))
        k = [round((az[i + 1] - az[i]) / step) for i in range(len(p) - 1)]
        for i in range(len(p) - 1):
            j = band(min(r[i], r[i + 1]))
            if j >= 0 and same(r[i], r[i + 1], 0.05, 0.3):
                if k[i] == 1:
                    out[j]["kept"] += 1
                elif 2 <= k[i] <= 10:
                    out[j]["lost"] += k[i] - 1
        for i in range(1, len(p) - 1):
            j = band(r[i])
            if j < 0 or k[i - 1] != 1 or k[i] != 1:
                continue
            a, m, c = r[i - 1], r[i], r[i + 1]
            lo, hi = min(a, c), max(a, c)
            if same(a, c, 0.10, 1.0):
                out[j]["sd"].append(a - 2 * m + c)
                if ground[i - 1] and ground[i] and ground[i + 1]:
                    out[j]["gsd"].append(a - 2 * m + c)
                out[j]["near"] += m < lo and not same(m, lo, 0.10, 1.0)
                out[j]["far"] += m > hi and not same(m, hi, 0.10, 1.0)
            else:
                out[j]["edge"] += 1
                out[j]["between"] += lo < m < hi and not same(m, lo, 0.03, 0.3) and not same(m, hi, 0.03, 0.3)
    return out


def _mad(x):
    x = np.asarray(x)
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def test_near_statistics_match_a_plain_count_on_an_analytic_scene():
    points, ring = _scene()
    st = near_statistics(points, ring)
    plain = _plain(points, ring)
    for j, name in enumerate(st["bands"]):
        got, want = st["bands"][name], plain[j]
        assert got["smooth"] == len(want["sd"]) and got["ground"] == len(want["gsd"])
        assert got["second_diff_m"] == pytest.approx(_mad(want["sd"]), rel=1e-9, nan_ok=True)
        assert got["ground_second_diff_m"] == pytest.approx(_mad(want["gsd"]), rel=1e-9, nan_ok=True)
        assert got["spike_near_share"] == pytest.approx(want["near"] / max(len(want["sd"]), 1))
        assert got["spike_far_share"] == pytest.approx(want["far"] / max(len(want["sd"]), 1))
        assert got["edge_triples"] == want["edge"]
        assert got["mixed_share"] == pytest.approx(want["between"] / max(want["edge"], 1))
        assert got["dropout"] == pytest.approx(want["lost"] / max(want["lost"] + want["kept"], 1))
    b5 = st["bands"]["5-10"]
    # The analytic counts: the posts and the mixed return are edge triples; 5 lost returns; the far spike.
    assert b5["edge_triples"] == plain[1]["edge"] > 0 and plain[1]["between"] >= 1
    assert plain[1]["lost"] == 5 and plain[1]["near"] == 0 and plain[1]["far"] == 1
    assert plain[0]["near"] == 1 and st["within_ego_m"] == 0.0     # the 2.5 m spike is in the 0-5 m band
    # Noise of 1 cm: the ground's second difference spreads sqrt(6) cm.
    assert st["bands"]["0-5"]["ground_second_diff_m"] == pytest.approx(0.01 * math.sqrt(6.0), rel=0.15)


def test_band_effects_turn_the_measured_spread_into_noise():
    points, ring = _scene()
    eff = band_effects(near_statistics(points, ring), SensorEffects(noise_m=0.02, dropout=0.03))
    assert eff.band_upper_m == (5.0, 10.0, 20.0) and eff.noise_m == 0.02 and eff.dropout == 0.03
    assert eff.band_noise_m[0] == pytest.approx(0.01, rel=0.15)
    with pytest.raises(ValueError, match="one length"):
        SensorEffects(band_upper_m=(5.0,), band_noise_m=(), band_dropout=())
    with pytest.raises(ValueError, match="ascending"):
        SensorEffects(band_upper_m=(10.0, 5.0), band_noise_m=(0.0, 0.0), band_dropout=(0.0, 0.0))


def _twin(effects):
    return make_twin("nuscenes", sweeps=1, seed=0, scale=0.05, effects=effects)


def test_range_bands_are_off_by_default_and_change_only_their_band():
    base = SensorEffects(**SENSOR_EFFECTS["nuscenes"])
    assert base.bands().shape == (0, 3)
    default = _twin(True)
    np.testing.assert_array_equal(default.cloud.points, _twin(base).cloud.points)
    # Bands with the base rates: the same bytes.
    same = dataclasses.replace(base, band_upper_m=(5.0, 10.0), band_noise_m=(base.noise_m,) * 2,
                               band_dropout=(base.dropout,) * 2)
    np.testing.assert_array_equal(default.cloud.points, _twin(same).cloud.points)
    # Within 10 m: no noise, nothing lost; beyond it the default's points, draw for draw.
    quiet = dataclasses.replace(base, band_upper_m=(10.0,), band_noise_m=(0.0,), band_dropout=(0.0,))
    tw = _twin(quiet)
    exact_r = np.linalg.norm(tw.point_exact, axis=1)
    near = (exact_r < 10.0) & ~tw.point_mixed
    np.testing.assert_array_equal(tw.cloud.points[near], tw.point_exact[near])
    d_far = np.linalg.norm(default.point_exact, axis=1) >= 10.0
    np.testing.assert_array_equal(tw.cloud.points[exact_r >= 10.0], default.cloud.points[d_far])
    assert (exact_r < 10.0).sum() > (np.linalg.norm(default.point_exact, axis=1) < 10.0).sum()


def _firing_order_sweep(cols=1084, rings=32):
    """A sweep stored as nuScenes stores it (column by column, every ring; ring b at -30 + b deg): 10 m
    everywhere except ring 0's first 50 columns at 0.6 m (the ego's body) and columns 100-109 of ring 1 (aimed
    at the road) and ring 31 (above the horizon) stored at a fixed point (0, -0.45, 0) (invalid returns)."""
    k = np.repeat(np.arange(cols), rings)
    b = np.tile(np.arange(rings), cols)
    az = np.pi - 2.0 * np.pi * (k + 0.5) / cols
    r = np.where((b == 0) & (k < 50), 0.6, 10.0)
    el = np.radians(-30.0 + b)
    p = np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], 1)
    invalid = np.isin(b, (1, 31)) & (k >= 100) & (k < 110)
    p[invalid] = (0.0, -0.45, 0.0)
    return p, b, az, invalid


def test_ego_table_puts_every_return_at_its_column_azimuth():
    from jaxdepth.research.twin_measure import ego_table
    p, b, az, invalid = _firing_order_sweep()
    tab = ego_table(p, b)
    cols = np.round(np.angle(np.exp(1j * az[invalid & (b == 1)])), 9)
    for ring, want_r in ((1, 0.45), (31, np.inf)):
        a1, r1, p1 = tab[ring]
        np.testing.assert_allclose(a1, np.sort(np.angle(np.exp(1j * az[b == ring]))), atol=1e-9)
        # The invalid returns (a fixed point, far off their columns' azimuths) sit at their columns' azimuths;
        # on a laser aimed at the road they are the ego (0.45 m), above the horizon no echo (inf).
        near = np.isin(np.round(a1, 9), cols)
        assert near.sum() == 10 and np.all(r1[near] == pytest.approx(want_r))
        assert np.allclose(p1[near], (0.0, -0.45, 0.0))
    a0, r0, p0 = tab[0]
    assert (r0 < 2.0).sum() == 50 and np.allclose(np.linalg.norm(p0[r0 < 2.0], axis=1), 0.6)


def test_ego_returns_replace_only_the_ego_rays():
    from jaxdepth.research.twin_measure import ego_table
    from jaxdepth.research.twin_rigs import RIG_BUILDERS
    from jaxdepth.research.twins import ego_returns
    p, b, _, _ = _firing_order_sweep()
    base = SensorEffects(**SENSOR_EFFECTS["nuscenes"])
    plain = _twin(base)
    tw = make_twin("nuscenes", sweeps=1, seed=0, scale=0.05, effects=base, ego=ego_table(p, b))
    r = np.linalg.norm(tw.cloud.points, axis=1)
    ego = r < 2.0
    # Ring 0's first 50 columns and ring 1's 10 invalid returns (1088 twin columns against 1084: 49-51, 9-11);
    # ring 31's invalid returns are no ego.
    assert 58 <= ego.sum() <= 62 and set(tw.cloud.ring[ego].tolist()) == {0, 1}
    np.testing.assert_allclose(r[ego & (tw.cloud.ring == 0)], 0.6, rtol=1e-5)
    np.testing.assert_allclose(tw.cloud.points[ego & (tw.cloud.ring == 1)], [[0.0, -0.45, 0.0]] * 10, atol=1e-6)
    np.testing.assert_array_equal(tw.point_exact[ego], tw.cloud.points[ego])
    # Every other return is the plain twin's, draw for draw (the twin's rays: apex at the origin).
    unit = RIG_BUILDERS["nuscenes"](base).units[0][0](0)
    rays = np.isfinite(ego_returns(unit, ego_table(p, b))[:, 0])
    assert rays.sum() == ego.sum()
    d = unit.directions[rays]
    a_rays = np.arctan2(d[:, 1], d[:, 0])
    a_plain = np.arctan2(plain.cloud.points[:, 1], plain.cloud.points[:, 0])
    hit = np.zeros(len(a_plain), bool)
    for ring, a in zip(unit.ring[rays], a_rays):
        hit |= (plain.cloud.ring == ring) & (np.abs(np.angle(np.exp(1j * (a_plain - a)))) < 1e-4)
    np.testing.assert_array_equal(tw.cloud.points[~ego], plain.cloud.points[~hit])
    with pytest.raises(ValueError, match="ego"):
        make_twin("av2", sweeps=1, seed=0, scale=0.05, ego=ego_table(p, b))
