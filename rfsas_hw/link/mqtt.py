"""MQTT 5 transport (paho-mqtt 2.x, the ``mqtt`` extra): the link through a broker.

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
"""

from __future__ import annotations

import contextlib
import logging
import secrets
import select
import socket
import ssl
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal
from urllib.parse import parse_qs, urlsplit

from rfsas_hw.errors import LinkError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link.topics import (
    Route,
    TopicRouter,
    advisory_filter,
    bearing_filter,
    check_quadkey,
    nonce_filter,
)
from rfsas_hw.link.transport import Transport
from rfsas_hw.optional import require
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, DEFAULT_GRACE_S, EpochSchedule

if TYPE_CHECKING:
    import paho.mqtt.client as paho

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
        port = parts.port or DEFAULT_PORTS[parts.scheme]
    except ValueError as err:
        raise LinkError(f"{url!r}: bad port: {err}") from err
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
        keepalive_s=max(1, int(_number(query, "keepalive", url, 5))),
        connect_s=_number(query, "connect_s", url, 5.0),
        queue=int(_number(query, "queue", url, 65_536)),
        client_id=_one(query, "client_id", url) or "",
    )


def _csv(query: dict[str, list[str]], name: str, url: str) -> list[str]:
    out = []
    for raw in query.get(name, []):
        for item in raw.split(","):
            try:
                out.append(check_quadkey(item.strip()))
            except LinkError as err:
                raise LinkError(f"{url!r}: {name}: {err}") from err
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


