"""The three ways to brake on small fixed cases: the brake, the LOS AEB, the cue, RF-SAS."""

from __future__ import annotations

import math

import pytest

from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.ncap.brake import Brake, BrakeModel
from rfsas_hw.ncap.cue import CueParams, Cues
from rfsas_hw.ncap.los_aeb import LosAeb, LosParams
from rfsas_hw.ncap.scenarios import Cell
from rfsas_hw.records import Assessment
from rfsas_hw.twin.scenario import BuildingSpec


def _car(x: float = 0.0, speed: float = 10.0) -> Entity:
    return Entity("ego", "vehicle", x, 0.0, 90.0, speed, 4.5, 1.8)


def _walker(x: float, y: float) -> Entity:
    return Entity("person:w", "pedestrian", x, y, 0.0, 1.4, 0.3, 0.5)


def test_brake_waits_its_latency_then_builds_up_at_the_jerk() -> None:
    b = Brake(BrakeModel(decel_mps2=9.0, jerk_mps3=25.0, latency_s=0.1), 10.0)
    b.request(0.0)
    assert b.advance(0.0, 0.05) == 10.0 and b.advance(0.05, 0.05) == 10.0
    v = b.advance(0.1, 0.05)
    assert v == pytest.approx(10.0 - 1.25 * 0.05)
    for k in range(3, 12):
        b.request(k * 0.05)
        v = b.advance(k * 0.05, 0.05)
    assert b.decel_mps2 == 9.0  # 0.36 s of build-up at 25 m/s³
    for k in range(12, 60):
        b.request(k * 0.05)
        v = b.advance(k * 0.05, 0.05)
    assert v == 0.0


def test_brake_releases_after_hold_and_keeps_the_speed() -> None:
    b = Brake(BrakeModel(decel_mps2=9.0, jerk_mps3=25.0, latency_s=0.0, hold_s=0.2), 10.0)
    b.request(0.0)
    speeds = [b.advance(k * 0.05, 0.05) for k in range(40)]
    assert min(speeds) == speeds[-1] > 0.0  # released: no more slowing, no speeding up
    assert speeds[-1] == speeds[-2]
    assert b.first_request_s == 0.0


def test_los_sees_in_its_field_of_view_and_range_not_through_a_parked_car() -> None:
    los = LosAeb(LosParams(fov_deg=90.0, range_m=60.0), [BuildingSpec(10.0, 14.0, -3.6, -1.9)])
    car = _car()
    assert los.visible(car, _walker(30.0, -4.0))
    assert los.visible(car, _walker(30.0, 25.0))  # 40 degrees off the heading
    assert not los.visible(car, _walker(30.0, 36.0))  # 50 degrees off the heading
    assert not los.visible(car, _walker(80.0, 0.0))  # out of range
    assert not los.visible(car, _walker(16.0, -4.5))  # behind the parked car
    assert los.visible(car, _walker(16.0, -1.0))  # stepped out


def test_los_confirms_after_its_latency_and_brakes_at_the_ttc_threshold() -> None:
    p = LosParams(confirm_s=0.5, ttc_brake_s=1.6)
    los = LosAeb(p, [])
    # a pedestrian standing in the lane 30 m ahead: TTC 3 s at 10 m/s, then closer
    requests = []
    for k in range(40):
        t = k * 0.05
        car = _car(x=10.0 * t)
        requests.append(los.step(t, car, [Entity("p", "pedestrian", 32.25, 0.0, 0.0, 0.0)]))
    first = requests.index(True) * 0.05
    # contact when the front (x + 2.25) reaches 32.0 → t = 2.975 s; brake at TTC <= 1.6 s
    assert first == pytest.approx(2.975 - 1.6, abs=0.06)
    assert los.first_confirmed_s["p"] == pytest.approx(0.5)


def _assessment(x: float, y: float, advisory: str = "caution") -> Assessment:
    nan = math.nan
    return Assessment(
        t_ns=0, emitter="00" * 8, x_m=x, y_m=y, cov_xx_m2=1.0, cov_xy_m2=0.0, cov_yy_m2=1.0,
        vx_mps=0.0, vy_mps=1.4, age_s=0.1, sensors=("a", "b"), fix_ok=True, fix_reason="ok",
        p_collision=nan, t_closest_s=nan, distance_to_contact_m=nan, impact_speed_mps=nan,
        fatality_risk=nan, risk=nan, advisory=advisory, reasons=(), link_alarm=False,
    )  # fmt: skip


