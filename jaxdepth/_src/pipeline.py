"""The SGM pipeline: ordering of the paper's four steps. No maths of its own.

Two entry points share one tail (Steps 2-4, :func:`_complete_tail`); Step 1 (normals) runs
in a different module for each:

* :func:`complete_stages` takes a sparse depth image and K (the KITTI benchmark
  input). Step 1 runs in :func:`~jaxdepth._src.pixel_normals.pixel_normals`: the
  pixels back-projected through K, carried into the LiDAR frame with
  ``T_cam_lidar`` (KITTI camera 2 by default) and binned into the range image.
  Its normals stay listed (:func:`~jaxdepth._src.pixel_normals.pixel_normals_slots`: a slot
  image and a small table; the dense fallback is chosen in the tail, :func:`_listed_plane`).
* :func:`complete_points_stages` takes a raw sweep and a camera. Step 1 runs in
  :func:`~jaxdepth._src.normals.point_normals` on the sweep's true range image, and
  outlier removal uses the exact point angles.

Speed: the image path bins pixels straight into the range image
(:func:`~jaxdepth._src.pixel_normals.pixel_normals`, equal to ``point_normals`` of the
back-projected pixels up to float32 rounding), and stage fences
(:mod:`~jaxdepth._src.xla_tuning`) keep XLA from re-running producers inside their
consumers. tests/test_speed_equivalence.py checks the result against the plain
composition of the stage functions.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from jaxdepth._src import presets
from jaxdepth._src.above_scan import background_above_scan, capped_above_scan
from jaxdepth._src.config import DEFAULT_CONFIG, SGMConfig
from jaxdepth._src.distance import gather_at_seed, nearest_seed, seed_index, seed_offsets
from jaxdepth._src.geodesic import geodesic_seed
from jaxdepth._src.images import guidance_image
from jaxdepth._src.geometry import camera_points, winners_image, zbuffer_image, zbuffer_winners
from jaxdepth._src.hypotheses import column_hypotheses
from jaxdepth._src.normals import point_normals
from jaxdepth._src.pixel_normals import ListedNormals, pixel_normals_listed, pixel_normals_slots
from jaxdepth._src.outliers import keep_mask_for_config
from jaxdepth._src.residual import plane_residual
from jaxdepth._src.smoothing import gaussian_blur
from jaxdepth._src.xla_tuning import after, cond_all, enabled, fence, entry_jit, stage_token, take_last
from jaxdepth._src.validity import seed_distance
from jaxdepth._src.types import Camera, LidarSpec, Stages

def _check_image_inputs(sparse_depth, K):
    if sparse_depth.ndim != 2:
        raise ValueError(f"complete: field 'sparse_depth' expected shape (H, W), got {sparse_depth.shape}")
    if K.shape != (3, 3):
        raise ValueError(f"complete: field 'K' expected shape (3, 3), got {K.shape}")


def _gather_seeds(sparse_depth, keep, normals, at, has_seed):
    """The seed depth and normals at every pixel's seed: ``where(keep, sparse_depth, 0)`` and the (3, H, W)
    normals read by ``at`` ((..., H, W) field -> (..., H, W) values at each pixel's seed).

    A seed is a pixel of ``keep``, so the masked depth at the seed is ``sparse_depth`` there: the depth is read
    unmasked and set to 0 where the mask has no seed (``has_seed``, a scalar; then every pixel is its own
    "seed"). The same values, one read fewer at each pixel's seed (the mask's).

    Returns (seed depth (H, W), seed normals (3, H, W)).
    """
    if not enabled():  # plain: one gather of the four stacked channels
        gathered = at(jnp.stack([normals[0], normals[1], normals[2], sparse_depth]))
        return jnp.where(has_seed, gathered[3], 0.0), gathered[:3]
    # XLA:CPU: four float32 gathers, each fused into its consumers. As two complex64 pairs the single-camera tail
    # wrote them out (the packing fused into the gathers) and read them back: 0.88x its tail's CPU, 0.96x under a
    # vmap (docs/speed.md, "The rig's tail, sub-stage by sub-stage").
    nx, ny, nz, depth = (at(channel) for channel in (*normals, sparse_depth))
    return jnp.where(has_seed, depth, 0.0), jnp.stack([nx, ny, nz])


def _at_seed_index(seed_at):
    """``at`` of :func:`_gather_seeds` for a flat seed index ((H, W) int32, :func:`~jaxdepth._src.distance.seed_index`): under a rig's
    ``vmap`` one flat gather per channel (``xla_tuning.take_last``), no (camera, index) pairs written out."""
    h, w = seed_at.shape
    return lambda field: take_last(field.reshape(field.shape[:-2] + (h * w,)), seed_at)


def _seeds(keep, image, config: SGMConfig):
    """Step 3's seed search: the paper's nearest seed, or the image-guided one."""
    if config.guidance_weight > 0:
        if image is None:  # entry points that take no image (complete_rig, ...)
            raise ValueError("SGMConfig: field 'guidance_weight' > 0 expected a camera image, but this entry "
                             "point takes none (use complete / complete_points with image=, or guidance_weight=0)")
        return geodesic_seed(keep, image, color_weight=config.guidance_weight, sweeps=config.guidance_sweeps,
                             noise_floor=config.guidance_noise_floor)
    return nearest_seed(keep, metric=config.distance_metric, horizontal_cost=config.seed_horizontal_cost)


def _complete_tail(sparse_depth, normals_cam, points_cam, K, T_cam_lidar, *, beams: int,
                   config: SGMConfig, image=None, keep=None, image_size=None, keep_is_step2: bool = False,
                   whole_window: bool = False) -> Stages:
    """Steps 2-4 on one camera image: outliers, nearest seed, residual, smoothing.

    ``keep``: optional (H, W) bool Step-2 mask computed by the caller (several
    sources, each with its own viewpoint); None runs Algorithm 1 here.
    ``image_size``: optional traced (2,) int32 (h, w), the camera's image as the
    top-left window of a rig's (H, W) canvas (nothing projected beyond it). Every
    stage then uses the camera's own size (Step 2's window bounds, the column
    bracket's h / L, the blur's border), so inside the window the result is that
    of the (h, w) image alone (tests/test_rig.py); outside it, any value.
    ``normals_cam`` and ``points_cam``: (3, H, W), or three (H, W) channels each (a rig's views,
    :func:`project_with_normals` with ``apart``); ``normals_cam`` may also be a
    :class:`~jaxdepth._src.pixel_normals.ListedNormals` (the frame); ``Stages.normals`` is (3, H, W) in every case.
    ``keep_is_step2`` (static): the caller's ``keep`` is Step 2's mask of this ``sparse_depth`` (a rig's own
    stage), so a kept pixel has a finite positive depth, as when Step 2 runs here. ``whole_window`` (static):
    ``image_size`` is the array's own (H, W) (a rig's size group): the column bracket, the above-scan rules and
    the depth's masks take the one camera's forms, and the blur pads by copies (``copies`` of
    :func:`gaussian_blur`: the window form's bytes; the default static border rounds a few border pixels of the
    small test rigs 1 ulp apart). With both, the depth's masks read the seed search's scalar (``scalar_mask`` of
    :func:`_tail_after_seeds`).
    """
    # One camera whose Step 2 runs here: each pixel's seed (a kept pixel, nearest_seed) has a finite positive
    # depth whenever the search found a seed, so seed_depth > 0 is the search's scalar at every pixel.
    # So with a caller's keep that is Step 2's mask of it (keep_is_step2), on a window that is the whole array.
    scalar_mask = (keep is None or keep_is_step2) and (image_size is None or whole_window)
    if keep is None:
        keep = keep_mask_for_config(sparse_depth, K, T_cam_lidar, beams=beams, config=config,
                                    points_cam=points_cam, image_size=image_size)
    # Stage fences (real buffers): XLA would otherwise fuse each producer into
    # its consumers and re-run it there (the mask into every step of the
    # distance transform's loops, the offsets into every gather). Their token is the depth's, as Step 1's
    # stages' (one predicate kernel for all of them, not one per fence).
    token = stage_token(sparse_depth)
    keep, = fence(keep, token=token)
    seeds = _seeds(keep, image, config)
    if config.above_scan == "capped":
        # du and dv, read by gathers of (v + dv, u + du): the flat index below moved the capped plane's float32
        # rounding in the Argoverse 2 depth program (a few ulps at 0.7-1 % of its pixels; docs/speed.md, "The seed
        # search's one flat index and the seed depth's read").
        seed_args = fence(seeds.du, seeds.dv, token=token)
    else:
        # One int32 image out of the seed search, the seed's flat index (du and dv: two, and under a rig's vmap the
        # gathers' (camera, index) pairs a third); du and dv are recomputed from it where they are read.
        seed_args = fence(seed_index(seeds.du, seeds.dv), token=token)
    if isinstance(normals_cam, ListedNormals) and (config.blend_hypotheses or config.above_scan == "capped"):
        normals_cam = _listed_image(normals_cam)  # (the blend and the capped rule read the normals' image)
    return _tail_after_seeds(sparse_depth, keep, normals_cam, K, seeds.has_seed, *seed_args, beams=beams,
                             config=config, image_size=None if whole_window else image_size, scalar_mask=scalar_mask,
                             whole_window=whole_window)


def _seed_reader(capped: bool, seed_args):
    """``(at, du, dv)`` from the seed search's fenced output: du, dv when ``capped``, else the flat seed index."""
    if capped:
        du, dv = seed_args
        return functools.partial(gather_at_seed, du=du, dv=dv), du, dv
    seed_at, = seed_args
    du, dv = seed_offsets(seed_at)
    return _at_seed_index(seed_at), du, dv


