"""Receiver: every kind of bad datagram is rejected, counted by reason, and never raises."""

from __future__ import annotations

import os

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric import ec
from linkhelp import NOW_NS, SCHEDULE, key, message

from rfsas_hw.link import (
    REASONS,
    Receiver,
    ReceiverConfig,
    SafetyMessage,
    Signer,
    TrustedKeys,
)
from rfsas_hw.link.replay import ReplayGuard
from rfsas_hw.records import Pose

MS = 1_000_000


def rx(trust: TrustedKeys, **config: object) -> Receiver:
    return Receiver(trust, config=ReceiverConfig(**config), clock=lambda: NOW_NS)  # type: ignore[arg-type]


def only_reason(receiver: Receiver) -> str:
    (reason,) = receiver.stats.rejected
    return reason


def test_valid_message_is_verified_with_its_age(signer: Signer, trust: TrustedKeys) -> None:
    r = rx(trust)
    got = r.feed(signer.encode(message(t_gen_ns=NOW_NS - 30 * MS)), NOW_NS)
    assert got is not None
    assert got.sender_id == "rsu-1" and len(got.bearings) == 3
    assert got.age_s == pytest.approx(0.030)
    assert r.stats.verified == 1 and r.stats.rejected_total == 0
    assert r.stats.as_dict()["bearings"] == 3


def test_forged_signature(signer: Signer, trust: TrustedKeys) -> None:
    raw = signer.encode(message())
    r = rx(trust)
    assert r.feed(raw[:-64] + os.urandom(64), NOW_NS) is None
    assert r.feed(raw[:-64] + bytes(64), NOW_NS) is None  # r = s = 0
    assert r.feed(raw[:-64] + b"\xff" * 64, NOW_NS) is None  # r, s >= curve order
    assert r.stats.rejected == {"bad_signature": 3}


def test_wrong_key_for_an_enrolled_sender(trust: TrustedKeys) -> None:
    impostor = Signer("rsu-1", key(0xBAD))
    r = rx(trust)
    assert r.feed(impostor.encode(message()), NOW_NS) is None
    assert only_reason(r) == "bad_signature"


def test_unknown_sender(trust: TrustedKeys) -> None:
    stranger = Signer("rsu-77", key(77))
    r = rx(trust)
    assert r.feed(stranger.encode(message("rsu-77")), NOW_NS) is None
    assert r.stats.rejected == {"unknown_sender": 1}


def test_every_modified_byte_is_rejected(signer: Signer, trust: TrustedKeys) -> None:
    raw = signer.encode(message(n=2))
    r = rx(trust)
    assert r.feed(raw, NOW_NS) is not None
    fresh = rx(trust)
    for pos in range(len(raw)):
        for flip in (0x01, 0x80, 0xFF):
            bad = bytearray(raw)
            bad[pos] ^= flip
            assert fresh.feed(bytes(bad), NOW_NS) is None, (pos, flip)
    assert fresh.stats.verified == 0
    assert fresh.stats.rejected_total == 3 * len(raw)
    assert set(fresh.stats.rejected) <= set(REASONS) - {"internal_error"}
    assert fresh.stats.rejected["bad_signature"] > 0


def test_replayed_message_is_rejected_once_seen(signer: Signer, trust: TrustedKeys) -> None:
    r = rx(trust)
    raw = signer.encode(message(seq=10))
    assert r.feed(raw, NOW_NS) is not None
    assert r.feed(raw, NOW_NS + 5 * MS) is None
    # another message with the same sequence number is a replay too
    assert r.feed(signer.encode(message(seq=10, seed=3)), NOW_NS + 6 * MS) is None
    assert r.stats.rejected == {"replay": 2}
    # out-of-order delivery of a new sequence number is fine
    assert r.feed(signer.encode(message(seq=9, t_gen_ns=NOW_NS - 40 * MS)), NOW_NS) is not None


def test_replay_after_the_window_is_stale_not_accepted(signer: Signer, trust: TrustedKeys) -> None:
    r = rx(trust, max_age_s=0.5)
    raw = signer.encode(message(t_gen_ns=NOW_NS - 10 * MS))
    assert r.feed(raw, NOW_NS) is not None
    assert r.feed(raw, NOW_NS + 600 * MS) is None
    assert r.stats.rejected == {"stale": 1}


def test_stale_and_future(signer: Signer, trust: TrustedKeys) -> None:
    r = rx(trust, max_age_s=1.0, max_future_s=0.2)
    assert r.feed(signer.encode(message(t_gen_ns=NOW_NS - 1001 * MS, seq=1)), NOW_NS) is None
    assert r.feed(signer.encode(message(t_gen_ns=NOW_NS + 201 * MS, seq=2)), NOW_NS) is None
    assert r.stats.rejected == {"stale": 1, "future": 1}
    # inside the skew allowance: accepted, with a negative age
    got = r.feed(signer.encode(message(t_gen_ns=NOW_NS + 150 * MS, seq=3)), NOW_NS)
    assert got is not None and got.age_s == pytest.approx(-0.150)


def test_too_far_only_when_the_receiver_knows_where_it_is(
    signer: Signer, trust: TrustedKeys
) -> None:
    far = signer.encode(message(pose=Pose(3000.0, 0.0, 0.0), seq=1))
    here: list[tuple[float, float] | None] = [(0.0, 0.0)]
    r = Receiver(trust, config=ReceiverConfig(max_range_m=2000.0), position=lambda: here[0])
    assert r.feed(far, NOW_NS) is None
    assert r.stats.rejected == {"too_far": 1}
    here[0] = (1500.0, 0.0)
    assert r.feed(far, NOW_NS) is not None
    here[0] = None
    assert r.feed(signer.encode(message(pose=Pose(9e6, 0.0, 0.0), seq=2)), NOW_NS) is not None


