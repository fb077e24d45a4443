"""``bleiq+zephyr:PORT_OR_FILE?elements=N``: IQ reports from the console text of Zephyr's
direction-finding samples.

The samples' lines (:mod:`rfsas_hw.sources.ble_iq_zephyr`) come from the
board's UART (``/dev/ttyACM0``, or any pyserial URL such as
``socket://host:port``), or from a file they were saved to. From a port each
report is stamped with the time its header line arrived (UTC ns, this
host's clock); a file carries no times, so its reports have time 0.

Options: ``elements`` (required), ``pattern`` (the switching pattern as
given to ``bt_df_*_cte_rx_enable``, as antenna ids 0…N−1; default 0…N−1),
``channel`` (the BLE channel index to assume: the lines do not say which
channel a packet came on; without it the band centre, 2440 MHz, is used —
the wavelength is then off by at most 1.6 %), ``baud`` (default 115200).

Report keys: a connection report's peer address; a connectionless report's
advertiser address when the text holds the ``PER_ADV_SYNC[i]: … synced``
line of its sync index, else the sync index. Addresses are hashed by the
pipeline like every MAC.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rfsas_hw.errors import CaptureFormatError, SourceError
from rfsas_hw.records import ObservationBatch
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.ble_iq import ble_channel_mhz
from rfsas_hw.sources.ble_iq_source import IqReportSource, IqRow, parse_query
from rfsas_hw.sources.ble_iq_zephyr import ZephyrIqParser, ZephyrReport
from rfsas_hw.sources.serial_lines import PortLines

BAND_CENTRE_MHZ = 2440.0
"""Frequency assumed when the channel is not given, MHz."""
MAX_LINE = 400
"""Longest line accepted from a port, bytes (a header is about 130)."""


class BleIqZephyrSource(IqReportSource):
    """IQ reports printed by a Zephyr direction-finding sample, from a port or a file.

    Args:
        where: a file of the console text, or a serial port / pyserial URL.
        elements, pattern, errors, filter: see
            :class:`~rfsas_hw.sources.ble_iq_source.IqReportSource`.
        channel: BLE channel index to assume (None: the band centre).
        baudrate: line speed of a port.
        port_factory: opens a port (tests; default :func:`serial.serial_for_url`).
        clock: UTC ns, for the times of a port's reports.

    Raises:
        SourceError: a bad option, or a port that cannot be opened.
    """

    scheme = "bleiq+zephyr"

    def __init__(
        self,
        where: str,
        *,
        elements: int,
        pattern: list[int] | None = None,
        channel: int | None = None,
        baudrate: int = 115_200,
        port_factory: Any = None,
        clock: Callable[[], int] = time.time_ns,
        **base: Any,
    ) -> None:
        name = f"{self.scheme}:{where}"
        if channel is not None and not 0 <= channel <= 39:
            raise SourceError(f"{name}: channel {channel}: a BLE channel index 0…39 expected")
        super().__init__(name, elements=elements, pattern=pattern, **base)
        self.where = where
        self.freq_mhz = BAND_CENTRE_MHZ if channel is None else ble_channel_mhz(channel)
        self.clock = clock
        self._parser = ZephyrIqParser(where, 0 if channel is None else channel)
        self._line_no = 0
        self._file: Path | None = Path(where) if Path(where).is_file() else None
        self._port: PortLines | None = None
        if self._file is None:
            try:
                self._port = PortLines(where, baudrate, port_factory, "serial port", MAX_LINE)
            except SourceError:
                self.close()
                raise

    @classmethod
    def from_spec(cls, arg: str, **options: Any) -> Source[Any]:
        """``PORT_OR_FILE?elements=N&pattern=…&channel=17&baud=115200``; keywords win.

        Raises:
            SourceError: a missing, malformed or unknown option.
        """
        keys = {"elements": "elements", "pattern": "pattern", "channel": "channel"}
        where, options = parse_query(cls.scheme, arg, options, {**keys, "baud": "baudrate"})
        return cls(where, **options)

    def __repr__(self) -> str:
        return f"BleIqZephyrSource({self.where!r})"

    def _take(self, lines: list[bytes], t_ns: int, rows: list[IqRow]) -> None:
        """Parse ``lines``; completed reports go to ``rows``, errors to the policy."""
        for raw in lines:
            self._line_no += 1
            text = raw.decode("utf-8", "replace")
            self._handle(self._parser.feed(text, self._line_no), t_ns, rows)

    def _handle(
        self, items: list[ZephyrReport | CaptureFormatError], t_ns: int, rows: list[IqRow]
    ) -> None:
        for item in items:
            if isinstance(item, CaptureFormatError):
                self._bad("bad_report", item)
            else:
                where = f"{self.where}: line {item.line}"
                rows.append(IqRow(t_ns, item.key, self.freq_mhz, item.report, where))

    def _read_raw(self, timeout: float | None) -> ObservationBatch | None:
        rows: list[IqRow] = []
        if self._file is not None:
            self._end()
            try:
                data = self._file.read_bytes()
            except OSError as err:
                raise SourceError(f"{self.scheme}:{self.where}: cannot read: {err}") from err
            lines = data.split(b"\n")
            if lines and not lines[-1]:
                lines.pop()  # the end of the last line, not a line
            self._take(lines, 0, rows)
            self._handle(self._parser.finish(self._line_no), 0, rows)
        else:
            assert self._port is not None
            got = self._port.read()
            if got is None:
                if self._port.error is not None:
                    self.stats.errors.append(self._port.error)
                    self._end()
                    self._handle(self._parser.finish(self._line_no), self.clock(), rows)
                    return self._batch(rows) if rows else None
                return None
            lines, overflow = got
            self._take(lines, self.clock(), rows)
            if overflow:
                self._line_no += 1
                self._bad(
                    "bad_report",
                    CaptureFormatError(
                        f"{self.where}: line {self._line_no}: longer than {MAX_LINE} bytes"
                    ),
                )
        self.stats.extra["iq_reports"] = self.stats.extra.get("iq_reports", 0) + len(rows)
        self.stats.extra["other_lines"] = self._parser.other_lines
        return self._batch(rows)

    def _close(self) -> None:
        if self._port is not None:
            self._port.close()
