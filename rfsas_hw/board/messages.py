"""Typed messages of the DF-board protocol, version 1.

Each message class knows its type id, its version-1 field layout (which also
fixes its CRC seed byte), how to pack itself into a payload and how to unpack
one. Payloads are little-endian. Fields are only ever appended: a decoder
reads the version-1 prefix and ignores trailing bytes from a newer sender; a
payload shorter than the version-1 layout is an error. Messages that end in a
variable-length tail (batch, scan plan, error report) never get appended
fields; a new layout gets a new type id.

``firmware_protocol/SPEC.md`` is the normative description; the tables there
are generated from these classes and checked by the tests.
"""

from __future__ import annotations

import dataclasses
import enum
import struct
from dataclasses import dataclass, field
from typing import ClassVar, Self

from rfsas_hw.board.framing import MAX_PAYLOAD, layout_crc_extra
from rfsas_hw.errors import BoardProtocolError

RSSI_SLOTS = 4
"""RSSI values carried per measurement (antennas beyond the board's count are "no value")."""
RSSI_NONE = -128
"""Wire value of an RSSI slot that carries no value."""
FRAME_SEQ_NONE = 0xFFFF
"""Wire value of ``frame_seq`` when the frame had no 802.11 sequence number."""
MAX_SCAN_CHANNELS = 64
"""Most entries a scan plan may list."""
MAX_ERROR_TEXT = 64
"""Longest error-report text, bytes of UTF-8."""


class PayloadError(BoardProtocolError):
    """A frame passed its CRC but its payload does not fit the message layout."""


class Capability(enum.IntFlag):
    """Bits of :attr:`Info.capabilities`."""

    NONE = 0
    WIFI_2G4 = 0x01
    WIFI_5G = 0x02
    BLE = 0x04
    BATCH = 0x08
    """The board sends :class:`MeasurementBatch` frames."""
    TIME_SYNC = 0x10
    """The board answers :class:`TimeSyncRequest`."""
    SCAN_PLAN = 0x20
    """The board accepts :class:`SetScanPlan`."""
    FRAME_SEQ = 0x40
    """Measurements carry the 802.11 sequence number."""


class MeasFlag(enum.IntFlag):
    """Bits of :attr:`Measurement.flags` (the low two equal ``ObsFlag`` bits)."""

    NONE = 0
    RETRY = 0x01
    """The 802.11 retry bit was set."""
    BAD_FCS = 0x02
    """The receiver reported a failed FCS; the MAC may be corrupt."""
    SATURATED = 0x04
    """At least one receiver was saturated; its RSSI is a lower bound."""


class CompatFlag(enum.IntFlag):
    """Bits of the header's compatible-flag byte (a receiver may ignore any of them)."""

    NONE = 0
    OVERFLOW = 0x01
    """The board dropped measurements before this frame (queue full)."""
    RESTART = 0x02
    """First frame after the sender (re)started: its sequence counter begins anew."""


class NakCode(enum.IntEnum):
    """Why the board refused a command (:attr:`Nak.error`)."""

    UNKNOWN_TYPE = 1
    BAD_PAYLOAD = 2
    BAD_VALUE = 3
    UNSUPPORTED = 4
    BUSY = 5
    INTERNAL = 6


class ErrorCode(enum.IntEnum):
    """What an unsolicited :class:`ErrorReport` is about."""

    QUEUE_OVERFLOW = 1
    RADIO_FAULT = 2
    CLOCK_FAULT = 3
    RX_FRAMING = 4
    RESET = 5
    OTHER = 0xFFFF


class BoardState(enum.IntEnum):
    """:attr:`Heartbeat.state`."""

    IDLE = 0
    STREAMING = 1


class Message:
    """Base of every protocol message."""

    __slots__ = ()
    TYPE: ClassVar[int]
    LAYOUT: ClassVar[str]
    """Canonical version-1 layout; its CRC fixes :attr:`CRC_EXTRA`."""
    CRC_EXTRA: ClassVar[int]
    FROM_BOARD: ClassVar[bool]
    """True for board → host messages, False for host → board commands."""

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        if "LAYOUT" in cls.__dict__:
            cls.CRC_EXTRA = layout_crc_extra(cls.LAYOUT)

    def pack(self) -> bytes:
        """The payload bytes."""
        raise NotImplementedError

    @classmethod
    def unpack(cls, payload: bytes) -> Self:
        """Decode a payload (trailing bytes from newer senders are ignored).

        Raises:
            PayloadError: the payload is shorter than the layout or a value is invalid.
        """
        raise NotImplementedError


