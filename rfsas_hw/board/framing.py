"""Byte-level framing of the DF-board protocol: COBS, header, CRC.

A frame on the wire is ``COBS(header ‖ payload ‖ crc) 0x00``. The header is 8
bytes, little-endian (see ``firmware_protocol/SPEC.md``)::

    magic u8 (0xD1) | incompat u8 | compat u8 | seq u16 | type u8 | length u16

The CRC is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no
final xor; check value 0x29B1) computed over ``crc_extra ‖ header ‖ payload``,
where ``crc_extra`` is one byte fixed per message type and derived from the
type's version-1 field layout. The CPython implementation is
:func:`binascii.crc_hqx`, which is this exact CRC in C; seeding with the extra
byte is a precomputed start value per type, so checking costs one C call.

Everything here works on ``bytes``; nothing knows about serial ports.
"""

from __future__ import annotations

import binascii
import struct
from typing import NamedTuple

from rfsas_hw.errors import BoardProtocolError

MAGIC = 0xD1
"""First header byte: identifies the protocol and its version (1)."""
HEADER = struct.Struct("<BBBHBH")
HEADER_SIZE = HEADER.size
CRC_SIZE = 2
MAX_PAYLOAD = 1024
"""Largest payload a frame may carry, bytes."""
MAX_FRAME = HEADER_SIZE + MAX_PAYLOAD + CRC_SIZE
MAX_ENCODED = MAX_FRAME + MAX_FRAME // 254 + 1
"""Largest COBS-encoded frame without its delimiter, bytes."""
DELIMITER = b"\x00"
CRC_INIT = 0xFFFF
KNOWN_INCOMPAT_FLAGS = 0x00
"""Incompatible-flag bits this implementation understands (none in version 1)."""


class FrameError(BoardProtocolError):
    """One segment between delimiters is not a valid frame.

    ``kind`` is one of the error names of :data:`ERROR_KINDS`.
    """

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind
        self.offset: int | None = None
        """Stream offset of the segment, bytes, when a stream decoder raised it."""
        self.header: tuple[int, int] | None = None
        """``(msg_type, seq)`` of a well-formed frame of unknown type (for a NAK)."""


ERROR_KINDS = ("cobs", "short", "magic", "incompatible", "length", "unknown_type", "crc")
"""Why a segment is rejected, in the order the checks run."""


def crc16(data: bytes | bytearray | memoryview, crc: int = CRC_INIT) -> int:
    """CRC-16/CCITT-FALSE of ``data`` continuing from register value ``crc``."""
    return binascii.crc_hqx(data, crc)


def crc_start(crc_extra: int) -> int:
    """The CRC register after the per-type seed byte: the start value for a frame."""
    return binascii.crc_hqx(bytes((crc_extra & 0xFF,)), CRC_INIT)


def layout_crc_extra(layout: str) -> int:
    """The seed byte of a message type from its canonical layout string.

    The layout string names the type and its version-1 fields
    (``"MEASUREMENT u64 t_us, u8[6] mac, …"``); the seed is the CRC-16 of its
    ASCII bytes folded to 8 bits (high byte xor low byte).
    """
    crc = crc16(layout.encode("ascii"))
    return (crc ^ (crc >> 8)) & 0xFF


def cobs_encode(data: bytes | bytearray) -> bytes:
    """COBS-encode ``data`` (no zero bytes in the result, no delimiter added).

    Canonical form: a final block of exactly 254 non-zero bytes is not
    followed by an empty block.
    """
    out = bytearray()
    chunks = bytes(data).split(b"\x00")
    last = len(chunks) - 1
    for k, chunk in enumerate(chunks):
        while len(chunk) >= 254:
            out.append(0xFF)
            out += chunk[:254]
            chunk = chunk[254:]
            if not chunk and k == last:
                return bytes(out)
        out.append(len(chunk) + 1)
        out += chunk
    return bytes(out)


def cobs_decode(encoded: bytes | bytearray) -> bytearray:
    """Undo :func:`cobs_encode`.

    Raises:
        FrameError: ``kind="cobs"`` when the input contains a zero byte or a
            code byte points past the end.
    """
    n = len(encoded)
    if n == 0 or 0 in encoded:
        raise FrameError("cobs", "COBS block contains a zero byte or is empty")
    # Replace every code byte by the zero it stands for; codes that follow a
    # 0xFF block stand for nothing and are deleted afterwards.
    out = bytearray(encoded)
    i = 0
    code = out[0]
    after_ff: list[int] | None = None
    while True:
        j = i + code
        if j >= n:
            if j > n:
                raise FrameError("cobs", f"COBS code {code} at offset {i} runs past the end ({n})")
            break
        nxt = out[j]
        if code == 0xFF:
            if after_ff is None:
                after_ff = []
            after_ff.append(j)
        else:
            out[j] = 0
        i = j
        code = nxt
    if after_ff is not None:
        for pos in reversed(after_ff):
            del out[pos]
    del out[0]
    return out


