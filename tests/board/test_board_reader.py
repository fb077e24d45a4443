"""Stream reader: resynchronisation, exact loss accounting, the board_*.bin captures."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rfsas_hw.board import codec
from rfsas_hw.board.columns import is_measurement, records
from rfsas_hw.board.messages import Heartbeat, Measurement, Message
from rfsas_hw.board.reader import FrameDecoder, FrameReader
from rfsas_hw.errors import BoardProtocolError

from .board_strategies import measurements, messages

small_messages = st.one_of(
    measurements, st.builds(Heartbeat, *(st.integers(0, 255) for _ in range(7))), messages
)


def _read(data: bytes, chunk: int = 4096) -> tuple[list[Message], FrameReader]:
    reader = FrameReader(io.BytesIO(data), chunk_size=chunk)
    return [m for _, m in reader], reader


@settings(max_examples=150, deadline=None)
@given(st.lists(small_messages, min_size=1, max_size=12), st.data())
def test_garbage_between_frames_costs_no_frame(msgs: list[Message], data: st.DataObject) -> None:
    enc = codec.Encoder()
    stream = bytearray()
    garbage_bytes = 0
    for m in msgs:
        g = data.draw(st.binary(max_size=40), label="garbage")
        stream += g + enc.encode(m)
        garbage_bytes += sum(1 for b in g if b)
    chunk = data.draw(st.integers(1, 97), label="chunk")
    out, reader = _read(bytes(stream), chunk)
    assert out == msgs
    st_ = reader.stats
    assert st_.frames == len(msgs)
    assert st_.lost == 0 and st_.sequence_gaps == 0
    # every non-delimiter garbage byte is accounted for, no more
    assert st_.discarded_bytes == garbage_bytes


def _touch(frame: bytes, how: str, pos: int, bit: int) -> bytes:
    b = bytearray(frame)
    if how != "insert":
        pos %= len(b)
    if how == "flip":
        b[pos] ^= 1 << bit
    elif how == "drop":
        del b[pos]
    else:
        # after the code byte and the magic: a byte in front of the magic
        # equal to the code byte would leave the frame intact behind garbage
        b.insert(2 + pos % (len(b) - 2), (pos * 37 + bit) & 0xFF)
    return bytes(b)


@settings(max_examples=150, deadline=None)
@given(st.lists(small_messages, min_size=3, max_size=14), st.data())
def test_touched_frames_are_exactly_the_lost_ones(msgs: list[Message], data: st.DataObject) -> None:
    enc = codec.Encoder()
    wires = [enc.encode(m) for m in msgs]
    # the first and last frames stay intact so every gap is visible
    touched = data.draw(
        st.sets(st.integers(1, len(msgs) - 2), max_size=len(msgs) - 2), label="touched"
    )
    stream = bytearray()
    repaired = set()
    for i, w in enumerate(wires):
        if i in touched:
            how = data.draw(st.sampled_from(["flip", "drop", "insert"]))
            w = _touch(w, how, data.draw(st.integers(0, 10_000)), data.draw(st.integers(0, 7)))
            # the garbage before a frame joins it up to the last delimiter: it can give
            # back a dropped first byte (garbage b"\x02" before a frame whose code byte
            # 0x02 was dropped), and then the frame is whole again on the wire
            start = stream.rfind(b"\x00") + 1
            if bytes(stream[start:]) + w == wires[i]:
                repaired.add(i)
        stream += w
        stream += data.draw(st.binary(max_size=6), label="garbage")
    out, reader = _read(bytes(stream), data.draw(st.integers(1, 64)))
    lost = touched - repaired
    assert out == [m for i, m in enumerate(msgs) if i not in lost]
    assert reader.stats.lost == len(lost)


def test_sequence_gaps_and_restart() -> None:
    m = Measurement(1, 2, 2412, 1, 0, 0, None, (-50, -50, None, None))
    wire = b"".join(codec.encode(m, s) for s in (10, 11, 15, 16))
    wire += codec.encode(m, 0, compat=0x02) + codec.encode(m, 1)
    wire += codec.encode(m, 0xFFFF) + codec.encode(m, 0x0000)
    _, reader = _read(wire)
    st_ = reader.stats
    assert (st_.frames, st_.sequence_gaps, st_.lost) == (8, 1, 3)
    # the RESTART frame and the backwards jump to 0xFFFF are restarts, not losses;
    # 0xFFFF -> 0 is the normal wrap
    assert st_.restarts == 2


def test_clean_capture_decodes_without_loss(data_dir: Path) -> None:
    out, reader = _read((data_dir / "board_clean_stream.bin").read_bytes())
    st_ = reader.stats
    assert st_.frames == 1 + 200 + 4 + 5
    assert (st_.lost, st_.crc_errors, st_.resyncs, st_.discarded_bytes) == (0, 0, 0, 0)
    assert sum(isinstance(m, Measurement) for m in out) == 200


def test_badcrc_capture_costs_exactly_the_bad_frames(data_dir: Path) -> None:
    out, reader = _read((data_dir / "board_badcrc.bin").read_bytes())
    st_ = reader.stats
    assert (st_.frames, st_.crc_errors, st_.lost, st_.sequence_gaps) == (98, 2, 2, 2)
    assert [m.frame_seq for m in out if isinstance(m, Measurement)][9:11] == [9, 11]
    # the error names the byte offset of the bad frame: frames are 37 bytes
    assert st_.errors[0].startswith("byte 370: CRC mismatch in type 0x10 seq 10")


def test_garbage_capture_resyncs_on_every_frame(data_dir: Path) -> None:
    out, reader = _read((data_dir / "board_garbage_resync.bin").read_bytes(), chunk=7)
    assert len(out) == 50
    assert reader.stats.lost == 0 and reader.stats.resyncs > 0


def test_truncated_capture_reports_the_cut_frame(data_dir: Path) -> None:
    out, reader = _read((data_dir / "board_truncated.bin").read_bytes())
    assert len(out) == 20 and reader.stats.truncated == 1
    assert "input ended inside a frame (17 bytes)" in reader.stats.errors[-1]


def test_unknown_type_and_flags_capture(data_dir: Path) -> None:
    out, reader = _read((data_dir / "board_unknown_type_and_flags.bin").read_bytes())
    st_ = reader.stats
    # frames 0, 2 (unknown compatible flag ignored) and 4 arrive; the unknown
    # type (1) is counted and skipped, the unknown incompatible flag (3) dropped
    assert len(out) == 3
    assert (st_.unknown_types, st_.incompatible, st_.lost, st_.sequence_gaps) == (1, 1, 2, 2)


def test_raise_policy_names_the_offset(data_dir: Path) -> None:
    reader = FrameReader(
        io.BytesIO((data_dir / "board_badcrc.bin").read_bytes()), errors="raise", name="cap.bin"
    )
    with pytest.raises(BoardProtocolError, match=r"cap.bin: byte 370: CRC mismatch"):
        list(reader)


def test_overlong_run_without_delimiter_is_bounded() -> None:
    m = Measurement(1, 2, 2412, 1, 0, 0, None, (-50, -50, None, None))
    dec = FrameDecoder()
    dec.feed(b"\x07" * 5000)
    assert len(dec._buf) <= 1039
    frames = dec.feed(codec.encode(m, 1))
    assert len(frames) == 1
    assert dec.stats.discarded_bytes == 5000


@settings(max_examples=120, deadline=None)
@given(st.lists(small_messages, min_size=1, max_size=25), st.data())
def test_columns_hold_the_measurements_of_the_frames(
    msgs: list[Message], data: st.DataObject
) -> None:
    enc = codec.Encoder(first_seq=data.draw(st.integers(0, 0xFFFF)))
    stream = bytearray()
    for m in msgs:
        w = enc.encode(m)
        if data.draw(st.booleans()):
            w = _touch(
                w,
                data.draw(st.sampled_from(["flip", "drop", "insert"])),
                data.draw(st.integers(0, 10_000)),
                data.draw(st.integers(0, 7)),
            )
        stream += data.draw(st.binary(max_size=8)) + w
    chunk = data.draw(st.integers(1, 300))
    slow, fast = FrameDecoder(), FrameDecoder()
    slow_recs, slow_other, fast_recs, fast_other = [], [], [], []
    for i in range(0, len(stream), chunk):
        piece = bytes(stream[i : i + chunk])
        frames = slow.feed(piece)
        slow_recs.append(records(f for _, f in frames))
        slow_other += [(raw, f) for raw, f in frames if not is_measurement(f)]
        recs, other = fast.feed_columns(piece)
        fast_recs.append(recs)
        fast_other += other
    assert np.concatenate(fast_recs).tobytes() == np.concatenate(slow_recs).tobytes()
    assert fast_other == slow_other
    assert fast.stats == slow.stats


def test_short_measurement_payload_is_counted_and_the_others_kept() -> None:
    """A sender bug (a MEASUREMENT payload too short) costs that frame only, with its offset."""
    from rfsas_hw.board.framing import encode_frame

    good = Measurement(1_000, 0x3C2EF9000001, 2437, 6, 2, 0, 7, (-40, -45, None, None))
    first = codec.encode(good, 0)
    short = encode_frame(Measurement.TYPE, 1, bytes(10), Measurement.CRC_EXTRA)
    last = codec.encode(good, 2)
    dec = FrameDecoder()
    recs, others = dec.feed_columns(first + short + last)
    assert len(recs) == 2 and others == []
    assert dec.stats.bad_payloads == 1 and dec.stats.frames == 3
    assert dec.new_errors[0].kind == "payload" and dec.new_errors[0].offset == len(first)
    assert dec.stats.errors[0].startswith(f"byte {len(first)}: ")


def test_garbage_that_gives_back_a_dropped_first_byte_makes_the_frame_whole() -> None:
    """A frame whose COBS code byte was dropped, behind garbage that ends with that very
    byte, is whole again on the wire: it is read, and only the frame really broken is
    lost (the case the property test above once drew)."""
    m = Measurement(0, 0, 0, 0, 0, 0, None, (None, None, None, None))
    enc = codec.Encoder()
    wires = [enc.encode(m) for _ in range(4)]
    assert wires[2][0] == 0x02
    stream = wires[0] + _touch(wires[1], "flip", 0, 0) + b"\x02" + wires[2][1:] + wires[3]
    out, reader = _read(stream)
    assert len(out) == 3
    assert reader.stats.lost == 1
