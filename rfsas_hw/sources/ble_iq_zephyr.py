"""The IQ reports Zephyr's and nRF Connect SDK's direction-finding samples print on their UART.

The locator samples (``direction_finding_connectionless_rx``, periodic
advertising, and ``direction_finding_central``, a connection) print one
header line per IQ report from their CTE report callback, then, when built
with ``CONFIG_DF_LOCATOR_APP_IQ_REPORT_PRINT_IQ_SAMPLES=y`` (connectionless)
or ``CONFIG_DF_CENTRAL_APP_IQ_REPORT_PRINT_IQ_SAMPLES=y`` (connection), one
line per sample (the header is one line, shown here in two)::

    CTE[0]: samples type: 8 bits int, samples count 45, cte type AOA, slot durations: 2 [us], \
packet status CRC OK, RSSI -604
     IQ[0]: 12, -7
     IQ[1]: 11, -9
     ...

- ``CTE[…]`` holds the periodic-advertising sync index (connectionless) or
  the peer's address as ``bt_addr_le_to_str`` writes it,
  ``AA:BB:CC:DD:EE:FF (random)`` (connection);
- ``samples type`` (``8 bits int`` or ``16 bits int``, the latter a vendor
  event) is missing in the samples' first releases, which also lack the
  sample lines; those mean 8-bit samples;
- ``cte type`` is ``AOA``, ``AOD 1 [us]`` or ``AOD 2 [us]``; ``packet
  status`` is ``CRC OK``, ``CRC not OK, CTE Info OK``, ``CRC not OK, Sampled
  other way`` or ``No resources`` (the HCI report's 0, 1, 2 and 0xFF);
- ``RSSI`` is the report's integer in 0.1 dBm;
- each sample line is ``" IQ[k]: I, Q"``, ``k`` counting from 0.

The lines carry no channel index, event counter or time. Other lines the
samples print (scan results, ``PER_ADV_SYNC[i]: …`` periodic advertising
reports, connection messages, ``CTE[…]: request failed, err N``) are not
reports; ``PER_ADV_SYNC[i]: [DEVICE]: <address> synced, …`` tells which
advertiser sync index ``i`` follows, and the reports of that index are then
keyed by its address.

A report whose sample lines stop early (the console cut, a line lost), come
out of order, or hold a value outside the sample type is an error naming the
line; so is a header the sample never prints (a count of 1–8 or over 82, an
unknown CTE type). The values ``-128`` (8-bit) and ``-32768`` (16-bit) are
the controller's "no valid sample" sentinel and are flagged, not used.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rfsas_hw.errors import CaptureFormatError
from rfsas_hw.sources.ble_iq import (
    MAX_SAMPLES,
    NO_SAMPLES_STATUS,
    REFERENCE_SAMPLES,
    SENTINEL_8,
    SENTINEL_16,
    IqReport,
    Kind,
)

CTE_TYPES = {"AOA": 0, "AOD 1 [us]": 1, "AOD 2 [us]": 2}
PACKET_STATUSES = {
    "CRC OK": 0,
    "CRC not OK, CTE Info OK": 1,
    "CRC not OK, Sampled other way": 2,
    "No resources": NO_SAMPLES_STATUS,
}
SAMPLE_TYPES = {"8 bits int": 8, "16 bits int": 16}

_HEADER = re.compile(
    r"CTE\[(?P<who>[^\]]*)\]: (?:samples type: (?P<stype>[^,]*), )?samples count (?P<count>\d+), "
    r"cte type (?P<cte>[^,]*), slot durations: (?P<slot>\d+) \[us\], "
    r"packet status (?P<status>.*), RSSI (?P<rssi>-?\d+)"
)
_SAMPLE = re.compile(r"IQ\[(?P<k>\d+)\]: (?P<i>-?\d+), (?P<q>-?\d+)")
_SYNCED = re.compile(
    r"PER_ADV_SYNC\[(?P<index>\d+)\]: \[DEVICE\]: (?P<addr>(?:[0-9A-Fa-f]{2}:){5}[0-9A-Fa-f]{2})"
    r" \([^)]*\) synced"
)
_ADDRESS = re.compile(r"(?P<addr>(?:[0-9A-Fa-f]{2}:){5}[0-9A-Fa-f]{2})(?: \([^)]*\))?")
_NOT_A_REPORT = re.compile(r"CTE\[[^\]]*\]: request failed")


def address_key(text: str) -> int:
    """``AA:BB:CC:DD:EE:FF`` as the 48-bit integer ``0xAABBCCDDEEFF``.

    Raises:
        ValueError: not six colon-separated hex octets.
    """
    parts = text.split(":")
    if len(parts) != 6 or not all(len(p) == 2 for p in parts):
        raise ValueError(f"{text!r} is not a BLE address")
    return int("".join(parts), 16)


@dataclass(frozen=True, slots=True)
class ZephyrReport:
    """One IQ report read from the text."""

    key: int
    """The peer's or advertiser's address as an integer, else the sync index."""
    report: IqReport
    line: int
    """Line number of the report's header, from 1."""


