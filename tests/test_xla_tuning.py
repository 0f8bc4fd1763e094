"""The XLA:CPU tuning switch (jaxdepth._src.xla_tuning): both paths give the same completion.

On CPU, ``complete``, ``complete_points`` and ``complete_rig`` are traced once with the tricks on
(stage fences, complex64 gathers, the scheduling dependence, shared loop bounds) and once plain;
the oracle is the other path. The maths is the same, but XLA fuses the float stages differently
(a fence is a fusion boundary), which moves float32 rounding:

* bit for bit: the sparse depth, the inlier mask, the seeds (du, dv) and the seed depth;
* within float32 rounding: normals (measured <= 1.8e-7, 1.5 ulps of 1), the residual (<= 6e-6 m),
  ``depth_raw`` and ``depth`` (<= 2 ulps; 8e-6 m on the KITTI frame);
* image-guided seeds: the geodesic distances round differently, so near-tie seeds flip (70 of
  466k pixels on the KITTI frame); checked as a share of pixels.
"""

from __future__ import annotations

import numpy as np
import pytest

import jaxdepth
from jaxdepth._src import xla_tuning
from jaxdepth._src.config import SGMConfig

from conftest import require_shared


def _both(run):
    """``run()`` traced with the tricks on, then plain (caches cleared between)."""
    out = {}
    for mode in ("cpu", "plain"):
        with xla_tuning.forced(mode):
            assert xla_tuning.enabled() == (mode == "cpu")
            out[mode] = {k: np.asarray(v) for k, v in run()._asdict().items() if v is not None}
    return out["cpu"], out["plain"]


EXACT = ("sparse_depth", "inlier_mask", "seed_depth", "du", "dv")


def _assert_same(tuned, plain):
    assert tuned.keys() == plain.keys()
    for name in EXACT:
        np.testing.assert_array_equal(tuned[name], plain[name], err_msg=name)
    np.testing.assert_allclose(tuned["normals"], plain["normals"], rtol=0, atol=2.5e-7, err_msg="normals")
    np.testing.assert_allclose(tuned["residual"], plain["residual"], rtol=0, atol=1e-5, err_msg="residual")
    for name in ("depth_raw", "depth"):
        np.testing.assert_array_max_ulp(tuned[name], plain[name], maxulp=4)


def _assert_same_but_near_ties(tuned, plain, *, share: float):
    """Guided: seeds may differ at near ties; elsewhere the unguided tolerances hold."""
    for name in EXACT[:2]:
        np.testing.assert_array_equal(tuned[name], plain[name], err_msg=name)
    flipped = (tuned["du"] != plain["du"]) | (tuned["dv"] != plain["dv"])
    assert flipped.mean() < share, flipped.mean()
    differs = np.abs(tuned["depth"].astype(np.float64) - plain["depth"]) > 1e-4
    assert differs.mean() < 10 * share, differs.mean()


def test_mode_comes_from_the_environment_and_set_mode(monkeypatch):
    monkeypatch.setenv("JAXDEPTH_XLA_TUNING", "plain")
    assert xla_tuning.mode() == "plain" and not xla_tuning.enabled()
    monkeypatch.setenv("JAXDEPTH_XLA_TUNING", "auto")
    import jax
    assert xla_tuning.enabled() == (jax.default_backend() == "cpu")
    with xla_tuning.forced("cpu"):
        monkeypatch.setenv("JAXDEPTH_XLA_TUNING", "plain")
        assert xla_tuning.enabled()  # set_mode wins over the environment
    assert not xla_tuning.enabled()
    monkeypatch.setenv("JAXDEPTH_XLA_TUNING", "fast")
    with pytest.raises(ValueError, match="JAXDEPTH_XLA_TUNING"):
        xla_tuning.mode()
    with pytest.raises(ValueError, match="'value'"):
        xla_tuning.set_mode("fast")


def test_helpers_reduce_to_the_plain_computation():
    import jax.numpy as jnp
    a, b = jnp.arange(6.0), -jnp.arange(6.0)
    index = jnp.array([5, 0, 2])
    for mode in ("cpu", "plain"):
        with xla_tuning.forced(mode):
            packed = xla_tuning.pack_pair(a, b)
            assert isinstance(packed, tuple) == (mode == "plain")
            got = xla_tuning.take_pair(packed, index)
            np.testing.assert_array_equal(got[0], a[index])
            np.testing.assert_array_equal(got[1], b[index])
            np.testing.assert_array_equal(xla_tuning.after(a, jnp.int32([7])), a)
            first, stop = xla_tuning.shared_loop_bounds(jnp.int32(2), jnp.int32(5))
            assert (int(first), int(stop)) == (2, 5)


@pytest.mark.parametrize("config", [SGMConfig(), SGMConfig(distance_metric="l2", blend_hypotheses=True)],
                         ids=["default", "l2_blend"])
def test_complete_points_and_rig_agree_on_the_synthetic_scene(config):
    frame = jaxdepth.make_street_scene(0, cameras="stereo", image_scale=0.5)
    camera = frame.cameras[0]
    _assert_same(*_both(lambda: jaxdepth.complete_points_stages(frame.points, frame.valid, camera,
                                                                config=config, lidar=frame.lidar)))
    cameras = jaxdepth.stack_cameras(frame.cameras)
    _assert_same(*_both(lambda: jaxdepth.complete_rig_stages(frame.points, frame.valid, cameras,
                                                             config=config, lidar=frame.lidar)))


@pytest.mark.slow
@pytest.mark.shared_data
def test_complete_and_complete_points_agree_on_the_kitti_frame():
    from jaxdepth.io import pad_points, read_depth_png, read_kitti_raw_calib, read_points
    frame = require_shared("kitti", "drive_0001_frame05")
    sparse = read_depth_png(frame / "velodyne_raw_image_02.png")
    calib = read_kitti_raw_calib(frame / "calib_cam_to_cam.txt", frame / "calib_velo_to_cam.txt")["cameras"][2]
    K, T = calib["K"], calib["T_cam_lidar"]
    image = np.asarray(__import__("cv2").imread(str(frame / "image_02.png")))[..., ::-1]
    _assert_same(*_both(lambda: jaxdepth.complete_stages(sparse, K, T)))
    _assert_same_but_near_ties(*_both(lambda: jaxdepth.complete_stages(
        sparse, K, T, image=image, config=SGMConfig(guidance_weight=50.0))), share=5e-4)
    points, _ = read_points(frame / "lidar_data.bin", columns=4)
    padded, valid = pad_points(points)
    camera = jaxdepth.Camera(K=K, T_cam_lidar=T, height=sparse.shape[0], width=sparse.shape[1])
    _assert_same(*_both(lambda: jaxdepth.complete_points_stages(padded, valid, camera)))
    cameras = jaxdepth.stack_cameras([camera, camera])
    _assert_same(*_both(lambda: jaxdepth.complete_rig_stages(padded, valid, cameras)))
