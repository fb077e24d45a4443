"""Scoring like the protocol on small fixed cases."""

from __future__ import annotations

import pytest

from rfsas_hw.ncap.runner import RunResult
from rfsas_hw.ncap.scoring import band, goal_configs, goals, nuisance, points, score_cells


def _r(
    cell: str, config: str, v: float, impact_kmh: float, seed: int = 0, **kw: object
) -> RunResult:
    scen = cell.split("-")[0] if not cell.startswith("TN-") else "-".join(cell.split("-")[:2])
    return RunResult(
        scen, cell, v, 0.5, config, config, "car+rsu", "phone-active", seed,
        scen.startswith("TN-"), contact=impact_kmh > 0, impact_speed_kmh=impact_kmh, **kw,  # type: ignore[arg-type]
    )  # fmt: skip


def test_bands_follow_the_share_of_speed_taken_off() -> None:
    assert band(0.0, 40.0) == ("green", 1.0)
    assert band(10.0, 40.0) == ("yellow", 0.8)
    assert band(20.0, 40.0) == ("orange", 0.4)
    assert band(25.0, 40.0) == ("brown", 0.2)
    assert band(40.0, 40.0) == ("red", 0.0)
    with pytest.raises(ValueError, match="test_kmh"):
        band(5.0, 0.0)


def test_cells_take_the_median_seed_and_points_share_the_scenarios_points() -> None:
    runs = [
        _r("CPNCO-50@20", "los", 20.0, 0.0, 0),
        _r("CPNCO-50@20", "los", 20.0, 0.0, 1),
        _r("CPNCO-50@20", "los", 20.0, 20.0, 2),  # one seed of three hit: median avoided
        _r("CPNCO-50@60", "los", 60.0, 60.0, 0),
        _r("CPLA-50@20", "los", 20.0, 10.0, 0),  # relative: 15 km/h test speed, 1/3 off
        _r("TN-KERB-50@20", "los", 20.0, 0.0, 0, first_brake_s=2.0),
        _r("TN-KERB-50@20", "los", 20.0, 0.0, 1),
    ]
    cells = score_cells(runs)
    by = {c.cell: c for c in cells}
    assert set(by) == {"CPNCO-50@20", "CPNCO-50@60", "CPLA-50@20"}
    assert by["CPNCO-50@20"].band == "green" and by["CPNCO-50@20"].contacts == 1
    assert by["CPNCO-50@60"].band == "red"
    assert by["CPLA-50@20"].band == "brown"
    pts = points(cells)["los"]
    assert pts["CPNCO"] == pytest.approx((1.0, 2.0))  # half the cells green
    assert pts["CPLA"] == pytest.approx((0.4, 2.0))
    assert nuisance(runs) == {"los": (1, 2)}


def test_turning_cells_count_avoidance_only() -> None:
    runs = [
        _r("CPTA-50@20", "los", 20.0, 0.0),
        _r("CBTA-50@20", "los", 20.0, 1.0),  # 95 % of the speed off: yellow elsewhere, red here
        _r("CBTA-50@10", "los", 10.0, 0.0),
    ]
    got = {c.cell: (c.band, c.share) for c in score_cells(runs)}
    assert got == {
        "CPTA-50@20": ("green", 1.0),
        "CBTA-50@20": ("red", 0.0),
        "CBTA-50@10": ("green", 1.0),
    }
    assert points(score_cells(runs))["los"] == {"CBTA": (1.0, 2.0), "CPTA": (2.0, 2.0)}


def test_goals_are_measured_for_every_deployment_of_the_goal_controller() -> None:
    two = "rfsas+los/car+2rsu/phone-active"
    runs = [
        _r("CPNCO-50@20", "los", 20.0, 10.0),
        _r("CPNCO-50@20", two, 20.0, 0.0),
        _r("CBNAO-50@60", two, 60.0, 45.0),
        _r("TN-KERB-50@20", two, 20.0, 0.0),
        _r("CPNCO-50@20", "rfsas/car+rsu/phone-active", 20.0, 0.0),
    ]
    # the stated configuration first, even where it did not run: its goals say so
    assert goal_configs(r.config for r in runs) == ["rfsas+los/car+rsu/phone-active", two]
    cells = score_cells(runs)
    pts, nuis = points(cells), nuisance(runs)
    stated, other = (goals(cells, pts, nuis, c) for c in goal_configs(r.config for r in runs))
    assert stated["green_obstructed"] is None and stated["not_below_los"] is None
    assert other["green_obstructed"] is False and other["not_green"] == ["CBNAO-50@60"]
    assert other["not_below_los"] is True and other["no_nuisance"] is True
