"""Safety message codec: golden vector, round trips, and inputs that must fail cleanly."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from linkhelp import key, message

from rfsas_hw.errors import LinkError
from rfsas_hw.link import (
    DEFAULT_DATAGRAM,
    MessageFormatError,
    SafetyMessage,
    Signer,
    decode,
    encode_body,
    max_bearings,
    verify,
)
from rfsas_hw.link.message import BEARING_BYTES, HEADER_BYTES, SIGNATURE_BYTES, peek
from rfsas_hw.records import BearingBatch, Pose

GOLDEN = Path(__file__).parent.parent / "data" / "link_message_v1_two_bearings.bin"


def test_golden_vector_decodes_field_by_field_and_verifies() -> None:
    raw = GOLDEN.read_bytes()
    assert len(raw) == 168 == HEADER_BYTES + 5 + 2 * BEARING_BYTES + SIGNATURE_BYTES
    # the layout of docs/protocol.md, read by hand
    assert raw[:6] == b"RF\x01\x01\x00\x05" and raw[6:11] == b"rsu-1"
    t_gen_us, seq, epoch, x, y, hdg, n = struct.unpack(">qIQfffB", raw[11:44])
    assert (t_gen_us, seq, epoch, x, y, hdg, n) == (
        1_763_800_030_000_000,
        4242,
        29_396_667,
        12.5,
        -40.0,
        90.0,
        2,
    )
    t_us, emitter, az, sigma, snr, channel = struct.unpack(">qQfffH", raw[74:104])
    assert (t_us, emitter, az, sigma, snr, channel) == (
        1_763_800_029_990_123,
        0xFEDCBA9876543210,
        271.5,
        7.25,
        9.5,
        37,
    )
    msg = decode(raw)
    assert msg.sender_id == "rsu-1" and msg.pose == Pose(12.5, -40.0, 90.0)
    assert msg.bearings.emitter.tolist() == [0x0123456789ABCDEF, 0xFEDCBA9876543210]
    assert msg.bearings.t_ns.tolist() == [1_763_800_029_980_000_000, 1_763_800_029_990_123_000]
    assert encode_body(msg) == raw[:-64]
    assert verify(key(0x1234).public_key(), raw[:-64], raw[-64:])
    assert not verify(key(0x1235).public_key(), raw[:-64], raw[-64:])


@settings(max_examples=60, deadline=None)
@given(
    sender=st.from_regex(r"[A-Za-z0-9._-]{1,32}", fullmatch=True),
    n=st.integers(1, 40),
    seq=st.integers(0, 2**32 - 1),
    epoch=st.integers(0, 2**62),
    t_gen_us=st.integers(0, 2**62),
    seed=st.integers(0, 2**32 - 1),
)
def test_round_trip(sender: str, n: int, seq: int, epoch: int, t_gen_us: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    batch = BearingBatch(
        sensor_id=sender,
        t_ns=rng.integers(0, 2**62 // 1000, n) * 1000,
        azimuth_deg=rng.uniform(0, 360, n).astype(np.float32).astype(np.float64),
        sigma_deg=rng.uniform(0.01, 90, n).astype(np.float32).astype(np.float64),
        snr_db=rng.uniform(-10, 60, n).astype(np.float32).astype(np.float64),
        channel=rng.integers(0, 200, n).astype(np.int16),
        emitter=rng.integers(0, 2**64 - 1, n, dtype=np.uint64, endpoint=True),
    )
    msg = SafetyMessage(sender, Pose(-1.5, 2.25, 359.5), t_gen_us, seq, epoch, batch)
    body = encode_body(msg)
    got = decode(body + bytes(64))
    assert (got.sender_id, got.pose, got.t_gen_us, got.seq, got.epoch) == (
        sender,
        msg.pose,
        t_gen_us,
        seq,
        epoch,
    )
    for name in ("t_ns", "azimuth_deg", "sigma_deg", "snr_db", "channel", "emitter"):
        np.testing.assert_array_equal(getattr(got.bearings, name), getattr(batch, name))


def test_signed_datagram_fits_the_size_it_was_built_for() -> None:
    sender = "a-sensor-with-a-long-name-32-chr"
    n = max_bearings(sender, DEFAULT_DATAGRAM)
    raw = Signer(sender, key(5)).encode(message(sender, n=n))
    assert len(raw) <= DEFAULT_DATAGRAM < len(raw) + BEARING_BYTES
    with pytest.raises(LinkError, match="cannot hold one bearing"):
        max_bearings(sender, 150)


def test_the_rows_on_the_wire_are_the_documented_layout_of_float32_values() -> None:
    # the encoder packs each row with struct: the same bytes as the wire's dtype,
    # each float rounded to float32 as numpy rounds it
    from rfsas_hw.link.message import BEARING_DTYPE

    rng = np.random.default_rng(8)
    for n in (1, 3, 17):
        msg = message(n=n)
        b = msg.bearings
        b.azimuth_deg[:] = rng.uniform(0.0, 359.0, n)
        b.sigma_deg[:] = rng.uniform(0.01, 40.0, n) / 3.0
        b.snr_db[:] = rng.normal(0.0, 30.0, n) / 7.0
        rows = np.empty(n, BEARING_DTYPE)
        rows["t_us"] = b.t_ns // 1000
        rows["emitter"] = b.emitter
        rows["azimuth_deg"] = b.azimuth_deg
        rows["sigma_deg"] = b.sigma_deg
        rows["snr_db"] = b.snr_db
        rows["channel"] = b.channel
        assert encode_body(msg).endswith(rows.tobytes())


def test_azimuth_that_rounds_to_360_in_float32_is_sent_as_0() -> None:
    msg = message(n=1)
    msg.bearings.azimuth_deg[0] = 359.999999
    assert decode(encode_body(msg) + bytes(64)).bearings.azimuth_deg[0] == 0.0


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda m: SafetyMessage("bad id!", m.pose, m.t_gen_us, m.seq, m.epoch, m.bearings), "id"),
        (lambda m: SafetyMessage("x" * 33, m.pose, m.t_gen_us, m.seq, m.epoch, m.bearings), "id"),
        (
            lambda m: SafetyMessage(
                m.sender_id, m.pose, m.t_gen_us, m.seq, m.epoch, BearingBatch.empty("rsu-1")
            ),
            "1-255 bearings",
        ),
        (
            lambda m: SafetyMessage(m.sender_id, m.pose, m.t_gen_us, 2**32, m.epoch, m.bearings),
            "32 bits",
        ),
        (
            lambda m: SafetyMessage(
                m.sender_id, Pose(float("nan"), 0, 0), m.t_gen_us, 1, m.epoch, m.bearings
            ),
            "finite",
        ),
    ],
)
def test_encode_refuses_what_cannot_go_on_the_wire(change: object, match: str) -> None:
    with pytest.raises(LinkError, match=match):
        encode_body(change(message()))  # type: ignore[operator]


@pytest.mark.parametrize(
    ("column", "value", "match"),
    [
        ("sigma_deg", float("nan"), "sigma"),
        ("sigma_deg", 0.0, "sigma"),
        ("azimuth_deg", -1.0, "azimuth"),
        # not wrapped to 0 as a value that rounds up to 360 in float32 is
        ("azimuth_deg", 365.0, "azimuth"),
        ("azimuth_deg", float("inf"), "azimuth"),
        ("snr_db", float("inf"), "SNR"),
        ("channel", -6, "negative"),
    ],
)
def test_encode_refuses_bad_bearing_values(column: str, value: float, match: str) -> None:
    msg = message()
    getattr(msg.bearings, column)[1] = value
    with pytest.raises(LinkError, match=match):
        encode_body(msg)


def test_every_prefix_of_a_message_is_truncated() -> None:
    raw = GOLDEN.read_bytes()
    for cut in range(len(raw)):
        with pytest.raises(MessageFormatError) as info:
            peek(raw[:cut])
        assert info.value.reason == "truncated", cut


def test_padding_and_oversize_are_refused() -> None:
    raw = GOLDEN.read_bytes()
    with pytest.raises(MessageFormatError) as info:
        peek(raw + b"\x00")
    assert info.value.reason == "oversized"
    with pytest.raises(MessageFormatError) as info:
        peek(raw + bytes(2000))
    assert info.value.reason == "oversized" and "1472" in str(info.value)


@pytest.mark.parametrize(
    ("offset", "value", "reason"),
    [
        (0, 0x51, "bad_magic"),
        (2, 3, "bad_version"),  # 1 and 2 (with a pre-authentication tag) exist
        (3, 9, "bad_type"),
        (4, 1, "malformed"),  # reserved flags
        (6, ord("!"), "malformed"),  # sender id character
        (43, 0, "malformed"),  # no bearings
        (43, 3, "truncated"),  # more bearings declared than present
        (43, 1, "oversized"),  # fewer bearings declared than present
    ],
)
def test_header_corruptions_are_named(offset: int, value: int, reason: str) -> None:
    raw = bytearray(GOLDEN.read_bytes())
    raw[offset] = value
    with pytest.raises(MessageFormatError) as info:
        decode(bytes(raw))
    assert info.value.reason == reason


@pytest.mark.parametrize(
    ("offset", "fmt", "value"),
    [
        (60, ">f", float("nan")),  # azimuth of bearing 0
        (60, ">f", 360.0),
        (64, ">f", -2.0),  # sigma of bearing 0
        (98, ">f", float("inf")),  # SNR of bearing 1
        (35, ">f", float("inf")),  # sender y
        (39, ">f", 360.0),  # sender heading
        (11, ">q", -5),  # generation time
    ],
)
def test_value_corruptions_are_malformed(offset: int, fmt: str, value: float) -> None:
    raw = bytearray(GOLDEN.read_bytes())
    struct.pack_into(fmt, raw, offset, value)
    with pytest.raises(MessageFormatError) as info:
        decode(bytes(raw))
    assert info.value.reason == "malformed"


BAD_VALUES = {
    "az": (16, ">f", 360.0, "azimuth outside [0, 360) degrees"),
    "neg_az": (16, ">f", -1e-3, "azimuth outside [0, 360) degrees"),
    "nan_az": (16, ">f", float("nan"), "azimuth outside [0, 360) degrees"),
    "zero_sigma": (20, ">f", 0.0, "sigma must be finite and positive"),
    "nan_sigma": (20, ">f", float("nan"), "sigma must be finite and positive"),
    "inf_sigma": (20, ">f", float("inf"), "sigma must be finite and positive"),
    "inf_snr": (24, ">f", float("-inf"), "SNR must be finite"),
    "nan_snr": (24, ">f", float("nan"), "SNR must be finite"),
    "time": (0, ">q", -1, "capture time before 1970"),
    "late": (0, ">q", 2**63 // 1000 + 1, "capture time out of range"),
    "channel": (28, ">H", 0x8000, "channel number above 32767"),
}


@settings(max_examples=80, deadline=None)
@given(
    n=st.integers(1, 40),
    seed=st.integers(0, 2**32 - 1),
    bad=st.sampled_from(["", *BAD_VALUES]),
)
def test_bearing_values_decode_or_are_named(n: int, seed: int, bad: str) -> None:
    """Every row is checked, whatever the number of bearings: a bad value anywhere is
    refused with its name; good rows come back as sent (float32 on the wire)."""
    sent = message("rsu-1", n, seed=seed)
    raw = bytearray(encode_body(sent) + bytes(SIGNATURE_BYTES))
    row = HEADER_BYTES + 5 + (seed % n) * BEARING_BYTES
    if bad:
        at, fmt, value, why = BAD_VALUES[bad]
        struct.pack_into(fmt, raw, row + at, value)
        with pytest.raises(MessageFormatError, match=re.escape(why)):
            decode(bytes(raw))
        return
    got = decode(bytes(raw)).bearings
    assert got.t_ns.tolist() == (sent.bearings.t_ns // 1000 * 1000).tolist()
    assert got.emitter.tolist() == sent.bearings.emitter.tolist()
    assert got.channel.tolist() == sent.bearings.channel.tolist()
    for name in ("azimuth_deg", "sigma_deg", "snr_db"):
        want = getattr(sent.bearings, name).astype(np.float32).astype(np.float64)
        assert getattr(got, name).dtype == np.float64
        assert np.array_equal(getattr(got, name), want), name
