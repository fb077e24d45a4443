"""The 802.11 MAC header fields direction finding needs, one frame or many at once.

Frame control (type, subtype, retry), the transmitter address (addr2) and the
sequence control field. Frames without a transmitter address (ACK, CTS) cannot
be attributed to an emitter; :func:`has_transmitter` says which those are.

All multi-byte header fields are little-endian except the addresses, which are
read as written on air (first octet most significant), matching
:func:`rfsas_hw.records.mac_to_int`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import CaptureFormatError
from rfsas_hw.records import FrameKind

TYPE_MGMT = 0
TYPE_CTRL = 1
TYPE_DATA = 2
TYPE_EXT = 3

SUBTYPE_PROBE_REQ = 4
SUBTYPE_PROBE_RESP = 5
SUBTYPE_BEACON = 8

FC_RETRY = 0x0800
FCS_LEN = 4

MGMT_DATA_HEADER_LEN = 24
"""Bytes up to and including the sequence control field of management and data frames."""
CTRL_TA_HEADER_LEN = 16
"""Bytes up to the end of addr2 in control frames that carry a transmitter address."""
MIN_FRAME_LEN = 10
"""Frame control, duration and addr1: the shortest 802.11 frame (ACK, CTS)."""

# Control subtypes that carry a transmitter address in addr2: trigger (2),
# beamforming report poll (4), VHT/HE NDP announcement (5), block ack request
# (8), block ack (9), PS-Poll (10), RTS (11), CF-End (14), CF-End+CF-Ack (15).
CTRL_WITH_TA = frozenset({2, 4, 5, 8, 9, 10, 11, 14, 15})
_CTRL_TA_MASK = sum(1 << s for s in CTRL_WITH_TA)

_HDR = struct.Struct("<HH6s6s")
_SEQ = struct.Struct("<H")


@dataclass(frozen=True, slots=True)
class Dot11Header:
    """The fields of one 802.11 MAC header that DF uses."""

    type: int
    """Frame type: 0 management, 1 control, 2 data, 3 extension."""
    subtype: int
    """Frame subtype (0–15)."""
    retry: bool
    """Retry bit: a retransmission of an earlier frame."""
    transmitter: int | None
    """Transmitter address (addr2) as a 48-bit int, or None for ACK/CTS."""
    seq: int | None
    """Sequence number (0–4095), or None for control frames."""
    frag: int | None
    """Fragment number (0–15), or None for control frames."""

    @property
    def type_subtype(self) -> int:
        """``type << 4 | subtype``, as tshark's ``wlan.fc.type_subtype``."""
        return self.type << 4 | self.subtype

    @property
    def kind(self) -> FrameKind:
        """The frame kind used in observations."""
        return FrameKind(int(kind_of(np.array([self.type]), np.array([self.subtype]))[0]))


def has_transmitter(ftype: int, subtype: int) -> bool:
    """True when a frame of this type/subtype carries a transmitter address."""
    return ftype in (TYPE_MGMT, TYPE_DATA) or (ftype == TYPE_CTRL and subtype in CTRL_WITH_TA)


def required_length(ftype: int, subtype: int) -> int:
    """Bytes of header needed to read the fields DF uses for this type/subtype."""
    if ftype in (TYPE_MGMT, TYPE_DATA):
        return MGMT_DATA_HEADER_LEN
    if ftype == TYPE_CTRL and subtype in CTRL_WITH_TA:
        return CTRL_TA_HEADER_LEN
    return MIN_FRAME_LEN


def parse_header(buf: bytes | memoryview, start: int = 0, length: int | None = None) -> Dot11Header:
    """Parse the 802.11 header at ``buf[start:]`` (``length`` bytes of frame, FCS excluded).

    Raises:
        CaptureFormatError: the frame is shorter than the fields its type
            needs, or its protocol version is not 0.
    """
    if length is None:
        length = len(buf) - start
    if length < 2:
        raise CaptureFormatError(f"802.11: frame has {length} bytes, no frame control field")
    fc = buf[start] | buf[start + 1] << 8
    version = fc & 3
    if version != 0:
        raise CaptureFormatError(f"802.11: protocol version {version} is not supported")
    ftype = (fc >> 2) & 3
    subtype = (fc >> 4) & 0xF
    need = required_length(ftype, subtype)
    if length < need:
        raise CaptureFormatError(
            f"802.11: type {ftype} subtype {subtype} needs a {need}-byte header, frame has {length}"
        )
    ta: int | None = None
    if has_transmitter(ftype, subtype):
        ta = int.from_bytes(bytes(buf[start + 10 : start + 16]), "big")
    seq = frag = None
    if ftype in (TYPE_MGMT, TYPE_DATA):
        sc = _SEQ.unpack_from(buf, start + 22)[0]
        seq, frag = sc >> 4, sc & 0xF
    return Dot11Header(ftype, subtype, bool(fc & FC_RETRY), ta, seq, frag)


def _kind_table() -> npt.NDArray[np.uint8]:
    table = np.full(64, FrameKind.UNKNOWN, np.uint8)
    for subtype in range(16):
        table[TYPE_MGMT << 4 | subtype] = FrameKind.OTHER_MGMT
        table[TYPE_CTRL << 4 | subtype] = FrameKind.CONTROL
        table[TYPE_DATA << 4 | subtype] = FrameKind.QOS_DATA if subtype & 8 else FrameKind.DATA
    table[TYPE_MGMT << 4 | SUBTYPE_BEACON] = FrameKind.BEACON
    table[TYPE_MGMT << 4 | SUBTYPE_PROBE_REQ] = FrameKind.PROBE_REQUEST
    table[TYPE_MGMT << 4 | SUBTYPE_PROBE_RESP] = FrameKind.PROBE_RESPONSE
    return table


_KIND = _kind_table()


def kind_of(
    ftype: npt.NDArray[np.integer], subtype: npt.NDArray[np.integer]
) -> npt.NDArray[np.uint8]:
    """:class:`FrameKind` codes for arrays of frame types and subtypes."""
    index = ((np.asarray(ftype, np.int64) & 3) << 4) | (np.asarray(subtype, np.int64) & 0xF)
    out: npt.NDArray[np.uint8] = _KIND[index]
    return out


def required_length_batch(
    ftype: npt.NDArray[np.integer], subtype: npt.NDArray[np.integer]
) -> npt.NDArray[np.int64]:
    """Vectorised :func:`required_length`."""
    ftype = np.asarray(ftype)
    ctrl_ta = (ftype == TYPE_CTRL) & (((_CTRL_TA_MASK >> np.asarray(subtype, np.int64)) & 1) == 1)
    need = np.full(ftype.shape, MIN_FRAME_LEN, np.int64)
    need[ctrl_ta] = CTRL_TA_HEADER_LEN
    need[(ftype == TYPE_MGMT) | (ftype == TYPE_DATA)] = MGMT_DATA_HEADER_LEN
    return need


def has_transmitter_batch(
    ftype: npt.NDArray[np.integer], subtype: npt.NDArray[np.integer]
) -> npt.NDArray[np.bool_]:
    """Vectorised :func:`has_transmitter`."""
    ftype = np.asarray(ftype)
    ctrl_ta = (ftype == TYPE_CTRL) & (((_CTRL_TA_MASK >> np.asarray(subtype, np.int64)) & 1) == 1)
    out: npt.NDArray[np.bool_] = (ftype == TYPE_MGMT) | (ftype == TYPE_DATA) | ctrl_ta
    return out
