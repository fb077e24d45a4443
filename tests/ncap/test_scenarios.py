"""The generated matrix: with no braking every scenario hits where and as fast as planned."""

from __future__ import annotations

import itertools
import math

import pytest

from rfsas_hw.errors import ConfigError
from rfsas_hw.ncap.scenarios import (
    KMH,
    SCENARIOS,
    TRUE_NEGATIVES,
    VUT_WIDTH_M,
    Cell,
    cells,
    plan,
    scenario,
)


def test_the_matrix_has_the_protocols_cells() -> None:
    all_cells = cells(SCENARIOS)
    per = {name: [c for c in all_cells if c.scenario == name] for name in SCENARIOS}
    assert len(per["CPNA"]) == 12 and {c.impact for c in per["CPNA"]} == {0.25, 0.75}
    assert len(per["CPNCO"]) == 18
    assert {c.vut_speed_kmh for c in per["CBLA"]} == {20, 30, 40, 50, 60}
    # a speed one of the chosen scenarios does not test is left out for that one only
    assert [c.key for c in cells(["CBLA", "CBNA"], [10, 20])] == ["CBLA-50@20", "CBNA-50@10",
                                                                 "CBNA-50@20"]  # fmt: skip
    assert scenario("CPNCO").target.kind == "pedestrian" and scenario("CBNAO").obstructed
    with pytest.raises(KeyError, match="known: CPNA"):
        scenario("CPXX")


@pytest.mark.parametrize(
    ("names", "speeds", "match"),
    [
        (["CBLA"], [10, 20], r"speeds: 10 km/h: not a VUT speed of CBLA \(CBLA tested at 20, 30"),
        (["CPNCO"], [5, 70], r"speeds: 5, 70 km/h: not a VUT speed of CPNCO \(.*at 10, 20, 30"),
        (["CPNCO"], [], r"speeds: none \(CPNCO tested at 10"),
        ([], None, "scenarios: none chosen"),
    ],
)
def test_a_selection_with_nothing_to_run_says_what_is_tested(
    names: list[str], speeds: list[float] | None, match: str
) -> None:
    with pytest.raises(ConfigError, match=match):
        cells(names, speeds)


def test_obstructed_scenarios_park_two_vehicles_upstream_of_the_path() -> None:
    p = plan(Cell("CPNCO", 40.0, 0.5))
    car, van = p.obstacles
    assert car.x_max_m == pytest.approx(-1.0) and van.x_max_m < car.x_min_m
    assert car.y_max_m == pytest.approx(-(VUT_WIDTH_M / 2 + 1.0))
    assert (car.x_max_m - car.x_min_m) < (van.x_max_m - van.x_min_m)  # smaller one nearest
    assert plan(Cell("CPNA", 40.0, 0.25)).obstacles == ()


def _planned(name: str) -> list[Cell]:
    s = SCENARIOS[name]
    speeds = (s.vut_speeds_kmh[0], s.vut_speeds_kmh[-1])
    return [c for c in cells([name]) if c.vut_speed_kmh in speeds]


CASES = [c for name in SCENARIOS for c in _planned(name)]


@pytest.mark.parametrize("cell", CASES, ids=[c.key for c in CASES])
def test_no_braking_hits_the_planned_location_at_the_planned_speed(cell: Cell) -> None:
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.runner import RunSpec, run_one

    r = run_one(RunSpec(cell, "none"))
    assert r.contact
    assert r.impact_location_m is not None
    assert r.impact_location_m == pytest.approx(cell.impact * VUT_WIDTH_M, abs=0.3)
    s = SCENARIOS[cell.scenario]
    expected = cell.vut_speed_kmh - (s.speed_kmh if s.motion == "along" else 0.0)
    assert r.impact_speed_kmh == pytest.approx(expected, abs=0.5)
    assert r.contact_t_s == pytest.approx(plan(cell).contact_t_s, abs=0.06)
    assert r.first_brake_s is None and r.min_gap_m == 0.0


@pytest.mark.parametrize("name", list(TRUE_NEGATIVES))
def test_true_negatives_never_touch_the_car(name: str) -> None:
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.runner import RunSpec, run_one

    r = run_one(RunSpec(Cell(name, 50.0, 0.5), "none"))
    assert not r.contact
    assert r.min_gap_m > 0.3
    assert r.true_negative and not r.nuisance


