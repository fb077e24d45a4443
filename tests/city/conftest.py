"""Small generated districts for the city tests (SUMO's netgenerate from the wheel)."""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from rfsas_hw.city.net import sumo_binary, sumo_env

CITY = "needs the city extra: pip install 'rfsas-hw[city]'"


def make_grid(path: Path, number: int = 3, length_m: float = 120.0) -> Path:
    """A ``number`` × ``number`` grid of traffic-light junctions, ``length_m`` apart, with
    sidewalks and crossings, written to ``path``."""
    cmd = [
        str(sumo_binary("netgenerate")),
        "--grid",
        f"--grid.number={number}",
        f"--grid.length={length_m}",
        "--grid.attach-length=60",
        "--default.junctions.type=traffic_light",
        "--sidewalks.guess",
        "--crossings.guess",
        "--no-turnarounds",
        "--seed=1",
        "-o",
        str(path),
    ]
    subprocess.run(cmd, env=sumo_env(), check=True, capture_output=True, timeout=60)
    return path


@pytest.fixture(scope="session")
def grid_net(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3 × 3 grid of signalised junctions 120 m apart, with sidewalks and crossings."""
    pytest.importorskip("sumo", reason=CITY)
    pytest.importorskip("sumolib", reason=CITY)
    return make_grid(tmp_path_factory.mktemp("grid") / "grid3.net.xml")


@pytest.fixture(scope="session")
def grid_factory(tmp_path_factory: pytest.TempPathFactory) -> Callable[[int, float], Path]:
    """Make other grids: ``grid_factory(number, length_m)`` → the net's path."""
    pytest.importorskip("sumo", reason=CITY)
    pytest.importorskip("sumolib", reason=CITY)

    def make(number: int, length_m: float) -> Path:
        folder = tmp_path_factory.mktemp("grid")
        return make_grid(folder / f"grid{number}.net.xml", number, length_m)

    return make
