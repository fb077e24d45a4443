"""Fixtures for the capture-source tests."""

from __future__ import annotations

import contextlib
import os
import sys
import tty
from collections.abc import Iterator
from pathlib import Path

# The tests share the independent radiotap writer in this folder.
sys.path.insert(0, str(Path(__file__).parent))


import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def cal_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A single-table calibration (valid on every channel) fitted from the example turntable log."""
    from rfsas_hw.df import fit_calibration, read_samples_csv, save_calibration

    samples = read_samples_csv(REPO / "calibration" / "example_turntable.csv")
    path = tmp_path_factory.mktemp("cal") / "cal.yaml"
    save_calibration(fit_calibration(samples, per_channel=False), path)
    return path


@pytest.fixture
def unit() -> Iterator[tuple[int, str]]:
    """A raw pseudo-terminal standing in for a serial unit: (master fd, slave device path)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    yield master, os.ttyname(slave)
    for fd in (master, slave):
        with contextlib.suppress(OSError):
            os.close(fd)
