"""Tests of the synthetic camera images (issue 16: scenes whose image carries real edges).

Oracles: hand-derived colours (albedo x Lambertian shade of an analytic normal,
quantised) on small scenes; a per-primitive first hit from :func:`cast_rays`
(NumPy argmin) for the hit labels; the exact depth of :func:`render_depth` for
which pixels hit something. Invariants: determinism, the existing outputs are
unchanged by ``images=True``, jit == eager.
"""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest

from jaxdepth._src import synthetic, synthetic_images
from jaxdepth._src.types import LidarSpec

# One worker for the module: its tests share the small scene's render_image program (on two workers two tests
# compiled it at once: suite12's profile; docs/testing.md, "Compiled programs").
pytestmark = pytest.mark.xdist_group("synthetic_images")
SPEC = LidarSpec(beams=16, fov_up_deg=2.0, fov_down_deg=-24.9, columns=256)
SUN = np.asarray(synthetic_images.SUN_DIRECTION) / np.linalg.norm(synthetic_images.SUN_DIRECTION)
AMBIENT = 0.4


def _forward_camera(height=40, width=60, f=30.0, z=0.0):
    """A camera at (0, 0, z) of the scene frame looking along +x (x right = -y, y down = -z)."""
    return synthetic._camera(np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]]), 0.0,
                             np.array([0.0, 0.0, z]), height, width)


def _expected(albedo, normal):
    shade = AMBIENT + (1 - AMBIENT) * max(0.0, float(np.dot(normal, SUN)))
    return np.round(255 * np.clip(np.asarray(albedo) * shade, 0, 1)).astype(np.uint8)


@pytest.fixture(scope="module")
def small_scene():
    # Ground 1.5 m below the camera, a box 10 m ahead (front face at x = 9), a yawed box to the left,
    # a cylinder to the right.
    scene = synthetic.scene_arrays(planes=[[0.0, 0.0, 1.0, -1.5]],
                                   boxes=[[10.0, 0.0, 0.0, 1.0, 1.5, 1.5, 0.0],
                                          [12.0, 6.0, 0.0, 1.0, 1.0, 1.5, math.radians(30.0)]],
                                   cylinders=[[8.0, -4.0, 0.5, -1.5, 1.5]])
    colours = synthetic_images.scene_colours(scene, planes=[[0.3, 0.3, 0.3]],
                                      boxes=[[0.8, 0.2, 0.1], [0.1, 0.6, 0.2]], cylinders=[[0.2, 0.3, 0.9]],
                                      ground_bands=[[-0.25, 0.25, 0.0, 0.0, 0.9, 0.9, 0.9]])
    return scene, colours


def _render(camera, scene, colours, *, noise=None, texture_amplitude=0.0):
    """Flat colours (and no noise) by default; always called with the same arguments (a noise image,
    zeros by default, and a texture amplitude): one compiled program per camera size."""
    if noise is None:
        noise = np.zeros((camera.height, camera.width, 3), np.float32)
    return np.asarray(synthetic_images.render_image(camera, scene, colours, noise,
                                                    texture_amplitude=texture_amplitude))


