"""Latency and denial-of-service watch: per-sender message age against the budget.

Denial of service — jamming, congestion, a flood of junk datagrams — shows up
at a receiver as messages that arrive late or not at all. For each sender the
watch keeps the ages (generation → verified) of its last ``window`` messages
and a state:

- ``ok``: the budget is being met;
- ``late``: at least ``enter_fraction`` of the window missed the budget (a
  message lost on the way, seen as a gap in the sender's sequence numbers,
  counts as one that missed it; a jump of more than 4096 is taken as the
  sender restarting). The
  state only returns to ``ok`` once the late fraction drops to
  ``exit_fraction`` or below (hysteresis, so a borderline link does not
  flap);
- ``silent``: nothing verified from the sender for ``silent_s`` seconds
  (or, for a sender announced with :meth:`LatencyWatch.expect`, ever).

State changes are counted (:attr:`LatencyWatch.changes`), logged at WARNING
(alarm) / INFO (cleared) — once per change, unless the configuration turns the
log off (``log_changes``: a simulated district, whose units fall silent whenever
no phone is near, counts them only) — and passed to optional callbacks;
:meth:`LatencyWatch.snapshot` gives the backend and the user a table of every
sender's state and age statistics.
"""

from __future__ import annotations

import enum
import logging
from collections import Counter, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
SEQ_MOD = 1 << 32
MAX_GAP = 4096
"""A jump in sequence numbers larger than this is a sender restart, not a loss."""


class LinkState(enum.Enum):
    """Health of the link from one sender."""

    OK = "ok"
    LATE = "late"
    SILENT = "silent"


@dataclass(frozen=True, slots=True)
class LatencyConfig:
    """Thresholds of the latency watch.

    Raises:
        ValueError: on a non-positive budget, window or silence time, or
            fractions that are not 0 ≤ exit < enter ≤ 1.
    """

    budget_s: float = 0.100
    """Largest acceptable age (generation → verified), seconds."""
    window: int = 50
    """Number of recent messages per sender the late fraction is computed over."""
    enter_fraction: float = 0.2
    """Late fraction at or above which the sender goes ``late``."""
    exit_fraction: float = 0.05
    """Late fraction at or below which a ``late`` sender returns to ``ok``."""
    min_samples: int = 5
    """Messages needed in the window before ``late`` can be declared."""
    silent_s: float = 1.0
    """Seconds without a verified message after which a sender is ``silent``."""
    log_changes: bool = True
    """Log every state change (WARNING when raised, INFO when cleared). Off: they are
    only counted (:attr:`LatencyWatch.changes`) and passed to the callbacks."""

    def __post_init__(self) -> None:
        if self.budget_s <= 0 or self.window < 1 or self.silent_s <= 0 or self.min_samples < 1:
            raise ValueError("latency budget, window, min_samples and silent_s must be positive")
        if not 0.0 <= self.exit_fraction < self.enter_fraction <= 1.0:
            raise ValueError(
                "latency fractions must satisfy 0 <= exit_fraction < enter_fraction <= 1, got "
                f"exit {self.exit_fraction}, enter {self.enter_fraction}"
            )


@dataclass(frozen=True, slots=True)
class SenderLatency:
    """One sender's link health at one moment."""

    sender_id: str
    state: LinkState
    messages: int
    """Verified messages seen from this sender in total."""
    lost: int
    """Messages missing from the sender's sequence (lost, dropped, or rejected)."""
    late_fraction: float
    """Fraction of the window over budget (NaN before the first message)."""
    p50_ms: float
    """Median age over the window, milliseconds (NaN before the first message)."""
    p99_ms: float
    """99th-percentile age over the window, milliseconds (NaN before the first message)."""
    last_age_ms: float
    """Age of the most recent message, milliseconds (NaN before the first message)."""
    silent_for_s: float
    """Seconds since the last verified message (or since it was expected)."""


@dataclass(slots=True)
class _Track:
    ages_s: deque[float]
    last_seen_ns: int
    messages: int = 0
    late: bool = False
    state: LinkState = LinkState.OK
    last_age_s: float = float("nan")
    late_flags: deque[bool] = field(default_factory=deque)
    last_seq: int | None = None
    lost: int = 0


StateCallback = Callable[[str, LinkState, LinkState], None]
"""Called as ``callback(sender_id, old_state, new_state)`` on every state change."""