def test_a_cue_points_at_its_bearing_for_its_time_to_live() -> None:
    cues = Cues(CueParams(ttl_s=1.0, half_width_deg=10.0))
    car = _car()
    assert cues.add(0.0, car, [_assessment(20.0, -3.0), _assessment(5.0, 5.0, "clear")]) == 1
    near, far = _walker(21.0, -3.5), _walker(20.0, 8.0)
    assert cues.cued(0.5, car, [near, far]) == [True, False]
    assert cues.cued(1.5, car, [near, far]) == [False, False]


def test_a_cued_target_is_confirmed_sooner() -> None:
    p = LosParams(confirm_s=0.5, confirm_cued_s=0.1)
    seen = {}
    for cued in (False, True):
        los = LosAeb(p, [])
        for k in range(20):
            t = k * 0.05
            los.step(t, _car(x=0.0, speed=0.0), [_walker(30.0, -4.0)], [cued])
        seen[cued] = los.first_confirmed_s["person:w"]
    assert seen[False] == pytest.approx(0.5) and seen[True] == pytest.approx(0.1)


def test_los_aeb_avoids_a_visible_adult_but_not_a_hidden_child_at_speed() -> None:
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.runner import RunSpec, run_one

    open_road = run_one(RunSpec(Cell("CPNA", 40.0, 0.25), "los"))
    assert not open_road.contact and open_road.first_brake_s is not None
    hidden = run_one(RunSpec(Cell("CPNCO", 60.0, 0.5), "los"))
    # the child is first confirmed only after it stepped out from behind the parked car
    assert hidden.first_los_confirm_s is not None and hidden.first_los_confirm_s > 3.5
    assert hidden.contact and hidden.impact_speed_kmh > 10.0


def test_rfsas_with_a_roadside_unit_brakes_for_the_hidden_child() -> None:
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.runner import RunSpec, run_one

    # (RF-SAS alone brakes late for a hidden child now that a brake by position needs
    # the child inside the path by a sigma of its position (docs/ncap.md, "Evidence of
    # position"): at 30 km/h it hits the child at 75 %; LOS, cued, still avoids it).
    # At 20 km/h and 75 % it brakes in every seed and avoids the child in most (seeds
    # 0-3: 3)
    runs = [
        run_one(RunSpec(Cell("CPNCO", 20.0, 0.75), "rfsas", "car+rsu", "phone-active", seed))
        for seed in range(4)
    ]
    assert all(r.first_rf_brake_s is not None for r in runs)
    assert sum(not r.contact for r in runs) >= 3
    fused = run_one(RunSpec(Cell("CPNCO", 30.0, 0.5), "rfsas+los", "car+rsu", "phone-active", 1))
    assert not fused.contact and fused.cued_steps > 0


def test_a_second_roadside_unit_on_the_kerb_lets_rfsas_alone_avoid_the_hidden_child() -> None:
    """CPNCO at 20 km/h and 50 %, seed 0, RF-SAS alone: with the farside unit only its BRAKE
    comes at 4.7 s and the child is hit (16.6 km/h); with the kerb unit of ``car+2rsu``
    beside it, which places the child across the road, the BRAKE comes at 4.3 s and the
    child is avoided (seeds 0-3: avoided in 4, against 1 with one unit; docs/ncap.md,
    "Two roadside units")."""
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.runner import RunSpec, run_one

    cell = Cell("CPNCO", 20.0, 0.5)
    one = run_one(RunSpec(cell, "rfsas", "car+rsu", "phone-active", 0))
    two = run_one(RunSpec(cell, "rfsas", "car+2rsu", "phone-active", 0))
    assert one.contact and one.impact_speed_kmh > 5.0
    assert not two.contact and two.first_rf_brake_s is not None
    assert one.first_rf_brake_s is not None and two.first_rf_brake_s < one.first_rf_brake_s