def _short(cls: type[Message], payload: bytes, need: int) -> PayloadError:
    return PayloadError(f"{cls.__name__} payload of {len(payload)} bytes, version 1 needs {need}")


def _pack_error(cls: type[Message], err: Exception) -> PayloadError:
    return PayloadError(f"{cls.__name__}: field out of range: {err}")


_LAYOUT_CODES = {"u8": "B", "u16": "H", "u32": "I", "u64": "Q", "i8": "b", "i16": "h"}


def layout_struct(layout: str) -> struct.Struct:
    """The little-endian ``struct`` of a fixed layout, e.g. ``"ACK u16 acked_seq, u8 acked_type"``.

    Raises:
        ValueError: a field that is not a fixed-size integer (arrays, nested records).
    """
    _, _, fields_text = layout.partition(" ")
    codes = []
    for item in filter(None, (f.strip() for f in fields_text.split(","))):
        kind = item.split()[0]
        if kind not in _LAYOUT_CODES:
            raise ValueError(f"{layout!r}: {kind!r} is not a fixed-size integer field")
        codes.append(_LAYOUT_CODES[kind])
    return struct.Struct("<" + "".join(codes))


class FixedMessage(Message):
    """A message whose payload is its dataclass fields, in order, laid out as ``LAYOUT`` says."""

    __slots__ = ()
    _S: ClassVar[struct.Struct]

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        if "LAYOUT" in cls.__dict__:
            cls._S = layout_struct(cls.LAYOUT)

    def pack(self) -> bytes:
        values = (getattr(self, f.name) for f in dataclasses.fields(self))  # type: ignore[arg-type]
        try:
            return self._S.pack(*values)
        except struct.error as err:
            raise _pack_error(type(self), err) from err

    @classmethod
    def unpack(cls, payload: bytes) -> Self:
        if len(payload) < cls._S.size:
            raise _short(cls, payload, cls._S.size)
        return cls(*cls._S.unpack_from(payload))


@dataclass(slots=True)
class Hello(FixedMessage):
    """Host → board: ask for :class:`Info`; also resets nothing on the board."""

    TYPE: ClassVar[int] = 0x01
    LAYOUT: ClassVar[str] = "HELLO u8 protocol_version"
    FROM_BOARD: ClassVar[bool] = False

    protocol_version: int = 1
    """Protocol version the host speaks."""


@dataclass(slots=True)
class Info(FixedMessage):
    """Board → host: who the board is (answer to :class:`Hello`, also sent at boot)."""

    TYPE: ClassVar[int] = 0x02
    LAYOUT: ClassVar[str] = (
        "INFO u8 protocol_version, u8 fw_major, u8 fw_minor, u8 fw_patch, "
        "u8 n_antennas, u32 capabilities, u64 board_id"
    )
    FROM_BOARD: ClassVar[bool] = True

    protocol_version: int
    """Protocol version the board speaks (1)."""
    fw_major: int
    """Firmware version, major."""
    fw_minor: int
    """Firmware version, minor."""
    fw_patch: int
    """Firmware version, patch."""
    n_antennas: int
    """Antennas (RSSI values per measurement) the board reports, 1–4."""
    capabilities: int
    """:class:`Capability` bits."""
    board_id: int
    """Unique id of the board (e.g. the MCU's serial number), 64 bits."""

    @property
    def firmware(self) -> str:
        """Firmware version as ``major.minor.patch``."""
        return f"{self.fw_major}.{self.fw_minor}.{self.fw_patch}"


MEASUREMENT = struct.Struct("<Q6sHBBBH4b")
"""Version-1 layout of one measurement record (25 bytes)."""


