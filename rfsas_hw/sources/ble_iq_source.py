"""``bleiq:FILE?elements=N[&pattern=…]``: observations from BLE direction-finding IQ reports,
and the step from decoded reports to observations that every BLE IQ source shares
(:class:`IqReportSource`; the Zephyr console and Silicon Labs MQTT readers use it too).

The file is a btsnoop capture (``btmon -w``, an Android HCI log) or a raw H4
(UART) byte stream of HCI packets. Every Connectionless or Connection IQ
Report becomes one observation:

- its samples with the carrier offset of the reference period removed
  (:func:`~rfsas_hw.sources.ble_iq.remove_cfo`), arranged by the antenna
  switching pattern into snapshots of the array — each full pass through
  the pattern one snapshot, carried as CSI of shape (antennas, passes, 1) so
  that the sensor pipeline's array fit uses every antenna; passes with an
  invalid (missing or saturated) sample are left out;
- its RSSI (for every antenna), channel index, and the centre frequency of
  that channel;
- as emitter key the report's sync or connection handle (IQ reports carry
  no address), hashed by the pipeline like a MAC.

Bad reports (truncated, inconsistent, no samples, a carrier offset beyond
±150 kHz, no complete pass) are counted and skipped, or raised under the
``raise`` policy.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

import numpy as np

from rfsas_hw.errors import CaptureFormatError, SourceError
from rfsas_hw.records import CsiBlock, ObservationBatch
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.ble_iq import (
    BTSNOOP_MAGIC,
    MAX_CFO_HZ,
    NO_SAMPLES_STATUS,
    IqReport,
    ble_channel_mhz,
    element_snapshots,
    iter_btsnoop_events,
    iter_h4_events,
    parse_iq_event,
    remove_cfo,
)


@dataclass(frozen=True, slots=True)
class IqRow:
    """One decoded IQ report with what the observation needs besides it."""

    t_ns: int
    """Capture time, UTC ns (0 when the input has none)."""
    key: int
    """Emitter key: the transmitter's address when the input gives it, else a handle."""
    freq_mhz: float
    """Carrier frequency the samples were taken on, MHz."""
    report: IqReport
    where: str
    """Where the report came from, for messages (file and line, byte, topic)."""


def parse_query(
    scheme: str, arg: str, options: dict[str, Any], keys: Mapping[str, str]
) -> tuple[str, dict[str, Any]]:
    """Split ``WHAT?key=value&…`` into ``WHAT`` and ``options`` with the query's keys
    filled in (``keys`` maps a query key to its argument name; ``pattern`` takes
    comma-separated whole numbers, every other key one whole number). Keywords the
    caller passed win.

    Raises:
        SourceError: an unknown key, a value that is not whole numbers, or no
            ``elements``.
    """
    what, _, query = arg.partition("?")
    for key, values in parse_qs(query, keep_blank_values=True).items():
        value = values[-1]
        if key not in keys:
            raise SourceError(f"{scheme}:{arg}: unknown option {key!r} ({', '.join(sorted(keys))})")
        try:
            parsed: Any = [int(v) for v in value.split(",")] if key == "pattern" else int(value)
        except ValueError as err:
            raise SourceError(
                f"{scheme}:{arg}: {key} must be whole numbers, got {value!r}"
            ) from err
        options.setdefault(keys[key], parsed)
    if "elements" not in options:
        raise SourceError(f"{scheme}:{arg}: give the array's antenna count: ?elements=N")
    return what, options


