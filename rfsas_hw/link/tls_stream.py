"""TLS over a connected TCP socket through memory buffers, for the MQTT client.

A broker sends every message in its own TLS record, and ``ssl.SSLSocket.recv``
returns one record per call, each call reading the socket twice (the record's
header, then its body). :class:`TlsStream` reads the socket once for everything
that has arrived, decrypts every complete record from memory and returns their
bytes together: one system call and one packet-parser pass for a batch of
messages instead of two system calls and one pass per message. It tells
(:attr:`TlsStream.drained`) when that read emptied the socket's buffer, so a
reader need not ask the socket again only to hear that nothing is left.

It offers the part of the socket interface :mod:`rfsas_hw.link.mqtt` uses
(``recv``, ``send``, ``sendall``, ``settimeout``, ``setblocking``, ``fileno``,
``pending``, ``shutdown``, ``close``), with the same meanings: a non-blocking
``recv`` with nothing to return raises ``ssl.SSLWantReadError``, a timed-out one
``TimeoutError``, a closed connection returns ``b""``. Not thread-safe: the
caller serialises every call (the MQTT transport holds one lock for them).
"""

from __future__ import annotations

import select
import socket
import ssl
import time

_READ = 262_144
"""Most bytes taken from the socket per read."""
WRITE_TIMEOUT_S = 2.0
"""How long a write waits for room in the socket buffer, seconds."""


class TlsStream:
    """A client TLS connection over ``raw``, handshake done in the constructor.

    Args:
        raw: a connected TCP socket (taken over: closed by :meth:`close`).
        context: the client TLS context (CA, certificate, key).
        server_hostname: the name the server's certificate must carry.
        timeout: seconds the handshake may take.

    Raises:
        ssl.SSLError: the handshake failed (certificate refused, protocol error).
        TimeoutError: no handshake within ``timeout``.
        OSError: the connection failed or closed during the handshake.
    """

    def __init__(
        self, raw: socket.socket, context: ssl.SSLContext, server_hostname: str, timeout: float
    ) -> None:
        self.raw = raw
        self._in = ssl.MemoryBIO()
        self._out = ssl.MemoryBIO()
        self._tls = context.wrap_bio(self._in, self._out, server_hostname=server_hostname)
        self._timeout: float | None = timeout
        self._eof = False
        self.drained = False
        """True when the last read of the socket took less than it could (its buffer was
        emptied) or found nothing: reading again now would most likely find nothing."""
        raw.setblocking(False)
        deadline = time.monotonic() + timeout
        while True:
            try:
                self._tls.do_handshake()
                break
            except ssl.SSLWantReadError:
                self._flush()
                if not self._fill(deadline):
                    raise OSError(
                        "the server closed the connection during the TLS handshake"
                    ) from None
        self._flush()

    # --- reading ---

    def recv(self, bufsize: int = _READ) -> bytes:
        """Every decrypted byte available now (at least one; ``bufsize`` is not a
        limit: whole records are returned), after waiting as :meth:`settimeout` says.
        ``b""`` once the connection is closed.

        Raises:
            ssl.SSLWantReadError: non-blocking, and nothing has arrived.
            TimeoutError: nothing within the timeout.
            ssl.SSLError: a corrupt or forged record (the connection is lost).
            OSError: the socket failed.
        """
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        while True:
            data = self._decrypted()
            if data or self._eof:
                return data
            if self._timeout == 0.0:
                if not self._fill(None, wait=False):
                    self._eof = True
                continue
            if not self._fill(deadline):
                self._eof = True

    def _decrypted(self) -> bytes:
        parts = []
        while True:
            try:
                data = self._tls.read(_READ)
            except ssl.SSLWantReadError:
                break
            except (ssl.SSLZeroReturnError, ssl.SSLEOFError):
                # the peer's close_notify, or the connection closed without one (read
                # as the end, like SSLSocket's default suppress_ragged_eofs)
                self._eof = True
                break
            if not data:
                self._eof = True
                break
            parts.append(data)
        if self._out.pending:  # e.g. a key update answered while reading
            self._flush()
        return b"".join(parts)

    def _fill(self, deadline: float | None, wait: bool = True) -> bool:
        """Move what the socket holds into the TLS input; False at end of stream.

        Raises:
            ssl.SSLWantReadError: not ``wait`` and nothing has arrived.
            TimeoutError: nothing before ``deadline``.
        """
        while True:
            try:
                data = self.raw.recv(_READ)
            except (BlockingIOError, InterruptedError):
                self.drained = True
                if not wait:
                    raise ssl.SSLWantReadError("nothing to read") from None
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    raise TimeoutError("timed out") from None
                select.select([self.raw], [], [], left)
                continue
            if not data:
                self._in.write_eof()
                return False
            self.drained = len(data) < _READ
            self._in.write(data)
            return True

    def pending(self) -> int:
        """Decrypted bytes held and not yet returned (0 after every :meth:`recv`)."""
        return self._tls.pending()

    # --- writing ---

    def send(self, data: bytes | memoryview) -> int:
        """Encrypt and write all of ``data``, waiting up to :data:`WRITE_TIMEOUT_S`
        for room in the socket buffer; returns ``len(data)``.

        Raises:
            OSError: the socket failed, or did not take the data in time.
        """
        written = self._tls.write(data)
        self._flush()
        return written

    def sendall(self, data: bytes | memoryview) -> None:
        """:meth:`send`."""
        self.send(data)

    def _flush(self) -> None:
        view = memoryview(self._out.read())
        deadline = time.monotonic() + WRITE_TIMEOUT_S
        while view:
            try:
                view = view[self.raw.send(view) :]
            except (BlockingIOError, InterruptedError):
                left = deadline - time.monotonic()
                if left <= 0:
                    raise OSError("the broker did not take the data within 2 s") from None
                select.select([], [self.raw], [], min(left, 0.05))

    # --- the socket's other parts ---

    def settimeout(self, timeout: float | None) -> None:
        """Timeout of :meth:`recv`, seconds (None: wait as long as it takes; 0: never)."""
        self._timeout = timeout

    def setblocking(self, flag: bool) -> None:
        """``settimeout(None)`` when ``flag``, else ``settimeout(0.0)``."""
        self._timeout = None if flag else 0.0

    def fileno(self) -> int:
        """The TCP socket's descriptor (readable when records may have arrived)."""
        return self.raw.fileno()

    def shutdown(self, how: int) -> None:
        """Shut the TCP socket down (wakes a reader of it).

        Raises:
            OSError: it is not connected.
        """
        self.raw.shutdown(how)

    def close(self) -> None:
        """Close the TCP socket (no TLS close_notify, as ``SSLSocket.close``)."""
        self.raw.close()
