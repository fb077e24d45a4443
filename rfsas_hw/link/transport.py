"""Datagram transports for the link: a small interface, UDP unicast and multicast.

A transport moves opaque datagrams; it knows nothing of message formats, so
another carrier (a broker, a radio) can be added behind the same interface.

URLs::

    udp://127.0.0.1:47000              unicast (send to / listen on that address)
    udp://239.255.42.1:47000           multicast group, on the loopback interface
    udp://239.255.42.1:47000?iface=192.168.1.10&ttl=4
                                       multicast on another interface, TTL 4
    udp://0.0.0.0:47000?rcvbuf=262144  a listener with a 256 KiB receive buffer

Multicast defaults to the loopback interface with TTL 1, so nothing leaves
the machine unless asked for. A listener asks for a 1 MiB receive buffer: a
flood it cannot keep up with then costs at most that much queueing delay
(the kernel may grant more or less; ``net.core.rmem_max`` caps it).
"""

from __future__ import annotations

import ipaddress
import select
import socket
import time
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal
from urllib.parse import parse_qs, urlsplit

from rfsas_hw.closing import ClosingContext
from rfsas_hw.errors import LinkError

RECV_BUFFER = 65_536
"""Bytes read per datagram: the largest UDP payload, so oversized datagrams are seen whole."""
DEFAULT_RCVBUF = 1 << 20
"""Receive buffer a listener asks the kernel for, bytes."""


