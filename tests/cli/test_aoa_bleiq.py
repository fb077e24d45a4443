"""``rfsas aoa emulate bleiq`` then ``rfsas replay bleiq:…``: array bearings without hardware."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from clihelp import run


@pytest.mark.parametrize("suffix", [".btsnoop", ".h4"])
def test_emulated_reports_replay_to_bearings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], suffix: str
) -> None:
    iq, cal, out = tmp_path / f"iq{suffix}", tmp_path / "array.yaml", tmp_path / "b.jsonl"
    code, _, err = run(
        ["aoa", "emulate", "bleiq", "-o", str(iq), "--calibration-out", str(cal),
         "--packets", "200", "--seed", "4"],
        capsys,
    )  # fmt: skip
    assert code == 0, err
    code, _, err = run(
        ["replay", f"bleiq:{iq}?elements=8", "--calibration", str(cal), "--out", str(out)], capsys
    )
    assert code == 0, err
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == 200
    truth = np.random.default_rng(4).uniform(-180.0, 180.0, 200)
    rel = np.array([r["relative_deg"] for r in rows])
    err_deg = (rel - truth + 180.0) % 360.0 - 180.0
    # 25 dB per sample, 4 passes of 8 antennas: the CRB is about 0.15°
    assert np.sqrt(np.mean(err_deg**2)) < 0.3
    # the handle stands in for an address and is hashed like one
    assert all(r["emitter"] != "1" for r in rows)


def test_an_existing_output_needs_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    iq = tmp_path / "iq.btsnoop"
    iq.write_bytes(b"keep")
    code, _, err = run(["aoa", "emulate", "bleiq", "-o", str(iq)], capsys)
    assert code == 2 and "--force" in err
    assert iq.read_bytes() == b"keep"
