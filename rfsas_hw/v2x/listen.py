"""Receiving CPMs from other stations (and our own): a UDP port or an MQTT topic.

``udp://HOST:PORT`` binds a UDP socket; a datagram is taken only from a sender
whose address is in the allow list (loopback by default), one at a time, each
decoded at once, so nothing queues beyond the socket's own buffer; UDP holds no
per-peer state, so there is no idle peer to time out. A datagram may be a bare
CPM, BTP-B + CPM or GeoNetworking + BTP-B + CPM
(:func:`~rfsas_hw.v2x.geonet.split_datagram`).
``mqtt://HOST[:PORT]/TOPIC`` (or ``mqtts://…?ca=…&cert=…&key=…``) subscribes to
TOPIC through the link's MQTT client: the broker authenticates the publishers,
and the client's queue is bounded (its ``queue`` option).
"""

from __future__ import annotations

import ipaddress
import socket
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlencode, urlsplit, urlunsplit

from rfsas_hw.errors import ConfigError, CpmFormatError, LinkError
from rfsas_hw.link.transport import Transport, open_transport
from rfsas_hw.v2x.codec import decode_cpm_tree
from rfsas_hw.v2x.geonet import split_datagram

__all__ = ["CpmListener", "ReceivedCpm"]

MAX_DATAGRAM = 65_535


@dataclass(frozen=True, slots=True)
class ReceivedCpm:
    """One received datagram: the decoded CPM, or why it could not be read."""

    t_ns: int
    """Arrival time, UTC ns."""
    sender: str
    """``HOST:PORT`` of a UDP sender, or the MQTT topic."""
    cpm: dict[str, Any] | None
    """The CPM as JSON values (:func:`~rfsas_hw.v2x.codec.decode_cpm_tree`), or None."""
    data: bytes = b""
    """The CPM's bytes without BTP-B/GeoNetworking headers (the datagram when those
    cannot be read)."""
    error: str = ""
    """Why the datagram is not a readable CPM (empty when it is)."""


class CpmListener:
    """Receives and decodes CPMs (see the module docstring).

    Args:
        url: ``udp://HOST:PORT`` or ``mqtt(s)://HOST[:PORT]/TOPIC``.
        allow: UDP senders accepted, as networks (``127.0.0.0/8``, ``10.1.2.3``).

    Raises:
        ConfigError: a bad URL or network.
        LinkError: the port cannot be bound or the broker cannot be reached.
    """

    def __init__(self, url: str, allow: Sequence[str] = ("127.0.0.0/8", "::1/128")) -> None:
        parts = urlsplit(url)
        self.url = url
        self.stats: Counter[str] = Counter()
        """``received``, ``decoded``, ``bad`` (not a CPM) and ``refused_sender``."""
        self._udp: socket.socket | None = None
        self._mqtt: Transport | None = None
        try:
            self.allow = [ipaddress.ip_network(a, strict=False) for a in allow]
        except ValueError as err:
            raise ConfigError(f"allowed sender {err}") from err
        if parts.scheme == "udp":
            try:
                port = parts.port
            except ValueError as err:
                raise ConfigError(f"{url!r}: bad port: {err}") from err
            if not parts.hostname or port is None:
                raise ConfigError(f"{url!r}: expected udp://HOST:PORT")
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                sock.bind((parts.hostname, port))
            except OSError as err:
                sock.close()
                raise LinkError(f"{url!r}: cannot bind: {err.strerror or err}") from err
            self._udp = sock
        elif parts.scheme in ("mqtt", "mqtts"):
            topic = parts.path.strip("/")
            if not topic:
                raise ConfigError(f"{url!r}: name the topic: mqtt://HOST[:PORT]/TOPIC")
            query = parts.query + ("&" if parts.query else "") + urlencode({"sub": topic})
            self._mqtt = open_transport(urlunsplit(parts._replace(path="", query=query)), "recv")
        else:
            raise ConfigError(f"{url!r}: expected udp://HOST:PORT or mqtt(s)://HOST[:PORT]/TOPIC")

    @property
    def address(self) -> tuple[str, int] | None:
        """The bound UDP address (None for MQTT)."""
        if self._udp is None:
            return None
        host, port = self._udp.getsockname()[:2]
        return str(host), int(port)

    def _allowed(self, host: str) -> bool:
        try:
            ip = ipaddress.ip_address(host)
        except ValueError:
            return False
        return any(ip in net for net in self.allow)

    def receive(self, timeout: float | None = None) -> ReceivedCpm | None:
        """The next datagram from an allowed sender, decoded; None after ``timeout`` s."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            if self._udp is not None:
                self._udp.settimeout(left)
                try:
                    data, (host, port, *_) = self._udp.recvfrom(MAX_DATAGRAM)
                except TimeoutError:
                    return None
                except OSError as err:
                    raise LinkError(f"{self.url}: receive failed: {err}") from err
                if not self._allowed(host):
                    self.stats["refused_sender"] += 1
                    continue
                sender = f"{host}:{port}"
            elif self._mqtt is not None:
                got = self._mqtt.recv_from(left)
                if got is None:
                    return None
                data, topic = got
                sender = topic or ""
            else:
                raise LinkError(f"{self.url}: listener is closed")
            return self._decode(data, sender)

    def _decode(self, data: bytes, sender: str) -> ReceivedCpm:
        self.stats["received"] += 1
        now = time.time_ns()
        cpm = data
        try:
            cpm = split_datagram(data, f"datagram from {sender}")
            tree = decode_cpm_tree(cpm)
        except CpmFormatError as err:
            self.stats["bad"] += 1
            return ReceivedCpm(now, sender, None, cpm, str(err))
        self.stats["decoded"] += 1
        return ReceivedCpm(now, sender, tree, cpm)

    def close(self) -> None:
        """Close the socket or broker connection; idempotent."""
        if self._udp is not None:
            self._udp.close()
            self._udp = None
        if self._mqtt is not None:
            self._mqtt.close()
            self._mqtt = None
