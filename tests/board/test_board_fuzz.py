"""Fuzzing the board stream decoder with mutated streams.

Each case is a mutated stream of up to 30 frames, so ``RFSAS_FUZZ_CASES``
counts frames: the test runs one stream per 50 of them, at least 200
(``make fuzz`` sets 1,000,000: 20,000 streams, a few minutes). Nothing may
raise; every non-delimiter byte must be accounted for (delivered in a frame,
discarded, or still buffered); the records of ``feed_columns`` must be those
of the measurement frames ``feed`` delivers.
"""

from __future__ import annotations

import os
import random
from collections.abc import Sequence

import numpy as np
import pytest
from bytefuzz import Mutation, delete, duplicate, flip_bits, insert, mutate, set_byte

from rfsas_hw.board import codec
from rfsas_hw.board.columns import is_measurement, records
from rfsas_hw.board.messages import (
    Ack,
    Heartbeat,
    Info,
    Measurement,
    MeasurementBatch,
    TimeSync,
)
from rfsas_hw.board.reader import FrameDecoder

CASES = max(200, int(os.environ.get("RFSAS_FUZZ_CASES", "0")) // 50)
SEED = int(os.environ.get("RFSAS_FUZZ_SEED", "20261122"))


def _seed_stream(rng: random.Random) -> bytes:
    enc = codec.Encoder(first_seq=rng.randrange(65536))
    out = [enc.encode(Info(1, 1, 0, 0, 2, 0x3F, 42))]
    for i in range(rng.randint(3, 30)):
        m = Measurement(
            i * 997, rng.getrandbits(48), 2437, 6, 1, 0, i, (-40 - i % 30, -50, None, None)
        )
        pick = rng.random()
        if pick < 0.7:
            out.append(enc.encode(m))
        elif pick < 0.8:
            out.append(enc.encode(MeasurementBatch((m,) * rng.randint(0, 5))))
        elif pick < 0.9:
            out.append(enc.encode(Heartbeat(i, i, 0, 1, 64, 1, 2437)))
        else:
            out.append(enc.encode(rng.choice([Ack(i, 0x22), TimeSync(i, i, i)])))
    return b"".join(out)


def fake_magic(rng: random.Random, d: bytes, _: Sequence[bytes]) -> bytes:
    """One to five frame-start bytes inserted: false frame starts to resynchronise on."""
    pos = rng.randrange(len(d) + 1)
    return d[:pos] + b"\xd1" * rng.randint(1, 5) + d[pos:]


MUTATIONS: list[Mutation] = [flip_bits] * 3 + [delete] * 2 + [insert] * 2
MUTATIONS += [set_byte(header=1 << 30, values=b"\x00"), duplicate, fake_magic]


@pytest.mark.fuzz
def test_mutated_streams_never_crash_and_every_byte_is_accounted_for() -> None:
    rng = random.Random(SEED)
    for case in range(CASES):
        stream = mutate(rng, _seed_stream(rng), MUTATIONS, rounds=range(1, 9))
        chunk = rng.choice([5, 64, 5000])
        slow, col = FrameDecoder(), FrameDecoder()
        delivered = 0
        slow_recs, col_recs = [], []
        for i in range(0, len(stream), chunk):
            piece = stream[i : i + chunk]
            frames = slow.feed(piece)
            delivered += sum(len(raw) - 1 for raw, _ in frames)
            ok = [f for _, f in frames if is_measurement(f)]
            good = []
            for f in ok:
                try:
                    records([f])
                except Exception:  # a short payload is counted by feed_columns
                    continue
                good.append(f)
            slow_recs.append(records(good))
            col_recs.append(col.feed_columns(piece)[0])
        nonzero = len(stream) - stream.count(0)
        assert delivered + slow.stats.discarded_bytes + len(slow._buf) == nonzero, f"case {case}"
        assert slow.stats.frames == col.stats.frames, f"case {case}"
        assert np.concatenate(slow_recs).tobytes() == np.concatenate(col_recs).tobytes()
        slow.flush()
        assert delivered + slow.stats.discarded_bytes == nonzero
