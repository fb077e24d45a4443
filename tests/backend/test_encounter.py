"""A threat against the vehicle: closest approach, P(collision), impact speed, advisory."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rfsas_hw.backend.collision import collision_probability, heading_covariance
from rfsas_hw.backend.encounter import EncounterConfig, assess_encounter
from rfsas_hw.backend.risk import Advisory, fatality_risk
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import BackendError


def still(x: float, y: float, var: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    cov = np.diag([var, var, 1e-6, 1e-6])
    return np.array([x, y, 0.0, 0.0]), cov


def test_crossing_pedestrian_is_judged_at_closest_approach() -> None:
    car = VehicleState(x_m=-30.0, y_m=0.0, heading_deg=90.0, speed_mps=10.0)
    state = np.array([0.0, -6.0, 0.0, 2.0])  # walking north at 2 m/s
    cov = np.diag([0.5, 0.5, 0.04, 0.04])
    enc = assess_encounter(car, state, cov)
    # r0 = (30, -6), w = (-10, 2): t* = 312 / 104 = 3 s, both at the origin then
    assert enc.t_closest_s == pytest.approx(3.0)
    expected = collision_probability(
        [0.0, 0.0],
        90.0,
        heading_covariance(90.0),
        (4.5, 1.8),
        [0.0, 0.0],
        0.0,  # north
        np.diag([0.5 + 9 * 0.04, 0.5 + 9 * 0.04]),
        "pedestrian",
    )
    assert enc.p_collision == pytest.approx(expected, rel=1e-12)
    assert enc.p_collision > 0.2


def test_impact_speed_risk_and_advisory_by_distance() -> None:
    ped = still(0.0, 0.0)
    # contact at 20 − 2.25 − 0.25 = 17.5 m, stopping from 15 m/s needs 225 / 9.218251 = 24.408 m:
    # v = √(225 − 2·4.6091255·17.5) = 7.980 m/s
    near = assess_encounter(VehicleState(-20.0, 0.0, 90.0, 15.0), *ped)
    assert near.distance_to_contact_m == pytest.approx(17.5)
    assert near.stopping_distance_m == pytest.approx(24.4081, abs=1e-4)
    assert near.impact_speed_mps == pytest.approx(7.980, abs=1e-3)
    assert near.fatality_risk == pytest.approx(fatality_risk(near.impact_speed_mps))
    assert near.risk == pytest.approx(near.p_collision * near.fatality_risk)
    assert near.advisory is Advisory.BRAKE
    # contact at 27.5 m: stops in time (impact 0) but only just: brake now
    mid = assess_encounter(VehicleState(-30.0, 0.0, 90.0, 15.0), *ped)
    assert mid.impact_speed_mps == 0.0 and mid.advisory is Advisory.BRAKE
    # contact at 57.5 m: plenty of room, yet a likely collision ahead: caution
    far = assess_encounter(VehicleState(-60.0, 0.0, 90.0, 15.0), *ped)
    assert far.advisory is Advisory.CAUTION
    # 20 m to the side: clear
    side = assess_encounter(VehicleState(-20.0, 20.0, 90.0, 15.0), *ped)
    assert side.p_collision < 1e-6 and side.advisory is Advisory.CLEAR
    # behind the vehicle: no contact ahead
    behind = assess_encounter(VehicleState(20.0, 0.0, 90.0, 15.0), *ped)
    assert math.isinf(behind.distance_to_contact_m) and behind.impact_speed_mps == 0.0
    # a reaction delay of 1 s turns the near case into a faster impact
    late = assess_encounter(
        VehicleState(-20.0, 0.0, 90.0, 15.0), *ped, EncounterConfig(reaction_s=1.0)
    )
    assert late.impact_speed_mps == pytest.approx(math.sqrt(225 - 2 * 4.6091255 * 2.5), abs=1e-6)


def test_bad_fix_and_link_alarm_raise_caution() -> None:
    enc = assess_encounter(
        VehicleState(-20.0, 30.0, 90.0, 15.0), *still(0, 0), fix_ok=False, fix_reason="parallel"
    )
    assert enc.advisory is Advisory.CAUTION and "emitter not located: parallel" in enc.reasons
    enc = assess_encounter(VehicleState(-20.0, 30.0, 90.0, 15.0), *still(0, 0), link_alarm=True)
    assert enc.advisory is Advisory.CAUTION
    with pytest.raises(BackendError, match="unknown threat kind"):
        EncounterConfig(threat_kind="horse")
    with pytest.raises(BackendError, match="finite"):
        assess_encounter(VehicleState(0, 0, 0, 1), np.zeros(3), np.eye(4))
