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
from collections.abc import Sequence

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
from cryptography.hazmat.primitives.asymmetric import x25519
from linkhelp import NOW_NS, key, message

from rfsas_hw.link import REASONS, Receiver, ReceiverConfig, Signer, TrustedKeys
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.privacy.nonces import NonceAuthority, NonceStore

CASES = int(os.environ.get("RFSAS_FUZZ_CASES", "100000"))


def swap_signature(rng: random.Random, d: bytes, pool: Sequence[bytes]) -> bytes:
    """Another datagram's 64-byte signature on this one's body."""
    return d[:-64] + rng.choice(pool)[-64:]


MUTATIONS: list[Mutation] = [
    flip_bits,
    flip_bits,
    set_byte(header=48),
    set_byte(header=48),
    truncate,
    extend((1, 2, 30, 64, 1500, 3000)),
    insert,
    delete,
    splice,
    swap_signature,
    junk(heads=(b"RF\x01\x01", b"RF\x01\x02")),
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
        mutated = mutate(rng, base, MUTATIONS, pool)
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
