"""A scan scheduler that obeys cues, shared by every tunable source.

A tunable receiver (a monitor-mode Wi-Fi card moved with ``iw``, a DF board
given scan plans, the twin's virtual sensor) normally walks its hop plan:
``channels`` in turn, ``dwell_s`` each. A *cue* ("the emitter with hash H was
heard on channel C; listen there until T") interrupts the plan:

- the cued channel is held for one cue dwell, at most ``cue_dwell_s`` and
  never past the cue's expiry; the plan is paused meanwhile and resumes on
  the channel it left, so no plan channel is skipped;
- cues wait in a queue served by risk (highest first; ties: soonest expiry);
  a new cue of strictly higher risk preempts a running dwell;
- cue dwells may take at most ``max_share`` of the airtime over any
  ``window_s`` seconds (the plan keeps finding emitters nobody has cued);
  a cue that cannot be served before it expires is counted ``expired``;
- a cue for an emitter already queued or being served updates it (counted
  ``merged``); hearing the cued emitter during its dwell ends the dwell early
  and counts an ``intercepts_gained`` when the plan was elsewhere.

The scheduler is pure logic on a caller's clock (seconds, non-decreasing);
it never touches hardware. Sources ask :meth:`CueScheduler.channel_at` and
:meth:`CueScheduler.next_change_s`; the twin asks for a :class:`Timeline`.
It knows nothing of the link: whoever receives a signed cue turns it into a
:class:`ChannelCue` on this clock.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import ConfigError
from rfsas_hw.records import BearingBatch

_EPS = 1e-9


@dataclass(frozen=True, slots=True)
class ChannelCue:
    """A cue as the scheduler sees it."""

    emitter: int
    """Keyed hash of the cued emitter (the scheduler only compares it)."""
    channel: int
    """Channel to listen on."""
    risk: float
    """Priority, 0–1 (higher first)."""
    expires_s: float
    """Scheduler-clock time after which the cue must not be obeyed, seconds."""


@dataclass(frozen=True, slots=True)
class SchedulerConfig:
    """Rules of the cue scheduler.

    Raises:
        ConfigError: non-positive dwell or window, or a share outside (0, 1].
    """

    cue_dwell_s: float = 0.6
    """Longest dwell on a cued channel, seconds (about one burst period of a phone)."""
    max_share: float = 0.5
    """Largest fraction of airtime cue dwells may take over ``window_s``."""
    window_s: float = 1.2
    """Window of the airtime bound, seconds. Short on purpose: with a long window a
    stream of cues spends the whole budget at once and then leaves the receiver
    uncued for as long (in the twin's demo a 10 s window ran the budget out just
    before the pedestrian stepped out)."""
    min_dwell_s: float = 0.05
    """A dwell shorter than this is not started (the budget waits to refill), seconds."""
    max_pending: int = 32
    """Most cues queued; beyond it the lowest-risk one is dropped (counted ``expired``)."""

    def __post_init__(self) -> None:
        if not (self.cue_dwell_s > 0 and self.window_s > 0 and self.min_dwell_s > 0):
            raise ConfigError("scheduler: cue_dwell_s, window_s and min_dwell_s must be positive")
        if not 0.0 < self.max_share <= 1.0:
            raise ConfigError(f"scheduler: max_share {self.max_share} outside (0, 1]")
        if self.max_share * self.window_s < self.min_dwell_s:
            raise ConfigError("scheduler: max_share × window_s is shorter than min_dwell_s")
        if self.max_pending < 1:
            raise ConfigError("scheduler: max_pending must be at least 1")


@dataclass(slots=True)
class SchedulerStats:
    """What the scheduler did with the cues it was given."""

    received: int = 0
    """Cues offered."""
    obeyed: int = 0
    """Cue dwells started."""
    expired: int = 0
    """Cues that expired (or were dropped from a full queue) before they were served."""
    merged: int = 0
    """Cues that updated one already queued or running for the same emitter."""
    preempted: int = 0
    """Running dwells cut short by a higher-risk cue."""
    intercepts_gained: int = 0
    """Cued emitters heard during a cue dwell on a channel the plan was not on."""
    cue_airtime_s: float = 0.0
    """Time spent on cued channels, seconds."""

    def as_dict(self) -> dict[str, float]:
        """Flat counters."""
        return {
            "cues_received": self.received,
            "cues_obeyed": self.obeyed,
            "cues_expired": self.expired,
            "cues_merged": self.merged,
            "cues_preempted": self.preempted,
            "intercepts_gained": self.intercepts_gained,
            "cue_airtime_s": round(self.cue_airtime_s, 3),
        }


@dataclass(slots=True)
class _Dwell:
    cue: ChannelCue
    start_s: float
    end_s: float
    plan_channel: int
    heard: bool = False


@dataclass(frozen=True)
class Timeline:
    """Which channel a scheduled receiver was on, as a function of time.

    Built by :meth:`CueScheduler.timeline`: cue dwells as segments, the plan in
    between, paused during each dwell.
    """

    channels: tuple[int, ...]
    dwell_s: float
    start_s: float
    seg_start_s: npt.NDArray[np.float64]
    seg_end_s: npt.NDArray[np.float64]
    seg_channel: npt.NDArray[np.int64]

    def channel_at(self, t_s: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Channel at each time (scheduler clock, seconds); the plan's first before the start."""
        t = np.atleast_1d(np.asarray(t_s, np.float64))
        n = len(self.seg_start_s)
        plan_ch = np.asarray(self.channels, np.int64)
        if n == 0:
            plan_t = np.maximum(t - self.start_s, 0.0)
            slot = np.floor(plan_t / self.dwell_s + _EPS).astype(np.int64) % len(plan_ch)
            return plan_ch[slot]
        k = np.searchsorted(self.seg_start_s, t, side="right") - 1
        kc = np.clip(k, 0, n - 1)
        started = k >= 0
        inside = started & (t < self.seg_end_s[kc])
        # cue time before each segment: the plan is paused for all of it
        cum = np.concatenate(([0.0], np.cumsum(self.seg_end_s - self.seg_start_s)))
        paused = np.where(
            inside,
            cum[kc] + (t - self.seg_start_s[kc]),
            np.where(started, cum[kc + 1], 0.0),
        )
        plan_t = np.maximum(t - self.start_s - paused, 0.0)
        slot = np.floor(plan_t / self.dwell_s + _EPS).astype(np.int64) % len(plan_ch)
        return np.where(inside, self.seg_channel[kc], plan_ch[slot])

    def listens(self, t_s: npt.ArrayLike, channel: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Whether the receiver was on ``channel`` at ``t_s`` (element-wise)."""
        return np.asarray(self.channel_at(t_s) == np.asarray(channel), bool)


class CueInbox(Protocol):
    """Where a scheduler pulls newly arrived cues from (a cue receiver on the link)."""

    def poll(self, now_s: float) -> list[ChannelCue]:
        """Cues that arrived since the last poll, on the scheduler's clock (``now_s``)."""
        ...


class NoteHeard:
    """A bearing listener that tells a scheduler which emitters its sensor now hears.

    Args:
        scheduler: the source's scheduler.
        now_s: the scheduler's clock (the source's ``now_s``).
    """

    def __init__(self, scheduler: CueScheduler, now_s: Callable[[], float]) -> None:
        self.scheduler = scheduler
        self.now_s = now_s

    def on_bearings(self, batch: BearingBatch) -> None:
        """Report every emitter of ``batch`` as heard now."""
        if len(batch) == 0:
            return
        now = self.now_s()
        for emitter in np.unique(batch.emitter).tolist():
            self.scheduler.note_heard(int(emitter), now)

    def close(self) -> None:
        """Nothing to release."""


class CueScheduler:
    """Hop plan plus cues (see the module docstring).

    Args:
        channels: the hop plan, in visiting order.
        dwell_s: time per plan channel, seconds.
        config: cue rules.
        start_s: scheduler-clock time the plan starts, seconds.

    Raises:
        ConfigError: an empty plan or a non-positive dwell.
    """

    def __init__(
        self,
        channels: Sequence[int],
        dwell_s: float,
        config: SchedulerConfig | None = None,
        start_s: float = 0.0,
    ) -> None:
        if not channels:
            raise ConfigError("a scan plan needs at least one channel")
        if not dwell_s > 0:
            raise ConfigError(f"scan plan dwell must be positive, got {dwell_s} s")
        self.channels = tuple(int(c) for c in channels)
        self.dwell_s = float(dwell_s)
        self.config = config or SchedulerConfig()
        self.start_s = float(start_s)
        self.stats = SchedulerStats()
        self.inbox: CueInbox | None = None
        """Where :meth:`pull` takes new cues from (None: cues are only :meth:`offer` ed)."""
        self._now = self.start_s
        self._plan_s = 0.0
        self._active: _Dwell | None = None
        self._pending: list[ChannelCue] = []
        self._segments: list[tuple[float, float, int]] = []

    # -- the plan ---------------------------------------------------------------

    def _plan_channel(self) -> int:
        slot = math.floor(self._plan_s / self.dwell_s + _EPS) % len(self.channels)
        return self.channels[slot]

    def _used_s(self, t: float) -> float:
        """Cue airtime inside ``[t - window_s, t]``."""
        lo = t - self.config.window_s
        used = 0.0
        for start, end, _ in reversed(self._segments):
            if end <= lo:
                break
            used += min(end, t) - max(start, lo)
        if self._active is not None:
            used += max(0.0, min(self._active.end_s, t) - max(self._active.start_s, lo))
        return used

    def _budget_free_at(self, t: float) -> float:
        """Earliest time after ``t`` at which a minimal dwell fits the airtime bound.

        While cues wait for budget nothing is added to the airtime, so the used
        airtime only falls, linearly between the points where a past dwell's start
        or end leaves the window: find the first such point where enough is free
        and interpolate back from it.
        """
        cfg = self.config
        target = cfg.max_share * cfg.window_s - cfg.min_dwell_s
        points = sorted(
            {p for seg in self._segments for p in (seg[0] + cfg.window_s, seg[1] + cfg.window_s)}
        )
        prev_t, prev_used = t, self._used_s(t)
        if prev_used <= target + _EPS:
            return t
        for p in points:
            if p <= t:
                continue
            used = self._used_s(p)
            if used <= target + _EPS:
                # linear on [prev_t, p]
                frac = (prev_used - target) / (prev_used - used) if prev_used > used else 1.0
                return prev_t + frac * (p - prev_t)
            prev_t, prev_used = p, used
        return math.inf

    # -- time -------------------------------------------------------------------

    def _finish(self, at: float) -> None:
        d = self._active
        assert d is not None
        self._segments.append((d.start_s, at, d.cue.channel))
        self.stats.cue_airtime_s += at - d.start_s
        self._active = None

    def _drop_expired(self, t: float) -> None:
        alive = [c for c in self._pending if c.expires_s > t + _EPS]
        self.stats.expired += len(self._pending) - len(alive)
        self._pending = alive

    def _try_start(self, t: float) -> bool:
        self._drop_expired(t)
        if not self._pending:
            return False
        cfg = self.config
        room = cfg.max_share * cfg.window_s - self._used_s(t)
        cue = self._pending[0]
        length = min(cfg.cue_dwell_s, cue.expires_s - t, room)
        if length < cfg.min_dwell_s - _EPS:
            return False
        self._pending.pop(0)
        self._active = _Dwell(cue, t, t + length, self._plan_channel())
        self.stats.obeyed += 1
        return True

    def advance(self, now_s: float) -> None:
        """Run the schedule up to ``now_s`` (earlier times are ignored)."""
        while self._now < now_s - _EPS:
            t = self._now
            if self._active is not None:
                end = min(self._active.end_s, now_s)
                if end >= self._active.end_s - _EPS:
                    self._finish(self._active.end_s)
                self._now = end
                continue
            if self._try_start(t):
                continue
            # the plan runs until now, the next expiry, or the budget freeing up
            nxt = now_s
            if self._pending:
                nxt = min(nxt, min(c.expires_s for c in self._pending))
                nxt = min(nxt, self._budget_free_at(t))
            nxt = max(nxt, t + _EPS)
            self._plan_s += nxt - t
            self._now = nxt
            self._drop_expired(self._now)
        if self._active is None:
            self._try_start(self._now)

    # -- cues -------------------------------------------------------------------

    def offer(self, cue: ChannelCue, now_s: float) -> None:
        """Take a cue at ``now_s``; it may start a dwell at once."""
        self.advance(now_s)
        self.stats.received += 1
        if cue.expires_s <= now_s:
            self.stats.expired += 1
            return
        active = self._active
        if active is not None and active.cue.emitter == cue.emitter:
            self.stats.merged += 1
            if cue.channel == active.cue.channel:
                return
        for k, queued in enumerate(self._pending):
            if queued.emitter == cue.emitter:
                self.stats.merged += 1
                del self._pending[k]
                break
        self._pending.append(cue)
        self._pending.sort(key=lambda c: (-c.risk, c.expires_s))
        if len(self._pending) > self.config.max_pending:
            self._pending.pop()
            self.stats.expired += 1
        if active is not None and cue.risk > active.cue.risk:
            self.stats.preempted += 1
            self._finish(now_s)
            self._pending.append(active.cue)
            self._pending.sort(key=lambda c: (-c.risk, c.expires_s))
        if self._active is None:
            self._try_start(now_s)

    def pull(self, now_s: float) -> int:
        """Offer every cue waiting in :attr:`inbox` at ``now_s``; returns how many."""
        if self.inbox is None:
            return 0
        cues = self.inbox.poll(now_s)
        for cue in cues:
            self.offer(cue, now_s)
        return len(cues)

    def note_heard(self, emitter: int, now_s: float) -> bool:
        """Report that ``emitter`` was heard at ``now_s``; True if it was the cued one.

        Ends the running dwell for it (the vehicle now has its own bearing) and
        drops any queued cue for it.
        """
        self.advance(now_s)
        before = len(self._pending)
        self._pending = [c for c in self._pending if c.emitter != emitter]
        hit = len(self._pending) != before
        d = self._active
        if d is not None and d.cue.emitter == emitter:
            if d.cue.channel != d.plan_channel:
                self.stats.intercepts_gained += 1
            self._finish(now_s)
            self._try_start(now_s)
            return True
        return hit

    # -- what sources ask -------------------------------------------------------

    def channel_at(self, now_s: float) -> int:
        """The channel to be on at ``now_s``."""
        self.advance(now_s)
        if self._active is not None:
            return self._active.cue.channel
        return self._plan_channel()

    @property
    def cued(self) -> ChannelCue | None:
        """The cue being served now, if any."""
        return self._active.cue if self._active is not None else None

    def next_change_s(self, now_s: float) -> float:
        """Seconds from ``now_s`` until the channel may change (a new cue may come sooner)."""
        self.advance(now_s)
        if self._active is not None:
            return max(self._active.end_s - now_s, 0.0)
        into = self._plan_s % self.dwell_s
        left = self.dwell_s - into if self.dwell_s - into > _EPS else self.dwell_s
        if len(self.channels) == 1:
            left = math.inf
        if self._pending:
            left = min(left, self._budget_free_at(now_s) - now_s)
        return max(left, 0.0)

    def timeline(self, until_s: float) -> Timeline:
        """The channel history from the start to ``until_s`` (advances the schedule there)."""
        self.advance(until_s)
        segs = list(self._segments)
        if self._active is not None:
            segs.append((self._active.start_s, self._active.end_s, self._active.cue.channel))
        segs.sort()
        starts = [s for s, _, _ in segs]
        return Timeline(
            channels=self.channels,
            dwell_s=self.dwell_s,
            start_s=self.start_s,
            seg_start_s=np.array(starts, np.float64),
            seg_end_s=np.array([e for _, e, _ in segs], np.float64),
            seg_channel=np.array([c for _, _, c in segs], np.int64),
        )