@dataclass
class _Pending:
    line: int
    who: str
    kind: Kind
    handle: int
    count: int
    bits: int
    cte: int
    slot: int
    status: int
    rssi_ddbm: int
    i: list[int] = field(default_factory=list)
    q: list[int] = field(default_factory=list)


class ZephyrIqParser:
    """Reads the sample's lines one at a time and returns the reports they complete.

    Args:
        where: the input's name for messages (file or port).
        channel_index: the BLE channel index to put in the reports (the lines do
            not say which channel each packet came on); 0 when unknown.
    """

    def __init__(self, where: str, channel_index: int = 0) -> None:
        self.where = where
        self.channel_index = channel_index
        self.synced: dict[int, int] = {}
        """Sync index → advertiser address, from the ``synced`` lines."""
        self._pending: _Pending | None = None
        self._dropping = False
        """The sample lines of a report already refused follow; they are not errors too."""
        self.other_lines = 0
        """Lines that are neither report headers nor samples."""

    def feed(self, line: str, number: int) -> list[ZephyrReport | CaptureFormatError]:
        """The reports (and errors) line ``number`` (from 1) completes or causes.

        A header that cuts a report short yields that report's error and starts
        its own report, so a lost line costs one report, not the rest.
        """
        text = line.strip()
        out: list[ZephyrReport | CaptureFormatError] = []
        sample = _SAMPLE.fullmatch(text)
        if sample is not None:
            self._sample(sample, number, out)
            return out
        if text.startswith("CTE[") and not _NOT_A_REPORT.match(text):
            self._dropping = False
            self._cut(number, out)
            self._header(text, number, out)
            return out
        synced = _SYNCED.match(text)
        if synced is not None:
            self.synced[int(synced["index"])] = address_key(synced["addr"])
        self.other_lines += 1
        return out

    def finish(self, number: int) -> list[ZephyrReport | CaptureFormatError]:
        """The error of a report the input ended inside (``number``: the last line)."""
        out: list[ZephyrReport | CaptureFormatError] = []
        self._cut(number + 1, out, at_end=True)
        return out

    def _error(self, number: int, message: str) -> CaptureFormatError:
        return CaptureFormatError(f"{self.where}: line {number}: {message}")

    def _cut(
        self, number: int, out: list[ZephyrReport | CaptureFormatError], at_end: bool = False
    ) -> None:
        p = self._pending
        if p is None:
            return
        self._pending = None
        where = "the input ended" if at_end else f"line {number} starts the next report"
        if not p.i:
            out.append(
                self._error(
                    p.line,
                    f"the report announces {p.count} samples and none follow ({where}); "
                    "build the sample with CONFIG_DF_LOCATOR_APP_IQ_REPORT_PRINT_IQ_SAMPLES=y "
                    "(connectionless) or CONFIG_DF_CENTRAL_APP_IQ_REPORT_PRINT_IQ_SAMPLES=y "
                    "(connection) so that it prints them",
                )
            )
        else:
            out.append(
                self._error(
                    p.line, f"the report announces {p.count} samples, {len(p.i)} came ({where})"
                )
            )

    def _header(self, text: str, number: int, out: list[ZephyrReport | CaptureFormatError]) -> None:
        m = _HEADER.fullmatch(text)
        if m is None:
            self._dropping = True
            # the line is not echoed: it may hold a peer's address
            out.append(self._error(number, "a CTE line that is not a report header of the sample"))
            return
        who = m["who"]
        if who.isdigit():
            kind: Kind = "connectionless"
            handle = int(who)
        elif _ADDRESS.fullmatch(who):
            kind, handle = "connection", 0
        else:
            self._dropping = True
            out.append(self._error(number, "CTE[…]: a sync index or an address expected"))
            return
        problems = []
        bits = SAMPLE_TYPES.get(m["stype"] or "8 bits int")
        if bits is None:
            problems.append(f"samples type {m['stype']!r}: 8 bits int or 16 bits int expected")
        count = int(m["count"])
        if count > MAX_SAMPLES or 0 < count < REFERENCE_SAMPLES + 1:
            problems.append(f"samples count {count}: 0 or 9…{MAX_SAMPLES} expected")
        cte = CTE_TYPES.get(m["cte"])
        if cte is None:
            problems.append(f"cte type {m['cte']!r}: AOA, AOD 1 [us] or AOD 2 [us] expected")
        slot = int(m["slot"])
        if slot not in (1, 2):
            problems.append(f"slot durations {slot}: 1 or 2 expected")
        status = PACKET_STATUSES.get(m["status"])
        if status is None:
            problems.append(f"packet status {m['status']!r} unknown")
        rssi = int(m["rssi"])
        if not -1270 <= rssi <= 200:
            problems.append(f"RSSI {rssi} (0.1 dBm): -1270…200 expected")
        if problems or bits is None or cte is None or status is None:
            self._dropping = True
            out.append(self._error(number, "; ".join(problems)))
            return
        pending = _Pending(number, who, kind, handle, count, bits, cte, slot, status, rssi)
        if count == 0:
            out.append(self._complete(pending))
        else:
            self._pending = pending

    def _sample(
        self, m: re.Match[str], number: int, out: list[ZephyrReport | CaptureFormatError]
    ) -> None:
        p = self._pending
        if p is None:
            if not self._dropping:
                out.append(self._error(number, "an IQ sample line outside a report"))
            return
        k, i, q = int(m["k"]), int(m["i"]), int(m["q"])
        if k != len(p.i):
            self._pending, self._dropping = None, True
            out.append(
                self._error(
                    number, f"IQ[{k}] where IQ[{len(p.i)}] was due (report of line {p.line})"
                )
            )
            return
        top = (1 << (p.bits - 1)) - 1
        if not (-top - 1 <= i <= top and -top - 1 <= q <= top):
            self._pending, self._dropping = None, True
            out.append(self._error(number, f"IQ[{k}]: {i}, {q} outside {p.bits}-bit samples"))
            return
        p.i.append(i)
        p.q.append(q)
        if len(p.i) == p.count:
            self._pending = None
            out.append(self._complete(p))

    def _complete(self, p: _Pending) -> ZephyrReport:
        i = np.array(p.i, np.float64)
        q = np.array(p.q, np.float64)
        iq = i + 1j * q
        sentinel = SENTINEL_16 if p.bits == 16 else SENTINEL_8
        iq[(i == sentinel) | (q == sentinel)] = np.nan
        if p.kind == "connection":
            key = address_key(_ADDRESS.fullmatch(p.who)["addr"])  # type: ignore[index]
        else:
            key = self.synced.get(p.handle, p.handle)
        report = IqReport(
            p.kind, p.handle, self.channel_index, 1, p.rssi_ddbm / 10.0, 0, p.cte, p.slot,
            p.status, 0, iq,
        )  # fmt: skip
        return ZephyrReport(key, report, p.line)


