"""MQTT 5 transport: the link through a broker.

URLs::

    mqtt://HOST[:1883]?origin=LAT,LON             a sensor publishing bearings
    mqtts://HOST[:8883]?ca=CA&cert=CRT&key=KEY    the same with mutual TLS
    mqtts://HOST:8883?ca=…&cert=…&key=…&tiles=120212,120213&nonces=backend-1
                                                  a backend taking two tiles and
                                                  its own nonce envelopes

Query options:

- ``ca``, ``cert``, ``key``: CA certificate and this client's certificate and
  key (PEM files); required by ``mqtts``, refused by ``mqtt``.
- ``origin=LAT,LON``: the site origin (degrees) that puts local metres on the
  globe, so a sensor's bearings go to the topic of its tile.
- ``sub=FILTER`` (repeatable), ``tiles=Q,…`` (bearings of those quadkey tiles),
  ``nonces=ID`` (nonce envelopes for ``ID``), ``advisories=Q,…``: what a
  listener subscribes to; with none of them, every bearing topic.
- ``epoch``, ``grace``: the nonce epoch schedule, seconds (for the expiry of
  retained nonce envelopes).
- ``keepalive`` (s, default 5), ``connect_s`` (how long opening waits for the
  first connection, default 5), ``queue`` (received messages held, default 65536;
  the oldest go first when it is full), ``client_id``.

The payload is the signed datagram, byte for byte: the broker is not trusted
(receivers check the signature, and that a bearing topic names the signed sender).
Nagle is turned off on the client socket; set ``set_tcp_nodelay true`` on the
broker as well, or one hop costs tens of milliseconds. Bearings go at QoS 0;
nonce envelopes at QoS 1, retained, with an MQTT 5 message expiry. After the
first connection, a lost broker is retried with exponential backoff (1–8 s);
sends while disconnected fail (the publisher counts them), so a sensor that
must not lose bearings sends on local UDP as well.

The MQTT client is this package's own (:mod:`rfsas_hw.link.mqtt_wire` for the
packets): the subset of MQTT 5 the link needs, with reads of whole socket
buffers and no per-message objects. ``bench/bench_mqtt_client.py`` measures
CPU per received message over mutual TLS through mosquitto on loopback; one
run on a busy 2-core machine: this client 20.5 µs, gmqtt 25.7 µs (1.25×),
paho-mqtt 2 with MQTT 5 110 µs (5.4×: a properties object per PUBLISH, one
select and several TLS reads per packet, a thread hand-off). The tests run
this client against mosquitto and against paho-mqtt.
"""

from __future__ import annotations

import contextlib
import logging
import re
import secrets
import select
import socket
import ssl
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal
from urllib.parse import parse_qs, urlsplit

from rfsas_hw.errors import LinkError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link import mqtt_wire as wire
from rfsas_hw.link.mqtt_wire import (
    DISCONNECT_PACKET,
    PINGREQ_PACKET,
    Ack,
    MqttProtocolError,
    Packet,
    PacketReader,
    Ping,
    Publish,
    connect_packet,
    framed,
    puback_packet,
    publish_head,
    publish_packet,
    reason_text,
    subscribe_packet,
)
from rfsas_hw.link.tls_stream import TlsStream
from rfsas_hw.link.topics import (
    ZOOM,
    Route,
    TopicRouter,
    advisory_filter,
    bearing_filter,
    check_quadkey,
    nonce_filter,
)
from rfsas_hw.link.transport import Transport
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, DEFAULT_GRACE_S, EpochSchedule

log = logging.getLogger(__name__)

DEFAULT_PORTS = {"mqtt": 1883, "mqtts": 8883}
_OPTIONS = {
    "ca",
    "cert",
    "key",
    "origin",
    "sub",
    "tiles",
    "nonces",
    "advisories",
    "epoch",
    "grace",
    "keepalive",
    "connect_s",
    "queue",
    "client_id",
}


@dataclass(frozen=True, slots=True)
class MqttEndpoint:
    """A parsed ``mqtt://`` or ``mqtts://`` URL (see the module docstring)."""

    host: str
    port: int
    tls: bool = False
    ca: Path | None = None
    cert: Path | None = None
    key: Path | None = None
    origin: SiteOrigin | None = None
    subscriptions: tuple[str, ...] = ()
    schedule: EpochSchedule = field(default_factory=EpochSchedule)
    keepalive_s: int = 5
    connect_s: float = 5.0
    queue: int = 65_536
    client_id: str = ""

    def url(self) -> str:
        """A short form for messages (no file names)."""
        return f"{'mqtts' if self.tls else 'mqtt'}://{self.host}:{self.port}"


def _one(query: dict[str, list[str]], name: str, url: str) -> str | None:
    values = query.get(name)
    if not values:
        return None
    if len(values) > 1:
        raise LinkError(f"{url!r}: option {name} given {len(values)} times")
    return values[0]


