"""Write the tests/data/board_*.bin captures (deterministic; run from the repo root).

    python tests/board/make_board_data.py

Each file is a raw byte stream as a board sends it; the test that reads it
states what it proves.
"""

from __future__ import annotations

import random
from pathlib import Path

from rfsas_hw.board import codec, framing
from rfsas_hw.board.messages import Heartbeat, Info, Measurement, MeasurementBatch

DATA = Path(__file__).resolve().parents[1] / "data"


def _meas(rng: random.Random, i: int) -> Measurement:
    return Measurement(
        t_us=1_000_000 + 400 * i,
        mac=rng.choice([0x3C2EF9A1B2C3, 0xF8E4E3D2C1B0, 0x020000ABCDEF]),
        freq_mhz=2437,
        channel=6,
        kind=rng.choice([1, 2, 6, 7]),
        flags=0,
        frame_seq=i % 4096,
        rssi_dbm=(rng.randint(-90, -30), rng.randint(-90, -30), None, None),
    )


def clean(rng: random.Random) -> bytes:
    enc = codec.Encoder()
    out = [enc.encode(Info(1, 1, 0, 0, 2, 0x7F, 0xB0A4D5))]
    for i in range(200):
        out.append(enc.encode(_meas(rng, i)))
        if i % 50 == 0:
            out.append(enc.encode(Heartbeat(1_000_000 + 400 * i, i, 0, 1, 64, 1, 2437)))
    for b in range(5):
        batch = MeasurementBatch(tuple(_meas(rng, 1000 + 8 * b + k) for k in range(8)))
        out.append(enc.encode(batch))
    return b"".join(out)


def badcrc(rng: random.Random) -> bytes:
    out = []
    for i in range(100):
        m = _meas(rng, i)
        body = bytearray(framing.build_frame(m.TYPE, i, m.pack(), m.CRC_EXTRA))
        if i in (10, 50):
            body[-1] ^= 0x04
        out.append(framing.cobs_encode(bytes(body)) + b"\x00")
    return b"".join(out)


def garbage(rng: random.Random) -> bytes:
    out = []
    for i in range(50):
        # garbage with fake frame starts (a code byte followed by the magic)
        g = bytes(rng.choice([0x00, 0x05, 0xD1, rng.randint(1, 255)]) for _ in range(i % 9))
        out.append(g + codec.encode(_meas(rng, i), i))
    return b"".join(out)


def truncated(rng: random.Random) -> bytes:
    frames = [codec.encode(_meas(rng, i), i) for i in range(21)]
    return b"".join(frames[:20]) + frames[20][:17]


def unknown(rng: random.Random) -> bytes:
    m = _meas(rng, 0)
    return b"".join(
        [
            codec.encode(m, 0),
            framing.encode_frame(0x7E, 1, b"future message", 0x99),
            codec.encode(m, 2, compat=0x80),
            framing.encode_frame(m.TYPE, 3, m.pack(), m.CRC_EXTRA, incompat=0x04),
            codec.encode(m, 4),
        ]
    )


FILES = {
    "board_clean_stream.bin": clean,
    "board_badcrc.bin": badcrc,
    "board_garbage_resync.bin": garbage,
    "board_truncated.bin": truncated,
    "board_unknown_type_and_flags.bin": unknown,
}


def main() -> None:
    for name, make in FILES.items():
        (DATA / name).write_bytes(make(random.Random(name)))


if __name__ == "__main__":
    main()
