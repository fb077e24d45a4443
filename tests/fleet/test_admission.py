"""The receiver's one admission path on a corpus of valid, forged, tampered, replayed,
mis-topicked, stale, version-1 and malformed datagrams: each accepted or refused for
its reason; and the batch receive deciding as one at a time."""

from __future__ import annotations

import os
import random
import struct
import sys
from pathlib import Path
from typing import Any

import pytest
from cryptography.hazmat.primitives.asymmetric.utils import encode_dss_signature

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "link"))

from linkhelp import NOW_NS, SCHEDULE, key, message

from rfsas_hw.link import Receiver, ReceiverConfig, Signer, TrustedKeys
from rfsas_hw.link.message import SIGNATURE_BYTES, VERSION_PREAUTH, encode_body
from rfsas_hw.link.preauth import PreauthKeys, TagKey, derive_key, make_tag, seal
from rfsas_hw.link.signing import der_signature
from rfsas_hw.link.transport import Transport
from rfsas_hw.privacy.hashing import FixedNonce

NONCE = bytes(range(32))
S1 = Signer("rsu-1", key(0x1234))
S2 = Signer("rsu-2", key(0x2222))
OUTSIDER = Signer("rsu-9", key(0x9999))
T1 = "rfsas/v1/bearing/rsu-1/0/1/2"


def sealed(signer: Signer, seq: int, **kw: object) -> bytes:
    msg = message(signer.sender_id, seq=seq, **kw)  # type: ignore[arg-type]
    return seal(signer, msg, derive_key(NONCE, signer.sender_id))


def hand_made(signer: Signer, seq: int, edit: int, value: int) -> bytes:
    """A version-2 message with one header byte changed, then signed and tagged
    properly: only the structural checks can refuse it."""
    body = bytearray(encode_body(message(signer.sender_id, seq=seq), VERSION_PREAUTH))
    body[edit] = value
    signed = bytes(body) + signer.sign(bytes(body))
    return signed + make_tag(derive_key(NONCE, signer.sender_id), signed)


def corpus() -> list[tuple[bytes, str | None]]:
    good = [sealed(S1, seq) for seq in range(1, 6)]
    sig_at = len(good[0]) - 8 - SIGNATURE_BYTES
    bad_sig = bytearray(sealed(S1, 40)[:-8])
    bad_sig[sig_at + 5] ^= 0x40
    insider = bytes(bad_sig) + make_tag(derive_key(NONCE, "rsu-1"), bytes(bad_sig))
    tampered = bytearray(good[1])
    tampered[30] ^= 1
    items: list[tuple[bytes, str | None]] = [(m, T1) for m in good]
    items += [
        (sealed(S2, 1), "rfsas/v1/bearing/rsu-2/0"),
        (good[0], T1),  # an exact copy: replay before the signature
        (sealed(S1, 2, t_gen_ns=NOW_NS - 30_000_000), T1),  # same seq, new bytes: replay after
        (good[2][:-8] + os.urandom(8), T1),  # an outsider's tag
        (insider, T1),  # right tag, wrong signature
        (bytes(tampered), T1),
        (sealed(S1, 20), "rfsas/v1/bearing/rsu-2/0/1"),  # topic names another sender
        (sealed(S1, 21), "rfsas/v1/bearing/rsu-1"),
        (sealed(S1, 22), "rfsas/v1/advisory/0/1"),
        (sealed(S1, 23), None),
        (sealed(S1, 24, t_gen_ns=NOW_NS - 5_000_000_000), T1),  # stale
        (sealed(S1, 25, t_gen_ns=NOW_NS + 1_000_000_000), T1),  # future
        (sealed(S1, 26, n=20), T1),  # the vectorised decoder
        (S1.encode(message("rsu-1", seq=27)), T1),  # version 1
        (hand_made(S1, 28, 4, 1), T1),  # reserved flags set
        (hand_made(S1, 29, 0, ord("X")), T1),  # bad magic
        (sealed(OUTSIDER, 1), "rfsas/v1/bearing/rsu-9/0"),  # not enrolled
        (sealed(S1, 30, epoch=SCHEDULE.epoch_of(NOW_NS) + 10), T1),  # wrong epoch
        (good[3][:-1], T1),  # truncated
        (good[3] + b"\0", T1),  # padded
        (b"RF\x01\x02" + os.urandom(40), None),  # a nonce envelope nobody expects
        (os.urandom(120), T1),
    ]
    items += [(sealed(S2, seq), "rfsas/v1/bearing/rsu-2/3") for seq in range(2, 12)]
    return items


