"""Which backend owns a vehicle now and lately; the deployment's processes run behind the
simulator's priority when told to."""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
from pathlib import Path

import pytest

from rfsas_hw.city.live import LiveConfig, deployment_process
from rfsas_hw.city.owners import VehicleOwners

sys.path.insert(0, str(Path(__file__).parent))
from childhelp import answer_nice


def test_a_backend_owns_a_vehicle_in_its_tile_and_for_the_memory_after_it_left() -> None:
    owners = VehicleOwners(memory_s=1.0)
    owners.update(0.1, ["car", "bus"], ["be-1", "be-2"], ["q1", "q2"])
    owners.update(0.2, ["car", "bus"], ["be-1", "be-2"], ["q1", "q2"])
    assert owners.owns("be-1", "car") and not owners.owns("be-2", "car")
    assert owners.tiles("car") == ("q1",)
    # the car crosses into be-2's tile q3 at 0.3 s: be-1 saw it last at 0.2 s
    owners.update(0.3, ["car", "bus"], ["be-2", "be-2"], ["q3", "q2"])
    assert owners.owns("be-2", "car") and owners.owns("be-1", "car")
    assert owners.tiles("car") == ("q1", "q3")
    owners.update(1.2, ["car", "bus"], ["be-2", "be-2"], ["q3", "q2"])
    assert owners.owns("be-1", "car")  # 1.0 s after 0.2 s: still within the memory
    owners.update(1.3, ["car", "bus"], ["be-2", "be-2"], ["q3", "q2"])
    assert not owners.owns("be-1", "car") and owners.tiles("car") == ("q3",)
    assert not owners.owns("be-1", "bus") and not owners.owns("be-1", "unknown")


def test_a_vehicle_back_in_a_tile_it_left_has_it_once_and_a_tile_nobody_owns_has_no_owner() -> None:
    owners = VehicleOwners(memory_s=1.0)
    owners.update(0.1, ["car"], ["be-1"], ["q1"])
    owners.update(0.2, ["car"], ["be-2"], ["q2"])
    owners.update(0.3, ["car"], ["be-1"], ["q1"])
    assert owners.tiles("car") == ("q2", "q1")
    owners.update(0.4, ["car"], [None], ["q9"])
    assert owners.tiles("car") == ("q2", "q1", "q9")
    assert owners.owns("be-1", "car") and owners.owns("be-2", "car")
    assert not owners.owns("be-1", "car", t_s=1.5)


def test_the_deployments_processes_take_the_nice_value_they_are_given() -> None:
    ctx = mp.get_context("spawn")
    base = os.nice(0)
    for nice in (0, 3):
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=deployment_process, args=(answer_nice, nice, None, child))
        proc.start()
        child.close()
        try:
            assert parent.poll(60.0), "the child did not answer"
            assert parent.recv() == min(base + nice, 19)
        finally:
            parent.close()
            proc.join(30.0)
    with pytest.raises(ValueError, match="nice"):
        LiveConfig(nice=20)
