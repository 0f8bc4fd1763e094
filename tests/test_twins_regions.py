"""benchmarks/twins_regions.py: the region masks against hand-built images, the pooled errors
against a brute-force NumPy score (no JAX pipeline is compiled)."""

from __future__ import annotations

import numpy as np

from benchmarks.twins_regions import region_errors, region_masks


def _scene():
    """(12, 20) exact depth: a 5 m wall on the left, a 40 m wall on the right, sky in row 0;
    reference points on rows 4 and 8 of every column."""
    exact = np.full((12, 20), 5.0, np.float32)
    exact[:, 10:] = 40.0
    exact[0] = 0.0
    ref = np.zeros_like(exact)
    ref[[4, 8]] = exact[[4, 8]]
    return exact, ref


def test_regions_partition_the_pixels_with_truth():
    exact, ref = _scene()
    masks = region_masks(exact, ref)
    stacked = np.stack(list(masks.values())).astype(int)
    assert (stacked.sum(0) == (exact > 0)).all()      # every truth pixel in exactly one region


def test_regions_by_hand():
    exact, ref = _scene()
    m = region_masks(exact, ref)
    rows = np.arange(12)[:, None] * np.ones((1, 20), int)
    assert (m["above_scan"] == ((rows < 4) & (exact > 0))).all()
    assert (m["below_scan"] == (rows > 8)).all()
    # the step marks columns 9 and 10 (both sides), dilated by 2 px, inside the scan
    cols = np.arange(20)[None, :] * np.ones((12, 1), int)
    assert (m["edge"] == ((rows >= 4) & (rows <= 8) & (cols >= 7) & (cols <= 12))).all()
    assert (m["near"] == ((rows >= 4) & (rows <= 8) & (cols < 7))).all()
    assert (m["far"] == ((rows >= 4) & (rows <= 8) & (cols > 12))).all()
    assert not m["mid"].any()


def test_pooled_errors_match_brute_force():
    rng = np.random.default_rng(0)
    exact, ref = _scene()
    preds = [np.where(rng.random(exact.shape) < 0.1, 0.0, exact + rng.normal(0, 1, exact.shape)).astype(np.float32)
             for _ in range(2)]
    masks = [region_masks(exact, ref)] * 2
    out = region_errors(preds, [exact, exact], masks)
    t = exact > 0
    d = np.concatenate([np.where(p[t] > 0, p[t] - exact[t], exact[t]) for p in preds]).astype(np.float64) * 1000
    assert np.isclose(out["all"]["rmse"], np.sqrt(np.mean(d ** 2)))
    assert np.isclose(out["all"]["mae"], np.mean(np.abs(d)))
    assert np.isclose(sum(v["ae_share"] for k, v in out.items() if k != "all"), 1.0)
    assert np.isclose(sum(v["share"] for k, v in out.items() if k != "all"), 1.0)