def receiver(transport: Transport | None = None, **cfg: object) -> Receiver:
    config = ReceiverConfig(epoch_s=SCHEDULE.epoch_s, grace_s=SCHEDULE.grace_s, **cfg)  # type: ignore[arg-type]
    trust = TrustedKeys({"rsu-1": S1.public_key, "rsu-2": S2.public_key})
    rx = Receiver(
        trust,
        config=config,
        clock=lambda: NOW_NS,
        preauth=PreauthKeys(FixedNonce(NONCE)),
        transport=transport,
    )
    return rx


def outcome(
    rx: Receiver, items: list[tuple[bytes, str | None]]
) -> tuple[list[object], dict[str, int]]:
    accepted = []
    for datagram, topic in items:
        got = rx.feed_from(datagram, topic, NOW_NS)
        if got is not None:
            accepted.append((got.sender_id, got.message.seq, got.bearings.emitter.tolist()))
    return accepted, rx.stats.as_dict()


@pytest.mark.parametrize(
    "cfg",
    [
        {},
        {"accept_v1": False},
        {"sender_burst": 8.0, "sender_rate_hz": 1e-3},
        {"check_epoch": False},
    ],
)
def test_every_datagram_is_decided_with_its_reason(cfg: dict[str, object]) -> None:
    accepted, stats = outcome(receiver(**cfg), corpus())
    seqs = sorted((sender, seq) for sender, seq, _ in accepted)  # type: ignore[misc]
    # the valid ones, those without a topic or on a topic that names no other sensor,
    # the long one (vectorised decoder) and rsu-2's; version 1 only where it is read,
    # the wrong epoch only where epochs are not checked
    want = [("rsu-1", s) for s in (1, 2, 3, 4, 5, 21, 22, 23, 26)]
    want += [("rsu-2", s) for s in range(1, 12)]
    if cfg.get("accept_v1", True):
        want.append(("rsu-1", 27))
    if not cfg.get("check_epoch", True):
        want.append(("rsu-1", 30))
    if "sender_burst" in cfg:
        assert stats["rejected.rate_limited"] > 0
        assert set(seqs) < set(want)  # the budget of 8 ran out on the way
    else:
        assert seqs == sorted(want)
    reasons = {k.removeprefix("rejected.") for k in stats if k.startswith("rejected.")}
    assert {"replay", "bad_preauth", "bad_signature", "topic_mismatch", "malformed"} <= reasons
    assert {"bad_magic", "unknown_sender", "truncated", "oversized", "nonce_unexpected"} <= reasons
    if cfg.get("check_epoch", True) and "sender_burst" not in cfg:
        assert {"stale", "future", "wrong_epoch"} <= reasons
    if cfg.get("accept_v1") is False:
        assert "v1_refused" in reasons


class Queued(Transport):
    """Hands out a fixed list of datagrams."""

    def __init__(self, items: list[tuple[bytes, str | None]]) -> None:
        self.items = list(items)

    def send(self, datagram: bytes) -> None:
        raise AssertionError("receive only")

    def recv(self, timeout: float | None = None) -> bytes | None:
        got = self.recv_from(timeout)
        return None if got is None else got[0]

    def recv_from(self, timeout: float | None = None) -> tuple[bytes, str | None] | None:
        return self.items.pop(0) if self.items else None

    def close(self) -> None:
        pass


def batch_corpus() -> list[tuple[bytes, str | None]]:
    """The corpus, copies of some of its messages later in the same run (of a
    verified one, a forged one, a stale one), and enough more for several runs."""
    items = corpus()
    items += [items[0], items[9], items[15], items[0]]
    items += [(sealed(S2, seq), "rfsas/v1/bearing/rsu-2/3") for seq in range(100, 190)]
    items += [items[-1], items[3]]
    return items