@dataclass(slots=True)
class Measurement(Message):
    """Board → host: one frame heard, with the signal on each antenna."""

    TYPE: ClassVar[int] = 0x10
    LAYOUT: ClassVar[str] = (
        "MEASUREMENT u64 t_us, u8[6] mac, u16 freq_mhz, u8 channel, u8 kind, "
        "u8 flags, u16 frame_seq, i8[4] rssi_dbm"
    )
    FROM_BOARD: ClassVar[bool] = True

    t_us: int
    """Board time at reception, microseconds since the board's clock started."""
    mac: int
    """Transmitter address as a 48-bit integer (first octet on air = most significant)."""
    freq_mhz: int
    """Centre frequency of the channel, MHz (0 if unknown)."""
    channel: int
    """IEEE channel number (0 if unknown)."""
    kind: int
    """Frame kind, ``rfsas_hw.records.FrameKind`` values."""
    flags: int
    """:class:`MeasFlag` bits."""
    frame_seq: int | None
    """802.11 sequence number 0–4095, or None."""
    rssi_dbm: tuple[int | None, ...]
    """Signal per antenna slot, whole dBm, antenna 0 first; None where no value (4 slots)."""

    def pack(self) -> bytes:
        return pack_measurement(self)

    @classmethod
    def unpack(cls, payload: bytes) -> Self:
        if len(payload) < MEASUREMENT.size:
            raise _short(cls, payload, MEASUREMENT.size)
        t_us, mac, freq, ch, kind, flags, fseq, r0, r1, r2, r3 = MEASUREMENT.unpack_from(payload)
        return cls(
            t_us,
            int.from_bytes(mac, "big"),
            freq,
            ch,
            kind,
            flags,
            None if fseq == FRAME_SEQ_NONE else fseq,
            (
                None if r0 == RSSI_NONE else r0,
                None if r1 == RSSI_NONE else r1,
                None if r2 == RSSI_NONE else r2,
                None if r3 == RSSI_NONE else r3,
            ),
        )


def pack_measurement(m: Measurement) -> bytes:
    """The 25-byte version-1 record of one measurement.

    Raises:
        PayloadError: a field is out of range (RSSI outside -127..127, more
            than four RSSI values, frame_seq above 4095, MAC above 48 bits).
    """
    rssi = list(m.rssi_dbm)
    if len(rssi) > RSSI_SLOTS:
        raise PayloadError(f"{len(rssi)} RSSI values, at most {RSSI_SLOTS}")
    rssi += [None] * (RSSI_SLOTS - len(rssi))
    wire = []
    for v in rssi:
        if v is None:
            wire.append(RSSI_NONE)
        elif -127 <= v <= 127:
            wire.append(int(v))
        else:
            raise PayloadError(f"RSSI {v} dBm outside -127..127")
    if m.frame_seq is not None and not 0 <= m.frame_seq <= 4095:
        raise PayloadError(f"frame_seq {m.frame_seq} outside 0..4095")
    if not 0 <= m.mac < (1 << 48):
        raise PayloadError(f"MAC {m.mac:#x} is not a 48-bit value")
    try:
        return MEASUREMENT.pack(
            m.t_us,
            m.mac.to_bytes(6, "big"),
            m.freq_mhz,
            m.channel,
            m.kind,
            m.flags,
            FRAME_SEQ_NONE if m.frame_seq is None else m.frame_seq,
            *wire,
        )
    except struct.error as err:
        raise _pack_error(Measurement, err) from err


@dataclass(slots=True)
class MeasurementBatch(Message):
    """Board → host: several measurements in one frame.

    Payload: ``count u8, record_size u8`` then ``count`` records of
    ``record_size`` bytes, each starting with the :class:`Measurement` layout.
    ``record_size`` lets records grow in later versions.
    """

    TYPE: ClassVar[int] = 0x11
    LAYOUT: ClassVar[str] = "MEASUREMENT_BATCH u8 count, u8 record_size, MEASUREMENT[count]"
    FROM_BOARD: ClassVar[bool] = True
    _S: ClassVar[struct.Struct] = struct.Struct("<BB")
    MAX_COUNT: ClassVar[int] = (MAX_PAYLOAD - 2) // MEASUREMENT.size

    measurements: tuple[Measurement, ...] = field(default_factory=tuple)
    """The records, in the order the board heard them."""

    def pack(self) -> bytes:
        if len(self.measurements) > self.MAX_COUNT:
            raise PayloadError(f"batch of {len(self.measurements)} exceeds {self.MAX_COUNT}")
        head = self._S.pack(len(self.measurements), MEASUREMENT.size)
        return head + b"".join(pack_measurement(m) for m in self.measurements)

    @classmethod
    def unpack(cls, payload: bytes) -> Self:
        count, size = batch_header(payload)
        return cls(
            tuple(
                Measurement.unpack(payload[2 + i * size : 2 + (i + 1) * size]) for i in range(count)
            )
        )


