"""A CSI replay that gives no bearing names the option the file needs."""

from __future__ import annotations

from pathlib import Path

import pytest

from rfsas_hw.cli.sensoropts import failure
from rfsas_hw.runner import RunSummary

pytest.importorskip("csiread", reason="needs the csi extra (pip install .[csi])")
REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data" / "csi"
CAL = REPO / "calibration" / "example_cal.yaml"


def _replay(spec: str, out: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    from clihelp import STILL, run

    code, _, err = run(
        ["replay", spec, *STILL, "--calibration", str(CAL), "--out", str(out)], capsys
    )
    return code, err


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("ath_csi_1.dat", "?rssi_offset=DB"),
        ("los_5.dat", "?freq=MHz"),
        ("example_4366c0.pcap", "records no RSSI (none (old nexmon format))"),
    ],
)
def test_the_missing_option_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], spec: str, says: str
) -> None:
    code, err = _replay(f"csi:{DATA / spec}", tmp_path / "b.jsonl", capsys)
    assert code == 1
    assert says in err


def test_with_the_option_the_same_files_give_bearings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for spec in ("ath_csi_1.dat?rssi_offset=-95", "los_5.dat?freq=2437"):
        code, err = _replay(f"csi:{DATA / spec}", tmp_path / f"{len(spec)}.jsonl", capsys)
        assert code == 0, err


def test_other_sources_keep_the_general_hints() -> None:
    summary = RunSummary(observations=5)
    summary.rejected["saturated"] = 5
    assert "saturation level" in (failure(summary) or "")
    summary.extra["csi_format"] = "picoscenes"
    assert "saturation level" in (failure(summary) or "")