@pytest.mark.parametrize(
    "cfg", [{}, {"accept_v1": False}, {"sender_burst": 30.0, "sender_rate_hz": 1e-3}]
)
def test_batch_receive_decides_as_one_at_a_time(cfg: dict[str, object]) -> None:
    items = batch_corpus()
    batched = receiver(Queued(items), **cfg)
    one_by_one = receiver(**cfg)
    a = [(v.sender_id, v.message.seq) for v in batched.receive(0, max_datagrams=len(items))]
    b = [(v.sender_id, v.message.seq) for d, t in items if (v := one_by_one.feed_from(d, t))]
    assert a == b and a
    assert batched.stats.as_dict() == one_by_one.stats.as_dict()
    assert batched.stats.rejected["replay"] >= 4


def test_overload_sheds_signature_checks_and_keeps_the_newest() -> None:
    items = batch_corpus()
    rx = receiver(Queued(items), backlog=4, shed_after_s=0.0)
    got = rx.receive(0, max_datagrams=len(items))
    assert rx.stats.rejected["overload"] > 0
    # the newest datagram (a late copy of rsu-1's fourth) is always checked in full
    assert [(v.sender_id, v.message.seq) for v in got] == [("rsu-1", 4)]


def test_recv_many_takes_at_most_the_limit_in_order() -> None:
    items = [(bytes([k]), None) for k in range(5)]
    q = Queued(items)
    assert q.recv_many(0, limit=3) == items[:3]
    assert q.recv_many(0) == items[3:]
    assert q.recv_many(0) == []


@pytest.mark.parametrize("size", [0, 1, 32, 64])
def test_prepared_tag_key_gives_the_hmac_tags(size: int) -> None:
    key = os.urandom(size)
    prepared = TagKey(key)
    for n in (0, 1, 55, 64, 200):
        data = os.urandom(n)
        tagged = data + make_tag(key, data)
        assert prepared.tag_ok(tagged)
        assert not prepared.tag_ok(tagged[:-1] + bytes([tagged[-1] ^ 1]))
    with pytest.raises(ValueError):
        TagKey(bytes(65))


def test_hand_made_helper_edits_only_the_named_byte() -> None:
    made = hand_made(S1, 3, 4, 1)
    assert struct.unpack_from(">2sBBB", made) == (b"RF", VERSION_PREAUTH, 1, 1)


def test_der_signature_is_the_library_encoding() -> None:
    rng = random.Random(7)
    cases = [bytes(rng.getrandbits(8) for _ in range(64)) for _ in range(3000)]
    for first_r, first_s in ((0x00, 0x00), (0x00, 0x80), (0x80, 0x00), (0x7F, 0xFF), (0x01, 0x80)):
        base = bytearray(rng.getrandbits(8) for _ in range(64))
        base[0], base[32] = first_r, first_s
        cases.append(bytes(base))
    cases += [
        bytes(64),
        bytes(32) + b"\1" * 32,
        b"\1" * 32 + bytes(32),
        bytes(31) + b"\x80" + b"\xff" * 32,
    ]
    for sig in cases:
        r, s = int.from_bytes(sig[:32], "big"), int.from_bytes(sig[32:], "big")
        want = None if r == 0 or s == 0 else encode_dss_signature(r, s)
        assert der_signature(sig) == want, sig.hex()


def test_copies_in_one_batch_cost_no_signature_check(monkeypatch: pytest.MonkeyPatch) -> None:
    import rfsas_hw.link.receiver as receiver_module

    checks = {"n": 0}
    real = receiver_module.verify

    def counting(*args: Any) -> bool:
        checks["n"] += 1
        return real(*args)

    monkeypatch.setattr(receiver_module, "verify", counting)
    forged = bytearray(sealed(S1, 41)[:-8])
    forged[-3] ^= 1
    insider = bytes(forged) + make_tag(derive_key(NONCE, "rsu-1"), bytes(forged))
    items = [(sealed(S1, 40), T1)] * 30 + [(insider, T1)] * 3
    rx = receiver(Queued(items))
    assert len(rx.receive(0)) == 1
    # one check for the valid message (its copies are replays), one per forged copy
    assert checks["n"] == 1 + 3
    # the copies of the valid one are replays; a forged message is never recorded,
    # so each of its copies meets the signature check and fails it
    assert rx.stats.rejected == {"replay": 29, "bad_signature": 3}
