"""The run's SUMO command: SUMO's own collision check is off, and the traffic is the same
as with it on (it only warned; the scorer finds the collisions itself)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.city.demand import DemandConfig, generate
from rfsas_hw.city.net import read_net, sumo_home
from rfsas_hw.city.run import CityRunConfig, sumo_command

libsumo = pytest.importorskip(
    "libsumo", reason="needs the city extra: pip install 'rfsas-hw[city]'"
)

WARN = ["--collision.action", "warn", "--collision.check-junctions", "true"]


def _trajectories(cmd: list[str], steps: int) -> tuple[list[np.ndarray], int]:
    """Every vehicle's and person's position after each step, and how many vehicles SUMO
    saw colliding in all."""
    libsumo.start(cmd)
    try:
        out, colliding = [], 0
        for _ in range(steps):
            libsumo.simulationStep()
            colliding += libsumo.simulation.getCollidingVehiclesNumber()
            rows = [(v, *libsumo.vehicle.getPosition(v)) for v in libsumo.vehicle.getIDList()]
            rows += [(p, *libsumo.person.getPosition(p)) for p in libsumo.person.getIDList()]
            out.append(np.array(sorted(rows), dtype=object))
        return out, colliding
    finally:
        libsumo.close()


def test_without_sumos_collision_check_the_traffic_is_the_same(
    grid_net: Path, tmp_path: Path
) -> None:
    os.environ.setdefault("SUMO_HOME", str(sumo_home()))
    # everyone reckless: SUMO sees collisions, so its check had something to act on
    demand_cfg = DemandConfig(
        vehicles=150, pedestrians=200, bicycles=80, end_s=30.0, reckless_share=1.0
    )
    cfg = CityRunConfig(net=grid_net, demand=demand_cfg, duration_s=60.0, seed=1)
    demand = generate(grid_net, tmp_path / "demand", demand_cfg, cfg.seed)
    cmd = sumo_command(cfg, read_net(grid_net), demand)
    assert "warn" not in cmd and "--collision.check-junctions" not in cmd
    run, seen = _trajectories(cmd, 600)
    assert seen == 0  # the check is off
    base = [c for c in cmd if c not in ("--collision.action", "none")]
    checked, seen_checked = _trajectories(base + WARN, 600)
    assert seen_checked > 0, "no collision on this seed: the comparison would prove nothing"
    assert len(run) == len(checked)
    for a, b in zip(run, checked, strict=True):
        assert a.shape == b.shape and (a == b).all()