def test_a_target_at_the_start_waits_and_then_moves_at_its_speed() -> None:
    p = plan(Cell("CPNCO", 10.0, 0.5))
    (path,) = p.targets
    _, y0, v0 = path.at(0.0)
    assert v0 == 0.0 and y0 == pytest.approx(-4.3)
    _, y1, v1 = path.at(p.contact_t_s)
    assert v1 == pytest.approx(5.0 * KMH) and y1 == pytest.approx(0.0)


@pytest.mark.parametrize(("name", "heading"), [("CBTA", 180.0), ("CPTA", 0.0)])
def test_turning_vut_follows_its_path_in_sumo(name: str, heading: float) -> None:
    """The VUT turns right (CBTA) or left (CPTA) in SUMO and meets the target on the side
    street's straight, with the target crossing from the VUT's right."""
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.scenarios import TURN_RADII_M
    from rfsas_hw.ncap.world import SumoWorld

    cell = Cell(name, 15.0, 0.5)
    p = plan(cell)
    assert p.vut_path is not None and p.obstacles == ()
    r = TURN_RADII_M[15.0]
    sign = 1.0 if heading == 180.0 else -1.0
    tgt = p.targets[0]
    assert tgt.heading_deg == (90.0 if sign > 0 else 270.0)
    with SumoWorld(p) as world:
        ego, _ = world.read()
        assert ego.heading_deg == pytest.approx(90.0) and ego.y_m == pytest.approx(0.0)
        headings = []
        while world.t_s < p.contact_t_s - 0.3:
            world.step(p.vut_speed_mps)
            ego, vrus = world.read()
            headings.append(ego.heading_deg)
            assert ego.speed_mps == pytest.approx(p.vut_speed_mps, abs=1e-6)
        # after the turn: on the side street's centre line, past the arc, heading along it
        assert ego.heading_deg == pytest.approx(heading, abs=1e-6)
        assert ego.x_m == pytest.approx(0.0, abs=1e-6)  # the side street's centre line
        assert -sign * ego.y_m > r  # past the arc
        # through the turn step by step: halfway round, never turning back
        assert any(abs(h - (90.0 + sign * 45.0)) < 5.0 for h in headings)
        assert all(sign * (b - a) >= 0 for a, b in itertools.pairwise(headings))
        ((target, cls),) = vrus
        assert cls == ("bicycle" if name == "CBTA" else "pedestrian")
        # the target is still to the VUT's right, coming towards its path
        a = math.radians(ego.heading_deg)
        right = (target.x_m - ego.x_m) * math.cos(a) - (target.y_m - ego.y_m) * math.sin(a)
        assert right > 0


@pytest.mark.parametrize("key", ["TN-BIKELANE@10", "CPNCO@40", "TN-PHONES@30", "CBTA@20"])
def test_the_first_read_finds_everyone_where_the_plan_puts_them(key: str) -> None:
    """At t = 0 the targets are at their planned places (not where SUMO inserted them, at
    the road's far end) and the VUT at its start, at its speed, so that RF-SAS's first
    bearings are of where the targets are."""
    pytest.importorskip("libsumo", reason="needs the sumo extra (pip install .[sumo])")
    from rfsas_hw.ncap.world import SumoWorld

    name, speed = key.split("@")
    p = plan(Cell(name, float(speed), 0.5))
    with SumoWorld(p) as world:
        ego, vrus = world.read()
        assert ego.x_m == pytest.approx(p.vut_start_x_m, abs=0.01)
        assert ego.y_m == pytest.approx(0.0, abs=0.01)
        assert ego.speed_mps == pytest.approx(p.vut_speed_mps, abs=1e-3)
        assert len(vrus) == len(p.targets)
        for path in p.targets:
            (target,) = [e for e, _ in vrus if e.id.endswith(path.id)]
            x, y, _ = path.at(0.0)
            assert (target.x_m, target.y_m) == pytest.approx((x, y), abs=0.01)
        # and the first step drives on from there
        world.step(p.vut_speed_mps)
        moved, _ = world.read()
        assert moved.x_m - ego.x_m == pytest.approx(p.vut_speed_mps * 0.05, abs=0.01)
