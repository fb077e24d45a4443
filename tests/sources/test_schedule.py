"""The cue scheduler: plan, dwell, priority, airtime bound, expiry, counters, timeline."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.errors import ConfigError
from rfsas_hw.sources.schedule import ChannelCue, CueScheduler, SchedulerConfig

PLAN = tuple(range(1, 14))


def test_plan_without_cues_hops_in_order() -> None:
    s = CueScheduler(PLAN, 0.1)
    assert [s.channel_at(0.1 * k + 0.05) for k in range(15)] == [*PLAN, 1, 2]
    assert s.next_change_s(1.48) == pytest.approx(0.02)


def test_cue_interrupts_then_plan_resumes_where_it_left() -> None:
    s = CueScheduler(PLAN, 0.1, SchedulerConfig(cue_dwell_s=0.5))
    assert s.channel_at(0.25) == 3
    s.offer(ChannelCue(emitter=7, channel=11, risk=0.5, expires_s=10.0), 0.25)
    assert s.channel_at(0.25) == 11 and s.channel_at(0.74) == 11
    assert s.next_change_s(0.5) == pytest.approx(0.25)
    # 0.05 s of channel 3 were left when the cue came: they come first
    assert [s.channel_at(t) for t in (0.76, 0.81, 0.91)] == [3, 4, 5]
    assert s.stats.received == 1 and s.stats.obeyed == 1
    assert s.stats.cue_airtime_s == pytest.approx(0.5)


def test_dwell_never_outlives_the_cue() -> None:
    s = CueScheduler(PLAN, 0.1, SchedulerConfig(cue_dwell_s=1.0))
    s.offer(ChannelCue(7, 11, 0.5, expires_s=0.3), 0.0)
    assert s.channel_at(0.29) == 11 and s.channel_at(0.31) == 1


def test_higher_risk_first_and_preempts() -> None:
    s = CueScheduler(PLAN, 0.1, SchedulerConfig(cue_dwell_s=0.4, window_s=10.0))
    s.offer(ChannelCue(1, 36, 0.2, 10.0), 0.0)
    s.offer(ChannelCue(2, 40, 0.1, 10.0), 0.0)  # waits behind the running one
    assert s.channel_at(0.1) == 36
    s.offer(ChannelCue(3, 44, 0.9, 10.0), 0.1)  # preempts
    assert s.channel_at(0.2) == 44
    assert s.channel_at(0.55) == 36  # the preempted cue is served again before the low one
    assert s.channel_at(0.95) == 40
    assert s.stats.preempted == 1 and s.stats.obeyed == 4


def test_airtime_share_is_bounded_and_waiting_cues_expire() -> None:
    cfg = SchedulerConfig(cue_dwell_s=0.5, max_share=0.2, window_s=5.0)
    s = CueScheduler(PLAN, 0.1, cfg)
    for k in range(20):
        s.offer(ChannelCue(k, 11, 0.5, expires_s=k * 0.1 + 1.5), k * 0.1)
    tl = s.timeline(20.0)
    t = np.arange(0.0, 20.0, 0.001)
    on_cue = np.zeros(len(t), bool)
    for a, b in zip(tl.seg_start_s, tl.seg_end_s, strict=True):
        on_cue |= (t >= a) & (t < b)
    for start in np.arange(0.0, 15.0, 0.25):
        win = (t >= start) & (t < start + 5.0)
        assert on_cue[win].mean() <= 0.2 + 1e-3
    assert s.stats.expired > 0
    assert s.stats.obeyed + s.stats.expired + s.stats.merged == s.stats.received


def test_same_emitter_merges_and_hearing_it_ends_the_dwell() -> None:
    s = CueScheduler(PLAN, 0.1, SchedulerConfig(cue_dwell_s=0.6))
    s.offer(ChannelCue(9, 11, 0.5, 10.0), 0.0)
    s.offer(ChannelCue(9, 11, 0.6, 10.0), 0.1)
    assert s.stats.merged == 1 and s.stats.obeyed == 1
    assert s.note_heard(9, 0.2)
    assert s.stats.intercepts_gained == 1
    assert s.channel_at(0.25) == 1  # back on the plan at once
    assert not s.note_heard(9, 0.3)


@pytest.mark.parametrize("seed", [3, 4, 5])
@pytest.mark.parametrize("window_s", [1.2, 10.0])
def test_timeline_agrees_with_the_live_answers(seed: int, window_s: float) -> None:
    rng = np.random.default_rng(seed)
    live = CueScheduler(PLAN, 0.1, SchedulerConfig(window_s=window_s))
    replay = CueScheduler(PLAN, 0.1, SchedulerConfig(window_s=window_s))
    cues = [
        (
            float(t),
            ChannelCue(int(rng.integers(1, 5)), int(rng.integers(1, 14)), rng.random(), t + 1.0),
        )
        for t in np.sort(rng.uniform(0, 8, 12))
    ]
    times = np.arange(0.0005, 10.0, 0.01)
    answers = []
    k = 0
    for t in times:
        while k < len(cues) and cues[k][0] <= t:
            live.offer(cues[k][1], cues[k][0])
            replay.offer(cues[k][1], cues[k][0])
            k += 1
        answers.append(live.channel_at(float(t)))
    assert (replay.timeline(10.0).channel_at(times) == np.array(answers)).all()


def test_bad_rules_are_config_errors() -> None:
    with pytest.raises(ConfigError):
        SchedulerConfig(max_share=0.0)
    with pytest.raises(ConfigError):
        CueScheduler((), 0.1)
