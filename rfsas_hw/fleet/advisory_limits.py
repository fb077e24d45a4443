"""How many advisories a backend publishes: a bound per vehicle and per emitter.

Every backend step judges every track, and a sink that published every
assessment of every step would publish without bound: a crowd of new emitters
(or a flood of forged ids that became tracks) made a backend publish about
9,700 advisories per second. The limiter between the backend's steps and the
broker keeps, per vehicle (one advisory sink):

- per emitter: an assessment goes out when the emitter is new, when its advice
  is more severe than the last one sent for it (``clear`` → ``caution`` →
  ``brake`` go out at once), or ``min_interval_s`` after the last one sent for
  it (0.09 s by default: one per step of the default 0.1 s, about 10 Hz, however
  often the backend steps); with ``brake_interval_s`` set, advice after a
  ``brake`` (an unchanged ``brake``, or milder advice) goes out that long after it
  instead: a vehicle that holds a BRAKE only for a while after the last one it
  heard needs those sooner than the repeats of milder advice, which it does not
  act on by time;
- with ``ride_along_s`` > 0, when a step sends anything to the vehicle, its
  unchanged assessments sent at least ``ride_along_s`` ago go with them, early,
  instead of each in a message of its own later: a vehicle near several
  emitters then gets their repeats together, about one message per
  ``min_interval_s``, instead of one per emitter, each at its own phase. No
  assessment goes out later than without it (0, the default: off);
- per vehicle: at most ``max_per_s`` assessments per second (100 by default, a
  token bucket with a burst of as many); when a step offers more, the most
  severe go first (then the highest collision probability), and the others
  are held back (counted as ``limited``) to go out in a later step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

from rfsas_hw.backend.risk import ADVISORY_RANK

__all__ = ["Advice", "AdvisoryLimiter", "AdvisoryLimits"]


class Advice(Protocol):
    """What the limits look at in an assessment (an ``Assessment`` or an
    ``AdvisoryItem``): whose it is, its advice, its collision probability."""

    @property
    def emitter(self) -> str: ...
    @property
    def advisory(self) -> str: ...
    @property
    def p_collision(self) -> float: ...


A = TypeVar("A", bound=Advice)
_CLEAR = ADVISORY_RANK["clear"]
_BRAKE = ADVISORY_RANK["brake"]


@dataclass(frozen=True, slots=True)
class AdvisoryLimits:
    """The limits of :class:`AdvisoryLimiter` (see the module docstring).

    Raises:
        ValueError: a negative interval or a rate below 1 per second.
    """

    min_interval_s: float = 0.09
    """Least time between two assessments of one emitter whose advice did not get
    more severe, seconds."""
    max_per_s: float = 100.0
    """Assessments per second per vehicle, on average (also the burst)."""
    memory: int = 4096
    """Emitters remembered; the longest unsent go first."""
    ride_along_s: float = 0.0
    """When a step sends anything, unchanged assessments sent at least this long ago go
    with it (0: off), seconds; at most ``min_interval_s`` and ``brake_interval_s``."""
    brake_interval_s: float | None = None
    """Least time after a ``brake`` went out for an emitter before its unchanged or
    milder advice goes again, seconds (None: ``min_interval_s``, as after any advice)."""

    def __post_init__(self) -> None:
        if self.min_interval_s < 0 or self.max_per_s < 1 or self.memory < 1:
            raise ValueError("min_interval_s must be >= 0, max_per_s and memory >= 1")
        if self.brake_interval_s is not None and self.brake_interval_s < 0:
            raise ValueError(f"brake_interval_s must be >= 0, got {self.brake_interval_s:g}")
        shortest = min(self.min_interval_s, self.interval_s(_BRAKE))
        if not 0.0 <= self.ride_along_s <= shortest:
            raise ValueError(
                f"ride_along_s must be in [0, {shortest:g}] (the shortest repeat interval), "
                f"got {self.ride_along_s:g}"
            )

    def interval_s(self, severity: int) -> float:
        """Least time after advice of rank ``severity``
        (:data:`~rfsas_hw.backend.risk.ADVISORY_RANK`) went out for an emitter before
        its unchanged or milder advice goes again, seconds."""
        if severity == _BRAKE and self.brake_interval_s is not None:
            return self.brake_interval_s
        return self.min_interval_s


class AdvisoryLimiter:
    """Chooses which of a step's assessments go out (see the module docstring)."""

    def __init__(self, limits: AdvisoryLimits | None = None) -> None:
        self.limits = limits or AdvisoryLimits()
        self.limited = 0
        """Assessments held back by either limit so far."""
        self._last: dict[str, tuple[float, int]] = {}
        """Emitter → (when its last assessment went out, monotonic s; its severity)."""
        self._tokens = self.limits.max_per_s
        self._filled_at: float | None = None
        self.unsettled: set[str] = set()
        """Emitters whose last assessment that went out was more severe than ``clear``
        (the vehicle has not been told since that they are clear)."""

    def select(self, items: Sequence[A], now_s: float) -> list[A]:
        """The items of one step that go out at ``now_s`` (monotonic seconds): those due,
        most severe first, then the riders (``ride_along_s``); the others are counted
        in :attr:`limited`."""
        lim = self.limits
        due = []
        riders = []
        for item in items:
            severity = ADVISORY_RANK.get(item.advisory, 0)
            if self.due(item.emitter, severity, now_s):
                due.append((severity, item))
            elif lim.ride_along_s > 0 and now_s - self._last[item.emitter][0] >= lim.ride_along_s:
                riders.append((severity, item))
        self._refill(now_s)
        due.sort(key=lambda d: (-d[0], -_finite(d[1].p_collision)))
        if due:  # the riders only after every due one, and only with a message going
            riders.sort(key=lambda d: (-d[0], -_finite(d[1].p_collision)))
            due += riders
        take = min(len(due), int(self._tokens))
        self._tokens -= take
        self.limited += len(items) - take
        chosen = [item for _, item in due[:take]]
        for severity, item in due[:take]:
            self._last.pop(item.emitter, None)
            self._last[item.emitter] = (now_s, severity)
            if severity > _CLEAR:
                self.unsettled.add(item.emitter)
            else:
                self.unsettled.discard(item.emitter)
        while len(self._last) > lim.memory:
            forgotten = next(iter(self._last))
            del self._last[forgotten]
            self.unsettled.discard(forgotten)
        return chosen

    def due(self, emitter: str, severity: int, now_s: float) -> bool:
        """Whether advice of rank ``severity`` (:data:`~rfsas_hw.backend.risk.ADVISORY_RANK`)
        about ``emitter`` would be due at ``now_s`` (monotonic seconds): the emitter is
        new, the advice more severe than the last sent, or the interval of the advice
        last sent has passed (unchanged or milder advice repeats at it). A step of items
        none of which is due sends nothing (riders go only with a due item)."""
        last = self._last.get(emitter)
        return (
            last is None or severity > last[1] or now_s - last[0] >= self.limits.interval_s(last[1])
        )

    def _refill(self, now_s: float) -> None:
        if self._filled_at is not None:
            rate = self.limits.max_per_s
            self._tokens = min(rate, self._tokens + (now_s - self._filled_at) * rate)
        self._filled_at = now_s


def _finite(value: float) -> float:
    return value if math.isfinite(value) else 0.0
