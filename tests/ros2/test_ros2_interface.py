"""``--ros2-interface`` names an interface of this host (or an address): a wrong name is
one clear line before DDS starts, not Cyclone's ``DDS_RETCODE_ERROR``."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "cli"))

from clihelp import run, write_calibration, write_capture

from rfsas_hw.cli.exitcodes import BAD_INPUT


def test_an_unknown_interface_is_named_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cap = write_capture(tmp_path / "cap.pcap", n=20, span_s=2.0)
    cal = write_calibration(tmp_path / "cal.yaml")
    args = ["replay", str(cap), "--calibration", str(cal), "--ros2"]
    code, _, err = run([*args, "--ros2-interface", "nosuch0"], capsys)
    assert code == BAD_INPUT and "Traceback" not in err, err
    assert "no such network interface" in err and "lo" in err
