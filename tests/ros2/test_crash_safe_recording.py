"""A recording that is killed keeps what it held a few seconds before, and a replayed
capture is recorded as one bearing array per span of time, each with its own stamp."""

from __future__ import annotations

import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "cli"))

from clihelp import STILL, run, write_calibration, write_capture

pytest.importorskip("mcap", reason="needs the ros2 extra (pip install .[ros2])")
pytest.importorskip("rosbags", reason="needs the ros2 extra (pip install .[ros2])")

MESSAGES = 40

WRITER = textwrap.dedent(
    """
    import os, signal, sys
    from rfsas_hw.ros2 import topics
    from rfsas_hw.ros2.bag import McapFileWriter, Rosbag2Writer
    from rfsas_hw.ros2.sink import SceneSink
    from rfsas_hw.ros2.scene import SceneBuilder
    from rfsas_hw.records import Pose

    kind, path, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
    writer = McapFileWriter(path, flush_s=0.0) if kind == "mcap" else Rosbag2Writer(
        path, flush_s=0.0)
    sink = SceneSink([writer])
    for k in range(n):
        sink.emit(SceneBuilder().sensors(1_000_000_000 * (k + 1), {"rsu-1": Pose(0, 0, 90)}))
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


def _killed_writer(kind: str, path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-c", WRITER, kind, str(path), str(MESSAGES)],
        capture_output=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()


def test_a_killed_mcap_recording_keeps_its_messages(tmp_path: Path) -> None:
    from mcap.exceptions import EndOfFile
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    path = tmp_path / "killed.mcap"
    _killed_writer("mcap", path)
    stamps = []
    with path.open("rb") as fh:
        try:
            for record in StreamReader(fh).records:
                if isinstance(record, Message):
                    stamps.append(record.log_time)
        except EndOfFile:
            pass  # no footer: the process never finished the file
    assert len(stamps) >= MESSAGES  # one sensors message (or more) per emit
    assert max(stamps) == MESSAGES * 1_000_000_000


def test_a_killed_rosbag2_recording_keeps_its_rows(tmp_path: Path) -> None:
    bag = tmp_path / "killed_bag"
    _killed_writer("rosbag2", bag)
    (db,) = bag.glob("*.db3")
    with sqlite3.connect(db) as conn:
        rows, last = conn.execute("SELECT COUNT(*), MAX(timestamp) FROM messages").fetchone()
    conn.close()
    assert rows >= MESSAGES - 1  # every row but those of the last moment
    assert last >= (MESSAGES - 1) * 1_000_000_000


def test_replay_to_mcap_records_one_array_per_span_with_its_time(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from mcap.reader import make_reader

    cap = write_capture(tmp_path / "cap.pcap", n=120, span_s=12.0)
    cal = write_calibration(tmp_path / "cal.yaml")
    out = tmp_path / "run.mcap"
    code, _, err = run(
        ["replay", str(cap), *STILL, "--calibration", str(cal), "--out", str(out)], capsys
    )
    assert code == 0, err
    with out.open("rb") as fh:
        stamps = [
            m.log_time
            for _, channel, m in make_reader(fh).iter_messages()
            if channel.topic.endswith("bearings")
        ]
    assert len(stamps) >= 20  # 12 s of beacons: far more than one array
    span_s = (max(stamps) - min(stamps)) / 1e9
    assert span_s > 10.0
