"""Shared fixtures for the digital-twin tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from rfsas_hw.twin.scenario import Scenario, load_scenario, scenario_from_mapping

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "crossing.yaml"


@pytest.fixture(scope="session")
def example() -> Scenario:
    """The bundled demo scenario."""
    return load_scenario(EXAMPLE)


def small_mapping(**overrides: Any) -> dict[str, Any]:
    """A small scenario: one AP, one walking phone, a roadside 2-chain sensor."""
    data: dict[str, Any] = {
        "version": 1,
        "name": "small",
        "seed": 5,
        "duration_s": 3.0,
        "intersection": {
            "buildings": [{"x_min_m": 10, "x_max_m": 30, "y_min_m": -30, "y_max_m": -10}]
        },
        "movers": [
            {
                "id": "walker",
                "kind": "pedestrian",
                "waypoints": [
                    {"x_m": 20, "y_m": -5, "speed_mps": 1.5},
                    {"x_m": -5, "y_m": -5},
                ],
            }
        ],
        "emitters": [
            {
                "id": "ap",
                "mac": "02:00:00:00:00:0a",
                "tech": "wifi",
                "position": [15.0, 15.0],
                "traffic": [{"model": "beacon", "channels": [6]}],
            },
            {
                "id": "phone",
                "mac": "02:00:00:00:00:0b",
                "tech": "wifi",
                "carried_by": "walker",
                "tx_power_dbm": 20,
                "traffic": [{"model": "data-bursts", "channels": [6], "interval_s": 0.2}],
            },
        ],
        "sensors": [
            {
                "id": "rsu",
                "kind": "roadside",
                "pose": {"x_m": -10, "y_m": 0, "heading_deg": 90},
                "driver": {"chain_drop_prob": 0.05},
            }
        ],
    }
    data.update(overrides)
    return data


def small(**overrides: Any) -> Scenario:
    """:func:`small_mapping` as a loaded scenario."""
    return scenario_from_mapping(small_mapping(**overrides), "small.yaml")
