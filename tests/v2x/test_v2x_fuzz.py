"""Fuzz the CPM decoder with mutated messages: each one is either refused with a
CpmFormatError or decoded strictly (its bytes are the canonical encoding of what was
read); nothing else escapes.

The number of cases comes from ``RFSAS_FUZZ_CASES`` (default 1,000 here: a decode
costs about a millisecond). Mutations start from the golden vectors: bit flips, byte
overwrites, truncation, extension, insertion, deletion, splices and random bytes.
"""

from __future__ import annotations

import os
import random
from collections import Counter

import pytest
from bytefuzz import (
    Mutation,
    delete,
    extend,
    flip_bits,
    insert,
    junk,
    mutate,
    set_byte,
    splice,
    truncate,
)
from golden import GOLDEN_DIR

from rfsas_hw.errors import CpmFormatError
from rfsas_hw.v2x.codec import decode_cpm, encode_cpm

CASES = min(int(os.environ.get("RFSAS_FUZZ_CASES", "1000")), 200_000)

MUTATIONS: list[Mutation] = [flip_bits, flip_bits, set_byte(header=40), truncate, insert, delete]
MUTATIONS += [extend((1, 2, 30, 600)), splice, junk(heads=(b"\x02\x0e",), longest=300)]


@pytest.mark.fuzz
def test_mutated_cpms_are_refused_or_read_strictly() -> None:
    pool = [p.read_bytes() for p in sorted(GOLDEN_DIR.glob("*.uper"))]
    assert len(pool) >= 10
    rng = random.Random(20261127)
    outcome: Counter[str] = Counter()
    for _ in range(CASES):
        data = mutate(rng, rng.choice(pool), MUTATIONS, pool)
        try:
            cpm = decode_cpm(data)
        except CpmFormatError as err:
            assert str(err)
            outcome["refused"] += 1
            continue
        outcome["decoded"] += 1
        # what was read is a CPM this codec can write again
        encode_cpm(cpm)
    # most mutations break a CPM; some (a flipped bit in a value) leave a valid one
    assert outcome["refused"] > CASES // 2, outcome
    assert outcome["decoded"] > 0, outcome


@pytest.mark.fuzz
def test_mutated_geonetworking_frames_are_refused_or_read() -> None:
    from rfsas_hw.v2x.geonet import GeoPosition, ethernet_frame, split_datagram

    pool = [
        ethernet_frame(p.read_bytes(), 7, 15, 1_795_737_600 * 10**9, GeoPosition(52.2, 0.12))[14:]
        for p in sorted(GOLDEN_DIR.glob("*.uper"))
    ]
    rng = random.Random(4400)
    refused = 0
    for _ in range(max(CASES // 4, 50)):
        data = mutate(rng, rng.choice(pool), MUTATIONS[:-1], pool)
        try:
            decode_cpm(split_datagram(data, "fuzzed packet"))
        except CpmFormatError as err:
            assert str(err)
            refused += 1
    assert refused > 0
