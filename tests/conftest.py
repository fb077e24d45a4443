"""Shared pytest options: hardware tests are opt-in, emulators are the default."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest

from rfsas_hw.optional import EXTRAS

DATA = Path(__file__).resolve().parent / "data"
REPO = Path(__file__).resolve().parent.parent

# pytest runs with --import-mode=importlib, which does not put test folders on sys.path;
# modules shared by tests of several folders (bytefuzz) live here.
sys.path.insert(0, str(Path(__file__).resolve().parent))

SLOW_TIMEOUT_S = 1200
"""Time limit of a test marked ``slow`` without a timeout of its own, seconds (the
default for the others is pyproject.toml's ``timeout``; ``fuzz`` tests: see
:func:`fuzz_timeout_s`)."""


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


def fuzz_timeout_s() -> float:
    """Time limit of a ``fuzz`` test: :data:`SLOW_TIMEOUT_S` per 100,000 cases of
    ``RFSAS_FUZZ_CASES`` (``make fuzz`` runs a million), at least :data:`SLOW_TIMEOUT_S`."""
    cases = int(os.environ.get("RFSAS_FUZZ_CASES", "100000") or 0)
    return SLOW_TIMEOUT_S * max(1.0, cases / 100_000)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Give tests marked ``slow`` or ``fuzz`` a longer time limit unless they set their own."""
    for item in items:
        if item.get_closest_marker("timeout"):
            continue
        if item.get_closest_marker("fuzz"):
            item.add_marker(pytest.mark.timeout(fuzz_timeout_s()))
        elif item.get_closest_marker("slow"):
            item.add_marker(pytest.mark.timeout(SLOW_TIMEOUT_S))


def _missing_extra(extra: str) -> str | None:
    """The first module of ``extra`` (rfsas_hw.optional.EXTRAS) that is not installed."""
    modules = [module for module, name in EXTRAS.items() if name == extra]
    if not modules:
        raise pytest.UsageError(f"@pytest.mark.extra({extra!r}): no such extra")
    return next((m for m in modules if importlib.util.find_spec(m) is None), None)


@pytest.hookimpl(tryfirst=True)  # before fixtures that would need the extra are set up
def pytest_runtest_setup(item: pytest.Item) -> None:
    """Skip a test marked ``extra(NAME)`` when that extra is not installed, naming it."""
    for mark in item.iter_markers("extra"):
        for extra in mark.args:
            missing = _missing_extra(extra)
            if missing is not None:
                pytest.skip(
                    f"needs the {extra} extra ({missing} is not installed): "
                    f"pip install 'rfsas-hw[{extra}]'"
                )
