"""The compiled row loop of :func:`rfsas_hw.backend.triangulation.triangulate_batch`.

One fix per row: the pseudo-linear start, the damped Gauss-Newton iterations and
the covariance and diagnostics at the solution (method.md §5; the module
docstring of :mod:`~rfsas_hw.backend.triangulation` has the formulas). Angles
are math radians, positions metres, weights ``1/σ²`` in rad⁻². A column whose
``valid`` is False takes no part.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.backend.triangulation import FixStatus
from rfsas_hw.jit import kernel

Array = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]

_OK = int(FixStatus.OK)
_TOO_FEW = int(FixStatus.TOO_FEW_BEARINGS)
_ILL = int(FixStatus.ILL_CONDITIONED)
_BEHIND = int(FixStatus.BEHIND_SENSOR)
_INCONSISTENT = int(FixStatus.INCONSISTENT)
_NOT_CONVERGED = int(FixStatus.NOT_CONVERGED)
_MIN_D2_M2 = 1e-12
"""Smallest squared range used in the information and the gradient, m²."""


@kernel
def prepare(S: Array, phi: Array, sigma_deg: Array) -> tuple[Any, ...]:
    """Which bearings take part and their weights: a bearing is usable when its angle,
    sigma and station are finite. Returns the mask (B, N), the weights ``1/σ²`` in
    rad⁻² (0 where not usable), the usable count per row (B,) and the first usable
    bearing whose sigma is not > 0 as ``(row, column)``, ``(−1, −1)`` if none."""
    B, N = phi.shape
    valid = np.zeros((B, N), np.bool_)
    w = np.zeros((B, N))
    n_valid = np.zeros(B, np.int32)
    for b in range(B):
        for i in range(N):
            ok = math.isfinite(phi[b, i]) and math.isfinite(sigma_deg[b, i])
            if not (ok and math.isfinite(S[b, i, 0]) and math.isfinite(S[b, i, 1])):
                continue
            if not sigma_deg[b, i] > 0:
                return valid, w, n_valid, b, i
            valid[b, i] = True
            w[b, i] = 1.0 / math.radians(sigma_deg[b, i]) ** 2
            n_valid[b] += 1
    return valid, w, n_valid, -1, -1


@kernel
def _lines_wls(
    S: Array, phi: Array, w: Array, valid: Mask, px0: float, py0: float, by_range: bool
) -> tuple[float, float]:
    """Weighted least-squares intersection of one row's lines of bearing (NaN if singular).

    Each line ``sin φ·x − cos φ·y = sin φ·x_i − cos φ·y_i`` has weight ``w``,
    or ``w/D²`` with ``D`` the range from ``(px0, py0)`` when ``by_range``.
    """
    a11 = a12 = a22 = b1 = b2 = 0.0
    for i in range(S.shape[0]):
        if not valid[i]:
            continue
        wi = w[i]
        if by_range:
            dx, dy = px0 - S[i, 0], py0 - S[i, 1]
            wi = wi / max(dx * dx + dy * dy, 1e-6)
        s, c = math.sin(phi[i]), math.cos(phi[i])
        rhs = s * S[i, 0] - c * S[i, 1]
        a11 += wi * s * s
        a12 -= wi * s * c
        a22 += wi * c * c
        b1 += wi * s * rhs
        b2 -= wi * c * rhs
    det = a11 * a22 - a12 * a12
    # relative test: exactly parallel lines leave only round-off in det
    if not det > 1e-12 * (a11 + a22) ** 2:
        return math.nan, math.nan
    return (a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det


@kernel
def _residual(phi: float, phi0: float) -> float:
    """Measured minus predicted math angle, wrapped into (−π, π] (as ``wrap_rad_pi``)."""
    return math.pi - (math.pi - (phi - phi0)) % (2 * math.pi)


@kernel
def _cost(px: float, py: float, S: Array, phi: Array, w: Array, valid: Mask) -> float:
    """Weighted squared residual sum ``Σ w·r²`` at ``(px, py)``."""
    total = 0.0
    for i in range(S.shape[0]):
        if valid[i]:
            r = _residual(phi[i], math.atan2(py - S[i, 1], px - S[i, 0]))
            total += w[i] * r * r
    return total


@kernel
def _information(
    px: float, py: float, S: Array, w: Array, valid: Mask, min_d2: float
) -> tuple[float, float, float]:
    """μ, λ, ν of method.md §5 at ``(px, py)``: Σ w·cos²φ₀/D², Σ w·sin²φ₀/D², Σ w·sinφ₀cosφ₀/D²
    with ``D²`` at least ``min_d2`` (m²)."""
    mu = lam = nu = 0.0
    for i in range(S.shape[0]):
        if valid[i]:
            dx, dy = px - S[i, 0], py - S[i, 1]
            a = math.atan2(dy, dx)
            c, s = math.cos(a), math.sin(a)
            wd = w[i] / max(dx * dx + dy * dy, min_d2)
            mu += wd * c * c
            lam += wd * s * s
            nu += wd * s * c
    return mu, lam, nu


@kernel
def _gauss_newton_step(
    px: float, py: float, S: Array, phi: Array, w: Array, valid: Mask
) -> tuple[float, float, float]:
    """The step ``(GᵀWG)⁻¹GᵀW·r`` (NaN when GᵀWG is singular) and the cost at ``(px, py)``.

    G has rows ``[−sin φ₀/D, cos φ₀/D]``; GᵀWG is ``[[λ, −ν], [−ν, μ]]`` and its
    inverse ``[[μ, ν], [ν, λ]]/(μλ − ν²)``.
    """
    mu = lam = nu = g1 = g2 = cost = 0.0
    for i in range(S.shape[0]):
        if not valid[i]:
            continue
        dx, dy = px - S[i, 0], py - S[i, 1]
        a = math.atan2(dy, dx)
        c, s = math.cos(a), math.sin(a)
        d2 = max(dx * dx + dy * dy, _MIN_D2_M2)
        wd = w[i] / d2
        root = math.sqrt(d2)
        r = _residual(phi[i], a)
        mu += wd * c * c
        lam += wd * s * s
        nu += wd * s * c
        g1 += w[i] * (-s) * r / root
        g2 += w[i] * c * r / root
        cost += w[i] * r * r
    det = mu * lam - nu * nu
    if not det > 0:
        return math.nan, math.nan, cost
    return (mu * g1 + nu * g2) / det, (nu * g1 + lam * g2) / det, cost


@kernel
def _max_abs_residual(px: float, py: float, S: Array, phi: Array, valid: Mask) -> float:
    """Largest ``|r|`` over the row's bearings, radians (0 without bearings)."""
    worst = 0.0
    for i in range(S.shape[0]):
        if valid[i]:
            r = abs(_residual(phi[i], math.atan2(py - S[i, 1], px - S[i, 0])))
            worst = max(worst, r)
    return worst


