"""RF-SAS on the test track: deployments, devices, parked vehicles in the radio model."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.ncap.rfsas import RSU_POSE, SITE_FLOOR_DEG, bridge_config
from rfsas_hw.ncap.scenarios import PARKED_LOSS_DB, VAN_LOSS_DB, Cell, plan
from rfsas_hw.twin.rfworld import blockage_db, building_array


def test_deployments_and_devices() -> None:
    obstacles = plan(Cell("CPNCO", 30.0, 0.5)).obstacles
    both = bridge_config("car+rsu", "phone-idle", 7, obstacles)
    assert [u.pose for u in both.units] == [RSU_POSE] and both.ego_unit is not None
    assert both.seed == 7
    # both units carry the track's measured floor, not the turntable's free space
    assert both.units[0].env_floor_deg == both.ego_unit.env_floor_deg == SITE_FLOOR_DEG > 0
    assert both.devices["pedestrian"].model == "phone-idle"
    assert both.devices["cyclist"].penetration == 1.0
    car = bridge_config("car", "phone-active", 0, obstacles)
    assert car.units == () and car.ego_unit is not None
    with pytest.raises(ValueError, match="unknown deployment"):
        bridge_config("drone", "phone-active", 0, ())  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="unknown device"):
        bridge_config("car", "pager", 0, ())


def test_parked_vehicles_attenuate_a_path_through_them() -> None:
    obstacles = plan(Cell("CBNAO", 30.0, 0.5)).obstacles
    cfg = bridge_config("car+rsu", "phone-active", 0, obstacles)
    assert not cfg.buildings_from_simulator
    rects = building_array(list(cfg.buildings))
    child = np.array([[0.0, -4.9]])
    # from far up the road the path to the hidden rider crosses the van (and the car)
    loss, hit = blockage_db(np.array([[-40.0, 0.0]]), child, rects)
    assert hit[0] and loss[0] >= VAN_LOSS_DB
    # the roadside unit across the road sees it past the parked vehicles' front
    loss, hit = blockage_db(np.array([[RSU_POSE.x_m, RSU_POSE.y_m]]), child, rects)
    assert not hit[0] and loss[0] == 0.0
    assert {b.loss_db for b in cfg.buildings} == {PARKED_LOSS_DB, VAN_LOSS_DB}
