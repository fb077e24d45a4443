"""A BLE array sensor end to end in the twin: the world's frames as IQ reports of an
8-element circular array, read back by bleiq: and turned into bearings by rfsas replay."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.df import load_calibration, save_calibration
from rfsas_hw.df.arraycal import ArrayCalibration, ElementCalibration
from rfsas_hw.errors import SimulationError
from rfsas_hw.sources import open_source
from rfsas_hw.sources.ble_iq import ble_channel_mhz
from rfsas_hw.sources.twin_bleiq import BleArray, write_sensor_bleiq
from rfsas_hw.twin.scenario import scenario_from_mapping
from rfsas_hw.twin.world import World

REPO = Path(__file__).resolve().parents[2]
ANGLES = (-160.0, -110.0, -60.0, -15.0, 30.0, 75.0, 120.0, 175.0)
HEADING = 30.0
_load_commands()


def _world() -> World:
    sc = scenario_from_mapping(
        {
            "version": 1,
            "name": "ble-array",
            "seed": 5,
            "duration_s": 3.0,
            "emitters": [
                {
                    "id": f"e{i}",
                    "mac": f"02:00:00:00:01:{i:02x}",
                    "tech": "wifi",
                    "tx_power_dbm": 20.0,
                    "position": [
                        15 * math.sin(math.radians(a + HEADING)),
                        15 * math.cos(math.radians(a + HEADING)),
                    ],
                    "traffic": [{"model": "beacon", "channels": [6]}],
                }
                for i, a in enumerate(ANGLES)
            ],
            "sensors": [
                {
                    "id": "ble-array",
                    "kind": "roadside",
                    "pose": {"x_m": 0.0, "y_m": 0.0, "heading_deg": HEADING},
                    "antenna": {"squint_deg": 15.0, "beamwidth_deg": 60.0},
                }
            ],
        },
        "<test>",
    )
    return World(sc)


def test_the_twin_runs_a_ble_array_sensor_end_to_end(tmp_path: Path) -> None:
    world = _world()
    array = BleArray.uca(8, 0.6)
    capture = tmp_path / "ble-array.btsnoop"
    rows = write_sensor_bleiq(world, "ble-array", array, capture, seed=7)
    rec = world.receptions("ble-array")
    heard = set(rec.emitter[rows].tolist())
    assert heard == set(range(len(ANGLES))), heard  # emitters all round, behind included
    with open_source(f"bleiq:{capture}?elements=8") as src:
        batch = next(iter(src))
    assert len(batch) == len(rows)
    # the frames' times, to the µs btsnoop keeps
    np.testing.assert_array_equal(batch.t_ns, rec.t_ns[rows] // 1000 * 1000)
    assert set(batch.mac.tolist()) == {e + 1 for e in heard}  # sync handles
    # the sensor pipeline: a calibration with the array, rfsas replay, compass bearings
    base = load_calibration(REPO / "calibration" / "example_cal.yaml")
    freq = ble_channel_mhz(array.channel_index)
    ideal = ElementCalibration(np.zeros(8), np.zeros(8))
    cal_path = tmp_path / "array.yaml"
    save_calibration(
        dataclasses.replace(base, array=ArrayCalibration(array.geometry, ideal, freq)), cal_path
    )
    out = tmp_path / "bearings.jsonl"
    result = CliRunner().invoke(
        cli,
        [
            *("replay", f"bleiq:{capture}?elements=8", "--calibration", str(cal_path)),
            *("--pose", f"0,0,{HEADING}", "--out", str(out)),
        ],
        catch_exceptions=False,
    )
    assert result.exit_code == 0, result.output
    got = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(got) >= 0.98 * len(rows)
    by_time = {int(t) // 1000: i for i, t in enumerate(rec.t_ns[rows])}
    errors, sigmas = [], []
    for b in got:
        i = by_time[int(b["t_ns"]) // 1000]
        truth = rec.true_azimuth_deg[rows][i]
        errors.append((b["azimuth_deg"] - truth + 180.0) % 360.0 - 180.0)
        sigmas.append(b["sigma_deg"])
    err, sig = np.abs(np.array(errors)), np.array(sigmas)
    # every emitter, in front or behind: bearings within their own 4σ, all but a few
    assert np.mean(err <= 4.0 * sig) >= 0.99, (np.max(err / sig), np.median(sig))
    assert np.max(err) < 5.0
    assert not any(f"02:00:00:00:01:{i:02x}" in out.read_text() for i in range(len(ANGLES)))


def test_chain_errors_and_options_are_checked(tmp_path: Path) -> None:
    world = _world()
    bad = dataclasses.replace(BleArray.uca(8, 0.6), chain_phase_deg=(1.0, 2.0))
    with pytest.raises(SimulationError, match="8 values"):
        write_sensor_bleiq(world, "ble-array", bad, tmp_path / "x.btsnoop", seed=1)
    with pytest.raises(SimulationError, match="slot 3"):
        write_sensor_bleiq(
            world, "ble-array", dataclasses.replace(bad, slot_us=3), tmp_path / "x", seed=1
        )


def test_same_seed_same_bytes(tmp_path: Path) -> None:
    world = _world()
    array = dataclasses.replace(BleArray.uca(8, 0.6), chain_phase_deg=tuple(range(0, 80, 10)))
    a, b = tmp_path / "a.btsnoop", tmp_path / "b.btsnoop"
    write_sensor_bleiq(world, "ble-array", array, a, seed=3)
    write_sensor_bleiq(world, "ble-array", array, b, seed=3)
    assert a.read_bytes() == b.read_bytes()
