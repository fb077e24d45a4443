"""Put a :class:`~rfsas_hw.board.emulator.BoardEmulator` on a pseudo-terminal or a TCP port.

:class:`PtyEndpoint` opens a pty pair and (optionally) keeps a stable
symlink to its slave side, the way udev's ``/dev/serial/by-id`` links stay
put across USB re-plugs; :class:`TcpEndpoint` serves one client at a time.
:class:`EmulatorRunner` paces the board's output at the line rate of a
UART (10 bits per byte), applies faults, and emulates unplugging.

Like a real UART, the emulated board never waits for the host: bytes the
host does not read in time are lost (counted as ``overrun_bytes``).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import select
import socket
import threading
import time
import tty
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Protocol, Self

from rfsas_hw.board.emulator import BoardEmulator
from rfsas_hw.board.faults import FaultInjector, Faults
from rfsas_hw.errors import SourceError

log = logging.getLogger(__name__)


class Endpoint(Protocol):
    """One end of the emulated serial line."""

    path: str
    """What a host opens (a device path or a pyserial URL)."""

    def open(self) -> None: ...
    def close(self) -> None: ...
    def fileno(self) -> int | None: ...
    def read(self) -> bytes: ...
    def write(self, data: bytes) -> int: ...


class PtyEndpoint:
    """A pseudo-terminal; the host opens :attr:`path`.

    Args:
        link: path of a symlink to keep pointing at the current slave device
            (survives the re-open after an emulated unplug); None to use the
            slave device path itself.
    """

    def __init__(self, link: str | Path | None = None) -> None:
        self.link = Path(link) if link is not None else None
        self._master: int | None = None
        self._slave: int | None = None
        self.device = ""
        self.path = ""
        self.open()

    def open(self) -> None:
        """Create the pty pair (raw mode, so no byte is translated or echoed)."""
        master, slave = os.openpty()
        tty.setraw(slave)
        tty.setraw(master)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self.device = os.ttyname(slave)
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".new")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self.device)
            tmp.replace(self.link)
            self.path = str(self.link)
        else:
            self.path = self.device

    def close(self) -> None:
        """Hang up: the host's next read fails, as when a USB adapter is pulled."""
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                self.link.unlink()
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None

    def fileno(self) -> int | None:
        return self._master

    def read(self) -> bytes:
        if self._master is None:
            return b""
        try:
            return os.read(self._master, 65536)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as err:
            if err.errno == errno.EIO:  # no process has the slave open
                return b""
            raise

    def write(self, data: bytes) -> int:
        if self._master is None:
            return 0
        try:
            return os.write(self._master, data)
        except (BlockingIOError, InterruptedError):
            return 0


class TcpEndpoint:
    """A TCP server for one client at a time; the host opens ``socket://HOST:PORT``."""

    def __init__(self, port: int = 0, host: str = "127.0.0.1") -> None:
        self.host = host
        self._server: socket.socket | None = None
        self._client: socket.socket | None = None
        self.port = port
        self.path = ""
        self.open()

    def open(self) -> None:
        """Listen (again) on the port."""
        srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            srv.bind((self.host, self.port))
        except OSError as err:
            srv.close()
            raise SourceError(f"cannot listen on {self.host}:{self.port}: {err}") from err
        srv.listen(1)
        srv.setblocking(False)
        self._server = srv
        self.port = srv.getsockname()[1]
        self.path = f"socket://{self.host}:{self.port}"

    def close(self) -> None:
        """Drop the client and stop listening."""
        for s in (self._client, self._server):
            if s is not None:
                s.close()
        self._client = self._server = None

    def _accept(self) -> None:
        if self._client is None and self._server is not None:
            try:
                client, _ = self._server.accept()
            except BlockingIOError:
                return
            client.setblocking(False)
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._client = client

    def fileno(self) -> int | None:
        self._accept()
        if self._client is not None:
            return self._client.fileno()
        return self._server.fileno() if self._server is not None else None

    def read(self) -> bytes:
        self._accept()
        if self._client is None:
            return b""
        try:
            data = self._client.recv(65536)
        except BlockingIOError:
            return b""
        except OSError:
            data = b""
        if not data:  # the host went away: wait for the next one
            self._client.close()
            self._client = None
        return data

    def write(self, data: bytes) -> int:
        self._accept()
        if self._client is None:
            return 0
        try:
            return self._client.send(data)
        except BlockingIOError:
            return 0
        except OSError:
            self._client.close()
            self._client = None
            return 0