def test_analytic_colours_of_known_surfaces(small_scene):
    scene, colours = small_scene
    cam = _forward_camera()
    img = _render(cam, scene, colours)
    assert img.shape == (40, 60, 3) and img.dtype == np.uint8
    K = np.asarray(cam.K)

    def pixel(p):  # scene point -> (v, u) rounded
        x, y = -p[1], -p[2]
        return int(round(K[1, 1] * y / p[0] + K[1, 2])), int(round(K[0, 0] * x / p[0] + K[0, 2]))

    # Front face of box 0 (normal -x, facing the camera).
    v, u = pixel(np.array([9.0, 0.6, 0.6]))
    np.testing.assert_array_equal(img[v, u], _expected([0.8, 0.2, 0.1], [-1.0, 0.0, 0.0]))
    # The ground (normal +z) outside and inside the painted band.
    v, u = pixel(np.array([4.0, 1.2, -1.5]))
    np.testing.assert_array_equal(img[v, u], _expected([0.3, 0.3, 0.3], [0.0, 0.0, 1.0]))
    v, u = pixel(np.array([4.0, 0.0, -1.5]))
    np.testing.assert_array_equal(img[v, u], _expected([0.9, 0.9, 0.9], [0.0, 0.0, 1.0]))
    # The cylinder's side: the pixel's own ray meets the circle (x - 8)^2 + (y + 4)^2 = 0.25 first at
    # a hit whose normal is radial.
    v, u = pixel(np.array([8.0, -4.0, 0.5]))
    ray = np.array([1.0, -(u - K[0, 2]) / K[0, 0], -(v - K[1, 2]) / K[1, 1]])
    a, b = ray[0] ** 2 + ray[1] ** 2, -2 * (8.0 * ray[0] - 4.0 * ray[1])
    t = (-b - math.sqrt(b * b - 4 * a * (8.0 ** 2 + 4.0 ** 2 - 0.25))) / (2 * a)
    radial = np.array([t * ray[0] - 8.0, t * ray[1] + 4.0, 0.0]) / 0.5
    np.testing.assert_array_equal(img[v, u], _expected([0.2, 0.3, 0.9], radial))
    # The yawed box: the face seen from the camera is the one whose normal is its local -x or -y.
    yaw = math.radians(30.0)
    centre = np.array([12.0, 6.0, 0.5])
    v, u = pixel(centre - 1.0 * np.array([math.cos(yaw), math.sin(yaw), 0.0]))
    np.testing.assert_array_equal(img[v, u], _expected([0.1, 0.6, 0.2], [-math.cos(yaw), -math.sin(yaw), 0.0]))
    # Sky above the horizon (nothing hit within range).
    np.testing.assert_array_equal(img[0, 0], np.round(255 * np.asarray(synthetic_images._SKY_RGB)).astype(np.uint8))


def test_hits_labels_and_sky_agree_with_depth_and_cast_rays(small_scene):
    scene, colours = small_scene
    cam = _forward_camera()
    origin, d = synthetic.camera_rays(cam)
    t, label = (np.asarray(x) for x in jax.jit(synthetic_images.cast_rays_labelled)(origin, d, scene))
    cast = jax.jit(synthetic.cast_rays)   # compiled once per scene layout (op by op: every primitive)
    t_ref = np.asarray(cast(origin, d, scene))
    assert t.tobytes() == t_ref.tobytes()
    # Oracle: cast each primitive on its own, argmin in NumPy.
    per = []
    for kind in range(3):
        for i in range(np.shape(scene[kind])[0]):
            only = [np.zeros((0, np.shape(x)[1]), np.float32) for x in scene]
            only[kind] = np.asarray(scene[kind])[i:i + 1]
            per.append(np.asarray(cast(origin, d, synthetic.SceneArrays(*only))))
    per = np.stack(per, 1)
    ref = np.where(np.isfinite(per.min(1)), np.argmin(per, 1), -1)
    np.testing.assert_array_equal(label, ref)
    assert set(np.unique(label)) == {-1, 0, 1, 2, 3}
    # Sky pixels of the image are exactly the pixels without depth.
    img = _render(cam, scene, colours)
    depth = np.asarray(synthetic.render_depth(cam, scene))
    sky = np.all(img == np.round(255 * np.asarray(synthetic_images._SKY_RGB)).astype(np.uint8), axis=2)
    np.testing.assert_array_equal(sky, depth == 0)


def test_texture_and_noise_bounds(small_scene):
    scene, colours = small_scene
    cam = _forward_camera()
    flat = _render(cam, scene, colours).astype(float)
    textured = _render(cam, scene, colours, texture_amplitude=0.1).astype(float)
    hit = np.asarray(synthetic.render_depth(cam, scene)) > 0
    # Texture scales each surface pixel by a factor in [0.9, 1.1] (rounding: +-1 DN) and varies it.
    assert np.all(textured[hit] <= 1.1 * flat[hit] + 1) and np.all(textured[hit] >= 0.9 * flat[hit] - 1)
    assert np.mean(textured[hit] != flat[hit]) > 0.3
    np.testing.assert_array_equal(textured[~hit], flat[~hit])
    noise = np.full((40, 60, 3), 3.0, np.float32)
    shifted = _render(cam, scene, colours, noise=noise).astype(float)
    assert np.all(np.abs(shifted - np.clip(flat + 3, 0, 255)) <= 1)


