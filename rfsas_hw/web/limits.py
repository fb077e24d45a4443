"""Connection admission for the dashboard: a cap on open connections and a deadline
for plain HTTP ones, enforced below the HTTP parser.

A client that opens connections and never finishes a request holds a file
descriptor each; without a bound, a few hundred of them exhaust the process's
descriptors (and the backend that hosts the dashboard with it). The gate sits
between the listening socket and aiohttp's protocol, so it sees a connection
the moment it is accepted, before any byte is parsed and before the access
check (which needs a complete request):

- at most ``max_connections`` are open at once; one more is answered ``503``
  and closed at once;
- a connection that is not a WebSocket is closed ``request_timeout_s`` after
  it was accepted, finished or not (the dashboard's requests are small: a
  browser reconnects for the next one). A WebSocket, once upgraded, is kept
  and watched by its heartbeat instead.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

log = logging.getLogger(__name__)

BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain\r\n"
    b"Content-Length: 29\r\nConnection: close\r\n\r\ntoo many connections, retry.\n"
)


@dataclass(frozen=True, slots=True)
class ConnectionLimits:
    """How many connections the dashboard holds and for how long.

    Raises:
        ValueError: a cap below 1 or a non-positive timeout.
    """

    max_connections: int = 64
    """Open connections (HTTP and WebSocket together) above which new ones are refused."""
    request_timeout_s: float = 10.0
    """Lifetime of a connection that is not a WebSocket, seconds (idle, partial or slow
    requests are cut there)."""

    def __post_init__(self) -> None:
        if self.max_connections < 1 or not self.request_timeout_s > 0:
            raise ValueError("max_connections must be >= 1 and request_timeout_s positive")


class ConnectionGate:
    """A protocol factory for ``loop.create_server`` that admits connections to
    ``factory``'s protocols within ``limits`` (see the module docstring).

    Counters: :attr:`open`, :attr:`refused`, :attr:`timed_out`.
    """

    def __init__(
        self, factory: Callable[[], asyncio.Protocol], limits: ConnectionLimits | None = None
    ) -> None:
        self.factory = factory
        self.limits = limits or ConnectionLimits()
        self.open = 0
        self.refused = 0
        """Connections refused because :attr:`ConnectionLimits.max_connections` were open."""
        self.timed_out = 0
        """Plain HTTP connections closed at their deadline."""
        self._streams: set[asyncio.BaseTransport] = set()

    def __call__(self) -> asyncio.Protocol:
        return _Admitted(self)

    def keep(self, transport: Any) -> None:
        """Exempt ``transport``'s connection from the deadline (an upgraded WebSocket)."""
        if transport is not None:
            self._streams.add(transport)

    def _refuse(self, transport: asyncio.Transport) -> None:
        self.refused += 1
        if self.refused == 1 or self.refused % 100 == 0:
            log.warning(
                "dashboard: %d connections open, refused a new one (%d refused so far)",
                self.open,
                self.refused,
            )
        transport.write(BUSY)
        transport.close()


class _Admitted(asyncio.Protocol):
    """One accepted connection: counted, timed, passed on to the wrapped protocol."""

    def __init__(self, gate: ConnectionGate) -> None:
        self.gate = gate
        self.inner: asyncio.Protocol | None = None
        self.transport: asyncio.Transport | None = None
        self.timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        gate = self.gate
        if gate.open >= gate.limits.max_connections:
            gate._refuse(transport)
            return
        gate.open += 1
        self.transport = transport
        self.inner = gate.factory()
        loop = asyncio.get_running_loop()
        self.timer = loop.call_later(gate.limits.request_timeout_s, self._expire)
        self.inner.connection_made(transport)

    def _expire(self) -> None:
        self.timer = None
        transport = self.transport
        if transport is None or transport in self.gate._streams:
            return
        self.gate.timed_out += 1
        log.debug("dashboard: closed a connection at its deadline")
        transport.abort()

    def connection_lost(self, exc: Exception | None) -> None:
        if self.inner is None:
            return
        self.gate.open -= 1
        if self.timer is not None:
            self.timer.cancel()
        self.gate._streams.discard(self.transport)
        inner, self.inner, self.transport = self.inner, None, None
        inner.connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self.inner is not None:
            self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        return None if self.inner is None else self.inner.eof_received()

    def pause_writing(self) -> None:
        if self.inner is not None:
            self.inner.pause_writing()

    def resume_writing(self) -> None:
        if self.inner is not None:
            self.inner.resume_writing()
