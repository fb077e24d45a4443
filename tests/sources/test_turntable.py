"""Calibration samples from a turntable capture joined with its angle log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rt_writer as w

from rfsas_hw.df import estimate, fit_calibration
from rfsas_hw.errors import DataFormatError
from rfsas_hw.rf.antenna import GaussianBeamPair
from rfsas_hw.sources.turntable import angles_at, read_angle_log, samples_from_capture

T0_S = 1_700_000_000
REF = 0x02_AA_BB_CC_DD_EE
REF_TEXT = "02:aa:bb:cc:dd:ee"


def angle_true(t_s: float) -> float:
    """The table sweeps -60° → +60° over 60 s."""
    return -60.0 + 2.0 * t_s


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, np.ndarray]:
    rng = np.random.default_rng(5)
    pair = GaussianBeamPair()
    frames = []
    truth = []
    for i in range(1200):
        t_s = i * 0.05
        theta = angle_true(t_s)
        g = pair.gains_db(np.array([theta]))[0]
        r0 = round(-45 + g[0] + rng.normal(0, 0.5))
        r1 = round(-45 + g[1] + rng.normal(0, 0.5))
        t_ns = (T0_S * 10**9) + int(t_s * 1e9)
        frames.append((t_ns, w.mac80211_header(r0, r1) + w.dot11(ta=REF, seq=i % 4096)))
        truth.append(theta)
        if i % 3 == 0:  # another transmitter, to be ignored
            frames.append((t_ns + 1000, w.mac80211_header(-70, -20) + w.dot11(ta=0x1234, seq=i)))
    d = tmp_path_factory.mktemp("turntable")
    (d / "turntable.pcap").write_bytes(w.pcap(frames))
    lines = ["time_s,angle_deg"]
    for k in range(0, 121):  # one row per 0.5 s
        lines.append(f"{T0_S + k * 0.5:.3f},{angle_true(k * 0.5):.3f}")
    (d / "angles.csv").write_text("\n".join(lines) + "\n")
    return d / "turntable.pcap", d / "angles.csv", np.array(truth)


def test_samples_carry_the_logged_angle_and_both_signals(
    session: tuple[Path, Path, np.ndarray],
) -> None:
    cap, log, truth = session
    samples, stats = samples_from_capture(str(cap), log, REF_TEXT)
    assert stats.emitter_frames == 1200
    assert stats.samples == 1200 - stats.outside_log
    assert stats.outside_log <= 1  # the last frame lies after the last log row
    np.testing.assert_allclose(samples.angle_deg, truth[: stats.samples], atol=1e-6)
    assert (samples.channel == 6).all()
    assert samples.rssi1_dbm.max() > -45 and samples.rssi2_dbm.max() > -45
    assert (samples.rssi1_dbm != -70).all()  # the other transmitter is not in the samples


def test_a_calibration_fitted_from_the_capture_finds_angles(
    session: tuple[Path, Path, np.ndarray],
) -> None:
    cap, log, _ = session
    samples, _ = samples_from_capture(str(cap), log, REF)
    cal = fit_calibration(samples, per_channel=False)
    theta = np.array([-20.0, 0.0, 15.0])
    g = GaussianBeamPair().gains_db(theta)
    got = estimate(cal, -45 + g[:, 0], -45 + g[:, 1], np.full(3, 6, np.int16))
    np.testing.assert_allclose(got.angle_deg, theta, atol=3.0)


def test_gaps_and_hold_mode(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    path.write_text("t_ns,angle\n0,10\n1000000000,20\n9000000000,30\n")
    log = read_angle_log(path)
    t = np.array([500_000_000, 5_000_000_000, 9_500_000_000], np.int64)
    angle, inside, no_gap = angles_at(log, t, max_gap_s=2.0)
    assert angle[0] == pytest.approx(15.0)
    assert inside.tolist() == [True, True, False]
    assert no_gap.tolist()[:2] == [True, False]
    held, _, _ = angles_at(log, t, mode="hold")
    assert held[0] == 10.0


def test_interpolation_takes_the_short_way_across_180(tmp_path: Path) -> None:
    path = tmp_path / "log.csv"
    path.write_text(
        "timestamp,angle_deg\n2024-01-01T00:00:00Z,170\n2024-01-01T00:00:01+00:00,-170\n"
    )
    log = read_angle_log(path)
    mid = log.t_ns[0] + 500_000_000
    angle, _, _ = angles_at(log, np.array([mid]))
    assert abs(abs(angle[0]) - 180.0) < 1e-9


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("when,angle\n1,2\n", "line 1: need a time column"),
        ("time,angle\n2024-01-01T00:00:00,5\n", "line 2: time .* has no time zone"),
        ("time_s,angle\n2,1\n1,1\n", "line 3: time goes backwards"),
        ("time_s,angle\n1,north\n", "line 2: angle 'north' is not a number"),
        ("time_s,angle\n", "no rows"),
    ],
)
def test_bad_angle_logs_name_the_line(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "log.csv"
    path.write_text(text)
    with pytest.raises(DataFormatError, match=message):
        read_angle_log(path)


def test_wrong_emitter_gives_a_clear_error(session: tuple[Path, Path, np.ndarray]) -> None:
    cap, log, _ = session
    with pytest.raises(DataFormatError, match="no samples: 0 frames from"):
        samples_from_capture(str(cap), log, "00:00:00:00:00:01")


def test_calibrate_command_from_a_capture(
    session: tuple[Path, Path, np.ndarray], tmp_path: Path
) -> None:
    from click.testing import CliRunner

    from rfsas_hw.cli.main import _load_commands, cli
    from rfsas_hw.df import load_calibration

    _load_commands()
    cap, log, _ = session
    out = tmp_path / "cal.yaml"
    args = ["calibrate", "--capture", str(cap), "--angles", str(log), "--emitter", REF_TEXT]
    result = CliRunner().invoke(cli, [*args, "-o", str(out)], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    assert "samples from 1200 frames" in result.output
    cal = load_calibration(out)
    assert [t.channel for t in cal.tables] == [6]
    assert cal.tables[0].samples >= 1199
