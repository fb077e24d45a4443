"""Physical two-ray models against their limits."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.rf import (
    free_space_path_loss_db,
    two_ray_breakpoint_path_loss_db,
    two_ray_coherent_path_loss_db,
    wavelength_m,
)


def test_free_space_reference_value() -> None:
    # 2.4 GHz at 1 m: 20·log10(4π/λ) with λ = c/2.4e9 → 40.05 dB
    assert float(free_space_path_loss_db(1.0, 2400.0)) == pytest.approx(40.05, abs=0.01)
    assert wavelength_m(2400.0) == pytest.approx(0.1249, abs=1e-4)


def test_coherent_model_approaches_forty_db_per_decade_far_out() -> None:
    # beyond the breakpoint (4·1·1/0.125 ≈ 32 m) the sum falls 40 dB/decade
    d = np.array([1000.0, 10000.0])
    pl = two_ray_coherent_path_loss_db(d, 2400.0)
    assert pl[1] - pl[0] == pytest.approx(40.0, abs=0.2)
    assert pl[1] == pytest.approx(float(two_ray_breakpoint_path_loss_db(10000.0, 2400.0)), abs=0.3)


def test_coherent_model_interferes_between_its_envelopes() -> None:
    d = np.linspace(1.0, 30.0, 5001)
    excess = two_ray_coherent_path_loss_db(d, 2400.0) - free_space_path_loss_db(d, 2400.0)
    gain = 10 ** (-excess / 10)
    a = d / np.hypot(d, 2.0)  # reflected / direct amplitude with 1 m antennas
    assert np.all(gain <= (1 + a) ** 2 + 1e-9)
    assert np.all(gain >= (1 - a) ** 2 - 1e-9)


def test_coherent_model_peaks_where_the_path_difference_is_half_a_wavelength() -> None:
    lam = wavelength_m(2400.0)
    # sqrt(d² + 4) − d = λ/2  →  d = (4 − λ²/4) / λ ; reflection −1 makes it constructive
    d = (4.0 - lam**2 / 4.0) / lam
    a = d / np.hypot(d, 2.0)
    excess = float(two_ray_coherent_path_loss_db(d, 2400.0) - free_space_path_loss_db(d, 2400.0))
    assert 10 ** (-excess / 10) == pytest.approx((1 + a) ** 2, rel=1e-6)


def test_breakpoint_switches_model() -> None:
    bp = 4 * 1.0 * 1.0 / wavelength_m(2437.0)
    below, above = two_ray_breakpoint_path_loss_db(np.array([bp * 0.5, bp * 2.0]), 2437.0)
    assert below == pytest.approx(float(free_space_path_loss_db(bp * 0.5, 2437.0)))
    assert above == pytest.approx(40 * np.log10(bp * 2.0))


def test_bad_distance_rejected() -> None:
    with pytest.raises(ValueError, match="distance"):
        free_space_path_loss_db(0.0, 2400.0)
