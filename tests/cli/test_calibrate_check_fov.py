"""``rfsas calibrate --check`` scores every sample, outside the field of view too."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.cli.main import main
from rfsas_hw.df import write_samples_csv
from rfsas_hw.rf import GaussianBeamPair, ReceiverModel, turntable_sweep
from rfsas_hw.rf.synth import TurntableSamples

ANT = GaussianBeamPair(
    squint_deg=20.0, beamwidth_deg=45.0, peak_gain_dbi=3.0, front_to_back_db=25.0
)
RX = ReceiverModel(measurement_floor_db=1.0, step_db=1.0, chain_offsets_db=(0.0, -1.5))


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exc:
        main([*args])
        raise SystemExit(0)
    out = capsys.readouterr()
    return int(exc.value.code or 0), out.out, out.err


def test_full_circle_check_reports_outside_bearings(
    tmp_path: Path, repo_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    check = tmp_path / "circle.csv"
    write_samples_csv(
        check, turntable_sweep(np.arange(-179.0, 180.0, 2.0), 20, -50.0, ANT, RX, 31, 6)
    )
    cal = repo_root / "calibration/example_cal.yaml"
    code, out, err = run(["calibrate", "--check", str(cal), str(check), "--json"], capsys)
    assert code == 0, err
    doc = json.loads(out)
    assert doc["samples"] == 3600 and doc["inside_fov"] < 1000
    assert doc["confident_wrong_share"] <= doc["confident_wrong_limit"] == 0.05
    assert doc["constant_guess_rms_deg"] > doc["rms_error_deg"]
    assert doc["consistent"] and doc["problems"] == [] and not doc["nothing_to_check"]


def test_beside_only_check_fails_on_confident_wrong(
    tmp_path: Path, repo_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the emitter only beside the antennas, swept across the boresight too so that the
    # sweep is accepted as check data, but 5 frames in front against 40 beside
    front = turntable_sweep(np.arange(-10.0, 10.0, 1.0), 5, -75.0, ANT, RX, 32, 6)
    beside = turntable_sweep(np.arange(50.0, 70.0, 0.5), 40, -50.0, ANT, RX, 33, 6)
    both = TurntableSamples(
        *(np.concatenate([getattr(front, k), getattr(beside, k)]) for k in
          ("angle_deg", "rssi1_dbm", "rssi2_dbm", "channel"))
    )  # fmt: skip
    check = tmp_path / "beside.csv"
    write_samples_csv(check, both)
    cal = repo_root / "calibration/example_cal.yaml"
    code, out, err = run(["calibrate", "--check", str(cal), str(check)], capsys)
    assert code == 1
    assert "NOT consistent" in err and "confident-wrong" in err
    assert "of them from outside the FoV" in out


def test_nothing_to_check_says_so(
    tmp_path: Path, repo_root: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    n = 400
    angle = np.repeat(np.arange(-20.0, 20.0, 1.0), 10)
    saturated = TurntableSamples(angle, np.full(n, -5.0), np.full(n, -5.0), np.full(n, 6, np.int16))
    check = tmp_path / "saturated.csv"
    write_samples_csv(check, saturated)
    cal = repo_root / "calibration/example_cal.yaml"
    code, _out, err = run(["calibrate", "--check", str(cal), str(check)], capsys)
    assert code == 1
    assert "nothing to check" in err
