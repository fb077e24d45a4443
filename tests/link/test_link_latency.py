"""Latency watch: the late alarm has hysteresis, silence is detected, changes are reported."""

from __future__ import annotations

import logging

import pytest

from rfsas_hw.link import LatencyConfig, LatencyWatch, LinkState

S = 1_000_000_000
T0 = 1_763_800_000 * S


def feed(watch: LatencyWatch, ages_s: list[float], t0: int = T0, step_ns: int = S // 20) -> int:
    t = t0
    for age in ages_s:
        watch.observe("rsu-1", age, t)
        t += step_ns
    return t


def test_late_alarm_enters_at_enter_fraction_and_clears_at_exit_fraction() -> None:
    changes: list[tuple[str, LinkState, LinkState]] = []
    cfg = LatencyConfig(budget_s=0.1, window=20, enter_fraction=0.2, exit_fraction=0.05)
    watch = LatencyWatch(cfg, on_change=[lambda *c: changes.append(c)])
    t = feed(watch, [0.02] * 20)
    assert watch.state("rsu-1") is LinkState.OK and not watch.alarm
    # 3 late of 20 (15 %): still ok
    t = feed(watch, [0.3] * 3, t)
    assert watch.state("rsu-1") is LinkState.OK
    # the 4th makes 20 %: late
    t = feed(watch, [0.3], t)
    assert watch.state("rsu-1") is LinkState.LATE and watch.alarm
    # 17 on time: 3 of 20 late (15 %), under the entry level, but still late (hysteresis)
    t = feed(watch, [0.02] * 17, t)
    assert watch.state("rsu-1") is LinkState.LATE
    t = feed(watch, [0.02], t)  # 10 %
    assert watch.state("rsu-1") is LinkState.LATE
    # once at most 1 of 20 (5 %) is late, the alarm clears
    t = feed(watch, [0.02], t)
    assert watch.state("rsu-1") is LinkState.OK
    assert changes == [
        ("rsu-1", LinkState.OK, LinkState.LATE),
        ("rsu-1", LinkState.LATE, LinkState.OK),
    ]


def test_no_alarm_before_min_samples() -> None:
    watch = LatencyWatch(LatencyConfig(min_samples=5))
    feed(watch, [1.0] * 4)
    assert watch.state("rsu-1") is LinkState.OK
    feed(watch, [1.0])
    assert watch.state("rsu-1") is LinkState.LATE


def test_silent_sender_and_expected_sender(caplog: pytest.LogCaptureFixture) -> None:
    watch = LatencyWatch(LatencyConfig(silent_s=1.0))
    watch.expect(["obu-2"], T0)
    t = feed(watch, [0.01] * 5)
    watch.poll(t)
    assert watch.state("rsu-1") is LinkState.OK
    assert watch.state("obu-2") is LinkState.OK
    with caplog.at_level(logging.WARNING, logger="rfsas_hw.link.latency"):
        watch.poll(T0 + S)
    assert watch.state("obu-2") is LinkState.SILENT
    assert watch.state("rsu-1") is LinkState.OK  # last heard at T0 + 0.2 s
    assert any("obu-2: ok -> silent" in r.getMessage() for r in caplog.records)
    snap = watch.snapshot(t + 2 * S)
    assert snap["rsu-1"].state is LinkState.SILENT
    assert snap["rsu-1"].silent_for_s == pytest.approx(2.05)
    assert snap["obu-2"].messages == 0
    # a message brings the sender back
    watch.observe("rsu-1", 0.01, t + 3 * S)
    assert watch.state("rsu-1") is LinkState.OK
    assert watch.state("nobody") is None


def test_snapshot_statistics() -> None:
    watch = LatencyWatch(LatencyConfig(window=100))
    feed(watch, [i / 1000 for i in range(1, 101)])
    snap = watch.snapshot(T0)["rsu-1"]
    assert snap.messages == 100
    assert snap.p50_ms == pytest.approx(50.5)
    assert snap.p99_ms == pytest.approx(99.01)
    assert snap.last_age_ms == pytest.approx(100.0)
    assert snap.late_fraction == 0.0  # 100 ms is within a 100 ms budget


@pytest.mark.parametrize(
    "kwargs",
    [
        {"budget_s": 0.0},
        {"window": 0},
        {"enter_fraction": 0.05, "exit_fraction": 0.05},
        {"enter_fraction": 1.5},
    ],
)
def test_bad_config(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="latency"):
        LatencyConfig(**kwargs)  # type: ignore[arg-type]


def test_sequence_gaps_count_as_missed_budget() -> None:
    watch = LatencyWatch(LatencyConfig(window=20, min_samples=5))
    t = T0
    # every 5th message arrives: 80 % lost, although each one is fast
    for seq in range(2**32 - 10, 2**32 + 40, 5):
        watch.observe("rsu-1", 0.001, t, seq % 2**32)
        t += S // 10
    snap = watch.snapshot(t)["rsu-1"]
    assert snap.state is LinkState.LATE
    assert snap.lost == 4 * (snap.messages - 1)
    assert snap.late_fraction == pytest.approx(0.8)
    # a late duplicate or reordered message is not a gap
    watch2 = LatencyWatch(LatencyConfig(min_samples=1))
    for seq in (1, 2, 3, 2, 4, 5):
        watch2.observe("rsu-1", 0.001, T0, seq)
    assert watch2.snapshot(T0)["rsu-1"].lost == 0
    assert watch2.state("rsu-1") is LinkState.OK


def test_a_sender_restart_is_not_a_loss() -> None:
    watch = LatencyWatch(LatencyConfig(window=20, min_samples=5))
    t = T0
    for seq in [*range(100, 110), *range(3_000_000_000, 3_000_000_010), *range(5, 15)]:
        watch.observe("rsu-1", 0.001, t, seq)
        t += S // 10
    snap = watch.snapshot(t)["rsu-1"]
    assert snap.lost == 0 and snap.state is LinkState.OK
    watch.observe("rsu-1", 0.001, t, 16)  # and losses after the restart still count
    assert watch.snapshot(t)["rsu-1"].lost == 1