@dataclass(frozen=True, slots=True)
class UdpEndpoint:
    """A parsed ``udp://HOST:PORT[?iface=ADDR&ttl=N]`` URL."""

    host: str
    port: int
    iface: str = "127.0.0.1"
    """Interface address for multicast (ignored for unicast)."""
    ttl: int = 1
    """Multicast TTL (ignored for unicast)."""
    rcvbuf: int = DEFAULT_RCVBUF
    """Receive buffer a listener asks for, bytes."""

    @property
    def multicast(self) -> bool:
        """True when ``host`` is an IPv4 multicast group."""
        try:
            return ipaddress.IPv4Address(self.host).is_multicast
        except ValueError:
            return False

    def url(self) -> str:
        """The URL form (an IPv6 host in brackets)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        if self.multicast:
            return f"udp://{host}:{self.port}?iface={self.iface}&ttl={self.ttl}"
        return f"udp://{host}:{self.port}"


def parse_url(url: str) -> UdpEndpoint:
    """Parse a transport URL.

    Raises:
        LinkError: unknown scheme, missing host or port, bad port, bad query.
    """
    parts = urlsplit(url)
    if parts.scheme != "udp":
        raise LinkError(
            f"{url!r}: unsupported transport {parts.scheme!r}, expected udp://HOST:PORT"
        )
    try:
        port = parts.port
    except ValueError as err:
        raise LinkError(f"{url!r}: bad port: {err}") from err
    if not parts.hostname or port is None:
        raise LinkError(f"{url!r}: expected udp://HOST:PORT")
    query = parse_qs(parts.query, strict_parsing=False)
    unknown = set(query) - {"iface", "ttl", "rcvbuf"}
    if unknown:
        raise LinkError(
            f"{url!r}: unknown option(s) {', '.join(sorted(unknown))}; use iface, ttl, rcvbuf"
        )
    iface = query.get("iface", ["127.0.0.1"])[-1]
    try:
        ttl = int(query.get("ttl", ["1"])[-1])
        rcvbuf = int(query.get("rcvbuf", [str(DEFAULT_RCVBUF)])[-1])
        ipaddress.IPv4Address(iface)
    except ValueError as err:
        raise LinkError(f"{url!r}: bad iface, ttl or rcvbuf: {err}") from err
    if not 0 <= ttl <= 255:
        raise LinkError(f"{url!r}: ttl {ttl} outside 0-255")
    if not 4096 <= rcvbuf <= 1 << 30:
        raise LinkError(f"{url!r}: rcvbuf {rcvbuf} outside 4096 bytes - 1 GiB")
    return UdpEndpoint(parts.hostname, port, iface, ttl, rcvbuf)


class Transport(ClosingContext, ABC):
    """Moves whole datagrams. ``send`` for publishers, ``recv`` for receivers."""

    @abstractmethod
    def send(self, datagram: bytes) -> None:
        """Send one datagram.

        Raises:
            LinkError: the datagram could not be sent.
        """

    @abstractmethod
    def recv(self, timeout: float | None = None) -> bytes | None:
        """Next datagram, or None after ``timeout`` seconds (None: wait forever, 0: poll)."""

    @abstractmethod
    def close(self) -> None:
        """Release the socket; idempotent."""

    def recv_from(self, timeout: float | None = None) -> tuple[bytes, str | None] | None:
        """Next datagram and where it was published (a broker topic; None when the
        carrier has no topics), or None after ``timeout`` seconds."""
        datagram = self.recv(timeout)
        return None if datagram is None else (datagram, None)

    def recv_many(
        self, timeout: float | None = None, limit: int = 4096
    ) -> list[tuple[bytes, str | None]]:
        """Everything queued, at most ``limit`` (datagram, topic) pairs in arrival
        order, waiting up to ``timeout`` seconds for the first; empty after the
        timeout. By default :meth:`recv_from` until it has nothing more."""
        out: list[tuple[bytes, str | None]] = []
        got = self.recv_from(timeout)
        while got is not None:
            out.append(got)
            if len(out) >= limit:
                break
            got = self.recv_from(0)
        return out

    def refused(self) -> int:
        """Datagrams sent without error that the far end then refused (a broker's
        negative acknowledgement); 0 for carriers that cannot tell."""
        return 0

    def fileno(self) -> int:
        """A descriptor that is readable while datagrams wait (for ``select``)."""
        raise LinkError(f"{type(self).__name__} cannot be waited on with select")

    def wait_fds(self) -> list[int]:
        """Every descriptor whose readability means :meth:`recv_from` may have
        something (for ``select``); by default :meth:`fileno`."""
        return [self.fileno()]


class UdpTransport(Transport):
    """UDP unicast or multicast on a real socket.

    Args:
        endpoint: where to send to, or what to listen on.
        mode: ``send`` (connect-less sender) or ``recv`` (bound listener).

    Raises:
        LinkError: the socket cannot be created, bound, or join its group.
    """

    def __init__(self, endpoint: UdpEndpoint, mode: Literal["send", "recv"]) -> None:
        self.endpoint = endpoint
        self.mode = mode
        self._closed = False
        self.sent = 0
        self.send_errors = 0
        family, self._address = _resolve(endpoint)
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            if mode == "recv":
                self._setup_recv(sock, endpoint.rcvbuf)
            else:
                self._setup_send(sock)
        except OSError as err:
            sock.close()
            raise LinkError(f"{endpoint.url()}: cannot open for {mode}: {err}") from err
        self._sock = sock

    def _setup_recv(self, sock: socket.socket, rcvbuf: int) -> None:
        ep = self.endpoint
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        if ep.multicast:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((ep.host, ep.port))
            membership = socket.inet_aton(ep.host) + socket.inet_aton(ep.iface)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
        else:
            sock.bind(self._address)
        sock.setblocking(False)

    def _setup_send(self, sock: socket.socket) -> None:
        ep = self.endpoint
        if ep.multicast:
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(ep.iface))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, ep.ttl)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)

    @property
    def address(self) -> tuple[str, int]:
        """The socket's own (host, port); for a listener on port 0, the port it got."""
        host, port = self._sock.getsockname()[:2]
        return str(host), int(port)

    def send(self, datagram: bytes) -> None:
        """Send one datagram to the endpoint.

        Raises:
            LinkError: the kernel refused it (too large, no route).
        """
        try:
            self._sock.sendto(datagram, self._address)
        except OSError as err:
            self.send_errors += 1
            raise LinkError(
                f"{self.endpoint.url()}: cannot send {len(datagram)} bytes: {err}"
            ) from err
        self.sent += 1

    def recv(self, timeout: float | None = None) -> bytes | None:
        """Next datagram (whole, up to 64 KiB), or None after ``timeout`` seconds."""
        try:
            return self._sock.recv(RECV_BUFFER)
        except BlockingIOError:
            pass
        if timeout is not None and timeout <= 0:
            return None
        ready, _, _ = select.select([self._sock], [], [], timeout)
        if not ready:
            return None
        try:
            return self._sock.recv(RECV_BUFFER)
        except BlockingIOError:
            return None

    def fileno(self) -> int:
        """The socket's descriptor."""
        return self._sock.fileno()

    def close(self) -> None:
        """Close the socket; idempotent."""
        if not self._closed:
            self._closed = True
            self._sock.close()


