"""Pre-authentication (version 2): forgeries cost one HMAC, not one ECDSA verify; old
messages are read or refused with a clear reason; per-sender budgets; exact copies."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "link"))

from linkhelp import NOW_NS, SCHEDULE, key, message

from rfsas_hw.link import Receiver, ReceiverConfig, Signer, TrustedKeys, decode
from rfsas_hw.link.message import PREAUTH_BYTES, VERSION_PREAUTH, peek
from rfsas_hw.link.preauth import PreauthKeys, RateLimiter, derive_key, seal, tag_ok
from rfsas_hw.privacy.hashing import FixedNonce

NONCE = bytes(range(32))


@pytest.fixture
def signer() -> Signer:
    return Signer("rsu-1", key(0x1234))


@pytest.fixture
def trust(signer: Signer) -> TrustedKeys:
    return TrustedKeys({"rsu-1": signer.public_key, "rsu-2": key(0x2222).public_key()})


def receiver(trust: TrustedKeys, nonce: bytes | None = NONCE, **cfg: object) -> Receiver:
    config = ReceiverConfig(epoch_s=SCHEDULE.epoch_s, grace_s=SCHEDULE.grace_s, **cfg)  # type: ignore[arg-type]
    keys = None if nonce is None else PreauthKeys(FixedNonce(nonce))
    return Receiver(trust, config=config, clock=lambda: NOW_NS, preauth=keys)


def v2(signer: Signer, seq: int = 7, nonce: bytes = NONCE) -> bytes:
    msg = message(seq=seq)
    return seal(signer, msg, derive_key(nonce, msg.sender_id))


def test_version_2_is_version_1_plus_a_tag(signer: Signer) -> None:
    msg = message()
    old, new = signer.encode(msg), v2(signer)
    assert len(new) == len(old) + PREAUTH_BYTES
    assert new[2] == VERSION_PREAUTH and new[3:-72] == old[3:-64]
    head = peek(new)
    assert head.preauth and head.sender_id == "rsu-1"
    assert decode(new).bearings.emitter.tolist() == msg.bearings.emitter.tolist()
    assert tag_ok(derive_key(NONCE, "rsu-1"), new)
    assert not tag_ok(derive_key(NONCE, "rsu-2"), new)  # keys are per sender


def test_valid_version_2_is_verified(signer: Signer, trust: TrustedKeys) -> None:
    r = receiver(trust, accept_v1=False)
    assert r.feed(v2(signer), NOW_NS) is not None
    assert r.stats.rejected_total == 0


def test_forged_tag_is_rejected_before_the_signature(signer: Signer, trust: TrustedKeys) -> None:
    r = receiver(trust)
    good = v2(signer)
    assert r.feed(good[:-8] + os.urandom(8), NOW_NS) is None
    # a tag made with another epoch's nonce (an outsider guessing) fails as well
    assert r.feed(v2(signer, seq=8, nonce=os.urandom(32)), NOW_NS) is None
    assert r.stats.rejected == {"bad_preauth": 2}
    assert r._verify_s == 0.0  # no signature was checked


def test_tag_cannot_be_stripped_to_pass_as_version_1(signer: Signer, trust: TrustedKeys) -> None:
    stripped = bytearray(v2(signer)[:-8])
    stripped[2] = 1  # the signature covers the version byte
    r = receiver(trust)
    assert r.feed(bytes(stripped), NOW_NS) is None
    assert r.stats.rejected == {"bad_signature": 1}


def test_version_1_is_read_or_refused_with_a_reason(signer: Signer, trust: TrustedKeys) -> None:
    old = signer.encode(message())
    assert receiver(trust).feed(old, NOW_NS) is not None
    strict = receiver(trust, accept_v1=False)
    assert strict.feed(old, NOW_NS) is None
    assert strict.stats.rejected == {"v1_refused": 1}


def test_without_the_epoch_nonce_the_tag_cannot_be_checked(
    signer: Signer, trust: TrustedKeys
) -> None:
    strict = receiver(trust, nonce=None, accept_v1=False)
    assert strict.feed(v2(signer), NOW_NS) is None
    assert strict.stats.rejected == {"no_preauth_key": 1}
    # a receiver that reads version 1 lets the signature decide, as for version 1
    lenient = receiver(trust, nonce=None)
    assert lenient.feed(v2(signer), NOW_NS) is not None
    assert lenient.feed(v2(signer, seq=9)[:-72] + bytes(72), NOW_NS) is None
    assert lenient.stats.rejected == {"bad_signature": 1}


def test_exact_copy_is_dropped_before_the_signature(signer: Signer, trust: TrustedKeys) -> None:
    r = receiver(trust)
    raw = v2(signer)
    assert r.feed(raw, NOW_NS) is not None
    spent = r._verify_s
    assert r.feed(raw, NOW_NS + 1000) is None
    assert r.stats.rejected == {"replay": 1}
    assert r._verify_s == spent


def test_per_sender_budget_of_signature_checks(signer: Signer, trust: TrustedKeys) -> None:
    r = receiver(trust, sender_rate_hz=1.0, sender_burst=3)
    forged = [signer.encode(message(seq=i))[:-64] + os.urandom(64) for i in range(10)]
    for d in forged:
        r.feed(d, NOW_NS)
    assert r.stats.rejected == {"bad_signature": 3, "rate_limited": 7}
    other = Signer("rsu-2", key(0x2222))
    assert r.feed(other.encode(message("rsu-2", seq=1)), NOW_NS) is not None


def test_token_bucket_refills() -> None:
    now = [0.0]
    limiter = RateLimiter(10.0, 2, lambda: now[0])
    assert [limiter.allow("a") for _ in range(3)] == [True, True, False]
    now[0] = 0.1
    assert limiter.allow("a") and not limiter.allow("a")
    assert limiter.allow("b")


def test_forged_tags_after_a_valid_message_are_refused_by_reason(
    signer: Signer, trust: TrustedKeys
) -> None:
    r = receiver(trust, accept_v1=False)
    assert r.feed(v2(signer, seq=1), NOW_NS) is not None  # the key of (rsu-1, epoch) is ready
    forged = v2(signer, seq=2)[:-8] + bytes(8)
    assert r.feed(forged, NOW_NS) is None
    assert r.feed(v2(signer, seq=3), NOW_NS) is not None
    # another epoch: refused for it, not for its tag
    other = bytearray(v2(signer, seq=4, nonce=NONCE))
    other[6 + 5 + 12 : 6 + 5 + 20] = (1).to_bytes(8, "big")
    r.feed(bytes(other), NOW_NS)
    r.feed(forged + b"x", NOW_NS)
    assert r.stats.rejected == {"bad_preauth": 1, "wrong_epoch": 1, "oversized": 1}
    assert r.stats.verified == 2
