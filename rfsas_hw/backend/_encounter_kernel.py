"""The compiled per-pair geometry of :func:`rfsas_hw.backend.encounter.assess_pairs`.

Each threat is judged against its own vehicle (many vehicles in one call; one
vehicle is the batch of one). Vehicle and threat move at constant velocity. The
closest approach is at ``t* = −r·w/|w|²`` (relative position ``r``, relative
velocity ``w``) clipped to ``[0, horizon]``; there the threat's position
covariance is ``J·P·Jᵀ`` with ``J = [I, t*·I]``. The threat's box lies along its
velocity (north when it moves slower than the moving speed); the along-track gap
from the vehicle's front to the near side of that box is the distance to contact
(inf when the box is behind the vehicle's front).

The path test of a brake: with ``n`` the unit normal left of the vehicle's
heading, the threat's lateral offset is ``d = (x − p_v)·n``, its speed towards
the path's centre line ``w = −(v·n)·sign(d)`` with one-sigma ``σ_w = √(nᵀ P_v n)``
(``P_v`` its velocity covariance), and the gap to the path ``|d| − h`` with ``h``
the sum of the two half-widths (the threat's larger side), whose one-sigma is
``σ_d = √(nᵀ P_x n)`` (``P_x`` the position covariance). The threat is in the
path when ``gap + k_d·σ_d ≤ 0`` (``k_d = 0``: its centre inside), and shows
evidence of entering it when ``w − k·σ_w > 0`` and ``gap ≤ (w − k·σ_w)·t*``.
Metres, seconds, m/s, radians.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.jit import kernel

Array = npt.NDArray[np.float64]


@kernel
def encounter_geometry(
    x: Array,
    P: Array,
    vehicle_of: npt.NDArray[np.int64],
    pv: Array,
    vv: Array,
    u_hat: Array,
    vehicle_size: Array,
    horizon_s: float,
    threat_length_m: float,
    threat_width_m: float,
    moving_mps: float,
    path_sigmas: float,
    position_sigmas: float,
) -> tuple[Any, ...]:
    """Per threat (states ``x`` (B, 4), covariances ``P`` (B, 4, 4)) against its vehicle
    ``v = vehicle_of[b]`` (B,): at ``pv[v]`` moving at ``vv[v]`` along the unit vector
    ``u_hat[v]``, of length and width ``vehicle_size[v]`` (each of shape (V, 2)).

    Returns:
        The first row whose state or covariance is not finite (−1: none; the other
        outputs are then meaningless from that row on), then per threat: ``t*`` (B,),
        the position covariance at ``t*`` (B, 2, 2, symmetrised), the vehicle's and
        the threat's positions at ``t*`` (B, 2 each), whether the threat moves (B,),
        the math angle of its velocity (B, π/2 when not moving), the distance to
        contact (B,), the gap to the vehicle's path and its one-sigma (B each), the
        speed towards it and that speed's one-sigma (B each), and whether it is in
        the path by ``position_sigmas`` or shows evidence of entering it with
        ``path_sigmas`` (B,).
    """
    B = x.shape[0]
    bad = -1
    t_star = np.empty(B)
    cov = np.empty((B, 2, 2))
    vehicle_at = np.empty((B, 2))
    where = np.empty((B, 2))
    moving = np.empty(B, np.bool_)
    heading = np.empty(B)
    contact = np.empty(B)
    gap = np.empty(B)
    gap_sigma = np.empty(B)
    towards = np.empty(B)
    towards_sigma = np.empty(B)
    path = np.empty(B, np.bool_)
    threat_half_m = max(threat_length_m, threat_width_m) / 2
    for b in range(B):
        v = vehicle_of[b]
        ux_v, uy_v = u_hat[v, 0], u_hat[v, 1]
        px, py = pv[v, 0], pv[v, 1]
        nx, ny = -uy_v, ux_v
        half_widths = vehicle_size[v, 1] / 2 + threat_half_m
        if bad < 0:
            for i in range(4):
                finite = math.isfinite(x[b, i])
                for j in range(4):
                    finite = finite and math.isfinite(P[b, i, j])
                if not finite:
                    bad = b
        rx, ry = x[b, 0] - px, x[b, 1] - py
        wx, wy = x[b, 2] - vv[v, 0], x[b, 3] - vv[v, 1]
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
        vehicle_at[b, 0], vehicle_at[b, 1] = px + t * vv[v, 0], py + t * vv[v, 1]
        tx, ty = x[b, 0] + t * x[b, 2], x[b, 1] + t * x[b, 3]
        where[b, 0], where[b, 1] = tx, ty
        speed = math.hypot(x[b, 2], x[b, 3])
        moving[b] = speed > moving_mps
        heading[b] = math.atan2(x[b, 3], x[b, 2]) if moving[b] else math.pi / 2
        ux, uy = (x[b, 2] / speed, x[b, 3] / speed) if moving[b] else (0.0, 1.0)
        reach = (
            vehicle_size[v, 0] / 2
            + threat_length_m / 2 * abs(ux * ux_v + uy * uy_v)
            + threat_width_m / 2 * abs(-uy * ux_v + ux * uy_v)
        )
        along = (tx - px) * ux_v + (ty - py) * uy_v
        contact[b] = max(along - reach, 0.0) if along + reach >= 0 else math.inf
        d = rx * nx + ry * ny
        side = 1.0 if d >= 0 else -1.0
        w = -(x[b, 2] * nx + x[b, 3] * ny) * side
        var_w = nx * (P[b, 2, 2] * nx + P[b, 2, 3] * ny) + ny * (P[b, 3, 2] * nx + P[b, 3, 3] * ny)
        sigma_w = math.sqrt(max(var_w, 0.0))
        var_d = nx * (P[b, 0, 0] * nx + P[b, 0, 1] * ny) + ny * (P[b, 1, 0] * nx + P[b, 1, 1] * ny)
        sigma_d = math.sqrt(max(var_d, 0.0))
        g = abs(d) - half_widths
        w_low = w - path_sigmas * sigma_w
        gap[b], gap_sigma[b], towards[b], towards_sigma[b] = g, sigma_d, w, sigma_w
        path[b] = g + position_sigmas * sigma_d <= 0 or (w_low > 0 and g <= w_low * max(t, 0.0))
    return (
        bad,
        t_star,
        cov,
        vehicle_at,
        where,
        moving,
        heading,
        contact,
        gap,
        gap_sigma,
        towards,
        towards_sigma,
        path,
    )
