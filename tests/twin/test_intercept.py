"""Scan plans and time to first intercept."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.errors import ConfigError
from rfsas_hw.twin.intercept import (
    first_intercepts,
    mean_gap_closed_form,
    mean_gap_simulated,
    plan_report,
    receiver_plans,
)
from rfsas_hw.twin.scan import ScanPlan


@pytest.mark.parametrize(
    ("t1", "tau1", "t2", "tau2"),
    [(1.3, 0.095, 0.1024, 0.002), (0.7, 0.2, 0.1024, 0.0004), (3.9, 0.1, 1.2817, 0.01)],
)
def test_closed_form_mean_gap_matches_simulation(t1, tau1, t2, tau2) -> None:
    """T1·T2/(τ1+τ2) against a long run with incommensurate periods (within 2 %)."""
    want = mean_gap_closed_form(t1, tau1, t2, tau2)
    got = mean_gap_simulated(t1, tau1, t2, tau2, horizon_s=2e5, phase_s=0.0123)
    assert got == pytest.approx(want, rel=0.02)


def test_fixed_channel_hears_the_first_beacon() -> None:
    """On the AP's own channel the first intercept is the first beacon: uniform on [0, 102.4 ms]."""
    t = first_intercepts([ScanPlan((6,), 0.1)], "beacon", trials=3000, airtime_s=0.0, seed=1)
    assert np.all(t <= 0.1024 + 0.0005 + 1e-9)
    # mean of U(0, T2) plus half the 0.5 ms default jitter
    assert np.mean(t) == pytest.approx(0.0512 + 0.00025, abs=0.003)


def test_more_receivers_intercept_sooner_and_revisit_faster() -> None:
    chans = tuple(range(1, 14))
    one = plan_report(receiver_plans(chans, 0.1, 1, 0.005), "beacon", trials=600, seed=2)
    three = plan_report(receiver_plans(chans, 0.1, 3, 0.005), "beacon", trials=600, seed=2)
    assert one.revisit_s == pytest.approx(1.3)
    assert three.revisit_s == pytest.approx(0.5)
    assert three.mean_s < 0.6 * one.mean_s
    assert three.p90_s < one.p90_s
    assert one.intercepted == 1.0


def test_ble_on_advertising_channels() -> None:
    rep = plan_report(receiver_plans((37, 38, 39), 0.2, 1), "ble", trials=400, seed=3)
    assert rep.intercepted == 1.0
    assert rep.mean_s < 0.2


def test_plan_errors() -> None:
    with pytest.raises(ConfigError, match="cannot share"):
        receiver_plans((1, 6), 0.1, 3)
    with pytest.raises(ConfigError, match="scan plan"):
        receiver_plans((1, 6), 0.1, 1, switch_s=0.2)
