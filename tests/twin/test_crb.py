"""The quantised-RSSI monopulse CRB: limits, Sheppard's correction, an estimator that meets it."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.twin.crb import monopulse_crb_deg2, quantised_fisher_info


def test_unquantised_and_wide_noise_limits() -> None:
    assert quantised_fisher_info(0.3, 0.8, step=0.0) == pytest.approx(1 / 0.64)
    mu = np.linspace(0, 1, 64, endpoint=False)
    # σ ≫ step: quantisation costs nothing
    assert np.mean(quantised_fisher_info(mu, 4.0)) * 16 == pytest.approx(1.0, abs=0.01)
    # σ ≈ step: the mean information is Sheppard's 1/(σ² + step²/12) within 1 %
    for s in (0.7, 1.0, 1.5):
        got = np.mean(quantised_fisher_info(mu, s))
        assert got == pytest.approx(1 / (s * s + 1 / 12), rel=0.01)


def test_small_noise_information_sits_at_the_cell_edges() -> None:
    at_edge = quantised_fisher_info(0.5, 0.1)
    at_centre = quantised_fisher_info(0.0, 0.1)
    # mid-cell the reading almost never changes; on an edge it is a fair coin:
    # a one-bit quantiser at its threshold keeps 2/π of the information
    assert at_centre < 0.01
    assert at_edge == pytest.approx(2 / np.pi / 0.1**2, rel=1e-6)


def test_crb_is_two_sigma_squared_over_slope_squared() -> None:
    s, k = 0.9, 0.8
    assert monopulse_crb_deg2(1 / s**2, 1 / s**2, k) == pytest.approx(2 * s**2 / k**2)


def test_ml_estimator_on_quantised_data_reaches_the_bound() -> None:
    """Monte Carlo (seeded): the difference estimator's variance over random grid offsets
    equals the mean CRB within the sampling error (n = 200k, relative SE ≈ 0.3 %)."""
    rng = np.random.default_rng(3)
    n, sigma, k = 200_000, 1.0, 0.8
    theta = rng.uniform(-10, 10, n)
    level = rng.uniform(-70, -50, n)
    mu1, mu2 = level + k * theta / 2, level - k * theta / 2
    q1 = np.round(mu1 + rng.normal(0, sigma, n))
    q2 = np.round(mu2 + rng.normal(0, sigma, n))
    est = (q1 - q2) / k
    crb = monopulse_crb_deg2(
        quantised_fisher_info(mu1, sigma), quantised_fisher_info(mu2, sigma), k
    )
    ratio = np.mean((est - theta) ** 2) / np.mean(crb)
    assert ratio == pytest.approx(1.0, abs=0.03)
