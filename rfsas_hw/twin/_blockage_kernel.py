"""The compiled loops of :func:`rfsas_hw.twin.rfworld.segment_crossings` and
:func:`~rfsas_hw.twin.rfworld.blockage_db`.

A segment crosses an axis-aligned rectangle when some part of it lies strictly
inside: Liang–Barsky slab clipping, ``t`` running from 0 at ``p0`` to 1 at
``p1``; along an axis where the segment does not move it is inside the slab for
every ``t`` (strictly between its sides) or for none. Each segment is clipped
only against the rectangles whose boxes its own box overlaps (strictly, so a
segment with a NaN end crosses nothing). Positions are metres; ``rects`` rows
are x_min, x_max, y_min, y_max (and the loss in dB for :func:`blockage`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.jit import kernel

Array = npt.NDArray[np.float64]

_MIN_SPAN = 1e-9
"""Shortest stretch of ``t`` inside a rectangle that counts as crossing it."""


@kernel
def _crosses(x0: float, y0: float, x1: float, y1: float, rects: Array, j: int) -> bool:
    """Whether the segment ``(x0, y0) → (x1, y1)`` crosses rectangle ``rects[j]``."""
    if not (
        rects[j, 0] < max(x0, x1)
        and rects[j, 1] > min(x0, x1)
        and rects[j, 2] < max(y0, y1)
        and rects[j, 3] > min(y0, y1)
    ):
        return False
    enter = 0.0
    leave = 1.0
    for axis in range(2):
        o = x0 if axis == 0 else y0
        d = (x1 if axis == 0 else y1) - o
        lo = rects[j, 2 * axis]
        hi = rects[j, 2 * axis + 1]
        if d == 0.0:
            if not (lo < o < hi):
                return False
            continue
        t1 = (lo - o) / d
        t2 = (hi - o) / d
        enter = max(enter, min(t1, t2))
        leave = min(leave, max(t1, t2))
    return leave - enter > _MIN_SPAN


@kernel
def crossings(p0: Array, p1: Array, rects: Array) -> Any:
    """Which segments ``p0[i] → p1[i]`` cross which rectangles, bool ``(n, m)``."""
    n, m = p0.shape[0], rects.shape[0]
    out = np.zeros((n, m), np.bool_)
    for i in range(n):
        x0, y0, x1, y1 = p0[i, 0], p0[i, 1], p1[i, 0], p1[i, 1]
        if math.isnan(x0) or math.isnan(y0) or math.isnan(x1) or math.isnan(y1):
            continue
        for j in range(m):
            out[i, j] = _crosses(x0, y0, x1, y1, rects, j)
    return out


@kernel
def blockage(
    p0: Array,
    p1: Array,
    rects: Array,
    starts: npt.NDArray[np.intp],
    cand_ptr: npt.NDArray[np.intp],
    cand_idx: npt.NDArray[np.intp],
) -> Any:
    """The summed loss (dB, column 4 of ``rects``) of the rectangles each segment
    ``p0[i] → p1[i]`` crosses, ``(n,)``, and whether it crosses any, ``(n,)``.

    The segments come in groups: group ``g`` is rows ``starts[g]:starts[g + 1]`` and may
    cross only rectangles ``cand_idx[cand_ptr[g]:cand_ptr[g + 1]]`` (increasing indices,
    so the losses add up in rectangle order)."""
    n = p0.shape[0]
    loss = np.zeros(n)
    hit = np.zeros(n, np.bool_)
    for g in range(starts.shape[0] - 1):
        for i in range(starts[g], starts[g + 1]):
            x0, y0, x1, y1 = p0[i, 0], p0[i, 1], p1[i, 0], p1[i, 1]
            if math.isnan(x0) or math.isnan(y0) or math.isnan(x1) or math.isnan(y1):
                continue
            for c in range(cand_ptr[g], cand_ptr[g + 1]):
                j = cand_idx[c]
                if _crosses(x0, y0, x1, y1, rects, j):
                    loss[i] += rects[j, 4]
                    hit[i] = True
    return loss, hit
