"""The compiled constant-velocity Kalman filter of :mod:`rfsas_hw.backend.tracking`.

State ``[x, y, vx, vy]`` (m, m/s), covariance 4×4; ``F`` moves the position by
``dt·v`` (dt in s) and ``Q`` is the discretised white-noise acceleration with
variance ``q`` (m²/s⁴): ``q·dt⁴/4`` on the positions, ``q·dt³/2`` between a
position and its velocity, ``q·dt²`` on the velocities. A fix measures the
position with covariance ``R`` (m²).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.jit import kernel

Array = npt.NDArray[np.float64]


@kernel
def _predict_row(x: Array, P: Array, dt: float, q: float, xo: Array, Po: Array) -> None:
    """``xo = F·x`` and ``Po = F·P·Fᵀ + Q`` for one track."""
    xo[0] = x[0] + dt * x[2]
    xo[1] = x[1] + dt * x[3]
    xo[2] = x[2]
    xo[3] = x[3]
    FP = np.empty((4, 4))
    for j in range(4):
        FP[0, j] = P[0, j] + dt * P[2, j]
        FP[1, j] = P[1, j] + dt * P[3, j]
        FP[2, j] = P[2, j]
        FP[3, j] = P[3, j]
    for i in range(4):
        Po[i, 0] = FP[i, 0] + dt * FP[i, 2]
        Po[i, 1] = FP[i, 1] + dt * FP[i, 3]
        Po[i, 2] = FP[i, 2]
        Po[i, 3] = FP[i, 3]
    pos, cross, vel = q * dt**4 / 4, q * dt**3 / 2, q * dt**2
    Po[0, 0] += pos
    Po[1, 1] += pos
    Po[0, 2] += cross
    Po[2, 0] += cross
    Po[1, 3] += cross
    Po[3, 1] += cross
    Po[2, 2] += vel
    Po[3, 3] += vel


@kernel
def predict(states: Array, covs: Array, dt: Array, q: float) -> tuple[Any, ...]:
    """Every track moved on by its ``dt``: states (B, 4) and covariances (B, 4, 4)."""
    B = states.shape[0]
    xo = np.empty((B, 4))
    Po = np.empty((B, 4, 4))
    for b in range(B):
        _predict_row(states[b], covs[b], dt[b], q, xo[b], Po[b])
    return xo, Po


@kernel
def update(states: Array, covs: Array, dt: Array, q: float, z: Array, R: Array) -> tuple[Any, ...]:
    """Predict every track by its ``dt``, then apply its fix ``z`` (B, 2) with covariance
    ``R`` (B, 2, 2): the updated states and covariances (Joseph form, which keeps the
    covariance symmetric positive definite) and each fix's squared Mahalanobis
    distance from the prediction (inf when the innovation covariance is singular)."""
    B = states.shape[0]
    xo = np.empty((B, 4))
    Po = np.empty((B, 4, 4))
    d2 = np.empty(B)
    x = np.empty(4)
    P = np.empty((4, 4))
    K = np.empty((4, 2))
    A = np.empty((4, 4))
    AP = np.empty((4, 4))
    for b in range(B):
        _predict_row(states[b], covs[b], dt[b], q, x, P)
        s11, s12 = P[0, 0] + R[b, 0, 0], P[0, 1] + R[b, 0, 1]
        s21, s22 = P[1, 0] + R[b, 1, 0], P[1, 1] + R[b, 1, 1]
        det = s11 * s22 - s12 * s21
        e1, e2 = z[b, 0] - x[0], z[b, 1] - x[1]
        if not det > 0:
            d2[b] = math.inf
            xo[b] = x
            Po[b] = P
            continue
        i11, i12, i21, i22 = s22 / det, -s12 / det, -s21 / det, s11 / det
        d2[b] = e1 * (i11 * e1 + i12 * e2) + e2 * (i21 * e1 + i22 * e2)
        for i in range(4):
            K[i, 0] = P[i, 0] * i11 + P[i, 1] * i21
            K[i, 1] = P[i, 0] * i12 + P[i, 1] * i22
        # A = I − K·H with H = [I 0]
        for i in range(4):
            for j in range(4):
                A[i, j] = (1.0 if i == j else 0.0) - (K[i, j] if j < 2 else 0.0)
        for i in range(4):
            for j in range(4):
                acc = 0.0
                for m in range(4):
                    acc += A[i, m] * P[m, j]
                AP[i, j] = acc
        for i in range(4):
            xo[b, i] = x[i] + K[i, 0] * e1 + K[i, 1] * e2
            for j in range(4):
                acc = 0.0
                for m in range(4):
                    acc += AP[i, m] * A[j, m]
                kr = 0.0
                for m in range(2):
                    kr += (K[i, 0] * R[b, 0, m] + K[i, 1] * R[b, 1, m]) * K[j, m]
                Po[b, i, j] = acc + kr
    return xo, Po, d2