class LatencyWatch:
    """Per-sender age tracking with a hysteretic ``late`` alarm and silence detection.

    Args:
        config: thresholds.
        on_change: callbacks called on every state change.
    """

    def __init__(
        self, config: LatencyConfig | None = None, on_change: Iterable[StateCallback] = ()
    ) -> None:
        self.config = config or LatencyConfig()
        self._tracks: dict[str, _Track] = {}
        self._callbacks = list(on_change)
        self.changes: Counter[str] = Counter()
        """State changes so far, by the state entered (``ok``, ``late``, ``silent``)."""

    def add_callback(self, callback: StateCallback) -> None:
        """Call ``callback(sender_id, old, new)`` on every future state change."""
        self._callbacks.append(callback)

    def expect(self, sender_ids: Iterable[str], now_ns: int) -> None:
        """Announce senders that should be heard: each goes ``silent`` if nothing
        arrives within ``silent_s`` of ``now_ns`` (UTC ns)."""
        for sender_id in sender_ids:
            if sender_id not in self._tracks:
                self._tracks[sender_id] = self._new_track(now_ns)

    def _new_track(self, now_ns: int) -> _Track:
        window = self.config.window
        return _Track(
            ages_s=deque(maxlen=window), last_seen_ns=now_ns, late_flags=deque(maxlen=window)
        )

    def observe(
        self, sender_id: str, age_s: float, now_ns: int, seq: int | None = None
    ) -> LinkState:
        """Record a verified message of age ``age_s`` (seconds) received at ``now_ns``,
        with its 32-bit sequence number ``seq`` if known (gaps count as lost messages).

        Returns the sender's state after the update.
        """
        track = self._tracks.get(sender_id)
        if track is None:
            track = self._tracks[sender_id] = self._new_track(now_ns)
        cfg = self.config
        if seq is not None:
            self._count_gap(track, seq)
        age = max(0.0, float(age_s))
        track.ages_s.append(age)
        track.late_flags.append(age > cfg.budget_s)
        track.last_seen_ns = now_ns
        track.last_age_s = age
        track.messages += 1
        n = len(track.late_flags)
        fraction = sum(track.late_flags) / n
        if track.late:
            track.late = fraction > cfg.exit_fraction
        else:
            track.late = n >= cfg.min_samples and fraction >= cfg.enter_fraction
        self._set(sender_id, track, LinkState.LATE if track.late else LinkState.OK)
        return track.state

    def _count_gap(self, track: _Track, seq: int) -> None:
        last = track.last_seq
        if last is None:
            track.last_seq = seq
            return
        ahead = (seq - last) % SEQ_MOD
        behind = (last - seq) % SEQ_MOD
        if 0 < ahead <= MAX_GAP:
            missing = ahead - 1
            if missing:
                track.lost += missing
                track.late_flags.extend([True] * min(missing, self.config.window))
            track.last_seq = seq
        elif behind > MAX_GAP:
            # far from anything recent: the sender restarted with a new sequence
            track.last_seq = seq
        # otherwise a late, reordered message: no gap, and the newest stays the reference

    def poll(self, now_ns: int) -> None:
        """Mark senders not heard for ``silent_s`` seconds at ``now_ns`` as ``silent``."""
        limit = int(self.config.silent_s * NS_PER_S)
        for sender_id, track in self._tracks.items():
            if now_ns - track.last_seen_ns >= limit:
                self._set(sender_id, track, LinkState.SILENT)

    def _set(self, sender_id: str, track: _Track, state: LinkState) -> None:
        old = track.state
        if old is state:
            return
        track.state = state
        self.changes[state.value] += 1
        if self.config.log_changes:
            self._log_change(sender_id, old, state)
        for callback in self._callbacks:
            callback(sender_id, old, state)

    def _log_change(self, sender_id: str, old: LinkState, state: LinkState) -> None:
        if state is LinkState.OK:
            log.info("link from %s: %s -> ok", sender_id, old.value)
        else:
            log.warning(
                "link from %s: %s -> %s (budget %.0f ms)",
                sender_id,
                old.value,
                state.value,
                self.config.budget_s * 1e3,
            )

    def state(self, sender_id: str) -> LinkState | None:
        """Current state of ``sender_id`` (None if never heard nor expected)."""
        track = self._tracks.get(sender_id)
        return None if track is None else track.state

    @property
    def alarm(self) -> bool:
        """True when any tracked sender is ``late`` or ``silent``."""
        return any(t.state is not LinkState.OK for t in self._tracks.values())

    def snapshot(self, now_ns: int) -> dict[str, SenderLatency]:
        """Every tracked sender's state and age statistics at ``now_ns`` (UTC ns)."""
        self.poll(now_ns)
        out = {}
        for sender_id, track in sorted(self._tracks.items()):
            if track.ages_s:
                ages_ms = np.asarray(track.ages_s) * 1e3
                p50, p99 = (float(v) for v in np.percentile(ages_ms, [50, 99]))
                fraction = sum(track.late_flags) / len(track.late_flags)
            else:
                p50 = p99 = fraction = float("nan")
            out[sender_id] = SenderLatency(
                sender_id=sender_id,
                state=track.state,
                messages=track.messages,
                lost=track.lost,
                late_fraction=fraction,
                p50_ms=p50,
                p99_ms=p99,
                last_age_ms=track.last_age_s * 1e3,
                silent_for_s=max(0, now_ns - track.last_seen_ns) / NS_PER_S,
            )
        return out
