"""Fixtures for the capture-source tests."""

from __future__ import annotations

import sys
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
