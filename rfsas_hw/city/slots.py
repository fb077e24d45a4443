"""A twin worker's sending side: each group of bearings published when its time has come.

The simulation runs ahead of the deployment's clock, so a twin worker knows a
step's frames before they are "heard". A sensor sends what it hears as it hears
it; the worker stands for that by publishing each group of bearings (a unit's
frames of one :data:`SLOT_S` slot) when its slot is over on the deployment's clock.
:class:`SlotSender` does that in a thread of its own, so the worker computes
the next step while the slots of this one go out on time (in the worker's
thread, a slot due during a step's computation would wait for it).

Each message is stamped with the time of its slot (:meth:`SlotSender.stamp_ns`,
the publishers' clock): its age at a receiver is then the age of the frames it
carries, give or take a slot, and a worker that publishes late shows as old
messages, never as young ones.

A group whose time is already further behind the clock than the receivers'
age limit (``shed_after_s``) when it comes up is not published: every receiver
would refuse it as ``stale``, so signing, sending and refusing it would only
spend the CPU that a run behind its clock needs to catch up. Such groups are
counted (:attr:`SlotStats.shed`), as a sensor that sheds its backlog would
count them.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Protocol

from rfsas_hw.records import BearingBatch

NS_PER_S = 1_000_000_000
SLOT_S = 0.02
"""The sensors' slot, seconds: a twin worker publishes a unit's frames of each slot as
one message when the slot is over, and a district backend steps between its ticks
on the same grid (:class:`~rfsas_hw.city.backendproc.Cadence`). One message per
unit and slot with bearings: a longer slot means fewer, larger messages, and a
frame waits up to one slot longer."""
CLOSE_TIMEOUT_S = 10.0
"""How long :meth:`SlotSender.close` waits for the due groups to go, wall seconds."""

__all__ = ["SLOT_S", "SlotSender", "SlotStats"]

log = logging.getLogger(__name__)


class _Sends(Protocol):
    def on_bearings(self, batch: BearingBatch) -> None: ...


class _Clock(Protocol):
    def __call__(self) -> int: ...

    def wall_s(self, clock_s: float) -> float: ...


@dataclass
class SlotStats:
    """How the groups went out."""

    groups: int = 0
    """Groups published."""
    late: int = 0
    """Of them, published more than ``late_s`` after their time."""
    late_max_s: float = 0.0
    """The largest delay of a published group behind its time, seconds of the clock."""
    shed: int = 0
    """Groups not published: their time was more than ``shed_after_s`` behind the
    clock when they came up."""


class SlotSender:
    """Publishes groups of bearings at their times, in a thread (see the module docstring).

    Args:
        publishers: by unit id; each group goes to its unit's publisher.
        clock: the deployment's clock (UTC ns; ``wall_s`` converts its seconds to wall
            seconds).
        late_s: a group published more than this after its time counts as late, seconds.
        shed_after_s: a group more than this behind its time is not published (the
            receivers' age limit, seconds); None: every group is published.

    Raises:
        ValueError: ``shed_after_s`` is not above ``late_s``.
    """

    def __init__(
        self,
        publishers: Mapping[str, _Sends],
        clock: _Clock,
        late_s: float = 0.02,
        shed_after_s: float | None = None,
    ) -> None:
        if shed_after_s is not None and not shed_after_s > late_s:
            raise ValueError(f"shed_after_s ({shed_after_s}) must be above late_s ({late_s})")
        self.publishers = publishers
        self.clock = clock
        self.late_ns = round(late_s * NS_PER_S)
        self.shed_ns = None if shed_after_s is None else round(shed_after_s * NS_PER_S)
        self.stats = SlotStats()
        self.error: BaseException | None = None
        """What stopped the thread (it publishes nothing more), or None."""
        self._stamp_ns = 0
        self._queue: list[tuple[int, int, str, BearingBatch]] = []
        """A heap of (time, order queued, unit id, bearings)."""
        self._order = itertools.count()
        self._cond = threading.Condition()
        self._closing = False
        self._thread = threading.Thread(target=self._run, name="slot-sender", daemon=True)
        self._thread.start()

    def stamp_ns(self) -> int:
        """The generation time of the message being published: its group's time, UTC ns
        (the publishers' clock)."""
        return self._stamp_ns

    def put(self, groups: Iterable[tuple[int, str, BearingBatch]]) -> None:
        """Queue groups of bearings as (time UTC ns, unit id, bearings); each is published
        once the clock reaches its time (at once when that has passed), earliest first
        (groups of one time in the order queued)."""
        with self._cond:
            for when, unit, batch in groups:
                heapq.heappush(self._queue, (when, next(self._order), unit, batch))
            self._cond.notify()

    def pending(self) -> int:
        """Groups waiting for their time."""
        with self._cond:
            return len(self._queue)

    def _next(self) -> tuple[int, str, BearingBatch] | None:
        """The first group once its time has come (None: closing and nothing left)."""
        with self._cond:
            while True:
                if self._queue:
                    wait_ns = self._queue[0][0] - self.clock()
                    if wait_ns <= 0:
                        when, _, unit, batch = heapq.heappop(self._queue)
                        return when, unit, batch
                    self._cond.wait(self.clock.wall_s(wait_ns / NS_PER_S))
                elif self._closing:
                    return None
                else:
                    self._cond.wait()

    def _run(self) -> None:
        try:
            while (group := self._next()) is not None:
                when, unit, batch = group
                behind = self.clock() - when
                if self.shed_ns is not None and behind > self.shed_ns:
                    self.stats.shed += 1  # every receiver would refuse it as stale
                    continue
                self._stamp_ns = when
                self.publishers[unit].on_bearings(batch)
                self.stats.groups += 1
                if behind > self.late_ns:
                    self.stats.late += 1
                self.stats.late_max_s = max(self.stats.late_max_s, behind / NS_PER_S)
        except BaseException as err:  # reported by the owner (check)
            log.debug("slot sender failed", exc_info=True)
            self.error = err

    def check(self) -> None:
        """Raise what stopped the thread, if anything did.

        Raises:
            the thread's exception.
        """
        if self.error is not None:
            raise self.error

    def close(self, on_timeout: Callable[[int], None] | None = None) -> None:
        """Publish what is queued (each at its time), then stop the thread. Idempotent.

        Args:
            on_timeout: called with the number of groups left unsent when they did not
                all go within :data:`CLOSE_TIMEOUT_S`.
        """
        with self._cond:
            self._closing = True
            self._cond.notify()
        self._thread.join(CLOSE_TIMEOUT_S)
        if self._thread.is_alive() and on_timeout is not None:
            on_timeout(self.pending())
