"""The Python side of the DF-board firmware protocol: framing, messages, codec, reader.

``firmware_protocol/SPEC.md`` is the protocol; this package implements it.
"""

from rfsas_hw.board.codec import Encoder, decode, decode_frame, encode, render
from rfsas_hw.board.framing import Frame, FrameError
from rfsas_hw.board.messages import BY_TYPE, MESSAGE_TYPES, Message, PayloadError
from rfsas_hw.board.reader import FrameDecoder, FrameReader, LinkStats

__all__ = [
    "BY_TYPE",
    "MESSAGE_TYPES",
    "Encoder",
    "Frame",
    "FrameDecoder",
    "FrameError",
    "FrameReader",
    "LinkStats",
    "Message",
    "PayloadError",
    "decode",
    "decode_frame",
    "encode",
    "render",
]