def format_report(report: IqReport, who: str, sample_bits: int = 8) -> list[str]:
    """The lines the sample prints for ``report`` (without line ends); NaN samples
    are written as the sentinel. ``who`` is the sync index or the peer's address
    as the sample writes it.

    Raises:
        ValueError: a value the sample could not print (a sample outside the
            sample type, an unknown CTE type or packet status).
    """
    cte = {v: k for k, v in CTE_TYPES.items()}.get(report.cte_type)
    status = {v: k for k, v in PACKET_STATUSES.items()}.get(report.packet_status)
    if cte is None or status is None or sample_bits not in (8, 16):
        raise ValueError("CTE type 0–2, a known packet status and 8 or 16 bits expected")
    stype = {8: "8 bits int", 16: "16 bits int"}[sample_bits]
    rssi = round(report.rssi_dbm * 10)
    lines = [
        f"CTE[{who}]: samples type: {stype}, samples count {len(report.iq)}, cte type {cte}, "
        f"slot durations: {report.slot_us} [us], packet status {status}, RSSI {rssi}"
    ]
    sentinel = SENTINEL_16 if sample_bits == 16 else SENTINEL_8
    top = -sentinel - 1
    for k, v in enumerate(report.iq):
        i, q = (round(v.real), round(v.imag)) if np.isfinite(v) else (sentinel, sentinel)
        if np.isfinite(v) and (abs(i) > top or abs(q) > top):
            raise ValueError(f"sample {k} ({i}, {q}) outside {sample_bits}-bit samples")
        lines.append(f" IQ[{k}]: {i}, {q}")
    return lines


def format_stream(
    reports: Sequence[IqReport], who: Sequence[str], synced: dict[int, str] | None = None
) -> str:
    """A console text of the connectionless sample: its start-up lines, a
    ``synced`` line per advertiser of ``synced`` (sync index → address), then
    every report (``who[i]`` naming report ``i``'s sync index or peer), ``\\n``
    line ends."""
    lines = ["Starting Connectionless Locator Demo", "Bluetooth initialization...success"]
    for index, addr in (synced or {}).items():
        lines.append(
            f"PER_ADV_SYNC[{index}]: [DEVICE]: {addr} (random) synced, "
            "Interval 0x0050 (100 ms), PHY LE 2M"
        )
    for report, name in zip(reports, who, strict=True):
        lines += format_report(report, name)
    return "\n".join(lines) + "\n"
