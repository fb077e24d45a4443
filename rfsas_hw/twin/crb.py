"""Cramér–Rao bound of amplitude-monopulse DF from quantised RSSI (derived in docs/simulation.md).

Measurement model (what the twin simulates and the estimator assumes):
each chain reports ``q_i = round(μ_i + n_i)`` with ``μ_i = P + G_i(θ)`` (dBm;
``P`` the unknown received level, ``G_i`` the beam gain), ``n_i ~ N(0, σ_i²)``
independent between chains, and rounding to a ``step`` (1 dB).

Fisher information of one quantised reading about its mean ``μ``, with cells
``[c_k − step/2, c_k + step/2)``, ``a_k = (c_k − step/2 − μ)/σ``,
``b_k = (c_k + step/2 − μ)/σ``::

    I_q(μ, σ) = (1/σ²) · Σ_k (φ(a_k) − φ(b_k))² / (Φ(b_k) − Φ(a_k))

which tends to ``1/σ²`` when ``σ ≫ step`` and to 0 between cell edges when
``σ ≪ step``. With the two unknowns ``(θ, P)`` the information matrix is
``J = Σ_i I_i·[g_i, 1]ᵀ[g_i, 1]`` with ``g_i = ∂G_i/∂θ``, and the bound on θ is
the (θ, θ) element of ``J⁻¹``::

    CRB(θ) = (I_1 + I_2) / (I_1·I_2·(g_1 − g_2)²)

For Gaussian beams ``g_1 − g_2 = 48·θ_s/β²`` (per degree) everywhere in the
main lobes, so with ``I_i = 1/σ²`` the bound is ``2σ²/k²``: the textbook
monopulse result with the level ``P`` as a nuisance parameter.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.special import ndtr

Array = npt.NDArray[np.float64]
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def quantised_fisher_info(mu: npt.ArrayLike, sigma: npt.ArrayLike, step: float = 1.0) -> Array:
    """Fisher information about ``μ`` of one reading ``round(μ + N(0, σ²))`` to ``step``, 1/dB².

    ``step = 0`` gives the unquantised ``1/σ²``. Vectorised over ``mu`` and ``sigma``.
    """
    mu_a = np.asarray(mu, np.float64)
    sig = np.broadcast_to(np.asarray(sigma, np.float64), mu_a.shape)
    if step <= 0:
        return np.asarray(1.0 / sig**2, np.float64)
    span = int(np.ceil(8.0 * float(np.max(sig)) / step)) + 2
    k = np.arange(-span, span + 1)
    centre = np.round(mu_a / step)[..., None] * step
    edges_lo = centre + (k - 0.5) * step
    a = (edges_lo - mu_a[..., None]) / sig[..., None]
    b = a + step / sig[..., None]
    pa = np.exp(-0.5 * a * a) * _INV_SQRT_2PI
    pb = np.exp(-0.5 * b * b) * _INV_SQRT_2PI
    mass = ndtr(b) - ndtr(a)
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(mass > 1e-300, (pa - pb) ** 2 / mass, 0.0)
    return np.asarray(terms.sum(axis=-1) / sig**2, np.float64)


def monopulse_crb_deg2(
    info1: npt.ArrayLike, info2: npt.ArrayLike, slope_db_per_deg: float
) -> Array:
    """CRB on the angle, degrees², from each chain's information (1/dB²) and ``g_1 − g_2``."""
    i1 = np.asarray(info1, np.float64)
    i2 = np.asarray(info2, np.float64)
    with np.errstate(divide="ignore"):
        return np.asarray((i1 + i2) / (i1 * i2 * slope_db_per_deg**2), np.float64)
