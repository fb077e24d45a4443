"""Helpers for CLI tests: run ``rfsas`` in-process with its real exit codes, and small
inputs (a capture, a calibration) built from the example turntable log."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import pytest

from rfsas_hw.cli.main import main

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests" / "sources"))

import rt_writer  # noqa: E402


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """Run ``rfsas ARGS`` as the console script does; (exit code, stdout, stderr)."""
    handler = signal.getsignal(signal.SIGTERM)
    try:
        main(args)
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        signal.signal(signal.SIGTERM, handler)
    out, err = capsys.readouterr()
    return code, out, err


def write_capture(path: Path, n: int = 200, span_s: float = 20.0) -> Path:
    """A radiotap pcap of ``n`` beacons from 3 transmitters on channel 6, two chains."""
    path.write_bytes(rt_writer.sweep_capture(n, span_s=span_s))
    return path


def write_calibration(path: Path) -> Path:
    """A single-table calibration fitted from the example turntable log."""
    from rfsas_hw.df import fit_calibration, read_samples_csv, save_calibration

    samples = read_samples_csv(REPO / "calibration" / "example_turntable.csv")
    save_calibration(fit_calibration(samples, per_channel=False), path)
    return path


STILL = rt_writer.STILL
"""Options for replaying :func:`write_capture`'s capture (its transmitters stand still)."""