def test_street_images_deterministic_and_leave_outputs_unchanged():
    kw = dict(lidar=SPEC, cameras="stereo", image_scale=0.125)
    plain = synthetic.make_street_scene(3, **kw)
    a = synthetic.make_street_scene(3, images=True, **kw)
    b = synthetic.make_street_scene(3, images=True, **kw)
    other = synthetic.make_street_scene(4, images=True, **kw)
    assert plain.images is None and len(a.images) == 2
    for img in a.images:
        assert img.shape == (44, 152, 3) and img.dtype == np.uint8
    assert a.points.tobytes() == plain.points.tobytes() and a.valid.tobytes() == plain.valid.tobytes()
    for x, y in zip(a.dense_depth, plain.dense_depth):
        assert x.tobytes() == y.tobytes()
    for x, y in zip(a.images, b.images):
        assert x.tobytes() == y.tobytes()
    assert not np.array_equal(a.images[0], other.images[0])
    assert not np.array_equal(a.images[0], a.images[1])       # two viewpoints (and noise streams)


def test_street_albedos_distinct_objects_differ_and_honest_cases():
    scene = synthetic.street_scene_arrays(1)
    colours = synthetic_images.street_colours(1, scene)
    boxes = np.asarray(colours.boxes)
    # Paired facades share a colour (no colour edge at their set-back), a car's body and cabin too.
    for side in (0, 7):
        np.testing.assert_array_equal(boxes[side], boxes[side + 1])
        assert not np.array_equal(boxes[side + 1], boxes[side + 2])
    np.testing.assert_array_equal(boxes[15], boxes[16])
    # Render a forward camera; pixels of two primitives with distinct albedo (flat, noise-free) differ.
    cam = synthetic.rig_cameras("kitti", image_scale=0.25)[0]
    img = _render(cam, scene, colours)
    origin, d = synthetic.camera_rays(cam)
    _, label = synthetic_images.cast_rays_labelled(origin, d, scene)
    label = np.asarray(label).reshape(cam.height, cam.width)
    table = np.concatenate([np.asarray(c).reshape(-1, 3) for c in colours[:3]])
    seen = [lab for lab in np.unique(label) if lab > 0 and np.sum(label == lab) >= 5]
    assert len(seen) >= 8
    # Per primitive, the pixel colour divided by its albedo is a shade in [ambient, 1] (flat texture).
    for lab in seen:
        ratio = img[label == lab].astype(float) / (255 * table[lab])
        assert np.all(ratio > AMBIENT - 0.05) and np.all(ratio < 1.05)
    # Shade multiplies all channels alike, so a pixel's chromaticity (colour / its sum) is its albedo's:
    # two primitives whose albedo chromaticities differ show different pixel colours wherever lit.
    chroma = table / table.sum(axis=1, keepdims=True)
    for lab in seen:
        px = img[label == lab].astype(float)
        bright = px.sum(axis=1) > 90
        np.testing.assert_allclose(px[bright] / px[bright].sum(axis=1, keepdims=True),
                                   np.broadcast_to(chroma[lab], px[bright].shape), atol=0.02)
    distinct = [(a, b) for i, a in enumerate(seen) for b in seen[i + 1:]
                if np.max(np.abs(chroma[a] - chroma[b])) > 0.05]
    assert len(distinct) > 10
    # The road markings paint the ground plane: the ground (label 0) shows asphalt and marking colours.
    ground = img[label == 0].astype(float).mean(axis=1)
    assert ground.max() - ground.min() > 100


def test_render_image_jit_equals_eager_and_validation(small_scene):
    scene, colours = small_scene
    cam = _forward_camera(height=12, width=16, f=8.0)
    jitted = np.asarray(synthetic_images.render_image(cam, scene, colours))
    eager = np.asarray(synthetic_images.render_image.__wrapped__(cam, scene, colours))
    assert np.max(np.abs(jitted.astype(int) - eager.astype(int))) <= 1
    with pytest.raises(ValueError, match="boxes.*\\(2, 3\\)"):
        synthetic_images.scene_colours(scene, boxes=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="planes.*\\[0, 1\\]"):
        synthetic_images.scene_colours(scene, planes=[[2.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="49 boxes"):
        synthetic_images.street_colours(0, scene)
