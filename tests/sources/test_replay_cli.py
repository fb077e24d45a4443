"""The sensor loop and the replay/live commands, end to end on real capture files and pipes."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rt_writer as w
from click.testing import CliRunner
from terminal import ctrl_c_as_at_a_terminal

import rfsas_hw.sources
from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.records import BearingBatch, Pose
from rfsas_hw.runner import ManualClock, Runner
from rfsas_hw.stream import Fanout

_load_commands()


COPY = "import sys; sys.stdout.buffer.write(open(sys.argv[1], 'rb').read())"


@pytest.fixture(scope="module")
def minute_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("cap") / "minute.pcap"
    path.write_bytes(w.sweep_capture(600, span_s=60.0))
    return path


class Collect:
    """A listener that keeps every batch."""

    def __init__(self) -> None:
        self.batches: list[BearingBatch] = []
        self.closed = False

    def on_bearings(self, batch: BearingBatch) -> None:
        self.batches.append(batch)

    def close(self) -> None:
        self.closed = True


def _runner(capture: Path, cal: Path, **kwargs: object) -> tuple[Runner, Collect]:
    from rfsas_hw.df import load_calibration

    pipeline = SensorPipeline(
        load_calibration(cal), MacHasher(FixedNonce(b"k" * 32)), "s1", Pose(0, 0, 90)
    )
    sink = Collect()
    source = rfsas_hw.sources.open(f"pcap:{capture}")
    return Runner(source, pipeline, Fanout([sink]), **kwargs), sink  # type: ignore[arg-type]


def test_fast_replay_processes_everything(minute_capture: Path, cal_path: Path) -> None:
    runner, sink = _runner(minute_capture, cal_path)
    summary = runner.run()
    assert summary.frames == 600 and summary.observations == 600
    assert summary.per_antenna == [600, 600] and summary.all_antennas == 600
    assert summary.bearings == sum(len(b) for b in sink.batches) > 500
    assert summary.emitters == 3
    assert summary.stopped == "end of input"
    assert sink.closed and runner.source.closed
    assert summary.capture_span_s == pytest.approx(60.0)


@pytest.mark.parametrize("speed", [1.0, 4.0])
def test_realtime_replay_of_a_minute_on_a_manual_clock(
    minute_capture: Path, cal_path: Path, speed: float
) -> None:
    clock = ManualClock()
    runner, sink = _runner(minute_capture, cal_path, clock=clock, realtime=True, speed=speed)
    t0 = time.monotonic()
    summary = runner.run()
    assert time.monotonic() - t0 < 10  # a minute of capture, replayed without waiting
    assert summary.observations == 600
    assert clock.slept_s == pytest.approx(60.0 / speed, abs=0.01)
    # Frames were released in capture order, never before their due time.
    times = [int(t) for b in sink.batches for t in b.t_ns]
    assert times == sorted(times)
    assert len(sink.batches) > 100  # paced: many small batches, not one


def test_duration_stops_a_realtime_replay(minute_capture: Path, cal_path: Path) -> None:
    clock = ManualClock()
    runner, _ = _runner(minute_capture, cal_path, clock=clock, realtime=True, duration_s=10.0)
    summary = runner.run()
    assert summary.stopped == "duration"
    assert clock.now_ns == pytest.approx(10e9, abs=1e7)
    assert 95 <= summary.observations <= 101  # ten frames per second for ten seconds


def test_progress_reports_bytes_up_to_the_total(tmp_path: Path, cal_path: Path) -> None:
    path = tmp_path / "big.pcap"
    path.write_bytes(w.sweep_capture(70_000, span_s=100.0))
    seen: list[tuple[int, int | None]] = []
    runner, _ = _runner(path, cal_path, progress=lambda d, t: seen.append((d, t)))
    runner.run()
    size = path.stat().st_size
    assert len(seen) >= 2
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)
    assert seen[-1] == (size, size)


def test_replay_cli_writes_hashed_bearings(
    minute_capture: Path, cal_path: Path, tmp_path: Path
) -> None:
    out = tmp_path / "b.jsonl"
    result = CliRunner().invoke(
        cli,
        [
            "replay",
            str(minute_capture),
            *w.STILL,
            "--calibration",
            str(cal_path),
            "--out",
            str(out),
        ],
        catch_exceptions=False,
    )
    assert result.exit_code == 0, result.output
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) > 500
    assert {r["sensor_id"] for r in rows} == {"sensor-1"}
    assert all(0 <= r["azimuth_deg"] < 360 and r["sigma_deg"] > 0 for r in rows)
    assert len({r["emitter"] for r in rows}) == 3
    text = out.read_text().lower()
    for mac in ("02:00:00:00:00:0", "020000000000", "02000000000"):
        assert mac not in text
    assert "frames read" in result.output and "600" in result.output


def test_replay_cli_csv_and_summary_of_a_broken_capture(
    data_dir: Path, cal_path: Path, tmp_path: Path
) -> None:
    out = tmp_path / "b.csv"
    result = CliRunner().invoke(
        cli,
        [
            "replay",
            str(data_dir / "broken_it_len_larger_than_packet.pcap"),
            *w.STILL,
            "--calibration",
            str(cal_path),
            "--out",
            str(out),
        ],
        catch_exceptions=False,
    )
    assert result.exit_code == 0, result.output
    assert out.read_text().splitlines()[0].startswith("t_ns,sensor_id,azimuth_deg")
    assert "skipped: malformed radiotap header" in result.output
    assert "frame 2 at byte 279" in result.output


def test_replay_cli_errors_are_one_line(cal_path: Path, tmp_path: Path) -> None:
    result = CliRunner().invoke(
        cli,
        [
            "replay",
            str(tmp_path / "none.pcap"),
            *w.STILL,
            "--calibration",
            str(cal_path),
            "--out",
            "x.jsonl",
        ],
    )
    assert result.exit_code != 0
    result = CliRunner().invoke(
        cli, ["replay", "x.pcap", *w.STILL, "--calibration", str(cal_path)], standalone_mode=False
    )
    assert result.exception is not None


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "rfsas_hw.cli.main", *args]


def test_live_reads_a_pcap_stream_from_a_real_pipe(
    minute_capture: Path, cal_path: Path, tmp_path: Path
) -> None:
    out = tmp_path / "live.jsonl"
    producer = subprocess.Popen(
        [sys.executable, "-c", COPY, str(minute_capture)],
        stdout=subprocess.PIPE,
    )  # fmt: skip
    consumer = subprocess.run(
        _cli("live", "pcap:-", *w.STILL, "--calibration", str(cal_path), "--out", str(out)),
        stdin=producer.stdout,
        capture_output=True,
        timeout=60,
    )
    assert producer.stdout is not None
    producer.stdout.close()
    producer.wait(timeout=10)
    assert consumer.returncode == 0, consumer.stderr.decode()
    assert len(out.read_text().splitlines()) > 500
    assert b"end of input" in consumer.stdout


def test_live_ctrl_c_ends_cleanly_with_the_summary(
    data_dir: Path, cal_path: Path, tmp_path: Path
) -> None:
    out = tmp_path / "live.jsonl"
    # The producer sends one capture and keeps the pipe open, like tcpdump on a quiet channel.
    producer = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time; sys.stdout.buffer.write(open(sys.argv[1], 'rb').read()); "
         "sys.stdout.flush(); time.sleep(60)",
         str(data_dir / "ieee802.11_meshid.pcap")],
        stdout=subprocess.PIPE,
    )  # fmt: skip
    consumer = subprocess.Popen(
        _cli("live", "pcap:-", *w.STILL, "--calibration", str(cal_path), "--out", str(out)),
        stdin=producer.stdout,
        preexec_fn=ctrl_c_as_at_a_terminal,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 30
        assert consumer.stderr is not None
        line = consumer.stderr.readline()
        assert b"Ctrl-C ends the run" in line
        time.sleep(0.5)
        consumer.send_signal(signal.SIGINT)
        stdout, stderr = consumer.communicate(timeout=max(1.0, deadline - time.monotonic()))
        assert consumer.returncode == 0, stderr.decode()
        assert b"interrupted" in stdout
        assert b"observations" in stdout
    finally:
        producer.kill()
        producer.wait()
        assert producer.stdout is not None
        producer.stdout.close()
        if consumer.poll() is None:
            consumer.kill()
            consumer.communicate()
