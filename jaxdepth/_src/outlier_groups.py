"""Step 2's exact test once for the cameras of every size group of a rig (image shapes as data).

Contract: the rig's Step 2 in per-group pieces in, the same keep masks out, bit for bit. Phases 1-2
(prefilter, compaction: dense passes of the image's own shape) stay per size group
(``outliers._keep_mask(..., defer=True)`` under each group's ``vmap``); phase 3, the exact-test loop
(:mod:`~jaxdepth._src.outlier_exact`), reads its images only at flat pixel indices, so it runs once, one
``vmap`` over every camera: each camera's (h, w) is data, its candidate and column words are padded to the
longest camera's, and the images stay in their groups' buffers (:class:`~jaxdepth._src.outlier_exact.Grouped`:
each read gathers from every group's buffer at the camera's index or 0 and keeps its own; no copy of the
images into one). The loop compiles once instead of once per group (the Argoverse 2 rig: the portrait
camera's copy), and the cameras run it in lockstep: to the largest chunk count among all of them (a camera's
extra chunks test no slot), not each group's own.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdepth._src.outlier_exact import ExactTest, Grouped, exact_test
from jaxdepth._src.outliers import _compact, _row_block, window_half_sizes


def _flat(x: jax.Array, length: int) -> jax.Array:
    """(n, ...) -> (n, length): each camera's array flat, zeros after it."""
    x = x.reshape(x.shape[0], -1)
    return jnp.pad(x, ((0, 0), (0, length - x.shape[1])))


def _by_group(images: tuple):
    """One group-flat array per group (:class:`~jaxdepth._src.outlier_exact.Grouped`), or None."""
    return None if images[0] is None else tuple(x.reshape(-1) for x in images)


def exact_test_groups(parts: tuple, sizes: tuple, *, hh: int, hw: int, test: str, down: bool) -> tuple:
    """Phase 3 of Step 2 for every camera of a rig at once.

    Args:
      parts: one :class:`~jaxdepth._src.outliers.KeepParts` per size group, each leaf with a leading axis of
        the group's cameras (``_keep_mask(..., defer=True)`` under the group's ``vmap``); ``points`` three
        channels apart (a rig's views); ``h_max`` given (``image_size``: the camera's own bounds).
      sizes: static (h, w) of each group's images.
      hh, hw, test, down: the static window half sizes, condition-1 form and word layout, the same for
        every group.

    Returns:
      One (n_g, h, w) bool keep mask per group, each camera's as its group's own ``_keep_mask`` gives it.
    """
    counts = [p.depth.shape[0] for p in parts]
    pixels = tuple(h * w for h, w in sizes)
    longest = lambda f: max(int(np.prod(f(p).shape[1:])) for p in parts)
    n_pix, n_words, n_columns = max(pixels), longest(lambda p: p.words), longest(lambda p: p.columns)
    cat = lambda f: jnp.concatenate([f(p) for p in parts])
    row_words = [p.words.shape[-1] for p in parts]
    per_camera = (cat(lambda p: _flat(p.valid, n_pix)), cat(lambda p: _flat(p.words, n_words)),
                  cat(lambda p: _flat(p.columns, n_columns)), cat(lambda p: p.K), cat(lambda p: p.t),
                  cat(lambda p: p.eps), cat(lambda p: p.k_max), cat(lambda p: p.cell_u), cat(lambda p: p.cell_v),
                  cat(lambda p: p.h_max), jnp.asarray(np.repeat(np.asarray(sizes, np.int32), counts, axis=0)),
                  jnp.asarray(np.repeat(np.asarray(row_words, np.int32), counts)),
                  jnp.asarray(np.repeat(np.arange(len(parts), dtype=np.int32), counts)),
                  jnp.asarray(np.concatenate([np.arange(n, dtype=np.int32) for n in counts])))
    depth = _by_group(tuple(p.depth for p in parts))
    points = tuple(_by_group(tuple(p.points[c] for p in parts)) for c in range(3))
    nearer, source = _by_group(tuple(p.nearer for p in parts)), _by_group(tuple(p.source for p in parts))

    def camera(valid, words, columns, K, t, eps, k_max, cell_u, cell_v, h_max, size, row_word, group, member):
        count, locate = _compact(words, down=down, row_words=row_word)
        ex = ExactTest(depth, points, columns, K, t, eps, k_max, cell_u, cell_v, h_max, count, locate, hh=hh, hw=hw,
                       test=test, nearer=nearer, source=source, shape=(size[0], size[1]),
                       grouped=Grouped(group, member, pixels))
        return exact_test(valid, ex)

    keep = jax.vmap(camera)(*per_camera)
    out, first = [], 0
    for n, (h, w) in zip(counts, sizes):
        out.append(keep[first:first + n, :h * w].reshape(n, h, w))
        first += n
    return tuple(out)


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
