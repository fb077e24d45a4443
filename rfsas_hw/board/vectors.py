"""The shared test vectors of the board protocol, generated from this codec.

``python -m rfsas_hw.board.vectors OUT.txt`` writes them; the file committed as
``firmware_protocol/vectors/vectors.txt`` is checked by the Python tests (it
must equal a fresh generation) and by the C test program.

File format (one record per line, ``#`` starts a comment)::

    vector NAME
    note   free text
    wire   HEX                  the byte stream, possibly several frames
    expect frame TYPE SEQ COMPAT SKIP REENCODE FIELDS...
    expect error KIND
    end

``expect`` lines list, in stream order, what a receiver reports: a frame
(``TYPE`` as 0xNN, ``SKIP`` garbage bytes cut off its front, ``REENCODE`` 1
when encoding the decoded message again must give the same wire bytes, then
the canonical ``name=value`` text of the message) or an error of ``KIND``
(``cobs short magic incompatible length unknown_type crc payload truncated``).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from rfsas_hw.board.codec import decode_payload, encode, render
from rfsas_hw.board.framing import DELIMITER, MAGIC, build_frame, cobs_encode, crc16, crc_start
from rfsas_hw.board.messages import (
    Ack,
    ErrorReport,
    Heartbeat,
    Hello,
    Info,
    Measurement,
    MeasurementBatch,
    Message,
    Nak,
    PayloadError,
    SetChannel,
    SetScanPlan,
    Start,
    Stop,
    TimeSync,
    TimeSyncRequest,
)
from rfsas_hw.board.reader import FrameDecoder


@dataclass
class Vector:
    """One named byte stream and what a receiver must report for it."""

    name: str
    note: str
    wire: bytes
    expect: list[str] = field(default_factory=list)


def expectations(wire: bytes) -> list[str]:
    """What this codec reports for ``wire``, as ``expect`` line bodies, in order."""
    dec = FrameDecoder()
    out: list[str] = []
    for i in range(len(wire)):
        before = dec.stats.discarded_bytes
        frames = dec.feed(wire[i : i + 1])
        for err in dec.new_errors:
            if err.kind != "garbage":
                out.append(f"error {err.kind}")
        for raw, frame in frames:
            skip = dec.stats.discarded_bytes - before
            try:
                msg = decode_payload(frame)
            except PayloadError:
                out.append("error payload")
                continue
            same = encode(msg, frame.seq, compat=frame.compat) == raw
            out.append(
                f"frame 0x{frame.msg_type:02x} {frame.seq} {frame.compat} {skip} "
                f"{int(same)}" + (f" {text}" if (text := render(msg)) else "")
            )
    dec.flush()
    out += [f"error {err.kind}" for err in dec.new_errors]
    return out


def _raw(msg_type: int, seq: int, payload: bytes, extra: int, **flags: int) -> bytes:
    return cobs_encode(build_frame(msg_type, seq, payload, extra, **flags)) + DELIMITER


def _nonzero_record(t_us: int = 0x0102030405060708) -> Measurement:
    return Measurement(t_us, 0x0A0B0C0D0E0F, 2313, 6, 7, 1, 257, (-50, -60, -70, -80))


def _batch_with_run(run: int, at_end: bool) -> bytes:
    """A batch frame whose body holds a run of exactly ``run`` non-zero bytes.

    Twelve records with no zero byte make a 312-byte body whose only zeros are
    the two flag bytes (offsets 1, 2); one payload byte is then set to zero
    to end the run after ``run`` bytes from offset 3, or, with ``at_end``,
    to start a run that ends at the last CRC byte. The first record's time
    is varied until the CRC bytes are non-zero.
    """
    for t_us in range(0x0102030405060708, 0x0102030405060708 + 1000):
        recs = [_nonzero_record(t_us if k == 0 else 0x0102030405060708) for k in range(12)]
        payload = bytearray(MeasurementBatch(tuple(recs)).pack())
        size = 8 + len(payload) + 2
        zero_at = size - run - 1 if at_end else 3 + run
        payload[zero_at - 8] = 0
        body = build_frame(0x11, 0x0101, bytes(payload), MeasurementBatch.CRC_EXTRA)
        if 0 not in body[-2:]:
            return cobs_encode(body) + DELIMITER
    raise AssertionError(f"no batch with a run of {run}")


def _message_vectors() -> Iterator[Vector]:
    examples: list[tuple[str, Message]] = [
        ("hello", Hello(1)),
        ("info", Info(1, 2, 3, 4, 2, 0x3F, 0x0123456789ABCDEF)),
        (
            "measurement",
            Measurement(1_234_567_890, 0xAABBCCDDEEFF, 2437, 6, 1, 0, 1234, (-47, -53, None, None)),
        ),
        (
            "measurement_extremes",
            Measurement(2**64 - 1, 0xFFFFFFFFFFFF, 65535, 255, 255, 255, 4095, (127, -127, 0, -1)),
        ),
        ("measurement_all_zero", Measurement(0, 0, 0, 0, 0, 0, 0, (None, None, None, None))),
        (
            "measurement_no_seq",
            Measurement(5, 0x020000000001, 2402, 37, 8, 2, None, (-90, None, None, None)),
        ),
        ("batch_empty", MeasurementBatch(())),
        (
            "batch_three",
            MeasurementBatch(
                tuple(
                    Measurement(
                        1000 + 17 * i,
                        0x001122334455 + i,
                        5180,
                        36,
                        6,
                        i,
                        i,
                        (-60 - i, -66 + i, None, None),
                    )
                    for i in range(3)
                )
            ),
        ),
        ("set_channel", SetChannel(2412)),
        ("set_scan_plan", SetScanPlan(100, (2412, 2437, 2462, 5180))),
        ("set_scan_plan_empty", SetScanPlan(50, ())),
        ("start", Start()),
        ("stop", Stop()),
        ("heartbeat", Heartbeat(10_000_000, 123456, 7, 3, 64, 1, 2437)),
        ("ack", Ack(513, 0x21)),
        ("nak", Nak(514, 0x20, 3, 9999)),
        ("error_report", ErrorReport(2, 0xDEADBEEF, "radio 1 PLL unlock")),
        ("error_report_no_text", ErrorReport(1, 5, "")),
        ("time_sync_request", TimeSyncRequest(1_700_000_000_123_456_789)),
        ("time_sync", TimeSync(1_700_000_000_123_456_789, 99_000_001, 99_000_042)),
    ]
    for i, (name, msg) in enumerate(examples):
        yield Vector(f"msg_{name}", f"{type(msg).__name__} round trip", encode(msg, 7 + i))


def _edge_vectors() -> Iterator[Vector]:
    meas = Measurement(42, 0x112233445566, 2412, 1, 2, 0, 77, (-40, -45, None, None))
    good = encode(meas, 100)
    body = build_frame(Measurement.TYPE, 100, meas.pack(), Measurement.CRC_EXTRA)

    yield Vector("cobs_run_254", "254 non-zero bytes then a zero", _batch_with_run(254, False))
    yield Vector("cobs_run_255", "255 non-zero bytes then a zero", _batch_with_run(255, False))
    yield Vector(
        "cobs_run_254_at_end",
        "frame ends with exactly 254 non-zero bytes (no trailing empty block)",
        _batch_with_run(254, True),
    )
    yield Vector(
        "cobs_zeros_in_data",
        "measurement full of zero bytes",
        encode(Measurement(0, 0, 0, 0, 0, 0, 0, (0, 0, 0, 0)), 0),
    )
    # non-canonical encoding: an explicit empty block after a final 0xFF block
    run = _batch_with_run(254, True)[:-1]
    yield Vector(
        "cobs_noncanonical_trailing_block",
        "a final 0xFF block followed by an empty block decodes the same",
        run + b"\x01" + DELIMITER,
    )

    bad = bytearray(body)
    bad[-1] ^= 0x01
    yield Vector("crc_wrong", "last CRC bit flipped", cobs_encode(bytes(bad)) + DELIMITER)
    bad = bytearray(body)
    bad[10] ^= 0x80
    yield Vector(
        "crc_payload_bit_flip", "one payload bit flipped", cobs_encode(bytes(bad)) + DELIMITER
    )
    other_seed = crc16(body[:-2], crc_start(Measurement.CRC_EXTRA ^ 0x01)).to_bytes(2, "big")
    yield Vector(
        "crc_wrong_seed",
        "CRC computed with another type's seed: a layout mismatch is caught",
        cobs_encode(body[:-2] + other_seed) + DELIMITER,
    )
    yield Vector(
        "flag_incompatible_unknown",
        "valid CRC, unknown incompatible flag 0x01: dropped",
        _raw(0x10, 100, meas.pack(), Measurement.CRC_EXTRA, incompat=0x01),
    )
    yield Vector(
        "flag_compatible_unknown",
        "valid CRC, unknown compatible flag 0x80: ignored",
        _raw(0x10, 100, meas.pack(), Measurement.CRC_EXTRA, compat=0x80),
    )
    yield Vector(
        "type_unknown",
        "well-formed frame of unknown type 0x7e: counted and skipped, next frame decodes",
        _raw(0x7E, 5, b"\x01\x02\x03", 0x00) + encode(meas, 6),
    )
    yield Vector(
        "magic_wrong",
        "first byte is not 0xD1",
        cobs_encode(bytes([0xD2]) + body[1:]) + DELIMITER,
    )
    yield Vector(
        "length_mismatch",
        "length field says 26, payload has 25 bytes",
        cobs_encode(body[:6] + (26).to_bytes(2, "little") + body[8:]) + DELIMITER,
    )
    yield Vector("truncated_frame", "last 5 bytes before the delimiter lost", good[:-6] + DELIMITER)
    yield Vector("truncated_short", "only 6 bytes of a frame", good[:6] + DELIMITER)
    yield Vector("truncated_at_end", "input ends inside a frame", good + good[:20])
    yield Vector(
        "short_frame",
        "valid COBS, but 3 bytes are fewer than header + CRC",
        cobs_encode(bytes([MAGIC, 0, 0])) + DELIMITER,
    )
    yield Vector(
        "cobs_bad_code", "a COBS code byte points past the delimiter", b"\x09\x01\x02" + DELIMITER
    )
    fake = bytes([0x05, MAGIC, 0x11, 0x22, MAGIC, 0x33, 0x44])
    yield Vector(
        "garbage_fake_start",
        "garbage with fake frame starts (code byte + magic) glued to a frame, no delimiter",
        fake + good,
    )
    yield Vector(
        "garbage_with_delimiters",
        "garbage containing zero bytes between two frames",
        good + b"\x13\x37\x00\xd1\x00\xfe\xfe" + encode(meas, 101),
    )
    yield Vector(
        "empty_segments", "repeated delimiters are idle, not errors", b"\x00\x00" + good + b"\x00"
    )
    yield Vector(
        "payload_too_short",
        "valid CRC but HELLO has no payload: the payload is rejected",
        _raw(Hello.TYPE, 3, b"", Hello.CRC_EXTRA),
    )
    yield Vector(
        "payload_newer_sender",
        "INFO with 4 appended bytes from a newer version: extra bytes ignored",
        _raw(Info.TYPE, 4, Info(1, 9, 0, 0, 2, 1, 77).pack() + b"\x01\x02\x03\x04", Info.CRC_EXTRA),
    )
    yield Vector(
        "sequence_gap",
        "frames 200, 201, 205: the receiver counts 3 lost",
        encode(meas, 200) + encode(meas, 201) + encode(meas, 205),
    )


def all_vectors() -> list[Vector]:
    """Every vector with its expectations filled in."""
    vectors = [*_message_vectors(), *_edge_vectors()]
    for v in vectors:
        v.expect = expectations(v.wire)
    return vectors


def format_vectors(vectors: list[Vector]) -> str:
    """The text of the vector file."""
    lines = [
        "# rfsas DF-board protocol v1 test vectors. Generated by",
        "# `python -m rfsas_hw.board.vectors`; do not edit by hand.",
        "# Format: see rfsas_hw/board/vectors.py and firmware_protocol/SPEC.md.",
    ]
    for v in vectors:
        lines += ["", f"vector {v.name}", f"note {v.note}", f"wire {v.wire.hex()}"]
        lines += [f"expect {e}" for e in v.expect]
        lines.append("end")
    return "\n".join(lines) + "\n"


def parse_vectors(text: str) -> list[Vector]:
    """Read a vector file back.

    Raises:
        ValueError: a line does not fit the format (its number is in the message).
    """
    out: list[Vector] = []
    cur: Vector | None = None
    handlers: dict[str, Callable[[Vector, str], None]] = {
        "note": lambda v, rest: setattr(v, "note", rest),
        "wire": lambda v, rest: setattr(v, "wire", bytes.fromhex(rest)),
        "expect": lambda v, rest: v.expect.append(rest),
    }
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        key, _, rest = line.partition(" ")
        if key == "vector":
            cur = Vector(rest, "", b"")
        elif key == "end" and cur is not None:
            out.append(cur)
            cur = None
        elif key in handlers and cur is not None:
            handlers[key](cur, rest)
        else:
            raise ValueError(f"vector file line {lineno}: unexpected {line[:40]!r}")
    if cur is not None:
        raise ValueError(f"vector {cur.name!r} has no 'end'")
    return out


def main(argv: list[str] | None = None) -> int:
    """Write the vector file named by the first argument (or print it)."""
    args = sys.argv[1:] if argv is None else argv
    text = format_vectors(all_vectors())
    if args:
        Path(args[0]).write_text(text, encoding="ascii")
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
