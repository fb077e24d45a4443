"""The latency watch's state changes: logged once per change by default (a real sensor's
link), or only counted (a simulated district, whose units fall silent whenever no phone is
near); counted either way, and in the receiver's counters."""

from __future__ import annotations

import logging

import pytest
from linkhelp import NOW_NS, message

from rfsas_hw.link import Receiver, Signer, TrustedKeys
from rfsas_hw.link.latency import LatencyConfig, LatencyWatch, LinkState

S = 1_000_000_000


def _flap(watch: LatencyWatch, times: int) -> None:
    """ok → silent → ok, ``times`` times, for one sender."""
    t = NOW_NS
    for _ in range(times):
        watch.observe("rsu-1", 0.01, t)
        t += 2 * S
        watch.poll(t)
        assert watch.state("rsu-1") is LinkState.SILENT


def test_each_change_is_logged_once_by_default(caplog: pytest.LogCaptureFixture) -> None:
    watch = LatencyWatch(LatencyConfig())
    with caplog.at_level(logging.INFO, logger="rfsas_hw.link.latency"):
        _flap(watch, 3)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    cleared = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    assert warnings == ["link from rsu-1: ok -> silent (budget 100 ms)"] * 3
    assert cleared == ["link from rsu-1: silent -> ok"] * 2
    assert watch.changes == {"silent": 3, "ok": 2}


def test_changes_are_only_counted_when_not_logged(caplog: pytest.LogCaptureFixture) -> None:
    seen: list[tuple[str, LinkState, LinkState]] = []
    watch = LatencyWatch(LatencyConfig(log_changes=False), on_change=[lambda *c: seen.append(c)])
    with caplog.at_level(logging.DEBUG, logger="rfsas_hw.link.latency"):
        _flap(watch, 3)
    assert not caplog.records
    assert watch.changes == {"silent": 3, "ok": 2}
    assert len(seen) == 5  # the callbacks still hear every change


def test_the_receivers_counters_carry_the_changes(signer: Signer, trust: TrustedKeys) -> None:
    r = Receiver(trust)
    assert r.feed(signer.encode(message(seq=1)), NOW_NS) is not None
    r.latency.poll(NOW_NS + 2 * S)
    counters = r.counters()
    assert counters["latency.to_silent"] == 1
    assert "latency.to_ok" not in counters
