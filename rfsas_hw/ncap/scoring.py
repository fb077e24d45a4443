"""Scoring like the protocol: impact speed per cell, colour bands, points, nuisance brakes.

Per cell and configuration, the cell's impact speed is the median over its
seeds of the relative impact speed (0 when the collision was avoided). Its
colour band follows the share of the test's relative speed that the
controller took off, ``r = 1 − v_impact / v_test`` (``v_test``: the VUT's
speed, minus the target's in the longitudinal scenarios): green when the
collision was avoided, yellow for ``r ≥ 0.75``, orange ``r ≥ 0.5``, brown
``r ≥ 0.25``, red below. The five bands are worth 100 / 80 / 40 / 20 / 0 % of
the cell's points, as in the 2026 protocols; the thresholds are chosen here
(the protocol gives them in a figure that is not in its public text). A
scenario's points (:attr:`~rfsas_hw.ncap.scenarios.Scenario.points`) are
shared equally by the cells that were run. The turning scenarios (CPTA,
CBTA) count avoidance only, as the protocol does: green when avoided, red
otherwise. True-negative scenarios score no points: every run with a brake
request in them is a nuisance brake.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from rfsas_hw.ncap.runner import RunResult
from rfsas_hw.ncap.scenarios import scenario

BANDS: tuple[tuple[str, float, float], ...] = (
    ("green", 1.0, 1.0),
    ("yellow", 0.75, 0.8),
    ("orange", 0.5, 0.4),
    ("brown", 0.25, 0.2),
    ("red", -math.inf, 0.0),
)
"""(band, smallest reduction share ``r``, share of the cell's points)."""
COLOURS = {
    "green": "#3aa655",
    "yellow": "#f2d43d",
    "orange": "#f28c28",
    "brown": "#8b5a2b",
    "red": "#d7301f",
}
"""How the bands are drawn."""

__all__ = ["BANDS", "COLOURS", "CellScore", "band", "nuisance", "points", "score_cells"]


def band(impact_kmh: float, test_kmh: float) -> tuple[str, float]:
    """The colour band and its share of the points for a relative impact speed.

    Args:
        impact_kmh: relative impact speed, km/h (0: avoided).
        test_kmh: the test's relative speed, km/h (> 0).

    Raises:
        ValueError: ``test_kmh`` is not positive or ``impact_kmh`` is negative.
    """
    if not test_kmh > 0 or impact_kmh < 0:
        raise ValueError(f"need test_kmh > 0 and impact_kmh >= 0, got {test_kmh}, {impact_kmh}")
    if impact_kmh == 0:
        return "green", 1.0
    r = 1.0 - impact_kmh / test_kmh
    for name, lo, share in BANDS[1:-1]:
        if r >= lo:
            return name, share
    return BANDS[-1][0], BANDS[-1][2]


@dataclass(frozen=True)
class CellScore:
    """One cell of one configuration over its seeds."""

    scenario: str
    cell: str
    vut_speed_kmh: float
    impact: float
    config: str
    impact_kmh: float
    """Median relative impact speed over the seeds, km/h."""
    band: str
    share: float
    seeds: int
    contacts: int
    """Seeds with a collision."""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return dict(self.__dict__)


def _test_kmh(r: RunResult) -> float:
    s = scenario(r.scenario)
    return r.vut_speed_kmh - (s.speed_kmh if s.motion == "along" else 0.0)


def score_cells(results: Iterable[RunResult]) -> list[CellScore]:
    """Every (cell, configuration) of the non-true-negative runs, in a stable order."""
    groups: dict[tuple[str, str], list[RunResult]] = {}
    for r in results:
        if not r.true_negative:
            groups.setdefault((r.config, r.cell), []).append(r)
    out = []
    for (config, _), rs in sorted(groups.items()):
        r0 = rs[0]
        v = statistics.median(r.impact_speed_kmh for r in rs)
        if scenario(r0.scenario).motion == "turn":  # avoidance only
            name, share = ("green", 1.0) if v <= 0.0 else ("red", 0.0)
        else:
            name, share = band(v, _test_kmh(r0))
        out.append(
            CellScore(
                r0.scenario,
                r0.cell,
                r0.vut_speed_kmh,
                r0.impact,
                config,
                v,
                name,
                share,
                len(rs),
                sum(r.contact for r in rs),
            )
        )
    return out


def points(cells: Sequence[CellScore]) -> dict[str, dict[str, tuple[float, float]]]:
    """Per configuration and scenario: (points earned, points available)."""
    per: dict[str, dict[str, list[CellScore]]] = {}
    for c in cells:
        per.setdefault(c.config, {}).setdefault(c.scenario, []).append(c)
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for config, scen in per.items():
        out[config] = {}
        for name, cs in sorted(scen.items()):
            full = scenario(name).points
            out[config][name] = (full * sum(c.share for c in cs) / len(cs), full)
    return out


def nuisance(results: Iterable[RunResult]) -> dict[str, tuple[int, int]]:
    """Per configuration: (true-negative runs with a brake request, true-negative runs)."""
    out: dict[str, list[int]] = {}
    for r in results:
        if r.true_negative:
            n = out.setdefault(r.config, [0, 0])
            n[0] += int(r.nuisance)
            n[1] += 1
    return {k: (v[0], v[1]) for k, v in sorted(out.items())}


GOAL_CONFIG = "rfsas+los/car+rsu/phone-active"
"""The configuration the goals are stated for."""
GOAL_CONTROLLER = "rfsas+los"
"""The controller the goals are stated for; every deployment and device of it is measured."""
GOAL_SCENARIOS = ("CPNCO", "CBNAO")
"""The obstructed scenarios that must be green in every cell."""


def goal_configs(configs: Iterable[str]) -> list[str]:
    """The configurations of ``configs`` the goals are measured for: :data:`GOAL_CONFIG`
    and every other deployment and device of :data:`GOAL_CONTROLLER`, the stated one
    first (it alone when none of them ran, so that the goals say what was not covered)."""
    mine = {c for c in configs if c.split("/")[0] == GOAL_CONTROLLER}
    return [GOAL_CONFIG, *sorted(mine - {GOAL_CONFIG})]


def goals(
    cells: Sequence[CellScore],
    pts: dict[str, dict[str, tuple[float, float]]],
    nuis: dict[str, tuple[int, int]],
    config: str = GOAL_CONFIG,
) -> dict[str, Any]:
    """The goals of the study, measured (None where the sweep did not cover them).

    - ``green_obstructed``: every run cell of CPNCO and CBNAO green for ``config``;
    - ``not_below_los``: ``config`` scores at least the LOS AEB's points in every scenario;
    - ``no_nuisance``: no configuration braked in a true-negative run.
    """
    mine = [c for c in cells if c.config == config and c.scenario in GOAL_SCENARIOS]
    not_green = [c.cell for c in mine if c.band != "green"]
    ours, los = pts.get(config), pts.get("los")
    below = (
        None
        if ours is None or los is None
        else [s for s in los if s in ours and ours[s][0] < los[s][0] - 1e-9]
    )
    return {
        "config": config,
        "green_obstructed": None if not mine else not not_green,
        "not_green": not_green,
        "not_below_los": None if below is None else not below,
        "below_los": below or [],
        "no_nuisance": None if not nuis else all(n == 0 for n, _ in nuis.values()),
        "nuisance": {k: list(v) for k, v in nuis.items()},
    }