def batch_header(payload: bytes) -> tuple[int, int]:
    """``(count, record_size)`` of a batch payload, checked against its length.

    Raises:
        PayloadError: the payload is too short for its count, or records are
            smaller than the version-1 measurement.
    """
    if len(payload) < 2:
        raise _short(MeasurementBatch, payload, 2)
    count, size = payload[0], payload[1]
    if size < MEASUREMENT.size:
        raise PayloadError(f"batch record_size {size} < {MEASUREMENT.size}")
    if len(payload) < 2 + count * size:
        raise PayloadError(
            f"batch of {count} records of {size} bytes needs {2 + count * size}, got {len(payload)}"
        )
    return count, size


@dataclass(slots=True)
class SetChannel(FixedMessage):
    """Host → board: listen on one channel (ends any scan plan)."""

    TYPE: ClassVar[int] = 0x20
    LAYOUT: ClassVar[str] = "SET_CHANNEL u16 freq_mhz"
    FROM_BOARD: ClassVar[bool] = False

    freq_mhz: int
    """Centre frequency, MHz."""


@dataclass(slots=True)
class SetScanPlan(Message):
    """Host → board: hop over channels, ``dwell_ms`` on each, in order, repeating."""

    TYPE: ClassVar[int] = 0x21
    LAYOUT: ClassVar[str] = "SET_SCAN_PLAN u16 dwell_ms, u8 count, u16[count] freq_mhz"
    FROM_BOARD: ClassVar[bool] = False
    _S: ClassVar[struct.Struct] = struct.Struct("<HB")

    dwell_ms: int
    """Time on each channel, milliseconds (1–65535)."""
    freqs_mhz: tuple[int, ...]
    """Centre frequencies to visit, MHz, at most :data:`MAX_SCAN_CHANNELS`."""

    def pack(self) -> bytes:
        if len(self.freqs_mhz) > MAX_SCAN_CHANNELS:
            raise PayloadError(f"scan plan of {len(self.freqs_mhz)} > {MAX_SCAN_CHANNELS}")
        try:
            return self._S.pack(self.dwell_ms, len(self.freqs_mhz)) + struct.pack(
                f"<{len(self.freqs_mhz)}H", *self.freqs_mhz
            )
        except struct.error as err:
            raise _pack_error(type(self), err) from err

    @classmethod
    def unpack(cls, payload: bytes) -> Self:
        if len(payload) < cls._S.size:
            raise _short(cls, payload, cls._S.size)
        dwell, count = cls._S.unpack_from(payload)
        if count > MAX_SCAN_CHANNELS:
            raise PayloadError(f"scan plan count {count} > {MAX_SCAN_CHANNELS}")
        need = cls._S.size + 2 * count
        if len(payload) < need:
            raise _short(cls, payload, need)
        return cls(dwell, struct.unpack_from(f"<{count}H", payload, cls._S.size))


@dataclass(slots=True)
class Start(FixedMessage):
    """Host → board: start streaming measurements."""

    TYPE: ClassVar[int] = 0x22
    LAYOUT: ClassVar[str] = "START"
    FROM_BOARD: ClassVar[bool] = False


@dataclass(slots=True)
class Stop(FixedMessage):
    """Host → board: stop streaming measurements."""

    TYPE: ClassVar[int] = 0x23
    LAYOUT: ClassVar[str] = "STOP"
    FROM_BOARD: ClassVar[bool] = False


@dataclass(slots=True)
class Heartbeat(FixedMessage):
    """Board → host, about once a second: counters and state."""

    TYPE: ClassVar[int] = 0x30
    LAYOUT: ClassVar[str] = (
        "HEARTBEAT u64 uptime_us, u32 frames_heard, u32 frames_dropped, "
        "u16 queue_depth, u16 queue_capacity, u8 state, u16 freq_mhz"
    )
    FROM_BOARD: ClassVar[bool] = True

    uptime_us: int
    """Board time now, microseconds (same clock as :attr:`Measurement.t_us`)."""
    frames_heard: int
    """Frames the radio heard since boot (wrapping at 2³²)."""
    frames_dropped: int
    """Measurements dropped on the board since boot (queue full), wrapping at 2³²."""
    queue_depth: int
    """Measurements waiting in the board's transmit queue."""
    queue_capacity: int
    """Size of that queue."""
    state: int
    """:class:`BoardState`."""
    freq_mhz: int
    """Frequency the radio is on now, MHz."""


