"""A small urban intersection for bridge tests: units on three corners, a building on the
south-west corner, a car coming north and a pedestrian crossing its lane."""

from __future__ import annotations

from typing import Any

from rfsas_hw.bridges.bridge import Bridge, Entity, StepResult

UNITS: list[dict[str, Any]] = [
    {"id": "rsu-nw", "pose": {"x_m": -9.0, "y_m": 9.0, "heading_deg": 160.0}},
    {"id": "rsu-ne", "pose": {"x_m": 9.0, "y_m": 9.0, "heading_deg": 200.0}},
    {"id": "rsu-se", "pose": {"x_m": 9.0, "y_m": -9.0, "heading_deg": 270.0}},
]
SW_BUILDING = {"x_min_m": -60, "x_max_m": -8, "y_min_m": -60, "y_max_m": -8, "name": "sw"}


def config_data(**overrides: Any) -> dict[str, Any]:
    """The bridge configuration as YAML would give it."""
    data: dict[str, Any] = {"seed": 1, "units": UNITS, "buildings": [SW_BUILDING]}
    data.update(overrides)
    return data


def drive(
    bridge: Bridge, *, steps: int = 40, ped_start_x: float = -10.0, ped_speed: float = 1.4
) -> list[StepResult]:
    """A car at 10 m/s from 60 m south; a pedestrian walking east along y = -4 m."""
    out = []
    for k in range(steps):
        t = 0.1 * k
        car = Entity("car", "vehicle", 1.75, -60.0 + 10.0 * t, 0.0, 10.0, 4.5, 1.8)
        ped = Entity("p1", "pedestrian", ped_start_x + ped_speed * t, -4.0, 90.0, ped_speed)
        out.append(bridge.step(t, car, [ped]))
    return out
