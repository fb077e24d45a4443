"""The two-beam antenna model and the RSSI synthesiser."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, quantise_db, rssi_pairs, rssi_sigma_db


def test_beams_peak_at_squint_and_are_3db_down_half_a_beamwidth_away() -> None:
    ant = GaussianBeamPair(squint_deg=20.0, beamwidth_deg=45.0, peak_gain_dbi=3.0)
    g = ant.gains_db(np.array([20.0, -20.0, 42.5]))
    assert g[0, 0] == pytest.approx(3.0)
    assert g[1, 1] == pytest.approx(3.0)
    assert g[2, 0] == pytest.approx(0.0)


def test_difference_is_linear_in_angle_inside_the_main_lobes() -> None:
    ant = GaussianBeamPair()
    theta = np.linspace(-30, 30, 7)
    g = ant.gains_db(theta)
    assert np.allclose(g[:, 0] - g[:, 1], ant.difference_slope_db_per_deg() * theta)


def test_floor_bounds_the_pattern() -> None:
    ant = GaussianBeamPair(front_to_back_db=25.0)
    assert ant.gains_db(np.array([180.0])).min() == pytest.approx(3.0 - 25.0)


def test_synthesised_readings_have_the_modelled_spread() -> None:
    rng = np.random.default_rng(3)
    rx = ReceiverModel(measurement_floor_db=1.0, step_db=0.0)
    r = rssi_pairs(np.zeros(200_000), -50.0, GaussianBeamPair(), rx, rng)
    expected = float(rssi_sigma_db(-50.0 - 7.5 - rx.noise_floor_dbm, 1.0))
    # 200k samples: the sample std is within 1% of the truth at >5 sigma
    assert np.std(r[:, 0]) == pytest.approx(expected, rel=0.01)


def test_quantisation_rounds_to_the_step() -> None:
    assert quantise_db(np.array([-50.4, -50.5, -50.6])).tolist() == [-50.0, -50.0, -51.0]
