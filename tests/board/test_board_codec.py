"""Framing and codec: CRC check value, COBS, round trips, corrupted input fails cleanly."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rfsas_hw.board import codec, framing
from rfsas_hw.board.framing import FrameError, cobs_decode, cobs_encode, crc16
from rfsas_hw.board.messages import (
    BY_TYPE,
    MESSAGE_TYPES,
    Hello,
    Info,
    Measurement,
    MeasurementBatch,
    Message,
    PayloadError,
    SetScanPlan,
)

from .board_strategies import measurements, messages


def test_crc16_ccitt_false_check_value() -> None:
    assert crc16(b"123456789") == 0x29B1


def test_type_ids_and_seeds_are_unique() -> None:
    assert len(BY_TYPE) == len(MESSAGE_TYPES)
    # two types with one seed would not be told apart by a layout mismatch
    # between them; every seed must differ
    assert len({cls.CRC_EXTRA for cls in MESSAGE_TYPES}) == len(MESSAGE_TYPES)


@pytest.mark.parametrize(
    ("data", "wire"),
    [
        (b"", b"\x01"),
        (b"\x00", b"\x01\x01"),
        (b"\x00\x00", b"\x01\x01\x01"),
        (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        (bytes(range(1, 255)), b"\xff" + bytes(range(1, 255))),
        (bytes(range(1, 256)), b"\xff" + bytes(range(1, 255)) + b"\x02\xff"),
        (bytes(range(0, 255)), b"\x01\xff" + bytes(range(1, 255))),
    ],
)
def test_cobs_known_encodings(data: bytes, wire: bytes) -> None:
    assert cobs_encode(data) == wire
    assert cobs_decode(wire) == data


@given(st.binary(max_size=1200))
def test_cobs_round_trip(data: bytes) -> None:
    enc = cobs_encode(data)
    assert 0 not in enc
    assert len(enc) <= len(data) + len(data) // 254 + 1
    assert cobs_decode(enc) == data


def test_cobs_rejects_zero_and_overrun() -> None:
    with pytest.raises(FrameError) as err:
        cobs_decode(b"\x03\x00\x01")
    assert err.value.kind == "cobs"
    with pytest.raises(FrameError, match="runs past the end"):
        cobs_decode(b"\x05\x01\x02")


@settings(max_examples=300)
@given(messages, st.integers(0, 0xFFFF), st.integers(0, 0xFF))
def test_message_round_trip(msg: Message, seq: int, compat: int) -> None:
    wire = codec.encode(msg, seq, compat=compat)
    assert wire.endswith(b"\x00") and 0 not in wire[:-1]
    frame, back = codec.decode_frame(wire)
    assert back == msg
    assert (frame.msg_type, frame.seq, frame.compat) == (msg.TYPE, seq, compat)


@given(measurements, st.binary(min_size=1, max_size=12))
def test_appended_fields_from_newer_sender_are_ignored(m: Measurement, extra: bytes) -> None:
    wire = framing.encode_frame(m.TYPE, 1, m.pack() + extra, m.CRC_EXTRA)
    assert codec.decode(wire) == m


@given(messages, st.data())
def test_any_single_bit_flip_is_rejected(msg: Message, data: st.DataObject) -> None:
    body = bytearray(framing.build_frame(msg.TYPE, 3, msg.pack(), msg.CRC_EXTRA))
    bit = data.draw(st.integers(0, 8 * len(body) - 1))
    body[bit // 8] ^= 1 << (bit % 8)
    wire = cobs_encode(bytes(body))
    with pytest.raises(FrameError):
        codec.decode(wire)


def test_layout_change_is_caught_by_the_seed() -> None:
    # a sender whose INFO layout differs (seeded with another layout) is
    # rejected as a CRC error, not decoded into wrong fields
    info = Info(1, 2, 3, 4, 2, 0, 99)
    other_seed = framing.layout_crc_extra(Info.LAYOUT.replace("u32 capabilities", "u16 caps"))
    assert other_seed != Info.CRC_EXTRA
    wire = framing.encode_frame(Info.TYPE, 0, info.pack(), other_seed)
    with pytest.raises(FrameError) as err:
        codec.decode(wire)
    assert err.value.kind == "crc"


def test_short_payload_is_a_payload_error() -> None:
    wire = framing.encode_frame(Info.TYPE, 0, b"\x01\x02", Info.CRC_EXTRA)
    with pytest.raises(PayloadError, match="Info payload of 2 bytes, version 1 needs 17"):
        codec.decode(wire)


@pytest.mark.parametrize(
    "msg",
    [
        Measurement(0, 1 << 48, 0, 0, 0, 0, None, (None,)),
        Measurement(0, 1, 0, 0, 0, 0, 4096, (None,)),
        Measurement(0, 1, 0, 0, 0, 0, None, (-128,)),
        Measurement(0, 1, 0, 0, 0, 0, None, (1, 2, 3, 4, 5)),
        Measurement(0, 1, 70000, 0, 0, 0, None, ()),
        Hello(256),
        SetScanPlan(10, tuple(range(2400, 2465))),
        MeasurementBatch(tuple(Measurement(0, 1, 0, 0, 0, 0, None, ()) for _ in range(41))),
    ],
)
def test_out_of_range_fields_fail_to_encode(msg: Message) -> None:
    with pytest.raises(PayloadError):
        codec.encode(msg)


def test_encoder_numbers_frames_and_flags_restart() -> None:
    enc = codec.Encoder(first_seq=0xFFFF)
    frames = [codec.decode_frame(enc.encode(Hello()))[0] for _ in range(3)]
    assert [f.seq for f in frames] == [0xFFFF, 0, 1]
    assert [f.compat & 0x02 for f in frames] == [0x02, 0, 0]


def test_render_is_canonical_text() -> None:
    m = Measurement(7, 0xAABBCCDDEEFF, 2412, 1, 1, 3, None, (-40, -45, None, None))
    assert codec.render(m) == (
        "t_us=7 mac=aabbccddeeff freq_mhz=2412 channel=1 kind=1 flags=3 "
        "frame_seq=- rssi_dbm=-40,-45,-,-"
    )