def _number(query: dict[str, list[str]], name: str, url: str, default: float) -> float:
    raw = _one(query, name, url)
    if raw is None:
        return default
    try:
        value = float(raw)
    except ValueError as err:
        raise LinkError(f"{url!r}: {name}={raw!r} is not a number") from err
    if not value > 0:
        raise LinkError(f"{url!r}: {name}={raw!r} must be positive")
    return value


def parse_mqtt_url(url: str) -> MqttEndpoint:
    """Parse an ``mqtt://`` / ``mqtts://`` URL.

    Raises:
        LinkError: unknown scheme or option, missing host, bad port, TLS files
            missing or given without ``mqtts``, a bad origin, quadkey or number.
    """
    parts = urlsplit(url)
    if parts.scheme not in DEFAULT_PORTS:
        raise LinkError(f"{url!r}: expected mqtt://HOST[:PORT] or mqtts://HOST[:PORT]")
    try:
        port = DEFAULT_PORTS[parts.scheme] if parts.port is None else parts.port
    except ValueError as err:
        raise LinkError(f"{url!r}: bad port: {err}") from err
    if not 1 <= port <= 65535:
        raise LinkError(f"{url!r}: port {port} outside 1-65535")
    if not parts.hostname:
        raise LinkError(f"{url!r}: no broker host")
    if parts.path not in ("", "/"):
        raise LinkError(f"{url!r}: no path expected; topics follow the rfsas/v1 contract")
    query = parse_qs(parts.query, keep_blank_values=True)
    unknown = set(query) - _OPTIONS
    if unknown:
        raise LinkError(
            f"{url!r}: unknown option(s) {', '.join(sorted(unknown))}; "
            f"use {', '.join(sorted(_OPTIONS))}"
        )
    tls = parts.scheme == "mqtts"
    files: dict[str, Path | None] = {}
    for name in ("ca", "cert", "key"):
        raw = _one(query, name, url)
        if raw is not None and not tls:
            raise LinkError(f"{url!r}: {name}= needs mqtts://")
        if tls and raw is None:
            raise LinkError(f"{url!r}: mqtts needs ca=, cert= and key= (PEM files)")
        files[name] = None if raw is None else Path(raw)
        if raw is not None and not Path(raw).is_file():
            raise LinkError(f"{url!r}: {name} file {raw} does not exist")
        if name == "key" and raw is not None and Path(raw).stat().st_mode & 0o077:
            raise LinkError(f"{url!r}: key file {raw} is readable by others (chmod 600 it)")
    origin = None
    raw_origin = _one(query, "origin", url)
    if raw_origin is not None:
        try:
            lat, lon = (float(v) for v in raw_origin.split(","))
            origin = SiteOrigin(lat, lon)
        except (ValueError, LinkError) as err:
            raise LinkError(f"{url!r}: origin={raw_origin!r}: expected LAT,LON degrees") from err
        except Exception as err:  # a ConfigError from SiteOrigin's range check
            raise LinkError(f"{url!r}: origin={raw_origin!r}: {err}") from err
    subs = list(query.get("sub", []))
    for tile in _csv(query, "tiles", url):
        subs.append(bearing_filter(tile))
    for tile in _csv(query, "advisories", url):
        subs.append(advisory_filter(tile))
    nonces = _one(query, "nonces", url)
    if nonces is not None:
        subs.append(nonce_filter(nonces))
    try:
        schedule = EpochSchedule(
            _number(query, "epoch", url, DEFAULT_EPOCH_S),
            float(_one(query, "grace", url) or DEFAULT_GRACE_S),
        )
    except ValueError as err:
        raise LinkError(f"{url!r}: epoch/grace: {err}") from err
    return MqttEndpoint(
        host=parts.hostname,
        port=port,
        tls=tls,
        ca=files["ca"],
        cert=files["cert"],
        key=files["key"],
        origin=origin,
        subscriptions=tuple(dict.fromkeys(subs)),
        schedule=schedule,
        keepalive_s=max(1, int(_bounded(query, "keepalive", url, 5, KEEPALIVE_MAX_S))),
        connect_s=_bounded(query, "connect_s", url, 5.0, CONNECT_MAX_S),
        queue=int(_bounded(query, "queue", url, 65_536, QUEUE_MAX)),
        client_id=_client_id(_one(query, "client_id", url) or "", url),
    )


KEEPALIVE_MAX_S = 65_535
"""MQTT's keep-alive is a 16-bit number of seconds."""
CONNECT_MAX_S = 3600.0
"""The longest wait for a connection ``connect_s`` may ask for, seconds."""
QUEUE_MAX = 10_000_000
"""The most received messages ``queue`` may hold."""
CLIENT_ID_MAX = 128
"""The longest ``client_id`` (brokers must take 23 characters; most take more)."""
_CLIENT_ID_RE = re.compile(r"[A-Za-z0-9._-]*")


