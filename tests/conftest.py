"""Shared pytest options: hardware tests are opt-in, emulators are the default."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parent / "data"
REPO = Path(__file__).resolve().parent.parent

SLOW_TIMEOUT_S = 1200
"""Time limit of a test marked ``slow`` without a timeout of its own, seconds (the
default for the others is pyproject.toml's ``timeout``)."""


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--serial-url",
        default=None,
        help="Run the serial-board tests against this real board (pyserial URL or device path).",
    )
    parser.addoption(
        "--wifi-iface",
        default=None,
        help="Run the live Wi-Fi tests on this monitor-mode interface.",
    )


@pytest.fixture
def data_dir() -> Path:
    """tests/data: real and deliberately broken inputs, named for what they prove."""
    return DATA


@pytest.fixture
def repo_root() -> Path:
    """The repository root (for bundled examples and calibration files)."""
    return REPO


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Give tests marked ``slow`` a longer time limit unless they set their own."""
    for item in items:
        if item.get_closest_marker("slow") and not item.get_closest_marker("timeout"):
            item.add_marker(pytest.mark.timeout(SLOW_TIMEOUT_S))