class Frame(NamedTuple):
    """One checked frame: the header fields and the payload bytes."""

    msg_type: int
    """Message type id."""
    seq: int
    """Sender's sequence number, 0–65535, one per frame, wrapping."""
    payload: bytes
    """Payload bytes (``length`` of them)."""
    incompat: int = 0
    """Incompatible-flag byte."""
    compat: int = 0
    """Compatible-flag byte."""


def build_frame(
    msg_type: int,
    seq: int,
    payload: bytes,
    crc_extra: int,
    *,
    incompat: int = 0,
    compat: int = 0,
) -> bytes:
    """Header + payload + CRC, before COBS.

    Raises:
        BoardProtocolError: payload longer than :data:`MAX_PAYLOAD` or a
            header field out of range.
    """
    if len(payload) > MAX_PAYLOAD:
        raise BoardProtocolError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    try:
        header = HEADER.pack(MAGIC, incompat, compat, seq & 0xFFFF, msg_type, len(payload))
    except struct.error as err:
        raise BoardProtocolError(f"header field out of range: {err}") from err
    body = header + payload
    return body + (crc16(body, crc_start(crc_extra))).to_bytes(2, "big")


def encode_frame(
    msg_type: int,
    seq: int,
    payload: bytes,
    crc_extra: int,
    *,
    incompat: int = 0,
    compat: int = 0,
) -> bytes:
    """The wire bytes of one frame: COBS-encoded, followed by the 0x00 delimiter."""
    body = build_frame(msg_type, seq, payload, crc_extra, incompat=incompat, compat=compat)
    return cobs_encode(body) + DELIMITER


def check_frame(decoded: bytes | bytearray, crc_starts: dict[int, int]) -> Frame:
    """Validate a COBS-decoded frame and split it into header fields and payload.

    ``crc_starts`` maps each known message type to its CRC start value
    (:func:`crc_start` of its seed byte).

    Raises:
        FrameError: with ``kind`` naming the first check that failed (see
            :data:`ERROR_KINDS`).
    """
    n = len(decoded)
    if n < HEADER_SIZE + CRC_SIZE:
        raise FrameError("short", f"frame of {n} bytes is shorter than header + CRC")
    magic, incompat, compat, seq, msg_type, length = HEADER.unpack_from(decoded)
    if magic != MAGIC:
        raise FrameError("magic", f"magic byte 0x{magic:02x}, expected 0x{MAGIC:02x}")
    if incompat & ~KNOWN_INCOMPAT_FLAGS:
        raise FrameError("incompatible", f"unknown incompatible flags 0x{incompat:02x}")
    if length != n - HEADER_SIZE - CRC_SIZE:
        raise FrameError(
            "length", f"length field {length} but {n - HEADER_SIZE - CRC_SIZE} payload bytes"
        )
    start = crc_starts.get(msg_type)
    if start is None:
        err = FrameError("unknown_type", f"unknown message type 0x{msg_type:02x}")
        err.header = (msg_type, seq)
        raise err
    # The CRC is stored most significant byte first, so the CRC over the
    # whole frame including it is zero when it matches (one C call).
    if binascii.crc_hqx(decoded, start):
        raise FrameError("crc", f"CRC mismatch in type 0x{msg_type:02x} seq {seq}")
    return Frame(msg_type, seq, bytes(decoded[HEADER_SIZE : n - CRC_SIZE]), incompat, compat)


def decode_segment(segment: bytes | bytearray, crc_starts: dict[int, int]) -> Frame:
    """COBS-decode and check one segment (the bytes between two delimiters).

    Raises:
        FrameError: the segment is not a valid frame.
    """
    if len(segment) > MAX_ENCODED:
        raise FrameError("length", f"segment of {len(segment)} bytes exceeds {MAX_ENCODED}")
    return check_frame(cobs_decode(segment), crc_starts)


def recover_suffix(
    segment: bytes | bytearray, crc_starts: dict[int, int]
) -> tuple[int, Frame] | None:
    """Find a valid frame at the end of a segment that failed as a whole.

    Garbage that arrives without a trailing 0x00 sticks to the front of the
    next frame. A frame starts with a COBS code byte followed by the magic
    byte, so only offsets ``i`` with ``segment[i + 1] == MAGIC`` are tried,
    from the left. Returns ``(offset, frame)`` or None.
    """
    magic = bytes((MAGIC,))
    lo = max(1, len(segment) - MAX_ENCODED)
    pos = segment.find(magic, lo + 1)
    while pos != -1:
        try:
            return pos - 1, decode_segment(segment[pos - 1 :], crc_starts)
        except FrameError:
            pos = segment.find(magic, pos + 1)
    return None