@dataclass(slots=True)
class Ack(FixedMessage):
    """Board → host: a command was accepted."""

    TYPE: ClassVar[int] = 0x40
    LAYOUT: ClassVar[str] = "ACK u16 acked_seq, u8 acked_type"
    FROM_BOARD: ClassVar[bool] = True

    acked_seq: int
    """Sequence number of the command's frame."""
    acked_type: int
    """Message type of the command."""


@dataclass(slots=True)
class Nak(FixedMessage):
    """Board → host: a command was refused."""

    TYPE: ClassVar[int] = 0x41
    LAYOUT: ClassVar[str] = "NAK u16 acked_seq, u8 acked_type, u8 error, u16 detail"
    FROM_BOARD: ClassVar[bool] = True

    acked_seq: int
    """Sequence number of the command's frame."""
    acked_type: int
    """Message type of the command."""
    error: int
    """:class:`NakCode`."""
    detail: int = 0
    """Code-specific detail (e.g. the offending frequency, MHz)."""


@dataclass(slots=True)
class ErrorReport(Message):
    """Board → host, unsolicited: something went wrong on the board."""

    TYPE: ClassVar[int] = 0x42
    LAYOUT: ClassVar[str] = "ERROR_REPORT u16 code, u32 detail, u8[] text"
    FROM_BOARD: ClassVar[bool] = True
    _S: ClassVar[struct.Struct] = struct.Struct("<HI")

    code: int
    """:class:`ErrorCode`."""
    detail: int = 0
    """Code-specific detail."""
    text: str = ""
    """Human-readable text, UTF-8, at most :data:`MAX_ERROR_TEXT` bytes."""

    def pack(self) -> bytes:
        text = self.text.encode("utf-8")
        if len(text) > MAX_ERROR_TEXT:
            raise PayloadError(f"error text of {len(text)} bytes > {MAX_ERROR_TEXT}")
        try:
            return self._S.pack(self.code, self.detail) + text
        except struct.error as err:
            raise _pack_error(type(self), err) from err

    @classmethod
    def unpack(cls, payload: bytes) -> Self:
        if len(payload) < cls._S.size:
            raise _short(cls, payload, cls._S.size)
        code, detail = cls._S.unpack_from(payload)
        text = bytes(payload[cls._S.size : cls._S.size + MAX_ERROR_TEXT])
        return cls(code, detail, text.decode("utf-8", errors="replace"))


@dataclass(slots=True)
class TimeSyncRequest(FixedMessage):
    """Host → board: ask for the board clock; ``host_time_ns`` is echoed back."""

    TYPE: ClassVar[int] = 0x50
    LAYOUT: ClassVar[str] = "TIME_SYNC_REQUEST u64 host_time_ns"
    FROM_BOARD: ClassVar[bool] = False

    host_time_ns: int
    """Host clock when the request was sent, ns (opaque to the board)."""


@dataclass(slots=True)
class TimeSync(FixedMessage):
    """Board → host: answer to :class:`TimeSyncRequest`."""

    TYPE: ClassVar[int] = 0x51
    LAYOUT: ClassVar[str] = "TIME_SYNC u64 host_time_ns, u64 board_rx_us, u64 board_tx_us"
    FROM_BOARD: ClassVar[bool] = True

    host_time_ns: int
    """The request's ``host_time_ns``, echoed."""
    board_rx_us: int
    """Board time when the request arrived, µs."""
    board_tx_us: int
    """Board time when this answer was queued, µs."""


MESSAGE_TYPES: tuple[type[Message], ...] = (
    Hello,
    Info,
    Measurement,
    MeasurementBatch,
    SetChannel,
    SetScanPlan,
    Start,
    Stop,
    Heartbeat,
    Ack,
    Nak,
    ErrorReport,
    TimeSyncRequest,
    TimeSync,
)
"""Every version-1 message class, in type-id order."""
BY_TYPE: dict[int, type[Message]] = {cls.TYPE: cls for cls in MESSAGE_TYPES}
"""Message class by type id."""
