"""The receiver's order of checks: what only refuses runs before the signature (a message
too old costs no ECDSA verify), what changes state waits for it (replay window, latency
watch, the sender's budget of signature checks)."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest
from linkhelp import NOW_NS, SCHEDULE, Queued, message

import rfsas_hw.fleet.advisory as advisory_module
import rfsas_hw.link.receiver as receiver_module
from rfsas_hw.fleet.advisory import AdvisoryItem, AdvisoryMessage, AdvisoryReceiver, sign_advisory
from rfsas_hw.link import Receiver, ReceiverConfig, Signer, TrustedKeys
from rfsas_hw.link.preauth import PreauthKeys, derive_key, seal
from rfsas_hw.privacy.hashing import FixedNonce

MS = 1_000_000
NONCE = bytes(range(32))


class Verifies:
    """Counts the ECDSA verifies a module makes (wrapping the real one)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, module: object) -> None:
        self.calls = 0
        real = module.verify  # type: ignore[attr-defined]

        def counted(*args: object) -> bool:
            self.calls += 1
            return bool(real(*args))

        monkeypatch.setattr(module, "verify", counted)


def forged(raw: bytes) -> bytes:
    """``raw`` (version 1) with a random signature."""
    return raw[:-64] + os.urandom(64)


@pytest.fixture
def verifies(monkeypatch: pytest.MonkeyPatch) -> Iterator[Verifies]:
    yield Verifies(monkeypatch, receiver_module)


def test_a_stale_message_is_refused_without_a_verify(
    signer: Signer, trust: TrustedKeys, verifies: Verifies
) -> None:
    r = Receiver(trust, config=ReceiverConfig(max_age_s=1.0))
    old = message(t_gen_ns=NOW_NS - 1500 * MS, seq=1)
    assert r.feed(signer.encode(old), NOW_NS) is None
    assert (
        r.feed(forged(signer.encode(message(t_gen_ns=NOW_NS - 1500 * MS, seq=2))), NOW_NS) is None
    )
    assert r.feed(signer.encode(message(t_gen_ns=NOW_NS + 300 * MS, seq=3)), NOW_NS) is None
    # a forged message that is also too old: stale (refused before its signature)
    assert r.stats.rejected == {"stale": 2, "future": 1}
    assert verifies.calls == 0
    # a fresh one costs one verify and passes
    assert r.feed(signer.encode(message(seq=4)), NOW_NS) is not None
    assert verifies.calls == 1


def test_a_forged_fresh_message_is_still_a_bad_signature(
    signer: Signer, trust: TrustedKeys, verifies: Verifies
) -> None:
    r = Receiver(trust)
    assert r.feed(forged(signer.encode(message(seq=5))), NOW_NS) is None
    assert r.stats.rejected == {"bad_signature": 1}
    assert verifies.calls == 1


def test_a_message_of_an_epoch_over_is_refused_without_a_verify(
    signer: Signer, trust: TrustedKeys, verifies: Verifies
) -> None:
    # version 1 too: the header's epoch is read before the signature
    r = Receiver(trust)
    k = SCHEDULE.epoch_of(NOW_NS)
    assert r.feed(signer.encode(message(epoch=k - 1, seq=1)), NOW_NS) is None
    assert r.stats.rejected == {"wrong_epoch": 1}
    assert verifies.calls == 0


def test_refused_messages_leave_the_replay_window_and_the_watch_alone(
    signer: Signer, trust: TrustedKeys
) -> None:
    r = Receiver(trust)
    # refused before the signature (stale) and at it (forged): nothing remembered
    assert r.feed(signer.encode(message(t_gen_ns=NOW_NS - 2000 * MS, seq=9)), NOW_NS) is None
    assert r.feed(forged(signer.encode(message(seq=9))), NOW_NS) is None
    assert r.stats.rejected == {"stale": 1, "bad_signature": 1}
    assert r.replay.remembered("rsu-1") == 0
    assert r.latency.state("rsu-1") is None
    # so the genuine message with that sequence number is still taken, once
    genuine = signer.encode(message(seq=9))
    assert r.feed(genuine, NOW_NS) is not None
    assert r.replay.remembered("rsu-1") == 1
    assert r.feed(genuine, NOW_NS) is None
    assert r.stats.rejected["replay"] == 1


