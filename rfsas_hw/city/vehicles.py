"""The vehicles' side: every vehicle's advisory receiver behind one gateway connection.

A district has hundreds of vehicles; each would hold its own broker connection
and read only its own topic. In the simulation one connection, as the
``gateway`` identity (the ACL lets it read ``rfsas/v1/vehicle/+/advisory``),
stands for their modems: each message is handed, by the vehicle id it is
addressed to, to that vehicle's own
:class:`~rfsas_hw.fleet.advisory.AdvisoryReceiver`, which verifies it with the
backends' keys exactly as a vehicle would (structure, addressee, enrolled
backend, replay, signature, age). Messages for a vehicle not in the simulation
are counted and dropped; receivers of vehicles that left are dropped.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from rfsas_hw.fleet.advisory import (
    AdvisoryMessage,
    AdvisoryReceiver,
    BackendKeys,
    peek_advisory,
)
from rfsas_hw.link.message import MessageFormatError
from rfsas_hw.link.transport import Transport

QUEUE_MAX = 100_000
"""Most arrivals the thread holds for the caller (the oldest go first)."""
_SEVERITY = {"brake": 3, "caution": 2, "clear": 1, "none": 0}

__all__ = ["Arrival", "GatewayStats", "VehicleGateway", "most_severe"]


@dataclass(frozen=True, slots=True)
class Arrival:
    """One verified advisory message at its vehicle."""

    vehicle_id: str
    message: AdvisoryMessage
    t_ns: int
    """When it arrived, UTC ns."""
    owned: bool | None = None
    """Whether the signing backend owned the vehicle's tile (None: not checked)."""
    tiles: tuple[str, ...] = ()
    """The tiles the vehicle was in during the last second (when checked)."""


@dataclass
class GatewayStats:
    """What reached the vehicles."""

    datagrams: int = 0
    verified: int = 0
    unknown_vehicle: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    """Datagrams the vehicles' receivers refused, by reason (``malformed`` here too)."""


def most_severe(message: AdvisoryMessage) -> str:
    """The most severe advice in a message (``brake``, ``caution``, ``clear``, ``none``)."""
    return max((it.advisory for it in message.items), key=lambda a: _SEVERITY.get(a, 0))


class VehicleGateway:
    """Hands each advisory to its vehicle's receiver (see the module docstring).

    Args:
        trust: the backends' keys (every vehicle holds the same cards).
        transport: the gateway's broker connection, subscribed to the vehicles' topics.
        max_age_s: an advisory older than this is ``stale`` at a vehicle, seconds.
        clock: UTC ns.
    """

    def __init__(
        self,
        trust: BackendKeys,
        transport: Transport,
        *,
        max_age_s: float = 1.0,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        self.trust = trust
        self.transport = transport
        self.max_age_s = max_age_s
        self.clock = clock
        self.receivers: dict[str, AdvisoryReceiver] = {}
        self.stats = GatewayStats()
        self._present: set[str] = set()
        self._lock = threading.Lock()
        self._queue: deque[Arrival] = deque(maxlen=QUEUE_MAX)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.cpu_s = 0.0
        """CPU time of the receiving thread, seconds."""

    def vehicles(self, present: Iterable[str]) -> None:
        """The vehicles in the simulation now (receivers of the others are dropped)."""
        with self._lock:
            self._present = set(present)
            for vid in [v for v in self.receivers if v not in self._present]:
                self._retire(self.receivers.pop(vid))

    def start(self) -> None:
        """Receive in a thread of its own from now on (arrival times are then taken when
        a message arrives, not when the caller next looks); :meth:`drain` takes them."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._loop, name="vehicle-gateway", daemon=True)
            self._thread.start()

    def _loop(self) -> None:
        start = time.thread_time()
        while not self._stop.is_set():
            self._queue.extend(self.receive(0.05))
            self.cpu_s = time.thread_time() - start

    def drain(self) -> list[Arrival]:
        """The arrivals the thread has taken since the last call, oldest first."""
        out = []
        while self._queue:
            out.append(self._queue.popleft())
        return out

    def _retire(self, rx: AdvisoryReceiver) -> None:
        self.stats.rejected.update(rx.stats.rejected)
        self.stats.verified += rx.stats.verified

    def receive(self, timeout: float | None = 0.0) -> list[Arrival]:
        """Wait up to ``timeout`` s, then hand every queued datagram to its vehicle; what
        verified. Never raises on a bad datagram (counted)."""
        out: list[Arrival] = []
        got = self.transport.recv(timeout)
        while got is not None:
            self.stats.datagrams += 1
            try:
                vid = peek_advisory(bytes(got)).vehicle_id
            except MessageFormatError as err:
                self.stats.rejected[err.reason] += 1
                got = self.transport.recv(0)
                continue
            with self._lock:
                if vid not in self._present:
                    self.stats.unknown_vehicle += 1
                else:
                    rx = self.receivers.get(vid)
                    if rx is None:
                        rx = AdvisoryReceiver(
                            self.trust, vehicle_id=vid, max_age_s=self.max_age_s, clock=self.clock
                        )
                        self.receivers[vid] = rx
                    now = self.clock()
                    msg = rx.feed(got, now)
                    if msg is not None:
                        out.append(Arrival(vid, msg, now))
            got = self.transport.recv(0)
        return out

    def totals(self) -> GatewayStats:
        """Every count so far, with the receivers still open."""
        with self._lock:
            return self._totals()

    def _totals(self) -> GatewayStats:
        total = GatewayStats(
            datagrams=self.stats.datagrams,
            verified=self.stats.verified,
            unknown_vehicle=self.stats.unknown_vehicle,
            rejected=Counter(self.stats.rejected),
        )
        for rx in self.receivers.values():
            total.verified += rx.stats.verified
            total.rejected.update(rx.stats.rejected)
        return total

    def close(self) -> None:
        """Stop the thread and close the transport; idempotent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        self.transport.close()