@dataclass
class RunnerStats:
    """What went over the emulated line."""

    bytes_sent: int = 0
    """Bytes the host could read."""
    overrun_bytes: int = 0
    """Bytes lost because the host did not read in time."""
    stalls: int = 0
    disconnects: int = 0


class EndpointServer(ABC):
    """Serves an emulated unit on an endpoint, in the caller's thread (:meth:`run`) or a
    background one (:meth:`start`), until :meth:`stop`.

    A subclass sets :attr:`endpoint`, calls ``super().__init__()`` and names its thread
    in :attr:`thread_name`.
    """

    thread_name: ClassVar[str] = "emulator"
    """Name of the background thread."""
    endpoint: PtyEndpoint | TcpEndpoint

    def __init__(self) -> None:
        self.stop_event = threading.Event()
        self._thread: threading.Thread | None = None

    @abstractmethod
    def run(self, duration_s: float | None = None) -> None:
        """Serve until :meth:`stop` (or for ``duration_s`` seconds)."""

    def start(self) -> Self:
        """Run in a background thread (for tests and embedding)."""
        self._thread = threading.Thread(target=self.run, name=self.thread_name, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the loop, wait for the thread, close the endpoint."""
        self.stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.endpoint.close()


class EmulatorRunner(EndpointServer):
    """Runs a board emulator on an endpoint until stopped.

    Args:
        emulator: the board.
        endpoint: pty or TCP.
        baud: line rate in bit/s (10 bits per byte); None sends as fast as
            the board produces.
        faults: what to break.
        tick_s: loop period, seconds.
    """

    thread_name = "board-emulator"

    def __init__(
        self,
        emulator: BoardEmulator,
        endpoint: PtyEndpoint | TcpEndpoint,
        *,
        baud: int | None = 921_600,
        faults: Faults | None = None,
        tick_s: float = 0.002,
    ) -> None:
        self.emulator = emulator
        self.endpoint = endpoint
        self.baud = baud
        self.faults = faults or Faults()
        self.injector = FaultInjector(self.faults)
        self.tick_s = tick_s
        self.stats = RunnerStats()
        super().__init__()

    def run(self, duration_s: float | None = None) -> None:
        """Serve until :meth:`stop` (or for ``duration_s`` seconds)."""
        f = self.faults
        start = last = time.monotonic()
        next_stall = start + f.stall_every_s if f.stall_every_s > 0 else float("inf")
        next_unplug = start + f.disconnect_every_s if f.disconnect_every_s > 0 else float("inf")
        stalled_until = 0.0
        budget = 0.0
        rate = self.baud / 10.0 if self.baud else None
        while not self.stop_event.is_set():
            now = time.monotonic()
            if duration_s is not None and now - start >= duration_s:
                break
            if now >= next_unplug:
                self._unplug(f.disconnect_s)
                next_unplug = time.monotonic() + f.disconnect_every_s
                last = time.monotonic()
                budget = 0.0
                continue
            fd = self.endpoint.fileno()
            if fd is not None:
                ready, _, _ = select.select([fd], [], [], self.tick_s)
                if ready:
                    data = self.endpoint.read()
                    if data:
                        self.emulator.receive(data)
            else:
                time.sleep(self.tick_s)
            now = time.monotonic()
            self.emulator.poll()
            if now >= next_stall:
                stalled_until = now + f.stall_s
                next_stall = now + f.stall_every_s
                self.stats.stalls += 1
                log.info("emulator: stalling for %.2f s", f.stall_s)
            if now < stalled_until:
                last = now
                continue
            limit: int | None = None
            if rate is not None:
                # at most 50 ms of line time may accumulate (a UART FIFO, not a burst)
                budget = min(budget + (now - last) * rate, 0.05 * rate)
                limit = int(budget)
            last = now
            frames = self.emulator.take(limit)
            if not frames:
                continue
            data = self.injector.apply(frames)
            written = self.endpoint.write(data)
            self.stats.bytes_sent += written
            self.stats.overrun_bytes += len(data) - written
            if rate is not None:
                budget -= len(data)

    def _unplug(self, down_s: float) -> None:
        log.info("emulator: unplugging for %.2f s", down_s)
        self.stats.disconnects += 1
        self.endpoint.close()
        self.stop_event.wait(down_s)
        self.endpoint.open()
        self.emulator.reboot()
