"""Scenario files: the example loads; mistakes are named with the file and key path."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rfsas_hw.errors import ConfigError
from rfsas_hw.rf.channels import channel_to_freq_mhz
from rfsas_hw.twin.scenario import (
    SCHEMA_VERSION,
    load_scenario,
    parse_utc_ns,
    scenario_from_mapping,
)

from .conftest import EXAMPLE, small_mapping


def test_example_loads_with_its_parts(example) -> None:
    spec = example.spec
    assert spec.version == SCHEMA_VERSION
    assert {s.id for s in spec.sensors} == {"rsu-nw", "car-obu"}
    assert example.calibration_path("rsu-nw") == EXAMPLE.parent / "calibration" / "rsu-nw.yaml"
    assert example.mover("car").waypoints[0].speed_mps == 20.0
    assert example.t0_ns == 1_767_268_800 * 10**9


def _write(tmp_path: Path, data: dict) -> Path:
    p = tmp_path / "scenario.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def test_unknown_key_is_named_with_file_and_path(tmp_path: Path) -> None:
    data = small_mapping()
    data["sensors"][0]["antena"] = {}
    p = _write(tmp_path, data)
    with pytest.raises(ConfigError, match=r"scenario\.yaml: sensors\[0\]: unknown key 'antena'"):
        load_scenario(p)


def test_nested_unknown_key(tmp_path: Path) -> None:
    data = small_mapping()
    data["emitters"][1]["traffic"][0]["intervall_s"] = 1
    where = r"emitters\[1\]\.traffic\[0\]: unknown key 'intervall_s'"
    with pytest.raises(ConfigError, match=where):
        load_scenario(_write(tmp_path, data))


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.update(version=2), r"version: scenario format 2"),
        (lambda d: d["emitters"][1].update(carried_by="nobody"), r"carried_by: no mover 'nobody'"),
        (lambda d: d["emitters"][1].update(mac="02:00:00:00:00:0a"), r"is also emitter 'ap'"),
        (lambda d: d["emitters"][1].update(mac="not-a-mac"), r"emitters\[1\]\.mac"),
        (lambda d: d["emitters"][1].update(tx_power_dbm=29), r"EIRP"),
        (lambda d: d["emitters"][1].update(tech="ble"), r"does not fit tech ble"),
        (lambda d: d["emitters"][0].update(position=None), r"exactly one of carried_by"),
        (lambda d: d["sensors"][0].update(pose=None), r"roadside sensor needs pose"),
        (lambda d: d["movers"][0]["waypoints"][0].update(speed_mps=0), r"speed_mps: must be"),
        (lambda d: d.update(start_utc="2026-01-01T00:00:00"), r"no time zone"),
        (lambda d: d["sensors"][0].update(scan={"channels": []}), r"at least one channel"),
        (lambda d: d["emitters"][1]["traffic"][0].update(channels=[15]), r"not a Wi-Fi channel"),
        (lambda d: d["sensors"][0].update(receiver="sdr"), r"'sdr' is not one of"),
    ],
)
def test_bad_values_are_rejected(change, message) -> None:
    data = small_mapping()
    change(data)
    with pytest.raises(ConfigError, match=message):
        scenario_from_mapping(data, "small.yaml")


def test_missing_file_and_bad_yaml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_scenario(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: [1\n")
    with pytest.raises(ConfigError, match="invalid YAML"):
        load_scenario(bad)


def test_channel_frequencies() -> None:
    assert channel_to_freq_mhz(1) == 2412
    assert channel_to_freq_mhz(6) == 2437
    assert channel_to_freq_mhz(14) == 2484
    assert channel_to_freq_mhz(36) == 5180
    assert channel_to_freq_mhz(37, "ble") == 2402
    assert channel_to_freq_mhz(39, "ble") == 2480
    assert channel_to_freq_mhz(0, "ble") == 2404
    assert channel_to_freq_mhz(11, "ble") == 2428


def test_parse_utc() -> None:
    assert parse_utc_ns("1970-01-01T00:00:01.5Z") == 1_500_000_000
    assert parse_utc_ns("1970-01-01T01:00:00+01:00") == 0
