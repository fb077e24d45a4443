"""Encode messages to wire bytes and decode wire bytes to messages.

``encode(msg, seq)`` gives the COBS-encoded frame with its 0x00 delimiter;
``decode(wire)`` takes one frame (delimiter optional) and gives the message.
:class:`Encoder` numbers frames for a sender. :func:`render` writes a message
as the canonical ``name=value`` text used by the shared test vectors.
"""

from __future__ import annotations

import dataclasses

from rfsas_hw.board.framing import (
    DELIMITER,
    Frame,
    FrameError,
    crc_start,
    decode_segment,
    encode_frame,
)
from rfsas_hw.board.messages import BY_TYPE, Measurement, MeasurementBatch, Message

CRC_STARTS: dict[int, int] = {t: crc_start(cls.CRC_EXTRA) for t, cls in BY_TYPE.items()}
"""CRC start value per known message type (the register after its seed byte)."""


def encode(msg: Message, seq: int = 0, *, compat: int = 0, incompat: int = 0) -> bytes:
    """The wire bytes of ``msg`` as frame number ``seq`` (COBS + trailing 0x00).

    Raises:
        PayloadError: a field is out of range for its wire type.
    """
    return encode_frame(msg.TYPE, seq, msg.pack(), msg.CRC_EXTRA, compat=compat, incompat=incompat)


def decode_payload(frame: Frame) -> Message:
    """The message a checked frame carries.

    Raises:
        PayloadError: the payload does not fit the message's layout.
    """
    return BY_TYPE[frame.msg_type].unpack(frame.payload)


def decode_frame(wire: bytes | bytearray) -> tuple[Frame, Message]:
    """Check one frame (its COBS bytes, delimiter optional); header and message.

    Raises:
        FrameError: the frame is malformed (COBS, magic, flags, length, type, CRC).
        PayloadError: the payload does not fit the message's layout.
    """
    segment = bytes(wire)
    if segment.endswith(DELIMITER):
        segment = segment[:-1]
    frame = decode_segment(segment, CRC_STARTS)
    return frame, decode_payload(frame)


def decode(wire: bytes | bytearray) -> Message:
    """The message in one frame (its COBS bytes, delimiter optional).

    Raises:
        FrameError: the frame is malformed.
        PayloadError: the payload does not fit the message's layout.
    """
    return decode_frame(wire)[1]


class Encoder:
    """Numbers the frames of one sender: 0, 1, 2, … wrapping at 65536.

    The first frame carries the RESTART compatible flag so a receiver does not
    count the jump of the sequence number as lost frames.
    """

    def __init__(self, first_seq: int = 0, *, announce_restart: bool = True) -> None:
        self.seq = first_seq & 0xFFFF
        self._restart = announce_restart

    def encode(self, msg: Message, *, compat: int = 0) -> bytes:
        """Wire bytes of ``msg`` with the next sequence number."""
        if self._restart:
            compat |= 0x02
            self._restart = False
        out = encode(msg, self.seq, compat=compat)
        self.seq = (self.seq + 1) & 0xFFFF
        return out


def _render_value(value: object) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return value.encode("utf-8").hex() or "-"
    if isinstance(value, tuple):
        return ",".join(_render_value(v) for v in value) or "-"
    raise TypeError(f"cannot render {type(value).__name__}")


def _render_fields(msg: Message, prefix: str = "") -> list[str]:
    out = []
    for f in dataclasses.fields(msg):  # type: ignore[arg-type]
        value = getattr(msg, f.name)
        if f.name == "mac":
            out.append(f"{prefix}mac={int(value):012x}")
        else:
            out.append(f"{prefix}{f.name}={_render_value(value)}")
    return out


def render(msg: Message) -> str:
    """Canonical text of a message: ``name=value`` tokens separated by spaces.

    Integers are decimal, the MAC is 12 hex digits, None is ``-``, tuples are
    comma-separated, text is its UTF-8 bytes in hex. A batch renders
    ``count=N`` followed by each record's tokens prefixed ``i.``. The C test
    program prints the same text, which is how both codecs are compared
    field by field.
    """
    if isinstance(msg, MeasurementBatch):
        tokens = [f"count={len(msg.measurements)}"]
        for i, m in enumerate(msg.measurements):
            tokens += _render_fields(m, f"{i}.")
        return " ".join(tokens)
    return " ".join(_render_fields(msg))


def message_name(msg_type: int) -> str:
    """The layout name of a type id (``MEASUREMENT``), or ``0xNN`` if unknown."""
    cls = BY_TYPE.get(msg_type)
    return cls.LAYOUT.split(" ", 1)[0] if cls is not None else f"0x{msg_type:02x}"


__all__ = [
    "CRC_STARTS",
    "Encoder",
    "FrameError",
    "Measurement",
    "decode",
    "decode_frame",
    "decode_payload",
    "encode",
    "message_name",
    "render",
]
