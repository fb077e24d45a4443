"""Fuzz the receiver with mutated datagrams: every one is rejected and counted, none crash it.

The number of cases comes from ``RFSAS_FUZZ_CASES`` (default 100,000). Mutations
start from valid signed messages and nonce envelopes: bit flips, byte
overwrites, truncation, extension, insertion, deletion, header fields set to
edge values, splices of two datagrams, and plain random bytes.
"""

from __future__ import annotations

import os
import random
from collections import Counter
from collections.abc import Callable

import pytest
from cryptography.hazmat.primitives.asymmetric import x25519
from linkhelp import NOW_NS, key, message

from rfsas_hw.link import REASONS, Receiver, ReceiverConfig, Signer, TrustedKeys
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.privacy.nonces import NonceAuthority, NonceStore

CASES = int(os.environ.get("RFSAS_FUZZ_CASES", "100000"))

Mutation = Callable[[random.Random, bytearray, list[bytes]], bytearray]


def flip_bits(rng: random.Random, d: bytearray, _: list[bytes]) -> bytearray:
    for _i in range(rng.choice((1, 1, 2, 3, 8))):
        pos = rng.randrange(len(d))
        d[pos] ^= 1 << rng.randrange(8)
    return d


def set_byte(rng: random.Random, d: bytearray, _: list[bytes]) -> bytearray:
    # header bytes are where parsers go wrong: bias towards them
    pos = rng.randrange(min(len(d), 48)) if rng.random() < 0.6 else rng.randrange(len(d))
    d[pos] = rng.choice((0, 1, 0x7F, 0x80, 0xFF, rng.randrange(256)))
    return d


def truncate(rng: random.Random, d: bytearray, _: list[bytes]) -> bytearray:
    return d[: rng.randrange(len(d))]


def extend(rng: random.Random, d: bytearray, _: list[bytes]) -> bytearray:
    return d + rng.randbytes(rng.choice((1, 2, 30, 64, 1500, 3000)))


def insert(rng: random.Random, d: bytearray, _: list[bytes]) -> bytearray:
    pos = rng.randrange(len(d) + 1)
    return d[:pos] + rng.randbytes(rng.randint(1, 31)) + d[pos:]


def delete(rng: random.Random, d: bytearray, _: list[bytes]) -> bytearray:
    pos = rng.randrange(len(d))
    return d[:pos] + d[pos + rng.randint(1, 31) :]


def splice(rng: random.Random, d: bytearray, pool: list[bytes]) -> bytearray:
    other = rng.choice(pool)
    cut = rng.randrange(1, len(d))
    return d[:cut] + other[rng.randrange(len(other)) :]


def swap_signature(rng: random.Random, d: bytearray, pool: list[bytes]) -> bytearray:
    other = rng.choice(pool)
    return d[:-64] + bytearray(other[-64:])


def junk(rng: random.Random, d: bytearray, _: list[bytes]) -> bytearray:
    head = b"RF\x01" + bytes([rng.choice((1, 2))]) if rng.random() < 0.5 else b""
    return bytearray(head + rng.randbytes(rng.randrange(0, 400)))


MUTATIONS: list[Mutation] = [
    flip_bits,
    flip_bits,
    set_byte,
    set_byte,
    truncate,
    extend,
    insert,
    delete,
    splice,
    swap_signature,
    junk,
]


@pytest.mark.fuzz
def test_mutated_datagrams_are_all_rejected_and_counted() -> None:
    assert CASES > 0
    sched = EpochSchedule(60.0, 5.0)
    signers = [Signer("rsu-1", key(0x1234)), Signer("obu-9", key(0x9999))]
    trust = TrustedKeys({s.sender_id: s.public_key for s in signers})
    auth_key, my_key = x25519.X25519PrivateKey.generate(), x25519.X25519PrivateKey.generate()
    authority = NonceAuthority("rsu-0", auth_key, sched)
    authority.enroll("obu-9", my_key.public_key())
    store = NonceStore("obu-9", my_key, {"rsu-0": auth_key.public_key()}, sched, clock=None)
    rx = Receiver(trust, nonces=store, config=ReceiverConfig(max_age_s=5.0))
    pool: list[bytes] = []
    for i, n in enumerate((1, 2, 7, 20, 35)):
        s = signers[i % 2]
        pool.append(s.encode(message(s.sender_id, n=n, seq=i, seed=i)))
    pool.append(authority.seal("obu-9", sched.epoch_of(NOW_NS)))
    originals = set(pool)
    for d in pool:  # the originals are valid: the receiver is not rejecting everything
        rx.feed(d, NOW_NS)
    assert rx.stats.verified == len(pool) - 1 and rx.stats.nonces == 1

    rng = random.Random(20261122)
    fed = 0
    for _ in range(CASES):
        base = rng.choice(pool)
        mutated = bytes(rng.choice(MUTATIONS)(rng, bytearray(base), pool))
        if mutated in originals:
            continue
        assert rx.feed(mutated, NOW_NS) is None
        fed += 1
    stats = rx.stats
    assert fed > 0.95 * CASES
    assert stats.verified == len(pool) - 1, "a mutated datagram verified"
    assert stats.nonces == 1, "a mutated envelope was accepted"
    assert stats.rejected_total == fed
    assert stats.rejected["internal_error"] == 0
    assert set(stats.rejected) <= set(REASONS)
    # the mutations reach every stage: structure, sender, signature and envelope checks
    reached: Counter[str] = stats.rejected
    for reason in ("truncated", "oversized", "bad_magic", "malformed", "bad_signature"):
        assert reached[reason] > 0, reason
    assert reached["unknown_sender"] > 0 and reached["nonce_rejected"] > 0
