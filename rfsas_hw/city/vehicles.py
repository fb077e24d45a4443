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

The gateway runs in a process of its own (:func:`gateway_main`), as the cars'
receivers are devices of their own: in the simulator's process it would wait
for the simulator's steps (SUMO holds the interpreter for tens of ms per step)
before it could take and stamp an advisory, and that wait would count as the
path's latency. The process tells the main process every verified advisory,
with when it was verified, over a pipe; the main process tells it which
vehicles are in the simulation. It sleeps until the broker connection or the
pipe has something (no polling while nothing happens), takes every advisory
that has arrived at once, and sends what verified as one list of plain tuples
(:func:`arrival_rows`, :func:`arrivals_of`): only what the simulator uses of
each, which pickles in a fraction of the time the decoded messages took.
"""

from __future__ import annotations

import contextlib
import select
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.backend.risk import ADVISORY_RANK
from rfsas_hw.city.clock import SimClock, cpu_s
from rfsas_hw.city.handshake import answer_failure
from rfsas_hw.fleet.advisory import (
    AdvisoryMessage,
    AdvisoryReceiver,
    BackendKeys,
    peek_advisory,
)
from rfsas_hw.link.message import MessageFormatError
from rfsas_hw.link.mqtt import open_mqtt
from rfsas_hw.link.transport import Transport

IDLE_S = 0.05
"""The longest the gateway process sleeps while neither the broker connection nor its
pipe has anything, wall seconds (it wakes at once for either; waking this often keeps
the broker connection's own thread from reading for it)."""

__all__ = [
    "Arrival",
    "GatewayStats",
    "GatewayWork",
    "KnownBackends",
    "VehicleGateway",
    "arrival_rows",
    "arrivals_of",
    "gateway_main",
    "most_severe",
]


@dataclass(frozen=True, slots=True)
class Arrival:
    """One verified advisory message at its vehicle: what the simulator acts on, scores
    and logs of it."""

    vehicle_id: str
    backend_id: str
    """The backend that signed it."""
    seq: int
    """Its sequence number (with ``backend_id``, the message's identity)."""
    t_ns: int
    """When it arrived (was verified), UTC ns."""
    signed_ns: int
    """When its backend signed it (its generation time), UTC ns."""
    advice: str
    """Its most severe advice (``brake``, ``caution``, ``clear``, ``none``)."""
    emitters: tuple[str, ...]
    """The emitter ids of its assessments, in order."""
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
    return max((it.advisory for it in message.items), key=lambda a: ADVISORY_RANK.get(a, 0))


ArrivalRow = tuple[str, str, int, int, int, str, tuple[str, ...]]
"""An :class:`Arrival` as it crosses the pipe: (vehicle id, backend id, sequence number,
arrival and signing UTC ns, most severe advice, emitter ids)."""


def arrival_rows(arrivals: Iterable[Arrival]) -> list[ArrivalRow]:
    """Arrivals as plain tuples, to cross a pipe (pickled without per-object state)."""
    return [
        (a.vehicle_id, a.backend_id, a.seq, a.t_ns, a.signed_ns, a.advice, a.emitters)
        for a in arrivals
    ]


def arrivals_of(rows: Iterable[ArrivalRow]) -> list[Arrival]:
    """The arrivals of :func:`arrival_rows`."""
    return [Arrival(*row) for row in rows]


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

    def vehicles(self, present: Iterable[str]) -> None:
        """The vehicles in the simulation now (receivers of the others are dropped)."""
        with self._lock:
            self._present = set(present)
            for vid in [v for v in self.receivers if v not in self._present]:
                self._retire(self.receivers.pop(vid))

    def _retire(self, rx: AdvisoryReceiver) -> None:
        self.stats.rejected.update(rx.stats.rejected)
        self.stats.verified += rx.stats.verified

    def receive(self, timeout: float | None = 0.0) -> list[Arrival]:
        """Wait up to ``timeout`` s, then hand every queued datagram to its vehicle; what
        verified. Never raises on a bad datagram (counted)."""
        out: list[Arrival] = []
        for got, _topic in self.transport.recv_many(timeout):
            self.stats.datagrams += 1
            datagram = bytes(got)
            try:
                head = peek_advisory(datagram)
            except MessageFormatError as err:
                self.stats.rejected[err.reason] += 1
                continue
            vid = head.vehicle_id
            with self._lock:
                if vid not in self._present:
                    self.stats.unknown_vehicle += 1
                    continue
                rx = self.receivers.get(vid)
                if rx is None:
                    rx = AdvisoryReceiver(
                        self.trust, vehicle_id=vid, max_age_s=self.max_age_s, clock=self.clock
                    )
                    self.receivers[vid] = rx
                now = self.clock()
                msg = rx.feed(datagram, now, head)
            if msg is not None:
                out.append(
                    Arrival(
                        vid,
                        msg.sender_id,
                        msg.seq,
                        now,
                        msg.t_gen_us * 1000,
                        most_severe(msg),
                        tuple(it.emitter for it in msg.items),
                    )
                )
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
        """Close the transport; idempotent."""
        self.transport.close()


@dataclass(frozen=True)
class GatewayWork:
    """What the gateway process runs."""

    url: str
    """Broker URL as the gateway identity, subscribed to every vehicle's advisory topic."""
    backend_keys: dict[str, bytes]
    """Each backend's public signing key (DER), as every vehicle holds them."""
    clock: SimClock
    """The deployment's clock."""
    max_age_s: float = 1.0
    """An advisory older than this is ``stale`` at a vehicle, seconds."""


class KnownBackends:
    """The backends' public signing keys given as DER (as they cross to the gateway
    process), for :class:`~rfsas_hw.fleet.advisory.AdvisoryReceiver`.

    Raises (from the constructor):
        ValueError: a key is not DER.
    """

    def __init__(self, der: dict[str, bytes]) -> None:
        self.keys: dict[str, ec.EllipticCurvePublicKey] = {}
        for backend, blob in der.items():
            key = serialization.load_der_public_key(blob)
            if isinstance(key, ec.EllipticCurvePublicKey):
                self.keys[backend] = key

    def backend_key(self, backend_id: str) -> ec.EllipticCurvePublicKey | None:
        """The signing key of ``backend_id``, or None when it is not enrolled."""
        return self.keys.get(backend_id)


def gateway_main(work: GatewayWork, conn: Connection) -> None:
    """The body of the gateway process: connect, answer ``("ready",)``; then take every
    advisory and send the verified ones as ``("arrivals", rows)`` (:func:`arrival_rows`;
    :func:`arrivals_of` makes them arrivals again), and take the vehicles in the
    simulation (a tuple of ids) from ``conn``, until ``None``; answer ``("end",
    GatewayStats, cpu_s)``. A failure is answered ``("error", message)``."""
    gateway: VehicleGateway | None = None
    try:
        transport = open_mqtt(work.url, "recv")
        gateway = VehicleGateway(
            KnownBackends(work.backend_keys),
            transport,
            max_age_s=work.max_age_s,
            clock=work.clock,
        )
        conn.send(("ready",))
        while True:
            # asleep until the broker connection or the pipe has something
            with contextlib.suppress(OSError, ValueError):  # a socket replaced meanwhile
                select.select([*transport.wait_fds(), conn.fileno()], [], [], IDLE_S)
            arrivals = gateway.receive(0)
            if arrivals:
                conn.send(("arrivals", arrival_rows(arrivals)))
            stop = False
            while conn.poll():
                msg: Any = conn.recv()
                if msg is None:
                    stop = True
                    break
                gateway.vehicles(msg)
            if stop:
                break
        last = gateway.receive(0)
        if last:
            conn.send(("arrivals", arrival_rows(last)))
        totals = gateway.totals()
        gateway.close()
        gateway = None
        conn.send(("end", totals, cpu_s()))
    except Exception as err:  # reported to the main process, which ends the run
        answer_failure(conn, "vehicles' gateway", err, gateway)
    finally:
        conn.close()
