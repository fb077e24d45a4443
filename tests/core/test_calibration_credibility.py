"""Sweeps and calibration tables that are well-formed but not credible are refused (or
warned about, loudly) by ``rfsas calibrate`` and by ``load_calibration``."""

from __future__ import annotations

import copy
import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from rfsas_hw.df import load_calibration, read_samples_csv, write_samples_csv
from rfsas_hw.df.validate import check_samples
from rfsas_hw.errors import CalibrationError
from rfsas_hw.rf.synth import TurntableSamples

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests" / "cli"))

from clihelp import run  # noqa: E402

SWEEP = REPO / "calibration" / "example_turntable.csv"
CAL = REPO / "calibration" / "example_cal.yaml"


def _sweep(tmp_path: Path, name: str, change: Any) -> Path:
    s = read_samples_csv(SWEEP)
    a, r1, r2, ch = change(s.angle_deg.copy(), s.rssi1_dbm.copy(), s.rssi2_dbm.copy(), s.channel)
    path = tmp_path / f"{name}.csv"
    write_samples_csv(path, TurntableSamples(a, r1, r2, ch))
    return path


def _sentinels(a, r1, r2, ch):  # type: ignore[no-untyped-def]
    r2[::7] = -128.0  # a chain that often reports "no reading"
    return a, r1, r2, ch


def _ten(a, r1, r2, ch):  # type: ignore[no-untyped-def]
    return a[:10], r1[:10], r2[:10], ch[:10]


def _no_boresight(a, r1, r2, ch):  # type: ignore[no-untyped-def]
    keep = a > 5
    return a[keep], r1[keep], r2[keep], ch[keep]


def _times_ten(a, r1, r2, ch):  # type: ignore[no-untyped-def]
    return a * 10, r1, r2, ch  # ±900° from a unit mix-up


def _swapped(a, r1, r2, ch):  # type: ignore[no-untyped-def]
    return a, r2, r1, ch


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        (_sentinels, "sentinels"),
        (_ten, "10 samples"),
        (_no_boresight, "misses boresight"),
        (_times_ten, "angles reach 900°"),
    ],
)
def test_calibrate_refuses_a_sweep_that_is_not_credible(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], change: Any, needle: str
) -> None:
    sweep = _sweep(tmp_path, change.__name__, change)
    out = tmp_path / "cal.yaml"
    code, _, err = run(["calibrate", str(sweep), "-o", str(out)], capsys)
    assert code == 2 and needle in err and "refused" in err, err
    assert not out.exists()


def test_swapped_antennas_are_warned_about_loudly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sweep = _sweep(tmp_path, "swapped", _swapped)
    out = tmp_path / "cal.yaml"
    code, _, err = run(["calibrate", str(sweep), "-o", str(out)], capsys)
    assert code == 0, err
    assert "warning" in err and "swapped" in err
    assert out.exists()  # a warning: the table may be right if the sensor is wired alike


def test_a_nan_noise_floor_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(
        ["calibrate", str(SWEEP), "-o", str(tmp_path / "c.yaml"), "--noise-floor", "nan"], capsys
    )
    assert code == 2 and "finite" in err
    findings = check_samples(read_samples_csv(SWEEP), "s.csv", noise_floor_dbm=float("nan"))
    assert [f.level for f in findings] == ["error"] and "noise floor" in str(findings[0])


def _table_file(tmp_path: Path, edit: Any) -> Path:
    doc = yaml.safe_load(CAL.read_text())
    table = copy.deepcopy(doc["tables"][0])
    edit(doc, table)
    doc["tables"][0] = table
    path = tmp_path / "edited.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _psi_beyond_one(doc: dict[str, Any], t: dict[str, Any]) -> None:
    t["psi"] = [3.0 * p for p in t["psi"]]


def _grid_900(doc: dict[str, Any], t: dict[str, Any]) -> None:
    t["grid_deg"] = [10.0 * g for g in t["grid_deg"]]
    t["fov_deg"] = [10.0 * f for f in t["fov_deg"]]


def _fov_2(doc: dict[str, Any], t: dict[str, Any]) -> None:
    t["fov_deg"] = [-1.0, 1.0]


def _kd_far(doc: dict[str, Any], t: dict[str, Any]) -> None:
    t["k_d"] = 0.0043  # what a sweep with −128 dBm sentinels gave


def _noise_floor_positive(doc: dict[str, Any], t: dict[str, Any]) -> None:
    doc["receiver"]["noise_floor_dbm"] = 5.0


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (_psi_beyond_one, "|ψ| reaches"),
        (_grid_900, "angles reach 900°"),
        (_fov_2, "2.0° wide"),
        (_kd_far, "dB apart"),
        (_noise_floor_positive, "not a noise floor"),
    ],
)
def test_load_calibration_refuses_a_table_that_is_not_credible(
    tmp_path: Path, edit: Any, needle: str
) -> None:
    path = _table_file(tmp_path, edit)
    with pytest.raises(CalibrationError, match="refused") as info:
        load_calibration(path)
    assert needle in str(info.value) and str(path) in str(info.value)


def test_a_lopsided_field_of_view_is_logged(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    def lopsided(doc: dict[str, Any], t: dict[str, Any]) -> None:
        t["fov_deg"] = [5.0, 45.0]

    path = _table_file(tmp_path, lopsided)
    with caplog.at_level(logging.WARNING):
        load_calibration(path)
    assert "lopsided field of view" in caplog.text


def test_a_replay_with_a_table_that_is_not_credible_is_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _table_file(tmp_path, _psi_beyond_one)
    code, _, err = run(
        ["replay", "x.pcap", "--calibration", str(path), "--out", str(tmp_path / "b.jsonl")],
        capsys,
    )
    assert code == 2 and "|ψ|" in err and "Traceback" not in err


def test_the_shipped_files_are_credible() -> None:
    assert not check_samples(read_samples_csv(SWEEP))
    cal = load_calibration(CAL)
    assert np.all(np.abs(cal.tables[0].psi) < 1)


def test_a_check_leaves_sentinel_rows_out_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    check = _sweep(tmp_path, "check", _sentinels)
    code, _, err = run(["calibrate", "--check", str(CAL), str(check), "--json"], capsys)
    assert code in (0, 1) and "rows with sentinel readings" in err and "left out" in err
