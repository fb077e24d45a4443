"""``rfsas board`` as a user runs it: emulate prints a path, info talks to it, errors are clean."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rfsas_hw.cli.main import main
from rfsas_hw.sources.serial_board import SerialSource

REPO = Path(__file__).resolve().parents[2]


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exc:
        main([*args])
        raise SystemExit(0)
    out = capsys.readouterr()
    return int(exc.value.code or 0), out.out, out.err


def test_emulate_prints_its_path_and_info_reads_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    link = tmp_path / "ttyDF"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "rfsas_hw.cli.main",
            "board",
            "emulate",
            "--link",
            str(link),
            "--emitters",
            "15,20,11,80",
            "--duration",
            "20",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        cwd=REPO,
    )
    try:
        assert proc.stdout is not None
        path = proc.stdout.readline().strip()
        assert path == str(link)
        code, out, err = run(["board", "info", path], capsys)
        assert code == 0, err
        assert "board id" in out and "5246000000000001" in out and "TIME_SYNC" in out
        code, out, err = run(["board", "info", path, "--json"], capsys)
        assert code == 0, err
        facts = json.loads(out)
        assert facts["board_id"] == "5246000000000001" and "TIME_SYNC" in facts["capabilities"]
        with SerialSource(path, channel=11) as src:
            deadline = time.monotonic() + 3
            got = 0
            while got == 0 and time.monotonic() < deadline:
                b = src.read(0.1)
                got += 0 if b is None else len(b)
        assert got > 0
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        if proc.stdout is not None:
            proc.stdout.close()


def test_info_on_a_missing_port_is_one_clean_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = run(["board", "info", str(tmp_path / "ttyNONE")], capsys)
    assert code == 2
    assert err.startswith("error: cannot open serial port") and "Traceback" not in err


def test_bad_fault_and_emitter_specs_are_clean_errors(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["board", "emulate", "--fault", "lightning=1", "--duration", "0"], capsys)
    assert code == 2 and "fault 'lightning=1': unknown fault" in err
    code, _, err = run(["board", "emulate", "--emitters", "left", "--duration", "0"], capsys)
    assert code == 2 and "emitter 'left'" in err


def test_pty_and_tcp_together_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["board", "emulate", "--pty", "--tcp", "0", "--duration", "0"], capsys)
    assert code == 2 and "give --pty or --tcp, not both" in err


def test_list_runs(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(["board", "list"], capsys)
    assert code == 0, err
    assert "Serial ports" in out or "no serial ports found" in out


def test_emulate_replays_a_board_capture(
    data_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(
        [
            "board",
            "emulate",
            "--capture",
            str(data_dir / "board_clean_stream.bin"),
            "--duration",
            "0.3",
        ],
        capsys,
    )
    assert code == 0, err
    assert out.strip().endswith("ttyBOARD")