@kernel
def solve(
    S: Array,
    phi: Array,
    w: Array,
    valid: Mask,
    chi2_limit: Array,
    max_iterations: int,
    tolerance_m: float,
    max_halvings: int,
    max_condition: float,
    max_range_fraction: float,
    behind_deg: float,
) -> tuple[Any, ...]:
    """Every row's fix: position, covariance, status, GDOP, condition, χ², iterations,
    range fraction and largest residual (degrees); shapes (B, 2), (B, 2, 2), (B,)…

    ``S`` (B, N, 2) station positions, ``phi`` (B, N) measured math angles, ``w``
    (B, N) weights, ``valid`` (B, N) usable bearings, ``chi2_limit`` (B,) the χ²
    threshold of each row (inf: no test); the rest are
    :class:`~rfsas_hw.backend.triangulation.TriangulationOptions`.
    """
    B = S.shape[0]
    position = np.full((B, 2), np.nan)
    covariance = np.full((B, 2, 2), np.inf)
    status = np.empty(B, np.uint8)
    gdop = np.full(B, np.inf)
    condition = np.full(B, np.inf)
    chi2 = np.full(B, np.nan)
    iterations = np.zeros(B, np.int32)
    range_fraction = np.full(B, np.inf)
    max_residual_deg = np.full(B, np.nan)
    behind_rad = math.radians(behind_deg)
    for b in range(B):
        Sb, phib, wb, vb = S[b], phi[b], w[b], valid[b]
        n = 0
        for i in range(vb.shape[0]):
            n += vb[i]
        if n < 2:
            status[b] = _TOO_FEW
            continue
        px, py = _lines_wls(Sb, phib, wb, vb, 0.0, 0.0, False)
        qx, qy = _lines_wls(Sb, phib, wb, vb, px, py, True)
        if math.isfinite(qx) and math.isfinite(qy):
            px, py = qx, qy
        if not (math.isfinite(px) and math.isfinite(py)):
            status[b] = _ILL
            continue
        start_x, start_y = px, py
        start_resid = _max_abs_residual(px, py, Sb, phib, vb)
        start_behind = start_resid > behind_rad
        # two lines that meet behind a sensor have no solution in front of both
        converged = start_behind and n == 2
        done = 0
        while not converged and done < max_iterations:
            done += 1
            sx, sy, cost = _gauss_newton_step(px, py, Sb, phib, wb, vb)
            if not (math.isfinite(sx) and math.isfinite(sy)):
                converged = True
                break
            # the full step, else halvings 2^-1 … 2^-max_halvings: the first that
            # does not raise the cost (a step that cannot lower it: at the minimum)
            limit = cost * (1 + 1e-12) + 1e-300
            alpha = 1.0
            accepted = False
            tx, ty = px, py
            for _ in range(max_halvings + 1):
                tx, ty = px + alpha * sx, py + alpha * sy
                if _cost(tx, ty, Sb, phib, wb, vb) <= limit:
                    accepted = True
                    break
                alpha *= 0.5
            if not accepted:
                converged = True
                break
            moved = math.hypot(tx - px, ty - py)
            px, py = tx, ty
            converged = moved < tolerance_m
        iterations[b] = done

        mu, lam, nu = _information(px, py, Sb, wb, vb, _MIN_D2_M2)
        det = mu * lam - nu * nu
        if det > 0:
            covariance[b, 0, 0] = mu / det
            covariance[b, 1, 1] = lam / det
            covariance[b, 0, 1] = covariance[b, 1, 0] = nu / det
        tr = mu + lam
        disc = math.sqrt(max(tr * tr / 4 - det, 0.0))
        e_max, e_min = tr / 2 + disc, tr / 2 - disc
        cond = e_max / e_min if e_min > 0 else np.inf
        major = 1.0 / math.sqrt(e_min) if e_min > 0 else np.inf
        d2_min = np.inf
        spread = 0.0
        ssq = 0.0
        for i in range(vb.shape[0]):
            if vb[i]:
                dx, dy = px - Sb[i, 0], py - Sb[i, 1]
                d2 = max(dx * dx + dy * dy, _MIN_D2_M2)
                d2_min = min(d2_min, d2)
                spread += d2 / wb[i]
                r = _residual(phib[i], math.atan2(dy, dx))
                ssq += wb[i] * r * r
        rf = major / math.sqrt(d2_min)
        resid_deg = math.degrees(_max_abs_residual(px, py, Sb, phib, vb))
        st = _OK
        if not converged:
            st = _NOT_CONVERGED
        if ssq > chi2_limit[b]:
            st = _INCONSISTENT
        if resid_deg > behind_deg:
            st = _BEHIND
        ill = not math.isfinite(cond) or cond > max_condition or not rf <= max_range_fraction
        if ill:
            st = _ILL
        if start_behind and (ill or resid_deg > behind_deg):
            # report the residual that proves it: at the lines' intersection
            st = _BEHIND
            resid_deg = math.degrees(start_resid)
            px, py = start_x, start_y
        position[b, 0], position[b, 1] = px, py
        status[b] = st
        gdop[b] = math.sqrt(covariance[b, 0, 0] + covariance[b, 1, 1]) / math.sqrt(spread / n)
        condition[b] = cond
        chi2[b] = ssq
        range_fraction[b] = rf
        max_residual_deg[b] = resid_deg
    return (
        position,
        covariance,
        status,
        gdop,
        condition,
        chi2,
        iterations,
        range_fraction,
        max_residual_deg,
    )


@kernel
def information_covariance(S: Array, T: Array, w: Array, valid: Mask) -> Array:
    """``(GᵀWG)⁻¹`` of every row at the points ``T`` (B, 2), shape (B, 2, 2); inf if singular."""
    B = S.shape[0]
    out = np.full((B, 2, 2), np.inf)
    for b in range(B):
        # no floor: at a station the bearing carries no information (inf, then no bound)
        mu, lam, nu = _information(T[b, 0], T[b, 1], S[b], w[b], valid[b], 0.0)
        det = mu * lam - nu * nu
        if det > 0:
            out[b, 0, 0] = mu / det
            out[b, 1, 1] = lam / det
            out[b, 0, 1] = out[b, 1, 0] = nu / det
    return out
