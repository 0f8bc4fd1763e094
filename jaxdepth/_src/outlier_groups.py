"""Step 2's exact test once for the cameras of every size group of a rig (image shapes as data).

Contract: the rig's Step 2 in per-group pieces in, the same keep masks out, bit for bit. Phases 1-2
(prefilter, compaction: dense passes of the image's own shape) stay per size group
(``outliers._keep_mask(..., defer=True)`` under each group's ``vmap``); phase 3, the exact-test loop
(:mod:`~jaxdepth._src.outlier_exact`), reads its images only at flat pixel indices, so it runs once for every
camera: each camera's (h, w) is data, its candidate and column words are padded to the longest camera's, and
the images stay in their groups' buffers (:class:`~jaxdepth._src.outlier_exact.Grouped`: each read gathers
from every group's buffer at the camera's index or 0 and keeps its own; no copy of the images into one).
The loop compiles once instead of once per group (the Argoverse 2 rig: the portrait camera's copy). Each
camera's candidates fill chunks of :data:`~jaxdepth._src.outlier_exact.CHUNK` slots, listed camera after
camera, and a loop step tests one chunk per lane, as many lanes as cameras (docs/speed.md, "Step 2's exact
test once for every camera").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.compaction import WORD_BITS, word_locator
from jaxdepth._src.outlier_exact import CHUNK, ExactTest, Grouped, candidates_removed
from jaxdepth._src.outliers import _row_block, window_half_sizes


def _flat(x: jax.Array, length: int) -> jax.Array:
    """(n, ...) -> (n, length): each camera's array flat, zeros after it."""
    x = x.reshape(x.shape[0], -1)
    return jnp.pad(x, ((0, 0), (0, length - x.shape[1])))


def _by_group(images: tuple):
    """One group-flat array per group (:class:`~jaxdepth._src.outlier_exact.Grouped`), or None."""
    return None if images[0] is None else tuple(x.reshape(-1) for x in images)


