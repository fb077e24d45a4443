"""Stopping distance, impact speed, Rosen's fatality risk and the advisory, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfsas_hw.backend.risk import (
    BRAKE_DECEL_MPS2,
    Advisory,
    AdvisoryThresholds,
    advise,
    fatality_risk,
    impact_speed,
    stopping_distance,
)
from rfsas_hw.errors import BackendError


def test_braking_deceleration_is_047_g() -> None:
    assert BRAKE_DECEL_MPS2 == pytest.approx(4.6091255, abs=1e-7)


def test_stopping_distance_hand_computed() -> None:
    # 20 m/s: 400 / (2 · 4.6091255) = 43.3922 m
    assert stopping_distance(20.0) == pytest.approx(43.3922, abs=1e-4)
    # 50 km/h = 13.8889 m/s: 192.901 / 9.218251 = 20.926 m; with 1 s reaction + 13.889 m
    assert stopping_distance(50 / 3.6) == pytest.approx(20.926, abs=1e-3)
    assert stopping_distance(50 / 3.6, reaction_s=1.0) == pytest.approx(34.815, abs=1e-3)
    assert stopping_distance(0.0) == 0.0


def test_impact_speed_hand_computed() -> None:
    # √(400 − 2 · 4.6091255 · 30) = √123.45247 = 11.1109 m/s
    assert impact_speed(20.0, 30.0) == pytest.approx(11.1109, abs=1e-4)
    assert impact_speed(20.0, 50.0) == 0.0  # stops within 43.392 m
    assert impact_speed(20.0, 43.0) == pytest.approx(math.sqrt(400 - 2 * 4.6091255 * 43), abs=1e-6)
    # 1 s reaction eats 20 m of the 30: √(400 − 92.18251) = 17.5447 m/s
    assert impact_speed(20.0, 30.0, reaction_s=1.0) == pytest.approx(17.5447, abs=1e-4)
    assert impact_speed(20.0, 10.0, reaction_s=1.0) == 20.0
    assert impact_speed(20.0, -1.0) == 20.0  # already touching
    # a gentler brake (0.3 g) at 15 m/s and 20 m: √(225 − 2·2.941995·20) = √107.3202 = 10.3596
    assert impact_speed(15.0, 20.0, decel_mps2=0.3 * 9.80665) == pytest.approx(10.3596, abs=1e-4)


def test_impact_speed_is_vectorised() -> None:
    v = impact_speed(np.array([20.0, 20.0, 10.0]), np.array([30.0, 50.0, 0.0]))
    assert isinstance(v, np.ndarray)
    np.testing.assert_allclose(v, [11.1109, 0.0, 10.0], atol=1e-4)


def test_a_float_gives_a_float_and_the_value_of_its_one_element_array() -> None:
    for u, x in [(0.0, 0.0), (13.9, -3.0), (5.0, 2.5), (30.0, 1e300)]:
        d, v = stopping_distance(u, reaction_s=0.5), impact_speed(u, x, reaction_s=0.5)
        assert type(d) is float and type(v) is float and type(fatality_risk(v)) is float
        assert d == pytest.approx(stopping_distance(np.array([u]), reaction_s=0.5)[0], rel=1e-12)
        assert v == pytest.approx(impact_speed(np.array([u]), x, reaction_s=0.5)[0], rel=1e-12)


def test_rosen_fatality_risk_published_values() -> None:
    assert fatality_risk(72 / 3.6) == pytest.approx(0.3965, abs=5e-5)
    assert fatality_risk(0.0) == pytest.approx(0.001007, abs=5e-7)
    # the 50 % point: 6.9 / 0.090 = 76.67 km/h
    assert fatality_risk(6.9 / 0.090 / 3.6) == pytest.approx(0.5, abs=1e-12)
    np.testing.assert_allclose(fatality_risk(np.array([0.0, 20.0])), [0.001007, 0.3965], atol=5e-5)


def test_invalid_inputs_raise() -> None:
    with pytest.raises(BackendError, match="speed"):
        impact_speed(-1.0, 10.0)
    with pytest.raises(BackendError, match="deceleration"):
        stopping_distance(10.0, decel_mps2=0.0)
    with pytest.raises(BackendError, match="impact speed"):
        fatality_risk(math.nan)
    with pytest.raises(BackendError, match="caution_risk"):
        AdvisoryThresholds(brake_risk=0.001, caution_risk=0.01)
    with pytest.raises(BackendError, match="speed must be"):
        impact_speed(math.nan, 1.0)
    with pytest.raises(BackendError, match="distance must be finite"):
        impact_speed(1.0, math.inf)
    with pytest.raises(BackendError, match="reaction delay"):
        impact_speed(1.0, 1.0, 2.0, -1.0)


def test_advisory_with_reasons() -> None:
    adv, why = advise(0.6, 0.2, 25.0, 43.4)
    assert adv is Advisory.BRAKE and any("risk 0.2" in r for r in why)
    # can still stop, but only just: brake now on a likely collision
    adv, why = advise(0.5, 0.5 * 0.001007, 50.0, 43.4)
    assert adv is Advisory.BRAKE and any("stopping needs 43.4 m" in r for r in why)
    # likely collision far beyond the stopping distance: caution only
    adv, why = advise(0.5, 0.0005, 200.0, 43.4)
    assert adv is Advisory.CAUTION
    adv, why = advise(0.001, 1e-6, 200.0, 43.4)
    assert adv is Advisory.CLEAR and why
    adv, why = advise(0.001, 1e-6, 200.0, 43.4, link_alarm=True)
    assert adv is Advisory.CAUTION and "link latency alarm" in why
    adv, why = advise(0.0, 0.0, math.inf, 43.4, fix_ok=False, fix_reason="parallel")
    assert adv is Advisory.CAUTION and why == ("emitter not located: parallel",)
