"""The bridge runs the real chain and keeps the truth out of the backend."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.bridges.bridge import Bridge, Entity
from rfsas_hw.bridges.config import (
    BACKEND_PROFILES,
    backend_config,
    bridge_config_from_mapping,
    load_bridge_config,
)
from rfsas_hw.errors import ConfigError, SimulationError

from .helpers import UNITS, config_data, drive


def test_unknown_keys_and_bad_values_are_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="unknown key 'unitz'"):
        bridge_config_from_mapping({"unitz": []}, "units.yaml")
    with pytest.raises(ConfigError, match=r"units\[0\].pose: unknown key 'heading'"):
        bridge_config_from_mapping(
            {"units": [{"id": "a", "pose": {"x_m": 0, "y_m": 0, "heading": 0}}]}, "u"
        )
    with pytest.raises(ConfigError, match="unknown entity kind 'dog'"):
        bridge_config_from_mapping(config_data(devices={"dog": {"model": "phone-idle"}}), "u")
    with pytest.raises(ConfigError, match="device model 'pager' is not known"):
        bridge_config_from_mapping(config_data(devices={"pedestrian": {"model": "pager"}}), "u")
    with pytest.raises(ConfigError, match="penetration must be in"):
        bridge_config_from_mapping(
            config_data(devices={"pedestrian": {"model": "phone-idle", "penetration": 1.5}}), "u"
        )
    with pytest.raises(ConfigError, match="backend_profile 'rural'"):
        bridge_config_from_mapping(config_data(backend_profile="rural"), "u")
    with pytest.raises(ConfigError, match="at least two units"):
        bridge_config_from_mapping({"units": [], "ego_unit": {}}, "u")
    path = tmp_path / "units.yaml"
    path.write_text("units: [\n")
    with pytest.raises(ConfigError, match="invalid YAML"):
        load_bridge_config(path)


def test_urban_profile_accepts_close_in_fixes() -> None:
    cfg = bridge_config_from_mapping(config_data(), "u")
    urban = backend_config(cfg)
    assert urban.triangulation.max_range_fraction == pytest.approx(0.3)
    assert BACKEND_PROFILES["backend-defaults"].triangulation.max_range_fraction == 0.1
    assert urban.encounter.reaction_s >= 0.2


def test_locates_the_pedestrian_and_keeps_truth_apart(tmp_path: Path) -> None:
    cfg = bridge_config_from_mapping(config_data(), "u")
    truth = tmp_path / "truth.jsonl"
    with Bridge(cfg, truth_path=truth) as bridge:
        steps = drive(bridge)
        fixes = [(s.t_ns, f) for s in steps for f in s.fixes if f.ok]
        assert len(fixes) >= 10
        errors = []
        for t_ns, f in fixes:
            assert bridge.entity_of(f.emitter, t_ns) == "p1"
            t = (f.t_ns - bridge.t0_ns) / 1e9
            errors.append(np.hypot(f.x_m - (-10.0 + 1.4 * t), f.y_m + 4.0))
        # a pedestrian 5–15 m from three units: fixes within a few metres
        assert float(np.median(errors)) < 3.0
        assert {s.advisory for s in steps} & {"caution", "brake", "clear"}
        assert bridge.device_of("p1") == "phone-active"
        assert bridge.device_of("car") is None
    lines = [json.loads(x) for x in truth.read_text().splitlines()]
    device = next(x for x in lines if x["record"] == "device")
    assert device["entity"] == "p1" and device["kind"] == "pedestrian"
    # a randomised MAC: locally administered bit set
    assert int(device["mac"].split(":")[0], 16) & 0x02
    assert device["emitter"] == fixes[0][1].emitter


def test_penetration_zero_gives_no_device() -> None:
    cfg = bridge_config_from_mapping(
        config_data(devices={"pedestrian": {"model": "phone-active", "penetration": 0.0}}), "u"
    )
    with Bridge(cfg) as bridge:
        steps = drive(bridge, steps=10)
    assert bridge.stats.devices == 0
    assert all(len(b) == 0 for s in steps for b in s.bearings.values())
    assert all(s.advisory == "none" for s in steps)


def test_same_seed_same_run_other_seed_differs() -> None:
    def run(seed: int) -> list[tuple[float, float]]:
        with Bridge(bridge_config_from_mapping(config_data(seed=seed), "u")) as bridge:
            return [(f.x_m, f.y_m) for s in drive(bridge, steps=20) for f in s.fixes]

    assert run(4) == run(4)
    assert run(4) != run(5)


def test_mac_rotation_makes_new_emitters() -> None:
    cfg = bridge_config_from_mapping(config_data(mac={"randomise": True, "rotate_s": 1.0}), "u")
    with Bridge(cfg) as bridge:
        steps = drive(bridge, steps=25)
    emitters = {f.emitter for s in steps for f in s.fixes}
    assert bridge.stats.devices == 3 and len(emitters) >= 2


def test_bad_steps_are_refused() -> None:
    cfg = bridge_config_from_mapping(config_data(), "u")
    with Bridge(cfg) as bridge:
        car = Entity("car", "vehicle", 0.0, -50.0, 0.0, 10.0, 4.5, 1.8)
        bridge.step(0.0, car, [])
        with pytest.raises(SimulationError, match="not after the previous"):
            bridge.step(0.0, car, [])
        ped = Entity("p", "pedestrian", 0.0, 0.0, 0.0)
        with pytest.raises(SimulationError, match="appears twice"):
            bridge.step(0.1, car, [ped, ped])
        with pytest.raises(SimulationError, match="reserved"):
            bridge.step(0.2, car, [Entity("ego", "pedestrian", 0.0, 0.0, 0.0)])


def test_a_units_site_floor_widens_its_bearings_sigma() -> None:
    """``env_floor_deg`` replaces the calibration's environment floor, so every bearing's
    σ covers it; without it the turntable fit's (free-space) σ stays."""
    with pytest.raises(ConfigError, match=r"'rsu-nw'.*env_floor_deg"):
        units = [dict(UNITS[0], env_floor_deg=-1.0), *UNITS[1:]]
        bridge_config_from_mapping(config_data(units=units), "u")
    floor = 6.0
    plain = bridge_config_from_mapping(config_data(), "u")
    units = [dict(u, env_floor_deg=floor) for u in UNITS]
    floored = bridge_config_from_mapping(
        config_data(units=units, ego_unit={"env_floor_deg": floor}), "u"
    )
    sigmas: dict[bool, list[float]] = {}
    for with_floor, cfg in ((False, plain), (True, floored)):
        with Bridge(cfg) as bridge:
            tables = [t for c in bridge.calibrations.values() for t in c.tables]
            assert all((t.env_floor_deg == floor) == with_floor for t in tables)
            sigmas[with_floor] = [
                float(s) for r in drive(bridge) for b in r.bearings.values() for s in b.sigma_deg
            ]
    assert sigmas[False] and sigmas[True]
    assert min(sigmas[False]) < floor <= min(sigmas[True])
