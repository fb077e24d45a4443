"""A bearing unit that prints text lines on a serial port or a pyserial URL.

:class:`SerialLineSource` opens the port, reads what has arrived, cuts it
into whole lines (a partial line waits for the rest; one that grows past
``max_line`` bytes without an end is handed back so the driver can count
it), treats a read error as the unit being gone, and closes the port. A
driver parses the lines and builds its batches.
"""

from __future__ import annotations

import logging
from typing import Any, ClassVar

import serial

from rfsas_hw.errors import SourceError
from rfsas_hw.records import BearingBatch
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.spec_options import SpecKeys, split_spec

log = logging.getLogger(__name__)


class PortLines:
    """Whole text lines from a serial port or pyserial URL.

    Args:
        url: the port (``/dev/ttyACM0``, ``socket://host:port``, ``loop://``).
        baudrate: line speed.
        port_factory: opens the port (default :func:`serial.serial_for_url`).
        what: what the unit is called when it cannot be opened.
        max_line: longest line accepted, bytes.
        device: what the unit is called in the log when its port goes away
            (default ``what``).

    Raises:
        SourceError: the port cannot be opened.
    """

    def __init__(
        self,
        url: str,
        baudrate: int,
        port_factory: Any,
        what: str,
        max_line: int,
        device: str | None = None,
    ) -> None:
        self.url = url
        self.device = device or what
        self.max_line = max_line
        self.error: str | None = None
        """Why the port stopped, once it has."""
        self._buf = b""
        factory = port_factory or serial.serial_for_url
        try:
            self._port = factory(url, baudrate=baudrate, timeout=0.05)
        except (serial.SerialException, OSError, ValueError) as err:
            raise SourceError(f"cannot open {what} {url!r}: {err}") from err

    def read(self) -> tuple[list[bytes], bytes] | None:
        """The whole lines that arrived, and an over-long unended rest (else ``b""``).

        Lines keep their ``\\r`` and blanks. None when nothing arrived, or when
        the port failed: then :attr:`error` says why.
        """
        try:
            data = self._port.read(max(1, self._port.in_waiting))
        except (serial.SerialException, OSError) as err:
            log.warning("%s at %s is gone (%s)", self.device, self.url, err)
            self.error = f"{self.url}: {err}"
            return None
        if not data:
            return None
        lines = (self._buf + data).split(b"\n")
        self._buf = lines.pop()
        overflow = b""
        if len(self._buf) > self.max_line:
            overflow, self._buf = self._buf, b""
        return lines, overflow

    def close(self) -> None:
        """Close the port (a failure to close is logged, not raised)."""
        try:
            self._port.close()
        except (serial.SerialException, OSError) as err:
            log.debug("closing %s: %s", self.url, err)


class SerialLineSource(Source[BearingBatch]):
    """Base of drivers that read ``\\n``-ended text lines from a serial port."""

    spec_keys: ClassVar[SpecKeys] = {}
    """``#key=value`` options of the spec (see :func:`split_spec`)."""
    device: ClassVar[str] = "serial unit"
    """What the unit is called in the log when its port goes away."""
    max_line: ClassVar[int] = 200
    """Longest line accepted, bytes."""

    url: str
    _lines: PortLines

    @classmethod
    def from_spec(cls, arg: str, **options: Any) -> Source[Any]:
        """``scheme:URL[#key=value&…]`` with the keys of :attr:`spec_keys`.

        Raises:
            ConfigError: an unknown key or a malformed value.
        """
        url, options = split_spec(cls.scheme, arg, cls.spec_keys, options)
        return cls(url, **options)  # type: ignore[call-arg, arg-type]

    def _open_port(self, url: str, baudrate: int, port_factory: Any, what: str) -> None:
        """Open ``url`` (through ``port_factory``, default :func:`serial.serial_for_url`).

        Raises:
            SourceError: the port cannot be opened (``what`` names the unit).
        """
        self.url = url
        self._lines = PortLines(url, baudrate, port_factory, what, self.max_line, self.device)

    def _read_lines(self) -> tuple[list[bytes], bytes] | None:
        """The whole lines that arrived, and an over-long unended rest (else ``b""``).

        Lines keep their ``\\r`` and blanks. None when nothing arrived, or
        when the port failed: then the error is kept in the stats and the
        input ends.
        """
        got = self._lines.read()
        if got is None and self._lines.error is not None:
            self.stats.errors.append(self._lines.error)
            self._end()
        return got

    def _close(self) -> None:
        self._lines.close()


__all__ = ["PortLines", "SerialLineSource"]
