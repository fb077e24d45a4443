"""LatencyMatch: a backend's report and the arrival of the advisory, in either order."""

from __future__ import annotations

import pytest

from rfsas_hw.city.latency import ARRIVED_MEMORY_S, NS_PER_S, LatencyMatch, LatencyParts


def test_latency_comes_with_whichever_half_comes_second() -> None:
    match = LatencyMatch()
    # the report first, then the arrival (the usual order): the frame at 1.000 s, its
    # backend's step from 1.012 s, signed at 1.020 s, verified at its car at 1.030 s
    assert match.sent(("be-1", 7), 1_000_000_000, 1_012_000_000) is None
    got = match.arrived(("be-1", 7), 1_030_000_000, 1_020_000_000)
    assert got == pytest.approx(LatencyParts(0.012, 0.008, 0.010))
    assert got is not None and got.total_s == pytest.approx(0.030)
    # the arrival first: an advisory published early in a long judging pass reaches its
    # car before its backend reports what it carried
    assert match.arrived(("be-2", 7), 2_045_000_000, 2_040_000_000) is None
    got = match.sent(("be-2", 7), 2_000_000_000, 2_025_000_000)
    assert got == pytest.approx(LatencyParts(0.025, 0.015, 0.005))
    assert len(match) == 0


def test_an_arrival_no_report_claims_is_forgotten_in_time() -> None:
    match = LatencyMatch()
    t0 = 10 * NS_PER_S
    assert match.arrived(("be-1", 1), t0, t0) is None  # it carried no fix of its step
    assert match.arrived(("be-1", 2), t0 + NS_PER_S, t0) is None
    match.forget(t0 + round(ARRIVED_MEMORY_S * NS_PER_S) + 1)
    assert len(match) == 1  # the older one went, the newer one waits
    # too late: waits for an arrival
    assert match.sent(("be-1", 1), t0 - NS_PER_S, t0 - NS_PER_S) is None
    got = match.sent(("be-1", 2), t0 - NS_PER_S, t0 - NS_PER_S)
    assert got is not None and got.total_s == pytest.approx(2.0)