def _table_at(table, index):
    """(3, ...) normals of the listed table (3, capacity + 1) at the slots ``index``."""
    return jnp.stack([take_last(table[i], index) for i in range(3)])


def _plane_depth(seed_depth, seed_normal, du, dv, K, *, config: SGMConfig):
    """Step 4's ``(residual, depth_raw)``: the seed's plane at each pixel, clipped, 0 where there is no seed."""
    residual = plane_residual(seed_depth, seed_normal, du, dv, K, min_abs_denom=config.min_abs_denom,
                              max_residual_ratio=config.max_residual_ratio)
    depth_raw = jnp.where(seed_depth > 0, jnp.clip(seed_depth + residual, config.min_depth_m, config.max_depth_m), 0.0)
    return residual, depth_raw


def _listed_image(listed: ListedNormals):
    """The (3, H, W) normals image of Step 1 kept listed: the table read at the slot image, or the dense fallback."""
    def from_slots(slot, table, *inputs):
        return _table_at(table, slot)

    return cond_all(listed.fits, from_slots, lambda slot, table, *inputs: listed.dense(*inputs),
                    listed.slot, listed.table, *listed.inputs)


def _listed_plane(listed: ListedNormals, sparse_depth, has_seed, K, seed_at, *, config: SGMConfig):
    """Step 4's residual and plane depth from Step 1 kept listed: where it fits, the seed's slot is gathered and
    then its normal from the small table; else the dense fallback's normals at the seed. Only the residual and
    the depth leave the conditional (the seed depth and offsets are recomputed inside it: fewer buffers live
    across it, as the fallback's own take ~27 MB)."""
    def branch(listed_form):
        def run(slot, table, depth, K_, T, sparse_depth, has_seed, K, seed_at):
            at = _at_seed_index(seed_at)
            if listed_form:
                seed_normal = _table_at(table, at(slot))
            else:
                seed_normal = jnp.stack([at(channel) for channel in listed.dense(depth, K_, T)])
            return _plane_depth(jnp.where(has_seed, at(sparse_depth), 0.0), seed_normal, *seed_offsets(seed_at), K,
                                config=config)
        return run

    return cond_all(listed.fits, branch(True), branch(False), listed.slot, listed.table, *listed.inputs,
                    sparse_depth, has_seed, K, seed_at)


