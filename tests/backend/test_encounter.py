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


def test_brake_held_for_a_young_track_or_a_threat_with_no_evidence_of_entering_the_path() -> None:
    from rfsas_hw.backend.risk import AdvisoryThresholds

    strict = EncounterConfig(
        thresholds=AdvisoryThresholds(brake_min_fixes=5, brake_needs_path=True)
    )
    car = VehicleState(-20.0, 0.0, 90.0, 15.0)
    # in the lane, 17.5 m ahead: brake, unless its track has just (re)started
    assert assess_encounter(car, *still(0.0, 0.0), strict, track_fixes=5).advisory is Advisory.BRAKE
    young = assess_encounter(car, *still(0.0, 0.0), strict, track_fixes=2)
    assert young.advisory is Advisory.CAUTION
    assert young.reasons[0].startswith("brake held: track has 2 fix(es)")
    assert assess_encounter(car, *still(0.0, 0.0), track_fixes=1).advisory is Advisory.BRAKE
    # 2.5 m right of the lane centre (1.35 m beside the path: 2.5 − 0.9 − 0.25), drifting at
    # 1 ± 0.7 m/s towards it: P(collision) is high enough to brake, the evidence of entering
    # is not (1 − 2·0.7 < 0)
    cov = np.diag([0.25, 0.25, 0.49, 0.49])
    drift = np.array([0.0, -2.5, 0.0, 1.0])
    loose = assess_encounter(car, drift, cov)
    assert loose.advisory is Advisory.BRAKE
    held = assess_encounter(car, drift, cov, strict, track_fixes=20)
    assert held.advisory is Advisory.CAUTION
    assert "1.4 m beside the path" in held.reasons[0]
    # the same place at 3 ± 0.2 m/s towards the path: it enters before closest approach
    sure = np.diag([0.25, 0.25, 0.04, 0.04])
    fast = assess_encounter(car, np.array([0.0, -2.5, 0.0, 3.0]), sure, strict, track_fixes=20)
    assert fast.advisory is Advisory.BRAKE
    with pytest.raises(BackendError, match="brake_min_fixes"):
        AdvisoryThresholds(brake_min_fixes=0)
    with pytest.raises(BackendError, match="brake_path_sigmas"):
        AdvisoryThresholds(brake_path_sigmas=-1.0)


def test_brake_by_position_needs_the_position_inside_the_path_by_its_sigmas() -> None:
    from rfsas_hw.backend.risk import AdvisoryThresholds

    def rule(k_d: float) -> EncounterConfig:
        return EncounterConfig(
            thresholds=AdvisoryThresholds(brake_needs_path=True, brake_position_sigmas=k_d)
        )

    car = VehicleState(-20.0, 0.0, 90.0, 15.0)
    # standing 0.5 m right of the lane centre: 0.65 m inside the path (0.9 + 0.25 − 0.5)
    sure = still(0.0, -0.5, var=0.04)  # position sigma 0.2 m: inside by 3 sigma
    wide = still(0.0, -0.5, var=1.0)  # position sigma 1 m: inside by 0.65 sigma
    assert assess_encounter(car, *wide, rule(0.0)).advisory is Advisory.BRAKE  # centre inside
    assert assess_encounter(car, *sure, rule(2.0)).advisory is Advisory.BRAKE
    held = assess_encounter(car, *wide, rule(2.0))
    assert held.advisory is Advisory.CAUTION
    assert "0.6 ± 1.0 m inside the path (needs 2 sigma inside)" in held.reasons[0]
    with pytest.raises(BackendError, match="brake_position_sigmas"):
        AdvisoryThresholds(brake_position_sigmas=math.inf)
