"""SGMConfig.older_sweeps_test: the older sweeps' points also judged by the paper form of condition 1."""

from __future__ import annotations

import argparse
import functools

import jax
import numpy as np
import pytest

import jaxdepth
from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.sources import source_keep_mask

from test_outliers import paper_double_loop

PAPER = DEFAULT_CONFIG.replace(older_sweeps_test="paper")
BEAMS = 6


@functools.lru_cache(maxsize=1)
def _scene():
    """(24, 40) image: a near face at 8 m (rows >= 14, columns 8-31) under a background at 30 m, sampled by
    three sources on interleaved rows and columns, their LiDARs 0.3 m above the camera and 0.4, 1.5 and 2.6 m
    behind it (the radial parallax of a roof LiDAR behind its cameras, and the ego's earlier origins)."""
    height, width = 24, 40
    K = np.array([[40.0, 0.0, 20.0], [0.0, 40.0, 12.0], [0.0, 0.0, 1.0]], np.float32)
    depth = np.zeros((height, width), np.float32)
    source = np.full((height, width), -1, np.int32)
    for s, rows in enumerate([(1, 5, 9, 15, 19, 23), (3, 7, 12, 17, 21), (2, 6, 11, 13, 18, 22)]):
        for v in rows:
            for u in range(s, width, 3):
                depth[v, u] = 8.0 if (v >= 14 and 8 <= u < 32) else 30.0
                source[v, u] = s
    vs, us = np.mgrid[:height, :width]
    points_cam = np.stack([(us - 20) / 40 * depth, (vs - 12) / 40 * depth, depth]).astype(np.float32)
    T3 = np.tile(np.eye(4, dtype=np.float32), (3, 1, 1))
    T3[:, :3, 3] = [[0.0, -0.3, -0.4], [0.0, -0.3, -1.5], [0.2, -0.3, -2.6]]
    return depth, source, points_cam, K, T3


def _paper_oracle(depth, source, points_cam, K, T3, judged):
    """Brute force, float64: the paper's Algorithm 1 as written (``test_outliers.paper_double_loop``) from each
    judged source's origin, every pixel a neighbour j; True where a judged source's pixel survives."""
    keep = np.ones(depth.shape, bool)
    for s in judged:
        own = paper_double_loop(depth, K, T3[s], beams=BEAMS, points_cam=points_cam,
                                max_half_width_px=DEFAULT_CONFIG.outlier_max_half_width_px,
                                max_half_height_px=DEFAULT_CONFIG.outlier_max_half_height_px)
        keep &= np.where(source == s, own, True)
    return keep


@pytest.mark.xdist_group("sources_keep_mask")  # one worker compiles the shared Step-2 programs once
def test_older_sweeps_are_also_judged_by_the_paper_form():
    """"paper": the footprint pass over the merged image AND the paper form for the older sweeps' pixels only
    (brute-force oracle of the paper's conditions from each pixel's own origin); the reference sweep's pixels and
    a single sweep are never judged by it; "footprint" (default): the footprint pass alone; jit == eager."""
    depth, source, points_cam, K, T3 = _scene()
    footprint = np.asarray(source_keep_mask(depth, source, points_cam, K, T3, beams=BEAMS, all_sweep=(0, -1, -2)))
    sweeps = [(0, -1, -2), (-1, 0, -2)]             # the second makes source 1 the reference sweep
    # jit == eager: both sweeps' masks in one program, one compile instead of two (suite18)
    jitted = jax.jit(lambda *a: [source_keep_mask(*a, beams=BEAMS, config=PAPER, all_sweep=sweep) for sweep in sweeps])
    fast = jitted(depth, source, points_cam, K, T3)
    for sweep, jit_mask in zip(sweeps, fast):
        older = [s for s, sw in enumerate(sweep) if sw != 0]
        want = footprint & _paper_oracle(depth, source, points_cam, K, T3, older)
        got = np.asarray(source_keep_mask(depth, source, points_cam, K, T3, beams=BEAMS, config=PAPER,
                                          all_sweep=sweep))
        np.testing.assert_array_equal(got, want)
        # the scene has older-sweep points hidden only under the paper form
        assert (footprint & ~got).sum() >= 2 and np.isin(source[footprint & ~got], older).all()
        np.testing.assert_array_equal(np.asarray(jit_mask), got)
    # the paper form alone would remove a point of source 1, which as the reference sweep it keeps
    assert not _paper_oracle(depth, source, points_cam, K, T3, [1])[footprint & (source == 1)].all()
    for kw in (dict(all_sweep=(0, 0, 0)), {}, dict(config=DEFAULT_CONFIG, all_sweep=(0, -1, -2))):
        one = np.asarray(source_keep_mask(depth, source, points_cam, K, T3, beams=BEAMS, **{"config": PAPER, **kw}))
        np.testing.assert_array_equal(one, footprint)


def test_older_sweeps_test_field_and_flag():
    """The field's values, its CLI flag (unset: the config's default) and the run record's copy of it."""
    from jaxdepth.batch.run_record import settings_of
    from jaxdepth.options import add_config_options, config_changes
    assert jaxdepth.SGMConfig().older_sweeps_test == "footprint"
    with pytest.raises(ValueError, match="older_sweeps_test"):
        jaxdepth.SGMConfig(older_sweeps_test="radial")
    p = argparse.ArgumentParser()
    add_config_options(p)
    assert config_changes(p.parse_args(["--older-sweeps-test", "paper"]))["older_sweeps_test"] == "paper"
    assert "older_sweeps_test" not in config_changes(p.parse_args([]))
    with pytest.raises(SystemExit):
        p.parse_args(["--older-sweeps-test", "radial"])
    assert settings_of(PAPER, method="sgm")["older_sweeps_test"] == "paper"
