"""The compiled closest-approach geometry of :func:`rfsas_hw.backend.encounter.assess_encounters`.

Vehicle and threat move at constant velocity. The closest approach is at
``t* = −r·w/|w|²`` (relative position ``r``, relative velocity ``w``) clipped to
``[0, horizon]``; there the threat's position covariance is ``J·P·Jᵀ`` with
``J = [I, t*·I]``. The threat's box lies along its velocity (north when it moves
slower than the moving speed); the along-track gap from the vehicle's front to
the near side of that box is the distance to contact (inf when the box is
behind the vehicle's front). Metres, seconds, m/s.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.jit import kernel

Array = npt.NDArray[np.float64]


@kernel
def closest_approach(
    x: Array,
    P: Array,
    pv: Array,
    vv: Array,
    u_hat: Array,
    horizon_s: float,
    vehicle_length_m: float,
    threat_length_m: float,
    threat_width_m: float,
    moving_mps: float,
) -> tuple[Any, ...]:
    """Per threat (states ``x`` (B, 4), covariances ``P`` (B, 4, 4)) against the vehicle
    at ``pv`` moving at ``vv`` along the unit vector ``u_hat``: ``t*`` (B,), the
    position covariance at ``t*`` (B, 2, 2, symmetrised), the threat's position at
    ``t*`` (B, 2), whether it moves (B,) and the distance to contact (B,)."""
    B = x.shape[0]
    t_star = np.empty(B)
    cov = np.empty((B, 2, 2))
    where = np.empty((B, 2))
    moving = np.empty(B, np.bool_)
    contact = np.empty(B)
    for b in range(B):
        rx, ry = x[b, 0] - pv[0], x[b, 1] - pv[1]
        wx, wy = x[b, 2] - vv[0], x[b, 3] - vv[1]
        ww = wx * wx + wy * wy
        t = 0.0 if ww == 0 else min(max(-(rx * wx + ry * wy) / ww, 0.0), horizon_s)
        t_star[b] = t
        for i in range(2):
            for j in range(2):
                cov[b, i, j] = (
                    P[b, i, j] + t * (P[b, i, j + 2] + P[b, i + 2, j]) + t * t * P[b, i + 2, j + 2]
                )
        off = (cov[b, 0, 1] + cov[b, 1, 0]) / 2
        cov[b, 0, 1] = cov[b, 1, 0] = off
        tx, ty = x[b, 0] + t * x[b, 2], x[b, 1] + t * x[b, 3]
        where[b, 0], where[b, 1] = tx, ty
        speed = math.hypot(x[b, 2], x[b, 3])
        moving[b] = speed > moving_mps
        ux, uy = (x[b, 2] / speed, x[b, 3] / speed) if moving[b] else (0.0, 1.0)
        reach = (
            vehicle_length_m / 2
            + threat_length_m / 2 * abs(ux * u_hat[0] + uy * u_hat[1])
            + threat_width_m / 2 * abs(-uy * u_hat[0] + ux * u_hat[1])
        )
        along = (tx - pv[0]) * u_hat[0] + (ty - pv[1]) * u_hat[1]
        contact[b] = max(along - reach, 0.0) if along + reach >= 0 else math.inf
    return t_star, cov, where, moving, contact
