"""Fitting, storing and checking calibration tables."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.df import (
    DfFlag,
    estimate,
    fit_calibration,
    fit_table,
    load_calibration,
    read_samples_csv,
    save_calibration,
)
from rfsas_hw.df.calfile import calibration_to_mapping
from rfsas_hw.df.check import check_calibration
from rfsas_hw.df.lut import lut_for
from rfsas_hw.errors import CalibrationError
from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, turntable_sweep

ANT = GaussianBeamPair(squint_deg=20.0, beamwidth_deg=45.0, front_to_back_db=25.0)
RX = ReceiverModel(measurement_floor_db=1.0, chain_offsets_db=(0.0, -1.5))


@pytest.fixture(scope="module")
def sweep():  # type: ignore[no-untyped-def]
    return turntable_sweep(np.arange(-90.0, 90.5, 1.0), 20, -50.0, ANT, RX, seed=11, channel=6)


@pytest.mark.parametrize("mode", ["linear", "db"])
def test_fit_finds_the_field_of_view_and_balance(sweep, mode: str) -> None:  # type: ignore[no-untyped-def]
    cal = fit_calibration(sweep, mode)  # type: ignore[arg-type]
    (table,) = cal.tables
    assert table.channel == 6
    # the weaker beam reaches its 25 dB floor 65.5° from its peak: FoV ≈ ±45.5°
    assert table.fov_deg[0] == pytest.approx(-45.0, abs=1.5)
    assert table.fov_deg[1] == pytest.approx(45.0, abs=1.5)
    # spread 1 dB plus rounding to 1 dB: sqrt(1 + 1/12) = 1.04 dB
    assert table.noise_db == pytest.approx(1.04, abs=0.05)
    if mode == "linear":
        # chain 1 is 1.5 dB weaker: K_D = 10^0.15 = 1.41 (boresight means of 20 readings)
        assert table.k_d == pytest.approx(10**0.15, rel=0.05)
    psi0 = np.interp(0.0, table.grid_deg, table.psi)
    assert abs(psi0) < 1e-9


def test_held_back_error_matches_predicted_sigma(sweep) -> None:  # type: ignore[no-untyped-def]
    cal = fit_calibration(sweep, "linear")
    check = turntable_sweep(np.arange(-44.25, 45.0, 2.5), 200, -50.0, ANT, RX, seed=12, channel=6)
    report = check_calibration(cal, check)
    # the edge rule refuses bearings whose ±3σ leaves the ±45° FoV: about 9° at each end
    assert 0.7 * report.inside_fov < report.valid < 0.9 * report.inside_fov
    # the acceptance: RMS error within 1.2× of what σ predicts
    assert report.consistent, report
    assert 1 / 1.2 <= report.ratio <= 1.2


def test_sigma_is_honest_at_lower_snr(sweep) -> None:  # type: ignore[no-untyped-def]
    cal = fit_calibration(sweep, "linear")
    # 25 dB weaker than on the turntable: the thermal term dominates near the edges
    check = turntable_sweep(np.arange(-30.0, 30.5, 2.0), 300, -75.0, ANT, RX, seed=13, channel=6)
    report = check_calibration(cal, check)
    assert report.consistent, report


def test_lookup_table_agrees_with_exact_inverse_interpolation(sweep) -> None:  # type: ignore[no-untyped-def]
    (table,) = fit_calibration(sweep, "linear").tables
    psi = np.linspace(table.psi.min(), table.psi.max(), 50_001)
    exact, outside = table.angle_of(psi)
    fast, _, outside_fast = lut_for(table, "db")(psi.astype(np.float32))
    inside = ~outside & ~outside_fast
    diff = np.abs(fast[inside] - exact[inside])
    # where ψ_D still has a usable slope (≥ 10 % of boresight's) they agree to 0.01°;
    # at the flat FoV edges (σ of many degrees) to within one grid step
    slope = np.abs(table.slope_at(exact[inside]))
    steep = slope >= 0.1 * np.abs(table.slope_at(np.array([0.0])))[0]
    assert np.max(diff[steep]) < 0.01
    assert np.max(diff) <= 0.5
    # and the published brute-force search lands within half a grid step
    brute = table.search_angle(psi[inside][::97])
    assert np.max(np.abs(brute - exact[inside][::97])) <= 0.25 + 1e-9


def test_flags() -> None:
    sweep = turntable_sweep(np.arange(-90.0, 90.5, 1.0), 10, -50.0, ANT, RX, seed=2, channel=6)
    cal = fit_calibration(sweep, "linear")
    r1 = np.array([np.nan, -5.0, -50.0, -20.0, -50.0, -95.0])
    r2 = np.array([-50.0, -50.0, -50.0, -60.0, -50.0, -95.0])
    ch = np.array([6, 6, 6, 6, 11, 6])
    res = estimate(cal, r1, r2, ch, min_snr_db=3.0)
    assert res.flags[0] & DfFlag.MISSING_CHAIN
    assert res.flags[1] & DfFlag.SATURATED
    assert res.flags[2] == 0 and res.valid[2]
    assert res.flags[3] & DfFlag.OUTSIDE_FOV  # 40 dB apart: beyond any angle in the FoV
    assert res.flags[4] & DfFlag.NO_TABLE
    assert res.flags[5] & DfFlag.LOW_SNR
    assert np.isnan(res.angle_deg[[0, 1, 3, 4, 5]]).all()


def test_file_round_trip(tmp_path: Path, sweep) -> None:  # type: ignore[no-untyped-def]
    cal = fit_calibration(sweep, "db", antenna={"description": "2x patch"})
    path = tmp_path / "cal.yaml"
    save_calibration(cal, path)
    again = load_calibration(path)
    assert again.mode == "db"
    assert calibration_to_mapping(again) == calibration_to_mapping(cal)
    r1, r2 = sweep.rssi1_dbm[:500], sweep.rssi2_dbm[:500]
    a = estimate(cal, r1, r2, sweep.channel[:500])
    b = estimate(again, r1, r2, sweep.channel[:500])
    assert np.allclose(a.angle_deg, b.angle_deg, equal_nan=True, atol=1e-4)


def _swap(values: list[float], i: int, j: int) -> None:
    values[i], values[j] = values[j], values[i]


def _write_cal(tmp_path: Path, sweep, edit) -> Path:  # type: ignore[no-untyped-def]
    import json

    import yaml

    doc = json.loads(json.dumps(calibration_to_mapping(fit_calibration(sweep, "linear"))))
    edit(doc)
    path = tmp_path / "broken.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(gain=3), r"broken.yaml: unknown key 'gain'"),
        (lambda d: d.update(version=2), r"broken.yaml: version: 2 is not supported"),
        (lambda d: d["tables"][0].update(colour="red"), r"tables\[0\]: unknown key 'colour'"),
        (lambda d: d["tables"][0]["psi"].pop(), r"tables\[0\]\.psi: \d+ values for a grid of \d+"),
        (lambda d: d["tables"][0].update(k_d="big"), r"tables\[0\]\.k_d: expected a number"),
        (lambda d: d.update(mode="log"), r"mode: 'log' is not one of"),
        (
            lambda d: d["tables"][0].update(fov_deg=[-100, 10]),
            r"fov_deg: \[-100, 10\] is not an interval",
        ),
        (lambda d: _swap(d["tables"][0]["psi"], 180, 184), r"psi: not strictly monotonic inside"),
        (lambda d: d.pop("tables"), r"missing required key 'tables'"),
    ],
)
def test_invalid_files_name_file_and_key(tmp_path: Path, sweep, edit, message: str) -> None:  # type: ignore[no-untyped-def]
    path = _write_cal(tmp_path, sweep, edit)
    with pytest.raises(CalibrationError, match=message):
        load_calibration(path)


def test_not_yaml(tmp_path: Path) -> None:
    path = tmp_path / "cal.yaml"
    path.write_text("format: [unclosed\n")
    with pytest.raises(CalibrationError, match=r"cal.yaml: line \d+, column \d+: invalid YAML"):
        load_calibration(path)


def test_non_monotonic_curve_has_no_usable_fov() -> None:
    # ψ oscillates with an 8° period: monotonic only within ±2° of boresight
    angles = np.repeat(np.arange(-60.0, 61.0, 1.0), 3)
    wiggle = 3.0 * np.sin(np.pi * angles / 4.0)
    with pytest.raises(CalibrationError, match="not monotonic around boresight"):
        fit_table(angles, -60.0 + wiggle, -60.0 - wiggle, "linear")


def test_samples_must_cover_boresight() -> None:
    angles = np.arange(5.0, 40.0, 1.0)
    with pytest.raises(CalibrationError, match="do not cover boresight"):
        fit_table(angles, -50 - angles * 0.1, -50 + angles * 0.1, "linear")


def test_example_files_are_consistent(repo_root: Path) -> None:
    cal = load_calibration(repo_root / "calibration" / "example_cal.yaml")
    check = read_samples_csv(repo_root / "calibration" / "example_turntable_check.csv")
    assert check_calibration(cal, check).consistent
