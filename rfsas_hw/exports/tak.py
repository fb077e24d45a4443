"""Live Cursor-on-Target to a TAK server or client: a result sink of the backend.

``udp://HOST:PORT`` sends one event per datagram through the link's UDP
transport (unicast, or a multicast group such as TAK's situational-awareness
group); ``tcp://HOST:PORT`` streams events one after the other over a TCP
connection (a TAK server's plain CoT input). TLS inputs are not supported.

The sender never holds the backend up: a TCP connection is attempted at most
once per ``retry_s`` with a short timeout, and an event that cannot be sent is
counted in :attr:`CotSender.dropped`, not retried.
"""

from __future__ import annotations

import logging
import math
import socket
import time
from collections.abc import Sequence
from urllib.parse import urlsplit
from xml.etree import ElementTree as ET

from rfsas_hw.errors import ConfigError, LinkError
from rfsas_hw.exports.cot import STALE_S, fix_event_local, track_event_local
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link.transport import Transport, open_transport
from rfsas_hw.records import Assessment, Fix

log = logging.getLogger(__name__)

__all__ = ["CotSender"]


class CotSender:
    """Sends each step's trustworthy fixes and tracked assessments as CoT events.

    Args:
        url: ``udp://HOST:PORT`` or ``tcp://HOST:PORT``.
        origin: the site origin (CoT is geodetic).
        stale_s: seconds after which a TAK map drops an event that was not renewed.
        timeout_s: TCP connect and send timeout, seconds.
        retry_s: least time between TCP connection attempts, seconds.

    Raises:
        ConfigError: a URL that is neither ``udp://`` nor ``tcp://`` with a host and port.
        LinkError: the UDP socket cannot be opened.
    """

    def __init__(
        self,
        url: str,
        origin: SiteOrigin,
        *,
        stale_s: float = STALE_S,
        timeout_s: float = 0.5,
        retry_s: float = 2.0,
    ) -> None:
        parts = urlsplit(url)
        if parts.scheme not in ("udp", "tcp") or not parts.hostname or parts.port is None:
            raise ConfigError(f"CoT URL {url!r}: expected udp://HOST:PORT or tcp://HOST:PORT")
        self.url = url
        self.origin = origin
        self.stale_s = stale_s
        self.timeout_s = timeout_s
        self.retry_s = retry_s
        self.sent = 0
        """Events sent."""
        self.dropped = 0
        """Events that could not be sent."""
        self._scheme = parts.scheme
        self._address = (parts.hostname, parts.port)
        self._udp: Transport | None = None
        self._tcp: socket.socket | None = None
        self._next_try = 0.0
        if parts.scheme == "udp":
            self._udp = open_transport(url, "send")

    def _connect(self) -> socket.socket | None:
        if self._tcp is not None:
            return self._tcp
        now = time.monotonic()
        if now < self._next_try:
            return None
        self._next_try = now + self.retry_s
        try:
            self._tcp = socket.create_connection(self._address, timeout=self.timeout_s)
        except OSError as err:
            log.warning("CoT: cannot connect to %s: %s", self.url, err)
            return None
        self._tcp.settimeout(self.timeout_s)
        return self._tcp

    def send(self, event: ET.Element) -> bool:
        """Send one event; True if it went out."""
        data = ET.tostring(event, encoding="utf-8")
        try:
            if self._scheme == "udp":
                if self._udp is None:
                    self.dropped += 1
                    return False
                self._udp.send(data)
            else:
                conn = self._connect()
                if conn is None:
                    self.dropped += 1
                    return False
                conn.sendall(data + b"\n")
        except (OSError, LinkError) as err:
            self.dropped += 1
            if self._tcp is not None:
                log.warning("CoT: connection to %s lost: %s", self.url, err)
                self._tcp.close()
                self._tcp = None
            return False
        self.sent += 1
        return True

    def on_results(self, fixes: Sequence[Fix], assessments: Sequence[Assessment]) -> None:
        """Send the step's trustworthy fixes, then every tracked emitter's state and advisory."""
        for fix in fixes:
            if fix.ok and math.isfinite(fix.x_m) and math.isfinite(fix.y_m):
                self.send(fix_event_local(fix, self.origin, stale_s=self.stale_s))
        for a in assessments:
            if all(math.isfinite(v) for v in (a.x_m, a.y_m, a.vx_mps, a.vy_mps)):
                self.send(track_event_local(a, self.origin, stale_s=self.stale_s))

    def close(self) -> None:
        """Close the socket; idempotent."""
        if self._udp is not None:
            self._udp.close()
            self._udp = None
        if self._tcp is not None:
            self._tcp.close()
            self._tcp = None
