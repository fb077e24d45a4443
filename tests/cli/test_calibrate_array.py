"""``rfsas calibrate CAL.yaml --array SPEC``: element phases and gains of an emulated array
with known errors, from a turntable sweep and from a transmitter at a known position."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.df import load_calibration
from rfsas_hw.df.array import C_MPS, ArrayGeometry
from rfsas_hw.df.arrayfit import crb_deg, estimate_array
from rfsas_hw.errors import RfsasError
from rfsas_hw.sources.ble_iq import ble_channel_mhz, element_snapshots, remove_cfo
from rfsas_hw.sources.ble_iq_emulator import btsnoop_file, iq_reports
from rfsas_hw.sources.ble_iq_zephyr import format_stream

REPO = Path(__file__).resolve().parents[2]
AMPLITUDE = REPO / "calibration" / "example_cal.yaml"
CH = 17
FREQ = ble_channel_mhz(CH)
RADIUS = 0.6 * C_MPS / (FREQ * 1e6)
UCA = ArrayGeometry.uca(8, RADIUS)
PHASE_ERR_DEG = np.array([0.0, 35.0, -50.0, 12.0, 80.0, -20.0, 5.0, -75.0])
GAIN_ERR_DB = np.array([0.0, -1.5, 0.8, 2.0, -0.5, 1.2, -2.0, 0.3])
CHAINS = 10 ** (GAIN_ERR_DB / 20) * np.exp(1j * np.radians(PHASE_ERR_DEG))
T0 = 1_800_000_000 * 10**9
_load_commands()


def _calibrate(*args: str) -> str:
    result = CliRunner().invoke(cli, ["calibrate", str(AMPLITUDE), *args], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return result.output


def _bearing_rms(cal_path: Path | None, seed: int) -> tuple[float, float]:
    """RMS error of fresh packets all round (with the calibration file's elements, or
    ideal ones), and the CRB's RMS."""
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-180.0, 180.0, 300)
    cfo = rng.uniform(-150e3, 150e3, 300)
    reports = iq_reports(UCA, list(range(8)), theta, 25.0, cfo, rng, channel_index=CH,
                         element_gain=CHAINS)  # fmt: skip
    pat = list(range(8))
    snaps = np.stack([element_snapshots(remove_cfo(r, pat)[0], pat, 8)[:4] for r in reports])
    elements = None if cal_path is None else load_calibration(cal_path).array
    res = estimate_array(
        UCA, snaps, FREQ, calibration=None if elements is None else elements.elements
    ).df
    v = res.flags == 0
    err = (res.angle_deg - theta + 180.0) % 360.0 - 180.0
    err = np.where(v, err, 180.0)  # a refused packet counts as lost
    crb = crb_deg(UCA, theta, 25.0, FREQ, snapshots=4)
    return float(np.sqrt(np.mean(err**2))), float(np.sqrt(np.mean(crb**2)))


def test_turntable_sweep_recovers_the_chains(tmp_path: Path) -> None:
    rng = np.random.default_rng(31)
    n = 400
    theta = np.linspace(-179.0, 179.0, n)  # one slow turn
    reports = iq_reports(UCA, list(range(8)), theta, 25.0, rng.uniform(-150e3, 150e3, n), rng,
                         channel_index=CH, element_gain=CHAINS)  # fmt: skip
    capture = tmp_path / "turntable.btsnoop"
    capture.write_bytes(btsnoop_file(reports, T0))
    log = tmp_path / "angles.csv"
    rows = [f"{T0 + i * 10_000_000},{a:.4f}" for i, a in enumerate(theta)]
    log.write_text("t_ns,angle_deg\n" + "\n".join(rows) + "\n")
    out = tmp_path / "cal-array.yaml"
    text = _calibrate(
        *("--array", f"bleiq:{capture}?elements=8", "--geometry", f"uca:8,{RADIUS}"),
        *("--angles", str(log), "-o", str(out)),
    )
    assert f"{n} frames with a known angle" in text and "calibrated" in text
    cal = load_calibration(out)
    assert cal.array is not None and cal.array.freq_mhz == FREQ
    assert cal.tables  # the amplitude tables are kept beside it
    phase = np.degrees(cal.array.elements.phase_rad)
    dphase = (phase - PHASE_ERR_DEG + 180.0) % 360.0 - 180.0
    # 400 packets × 4 passes at 25 dB: the circular mean is good to a few tenths of a degree
    assert np.max(np.abs(dphase)) < 1.0, phase
    assert np.max(np.abs(cal.array.elements.gain_db - GAIN_ERR_DB)) < 0.2
    assert 0.5 < np.degrees(cal.array.elements.residual_rad) < 10.0
    rms, bound = _bearing_rms(out, seed=32)
    raw, _ = _bearing_rms(None, seed=32)
    assert rms <= 1.2 * bound, (rms, bound)
    assert raw > 5 * rms, (raw, rms)


