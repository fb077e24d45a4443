"""``replay``/``live`` never write over an input, never say ok when they failed, and tell
a script what happened: exit codes, ``--out -``, ``--json``, ``--force``, SIGTERM."""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from clihelp import REPO, STILL, run, write_calibration, write_capture

from rfsas_hw.cli.exitcodes import BAD_INPUT, FAILED, INTERRUPTED, OK
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.publisher import SNR_UNKNOWN_DB, Publisher
from rfsas_hw.link.transport import open_transport
from rfsas_hw.output import BearingWriter
from rfsas_hw.records import BearingBatch, Pose


@pytest.fixture
def inputs(tmp_path: Path) -> tuple[Path, Path]:
    return write_capture(tmp_path / "cap.pcap"), write_calibration(tmp_path / "cal.yaml")


def test_an_output_that_is_an_input_is_refused_and_the_input_kept(
    tmp_path: Path, inputs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cap, cal = inputs
    before = cap.read_bytes()
    (tmp_path / "hard.pcap").hardlink_to(cap)
    (tmp_path / "sym.jsonl").symlink_to(cal)
    for out in (cap, tmp_path / "hard.pcap", cal, tmp_path / "sym.jsonl"):
        code, _, err = run(
            ["replay", str(cap), *STILL, "--calibration", str(cal), "--out", str(out), "--format",
             "jsonl", "--force"],
            capsys,
        )  # fmt: skip
        assert code == BAD_INPUT, err
        assert "is also an input" in err and "Traceback" not in err
    assert cap.read_bytes() == before
    assert cal.read_text().startswith("format: rfsas-calibration")


def test_an_existing_output_needs_force(
    tmp_path: Path, inputs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cap, cal = inputs
    out = tmp_path / "b.jsonl"
    out.write_text("keep me\n")
    args = ["replay", str(cap), *STILL, "--calibration", str(cal), "--out", str(out)]
    code, _, err = run(args, capsys)
    assert code == BAD_INPUT and "--force" in err
    assert out.read_text() == "keep me\n"
    code, _, err = run([*args, "--force"], capsys)
    assert code == OK, err
    assert len(out.read_text().splitlines()) == 200


def test_a_fixed_mount_refuses_emitters_that_stand_still(
    tmp_path: Path, inputs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cap, cal = inputs
    args = ["replay", str(cap), "--calibration", str(cal), "--out", str(tmp_path / "b.jsonl")]
    # by default the sensor is a fixed mount: transmitters that never move never count,
    # and the one line says how to replay such a capture
    code, _, err = run(args, capsys)
    assert code == FAILED, err
    assert "may_be_outside 200" in err and "--prove-motion 0" in err
    for opt_out in (["--prove-motion", "0"], ["--moving-mount"]):
        code, _, err = run([*args, "--force", *opt_out], capsys)
        assert code == OK, err
        assert len((tmp_path / "b.jsonl").read_text().splitlines()) == 200


def test_out_dash_is_stdout_and_the_summary_goes_to_stderr(
    inputs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cap, cal = inputs
    code, out, err = run(
        ["replay", str(cap), *STILL, "--calibration", str(cal), "--out", "-", "--json"], capsys
    )
    assert code == OK, err
    rows = [json.loads(line) for line in out.splitlines()]
    assert len(rows) == 200 and {"azimuth_deg", "emitter"} <= set(rows[0])
    summary = json.loads(err.strip().splitlines()[-1])
    assert summary["ok"] is True and summary["bearings"] == 200
    assert summary["outputs"]["stdout"]["written"] == 200
    assert not Path("-").exists()


def test_json_summary_on_stdout(
    tmp_path: Path, inputs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cap, cal = inputs
    code, out, _ = run(
        ["replay", str(cap), *STILL, "--calibration", str(cal), "--out", str(tmp_path / "b.csv"),
         "--json"],
        capsys,
    )  # fmt: skip
    assert code == OK
    summary = json.loads(out)
    assert summary["frames"] == 200 and summary["failure"] is None
    assert summary["outputs"][str(tmp_path / "b.csv")] == {"written": 200, "lost": 0}


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_failed_write_exits_1_with_one_line(
    inputs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cap, cal = inputs
    code, _, err = run(
        [
            "replay",
            str(cap),
            *STILL,
            "--calibration",
            str(cal),
            "--out",
            "/dev/full",
            "--format",
            "jsonl",
        ],
        capsys,
    )
    assert code == FAILED
    assert "No space left on device" in err and "Traceback" not in err


def test_zero_bearings_exit_1_with_a_hint(
    tmp_path: Path, inputs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cap, _ = inputs
    # a calibration for channel 11 only; the capture is on channel 6
    text = (REPO / "calibration" / "example_cal.yaml").read_text()
    cal11 = tmp_path / "cal11.yaml"
    cal11.write_text(text.replace("- channel: 6", "- channel: 11"))
    code, _, err = run(
        [
            "replay",
            str(cap),
            *STILL,
            "--calibration",
            str(cal11),
            "--out",
            str(tmp_path / "b.jsonl"),
        ],
        capsys,
    )
    assert code == FAILED
    assert "0 bearings" in err and "no_table" in err and "--single-table" in err


def test_send_to_a_host_that_does_not_resolve_is_bad_input(
    tmp_path: Path, inputs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cap, cal = inputs
    KeyStore.create(tmp_path / "rsu", "sensor")
    code, _, err = run(
        ["replay", str(cap), *STILL, "--calibration", str(cal), "--keys", str(tmp_path / "rsu"),
         "--send", "udp://no-such-host.invalid:47000"],
        capsys,
    )  # fmt: skip
    assert code == BAD_INPUT and "cannot resolve" in err


def _ipv6_loopback() -> bool:
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as s:
            s.bind(("::1", 0))
        return True
    except OSError:
        return False


@pytest.mark.skipif(not _ipv6_loopback(), reason="no IPv6 loopback")
def test_send_over_ipv6_arrives(
    tmp_path: Path, inputs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    cap, cal = inputs
    KeyStore.create(tmp_path / "rsu", "sensor")
    with open_transport("udp://[::1]:0", "recv") as rx:
        port = rx.address[1]
        code, out, err = run(
            ["replay", str(cap), *STILL, "--calibration", str(cal), "--keys", str(tmp_path / "rsu"),
             "--send", f"udp://[::1]:{port}", "--json"],
            capsys,
        )  # fmt: skip
        assert code == OK, err
        got = 0
        while rx.recv(0.2) is not None:
            got += 1
    summary = json.loads(out)
    sent = summary["outputs"][f"send udp://[::1]:{port}"]
    assert sent["sent"] == 200 and got == sent["messages"] > 0


def _batch(snr: float) -> BearingBatch:
    n = 4
    return BearingBatch(
        sensor_id="s1",
        t_ns=np.full(n, 1_763_800_030_000_000_000, np.int64),
        azimuth_deg=np.array([10.0, 20.0, 30.0, 40.0]),
        sigma_deg=np.full(n, 2.0),
        snr_db=np.full(n, snr),
        channel=np.full(n, 6, np.int16),
        emitter=np.arange(1, n + 1, dtype=np.uint64),
    )


def test_bearings_without_snr_are_sent_not_dropped(tmp_path: Path) -> None:
    signer = KeyStore.create(tmp_path / "rsu", "sensor").signer()
    with open_transport("udp://127.0.0.1:0", "recv") as rx:
        pub = Publisher.to_url(f"udp://127.0.0.1:{rx.address[1]}", signer, Pose(0, 0, 0))
        pub.on_bearings(_batch(math.nan))
        pub.close()
        assert rx.recv(1.0) is not None
    assert pub.stats.bearings == 4 and not pub.stats.dropped
    assert pub.problem() is None
    assert SNR_UNKNOWN_DB < -300


def test_a_publisher_that_sends_nothing_says_so(tmp_path: Path) -> None:
    signer = KeyStore.create(tmp_path / "rsu", "sensor").signer()
    pub = Publisher.to_url("udp://127.0.0.1:9", signer, Pose(0, 0, 0))
    bad = _batch(10.0)
    bad.sigma_deg[:] = math.nan
    pub.on_bearings(bad)
    pub.close()
    assert pub.problem() == "none of 4 bearings sent (invalid 4)"


def test_jsonl_writes_null_not_nan(tmp_path: Path) -> None:
    path = tmp_path / "b.jsonl"
    writer = BearingWriter(path)
    writer.on_bearings(_batch(math.nan))
    writer.close()
    for line in path.read_text().splitlines():
        row = json.loads(line, parse_constant=lambda c: pytest.fail(f"bare {c} in JSONL"))
        assert row["snr_db"] is None and row["relative_deg"] is None
    csv_path = tmp_path / "b.csv"
    writer = BearingWriter(csv_path)
    writer.on_bearings(_batch(math.nan))
    writer.close()
    assert "nan" not in csv_path.read_text().lower()


def test_sigterm_ends_a_replay_like_ctrl_c(tmp_path: Path, inputs: tuple[Path, Path]) -> None:
    cap, cal = inputs
    out = tmp_path / "b.jsonl"
    proc = subprocess.Popen(
        [sys.executable, "-m", "rfsas_hw.cli.main", "replay", str(cap), *STILL, "--calibration",
         str(cal), "--out", str(out), "--realtime", "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and (not out.exists() or out.stat().st_size == 0):
        time.sleep(0.1)  # wait until the run is under way
    os.kill(proc.pid, signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == INTERRUPTED, stderr
    summary = json.loads(stdout)
    assert summary["stopped"] == "terminated" and "Traceback" not in stderr
    assert 0 < summary["bearings"] < 200
    # every bearing the summary counts is in the file, whole
    lines = out.read_text().splitlines()
    assert len(lines) == summary["bearings"] and all(json.loads(x) for x in lines)
