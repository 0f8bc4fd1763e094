"""The scan-line cover tests of benchmarks/studies/cover_scan.py against a NumPy brute force on small random
scenes, and one analytic case (a target behind a nearer surface seen only by the scan line above)."""

import numpy as np
import pytest

from benchmarks.studies import cover_scan as cs


def _brute(target, full, half, K, T, origin):
    """Every :data:`cover_scan.SCAN` variant written out per target and offset."""
    H, W = target.shape
    K, T = np.asarray(K, np.float64), np.asarray(T, np.float64)
    c = T[:3, :3] @ np.asarray(origin, np.float64) + T[:3, 3]
    rows = {k: max(1, int(np.floor(k * half + 0.5))) for k in (1, 1.5)}
    out = {v: np.zeros((H, W), bool) for v in cs.SCAN}
    for y, x in zip(*np.nonzero(target > 0)):
        z = float(target[y, x])
        limit = z - max(1.0, 0.05 * z)

        def near(dy, dx):
            qy, qx = y + dy, x + dx
            return 0 <= qy < H and 0 <= qx < W and 0 < full[qy, qx] < limit

        def anywhere(r0, r1, c0, c1):
            return any(near(dy, dx) for dy in range(r0, r1 + 1) for dx in range(c0, c1 + 1))
        du, dv = K[0, 0] * c[0] - (x - K[0, 2]) * c[2], K[1, 1] * c[1] - (y - K[1, 2]) * c[2]
        for k, r in rows.items():
            out[f"scan_open_c2_{k:g}"][y, x] = anywhere(-r, r, -2, 2)
            out[f"scan_directed_c2_{k:g}"][y, x] = any(near(dy, dx) and dx * du + dy * dv < 0
                                                       for dy in range(-r, r + 1) for dx in range(-2, 3))
        out["scan_open_c4_1"][y, x] = anywhere(-half, half, -4, 4)
        out["scan_above"][y, x] = anywhere(-half, -1, -2, 2)
        out["scan_below"][y, x] = anywhere(1, half, -2, 2)
        h2 = 2 * half
        out["scan_both_2"][y, x] = ((anywhere(-h2, -1, -2, 2) and anywhere(1, h2, -2, 2))
                                    or (anywhere(-1, 1, -half, -1) and anywhere(-1, 1, 1, half)))
    return out


@pytest.mark.parametrize("seed, half", [(0, 3), (1, 5), (2, 1)])
def test_scan_masks_brute_force(seed, half):
    rng = np.random.default_rng(seed)
    H, W = 24, 31
    full = np.where(rng.random((H, W)) < 0.3, rng.uniform(2.0, 40.0, (H, W)), 0.0).astype(np.float32)
    target = np.where((full > 0) & (rng.random((H, W)) < 0.5), full, 0.0).astype(np.float32)
    K = np.array([[30.0, 0.0, 15.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, 3] = [0.1, 0.3, -0.2]
    origin = np.zeros(3)
    got = cs.scan_masks(target, full, half, K, T, origin)
    want = _brute(target, full, half, K, T, origin)
    assert set(got) == set(cs.SCAN)
    for v in cs.SCAN:
        np.testing.assert_array_equal(got[v], want[v], err_msg=v)


def test_target_seen_past_the_line_above():
    """A far wall (20 m) with a near surface (5 m) two rows above a target: the scan-line windows (h = 3) and
    ``scan_above`` drop it, ``scan_below`` and today's both-sided test (its vertical arms need both) do not."""
    H, W = 15, 15
    full = np.zeros((H, W), np.float32)
    full[7, :] = 20.0
    full[5, 5:10] = 5.0
    target = np.zeros((H, W), np.float32)
    target[7, 7] = 20.0
    got = cs.scan_masks(target, full, 3, np.eye(3), np.eye(4), np.zeros(3))
    for v in ("scan_open_c2_1", "scan_open_c2_1.5", "scan_open_c4_1", "scan_above"):
        assert got[v][7, 7], v
    for v in ("scan_below", "scan_both_2"):
        assert not got[v][7, 7], v
    assert int(sum(m.sum() for m in got.values())) == sum(int(got[v][7, 7]) for v in cs.SCAN)
