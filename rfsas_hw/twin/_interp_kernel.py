"""The compiled loop of the streaming twin's track lookups
(:meth:`rfsas_hw.twin.stream.StreamTwin._positions`).

Row ``i`` is interpolated on track ``track[i]``, whose knots are
``kt[ptr[u]:ptr[u + 1]]`` (times, increasing or equal) with the values ``kx``, ``ky``
at them: piecewise linear between knots, the first knot's value before the first
and the last knot's value from the last on — what ``np.interp`` gives on each track,
with its arithmetic (``slope·(t − t_j) + v_j``, the other end when that is not a
number). Times are seconds, positions metres.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.jit import kernel

Array = npt.NDArray[np.float64]


@kernel
def _interp_one(x: float, kt: Array, kv: Array, lo: int, hi: int) -> float:
    """``np.interp(x, kt[lo:hi], kv[lo:hi])`` for one ``x``."""
    if math.isnan(x):
        return x
    last = hi - 1
    if x < kt[lo]:
        return float(kv[lo])
    if x >= kt[last]:  # at or after the last knot (one knot: its value everywhere)
        return float(kv[last])
    # the last knot j with kt[j] <= x (x is below the last knot)
    a, b = lo, last
    while b - a > 1:
        mid = (a + b) // 2
        if kt[mid] <= x:
            a = mid
        else:
            b = mid
    j = a
    if kt[j] == x:
        return float(kv[j])
    slope = float((kv[j + 1] - kv[j]) / (kt[j + 1] - kt[j]))
    out = float(slope * (x - kt[j]) + kv[j])
    if math.isnan(out):
        out = float(slope * (x - kt[j + 1]) + kv[j + 1])
        if math.isnan(out) and kv[j] == kv[j + 1]:
            out = float(kv[j])
    return out


@kernel
def positions(
    kt: Array,
    kx: Array,
    ky: Array,
    ptr: npt.NDArray[np.intp],
    track: npt.NDArray[np.intp],
    t: Array,
) -> Any:
    """East and north of each row ``i`` at time ``t[i]`` on track ``track[i]``, ``(n, 2)``."""
    n = t.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        u = track[i]
        lo, hi = ptr[u], ptr[u + 1]
        out[i, 0] = _interp_one(t[i], kt, kx, lo, hi)
        out[i, 1] = _interp_one(t[i], kt, ky, lo, hi)
    return out
