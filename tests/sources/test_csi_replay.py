"""``rfsas replay csi:…``: bearings from CSI captures and the inter-chain phase in the summary."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.df.interferometer import C_MPS
from rfsas_hw.twin.csi_writer import CsiArray, synth_csi, write_feitcsi

_load_commands()
DATA = Path(__file__).resolve().parents[1] / "data" / "csi"
REPO = Path(__file__).resolve().parents[2]
CAL = REPO / "calibration" / "example_cal.yaml"
STILL = ["--prove-motion", "0"]
"""The transmitters of these CSI files stand still: on a fixed mount the motion rule would
refuse all their bearings, and these tests check the CSI path."""


def _replay(spec: str, out: Path) -> str:
    result = CliRunner().invoke(
        cli,
        ["replay", spec, *STILL, "--calibration", str(CAL), "--out", str(out)],
        catch_exceptions=False,
    )
    assert result.exit_code == 0, result.output
    return result.output


@pytest.mark.extra("csi")
def test_replay_reports_the_atheros_phase_spread(tmp_path: Path) -> None:
    text = _replay(f"csi:{DATA / 'ath_csi_1.dat'}?rssi_offset=-95", tmp_path / "b.jsonl")
    rows = {
        line.split("│")[1].strip(): line.split("│")[2].strip()
        for line in text.splitlines()
        if line.count("│") >= 3
    }
    assert rows["frames read"] == "401"
    assert rows["csi format"] == "atheros"
    assert float(rows["phase std deg 0 1"]) == 7.58
    assert float(rows["phase std deg 0 2"]) == 15.58
    # 40 frames near −33° have a ±3σ reaching past the −45° edge of the example
    # table's field of view: refused as possibly from outside it (the edge rule)
    assert rows["no bearing: may_be_outside"] == "40"
    assert rows["bearings"] == "361"


def test_replay_of_a_twin_csi_capture(tmp_path: Path) -> None:
    lam = C_MPS / 2437e6
    array = CsiArray(baseline_m=lam / 2)
    n = 200
    theta = np.linspace(-20, 20, n)
    h = synth_csi(array, theta, 2437, np.full((n, 2), 30.0), seed=2)
    rssi = np.column_stack([-55 - theta / 5, -55 + theta / 5]).round()
    path = tmp_path / "twin.csi"
    write_feitcsi(path, np.arange(n) * 10_000_000, np.full(n, 0x020000000001), rssi, h)
    out = tmp_path / "b.jsonl"
    _replay(f"csi:{path}?freq=2437", out)
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(lines) == n and {b["channel"] for b in lines} == {6}


def test_replay_with_a_phase_calibration_gives_interferometer_bearings(tmp_path: Path) -> None:
    import dataclasses

    from rfsas_hw.df import load_calibration, save_calibration
    from rfsas_hw.df.phasecal import PhaseCalibration, PhaseOffset, PhasePair

    lam = C_MPS / 2437e6
    array = CsiArray(baseline_m=lam / 2, phase_offset_deg=25.0)
    n = 300
    theta = np.linspace(-30, 30, n)
    h = synth_csi(array, theta, 2437, np.full((n, 2), 30.0), seed=3)
    rssi = np.column_stack([-55 - theta / 5, -55 + theta / 5]).round()
    path = tmp_path / "twin.csi"
    write_feitcsi(path, np.arange(n) * 10_000_000, np.full(n, 0x020000000001), rssi, h)
    phase = PhaseCalibration((PhasePair(0, 1, lam / 2, (PhaseOffset(6, 25.0),)),))
    cal_path = tmp_path / "cal-phase.yaml"
    save_calibration(dataclasses.replace(load_calibration(CAL), phase=phase), cal_path)
    out = tmp_path / "b.jsonl"
    result = CliRunner().invoke(
        cli,
        [
            "replay",
            f"csi:{path}?freq=2437",
            *STILL,
            "--calibration",
            str(cal_path),
            "--out",
            str(out),
        ],
        catch_exceptions=False,
    )
    assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == n
    rel = np.array([r["relative_deg"] for r in rows])
    sigma = np.array([r["sigma_deg"] for r in rows])
    # interferometer precision at 30 dB per subcarrier: a few hundredths of a degree
    assert np.all(sigma < 0.2)
    assert np.all(np.abs(rel - theta) < 5 * sigma)
