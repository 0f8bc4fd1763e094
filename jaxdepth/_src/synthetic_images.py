"""Camera images of the synthetic street: albedo, Lambertian shading, texture, noise.

The synthetic scenes of :mod:`jaxdepth._src.synthetic` carry exact depth; this
module renders the matching RGB camera image, so image-guided seeds can be
measured where the truth is known. Used by ``make_street_scene(images=True)``.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.scene import SceneArrays, camera_rays, checked_rays, nearest_hits, street_scene_arrays
from jaxdepth._src.types import Camera

# --------------------------------------------------------------------------- camera images
#
# An RGB image to go with the exact depth, so that image-guided methods can be tested on scenes whose
# colour edges are known. What a pixel shows (documented choices, all deterministic):
#
#   colour = albedo(surface, paint) * shade * texture + noise, quantised to uint8 (round, clip);
#   shade = ambient + (1 - ambient) * max(0, n . sun)        (Lambertian, no shadows, no gamma);
#   texture = 1 + texture_amplitude * (2 h - 1), h in [0, 1) an integer hash of the surface cell
#             (floor(p / texture_cell_m)) and the primitive, constant on each cell;
#   noise = optional per-pixel float (H, W, 3), in units of 1/255 (the street: N(0, 2) from the seed).
#
# Sky (no hit within max range) is _SKY_RGB (times nothing, plus the noise). The normal n is the
# primitive's analytic outward normal at the hit, turned to face the camera (two-sided planes).

_SKY_RGB = (0.55, 0.70, 0.90)
#: Default light direction (LiDAR / scene frame, unit after normalisation): sun ahead-left and high.
SUN_DIRECTION = (0.35, 0.45, 0.82)


class SceneColours(NamedTuple):
    """Albedo of every primitive of a :class:`SceneArrays` (a pytree), linear RGB in [0, 1], float32.

    Attributes:
      planes: (Q, 3) albedo per plane. boxes: (B, 3) per box. cylinders: (P, 3) per cylinder.
      ground_bands: (M, 7) ``[y_lo, y_hi, period_m, on_m, r, g, b]`` paint on plane 0 (the ground):
        a hit with ``y_lo <= y < y_hi`` and (``period_m == 0`` or ``x mod period_m < on_m``) gets
        albedo ``(r, g, b)`` instead of the plane's; later bands paint over earlier ones. Road
        markings and pavements: colour edges inside one planar surface.
    """

    planes: jax.Array
    boxes: jax.Array
    cylinders: jax.Array
    ground_bands: jax.Array


def scene_colours(scene: SceneArrays, *, planes=None, boxes=None, cylinders=None,
                  ground_bands=None) -> SceneColours:
    """Builds a :class:`SceneColours` for ``scene`` (missing albedos are mid grey, no bands).

    Raises:
      ValueError: a field with the wrong shape for ``scene`` or values outside [0, 1].
    """
    def check(name, value, rows, width, default):
        arr = np.full((rows, width), default, np.float64) if value is None else np.asarray(value, np.float64)
        if arr.shape != (rows, width):
            raise ValueError(f"scene_colours: field {name!r} expected shape {(rows, width)}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"scene_colours: field {name!r} expected finite values, got non-finite entries")
        return arr

    out = [check(name, value, np.shape(prims)[0], 3, 0.5)
           for name, value, prims in zip(("planes", "boxes", "cylinders"), (planes, boxes, cylinders), scene)]
    for name, arr in zip(("planes", "boxes", "cylinders"), out):
        if np.any(arr < 0) or np.any(arr > 1):
            raise ValueError(f"scene_colours: field {name!r} expected albedos in [0, 1], got "
                             f"[{arr.min():g}, {arr.max():g}]")
    bands = check("ground_bands", ground_bands, 0 if ground_bands is None else np.shape(ground_bands)[0], 7, 0.0)
    if np.any(bands[:, 4:] < 0) or np.any(bands[:, 4:] > 1) or np.any(bands[:, 2:4] < 0):
        raise ValueError("scene_colours: field 'ground_bands' expected period_m, on_m >= 0 and colours in [0, 1]")
    return SceneColours(*(a.astype(np.float32) for a in out), bands.astype(np.float32))


def cast_rays_labelled(origins: jax.Array, directions: jax.Array, scene: SceneArrays):
    """:func:`cast_rays` plus which primitive each ray hits (pure JAX, jittable).

    Returns:
      (t, label): t (N,) float32, bit-identical to :func:`cast_rays` (same
      minimum over the same per-primitive hits); label (N,) int32, the hit
      primitive's index in the concatenation planes, boxes, cylinders (the
      first one in that order on an exact tie), -1 where nothing is hit.
    """
    o, d = checked_rays(origins, directions, where="cast_rays_labelled")
    return nearest_hits(o, d, scene, labelled=True)


def _hit_normals(p, d, label, scene: SceneArrays):
    """(N, 3) unit normals at hit points p of primitives ``label``, facing against the rays d."""
    counts = [np.shape(x)[0] for x in scene]
    kind_start = np.cumsum([0] + counts)
    n = jnp.zeros_like(p)
    if counts[0]:
        idx = jnp.clip(label - kind_start[0], 0, counts[0] - 1)
        n = jnp.where((label < kind_start[1])[:, None], jnp.asarray(scene.planes)[idx, :3], n)
    if counts[1]:
        box = jnp.asarray(scene.boxes)[jnp.clip(label - kind_start[1], 0, counts[1] - 1)]
        cos, sin = jnp.cos(box[:, 6]), jnp.sin(box[:, 6])
        rx, ry = p[:, 0] - box[:, 0], p[:, 1] - box[:, 1]
        local = jnp.stack([cos * rx + sin * ry, -sin * rx + cos * ry, p[:, 2] - box[:, 2]], axis=1)
        ratio = jnp.abs(local) / jnp.maximum(box[:, 3:6], 1e-6)
        axis = jnp.argmax(ratio, axis=1)
        sign = jnp.sign(jnp.take_along_axis(local, axis[:, None], axis=1))[:, 0]
        nl = jax.nn.one_hot(axis, 3, dtype=p.dtype) * sign[:, None]
        nb = jnp.stack([cos * nl[:, 0] - sin * nl[:, 1], sin * nl[:, 0] + cos * nl[:, 1], nl[:, 2]], axis=1)
        is_box = (label >= kind_start[1]) & (label < kind_start[2])
        n = jnp.where(is_box[:, None], nb, n)
    if counts[2]:
        cyl = jnp.asarray(scene.cylinders)[jnp.clip(label - kind_start[2], 0, counts[2] - 1)]
        rx, ry = p[:, 0] - cyl[:, 0], p[:, 1] - cyl[:, 1]
        rho = jnp.sqrt(rx * rx + ry * ry)
        side_err = jnp.abs(rho - cyl[:, 2])
        top_err, bottom_err = jnp.abs(p[:, 2] - cyl[:, 4]), jnp.abs(p[:, 2] - cyl[:, 3])
        cap = jnp.minimum(top_err, bottom_err) < side_err
        safe = jnp.where(rho > 0, rho, 1.0)
        radial = jnp.stack([rx / safe, ry / safe, jnp.zeros_like(rx)], axis=1)
        vertical = jnp.stack([jnp.zeros_like(rx), jnp.zeros_like(rx), jnp.where(top_err < bottom_err, 1.0, -1.0)],
                             axis=1)
        nc = jnp.where(cap[:, None], vertical, radial)
        n = jnp.where((label >= kind_start[2])[:, None], nc, n)
    facing = jnp.sum(n * d, axis=1, keepdims=True) > 0
    return jnp.where(facing, -n, n)


def _cell_hash(p, label, cell_m):
    """[0, 1) float32 from an integer hash of the cell floor(p / cell_m) and the label (exact uint32 maths)."""
    cell = jnp.floor(p / cell_m).astype(jnp.int32).astype(jnp.uint32)
    h = (cell[:, 0] * jnp.uint32(73856093)) ^ (cell[:, 1] * jnp.uint32(19349663)) \
        ^ (cell[:, 2] * jnp.uint32(83492791)) ^ (label.astype(jnp.uint32) * jnp.uint32(2654435761))
    for shift, mult in ((16, 0x7FEB352D), (15, 0x846CA68B)):
        h = (h ^ (h >> shift)) * jnp.uint32(mult)
    h = h ^ (h >> 16)
    return (h >> 8).astype(jnp.float32) / jnp.float32(1 << 24)


def surface_albedo(p, label, colours: SceneColours, scene: SceneArrays):
    """(N, 3) float32 albedo at hit points p (N, 3) of primitives ``label`` (N,), ground paint included."""
    table = jnp.concatenate([jnp.asarray(c, jnp.float32).reshape(-1, 3) for c in colours[:3]])
    if table.shape[0] == 0:
        return jnp.zeros_like(p)
    albedo = table[jnp.clip(label, 0, table.shape[0] - 1)]
    if np.shape(scene.planes)[0] and np.shape(colours.ground_bands)[0]:
        on_ground = label == 0
        x, y = p[:, 0], p[:, 1]
        for m in range(np.shape(colours.ground_bands)[0]):
            band = jnp.asarray(colours.ground_bands, jnp.float32)[m]
            period = jnp.where(band[2] > 0, band[2], 1.0)
            dashed = jnp.where(band[2] > 0, jnp.mod(x, period) < band[3], True)
            inside = on_ground & (y >= band[0]) & (y < band[1]) & dashed
            albedo = jnp.where(inside[:, None], band[4:7], albedo)
    return albedo


@functools.partial(jax.jit, static_argnames=("max_range_m",))
def render_image(camera: Camera, scene: SceneArrays, colours: SceneColours, noise: jax.Array | None = None, *,
                 sun_direction=SUN_DIRECTION, ambient: float = 0.4, texture_amplitude: float = 0.06,
                 texture_cell_m: float = 0.4, max_range_m: float = 120.0) -> jax.Array:
    """A camera's RGB image of the scene: albedo times Lambertian shading (see the notes above).

    Args:
      camera: :class:`Camera`.
      scene: :class:`SceneArrays`. colours: :class:`SceneColours` of ``scene``.
      noise: optional (H, W, 3) float32 added to every pixel, in units of 1/255.
      sun_direction: (3,) light direction in the scene frame (normalised here).
      ambient: shade of a surface facing away from the sun, in [0, 1].
      texture_amplitude: relative brightness variation between texture cells (0 = flat colours).
      texture_cell_m: texture cell size, metres.
      max_range_m: as :func:`render_depth` (farther hits show the sky).

    Returns:
      (H, W, 3) uint8 RGB, ``round(255 * clip(albedo * shade * texture + noise / 255, 0, 1))``;
      its hits are those of :func:`render_depth` (same rays, same first hit).
    """
    origin, d = camera_rays(camera)
    t, label = cast_rays_labelled(origin, d, scene)
    hit = t * jnp.linalg.norm(d, axis=1) <= max_range_m
    label = jnp.where(hit, label, -1)
    p = origin + d * jnp.where(hit, t, 0.0)[:, None]
    sun = jnp.asarray(sun_direction, jnp.float32)
    sun = sun / jnp.linalg.norm(sun)
    n = _hit_normals(p, d, label, scene)
    shade = ambient + (1.0 - ambient) * jnp.maximum(jnp.sum(n * sun, axis=1), 0.0)
    texture = 1.0 + texture_amplitude * (2.0 * _cell_hash(p, label, texture_cell_m) - 1.0)
    colour = surface_albedo(p, label, colours, scene) * (shade * texture)[:, None]
    colour = jnp.where(hit[:, None], colour, jnp.asarray(_SKY_RGB, jnp.float32))
    colour = colour.reshape(camera.height, camera.width, 3)
    if noise is not None:
        colour = colour + jnp.asarray(noise, jnp.float32) / 255.0
    return jnp.round(255.0 * jnp.clip(colour, 0.0, 1.0)).astype(jnp.uint8)


# Street palette (linear RGB albedo).
_ASPHALT = (0.22, 0.22, 0.24)
_PAVEMENT = (0.52, 0.50, 0.47)
_MARKING = (0.85, 0.85, 0.80)
_POLE = (0.45, 0.46, 0.48)
_CAR_COLOURS = ((0.75, 0.10, 0.08), (0.08, 0.20, 0.55), (0.80, 0.80, 0.78), (0.10, 0.10, 0.11),
                (0.45, 0.47, 0.50), (0.22, 0.23, 0.25), (0.10, 0.40, 0.18), (0.85, 0.65, 0.12))


def street_colours(seed: int = 0, scene: SceneArrays | None = None) -> SceneColours:
    """Albedos of :func:`street_scene_arrays`' primitives, drawn from ``default_rng([seed, 2])``.

    A stream separate from the scene's, so colours do not move objects. Choices that keep the image an
    honest, not a perfect, guide:

    * buildings of a row come in pairs of one facade colour (buildings 0-1, 2-3, 4-5 of each side):
      adjacent facades at different set-backs without a colour edge between them;
    * a car's body and cabin share one colour (one of :data:`_CAR_COLOURS`, which include dark greys
      close to the asphalt);
    * the road is asphalt with a dashed white centre line (3 m of every 9 m, 15 cm wide), two solid
      edge lines (|y| in [3.0, 3.15] m) and lighter pavements beyond |y| = 5 m: colour edges inside
      the one ground plane;
    * poles share one grey; each cyclist's bike, torso and head differ.

    Args:
      seed: the scene seed. scene: the scene (default ``street_scene_arrays(seed)``; only its
        primitive counts are used).
    """
    scene = street_scene_arrays(seed) if scene is None else scene
    rng = np.random.default_rng([seed, 2])
    n_boxes, n_cyl = np.shape(scene.boxes)[0], np.shape(scene.cylinders)[0]
    if (n_boxes, n_cyl) != (49, 13):
        raise ValueError(f"street_colours: field 'scene' expected the street's 49 boxes and 13 cylinders, "
                         f"got {n_boxes} and {n_cyl}")

    def facade():
        return rng.uniform([0.30, 0.25, 0.20], [0.85, 0.75, 0.70])

    boxes = []
    for _side in range(2):
        palette = [facade() for _ in range(3)]
        boxes += [palette[k // 2] for k in range(6)]
        boxes.append(facade())                        # the angled building
    boxes.append(facade())                            # the building closing the street
    for _car in range(15):
        colour = np.asarray(_CAR_COLOURS[rng.integers(len(_CAR_COLOURS))]) * rng.uniform(0.9, 1.1)
        boxes += [colour, colour]                     # body, cabin
    for _cyclist in range(2):
        boxes.append(rng.uniform(0.05, 0.3, 3))       # bike
        boxes.append(rng.uniform(0.2, 0.9, 3))        # torso
    cylinders = [_POLE] * 11 + [(0.80, 0.60, 0.48), (0.55, 0.40, 0.30)]   # poles, two heads
    bands = [[-1e4, -5.0, 0.0, 0.0, *_PAVEMENT], [5.0, 1e4, 0.0, 0.0, *_PAVEMENT],
             [-3.15, -3.0, 0.0, 0.0, *_MARKING], [3.0, 3.15, 0.0, 0.0, *_MARKING],
             [-0.075, 0.075, 9.0, 3.0, *_MARKING]]
    return scene_colours(scene, planes=[_ASPHALT], boxes=np.clip(boxes, 0.0, 1.0), cylinders=cylinders,
                         ground_bands=bands)


def street_image_noise(seed: int, camera_index: int, height: int, width: int, *, std_dn: float = 2.0) -> np.ndarray:
    """(H, W, 3) float32 N(0, std_dn) pixel noise, units of 1/255, from ``default_rng([seed, 3, camera_index])``."""
    rng = np.random.default_rng([seed, 3, camera_index])
    return (std_dn * rng.standard_normal((height, width, 3))).astype(np.float32)
