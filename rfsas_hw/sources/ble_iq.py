"""Bluetooth direction-finding IQ reports: HCI event layouts, and the CTE's carrier offset.

Two LE Meta events (HCI event code ``0x3E``) carry the IQ samples a
controller took of a Constant Tone Extension (Core specification, Vol 4,
Part E, 7.7.65.21 and 7.7.65.22), little-endian:

- Connectionless IQ Report (subevent ``0x15``): subevent (1), Sync_Handle (2),
  Channel_Index (1), then the common part;
- Connection IQ Report (subevent ``0x16``): subevent (1), Connection_Handle
  (2), RX_PHY (1: LE 1M, 2: LE 2M), Data_Channel_Index (1), then the
  common part;
- common part: RSSI (int16, 0.1 dBm), RSSI_Antenna_ID (1), CTE_Type (1: 0
  AoA, 1 AoD 1 µs, 2 AoD 2 µs), Slot_Durations (1: 1 or 2 µs), Packet_Status
  (1: 0 CRC ok, 1 and 2 CRC bad, 0xFF no samples for want of resources),
  the periodic or connection event counter (2), Sample_Count (1: 0 or
  9…82) and that many ``(I, Q)`` pairs of int8.

Edge cases handled as the Zephyr controller produces them: an I or Q of
``0x80`` (−128) means "no valid sample" (Zephyr also writes it for a
saturated sample), so that sample is flagged and not used; a report with
``Packet_Status = 0xFF`` has ``Sample_Count = 0`` and may still carry one
``(0x80, 0x80)`` pair; 16-bit samples (a vendor event) are read with
``sample_bits=16``, where ``-32768`` is the sentinel.

The samples: the first 8 are the reference period, 1 µs apart, all from the
pattern's first antenna; then one sample per sample slot, ``2·slot`` µs
apart, from the antennas of the switching pattern in turn, starting with its
second entry. The transmitter's carrier-frequency offset (up to ±150 kHz)
turns the phase by ``2π·Δf·t`` between samples; :func:`remove_cfo`
measures it on the reference period and takes it out of every sample.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import CaptureFormatError

LE_META_EVENT = 0x3E
CONNECTIONLESS_IQ = 0x15
CONNECTION_IQ = 0x16
REFERENCE_SAMPLES = 8
"""IQ samples of the reference period (8 µs, one per µs)."""
MAX_SAMPLES = 82
"""Most samples one report may carry."""
NO_SAMPLES_STATUS = 0xFF
SENTINEL_8 = -128
SENTINEL_16 = -32768
MAX_CFO_HZ = 150_000.0
"""The Core specification's limit on a transmitter's carrier offset (±150 kHz)."""

Kind = Literal["connectionless", "connection"]


@dataclass(frozen=True, slots=True)
class IqReport:
    """One decoded IQ report."""

    kind: Kind
    """``connectionless`` (periodic advertising) or ``connection``."""
    handle: int
    """Sync handle or connection handle."""
    channel_index: int
    """BLE channel index 0–39 (data channel index for a connection)."""
    phy: int
    """Receiver PHY (1: LE 1M, 2: LE 2M; 1 for connectionless reports)."""
    rssi_dbm: float
    """RSSI, dBm (the report's 0.1 dBm units)."""
    rssi_antenna: int
    """Antenna the RSSI was measured on."""
    cte_type: int
    """0: AoA, 1: AoD with 1 µs slots, 2: AoD with 2 µs slots."""
    slot_us: int
    """Switch and sample slot length, µs (1 or 2)."""
    packet_status: int
    """0: CRC ok; 1, 2: CRC bad; 0xFF: no samples (controller out of resources)."""
    event_counter: int
    """Periodic or connection event counter."""
    iq: npt.NDArray[np.complex128]
    """The samples, I + jQ in the report's units; NaN where the sample is not valid."""

    @property
    def invalid(self) -> int:
        """Samples flagged not valid (sentinel: missing or saturated)."""
        return int(np.count_nonzero(~np.isfinite(self.iq)))


def parse_iq_event(event: bytes, where: str = "event", sample_bits: int = 8) -> IqReport | None:
    """Decode an HCI event packet (from its event code on); None if it is not an IQ report.

    Raises:
        CaptureFormatError: a truncated or inconsistent IQ report (``where`` and the
            field named).
    """
    if (
        len(event) < 3
        or event[0] != LE_META_EVENT
        or event[2]
        not in (
            CONNECTIONLESS_IQ,
            CONNECTION_IQ,
        )
    ):
        return None
    length = event[1]
    body = event[2:]
    if len(body) < length:
        raise CaptureFormatError(
            f"{where}: LE meta event says {length} parameter octets, {len(body)} present"
        )
    body = body[:length]
    kind: Kind = "connectionless" if body[0] == CONNECTIONLESS_IQ else "connection"
    head = 14 if kind == "connection" else 13
    if len(body) < head:
        raise CaptureFormatError(
            f"{where}: {kind} IQ report of {len(body)} octets, its fixed part needs {head}"
        )
    if kind == "connectionless":
        handle, channel, rssi, ant, cte, slot, status, counter, count = struct.unpack_from(
            "<HBhBBBBHB", body, 1
        )
        phy = 1
    else:
        handle, phy, channel, rssi, ant, cte, slot, status, counter, count = struct.unpack_from(
            "<HBBhBBBBHB", body, 1
        )
    width = 2 if sample_bits == 16 else 1
    payload = body[head:]
    if count > MAX_SAMPLES or (0 < count < REFERENCE_SAMPLES + 1):
        raise CaptureFormatError(f"{where}: Sample_Count {count}: 0 or 9…{MAX_SAMPLES} expected")
    if count == 0:
        if len(payload) not in (0, 2 * width):
            raise CaptureFormatError(
                f"{where}: a report without samples carries {len(payload)} sample octets"
            )
        samples = np.zeros(0, np.complex128)
    else:
        need = 2 * width * count
        if len(payload) != need:
            raise CaptureFormatError(
                f"{where}: Sample_Count {count} needs {need} sample octets, {len(payload)} present"
            )
        raw = np.frombuffer(payload, dtype="<i2" if width == 2 else np.int8).astype(np.float64)
        i, q = raw[0::2], raw[1::2]
        sentinel = SENTINEL_16 if width == 2 else SENTINEL_8
        bad = (i == sentinel) | (q == sentinel)
        samples = i + 1j * q
        samples[bad] = np.nan
    if slot not in (1, 2):
        raise CaptureFormatError(f"{where}: Slot_Durations {slot}: 1 or 2 (µs) expected")
    if cte > 2:
        raise CaptureFormatError(f"{where}: CTE_Type {cte}: 0, 1 or 2 expected")
    if channel > 39:
        raise CaptureFormatError(f"{where}: channel index {channel}: 0…39 expected")
    return IqReport(
        kind, handle, channel, phy, rssi / 10.0, ant, cte, slot, status, counter, samples
    )


def encode_iq_event(report: IqReport) -> bytes:
    """The HCI event packet (from its event code on) of ``report``, 8-bit samples;
    NaN samples are written as the sentinel.

    Raises:
        ValueError: a sample outside int8 or more than :data:`MAX_SAMPLES` samples.
    """
    iq = report.iq
    if len(iq) > MAX_SAMPLES:
        raise ValueError(f"{len(iq)} samples; a report holds at most {MAX_SAMPLES}")
    finite = np.isfinite(iq)
    i = np.where(finite, np.round(iq.real), SENTINEL_8)
    q = np.where(finite, np.round(iq.imag), SENTINEL_8)
    if np.any(np.abs(i[finite]) > 127) or np.any(np.abs(q[finite]) > 127):
        raise ValueError("IQ samples must fit int8 (−127…127; −128 is the sentinel)")
    samples = np.column_stack([i, q]).astype(np.int8).tobytes()
    rssi = round(report.rssi_dbm * 10)
    if report.kind == "connectionless":
        fixed = struct.pack(
            "<BHBhBBBBHB", CONNECTIONLESS_IQ, report.handle, report.channel_index, rssi,
            report.rssi_antenna, report.cte_type, report.slot_us, report.packet_status,
            report.event_counter, len(iq),
        )  # fmt: skip
    else:
        fixed = struct.pack(
            "<BHBBhBBBBHB", CONNECTION_IQ, report.handle, report.phy, report.channel_index, rssi,
            report.rssi_antenna, report.cte_type, report.slot_us, report.packet_status,
            report.event_counter, len(iq),
        )  # fmt: skip
    params = fixed + samples
    return bytes([LE_META_EVENT, len(params)]) + params


def ble_channel_mhz(index: int) -> float:
    """Centre frequency of BLE channel index 0–39, MHz (37, 38, 39: advertising).

    Raises:
        ValueError: an index outside 0–39.
    """
    if index == 37:
        return 2402.0
    if index == 38:
        return 2426.0
    if index == 39:
        return 2480.0
    if 0 <= index <= 10:
        return 2404.0 + 2.0 * index
    if 11 <= index <= 36:
        return 2428.0 + 2.0 * (index - 11)
    raise ValueError(f"BLE channel index {index}: 0…39 expected")


def sample_times_us(n_samples: int, slot_us: int) -> npt.NDArray[np.float64]:
    """When each sample was taken, µs from the first: the reference period's 8 at 1 µs,
    then one per sample slot every ``2·slot_us`` µs (the first ``slot_us`` after the
    reference period's end, past the first switch slot)."""
    k = np.arange(n_samples, dtype=np.float64)
    ref = k[:REFERENCE_SAMPLES]
    after = (
        REFERENCE_SAMPLES + slot_us + 2.0 * slot_us * (k[REFERENCE_SAMPLES:] - REFERENCE_SAMPLES)
    )
    return np.concatenate([ref, after])


def estimate_cfo_hz(iq: npt.NDArray[np.complexfloating[Any, Any]]) -> float:
    """Carrier offset measured on the reference period, Hz (NaN if it has fewer than 2
    valid neighbouring samples). Unambiguous within ±500 kHz at 1 µs spacing."""
    ref = np.asarray(iq[:REFERENCE_SAMPLES], np.complex128)
    prod = ref[1:] * np.conj(ref[:-1])
    prod = prod[np.isfinite(prod)]
    if not len(prod):
        return math.nan
    return float(np.angle(prod.sum()) / (2.0 * math.pi * 1e-6))


def remove_cfo(
    report: IqReport, pattern: Sequence[int] | None = None
) -> tuple[npt.NDArray[np.complex128], float]:
    """The report's samples with its carrier offset removed, and that offset, Hz (the
    samples unchanged and NaN when it cannot be measured).

    The reference period gives the offset to a few kHz (8 samples, ±500 kHz
    unambiguous); with the switching ``pattern``, the phase between two visits
    of the same antenna, ``2·slot·len(pattern)`` µs apart, refines it: over the
    tens of µs of the sample slots a few kHz left in would turn the phase by
    up to a radian between the first antenna and the last.
    """
    cfo = estimate_cfo_hz(report.iq)
    if not math.isfinite(cfo):
        return report.iq.copy(), cfo
    t = sample_times_us(len(report.iq), report.slot_us) * 1e-6
    out: npt.NDArray[np.complex128] = report.iq * np.exp(-2j * math.pi * cfo * t)
    size = 0 if pattern is None else len(pattern)
    slots = out[REFERENCE_SAMPLES:]
    if size and len(slots) > size:
        prod = slots[size:] * np.conj(slots[:-size])
        prod = prod[np.isfinite(prod)]
        if len(prod):
            lag_s = 2.0 * report.slot_us * size * 1e-6
            fine = float(np.angle(prod.sum()) / (2.0 * math.pi * lag_s))
            cfo += fine
            out = out * np.exp(-2j * math.pi * fine * t)
    return out, cfo


def element_snapshots(
    iq: npt.NDArray[np.complex128], pattern: Sequence[int], n_elements: int
) -> npt.NDArray[np.complex128]:
    """Sample-slot samples arranged as snapshots of the array, shape (rounds, N).

    Sample slot ``j`` used antenna ``pattern[(j + 1) % len(pattern)]`` (the
    pattern's first antenna served the reference period); each full pass
    through the pattern is one snapshot. Elements the pattern does not visit,
    and invalid samples, are NaN.

    Raises:
        ValueError: an antenna id outside ``0 … n_elements − 1`` or an empty pattern.
    """
    if not pattern or min(pattern) < 0 or max(pattern) >= n_elements:
        raise ValueError(f"switching pattern {list(pattern)} must name antennas 0…{n_elements - 1}")
    slots = iq[REFERENCE_SAMPLES:]
    size = len(pattern)
    rounds = len(slots) // size
    out = np.full((max(rounds, 0), n_elements), np.nan + 0j)
    for j in range(rounds * size):
        out[j // size, pattern[(j + 1) % size]] = slots[j]
    return out


def iter_h4_events(data: bytes, where: str = "stream") -> Iterator[tuple[int, bytes]]:
    """(byte offset, event packet) for every HCI event in an H4 (UART) byte stream;
    other packet types are skipped by their length fields.

    Raises:
        CaptureFormatError: an unknown packet indicator or a packet cut short (offset named).
    """
    pos = 0
    n = len(data)
    while pos < n:
        kind = data[pos]
        if kind == 0x04:  # event: code, length
            if pos + 3 > n:
                raise CaptureFormatError(f"{where}: byte {pos}: event header cut short")
            end = pos + 3 + data[pos + 2]
            if end > n:
                raise CaptureFormatError(
                    f"{where}: byte {pos}: event cut short ({n - pos} of {end - pos} octets)"
                )
            yield pos, data[pos + 1 : end]
        elif kind == 0x01:  # command: opcode(2), length(1)
            if pos + 4 > n:
                raise CaptureFormatError(f"{where}: byte {pos}: command header cut short")
            end = pos + 4 + data[pos + 3]
        elif kind in (0x02, 0x05):  # ACL or ISO data: handle(2), length(2)
            if pos + 5 > n:
                raise CaptureFormatError(f"{where}: byte {pos}: data header cut short")
            end = (
                pos
                + 5
                + int.from_bytes(data[pos + 3 : pos + 5], "little")
                % (1 << 14 if kind == 0x05 else 1 << 16)
            )
        elif kind == 0x03:  # SCO: handle(2), length(1)
            if pos + 4 > n:
                raise CaptureFormatError(f"{where}: byte {pos}: SCO header cut short")
            end = pos + 4 + data[pos + 3]
        else:
            raise CaptureFormatError(
                f"{where}: byte {pos}: 0x{kind:02x} is not an HCI packet indicator"
            )
        if end > n:
            raise CaptureFormatError(f"{where}: byte {pos}: packet cut short")
        pos = end


BTSNOOP_MAGIC = b"btsnoop\x00"
BTSNOOP_EPOCH_OFFSET_US = 0x00DCDDB30F2F8000
"""btsnoop timestamps count µs from year 0 AD; this many of them lie before 1970."""


def iter_btsnoop_events(data: bytes, where: str = "btsnoop") -> Iterator[tuple[int, int, bytes]]:
    """(record number, time in UTC ns, event packet) of every HCI event in a btsnoop
    file (``btmon -w``, Android's HCI log): datalink 1001 (HCI, the flags tell
    events) or 1002 (H4, a packet indicator first).

    Raises:
        CaptureFormatError: not a btsnoop file, an unknown datalink, a record cut short.
    """
    if len(data) < 16 or data[:8] != BTSNOOP_MAGIC:
        raise CaptureFormatError(f"{where}: not a btsnoop file (no 'btsnoop' magic)")
    version, datalink = struct.unpack_from(">II", data, 8)
    if version != 1 or datalink not in (1001, 1002):
        raise CaptureFormatError(
            f"{where}: btsnoop version {version}, datalink {datalink}: version 1 with "
            "datalink 1001 (HCI) or 1002 (H4) expected"
        )
    pos, record = 16, 0
    while pos < len(data):
        record += 1
        if pos + 24 > len(data):
            raise CaptureFormatError(f"{where}: record {record} at byte {pos}: header cut short")
        _orig, incl, flags, _drops, ts = struct.unpack_from(">IIIIq", data, pos)
        start, end = pos + 24, pos + 24 + incl
        if end > len(data):
            raise CaptureFormatError(f"{where}: record {record} at byte {pos}: data cut short")
        packet = data[start:end]
        t_ns = (ts - BTSNOOP_EPOCH_OFFSET_US) * 1000
        if datalink == 1002:
            if packet[:1] == b"\x04":
                yield record, t_ns, packet[1:]
        elif flags & 0x02 and flags & 0x01:  # command/event bit and received: an event
            yield record, t_ns, packet
        pos = end
