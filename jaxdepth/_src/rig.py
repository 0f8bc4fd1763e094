"""Several cameras from one sweep: the range image and normals once, the cameras vmapped.

Cameras of different sizes share one padded (H, W) canvas in the outputs; each keeps a traced
``image_size`` window, points outside it are not projected, and the output
outside it is 0. Inside the program the cameras are grouped by size (the static
``RigCameras.sizes``): one vmap per group of equal-sized cameras on a canvas of
exactly that size, so no camera computes the padding (the Argoverse 2 rig: six
landscape cameras on 1550 x 2048 and the portrait one on 2048 x 1550, not seven
on 2048 x 2048); the results are padded back onto the (C, H, W) canvas in camera
order (:func:`vmap_by_size`). The projection's per-point part (each point's pixel and
camera-frame values, no (h, w) array) runs once, one vmap of every camera
(:func:`map_by_size_shared`: one set of kernels, not one per size group), and so does Step 2's exact-test loop
(:func:`keep_by_size`, the multi-source path's). Every stage uses the camera's own size, never the canvas's:
Step 2's window bounds (W L / N, H / L), the column bracket's H / L, the
above-scan window and the blur's border (mirrored at the window's edge, the
padding never read). With the sizes known a group's canvas is its cameras' size, so the tail drops the
window (:func:`window`; the blur's border as copies), one source's and several sources', and the one-source
program reads the depth's masks from the seed search's scalar, as one camera does (the same bytes; docs/speed.md,
"The one-source rig's size groups", "The several-sources tail"). A camera's result is therefore the single-camera call's
(``complete_points`` with its K, pose and size) whatever the other cameras:
the z-buffer, the mask and the seeds bit for bit, the depths to float32 rounding
(Step 4's vmapped body is fused differently; tests/test_rig_sizes.py). The projection
forms every product exactly (:func:`~jaxdepth._src.geometry.fixed_dot`), so a point
gets the same pixel and depth bits in the rig as in its own call (issue 37: with plain
float32 products, XLA:CPU's batched rotation product for three or more cameras rounded
z, u, v apart from the unbatched one, and on the Argoverse 2 sweep ``sparse_depth``
differed on 1,700-4,600 px per camera; docs/speed.md, "Grouped by size").

The pipeline is written as three stages, each a ``jit`` of its own (:func:`run_rig_stages`):
:func:`rig_stage_projection` (Step 1 and each camera's z-buffer, a :class:`CameraView` per
camera), :func:`rig_stage_keep` (Step 2) and :func:`rig_stage_tail` (Steps 3-4, the canvas).
Called one after another they are three programs with the one program's bytes; measured, they
compiled no faster than one program and ran 13-31 % slower (docs/speed.md, "Stage programs"),
so :func:`complete_rig_stages` runs them in one ``jit``, :func:`rig_program`; the jobs and :func:`complete_rig`,
which return depth alone, run :func:`rig_depth_program` (the same depth bytes, the other fields never written). The multi-source
pipeline (:mod:`~jaxdepth._src.sources`) is split at the same places and shares the tail
(:func:`camera_tails`); :mod:`jaxdepth.batch.program_cache` serves ``rig_program`` from disk. Every program here is an
:func:`~jaxdepth._src.xla_tuning.entry_jit` (region-analysis copy insertion at the top level; the same bytes).

Image-guided seeds (``SGMConfig.guidance_weight > 0``) take one camera
image per camera on the same canvas, ``images`` (C, H, W) grey or (C, H, W, 3)
colour: each camera's image sits in the top-left corner of the canvas, inside its
``image_size`` window, and the padding beyond is ignored (:func:`stack_images`
pads with zeros). The geodesic seed search stays inside the window: colours
outside it are replaced by NaN, which makes every step into the padding cost
1e6 px (:func:`~jaxdepth._src.geodesic.step_costs`), so no path uses the padding
as a shortcut around an image edge as long as paths inside the window cost less
than 2e6 px (at colour weight 5 a straight path across a 1600 x 900 image costs
at most 2500 * (1 + 5 sqrt 3) ~ 24000 px).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src import presets
from jaxdepth._src.config import SGMConfig
from jaxdepth._src.images import unit_float_image
from jaxdepth._src.normals import point_normals
from jaxdepth._src.config import DEFAULT_CONFIG
from jaxdepth._src.outlier_groups import exact_test_groups, shared_windows
from jaxdepth._src.outliers import keep_mask_for_config
from jaxdepth._src.pipeline import _complete_tail, clear_outside_window, project_winners, winners_apart
from jaxdepth._src.types import LidarSpec, Stages
from jaxdepth._src.xla_tuning import entry_jit


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RigCameras:
    """C cameras stacked on a common canvas.

    Attributes:
      K: (C, 3, 3) float32. T_cam_lidar: (C, 4, 4) float32.
      image_size: (C, 2) int32 (height, width) of each real image (<= canvas).
      height, width: static canvas size.
      sizes: static tuple of C ``(height, width)`` int pairs, the values of ``image_size``
        (:func:`stack_cameras` fills both): the rig programs run each group of equal-sized
        cameras on a canvas of that size (:func:`vmap_by_size`). None: unknown, every camera
        on the (height, width) canvas.
    """

    K: jax.Array
    T_cam_lidar: jax.Array
    image_size: jax.Array
    height: int = dataclasses.field(metadata=dict(static=True))
    width: int = dataclasses.field(metadata=dict(static=True))
    sizes: tuple | None = dataclasses.field(default=None, metadata=dict(static=True))

    @property
    def count(self) -> int:
        return self.K.shape[0]


def stack_images(images, cameras) -> np.ndarray:
    """Pads one camera image per camera onto the rig's canvas, for ``complete_rig(..., images=)``.

    Args:
      images: sequence of C NumPy arrays, image ``i`` of shape (h_i, w_i) grey or
        (h_i, w_i, 3) colour, where (h_i, w_i) is camera ``i``'s
        ``image_size``; all grey or all colour, all one dtype (uint8 0-255, or
        float in [0, 1]). Rows are image rows (``v``), columns ``u``, as the
        camera's K expects; colour channel order as you like (RGB is what the
        jobs pass), the geodesic cost only uses colour differences.
      cameras: the :class:`RigCameras` of :func:`stack_cameras`, or the
        sequence of cameras given to it (anything with ``height`` and
        ``width``, e.g. :class:`Camera`; the canvas is then the largest size,
        as in :func:`stack_cameras`), in the same order as ``images``.

    Returns:
      (C, H, W) or (C, H, W, 3) array of the images' dtype on the (H, W) canvas:
      image ``i`` in the top-left ``h_i x w_i`` corner (camera ``i``'s window),
      zeros elsewhere (the padding is never read by the seed search).

    Raises:
      ValueError naming ``images[i]``: a wrong count, size, channel count or dtype.
    """
    if isinstance(cameras, RigCameras):
        sizes, height, width = np.asarray(cameras.image_size), cameras.height, cameras.width
    else:
        sizes = np.array([[int(c.height), int(c.width)] for c in cameras], np.int64).reshape(-1, 2)
        height, width = (int(x) for x in sizes.max(axis=0)) if len(sizes) else (0, 0)
    images = list(images)
    if len(images) != len(sizes) or not images:
        raise ValueError(f"stack_images: field 'images' expected one image per camera ({len(sizes)}), "
                         f"got {len(images)}")
    arrays = [np.asarray(im) for im in images]
    first = arrays[0]
    colour = first.ndim == 3
    for i, (im, (h, w)) in enumerate(zip(arrays, sizes)):
        want = f"({h}, {w}, 3) colour" if colour else f"({h}, {w}) grey"
        if im.shape not in ((h, w), (h, w, 3)):
            raise ValueError(f"stack_images: field 'images[{i}]' expected shape ({h}, {w}) (grey) or "
                             f"({h}, {w}, 3) (colour), camera {i}'s image size, got {im.shape}")
        if (im.ndim == 3) != colour:
            raise ValueError(f"stack_images: field 'images[{i}]' expected {want} like images[0] (all grey or "
                             f"all colour), got shape {im.shape}")
        if im.dtype != first.dtype:
            raise ValueError(f"stack_images: field 'images[{i}]' expected dtype {first.dtype} like images[0], "
                             f"got {im.dtype}")
    out = np.zeros((len(sizes), height, width) + first.shape[2:], first.dtype)
    for i, (im, (h, w)) in enumerate(zip(arrays, sizes)):
        out[i, :h, :w] = im
    return out


def _rig_images(images, cameras: RigCameras, *, guided: bool, where: str):
    """Checks ``images`` against the canvas; float32 [0, 1] when ``guided``, else None (ignored).

    Same rules as :func:`~jaxdepth._src.images.guidance_image` (the dtype rule is its
    :func:`~jaxdepth._src.images.unit_float_image`), for the stacked (C, H, W[, 3])
    array; ValueError naming the field 'images' otherwise.
    """
    c, h, w = cameras.count, cameras.height, cameras.width
    if images is None:
        if guided:
            raise ValueError(f"{where}: field 'images' expected ({c}, {h}, {w}) grey or ({c}, {h}, {w}, 3) colour "
                             "camera images (one per camera on the rig's canvas, see stack_images) because "
                             "config.guidance_weight > 0, got None")
        return None
    if not hasattr(images, "shape") or not hasattr(images, "dtype"):
        raise ValueError(f"{where}: field 'images' expected one array ({c}, {h}, {w}[, 3]) (see stack_images), "
                         f"got {type(images).__name__}")
    shp = tuple(images.shape)
    if shp not in ((c, h, w), (c, h, w, 3)):
        raise ValueError(f"{where}: field 'images' expected shape {(c, h, w)} (grey) or {(c, h, w, 3)} (colour): "
                         f"one image per camera on the rig's {h} x {w} canvas (see stack_images), got {shp}")
    return unit_float_image(images, guided=guided, where=where, field="images")


def _window_only(image: jax.Array, size: jax.Array) -> jax.Array:
    """The camera's ``size`` window of a canvas image, NaN outside (blocked steps in the geodesic passes)."""
    h, w = image.shape[:2]
    inside = (jnp.arange(h)[:, None] < size[0]) & (jnp.arange(w)[None, :] < size[1])
    if image.ndim == 3:
        inside = inside[..., None]
    return jnp.where(inside, image, jnp.nan)


def stack_cameras(cameras) -> RigCameras:
    """Stacks :class:`Camera` objects (any sizes) into :class:`RigCameras` on the largest canvas."""
    cameras = list(cameras)
    if not cameras:
        raise ValueError("stack_cameras: expected at least one camera, got none")
    sizes = tuple((int(c.height), int(c.width)) for c in cameras)
    return RigCameras(
        K=jnp.asarray(np.stack([np.asarray(c.K, np.float32) for c in cameras])),
        T_cam_lidar=jnp.asarray(np.stack([np.asarray(c.T_cam_lidar, np.float32) for c in cameras])),
        image_size=jnp.asarray(np.array(sizes, np.int32)),
        height=max(h for h, _ in sizes), width=max(w for _, w in sizes), sizes=sizes)


def size_groups(cameras: RigCameras) -> tuple:
    """Static ``((height, width), camera indices)`` per distinct camera size, in order of first
    appearance; without ``cameras.sizes`` one group: the canvas, every camera."""
    if cameras.sizes is None:
        return (((cameras.height, cameras.width), np.arange(cameras.count)),)
    groups: dict = {}
    for i, size in enumerate(cameras.sizes):
        groups.setdefault(tuple(int(x) for x in size), []).append(i)
    return tuple((size, np.asarray(idx)) for size, idx in groups.items())


def _pad_to_canvas(x: jax.Array, height: int, width: int) -> jax.Array:
    """(..., h, w) -> (..., height, width): ``x`` in the top-left corner, zeros (False) beyond."""
    pad = [(0, 0, 0)] * (x.ndim - 2) + [(0, height - x.shape[-2], 0), (0, width - x.shape[-1], 0)]
    return jax.lax.pad(x, jnp.zeros((), x.dtype), pad)


def _group_inputs(cameras: RigCameras, images, idx, h: int, w: int, whole: bool):
    """A size group's (K, T, image_size, image): every camera as stacked when ``whole``."""
    if whole:
        return cameras.K, cameras.T_cam_lidar, cameras.image_size, images
    image = None if images is None else images[idx, :h, :w]
    return cameras.K[idx], cameras.T_cam_lidar[idx], cameras.image_size[idx], image


def _whole_canvas(cameras: RigCameras, groups) -> bool:
    return len(groups) == 1 and groups[0][0] == (cameras.height, cameras.width)


def map_by_size(per_camera, cameras: RigCameras, images=None, per_group=None) -> tuple:
    """Runs ``per_camera(K, T_cam_lidar, size, image[, extra], *, height, width)`` for every camera, one
    vmap per size group (:func:`size_groups`) on a canvas of the group's size; the results stay per group.

    ``images``: None or (C, H, W[, 3]) on the rig's canvas; each group gets its top-left (h, w) corner.
    ``per_group``: None, or one pytree per group with a leading axis of the group's cameras (an earlier
    call's result), passed as ``extra``. Returns a tuple with one pytree per group, each leaf with a
    leading axis of the group's cameras (in the group's order) and trailing (h, w) axes;
    :func:`to_canvas` puts them back on the canvas in camera order.
    """
    groups = size_groups(cameras)
    whole = _whole_canvas(cameras, groups)
    out = []
    for g, ((h, w), idx) in enumerate(groups):
        run = functools.partial(per_camera, height=h, width=w)
        extra = () if per_group is None else (per_group[g],)
        out.append(jax.vmap(run)(*_group_inputs(cameras, images, idx, h, w, whole), *extra))
    return tuple(out)


def map_by_size_shared(shared, per_camera, cameras: RigCameras) -> tuple:
    """:func:`map_by_size` of ``per_camera(K, T_cam_lidar, size, image, shared_part, *, height, width)``, where
    ``shared_part = shared(K, T_cam_lidar, size, group_size, *, height, width)`` holds no (h, w) array.

    Several size groups: ``shared`` runs once, one vmap over every camera (one set of kernels, not one per
    group), with ``group_size`` each camera's group's traced (2,) int32 (h, w) and ``(height, width)`` =
    (the largest h w, 1), a flat buffer every group's pixels fit; its parts are then split by group. One
    group: ``shared`` inside the group's vmap with ``group_size`` None and the group's size.
    """
    groups = size_groups(cameras)
    if len(groups) == 1:
        def both(K, T, size, image, *, height, width):
            part = shared(K, T, size, None, height=height, width=width)
            return per_camera(K, T, size, image, part, height=height, width=width)
        return map_by_size(both, cameras)
    bound = np.zeros((cameras.count, 2), np.int32)
    for size, idx in groups:
        bound[idx] = size
    pixels = max(h * w for (h, w), _ in groups)
    parts = jax.vmap(functools.partial(shared, height=pixels, width=1))(cameras.K, cameras.T_cam_lidar,
                                                                         cameras.image_size, jnp.asarray(bound))
    return map_by_size(per_camera, cameras, None,
                       tuple(jax.tree.map(lambda x, idx=idx: _cameras_at(x, idx), parts) for _, idx in groups))


def keep_by_size(per_camera, cameras: RigCameras, views: tuple, *, beams: int, config: SGMConfig,
                 shared: bool = True) -> tuple:
    """Step 2 of every camera: :func:`map_by_size` of ``per_camera(K, T, size, image, view, keep=None, *, height,
    width, defer=False)`` over ``views`` (one per group), its (h, w) keep masks per group.

    ``shared`` and several size groups with the same static window (:func:`~jaxdepth._src.outlier_groups.
    shared_windows` of the LiDAR's ``beams`` and ``config``): ``per_camera(..., defer=True)`` returns each
    camera's phases 1-2 (``outliers.KeepParts``), the exact test runs once for all cameras
    (:func:`~jaxdepth._src.outlier_groups.exact_test_groups`), and ``per_camera(..., keep=)`` finishes each camera
    from its mask (the same masks as each group's own loop).
    """
    groups = size_groups(cameras)
    windows = shared_windows(tuple(size for size, _ in groups), beams=beams, config=config) if shared else None
    if windows is None:
        return map_by_size(per_camera, cameras, None, views)
    parts = map_by_size(functools.partial(per_camera, defer=True), cameras, None, views)
    keeps = exact_test_groups(parts, tuple(size for size, _ in groups), **windows)

    def finish(K, T, size, image, view_keep, *, height, width):
        return per_camera(K, T, size, image, view_keep[0], view_keep[1], height=height, width=width)

    return map_by_size(finish, cameras, None, tuple(zip(views, keeps)))


def _cameras_at(x: jax.Array, idx: np.ndarray) -> jax.Array:
    """``x[idx]`` on the leading axis, a slice when the static ``idx`` run in a row."""
    if np.array_equal(idx, np.arange(idx[0], idx[0] + len(idx))):
        return jax.lax.slice_in_dim(x, int(idx[0]), int(idx[0]) + len(idx))
    return jnp.take(x, jnp.asarray(idx), axis=0)


def to_canvas(parts: tuple, cameras: RigCameras):
    """:func:`map_by_size`'s per-group results as one pytree with a leading C axis, in camera order,
    each (..., h, w) leaf padded onto the (H, W) canvas with zeros (False)."""
    groups = size_groups(cameras)
    if _whole_canvas(cameras, groups):
        return parts[0]
    slots = [None] * cameras.count
    for ((h, w), idx), out in zip(groups, parts):
        for j, i in enumerate(idx):
            slots[i] = jax.tree.map(lambda x, j=j: x[j], out)
    return jax.tree.map(lambda *xs: jnp.stack([_pad_to_canvas(x, cameras.height, cameras.width) for x in xs]),
                        *slots)


def vmap_by_size(per_camera, cameras: RigCameras, images=None):
    """Runs ``per_camera(K, T_cam_lidar, size, image, *, height, width)`` for every camera, one
    vmap per size group (:func:`size_groups`) on a canvas of the group's size.

    ``images``: None or (C, H, W[, 3]) on the rig's canvas; each group gets its top-left
    (h, w) corner. Returns the pytree of ``per_camera``'s (..., h, w) arrays with a leading C
    axis, in camera order, each padded onto the (H, W) canvas with zeros (False). One group
    of the canvas's size (every same-size rig) is one vmap over the stacked cameras, as before
    the grouping. (:func:`to_canvas` of :func:`map_by_size`.)
    """
    return to_canvas(map_by_size(per_camera, cameras, images), cameras)


class CameraView(NamedTuple):
    """One camera's projected sweep: the stage programs' hand-over from the projection to Steps 2-4.

    Fields (h, w) of the camera's size group: ``sparse_depth`` float32 z-buffer (0 = empty),
    ``points_cam`` and ``normals_cam`` three (h, w) float32 channels each, x, y, z (0 where empty;
    apart, not a (3, h, w) array: under ``vmap`` a stacked (C, 3, h, w) channel array cost transposes
    and copies between the stages, docs/speed.md, "The rig's channels apart"); with several sources
    (:mod:`~jaxdepth._src.sources`) also ``pixel_source`` int8 (int32 past 127 sources; -1 = empty) and ``pixel_shadow``
    bool or None; None for a single sweep.
    """

    sparse_depth: jax.Array
    points_cam: tuple
    normals_cam: tuple
    pixel_source: jax.Array | None = None
    pixel_shadow: jax.Array | None = None


def window(size: jax.Array, cameras: RigCameras):
    """A camera's window as its group's stages take it: None (the whole array) when ``cameras.sizes`` is known,
    as each size group then runs on a canvas of exactly its cameras' size (:func:`map_by_size`), else ``size``.
    The one camera's specialisations apply then (:func:`~jaxdepth._src.pipeline._complete_tail`)."""
    return size if cameras.sizes is None else None


def call_stage(stage, *args, **statics):
    """How :func:`run_rig_stages` calls a stage program by default: ``stage(*args, **statics)`` (its ``jit``);
    :mod:`jaxdepth.batch.program_cache` passes one that serves each stage from its on-disk cache."""
    return stage(*args, **statics)


def check_images(images, cameras: RigCameras, config: SGMConfig, *, where: str) -> None:
    """Raises the ValueError :func:`_rig_images` would (naming the field 'images'), before any stage runs."""
    jax.eval_shape(lambda im: _rig_images(im, cameras, guided=config.guidance_weight > 0, where=where), images)


@functools.partial(entry_jit, static_argnames=("config", "lidar"))
def rig_stage_projection(points, valid, cameras: RigCameras, *, config: SGMConfig, lidar: LidarSpec) -> tuple:
    """Stage program 1 of :func:`complete_rig_stages`: Step 1 (the sweep's normals) and each camera's projection.

    Args: (N, 3) points, (N,) valid, cameras, config and lidar as :func:`complete_rig_stages`.
    Returns: :func:`map_by_size`'s tuple of :class:`CameraView` per size group.
    """
    points = jnp.asarray(points, jnp.float32)
    valid = jnp.asarray(valid, bool) & jnp.all(jnp.isfinite(points), axis=-1)
    points = jnp.where(valid[:, None], points, 0.0)
    normals_lidar = point_normals(points, valid, lidar=lidar, smoothing=config.normal_smoothing,
                                  fill_max_gap=config.range_fill_max_gap)

    def winners(K, T, size, group_size, *, height, width):       # one vmap of every camera (map_by_size_shared)
        return project_winners(points, valid, normals_lidar, jnp.asarray(T, jnp.float32), jnp.asarray(K, jnp.float32),
                               height=height, width=width, group_size=group_size,
                               image_size=size if group_size is not None else window(size, cameras))

    def per_camera(K, T, size, image, won, *, height, width):     # one vmap per camera size
        sparse_depth, points_cam, normals_cam, _ = winners_apart(won, height=height, width=width)
        return CameraView(sparse_depth, points_cam, normals_cam)

    return map_by_size_shared(winners, per_camera, cameras)


@functools.partial(entry_jit, static_argnames=("config", "beams"))
def rig_stage_keep(views: tuple, cameras: RigCameras, *, config: SGMConfig, beams: int) -> tuple:
    """Stage program 2 of :func:`complete_rig_stages`: Step 2, one (h, w) bool keep mask per camera, per size
    group (``views``: :func:`rig_stage_projection`'s; ``beams``: the LiDAR's L)."""
    def per_camera(K, T, size, image, view, *, height, width):
        return keep_mask_for_config(view.sparse_depth, jnp.asarray(K, jnp.float32), jnp.asarray(T, jnp.float32),
                                    beams=beams, config=config, points_cam=view.points_cam,
                                    image_size=window(size, cameras))

    return map_by_size(per_camera, cameras, None, views)


def camera_tails(views: tuple, keeps: tuple, cameras: RigCameras, images=None, *, config: SGMConfig, beams: int,
                 where: str, one_source: bool = False) -> Stages:
    """Steps 3-4 of every camera from its :class:`CameraView` and Step 2 mask (per size group), on the canvas.

    ``images``: as :func:`complete_rig_stages` (checked here, ``where`` names the entry point in errors).
    With ``cameras.sizes`` known (:func:`window` None) every group, one source's or several's, runs on the whole
    array: no window, the one camera's column bracket and above-scan rules, the blur's border as copies.
    ``one_source`` (static; :func:`rig_stage_tail`): ``keeps`` are :func:`rig_stage_keep`'s masks of the views'
    own depth, so the depth's masks also read the seed search's scalar. Several sources keep the per-pixel
    masks: their scalar form moved 1-643 depths of 12 of the 14 Argoverse 2 PNGs by one unit (docs/speed.md,
    "The several-sources tail"). The same bytes (tests/test_rig_sizes.py, tests/test_sources.py).
    Returns :class:`Stages` with a leading C axis, 0 (False) beyond each camera's window (:func:`to_canvas`).
    """
    images = _rig_images(images, cameras, guided=config.guidance_weight > 0, where=where)

    def per_camera(K, T, size, image, view_keep, *, height, width):
        view, keep = view_keep
        if image is not None:
            image = _window_only(image, size)
        whole = window(size, cameras) is None
        stages = _complete_tail(view.sparse_depth, view.normals_cam, view.points_cam, jnp.asarray(K, jnp.float32),
                                jnp.asarray(T, jnp.float32), beams=beams, config=config, image=image, keep=keep,
                                image_size=size, keep_is_step2=one_source, whole_window=whole)
        return clear_outside_window(stages, None if whole else size)

    return to_canvas(map_by_size(per_camera, cameras, images, tuple(zip(views, keeps))), cameras)


@functools.partial(entry_jit, static_argnames=("config", "beams"))
def rig_stage_tail(views: tuple, keeps: tuple, cameras: RigCameras, images=None, *, config: SGMConfig,
                   beams: int) -> Stages:
    """Stage program 3 of :func:`complete_rig_stages`: Steps 3-4 on the canvas (:func:`camera_tails`)."""
    return camera_tails(views, keeps, cameras, images, config=config, beams=beams, where="complete_rig",
                        one_source=True)


def run_rig_stages(points, valid, cameras: RigCameras, images=None, *, config: SGMConfig, lidar: LidarSpec,
                   call=call_stage) -> Stages:
    """:func:`complete_rig_stages` as three stage programs called through ``call`` (:func:`call_stage`):
    :func:`rig_stage_projection`, :func:`rig_stage_keep`, :func:`rig_stage_tail`.

    Called outside ``jit`` they are three programs, the same bytes as one (tests/test_rig_sizes.py), but
    measured no faster to compile and 13-31 % slower to run than one (docs/speed.md, "Stage programs"), so
    the library runs them inside one ``jit``, :func:`rig_program`.
    """
    check_images(images, cameras, config, where="complete_rig")
    views = call(rig_stage_projection, points, valid, cameras, config=config, lidar=lidar)
    keeps = call(rig_stage_keep, views, cameras, config=config, beams=lidar.beams)
    return call(rig_stage_tail, views, keeps, cameras, images, config=config, beams=lidar.beams)


@functools.partial(entry_jit, static_argnames=("config", "lidar"))
def rig_program(points, valid, cameras: RigCameras, images=None, *, config: SGMConfig, lidar: LidarSpec) -> Stages:
    """:func:`complete_rig_stages`' program: the three stages of :func:`run_rig_stages` traced into one ``jit``
    (the same bytes as the stages called one after another, and as fast or faster to compile and run:
    docs/speed.md, "Stage programs")."""
    return run_rig_stages(points, valid, cameras, images, config=config, lidar=lidar)


@functools.partial(entry_jit, static_argnames=("config", "lidar", "seen"))
def rig_depth_program(points, valid, cameras: RigCameras, images=None, *, config: SGMConfig,
                      lidar: LidarSpec, seen: bool = False):
    """:func:`rig_program`'s (C, H, W) ``depth`` alone (the jobs' program, :func:`complete_rig`'s): the other
    fields are never written out, nor put onto the canvas (on the Argoverse 2 sweep 0.8-0.9x the stages
    program's CPU, the same depth bytes: docs/speed.md, "The jobs' depth programs"). ``seen`` (static):
    ``(depth, seen)``, with (C,) int32 :func:`seen_pixels`."""
    return depth_output(run_rig_stages(points, valid, cameras, images, config=config, lidar=lidar), seen)


def seen_pixels(stages: Stages) -> jax.Array:
    """(C,) int32: each camera's pixels with a projected point (nonzero ``sparse_depth``; 0: no point
    projects into the camera, ``complete-rig`` warns)."""
    return jnp.sum(stages.sparse_depth != 0, axis=(1, 2), dtype=jnp.int32)


def depth_output(stages: Stages, seen: bool):
    """A depth program's output: ``stages.depth``, with :func:`seen_pixels` when ``seen``."""
    return (stages.depth, seen_pixels(stages)) if seen else stages.depth


def complete_rig_stages(points: jax.Array, valid: jax.Array, cameras: RigCameras, *,
                        config: SGMConfig = DEFAULT_CONFIG, lidar: LidarSpec = presets.KITTI_HDL64,
                        images: jax.Array | None = None) -> Stages:
    """SGM completion of one sweep for C cameras; every :class:`Stages` field gains a leading C axis.

    Args:
      points: (N, 3) float32 LiDAR-frame points. valid: (N,) bool.
      cameras: :class:`RigCameras` (see :func:`stack_cameras`).
      config, lidar: static configuration and sensor description.
      images: optional camera images on the rig's canvas, (C, H, W) grey or
        (C, H, W, 3) colour, uint8 or float in [0, 1]: camera ``i``'s image in
        the top-left ``image_size[i]`` corner (:func:`stack_images` pads them),
        the rest ignored. Required and used only when
        ``config.guidance_weight > 0`` (image-guided seeds, per camera inside
        its own window, see the module docstring); otherwise checked, then
        ignored (the result is the paper's LiDAR-only SGM, bit for bit).

    Returns:
      :class:`Stages` with (C, H, W) fields ((C, 3, H, W) normals); beyond a camera's window
      every field is 0 (False), ``depth`` and ``depth_raw`` always, the others when
      ``cameras.sizes`` is known (:func:`stack_cameras`: the cameras run grouped by size).

    Raises:
      ValueError (before any stage runs) naming the field 'images': missing while
      guided, a shape other than the canvas's, a dtype other than uint8 or float.

    One program, :func:`rig_program` (the stages of :func:`run_rig_stages` in one ``jit``).
    """
    return rig_program(points, valid, cameras, images, config=config, lidar=lidar)


def complete_rig(points: jax.Array, valid: jax.Array, cameras: RigCameras, *,
                 config: SGMConfig = DEFAULT_CONFIG, lidar: LidarSpec = presets.KITTI_HDL64,
                 images: jax.Array | None = None) -> jax.Array:
    """(C, H, W) float32 dense depth for every camera of the rig; see :func:`complete_rig_stages`.

    Runs :func:`rig_depth_program` (the other fields never written; the same depth bytes as
    ``complete_rig_stages(...).depth`` at XLA's default optimisation level, the suite's level 0 may
    round the two programs' blur 1 ulp apart: docs/speed.md, "The jobs' depth programs")."""
    return rig_depth_program(points, valid, cameras, images, config=config, lidar=lidar)


def at_origin(T) -> bool:
    """Whether a (4, 4) pose (NumPy or concrete) is the identity within 1e-9: a source at the reference origin."""
    return bool(np.allclose(np.asarray(T, np.float64), np.eye(4), atol=1e-9))


def one_sweep_lidar(sources, beams: int | None = None) -> LidarSpec | None:
    """The LiDAR spec when ``sources`` (:class:`~jaxdepth._src.sources.Sources`) is one sweep as
    :func:`~jaxdepth.complete_rig` takes it, else None (host, static): one source of the reference sweep at the
    reference origin (:func:`at_origin`, a pose known on the host), rows from elevation (``rows`` None: the rig
    has no laser rows), Step 2's L its beams. Free space, occlusion, the top-line and per-sweep rules need two
    sweeps, ``above_scan="auto"`` is ``"plane"`` for one LiDAR on both paths: the entry points then run the
    rig's program (one compiled program, the same bytes; docs/multi_source.md)."""
    spec = sources.lidars[0]
    if (sources.count != 1 or sources.sweep != (0,) or sources.rows is not None or beams not in (None, spec.beams)
            or isinstance(sources.T_ref_source, jax.core.Tracer)):
        return None
    return spec if at_origin(sources.T_ref_source[0]) else None


def one_sweep_call(program, sources, cameras: RigCameras, images=None, *, config: SGMConfig, beams=None):
    """``program(points, valid, cameras, images, config=, lidar=)`` (:func:`rig_program`, :func:`rig_depth_program`)
    of ``sources`` when :func:`one_sweep_lidar` takes them for one sweep (``images`` checked as
    ``complete_sources``'), else None: the multi-source entry points' dispatch on the host."""
    lidar = one_sweep_lidar(sources, beams)
    if lidar is None:
        return None
    check_images(images, cameras, config, where="complete_sources")
    return program(sources.points[0], sources.valid[0], cameras, images, config=config, lidar=lidar)
