"""Typed configuration: unknown keys, types, precedence."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

from rfsas_hw.config import from_mapping, load
from rfsas_hw.errors import ConfigError


@dataclass
class Inner:
    dwell_s: float = 0.2


@dataclass
class Sensor:
    sensor_id: str
    mode: Literal["db", "linear"] = "linear"
    channels: list[int] = field(default_factory=list)
    min_snr_db: float | None = None
    scan: Inner = field(default_factory=Inner)


def test_types_are_converted_and_checked() -> None:
    s = from_mapping(Sensor, {"sensor_id": 7, "channels": [1, 6], "scan": {"dwell_s": "0.5"}})
    assert s.sensor_id == "7" and s.channels == [1, 6] and s.scan.dwell_s == 0.5
    with pytest.raises(ConfigError, match=r"cfg.channels\[1\]: expected an integer, got 'six'"):
        from_mapping(Sensor, {"sensor_id": "a", "channels": [1, "six"]}, "cfg")
    with pytest.raises(ConfigError, match=r"cfg.mode: 'log' is not one of"):
        from_mapping(Sensor, {"sensor_id": "a", "mode": "log"}, "cfg")


def test_unknown_and_missing_keys() -> None:
    with pytest.raises(ConfigError, match=r"cfg.scan: unknown key 'dwel_s'"):
        from_mapping(Sensor, {"sensor_id": "a", "scan": {"dwel_s": 1}}, "cfg")
    with pytest.raises(ConfigError, match="missing required key 'sensor_id'"):
        from_mapping(Sensor, {}, "cfg")


def test_precedence_cli_over_env_over_file(tmp_path: Path) -> None:
    path = tmp_path / "s.yaml"
    path.write_text("sensor:\n  sensor_id: file\n  min_snr_db: 3\n  mode: db\n")
    env = {"RFSAS_SENSOR_SENSOR_ID": "env", "RFSAS_SENSOR_MIN_SNR_DB": "5"}
    s = load(Sensor, path, section="sensor", environ=env, cli={"sensor_id": "cli", "mode": None})
    assert (s.sensor_id, s.min_snr_db, s.mode) == ("cli", 5.0, "db")


def test_bad_yaml_names_line(tmp_path: Path) -> None:
    path = tmp_path / "s.yaml"
    path.write_text("sensor:\n  sensor_id: [x\n")
    with pytest.raises(ConfigError, match=r"s.yaml: line \d+, column \d+: invalid YAML"):
        load(Sensor, path, section="sensor")