class FanoutTransport(Transport):
    """Several transports as one: ``send`` goes out on every one, ``recv`` takes from
    whichever has something (a sensor on a broker *and* on local UDP; the receiver's
    replay guard drops the second copy).

    ``send`` fails only when every transport failed; single failures are counted
    in :attr:`send_errors` per URL.

    Args:
        transports: URL → open transport; the fanout owns them.
    """

    def __init__(self, transports: dict[str, Transport]) -> None:
        if not transports:
            raise LinkError("a fanout needs at least one transport")
        self.transports = dict(transports)
        self.send_errors: dict[str, int] = dict.fromkeys(self.transports, 0)
        self._order = list(self.transports.values())
        self._next = 0

    def send(self, datagram: bytes) -> None:
        """Send on every transport.

        Raises:
            LinkError: every transport failed (the first error is chained).
        """
        errors: list[LinkError] = []
        for url, transport in self.transports.items():
            try:
                transport.send(datagram)
            except LinkError as err:
                self.send_errors[url] += 1
                errors.append(err)
        if len(errors) == len(self.transports):
            raise LinkError(f"every transport failed: {errors[0]}") from errors[0]

    def refused(self) -> int:
        """What the far ends refused, over every transport."""
        return sum(t.refused() for t in self.transports.values())

    def recv_from(self, timeout: float | None = None) -> tuple[bytes, str | None] | None:
        """Next datagram from any transport (taken in turn), or None after ``timeout`` s."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            for _ in range(len(self._order)):
                transport = self._order[self._next]
                self._next = (self._next + 1) % len(self._order)
                got = transport.recv_from(0)
                if got is not None:
                    return got
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return None
            fds = [fd for t in self._order for fd in t.wait_fds()]
            try:
                ready, _, _ = select.select(fds, [], [], left)
            except (OSError, ValueError):  # a broker socket closed while waiting: ask again
                continue
            if not ready:
                return None

    def recv(self, timeout: float | None = None) -> bytes | None:
        """Next datagram from any transport, or None after ``timeout`` seconds."""
        got = self.recv_from(timeout)
        return None if got is None else got[0]

    def close(self) -> None:
        """Close every transport; idempotent."""
        for transport in self._order:
            transport.close()


def _resolve(endpoint: UdpEndpoint) -> tuple[int, tuple[Any, ...]]:
    """Address family and socket address of ``endpoint`` (IPv4 or IPv6), resolved once
    when the transport opens, so a bad host name fails there and not, silently, on
    every send.

    Raises:
        LinkError: the host name does not resolve.
    """
    if endpoint.multicast:
        return socket.AF_INET, (endpoint.host, endpoint.port)
    try:
        infos = socket.getaddrinfo(endpoint.host, endpoint.port, type=socket.SOCK_DGRAM)
    except (OSError, UnicodeError) as err:
        raise LinkError(f"{endpoint.url()}: cannot resolve {endpoint.host!r}: {err}") from err
    # prefer IPv4 when a name has both, as a sender and a listener on "localhost" must agree
    infos.sort(key=lambda info: info[0] != socket.AF_INET)
    family, _, _, _, sockaddr = infos[0]
    return int(family), tuple(sockaddr)


def open_transport(url: str, mode: Literal["send", "recv"]) -> Transport:
    """Open the transport a URL names, for sending or receiving: ``udp://`` here,
    ``mqtt://`` and ``mqtts://`` in :mod:`rfsas_hw.link.mqtt`.

    Raises:
        LinkError: bad URL, socket failure, or no broker connection.
    """
    if url.startswith(("mqtt://", "mqtts://")):
        from rfsas_hw.link.mqtt import open_mqtt

        return open_mqtt(url, mode)
    return UdpTransport(parse_url(url), mode)


def open_transports(urls: Sequence[str], mode: Literal["send", "recv"]) -> Transport:
    """One transport for one URL, a :class:`FanoutTransport` over several.

    Raises:
        LinkError: no URL, a bad URL, socket failure or no broker connection (those
            already open are closed).
    """
    if not urls:
        raise LinkError("no transport URL given")
    if len(urls) == 1:
        return open_transport(urls[0], mode)
    opened: dict[str, Transport] = {}
    try:
        for url in dict.fromkeys(urls):
            opened[url] = open_transport(url, mode)
    except Exception:
        for transport in opened.values():
            transport.close()
        raise
    return FanoutTransport(opened)