def test_stale_messages_spend_none_of_the_senders_budget(
    signer: Signer, trust: TrustedKeys, verifies: Verifies
) -> None:
    # a budget of one signature check, refilled once a thousand seconds
    r = Receiver(trust, config=ReceiverConfig(sender_rate_hz=0.001, sender_burst=1.0))
    for seq in range(10):
        old = message(t_gen_ns=NOW_NS - 1100 * MS, seq=seq)
        assert r.feed(forged(signer.encode(old)), NOW_NS) is None
    assert r.feed(signer.encode(message(seq=20)), NOW_NS) is not None
    assert r.feed(signer.encode(message(seq=21)), NOW_NS) is None
    assert r.stats.rejected == {"stale": 10, "rate_limited": 1}
    assert verifies.calls == 1


def test_version_2_stale_before_the_tag_and_in_batches(
    signer: Signer, trust: TrustedKeys, verifies: Verifies
) -> None:
    tag_key = derive_key(NONCE, "rsu-1")
    fresh = [seal(signer, message(seq=s), tag_key) for s in range(3)]
    old = [
        seal(signer, message(t_gen_ns=NOW_NS - 1200 * MS, seq=10 + s), tag_key) for s in range(3)
    ]
    # an outsider's message (wrong tag) that is too old as well
    outsider = seal(signer, message(t_gen_ns=NOW_NS - 1200 * MS, seq=20), os.urandom(32))
    r = Receiver(
        trust,
        config=ReceiverConfig(accept_v1=False),
        preauth=PreauthKeys(FixedNonce(NONCE)),
        transport=Queued([*old, *fresh, outsider]),
        clock=lambda: NOW_NS,
    )
    got = r.receive(0)
    assert [m.message.seq for m in got] == [0, 1, 2]
    assert r.stats.rejected == {"stale": 4}
    assert verifies.calls == 3


def _advisory(seq: int, t_gen_ns: int) -> AdvisoryMessage:
    it = AdvisoryItem(
        t_gen_ns, "0123456789abcdef", 20.0, 30.0, 1.5, 0.125, 2.5, 1.0, -0.5,
        0.375, 0.015625, 1.75, 7.5, "brake", True, False,
    )  # fmt: skip
    return AdvisoryMessage("rsu-1", t_gen_ns // 1000, seq, 29_396_667, "car-7", (it,))


class _BackendKeys:
    def __init__(self, signer: Signer) -> None:
        self.signer = signer

    def backend_key(self, backend_id: str) -> object:
        return self.signer.public_key if backend_id == self.signer.sender_id else None


def test_a_stale_advisory_is_refused_without_a_verify(
    signer: Signer, monkeypatch: pytest.MonkeyPatch
) -> None:
    verifies = Verifies(monkeypatch, advisory_module)
    rx = AdvisoryReceiver(_BackendKeys(signer), vehicle_id="car-7", clock=lambda: NOW_NS)  # type: ignore[arg-type]
    old = sign_advisory(signer, _advisory(1, NOW_NS - 1500 * MS))
    assert rx.feed(old) is None
    assert rx.feed(old[:-64] + os.urandom(64)) is None
    assert rx.stats.rejected == {"stale": 2}
    assert verifies.calls == 0
    # refused before the signature: the replay window holds nothing of it
    assert rx.replay.remembered("rsu-1") == 0
    fresh = sign_advisory(signer, _advisory(1, NOW_NS - 10 * MS))
    assert rx.feed(fresh) is not None
    assert rx.feed(fresh[:-64] + os.urandom(64)) is None  # an exact copy: replay, no verify
    assert rx.feed(sign_advisory(signer, _advisory(2, NOW_NS - 10 * MS))[:-64] + bytes(64)) is None
    assert rx.stats.rejected == {"stale": 2, "replay": 1, "bad_signature": 1}
    assert verifies.calls == 2