class MqttTransport(Transport):
    """Sends and receives signed datagrams through an MQTT 5 broker.

    Args:
        endpoint: the broker and options.
        mode: ``send`` (publish by the topic contract) or ``recv`` (subscribe).
        router: chooses topics for :meth:`send` (default: by the endpoint's origin
            and schedule).
        clock: UTC ns.

    Raises:
        MissingDependencyError: paho-mqtt is not installed.
        LinkError: the TLS files are unusable, or no connection within ``connect_s``.
    """

    def __init__(
        self,
        endpoint: MqttEndpoint,
        mode: Literal["send", "recv"],
        *,
        router: TopicRouter | None = None,
        clock: Any = time.time_ns,
    ) -> None:
        mqtt = require("paho.mqtt.client")
        self._props = require("paho.mqtt.properties")
        self._ptypes = require("paho.mqtt.packettypes")
        self.endpoint = endpoint
        self.mode = mode
        self.router = router or TopicRouter(endpoint.origin, endpoint.schedule)
        self.clock = clock
        self.stats = MqttStats()
        self.subscriptions = endpoint.subscriptions or (
            (bearing_filter(),) if mode == "recv" else ()
        )
        self._closed = False
        self._lock = threading.Lock()
        self._queue: deque[tuple[bytes, str]] = deque()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._connected = threading.Event()
        self._pending: list[Any] = []
        """QoS-1 publishes not yet acknowledged (close waits for them)."""
        self._last_error = "no answer"
        client_id = endpoint.client_id or f"rfsas-{secrets.token_hex(6)}"
        client: paho.Client = mqtt.Client(
            callback_api_version=mqtt.CallbackAPIVersion.VERSION2,
            client_id=client_id,
            protocol=mqtt.MQTTv5,
        )
        self._client = client
        self._no_conn = mqtt.MQTT_ERR_NO_CONN
        if endpoint.tls:
            try:
                client.tls_set(
                    ca_certs=str(endpoint.ca),
                    certfile=str(endpoint.cert),
                    keyfile=str(endpoint.key),
                    tls_version=ssl.PROTOCOL_TLS_CLIENT,
                )
            except (ssl.SSLError, OSError, ValueError) as err:
                self._close_wake()
                raise LinkError(f"{endpoint.url()}: unusable TLS files: {err}") from err
        client.reconnect_delay_set(1, 8)
        client.max_queued_messages_set(1000)
        client.on_socket_open = self._on_socket_open
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_message = self._on_message
        client.on_subscribe = self._on_subscribe
        client.on_publish = self._on_publish
        client.on_connect_fail = self._on_connect_fail
        try:
            client.connect_async(endpoint.host, endpoint.port, endpoint.keepalive_s)
        except (OSError, ValueError) as err:
            self._close_wake()
            raise LinkError(f"{endpoint.url()}: cannot connect: {err}") from err
        client.loop_start()
        if not self._connected.wait(endpoint.connect_s):
            self.close()
            raise LinkError(
                f"{endpoint.url()}: no connection within {endpoint.connect_s:g} s "
                f"({self._last_error})"
            )

    # --- paho callbacks (paho's network thread) ---

    def _on_socket_open(self, client: Any, userdata: Any, sock: Any) -> None:
        # not every socket paho hands over is TCP (a websocket wrapper)
        with contextlib.suppress(OSError, AttributeError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            self._last_error = f"broker refused the connection: {reason}"
            return
        self.stats.connects += 1
        for topic in self.subscriptions:
            client.subscribe(topic, qos=1 if "/nonce/" in topic else 0)
        self._connected.set()

    def _on_connect_fail(self, client: Any, userdata: Any) -> None:
        self._last_error = "connection failed"

    def _on_disconnect(
        self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any
    ) -> None:
        self._last_error = f"disconnected: {reason}"
        if self._connected.is_set() and not self._closed:
            self.stats.disconnects += 1
            if self.stats.disconnects == 1:
                log.warning("%s: lost the broker (%s); retrying", self.endpoint.url(), reason)
        self._connected.clear()

    def _on_subscribe(self, client: Any, userdata: Any, mid: int, reasons: Any, props: Any) -> None:
        for rc in reasons:
            if rc.is_failure:
                self.stats.refused += 1
                log.warning("%s: a subscription was refused: %s", self.endpoint.url(), rc)

    def _on_publish(self, client: Any, userdata: Any, mid: int, reason: Any, props: Any) -> None:
        # only QoS 1 and 2 get an answer: a refused QoS-0 publish vanishes silently
        if reason.is_failure:
            self.stats.refused += 1
            if self.stats.refused == 1:
                log.warning("%s: the broker refused a publish: %s", self.endpoint.url(), reason)

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        with self._lock:
            was_empty = not self._queue
            if len(self._queue) >= self.endpoint.queue:
                self._queue.popleft()
                self.stats.dropped += 1
            self._queue.append((bytes(msg.payload), str(msg.topic)))
            self.stats.received += 1
        if was_empty:
            with contextlib.suppress(OSError):  # a full wake-up buffer already wakes
                self._wake_w.send(b"\0")

    # --- Transport ---

    @property
    def connected(self) -> bool:
        """True while the broker connection is up."""
        return self._connected.is_set()

    def fileno(self) -> int:
        """A descriptor that is readable while received messages wait."""
        return self._wake_r.fileno()

    def send(self, datagram: bytes) -> None:
        """Publish ``datagram`` on the topic the contract gives it.

        Raises:
            LinkError: it cannot be routed, or the broker is not connected.
        """
        self.publish(self.router.route(datagram, int(self.clock())), datagram)

    def publish(self, route: Route, datagram: bytes) -> None:
        """Publish ``datagram`` as ``route`` says.

        Raises:
            LinkError: the broker is not connected or the client refused it.
        """
        props = None
        if route.expiry_s is not None:
            props = self._props.Properties(self._ptypes.PacketTypes.PUBLISH)
            props.MessageExpiryInterval = int(route.expiry_s)
        info = self._client.publish(
            route.topic, datagram, qos=route.qos, retain=route.retain, properties=props
        )
        if route.qos > 0:
            self._pending = [m for m in self._pending if not m.is_published()] + [info]
        if info.rc != 0:
            self.stats.send_errors += 1
            why = "not connected" if info.rc == self._no_conn else f"error {info.rc}"
            raise LinkError(f"{self.endpoint.url()}: cannot publish to {route.topic}: {why}")
        self.stats.sent += 1

    def recv_from(self, timeout: float | None = None) -> tuple[bytes, str | None] | None:
        """Next message and its topic, or None after ``timeout`` seconds."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            with self._lock:
                if self._queue:
                    return self._queue.popleft()
            self._drain_wake()
            with self._lock:
                if self._queue:
                    return self._queue.popleft()
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return None
            if not self._wait(left):
                return None

    def _wait(self, timeout: float | None) -> bool:
        ready, _, _ = select.select([self._wake_r], [], [], timeout)
        return bool(ready)

    def _drain_wake(self) -> None:
        with contextlib.suppress(OSError):
            while self._wake_r.recv(4096):
                pass

    def recv(self, timeout: float | None = None) -> bytes | None:
        """Next message payload, or None after ``timeout`` seconds."""
        got = self.recv_from(timeout)
        return None if got is None else got[0]

    def _close_wake(self) -> None:
        self._wake_r.close()
        self._wake_w.close()

    def close(self, flush_s: float = 2.0) -> None:
        """Wait up to ``flush_s`` seconds for QoS-1 publishes (retained nonce envelopes)
        to be acknowledged, then disconnect and stop the network thread; idempotent."""
        if self._closed:
            return
        deadline = time.monotonic() + flush_s
        for info in self._pending:
            left = deadline - time.monotonic()
            if left <= 0 or not self._connected.is_set():
                break
            with contextlib.suppress(RuntimeError, ValueError):
                info.wait_for_publish(left)
        self._closed = True
        try:
            self._client.disconnect()
        finally:
            self._client.loop_stop()
            self._close_wake()


def open_mqtt(url: str, mode: Literal["send", "recv"]) -> MqttTransport:
    """The MQTT transport ``url`` names.

    Raises:
        MissingDependencyError: paho-mqtt is not installed.
        LinkError: a bad URL or no connection.
    """
    return MqttTransport(parse_mqtt_url(url), mode)