def test_epoch_outside_the_grace_window_is_rejected(signer: Signer, trust: TrustedKeys) -> None:
    k = SCHEDULE.epoch_of(NOW_NS)
    r = rx(trust)
    assert r.feed(signer.encode(message(epoch=k - 1, seq=1)), NOW_NS) is None
    assert r.stats.rejected == {"wrong_epoch": 1}
    # a bearing captured in another epoch than the message names
    msg = message(seq=2)
    msg.bearings.t_ns[0] = SCHEDULE.start_ns(k) - 1
    assert r.feed(signer.encode(msg), NOW_NS) is None
    assert r.stats.rejected == {"wrong_epoch": 2}
    # just after a boundary the previous epoch is still accepted (grace)
    boundary = SCHEDULE.start_ns(k)
    late = message(t_gen_ns=boundary - 50 * MS, seq=3)
    assert late.epoch == k - 1
    assert r.feed(signer.encode(late), boundary + 10 * MS) is not None
    # ... and not when the receiver does not check epochs at all
    off = rx(trust, check_epoch=False)
    assert off.feed(signer.encode(message(epoch=k - 1000, seq=4)), NOW_NS) is not None


@pytest.mark.parametrize(
    ("datagram", "reason"),
    [
        (b"", "truncated"),
        (b"R", "truncated"),
        (b"RF\x01", "truncated"),
        (b"GET / HTTP/1.1\r\n\r\n", "bad_magic"),
        (bytes(1473), "oversized"),
        (b"RF\x01\x01" + bytes(2000), "oversized"),
        (b"RF\x03\x01\x00\x05rsu-1" + bytes(100), "bad_version"),
        (b"RF\x01\x02" + bytes(80), "nonce_unexpected"),
    ],
)
def test_junk_datagrams(trust: TrustedKeys, datagram: bytes, reason: str) -> None:
    r = rx(trust)
    assert r.feed(datagram, NOW_NS) is None
    assert r.stats.rejected == {reason: 1}


def test_truncated_and_padded_signed_messages(signer: Signer, trust: TrustedKeys) -> None:
    raw = signer.encode(message())
    r = rx(trust)
    for cut in range(len(raw)):
        assert r.feed(raw[:cut], NOW_NS) is None
    assert r.feed(raw + b"\x00", NOW_NS) is None
    assert r.stats.rejected == {"truncated": len(raw), "oversized": 1}


class ExplodingTrust:
    def signing_key(self, sender_id: str) -> ec.EllipticCurvePublicKey | None:
        raise RuntimeError("trust store broke")


def test_a_failing_check_is_counted_not_raised(
    signer: Signer, caplog: pytest.LogCaptureFixture
) -> None:
    r = Receiver(ExplodingTrust())
    for _ in range(3):
        assert r.feed(signer.encode(message()), NOW_NS) is None
    assert r.stats.rejected == {"internal_error": 3}
    assert sum("receiver check failed" in rec.message for rec in caplog.records) == 1


def test_latency_is_watched_per_sender(signer: Signer, trust: TrustedKeys) -> None:
    r = rx(trust)
    for i in range(10):
        t_recv = NOW_NS + i * 100 * MS
        assert r.feed(signer.encode(message(seq=i, t_gen_ns=t_recv - 250 * MS)), t_recv)
    snap = r.latency.snapshot(NOW_NS + 1000 * MS)
    assert snap["rsu-1"].state.value == "late"
    assert snap["rsu-1"].p50_ms == pytest.approx(250.0)
    assert r.latency.alarm


def test_replay_guard_capacity_floor() -> None:
    guard = ReplayGuard(window_us=1_000_000, capacity=4)
    now = 10_000_000
    for seq in range(4):
        assert guard.check_and_record("s", seq, now - 100 + seq, now)
    assert guard.check_and_record("s", 4, now, now)
    assert guard.remembered("s") == 4
    # seq 0 was evicted; the floor keeps it from coming back
    assert not guard.check_and_record("s", 0, now - 100, now)
    assert not guard.check_and_record("s", 3, now - 97, now)
    # time moves on: everything old falls out of the window
    later = now + 2_000_000
    assert guard.check_and_record("s", 3, later - 5, later)
    assert guard.remembered("s") == 1


def test_receiver_drops_many_messages_from_many_senders(trust: TrustedKeys) -> None:
    keys = {f"s{i}": key(1000 + i) for i in range(5)}
    trust2 = TrustedKeys({k: v.public_key() for k, v in keys.items()})
    r = rx(trust2)
    signers = {k: Signer(k, v) for k, v in keys.items()}
    count = 0
    for seq in range(20):
        for name, s in signers.items():
            msg: SafetyMessage = message(name, seq=seq, t_gen_ns=NOW_NS - (seq + 1) * MS)
            assert r.feed(s.encode(msg), NOW_NS) is not None
            count += 1
    assert r.stats.verified == count
    assert sorted(r.latency.snapshot(NOW_NS)) == sorted(keys)


def test_decoded_bearings_are_what_was_sent(signer: Signer, trust: TrustedKeys) -> None:
    msg = message(n=5)
    got = rx(trust).feed(signer.encode(msg), NOW_NS)
    assert got is not None
    np.testing.assert_array_equal(got.bearings.emitter, msg.bearings.emitter)
    np.testing.assert_allclose(got.bearings.azimuth_deg, msg.bearings.azimuth_deg, atol=1e-4)
