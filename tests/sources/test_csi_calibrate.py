"""``rfsas calibrate CAL.yaml --phase csi:…``: phase offsets from a turntable log or a position."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner

from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.df import load_calibration
from rfsas_hw.df.interferometer import C_MPS
from rfsas_hw.errors import RfsasError
from rfsas_hw.records import Pose
from rfsas_hw.sources.csi_calibration import known_angle_deg
from rfsas_hw.twin.csi_writer import CsiArray, synth_csi, write_feitcsi

_load_commands()
REPO = Path(__file__).resolve().parents[2]
CAL = REPO / "calibration" / "example_cal.yaml"
LAM = C_MPS / 2437e6
MAC = "02:00:00:00:00:42"
ARRAY = CsiArray(baseline_m=LAM / 2, phase_offset_deg=40.0, delay_ns=0.3)


def _capture(path: Path, theta: np.ndarray, dt_ns: int = 20_000_000) -> np.ndarray:
    n = len(theta)
    h = synth_csi(ARRAY, theta, 2437, np.full((n, 2), 30.0), seed=5)
    t = np.arange(n, dtype=np.int64) * dt_ns + 1_000_000
    macs = np.full(n, int(MAC.replace(":", ""), 16), np.uint64)
    macs[::7] = 0x020000000099  # another transmitter in the air
    write_feitcsi(path, t, macs, np.full((n, 2), -50.0), h)
    return t


def _run(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(cli, ["calibrate", *args])
    return result.exit_code, result.output


def test_turntable_log(tmp_path: Path) -> None:
    steps = np.arange(-40.0, 40.1, 5.0)
    theta = np.repeat(steps, 20)
    t = _capture(tmp_path / "tt.csi", theta)
    rows = ["t_ns,angle_deg"]
    for k, angle in enumerate(steps):
        dwell = t[k * 20 : (k + 1) * 20]
        rows += [f"{dwell[0] - 1000},{angle}", f"{dwell[-1] + 1000},{angle}"]
    (tmp_path / "log.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "cal-phase.yaml"
    code, text = _run(
        str(CAL),
        "--phase",
        f"csi:{tmp_path / 'tt.csi'}?freq=2437",
        "--angles",
        str(tmp_path / "log.csv"),
        "--emitter",
        MAC,
        "--baseline",
        f"{LAM / 2:.6f}",
        "-o",
        str(out),
    )
    assert code == 0, text
    cal = load_calibration(out)
    assert cal.phase is not None
    np.testing.assert_array_equal(cal.tables[0].psi, load_calibration(CAL).tables[0].psi)
    (pair,) = cal.phase.pairs
    (offset,) = pair.offsets
    assert offset.channel == 6
    assert offset.offset_deg == pytest.approx(40.0, abs=0.3)
    assert offset.delay_ns == pytest.approx(0.3, abs=0.1)
    # frames of the other transmitter and between dwells are not used
    assert offset.samples == int(np.sum(np.arange(len(theta)) % 7 != 0))


def test_known_position(tmp_path: Path) -> None:
    pose = Pose(0.0, 0.0, 90.0)  # boresight east
    angle = known_angle_deg(pose, 10.0, -10.0)  # south-east: 45° clockwise of east
    assert angle == pytest.approx(45.0)
    _capture(tmp_path / "fixed.csi", np.full(60, angle))
    out = tmp_path / "cal-phase.yaml"
    code, text = _run(
        str(CAL),
        "--phase",
        f"csi:{tmp_path / 'fixed.csi'}?freq=2437",
        "--known-position",
        "10,-10",
        "--pose",
        "0,0,90",
        "--emitter",
        MAC,
        "--baseline",
        f"{LAM / 2:.6f}",
        "-o",
        str(out),
        "--single-table",
    )
    assert code == 0, text
    cal = load_calibration(out)
    assert cal.phase is not None
    offset = cal.phase.pairs[0].offsets[0]
    assert offset.channel is None
    assert offset.offset_deg == pytest.approx(40.0, abs=0.5)
    assert "+45.00°" in text


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ([], "needs --baseline"),
        (["--baseline", "0.06"], "--angles LOG.csv or --known-position"),
        (
            ["--baseline", "0.06", "--known-position", "1,1", "--emitter", "02:00:00:00:00:07"],
            "no frame from 02:00:00:00:00:07",
        ),
        (["--baseline", "0.06", "--known-position", "1"], "expected 2 comma-separated"),
        (["--baseline", "0.06", "--known-position", "1,nan"], "expected 2 comma-separated"),
        (["--baseline", "0.06", "--known-position", "1,1", "--pair", "0.5,1"], "two different"),
        (["--baseline", "inf", "--known-position", "1,1"], "not a finite number"),
    ],
)
def test_errors_name_the_problem(tmp_path: Path, extra: list[str], match: str) -> None:
    """Usage errors and library errors (the CLI prints either as one line, exit 2)."""
    _capture(tmp_path / "c.csi", np.zeros(20))
    args = [str(CAL), "--phase", f"csi:{tmp_path / 'c.csi'}?freq=2437"]
    args += ["-o", str(tmp_path / "o.yaml"), *extra]
    result = CliRunner().invoke(cli, ["calibrate", *args], standalone_mode=False)
    assert isinstance(result.exception, click.UsageError | RfsasError)
    assert match in str(result.exception)
    assert not (tmp_path / "o.yaml").exists()