def exact_test_groups(parts: tuple, sizes: tuple, *, hh: int, hw: int, test: str, down: bool) -> tuple:
    """Phase 3 of Step 2 for every camera of a rig in one loop.

    Args:
      parts: one :class:`~jaxdepth._src.outliers.KeepParts` per size group, each leaf with a leading axis of
        the group's cameras (``_keep_mask(..., defer=True)`` under the group's ``vmap``); ``points`` three
        channels apart (a rig's views); ``h_max`` given (``image_size``: the camera's own bounds).
      sizes: static (h, w) of each group's images.
      hh, hw, test, down: the static window half sizes, condition-1 form and word layout, the same for
        every group.

    Returns:
      One (n_g, h, w) bool keep mask per group, each camera's as its group's own ``_keep_mask`` gives it.

    Each camera's candidates fill ``ceil(count / CHUNK)`` chunks of slots, listed camera after camera; a loop
    step tests C of them at once (C cameras: one lane each, ``vmap``), each lane with its chunk's camera's
    parameters: the loop runs ``ceil(all chunks / C)`` steps (the lanes in lockstep, to the largest window walk
    among them), not each group's largest chunk count. The loop carries each group's own keep buffer (its
    ``valid``): a lane's removals go to its camera's group, so no mask is concatenated and sliced back.
    """
    counts = [p.depth.shape[0] for p in parts]
    n_cam, pixels = sum(counts), tuple(h * w for h, w in sizes)
    longest = lambda f: max(int(np.prod(f(p).shape[1:])) for p in parts)
    n_words, n_columns = longest(lambda p: p.words), longest(lambda p: p.columns)
    cat = lambda f: jnp.concatenate([f(p) for p in parts])
    per_camera = lambda values: jnp.asarray(np.repeat(np.asarray(values, np.int32), counts, axis=0))
    size, row_words = per_camera(sizes), per_camera([p.words.shape[-1] for p in parts])
    group, member = per_camera(np.arange(len(parts))), jnp.asarray(np.concatenate([np.arange(n) for n in counts]))
    K, t, eps, k_max = cat(lambda p: p.K), cat(lambda p: p.t), cat(lambda p: p.eps), cat(lambda p: p.k_max)
    cell_u, cell_v, h_max = cat(lambda p: p.cell_u), cat(lambda p: p.cell_v), cat(lambda p: p.h_max)
    columns = cat(lambda p: _flat(p.columns, n_columns)).reshape(-1)
    images = (_by_group(tuple(p.depth for p in parts)), tuple(_by_group(tuple(p.points[c] for p in parts))
                                                              for c in range(3)))
    nearer, source = _by_group(tuple(p.nearer for p in parts)), _by_group(tuple(p.source for p in parts))
    _, locate_bit = word_locator(cat(lambda p: _flat(p.words, n_words)), runs=n_cam)
    count = cat(lambda p: jax.lax.population_count(p.words).astype(jnp.int32).reshape(p.words.shape[0], -1).sum(1))
    chunks = (count + CHUNK - 1) // CHUNK
    chunk_end = jnp.cumsum(chunks)
    first_slot = jnp.cumsum(count) - count

    def lane(j, cam):   # the j-th chunk of all (camera ``cam``'s): its slots' removed flags and keep indices
        c = j - (chunk_end[cam] - chunks[cam])
        slot = c * CHUNK + jnp.arange(CHUNK, dtype=jnp.int32)
        bit = locate_bit(first_slot[cam] + jnp.minimum(slot, jnp.maximum(count[cam] - 1, 0)))
        bit, rw = bit - cam * (n_words * WORD_BITS), row_words[cam]
        if down:       # words down the columns (outliers._compact)
            row, col = (bit // WORD_BITS // rw) * WORD_BITS + bit % WORD_BITS, bit // WORD_BITS % rw
        else:
            row, col = bit // (rw * WORD_BITS), bit % (rw * WORD_BITS)
        h, w = size[cam, 0], size[cam, 1]
        row, col = jnp.clip(row, 0, h - 1), jnp.clip(col, 0, w - 1)     # no candidate: a slot past the words
        ex = ExactTest(*images, columns, K[cam], t[cam], eps[cam], k_max[cam], cell_u[cam], cell_v[cam], h_max[cam],
                       count[cam], None, hh=hh, hw=hw, test=test, nearer=nearer, source=source, shape=(h, w),
                       grouped=Grouped(group[cam], member[cam], pixels, cam * n_columns))
        removed = candidates_removed(ex, row, col, row * w + col)
        at = jnp.where((slot < count[cam]) & (j < chunk_end[-1]), row * w + col, -1)   # -1: no candidate
        return removed, at, group[cam], member[cam]

    def step(i, keeps):     # each group's own keep buffer: no copy of the masks into one and out again
        j = i * n_cam + jnp.arange(n_cam, dtype=jnp.int32)
        cam = jnp.minimum(jnp.sum(chunk_end[None, :] <= j[:, None], axis=1), n_cam - 1)
        removed, at, g, m = jax.vmap(lane)(j, cam)
        out = []
        for k, keep in enumerate(keeps):    # another group's slots (and none) past the buffer: dropped
            mine = (g[:, None] == k) & (at >= 0)
            flat = jnp.where(mine, m[:, None] * pixels[k] + at, keep.shape[0])
            out.append(keep.at[flat.reshape(-1)].set(~removed.reshape(-1), mode="drop"))
        return tuple(out)

    keeps = jax.lax.fori_loop(0, (chunk_end[-1] + n_cam - 1) // n_cam, step, tuple(p.valid.reshape(-1) for p in parts))
    return tuple(keep.reshape(n, h, w) for keep, n, (h, w) in zip(keeps, counts, sizes))


def shared_windows(sizes: tuple, *, beams: int, config) -> dict | None:
    """:func:`exact_test_groups`' statics (``hh``, ``hw``, ``test``, ``down``) for size groups of static
    ``sizes`` under ``config`` (``outlier_max_half_*_px``, ``outlier_test``), or None when there is one group,
    Step 2 is off, or the groups' windows or word layouts differ (then each group runs its own loop)."""
    if len(sizes) < 2 or not config.outlier_removal:
        return None
    statics = set()
    for h, w in sizes:
        hw, hh = window_half_sizes(h, w, beams=int(beams), max_half_width_px=config.outlier_max_half_width_px,
                                   max_half_height_px=config.outlier_max_half_height_px)
        statics.add((hh, hw, _row_block(h, hh) is not None))
    if len(statics) > 1:
        return None
    (hh, hw, down), = statics
    return dict(hh=hh, hw=hw, test=config.outlier_test, down=down)
