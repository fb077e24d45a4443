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
            except Exception:
                name = type(listener).__name__
                self.failures[name] = self.failures.get(name, 0) + 1
                if self.failures[name] == 1:
                    log.exception("listener %s failed; it keeps receiving later batches", name)

    def close(self) -> None:
        """Close every listener, even if one of them fails."""
        for listener in self.listeners:
            try:
                listener.close()
            except Exception:
                log.exception("closing listener %s failed", type(listener).__name__)
