"""Fan-out of one bearing stream to several listeners (table, file, link).

The live table, the file writer and the link to the backend are all
listeners of the same stream; a failing listener is reported, not fatal to
the others.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from typing import Protocol, runtime_checkable

from rfsas_hw.records import BearingBatch

log = logging.getLogger(__name__)


@runtime_checkable
class BearingListener(Protocol):
    """Receives every batch of bearings a sensor produces."""

    def on_bearings(self, batch: BearingBatch) -> None:
        """Handle one batch (may be empty)."""
        ...

    def close(self) -> None:
        """Flush and release resources. Called once at the end of the stream."""
        ...


class Fanout:
    """Send each batch to every listener, in order; close them all at the end."""

    def __init__(self, listeners: Iterable[BearingListener] = ()) -> None:
        self.listeners: list[BearingListener] = list(listeners)
        self.failures: dict[str, int] = {}

    def add(self, listener: BearingListener) -> None:
        """Add a listener to the end of the list."""
        self.listeners.append(listener)

    def on_bearings(self, batch: BearingBatch) -> None:
        """Deliver ``batch`` to every listener; count (and log) a listener's failure."""
        for listener in self.listeners:
            try:
                listener.on_bearings(batch)
            except Exception as err:
                self._failed(listener, err, "failed; it keeps receiving later batches")

    def _failed(self, listener: BearingListener, err: Exception, what: str) -> None:
        name = type(listener).__name__
        self.failures[name] = self.failures.get(name, 0) + 1
        if self.failures[name] == 1:
            # one line: the run's summary reports the count, and a failing disk or
            # network must not bury the sensor's output in tracebacks
            log.warning("%s %s: %s", name, what, err)
            log.debug("%s failure", name, exc_info=True)

    def close(self) -> None:
        """Close every listener, even if one of them fails."""
        for listener in self.listeners:
            try:
                listener.close()
            except Exception as err:
                self._failed(listener, err, "could not be closed")

    def counters(self) -> dict[str, dict[str, int]]:
        """Each listener's counters (``written``, ``sent``, ``lost``, …) by listener name,
        plus ``failures`` for listeners that raised."""
        out: dict[str, dict[str, int]] = {}
        for listener in self.listeners:
            get = getattr(listener, "counters", None)
            name = listener_name(listener)
            values = dict(get()) if callable(get) else {}
            failures = self.failures.get(type(listener).__name__, 0)
            if failures:
                values["failures"] = failures
            out[name] = values
        return out

    def problems(self) -> list[str]:
        """One line per listener whose declared work failed (nothing written, nothing sent)."""
        found: list[str] = []
        for listener in self.listeners:
            name = listener_name(listener)
            error = getattr(listener, "error", None)
            if isinstance(error, str):
                found.append(f"{name}: {error}")
            elif self.failures.get(type(listener).__name__):
                found.append(f"{name}: failed {self.failures[type(listener).__name__]} time(s)")
            problem = getattr(listener, "problem", None)
            text = problem() if callable(problem) else None
            if isinstance(text, str):
                found.append(f"{name}: {text}")
        return found


def listener_name(listener: object) -> str:
    """A short name for a listener in summaries: its ``name`` attribute or its class."""
    name = getattr(listener, "name", None)
    return name if isinstance(name, str) else type(listener).__name__