def _bounded(query: dict[str, list[str]], name: str, url: str, default: float, top: float) -> float:
    value = _number(query, name, url, default)
    if not value <= top:
        raise LinkError(f"{url!r}: {name}={value:g} is more than {top:g}")
    return value


def _client_id(value: str, url: str) -> str:
    if len(value) > CLIENT_ID_MAX or not _CLIENT_ID_RE.fullmatch(value):
        raise LinkError(f"{url!r}: client_id must be at most {CLIENT_ID_MAX} of A-Z a-z 0-9 . _ -")
    return value


def _csv(query: dict[str, list[str]], name: str, url: str) -> list[str]:
    out = []
    for raw in query.get(name, []):
        for item in raw.split(","):
            try:
                key = check_quadkey(item.strip())
            except LinkError as err:
                raise LinkError(f"{url!r}: {name}: {err}") from err
            if len(key) > ZOOM:
                raise LinkError(
                    f"{url!r}: {name}: {key!r} is deeper than the topics' {ZOOM} tile levels "
                    "and would match nothing"
                )
            out.append(key)
    return out


@dataclass(slots=True)
class MqttStats:
    """Counters of one MQTT transport."""

    sent: int = 0
    send_errors: int = 0
    received: int = 0
    dropped: int = 0
    """Received messages dropped because the queue was full (the oldest go)."""
    connects: int = 0
    disconnects: int = 0
    refused: int = 0
    """Publishes or subscriptions the broker refused (not authorised)."""

    def as_dict(self) -> dict[str, int]:
        """Flat counters."""
        return {
            "sent": self.sent,
            "send_errors": self.send_errors,
            "received": self.received,
            "dropped": self.dropped,
            "connects": self.connects,
            "disconnects": self.disconnects,
            "refused": self.refused,
        }


class _LostError(Exception):
    """The broker connection is gone; the message says why."""


class _RefusedError(LinkError):
    """The broker refused this client (its connection or every subscription): trying
    again changes nothing until someone changes the broker's configuration."""


HELD_MAX_BYTES = 256 * 1024
"""Publishes held together (:meth:`MqttTransport.together`) are written once this many
bytes are held, bytes."""


@dataclass
class HeldWrites:
    """The publishes of one :meth:`MqttTransport.together` block."""

    thread: int
    """The thread whose publishes are held (``threading.get_ident``)."""
    packets: list[bytes] = field(default_factory=list)
    size: int = 0
    """Bytes held, not yet written."""
    written: int = 0
    """Publishes written so far."""
    lost: int = 0
    """Publishes whose write failed (the connection was then treated as lost)."""