def _tail_after_seeds(sparse_depth, keep, normals_cam, K, has_seed, *seed_args, beams: int, config: SGMConfig,
                      image_size=None, scalar_mask: bool = False, whole_window: bool = False) -> Stages:
    """Step 4 from the seed search's output (``seed_args``: du, dv when ``above_scan`` is "capped", else the
    flat seed index): gathers at the seed, residual, bracket, above-scan rule, blur. ``has_seed``: the seed
    search's (a scalar). ``normals_cam``: (3, H, W), three channels or :class:`ListedNormals`.
    ``scalar_mask`` (static): ``keep`` is Step 2's mask (a subset of ``sparse_depth > 0``, finite depths) and the
    image is the whole array, so ``seed_depth > 0`` equals ``has_seed`` at every pixel: the masks read the scalar, and
    the depth's last kernel no gather at the seed (the listed path) nor the seed depth's buffer (kitti14).
    ``whole_window`` (static, ``image_size`` None; a rig's size group): the blur pads by copies (``copies`` of
    :func:`gaussian_blur`: bit for bit its form with a window that is the whole array), and the bracket's input is
    ordered after the seed search's output buffer rather than after ``du`` (no ``du`` image written) and its
    neighbour search reads one key image (``column_hypotheses(one_key_image=True)``: the same values)."""
    at, du, dv = _seed_reader(config.above_scan == "capped", seed_args)
    if isinstance(normals_cam, ListedNormals):  # (not with the blend or the capped rule: _complete_tail)
        residual, depth_raw = _listed_plane(normals_cam, sparse_depth, has_seed, K, *seed_args, config=config)
        seed_depth = jnp.where(has_seed, at(sparse_depth), 0.0)
        has_seed = has_seed if scalar_mask else seed_depth > 0
        if config.column_bracket:  # the bracket's loop after the conditional (its buffers not live across it)
            depth_raw = column_hypotheses(depth_raw, after(jnp.where(keep, sparse_depth, 0.0), depth_raw), None,
                                          None, K, window_px=sparse_depth.shape[0] / beams,
                                          min_abs_denom=config.min_abs_denom,
                                          max_residual_ratio=config.max_residual_ratio)
    else:
        seed_depth, seed_normal = _gather_seeds(sparse_depth, keep, normals_cam, at, has_seed)
        residual, depth_raw = _plane_depth(seed_depth, seed_normal, du, dv, K, config=config)
        has_seed = has_seed if scalar_mask else seed_depth > 0
        if config.column_bracket:
            # XLA:CPU: the bracket's input comes after the seed search (else its buffers live across the loops).
            # A rig's whole-window group (one source or several since rigtail14): ordered by the
            # search's own output buffer; ordered by du, XLA wrote du out as an int32 image (read again by the last
            # kernel) instead of computing it where the residual reads it (docs/speed.md, nusc16); one key image
            # copied, not two key kernels (nusc17). The single-camera programs keep du and two (not measured there).
            bracket_input = after(jnp.where(keep, sparse_depth, 0.0), seed_args[0] if whole_window else du)
            distance = jnp.where(has_seed, seed_distance(du, dv, seed_depth, metric=config.distance_metric), 0.0)
            depth_raw = column_hypotheses(
                depth_raw, bracket_input, distance, normals_cam, K,
                window_px=sparse_depth.shape[0] / beams, blend=config.blend_hypotheses,
                materialise=config.guidance_weight == 0, min_abs_denom=config.min_abs_denom,
                max_residual_ratio=config.max_residual_ratio, image_size=image_size,
                image_gap=None if image_size is None else image_size[0] // beams, one_key_image=whole_window)
    if config.above_scan == "background":
        depth_raw = background_above_scan(depth_raw, seed_depth, keep, sparse_depth > 0, beams=beams,
                                          max_half_width_px=config.outlier_max_half_width_px,
                                          image_size=image_size)
    elif config.above_scan == "capped":
        depth_raw = capped_above_scan(depth_raw, seed_depth, seed_normal, du, dv, keep, sparse_depth > 0, K,
                                      beams=beams, rows_px=(sparse_depth.shape[0] if image_size is None
                                                            else image_size[0]) / beams,
                                      max_half_width_px=config.outlier_max_half_width_px,
                                      min_abs_denom=config.min_abs_denom,
                                      max_residual_ratio=config.max_residual_ratio, image_size=image_size)
        depth_raw = jnp.where(has_seed, jnp.clip(depth_raw, config.min_depth_m, config.max_depth_m), 0.0)
    depth = gaussian_blur(depth_raw, sigma_px=config.smoothing_sigma_px, radius_px=config.smoothing_radius_px,
                          image_size=image_size, copies=whole_window)
    if config.keep_measured_depth:
        depth = jnp.where(keep, sparse_depth, depth)
    depth = jnp.where(has_seed, jnp.clip(depth, config.min_depth_m, config.max_depth_m), 0.0)
    if isinstance(normals_cam, ListedNormals):  # (a conditional of its own: dropped where only the depth leaves)
        normals = _listed_image(normals_cam)
    else:
        normals = jnp.stack(normals_cam) if isinstance(normals_cam, tuple) else normals_cam
    return Stages(sparse_depth=sparse_depth, normals=normals, inlier_mask=keep, seed_depth=seed_depth,
                  du=du, dv=dv, residual=residual, depth_raw=depth_raw, depth=depth)


def complete_stages(sparse_depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array | None = None, *,
                    config: SGMConfig = DEFAULT_CONFIG, lidar: LidarSpec = presets.KITTI_HDL64,
                    image: jax.Array | None = None) -> Stages:
    """All intermediate products of SGM completion of one sparse depth image.

    Args:
      sparse_depth: (H, W) float32 metres, 0 = empty (e.g. KITTI ``velodyne_raw``).
      K: (3, 3) float32 intrinsics of that image (crop offsets included).
      T_cam_lidar: (4, 4) LiDAR -> camera transform used to recover the LiDAR's
        spherical angles (for normals and outlier removal). Defaults to KITTI's
        camera 2 (``presets.KITTI_T_CAM2_LIDAR``).
      config: static :class:`SGMConfig`.
      lidar: static :class:`LidarSpec` of the sensor that produced the points.
      image: optional camera image aligned with ``sparse_depth`` (same crop):
        (H, W) grey or (H, W, 3) colour, uint8 or float in [0, 1]. Used only
        when ``config.guidance_weight > 0`` (image-guided seeds), which
        requires it; otherwise ignored (the paper's LiDAR-only SGM).

    Returns:
      :class:`Stages`; ``.depth`` is the (H, W) float32 dense depth in metres.
    """
    # One call form for every caller: jit keys its cache on which keywords were passed.
    return _complete_stages(sparse_depth, K, T_cam_lidar, image, config=config, lidar=lidar)


@functools.partial(entry_jit, static_argnames=("config", "lidar", "listed_only"))
def _complete_stages(sparse_depth, K, T_cam_lidar, image=None, *, config: SGMConfig, lidar: LidarSpec,
                     listed_only: bool = False):
    # listed_only (private, the CLI's KITTI jobs: jaxdepth.batch.listed): Step 1 without pixel_normals'
    # dense fallback; returns (Stages, fits), the Stages equal to the public ones only where fits.
    sparse_depth = jnp.asarray(sparse_depth, jnp.float32)
    K = jnp.asarray(K, jnp.float32)
    _check_image_inputs(sparse_depth, K)
    image = guidance_image(image, sparse_depth.shape, guided=config.guidance_weight > 0, where="complete")
    if T_cam_lidar is None:
        T_cam_lidar = presets.KITTI_T_CAM2_LIDAR
    T_cam_lidar = jnp.asarray(T_cam_lidar, jnp.float32)
    sparse_depth = jnp.where(jnp.isfinite(sparse_depth) & (sparse_depth > 0), sparse_depth, 0.0)
    # Step 1 (normals) for image input, in pixel_normals.py: equals R @ point_normals(pixels
    # back-projected into the LiDAR frame) up to float32 rounding, without per-point (N, 3)
    # work over all H W pixels.
    if listed_only:
        normals_cam, fits = pixel_normals_listed(sparse_depth, K, T_cam_lidar, lidar=lidar,
                                                 smoothing=config.normal_smoothing,
                                                 fill_max_gap=config.range_fill_max_gap)
    else:
        # Kept listed (a slot image and a small table; pixel_normals' dense fallback chosen in the tail):
        # the same values as pixel_normals, without its 5 MB (3, H W) fill (docs/speed.md, kitti13).
        normals_cam = pixel_normals_slots(sparse_depth, K, T_cam_lidar, lidar=lidar,
                                          smoothing=config.normal_smoothing, fill_max_gap=config.range_fill_max_gap)
    stages = _complete_tail(sparse_depth, normals_cam, None, K, T_cam_lidar, beams=lidar.beams, config=config,
                            image=image)
    return (stages, fits) if listed_only else stages


def complete(sparse_depth: jax.Array, K: jax.Array, T_cam_lidar: jax.Array | None = None, *,
             config: SGMConfig = DEFAULT_CONFIG, lidar: LidarSpec = presets.KITTI_HDL64,
             image: jax.Array | None = None) -> jax.Array:
    """Dense (H, W) float32 depth in metres from a sparse depth image; see :func:`complete_stages`.

    ``jax.vmap(complete)`` over (B, H, W) depths and (B, 3, 3) intrinsics equals a
    Python loop of single-frame calls to float32 rounding (XLA may fuse the batched
    body differently).

    Examples:
      Two rows of LiDAR returns at the bottom of an 8 x 12 image:

      >>> import numpy as np
      >>> from jaxdepth import complete
      >>> sparse = np.zeros((8, 12), np.float32)
      >>> sparse[6, ::3], sparse[7, 1::3] = 5.0, 4.0
      >>> K = np.array([[10.0, 0, 5.5], [0, 10.0, 3.5], [0, 0, 1]], np.float32)
      >>> depth = complete(sparse, K)
      >>> depth.shape, depth.dtype
      ((8, 12), dtype('float32'))
      >>> bool(np.all(depth[sparse > 0] == sparse[sparse > 0]))  # measured depths are kept
      True
      >>> bool(np.all(depth > 0))  # every pixel has a nearest seed
      True
    """
    return _complete_depth(sparse_depth, K, T_cam_lidar, image, config=config, lidar=lidar)


@functools.partial(entry_jit, static_argnames=("config", "lidar", "listed_only"))
def _complete_depth(sparse_depth, K, T_cam_lidar, image=None, *, config: SGMConfig, lidar: LidarSpec,
                    listed_only: bool = False):
    # Its own jit: only the depth leaves the computation, so XLA drops or fuses
    # away the intermediate stages instead of writing each of them out. listed_only: (depth, fits).
    if listed_only:
        stages, fits = _complete_stages(sparse_depth, K, T_cam_lidar, image, config=config, lidar=lidar,
                                        listed_only=True)
        return stages.depth, fits
    return _complete_stages(sparse_depth, K, T_cam_lidar, image, config=config, lidar=lidar).depth


def complete_points_stages(points: jax.Array, valid: jax.Array, camera: Camera, *,
                           config: SGMConfig = DEFAULT_CONFIG, lidar: LidarSpec = presets.KITTI_HDL64,
                           image: jax.Array | None = None) -> Stages:
    """All intermediate products of SGM completion from a raw sweep, for one camera.

    Args:
      points: (N, 3) float32 LiDAR-frame points, metres (padded; see ``valid``).
      valid: (N,) bool; padding and non-finite points are ignored.
      camera: :class:`Camera` (K, T_cam_lidar traced; height, width static).
      config, lidar: static configuration and sensor description.
      image: optional (height, width) grey or (height, width, 3) colour camera
        image, uint8 or float in [0, 1]; required and used only when
        ``config.guidance_weight > 0`` (see :func:`complete_stages`).

    Returns:
      :class:`Stages` for the camera image.
    """
    return _complete_points_stages(points, valid, camera, image, config=config, lidar=lidar)


@functools.partial(entry_jit, static_argnames=("config", "lidar"))
def _complete_points_stages(points, valid, camera: Camera, image=None, *, config: SGMConfig,
                            lidar: LidarSpec) -> Stages:
    points = jnp.asarray(points, jnp.float32)
    valid = jnp.asarray(valid, bool) & jnp.all(jnp.isfinite(points), axis=-1)
    points = jnp.where(valid[:, None], points, 0.0)
    # Step 1 (normals) for a sweep, in normals.py.
    normals_lidar = point_normals(points, valid, lidar=lidar, smoothing=config.normal_smoothing,
                                  fill_max_gap=config.range_fill_max_gap)
    image = guidance_image(image, (camera.height, camera.width), guided=config.guidance_weight > 0,
                           where="complete_points")
    return camera_stages_from_points(points, valid, normals_lidar, camera.K, camera.T_cam_lidar,
                                     height=camera.height, width=camera.width, lidar=lidar, config=config,
                                     image=image)


def camera_stages_from_points(points, valid, normals_lidar, K, T_cam_lidar, *, height: int, width: int,
                              lidar: LidarSpec, config: SGMConfig, image_size=None, image=None) -> Stages:
    """Steps 1 (projection of points and normals) to 4 for one camera, from prepared sweep normals.

    ``image_size`` (traced (2,) height, width) restricts the image to a window of
    a larger canvas (multi-camera rigs); the output outside it is 0. ``image``:
    the float32 guidance image from :func:`guidance_image` (None when unguided).
    """
    K = jnp.asarray(K, jnp.float32)
    T = jnp.asarray(T_cam_lidar, jnp.float32)
    sparse_depth, _, points_cam, normals_cam = project_with_normals(points, valid, normals_lidar, T, K, height=height,
                                                                    width=width, image_size=image_size)
    stages = _complete_tail(sparse_depth, normals_cam, points_cam, K, T, beams=lidar.beams, config=config,
                            image=image, image_size=image_size)
    return clear_outside_window(stages, image_size)


def project_with_normals(points, valid, normals, T, K, *, height: int, width: int, image_size=None,
                         apart: bool = False):
    """The camera's z-buffer of a sweep, with each hit pixel's point and normal in the camera frame.

    Args:
      points: (N, 3) float32 points; valid: (N,) bool; normals: (N, 3) unit normals, same frame.
      T: (4, 4) float32 points' frame -> camera; K: (3, 3) float32.
      image_size: optional traced (2,) height, width of a window of the canvas (rigs).
      apart: static; points_cam and normals_cam as three (H, W) channels each, not stacked, written
        by :func:`project_apart` (rigs: under ``vmap`` the stack is a (3, C, H, W) buffer that the
        cameras' stages would transpose).

    Returns:
      sparse_depth (H, W) float32 (0 = empty); index (H, W) int32 of the point seen (-1 = none);
      points_cam and normals_cam (3, H, W) float32, 0 where no point is seen (tuples of (H, W) with ``apart``).

    Points and normals are transformed once per point with exact products
    (:func:`~jaxdepth._src.geometry.camera_points`), then gathered per pixel: the z-buffer and
    ``points_cam`` read the same float32 values, the same bits in a rig's camera (``vmap``) as in
    its single-camera call.
    """
    if apart:
        n = points.shape[0]
        sparse_depth, points_cam, normals_cam, (index,) = project_apart(
            points, valid, normals, T, K, height=height, width=width, image_size=image_size,
            labels=((jnp.arange(n, dtype=jnp.int32), -1),))
        return sparse_depth, index, points_cam, normals_cam
    p_cam = camera_points(T, points)
    sparse_depth, index = zbuffer_image(p_cam, valid, K, height=height, width=width, valid_size=image_size)
    n_cam = camera_points(T, normals, translate=False)
    return sparse_depth, index, gather_channels(p_cam, index), gather_channels(n_cam, index)


def project_apart(points, valid, normals, T, K, *, height: int, width: int, image_size=None, labels=()):
    """:func:`project_with_normals` (``apart``) written point by point: the rigs' projection.

    Args as :func:`project_with_normals`; ``labels``: pairs ``(values, fill)`` of further (N,) per-point
    values (a point's source, ...) to put on the pixels.

    Returns:
      ``(sparse_depth, points_cam, normals_cam, label_images)``: sparse_depth (H, W) float32 (0 = empty);
      points_cam and normals_cam three (H, W) float32 channels each (0 where empty); one (H, W) image
      per label, ``fill`` where empty.

    Each pixel's values are those of the point that won it
    (:func:`~jaxdepth._src.geometry.zbuffer_winners`), written by a scatter of the N points onto a
    filled image (:func:`~jaxdepth._src.geometry.winners_image`), the same bits as
    ``project_with_normals``' per-pixel gathers at the index, without reading an (H, W) index once per
    channel (a rig camera has ~20x more pixels than points; docs/speed.md, "The rig's projection
    point by point"). Every output is a scatter's buffer: no consumer re-runs it.
    """
    won = project_winners(points, valid, normals, T, K, height=height, width=width, image_size=image_size)
    return winners_apart(won, labels, height=height, width=width)


def project_winners(points, valid, normals, T, K, *, height: int, width: int, image_size=None, group_size=None):
    """:func:`project_apart`'s per-point half: ``(slot, x, y, z, nx, ny, nz)``, seven (N,) arrays, each point's
    :func:`~jaxdepth._src.geometry.zbuffer_winners` slot (``group_size``: as there) and its camera-frame point
    and normal channels (float32), each a real buffer (fused into the scatters, the exact transform would run
    once per channel). Nothing (H, W): cameras of several sizes share one ``vmap`` of it."""
    p_cam = camera_points(T, points)
    slot, _ = zbuffer_winners(p_cam, valid, K, height=height, width=width, valid_size=image_size,
                              group_size=group_size)
    n_cam = camera_points(T, normals, translate=False)
    return fence(slot, *(p_cam[:, k] for k in range(3)), *(n_cam[:, k] for k in range(3)))


def winners_apart(won, labels=(), *, height: int, width: int):
    """:func:`project_apart`'s (H, W) half from :func:`project_winners`' ``won``: its return value."""
    slot, *channels = won
    image = functools.partial(winners_image, slot, height=height, width=width)
    points_cam = tuple(image(c, 0.0) for c in channels[:3])
    # A winner's depth is its point's z (both read p_cam; winners lie in front): the z channel is the depth image.
    return (points_cam[2], points_cam, tuple(image(c, 0.0) for c in channels[3:]),
            tuple(image(v, fill) for v, fill in labels))


def channels_at(values: jax.Array, index: jax.Array) -> tuple:
    """:func:`gather_channels` as a tuple of C (H, W) channels, not stacked."""
    n, c = values.shape
    slot = jnp.where(index >= 0, index, n)
    zero = jnp.zeros((1,), values.dtype)
    return tuple(jnp.concatenate([values[:, k], zero])[slot] for k in range(c))


def gather_channels(values: jax.Array, index: jax.Array) -> jax.Array:
    """(N, C) per-point values at (H, W) point indices (-1 = none): (C, H, W), 0 where the index is -1.

    One 1-D gather per channel from the channel with a 0 appended at slot N (where the empty pixels
    point): no (H W, C) intermediate and no transpose, which cost ~3x more on 3 Mpx cameras
    (docs/speed.md, "The rig profile now, and the projection's gather"). The same values, bit for
    bit, as ``where(index >= 0, values[index].T, 0)``.
    """
    return jnp.stack(channels_at(values, index))


def clear_outside_window(stages: Stages, image_size) -> Stages:
    """``stages`` with ``depth`` and ``depth_raw`` set to 0 outside the (traced) ``image_size`` window; as is when None."""
    if image_size is None:
        return stages
    height, width = stages.depth.shape
    inside = (jnp.arange(height)[:, None] < image_size[0]) & (jnp.arange(width)[None, :] < image_size[1])
    return stages._replace(depth=jnp.where(inside, stages.depth, 0.0),
                           depth_raw=jnp.where(inside, stages.depth_raw, 0.0))


def complete_points(points: jax.Array, valid: jax.Array, camera: Camera, *,
                    config: SGMConfig = DEFAULT_CONFIG, lidar: LidarSpec = presets.KITTI_HDL64,
                    image: jax.Array | None = None) -> jax.Array:
    """Dense (H, W) float32 depth for ``camera`` from a raw sweep; see :func:`complete_points_stages`."""
    return _complete_points_depth(points, valid, camera, image, config=config, lidar=lidar)


@functools.partial(entry_jit, static_argnames=("config", "lidar"))
def _complete_points_depth(points, valid, camera: Camera, image=None, *, config: SGMConfig,
                           lidar: LidarSpec) -> jax.Array:
    return _complete_points_stages(points, valid, camera, image, config=config, lidar=lidar).depth
