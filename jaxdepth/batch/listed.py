"""The CLI's KITTI jobs without ``pixel_normals``' dense fallback in their program (issue 38).

:func:`jaxdepth.complete` keeps one program with both Step 1 paths (the listed fast path and the
dense fallback a frame takes when it has depth at over H W / 16 pixels or its points leave the
range-image window). The fallback is never run on KITTI frames but costs ~2.3 s of a cold job's
compile. A job (:func:`jaxdepth.batch.runner.run_jobs`, SGM on depth images) therefore runs a
*listed* program: the fast path alone, which also returns each frame's ``fits`` (the value the
fallback's choice reads); both programs map one frame function, with and without ``listed_only``
(:func:`jaxdepth.batch.frame_program.frame_function`). Where the runner collects a batch, a batch
with a frame that does not fit is recomputed by the job's full program (main's, built on first need),
and that group's later batches run the full program directly (a dataset denser than the capacity
pays the recompute once, not per batch): every output has the bytes of the full program, which a
fitting frame's listed program gives too (docs/speed.md, "The cold first frame without the dense fallback").
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Callable

import numpy as np

log = logging.getLogger("jaxdepth")


@dataclasses.dataclass(frozen=True)
class ListedBatch:
    """A batch function of the listed program ``fn``; ``full()`` builds (or returns) the full one;
    ``overflowed()`` is called when a batch needs it (the runner then gives the group the full program).
    A call dispatches ``fn`` and returns a :class:`ListedOut` (read it with :func:`settle`)."""

    fn: Callable
    full: Callable[[], Callable]
    overflowed: Callable[[], None] = lambda: None

    def __call__(self, *args):
        return ListedOut(self.fn(*args), args, self.full, self.overflowed)


@dataclasses.dataclass(frozen=True)
class ListedOut:
    out: tuple
    args: tuple
    full: Callable[[], Callable]
    overflowed: Callable[[], None]


def _arrays(out) -> tuple:
    return tuple(np.asarray(o) for o in out) if isinstance(out, tuple) else (np.asarray(out),)


def settle(out) -> tuple:
    """A dispatched batch's outputs as a tuple of NumPy arrays (waits for them). A :class:`ListedOut`
    with a frame that does not fit (padding frames, all empty, always fit) is recomputed by the full
    program on the same arguments, and its outputs are returned."""
    if not isinstance(out, ListedOut):
        return _arrays(out)
    *result, fits = _arrays(out.out)
    if bool(np.all(fits)):
        return tuple(result)
    log.info("a batch has %d frame(s) beyond the listed normals' capacity or window: recomputed by the "
             "program with the dense fallback (and so are this image size's later batches)", int(np.sum(~fits)))
    out.overflowed()
    return _arrays(out.full()(*out.args))
