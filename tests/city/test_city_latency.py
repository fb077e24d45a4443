"""LatencyMatch: a backend's report and the arrival of the advisory, in either order."""

from __future__ import annotations

import pytest

from rfsas_hw.city.latency import ARRIVED_MEMORY_S, NS_PER_S, LatencyMatch


def test_latency_comes_with_whichever_half_comes_second() -> None:
    match = LatencyMatch()
    # the report first, then the arrival (the usual order)
    assert match.sent(("be-1", 7), 1_000_000_000) is None
    assert match.arrived(("be-1", 7), 1_030_000_000) == pytest.approx(0.030)
    # the arrival first: an advisory published early in a long judging pass reaches its
    # car before its backend reports what it carried
    assert match.arrived(("be-2", 7), 2_045_000_000) is None
    assert match.sent(("be-2", 7), 2_000_000_000) == pytest.approx(0.045)
    assert len(match) == 0


def test_an_arrival_no_report_claims_is_forgotten_in_time() -> None:
    match = LatencyMatch()
    t0 = 10 * NS_PER_S
    assert match.arrived(("be-1", 1), t0) is None  # it carried no fix of its step
    assert match.arrived(("be-1", 2), t0 + NS_PER_S) is None
    match.forget(t0 + round(ARRIVED_MEMORY_S * NS_PER_S) + 1)
    assert len(match) == 1  # the older one went, the newer one waits
    assert match.sent(("be-1", 1), t0 - NS_PER_S) is None  # too late: waits for an arrival
    assert match.sent(("be-1", 2), t0) == pytest.approx(1.0)