class MqttTransport(Transport):
    """Sends and receives signed datagrams through an MQTT 5 broker.

    One network thread per transport connects (and reconnects with backoff) and
    keeps the connection alive. A caller of :meth:`recv_from` reads the socket
    itself (whole buffers, every packet in them), so a busy receiver does not
    trade the interpreter lock with another thread for each message; the
    network thread reads only while no caller has for :data:`CALLER_IDLE_S`
    (acknowledgements, pings, and messages for a receiver busy elsewhere).
    Publishing writes from the caller's thread, so a message leaves at once.
    Every socket operation holds one lock, as a TLS connection must not be read
    and written at the same time.

    Args:
        endpoint: the broker and options.
        mode: ``send`` (publish by the topic contract) or ``recv`` (subscribe).
        router: chooses topics for :meth:`send` (default: by the endpoint's origin
            and schedule).
        clock: UTC ns.

    Raises:
        LinkError: the TLS files are unusable, or no connection (with its
            subscriptions acknowledged) within ``connect_s``.
    """

    def __init__(
        self,
        endpoint: MqttEndpoint,
        mode: Literal["send", "recv"],
        *,
        router: TopicRouter | None = None,
        clock: Any = time.time_ns,
    ) -> None:
        self.endpoint = endpoint
        self.mode = mode
        self.router = router or TopicRouter(endpoint.origin, endpoint.schedule)
        self.clock = clock
        self.stats = MqttStats()
        self.subscriptions = endpoint.subscriptions or (
            (bearing_filter(),) if mode == "recv" else ()
        )
        self._tls = self._tls_context() if endpoint.tls else None
        self._client_id = endpoint.client_id or f"rfsas-{secrets.token_hex(6)}"
        self._keepalive_s = float(endpoint.keepalive_s)
        self._io = threading.Lock()
        """Held for every read and write of the socket."""
        self._sock: socket.socket | TlsStream | None = None
        self._reader = PacketReader()
        self._heads: dict[Route, tuple[int, bytes]] = {}
        """First byte and variable header of QoS-0 publishes, by route."""
        self._queue: deque[tuple[bytes, str]] = deque()
        self._qlock = threading.Lock()
        self._wake_r, self._wake_w = socket.socketpair()
        self._woken = False
        """Set after the network thread wrote a wake-up byte; cleared by the drain."""
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._connected = threading.Event()
        self._closed = threading.Event()
        self._ids = threading.Lock()
        self._next_id = 0
        self._pending: dict[int, threading.Event] = {}
        """QoS-1 publishes not yet acknowledged, by packet id (close waits for them)."""
        self._receive_max = 0xFFFF
        """QoS-1 publishes the broker takes unacknowledged (its CONNACK says)."""
        self._held: HeldWrites | None = None
        """The QoS-0 publishes of one thread written together (:meth:`together`)."""
        self._last_sent = time.monotonic()
        self._ping_sent = 0.0
        self._caller_at = 0.0
        """When a caller of recv_from last read or waited, monotonic seconds."""
        self._lost_why = ""
        """Set by a caller's read that found the connection lost, for the network thread."""
        self._last_error = "no answer"
        self._lost_at: float | None = None
        """When the connection was lost (monotonic seconds), until it is back."""
        self._thread = threading.Thread(
            target=self._run, name=f"mqtt {endpoint.url()}", daemon=True
        )
        self._thread.start()
        deadline = time.monotonic() + endpoint.connect_s
        while not self._connected.is_set() and self._thread.is_alive():
            self._connected.wait(min(0.05, max(deadline - time.monotonic(), 0.0)))
            if time.monotonic() >= deadline:
                break
        if not self._connected.is_set():
            refused = not self._thread.is_alive()
            self.close(flush_s=0.0)
            if refused:
                raise LinkError(f"{endpoint.url()}: {self._last_error}")
            raise LinkError(
                f"{endpoint.url()}: no connection within {endpoint.connect_s:g} s "
                f"({self._last_error})"
            )

    def _tls_context(self) -> ssl.SSLContext:
        ep = self.endpoint
        try:
            ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
            ctx.load_verify_locations(cafile=str(ep.ca))
            ctx.load_cert_chain(str(ep.cert), str(ep.key))
        except (ssl.SSLError, OSError, ValueError) as err:
            self._close_wake_if_open()
            raise LinkError(f"{ep.url()}: unusable TLS files: {err}") from err
        return ctx

    # --- the network thread ---

    def _run(self) -> None:
        delay = 1.0
        while not self._closed.is_set():
            try:
                self._open()
            except (OSError, LinkError) as err:
                self._last_error = str(err) or type(err).__name__
                if isinstance(err, _RefusedError) and self.stats.connects == 0:
                    return  # the start fails with this reason (see __init__)
                if self._closed.wait(delay):
                    return
                delay = min(2.0 * delay, 8.0)
                continue
            delay = 1.0
            try:
                self._serve()
            except _LostError as err:
                self._mark_lost(str(err) or "lost")
            finally:
                self._drop()
            if not self._closed.is_set():
                self._closed.wait(delay)

    def _mark_lost(self, why: str) -> None:
        """Count and report a lost connection once, whichever thread found it."""
        with self._ids:
            if self._lost_why:
                return
            self._lost_why = why
        self._connected.clear()
        self._last_error = f"disconnected: {why}"
        if not self._closed.is_set():
            self.stats.disconnects += 1
            self._lost_at = time.monotonic()
            log.warning(
                "%s: lost the broker (%s); retrying (loss %d)",
                self.endpoint.url(),
                why,
                self.stats.disconnects,
            )

    def _open(self) -> None:
        """Connect, say CONNECT, wait for CONNACK and SUBACK (blocking, ``connect_s``).

        Raises:
            OSError: no TCP or TLS connection.
            LinkError: the broker refused the connection or every subscription, or
                a subscription was not answered in time.
        """
        ep = self.endpoint
        raw = socket.create_connection((ep.host, ep.port), timeout=ep.connect_s)
        sock: socket.socket | TlsStream
        try:
            # without this, a small message waits for the previous one's ACK (tens of ms)
            raw.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock = raw if self._tls is None else TlsStream(raw, self._tls, ep.host, ep.connect_s)
        except BaseException:
            raw.close()
            raise
        try:
            reader = PacketReader()
            deadline = time.monotonic() + ep.connect_s
            sock.sendall(connect_packet(self._client_id, int(self._keepalive_s)))
            ack, early = self._await(sock, reader, wire.CONNACK, deadline)
            if ack.failed:
                why = ack.properties.get(wire.PROP_REASON_STRING)
                raise LinkError(
                    f"broker refused the connection: {reason_text(ack.reasons[0])}"
                    + (f" ({why})" if why else "")
                )
            server_keepalive = ack.properties.get(wire.PROP_SERVER_KEEP_ALIVE)
            if isinstance(server_keepalive, int) and server_keepalive > 0:
                self._keepalive_s = float(server_keepalive)
            receive_max = ack.properties.get(wire.PROP_RECEIVE_MAXIMUM)
            self._receive_max = receive_max if isinstance(receive_max, int) else 0xFFFF
            if self.subscriptions:
                filters = [(t, 1 if "/nonce/" in t else 0) for t in self.subscriptions]
                sock.sendall(subscribe_packet(self._packet_id(), filters))
                suback, more = self._await(sock, reader, wire.SUBACK, deadline)
                early += more
                self._count_suback(suback)
                if suback.reasons and all(code >= 0x80 for code in suback.reasons):
                    # a receiver the broker lets hear nothing would wait in silence
                    raise _RefusedError(
                        f"the broker refused every subscription "
                        f"({reason_text(suback.reasons[0])}): {', '.join(self.subscriptions)}"
                    )
        except BaseException:
            sock.close()
            raise
        sock.setblocking(False)
        with self._io:
            self._sock, self._reader = sock, reader
            self._lost_why = ""
        self._last_sent = time.monotonic()
        self._ping_sent = 0.0
        self.stats.connects += 1
        if self._lost_at is not None:
            log.warning(
                "%s: connected to the broker again after %.1f s (loss %d)",
                self.endpoint.url(),
                time.monotonic() - self._lost_at,
                self.stats.disconnects,
            )
            self._lost_at = None
        self._handle(early)
        self._connected.set()

    def _await(
        self, sock: socket.socket | TlsStream, reader: PacketReader, kind: int, deadline: float
    ) -> tuple[Ack, list[Packet]]:
        """Read until a packet of ``kind`` arrives: it, and every other packet read
        meanwhile (before it, and after it in the same read, as retained messages
        right behind a SUBACK), in order.

        Raises:
            LinkError: the broker closed the connection, sent nonsense, or took
                longer than ``deadline``.
        """
        got: list[Packet] = []
        found: Ack | None = None
        while found is None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise LinkError(f"no {_NAMES[kind]} within {self.endpoint.connect_s:g} s")
            sock.settimeout(left)
            try:
                data = sock.recv(65_536)
            except TimeoutError:
                continue
            if not data:
                raise LinkError(f"the broker closed the connection before {_NAMES[kind]}")
            for packet in reader.feed(data):
                if found is None and isinstance(packet, Ack) and packet.kind == kind:
                    if kind == wire.SUBACK:
                        self._count_suback(packet)
                    found = packet
                elif isinstance(packet, Ack) and packet.kind == wire.DISCONNECT:
                    raise LinkError(f"the broker disconnected: {reason_text(packet.reasons[0])}")
                else:
                    got.append(packet)
        return found, got

    def _serve(self) -> None:
        """Read and keep alive until the connection is lost or the transport closed.

        Raises:
            _LostError: the connection is lost.
        """
        sock = self._sock
        assert sock is not None
        pending = getattr(sock, "pending", None)
        while not self._closed.is_set():
            if self._lost_why:
                return
            if time.monotonic() - self._caller_at < CALLER_IDLE_S:
                # a caller is reading: stay out of its way (no lock trading per message)
                self._closed.wait(CALLER_IDLE_S / 2)
                self._keep_alive()
                continue
            try:
                ready, _, _ = select.select([sock], [], [], CALLER_IDLE_S)
            except (OSError, ValueError) as err:  # closed under us
                raise _LostError(str(err)) from None
            if ready or (pending is not None and pending()):
                self._read_and_handle(sock, wake=True)
            self._keep_alive()

    def _read_and_handle(self, sock: socket.socket | TlsStream, wake: bool) -> bool:
        """Read what the socket has and act on it (any thread); ``wake`` a caller waiting
        on :meth:`fileno` when messages were queued. True when the socket was emptied.

        Raises:
            _LostError: the connection is lost.
        """
        with self._io:
            if self._sock is not sock:
                return True
            packets, drained = self._read_available(sock)
        self._handle(packets, wake)
        return drained

    def _read_available(self, sock: socket.socket | TlsStream) -> tuple[list[Packet], bool]:
        """The packets in what the socket holds, and whether it was emptied: reading
        stops at a read that took less than it could, instead of asking the socket once
        more to hear that nothing is left (a system call and an exception per wake-up).

        Raises:
            _LostError: the connection failed, closed, or carried a malformed packet.
        """
        out: list[Packet] = []
        for _ in range(64):  # then let writers in
            try:
                data = sock.recv(_READ_BYTES)
            except (ssl.SSLWantReadError, ssl.SSLWantWriteError, BlockingIOError):
                return out, True
            except OSError as err:
                raise _LostError(str(err)) from None
            if not data:
                raise _LostError("the broker closed the connection")
            try:
                out += self._reader.feed(data)
            except MqttProtocolError as err:
                raise _LostError(str(err)) from None
            if sock.drained if isinstance(sock, TlsStream) else len(data) < _READ_BYTES:
                return out, True
        return out, False

    def _handle(self, packets: list[Packet], wake: bool = True) -> None:
        messages: list[tuple[bytes, str]] = []
        for packet in packets:
            if isinstance(packet, Publish):
                messages.append((packet.payload, packet.topic))
                if packet.qos:
                    self._write_or_lose(puback_packet(packet.packet_id))
            elif isinstance(packet, Ping):
                self._ping_sent = 0.0
            elif packet.kind == wire.PUBACK:
                if packet.failed:
                    self.stats.refused += 1
                    if self.stats.refused == 1:
                        log.warning(
                            "%s: the broker refused a publish: %s",
                            self.endpoint.url(),
                            reason_text(packet.reasons[0]),
                        )
                done = self._pending.pop(packet.packet_id, None)
                if done is not None:
                    done.set()
            elif packet.kind == wire.SUBACK:
                self._count_suback(packet)
            elif packet.kind == wire.DISCONNECT:
                raise _LostError(f"the broker disconnected: {reason_text(packet.reasons[0])}")
        if messages:
            self._enqueue(messages, wake)

    def _count_suback(self, ack: Ack) -> None:
        for code in ack.reasons:
            if code >= 0x80:
                self.stats.refused += 1
                log.warning(
                    "%s: a subscription was refused: %s", self.endpoint.url(), reason_text(code)
                )

    def _enqueue(self, messages: list[tuple[bytes, str]], wake: bool) -> None:
        """Queue received messages (the oldest go when the queue is full); ``wake``: the
        network thread read them, so a caller waiting in ``select`` must hear of it (a
        caller that read them itself takes them before it waits again)."""
        with self._qlock:
            was_empty = not self._queue
            overflow = len(self._queue) + len(messages) - self.endpoint.queue
            for _ in range(max(0, overflow)):
                if self._queue:
                    self._queue.popleft()
                else:
                    messages.pop(0)
                self.stats.dropped += 1
            self._queue.extend(messages)
            self.stats.received += len(messages)
        if wake and was_empty:
            with contextlib.suppress(OSError):  # a full wake-up buffer already wakes
                self._wake_w.send(b"\0")
            # after the byte: a caller that clears this drains every byte sent before
            self._woken = True

    def _keep_alive(self) -> None:
        now = time.monotonic()
        if self._ping_sent and now - self._ping_sent > self._keepalive_s:
            raise _LostError(f"no answer to a ping within {self._keepalive_s:g} s")
        if not self._ping_sent and now - self._last_sent >= 0.75 * self._keepalive_s:
            self._ping_sent = now
            self._write_or_lose(PINGREQ_PACKET)

    def _write_or_lose(self, packet: bytes) -> None:
        try:
            self._write(packet)
        except OSError as err:
            raise _LostError(str(err)) from None

    def _drop(self) -> None:
        self._connected.clear()
        with self._io:
            sock, self._sock = self._sock, None
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.close()

    # --- writing (any thread) ---

    def _write(self, packet: bytes) -> None:
        """Write ``packet`` whole, waiting up to 2 s for room in the socket buffer.

        Raises:
            OSError: not connected, the connection failed, or no room in time.
        """
        view = memoryview(packet)
        deadline = time.monotonic() + 2.0
        with self._io:
            sock = self._sock
            if sock is None:
                raise OSError("not connected")
            while view:
                try:
                    view = view[sock.send(view) :]
                except (ssl.SSLWantWriteError, ssl.SSLWantReadError, BlockingIOError):
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise OSError("the broker did not take the data within 2 s") from None
                    select.select([], [sock], [], min(left, 0.05))
        self._last_sent = time.monotonic()

    @contextlib.contextmanager
    def together(self) -> Iterator[HeldWrites]:
        """Within the block, this thread's QoS-0 publishes are written together at its
        end (and whenever :data:`HELD_MAX_BYTES` are held): one TLS record and one socket
        write for many messages (a backend advising many vehicles in one step) instead
        of one each. A QoS-1 publish in the block writes what is held first, so the
        order is kept. A publish still raises LinkError when the broker is not
        connected; a write that fails is counted per message (``stats.send_errors``,
        and :attr:`HeldWrites.lost` of the object given) and the connection is treated
        as lost, as a failed publish is. Blocks do not nest.

        Raises:
            LinkError: a block is already open on this transport.
        """
        if self._held is not None:
            raise LinkError(f"{self.endpoint.url()}: publishes are already held together")
        held = self._held = HeldWrites(threading.get_ident())
        try:
            yield held
        finally:
            self._held = None
            self._write_held(held)

    def _write_held(self, held: HeldWrites) -> None:
        """Write what ``held`` holds in one write; a failure is counted per message."""
        if not held.packets:
            return
        data = b"".join(held.packets)
        count = len(held.packets)
        held.packets.clear()
        held.size = 0
        try:
            self._write(data)
        except OSError as err:
            self.stats.send_errors += count
            held.lost += count
            log.warning("%s: %d held publishes lost: %s", self.endpoint.url(), count, err)
            self._lose(str(err))
            return
        self.stats.sent += count
        held.written += count

    def _packet_id(self) -> int:
        with self._ids:
            for _ in range(0xFFFF):
                self._next_id = self._next_id % 0xFFFF + 1
                if self._next_id not in self._pending:
                    return self._next_id
        raise LinkError(f"{self.endpoint.url()}: 65535 publishes wait for an answer")

    # --- Transport ---

    @property
    def connected(self) -> bool:
        """True while the broker connection is up."""
        return self._connected.is_set()

    def socket(self) -> socket.socket | None:
        """The TCP socket to the broker while connected (for inspection; do not read it)."""
        sock = self._sock
        return sock.raw if isinstance(sock, TlsStream) else sock

    def fileno(self) -> int:
        """A descriptor that becomes readable when the network thread has queued
        messages (those a caller read itself it takes before it waits again); wait on
        :meth:`wait_fds`, which adds the broker socket."""
        return self._wake_r.fileno()

    def wait_fds(self) -> list[int]:
        """The wake-up descriptor and, while connected, the broker socket: readable
        when :meth:`recv_from` may have something."""
        sock = self._sock
        fds = [self._wake_r.fileno()]
        if sock is not None:
            with contextlib.suppress(OSError, ValueError):
                fds.append(sock.fileno())
        return [fd for fd in fds if fd >= 0]

    def send(self, datagram: bytes) -> None:
        """Publish ``datagram`` on the topic the contract gives it.

        Raises:
            LinkError: it cannot be routed, or the broker is not connected.
        """
        self.publish(self.router.route(datagram, int(self.clock())), datagram)

    def publish(self, route: Route, datagram: bytes) -> None:
        """Publish ``datagram`` as ``route`` says (QoS 0 or 1, retain, expiry). In a
        :meth:`together` block of this thread a QoS-0 publish is held and written with
        the others at the block's end (its write's failure is counted there).

        Raises:
            LinkError: the broker is not connected or the write failed.
        """
        if not self._connected.is_set():
            self.stats.send_errors += 1
            raise LinkError(
                f"{self.endpoint.url()}: cannot publish to {route.topic}: not connected"
            )
        packet_id = 0
        if route.qos:
            # the broker disconnects a client that has more unacknowledged than it allows
            deadline = time.monotonic() + 2.0
            while len(self._pending) >= self._receive_max and time.monotonic() < deadline:
                oldest = next(iter(self._pending.values()), None)
                if oldest is not None:
                    oldest.wait(0.05)
            packet_id = self._packet_id()
            self._pending[packet_id] = threading.Event()
        if route.qos:
            packet = publish_packet(
                route.topic,
                datagram,
                qos=route.qos,
                retain=route.retain,
                packet_id=packet_id,
                expiry_s=route.expiry_s,
            )
        else:
            # a QoS-0 route's header is the same for every message on it: made once
            head = self._heads.get(route)
            if head is None:
                if len(self._heads) >= 1024:
                    self._heads.clear()
                head = self._heads[route] = publish_head(
                    route.topic, retain=route.retain, expiry_s=route.expiry_s
                )
            packet = framed(head[0], head[1], datagram)
            held = self._held
            if held is not None and held.thread == threading.get_ident():
                held.packets.append(packet)
                held.size += len(packet)
                if held.size >= HELD_MAX_BYTES:
                    self._write_held(held)
                return
        if self._held is not None and self._held.thread == threading.get_ident():
            self._write_held(self._held)  # what was held goes first, in order
        try:
            self._write(packet)
        except OSError as err:
            self._pending.pop(packet_id, None)
            self.stats.send_errors += 1
            self._lose(str(err))
            raise LinkError(
                f"{self.endpoint.url()}: cannot publish to {route.topic}: {err}"
            ) from err
        self.stats.sent += 1

    def _lose(self, why: str) -> None:
        """A caller found the connection lost: count it, and shut the socket so the
        network thread reconnects."""
        self._mark_lost(why or "lost")
        with self._io:
            if self._sock is not None:
                with contextlib.suppress(OSError):
                    self._sock.shutdown(socket.SHUT_RDWR)

    def recv_from(self, timeout: float | None = None) -> tuple[bytes, str | None] | None:
        """Next message and its topic, or None after ``timeout`` seconds."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            with self._qlock:
                if self._queue:
                    return self._queue.popleft()
            self._drain_wake()
            self._caller_read()
            with self._qlock:
                if self._queue:
                    return self._queue.popleft()
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return None
            if not self._wait(left):
                return None

    def recv_many(
        self, timeout: float | None = None, limit: int = 4096
    ) -> list[tuple[bytes, str | None]]:
        """Every queued message and what the socket holds now, with topics (at most
        ``limit``, in arrival order); waits up to ``timeout`` seconds for the first.

        Reading the socket here, not only when the queue is empty, keeps the
        broker's queue for this client short while the caller is busy checking a
        batch (the network thread, which gets the interpreter lock only between
        the caller's time slices, cannot keep up with a fast stream; a broker drops
        messages for a client whose queue grows past its limit)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            out = self._take(limit)
            self._drain_wake()
            while len(out) < limit:
                drained = self._caller_read()
                more = self._take(limit - len(out))
                out += more
                if drained or not more:
                    break
            if out:
                return out
            left = None if deadline is None else deadline - time.monotonic()
            if (left is not None and left <= 0) or not self._wait(left):
                return []

    def _take(self, limit: int) -> list[tuple[bytes, str | None]]:
        with self._qlock:
            queue = self._queue
            if len(queue) <= limit:
                out: list[tuple[bytes, str | None]] = list(queue)
                queue.clear()
            else:
                out = [queue.popleft() for _ in range(limit)]
        return out

    def _caller_read(self) -> bool:
        """Read the socket from the caller's thread, if connected; a lost connection
        is left to the network thread to notice and mend. True when nothing more is
        there to read now."""
        self._caller_at = time.monotonic()
        sock = self._sock
        if sock is None:
            return True
        try:
            return self._read_and_handle(sock, wake=False)
        except _LostError as err:
            self._lose(str(err))
            return True

    def _wait(self, timeout: float | None) -> bool:
        # wait in slices, so the network thread sees a caller present and stays away
        fds = self.wait_fds()
        slice_s = CALLER_IDLE_S / 2 if timeout is None else min(timeout, CALLER_IDLE_S / 2)
        self._caller_at = time.monotonic()
        try:
            ready, _, _ = select.select(fds, [], [], slice_s)
        except (OSError, ValueError):  # the network thread closed the socket meanwhile
            return True
        if ready:
            return True
        return timeout is None or timeout > slice_s

    def _drain_wake(self) -> None:
        if not self._woken:  # no byte sent since the last drain: no system call
            return
        self._woken = False
        with contextlib.suppress(OSError):
            while self._wake_r.recv(4096):
                pass

    def recv(self, timeout: float | None = None) -> bytes | None:
        """Next message payload, or None after ``timeout`` seconds."""
        got = self.recv_from(timeout)
        return None if got is None else got[0]

    def _close_wake_if_open(self) -> None:
        for sock in (getattr(self, "_wake_r", None), getattr(self, "_wake_w", None)):
            if sock is not None:
                sock.close()

    def refused(self) -> int:
        """Publishes (and subscriptions) the broker refused."""
        return self.stats.refused

    def close(self, flush_s: float = 2.0) -> None:
        """Wait up to ``flush_s`` seconds for QoS-1 publishes (retained nonce envelopes)
        to be acknowledged, then disconnect and stop the network thread; idempotent."""
        if self._closed.is_set():
            return
        deadline = time.monotonic() + flush_s
        for done in list(self._pending.values()):
            left = deadline - time.monotonic()
            if left <= 0 or not self._connected.is_set():
                break
            done.wait(left)
        self._closed.set()
        with contextlib.suppress(OSError):
            if self._connected.is_set():
                self._write(DISCONNECT_PACKET)
        self._drop()
        self._thread.join(5.0)
        self._close_wake_if_open()


_NAMES = {wire.CONNACK: "CONNACK", wire.SUBACK: "SUBACK"}
_READ_BYTES = 262_144
"""Most bytes taken from the socket per read."""
CALLER_IDLE_S = 0.1
"""The network thread reads the socket only when no caller of ``recv_from`` has
read or waited for this long, seconds."""


def open_mqtt(url: str, mode: Literal["send", "recv"]) -> MqttTransport:
    """The MQTT transport ``url`` names.

    Raises:
        LinkError: a bad URL or no connection.
    """
    endpoint = parse_mqtt_url(url)
    if mode == "send":
        query = parse_qs(urlsplit(url).query)
        given = sorted(RECEIVER_OPTIONS & set(query))
        if given:
            raise LinkError(f"{endpoint.url()}: {', '.join(given)} apply to receiving URLs only")
    return MqttTransport(endpoint, mode)


RECEIVER_OPTIONS = frozenset({"sub", "tiles", "nonces", "advisories", "queue"})
"""URL options that only a receiver uses."""