def test_known_position_from_a_zephyr_console(tmp_path: Path) -> None:
    # the transmitter at (3, 4) m; the sensor at the origin facing north: 36.87° to the right
    known = float(np.degrees(np.arctan2(3.0, 4.0)))
    rng = np.random.default_rng(33)
    reports = iq_reports(UCA, list(range(8)), np.full(300, known), 25.0,
                         rng.uniform(-150e3, 150e3, 300), rng, channel_index=CH,
                         element_gain=CHAINS)  # fmt: skip
    console = tmp_path / "console.txt"
    console.write_text(format_stream(reports, ["0"] * 300))
    out = tmp_path / "cal-array.yaml"
    text = _calibrate(
        *("--array", f"bleiq+zephyr:{console}?elements=8&channel={CH}"),
        *("--geometry", f"uca:8,{RADIUS}", "--known-position", "3,4", "--pose", "0,0,0"),
        *("--array-fov", "-180,180", "-o", str(out)),
    )
    assert "+36.87° from boresight" in text
    cal = load_calibration(out)
    assert cal.array is not None and cal.array.fov_deg == (-180.0, 180.0)
    dphase = (np.degrees(cal.array.elements.phase_rad) - PHASE_ERR_DEG + 180.0) % 360.0 - 180.0
    assert np.max(np.abs(dphase)) < 1.5


def test_geometry_from_a_csv_file(tmp_path: Path) -> None:
    rng = np.random.default_rng(34)
    reports = iq_reports(UCA, list(range(8)), np.zeros(100), 25.0, 0.0, rng, channel_index=CH)
    console = tmp_path / "console.txt"
    console.write_text(format_stream(reports, ["0"] * 100))
    positions = tmp_path / "elements.csv"
    rows = [f"{x:.6f},{y:.6f}" for x, y in UCA.positions_m]
    positions.write_text("x_m,y_m\n" + "\n".join(rows) + "\n")
    out = tmp_path / "cal.yaml"
    _calibrate(
        *("--array", f"bleiq+zephyr:{console}?elements=8&channel={CH}", "-o", str(out)),
        *("--geometry", str(positions), "--known-position", "0,10"),
    )
    cal = load_calibration(out)
    assert cal.array is not None
    assert np.max(np.abs(np.degrees(cal.array.elements.phase_rad))) < 1.5  # ideal chains


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--known-position", "0,10"], "needs --geometry"),
        (["--geometry", "uca:8,0.07"], "--angles LOG.csv or --known-position"),
        (["--geometry", "uca:8.5,0.07", "--known-position", "0,10"], "whole numbers"),
        (["--geometry", "uca:2,0.07", "--known-position", "0,10"], "UCA needs"),
        (["--geometry", "hex:8,0.07", "--known-position", "0,10"], "hex:8,0.07"),
        (
            ["--geometry", "uca:8,0.07", "--known-position", "0,10", "--phase", "csi:x"],
            "separate runs",
        ),
    ],
)
def test_bad_options_are_one_line_errors(tmp_path: Path, extra: list[str], message: str) -> None:
    console = tmp_path / "console.txt"
    console.write_text("")
    args = ["calibrate", str(AMPLITUDE), "--array", f"bleiq+zephyr:{console}?elements=8"]
    result = CliRunner().invoke(cli, [*args, *extra, "-o", str(tmp_path / "o.yaml")])
    assert result.exit_code != 0
    # a usage error is printed; a bad value is an RfsasError the entry point prints as one line
    text = result.output + ("" if result.exception is None else str(result.exception))
    assert message in text, text
    assert result.exception is None or isinstance(result.exception, (RfsasError, SystemExit))


def test_the_output_may_not_replace_the_recording(tmp_path: Path) -> None:
    console = tmp_path / "console.txt"
    console.write_text("x\n")
    result = CliRunner().invoke(
        cli,
        [
            *("calibrate", str(AMPLITUDE), "--array", f"bleiq+zephyr:{console}?elements=8"),
            *("--geometry", "uca:8,0.07", "--known-position", "0,10", "-o", str(console)),
            "--force",
        ],
    )
    assert result.exit_code != 0 and console.read_text() == "x\n"