class IqReportSource(Source[ObservationBatch]):
    """Base of the BLE IQ report sources: from decoded reports to array observations.

    Every report becomes one observation: its samples with the carrier offset
    of the reference period removed (:func:`~rfsas_hw.sources.ble_iq.remove_cfo`),
    arranged by the antenna switching pattern into snapshots of the array (each
    full pass through the pattern one snapshot; passes with an invalid sample
    left out), carried as CSI of shape (antennas, passes, 1); its RSSI for every
    antenna; its channel and carrier frequency; its emitter key (hashed by the
    pipeline like a MAC). Unusable reports (no samples, a carrier offset beyond
    ±150 kHz, no complete pass) are counted and skipped, or raised under the
    ``raise`` policy.

    Args:
        name: what the messages call the input.
        elements: antennas of the array (2…64).
        pattern: antenna switching pattern (ids 0…elements−1); default 0, 1, …, N−1.
        errors, filter: see :class:`~rfsas_hw.sources.base.Source`.

    Raises:
        SourceError: a bad element count or pattern.
    """

    def __init__(
        self, name: str, *, elements: int, pattern: list[int] | None = None, **base: Any
    ) -> None:
        if not 2 <= elements <= 64:
            raise SourceError(f"{name}: elements {elements}: 2…64 expected")
        self.pattern = list(range(elements)) if pattern is None else list(pattern)
        if not self.pattern or min(self.pattern) < 0 or max(self.pattern) >= elements:
            raise SourceError(f"{name}: pattern {self.pattern} must name antennas 0…{elements - 1}")
        self.elements = elements
        super().__init__(**base)

    def _snapshots(self, report: IqReport, where: str) -> np.ndarray | None:
        """Snapshots (passes, N) of one report, or None (counted) when it is unusable."""
        if report.packet_status == NO_SAMPLES_STATUS or not len(report.iq):
            self._bad("no_samples", CaptureFormatError(f"{where}: the report carries no samples"))
            return None
        iq, cfo = remove_cfo(report, self.pattern)
        if not math.isfinite(cfo) or abs(cfo) > MAX_CFO_HZ * 1.1:
            self._bad(
                "bad_cfo",
                CaptureFormatError(
                    f"{where}: carrier offset {cfo:.0f} Hz not measurable within ±150 kHz"
                ),
            )
            return None
        snaps = element_snapshots(iq, self.pattern, self.elements)
        complete = snaps[np.all(np.isfinite(snaps), axis=1)]
        if not len(complete):
            self._bad(
                "no_complete_pass",
                CaptureFormatError(f"{where}: no pass through the pattern without a bad sample"),
            )
            return None
        return complete

    def _batch(self, rows: Sequence[IqRow]) -> ObservationBatch:
        """The observations of ``rows`` (the usable ones), every row with as many
        passes as the one with the fewest."""
        kept = [
            (row, s) for row in rows if (s := self._snapshots(row.report, row.where)) is not None
        ]
        if not kept:
            return ObservationBatch.empty(self.elements)
        passes = min(len(s) for _, s in kept)
        h = np.stack([s[:passes].T for _, s in kept])[:, :, :, None]  # (n, N, passes, 1)
        return ObservationBatch(
            t_ns=np.array([r.t_ns for r, _ in kept], np.int64),
            mac=np.array([r.key for r, _ in kept], np.uint64),
            freq_mhz=np.array([round(r.freq_mhz) for r, _ in kept], np.int32),
            channel=np.array([r.report.channel_index for r, _ in kept], np.int16),
            rssi_dbm=np.repeat(np.array([[r.report.rssi_dbm] for r, _ in kept]), self.elements, 1),
            csi=CsiBlock(h.astype(np.complex64), np.zeros(1, np.int16)),
        )


class BleIqSource(IqReportSource):
    """IQ reports of an antenna array's BLE receiver, from a btsnoop or H4 file.

    Args:
        path: btsnoop or raw H4 file.
        elements: antennas of the array.
        pattern: antenna switching pattern (ids 0…elements−1); default 0, 1, …, N−1.
        sample_bits: 8 (the Core specification) or 16 (a vendor event).
        errors, filter: see :class:`~rfsas_hw.sources.base.Source`.

    Raises:
        SourceError: no such file, or a bad option.
        CaptureFormatError: the file is not btsnoop or H4 (under either policy: the
            file cannot be read at all).
    """

    scheme = "bleiq"

    def __init__(
        self,
        path: str,
        *,
        elements: int,
        pattern: list[int] | None = None,
        sample_bits: int = 8,
        **base: Any,
    ) -> None:
        p = Path(path)
        if not p.is_file():
            raise SourceError(f"bleiq:{path}: no such file")
        if sample_bits not in (8, 16):
            raise SourceError(f"bleiq:{path}: sample_bits {sample_bits}: 8 or 16 expected")
        super().__init__(f"bleiq:{path}", elements=elements, pattern=pattern, **base)
        self.path = path
        self.sample_bits = sample_bits
        self._rows: list[tuple[int, IqReport]] = []
        self._done = False
        try:
            self._load(p.read_bytes())
        except BaseException:
            self.close()  # under the raise policy: nothing left open behind the error
            raise
        self.stats.extra["iq_reports"] = len(self._rows)

    def _load(self, data: bytes) -> None:
        """Decode every IQ report of the file; a file cut short keeps what came before."""
        path = self.path
        events: Iterator[tuple[str, int, bytes]]
        if data.startswith(BTSNOOP_MAGIC):
            events = ((f"record {r}", t, e) for r, t, e in iter_btsnoop_events(data, path))
        else:
            events = ((f"byte {o}", 0, e) for o, e in iter_h4_events(data, path))
        try:
            for where, t_ns, event in events:
                try:
                    report = parse_iq_event(event, f"{path}: {where}", self.sample_bits)
                except CaptureFormatError as err:
                    self._bad("bad_report", err)
                    continue
                if report is not None:
                    self._rows.append((t_ns, report))
        except CaptureFormatError as err:
            self._bad("truncated", err)

    @classmethod
    def from_spec(cls, arg: str, **options: Any) -> Source[Any]:
        """``FILE?elements=N&pattern=0,1,2,3&bits=8``; keywords win.

        Raises:
            SourceError: a missing or malformed option, or an unknown one.
        """
        keys = {"elements": "elements", "pattern": "pattern", "bits": "sample_bits"}
        path, options = parse_query(cls.scheme, arg, options, keys)
        return cls(path, **options)

    def __repr__(self) -> str:
        return f"BleIqSource({self.path!r})"

    def _read_raw(self, timeout: float | None) -> ObservationBatch | None:
        if self._done:
            self._end()
            return None
        self._done = True
        self._end()
        return self._batch(
            [
                IqRow(
                    t, r.handle, ble_channel_mhz(r.channel_index), r, f"{self.path}: report {i + 1}"
                )
                for i, (t, r) in enumerate(self._rows)
            ]
        )