def test_los_cued_by_rfsas_brakes_only_on_its_own_sight() -> None:
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.runner import RunSpec, run_one

    # the bicyclist from the side street at 10 km/h, seed 0: RF-SAS advises BRAKE at 4.6 s
    # while the camera/radar never confirms the bicyclist...
    side = run_one(RunSpec(Cell("CBNA", 10.0, 0.5), "los+cue", "car+rsu", "phone-active", 0))
    assert side.first_rf_brake_s is not None
    assert side.first_brake_s is None and side.contact  # ...and this controller ignores it
    child = run_one(RunSpec(Cell("CPNCO", 50.0, 0.5), "los+cue", "car+rsu", "phone-active", 0))
    alone = run_one(RunSpec(Cell("CPNCO", 50.0, 0.5), "los"))
    assert child.cued_steps > 0 and child.first_los_confirm_s is not None
    assert alone.first_los_confirm_s is not None
    assert child.first_los_confirm_s < alone.first_los_confirm_s - 0.3  # confirmed sooner
    assert child.impact_speed_kmh < alone.impact_speed_kmh


def test_rfsas_does_not_brake_for_a_walker_standing_at_the_kerb() -> None:
    """TN-KERB at 30 km/h, seed 0: RF-SAS (roadside unit, active phone) braked at 3.3 s
    on a track whose velocity pointed into the lane (P(collision) 0.27) for a walker
    who stops 0.5 m short of it; a brake now needs evidence of a path into the lane."""
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.runner import RunSpec, run_one

    kerb = run_one(RunSpec(Cell("TN-KERB", 30.0, 0.5), "rfsas", "car+rsu", "phone-active", 0))
    assert kerb.first_rf_brake_s is None and not kerb.nuisance
    assert kerb.min_gap_m > 0 and not kerb.contact
    # seeds 4 and 11: the constant-velocity track kept the walk (and runs of the VUT
    # unit's bearing errors) as motion into the lane and braked at 3.8 and 3.7 s; the
    # standing model beside it believes the stop (docs/ncap.md, "A walker who stops")
    for seed in (4, 11):
        spec = RunSpec(Cell("TN-KERB", 30.0, 0.5), "rfsas", "car+rsu", "phone-active", seed)
        assert run_one(spec).first_rf_brake_s is None, seed
    # 60 km/h, seed 4: braked at 3.8 s on a track 1.9 m towards the lane from the standing
    # walker, 2 sigma of its position off; in the path by position now needs the track
    # inside it by a sigma (docs/ncap.md, "Evidence of position")
    spec = RunSpec(Cell("TN-KERB", 60.0, 0.5), "rfsas", "car+rsu", "phone-active", 4)
    assert run_one(spec).first_rf_brake_s is None


def test_rfsas_does_not_brake_for_a_walker_it_overtakes_at_the_edge_of_its_view() -> None:
    """TN-ALONG at 10 km/h, seed 0: the VUT's unit reads the walker it overtakes at the
    edge of its view, where its edge rule lets only readings that err towards boresight
    through; taken as such (censored), they no longer pull the track into the lane."""
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.runner import RunSpec, run_one

    spec = RunSpec(Cell("TN-ALONG", 10.0, 0.5), "rfsas", "car+rsu", "phone-active", 0)
    assert run_one(spec).first_rf_brake_s is None


def test_rfsas_does_not_brake_as_it_passes_a_walker_on_the_sidewalk() -> None:
    """TN-ALONG at 30 km/h, seed 0: RF-SAS braked at 5.3 s as the VUT passed the walker, on
    a track restarted by bearings folded in from outside the VUT unit's field of view; with
    the test track's floor in every bearing's sigma that track is too wide to brake for."""
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.runner import RunSpec, run_one

    along = run_one(RunSpec(Cell("TN-ALONG", 30.0, 0.5), "rfsas", "car+rsu", "phone-active", 0))
    assert along.first_rf_brake_s is None and not along.nuisance and not along.contact


def test_rfsas_does_not_brake_for_the_bicyclist_on_the_bike_lane_at_10_kmh() -> None:
    """TN-BIKELANE at 10 km/h, seed 5: RF-SAS braked at 3.0 s on a track started from a
    fix 16 m ahead of the bicyclist, made of the first frames, which the twin drew from
    where SUMO had inserted the bike (100 m down the road) before placing it; with the
    targets in place at t = 0 the track starts on the bicyclist."""
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.runner import RunSpec, run_one

    bike = run_one(RunSpec(Cell("TN-BIKELANE", 10.0, 0.5), "rfsas", "car+rsu", "phone-active", 5))
    assert bike.first_rf_brake_s is None and not bike.nuisance and not bike.contact
