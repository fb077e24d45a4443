"""A sender whose every message is refused is no longer lost in silence: after a run
of refusals the receiver raises a per-sender alarm naming the cause (clock skew with
the offset measured, nonce mismatch, unenrolled), and clears it on the next verified
message."""

from __future__ import annotations

import logging

import pytest
from linkhelp import NOW_NS, SCHEDULE, key, message

from rfsas_hw.link import Receiver, ReceiverConfig, Signer, TrustedKeys
from rfsas_hw.link.preauth import PreauthKeys, derive_key, seal
from rfsas_hw.link.refusals import RefusalConfig, RefusalWatch
from rfsas_hw.privacy.hashing import FixedNonce

NONCE = bytes(range(32))
S1, S2, OUTSIDER = (Signer(i, key(k)) for i, k in (("rsu-1", 11), ("rsu-2", 22), ("rsu-9", 99)))


def receiver() -> Receiver:
    config = ReceiverConfig(
        epoch_s=SCHEDULE.epoch_s, grace_s=SCHEDULE.grace_s, refusals=RefusalConfig(run=10)
    )
    trust = TrustedKeys({"rsu-1": S1.public_key, "rsu-2": S2.public_key})
    return Receiver(
        trust, config=config, clock=lambda: NOW_NS, preauth=PreauthKeys(FixedNonce(NONCE))
    )


def sent(signer: Signer, seq: int, skew_ns: int = 0, nonce: bytes = NONCE) -> bytes:
    msg = message(signer.sender_id, seq=seq, t_gen_ns=NOW_NS - 20_000_000 + skew_ns)
    return seal(signer, msg, derive_key(nonce, signer.sender_id))


@pytest.mark.parametrize(
    ("skew_ms", "reason", "cause", "says"),
    [
        (300, "future", "clock skew", "its clock runs 280 ms ahead of"),
        # too old: a clock behind and a sender that sends late look the same
        (-1500, "stale", "late", "they arrive 1520 ms after their generation time"),
    ],
)
def test_clock_skew_and_lateness_are_named_with_the_offset(
    skew_ms: int, reason: str, cause: str, says: str, caplog: pytest.LogCaptureFixture
) -> None:
    rx = receiver()
    with caplog.at_level(logging.INFO, logger="rfsas_hw.link.refusals"):
        for seq in range(1, 10):
            assert rx.feed(sent(S1, seq, skew_ms * 1_000_000)) is None
        assert not rx.refusals.alarms and "rsu-1" not in caplog.text  # 9: not yet a run
        assert rx.feed(sent(S1, 10, skew_ms * 1_000_000)) is None
        alarm = rx.refusals.alarms["rsu-1"]
        assert alarm.cause == cause and alarm.reasons == {reason: 10}
        # generated 20 ms before the skew: the offset is measured, not configured
        assert alarm.offset_s == pytest.approx(skew_ms / 1e3 - 0.020, abs=1e-6)
        assert f"rsu-1: 10 messages in a row refused ({reason} 10): {cause}" in caplog.text
        assert says in caplog.text
        for seq in range(11, 30):
            rx.feed(sent(S1, seq, skew_ms * 1_000_000))
        assert caplog.text.count("in a row refused") == 1  # logged once per run
        assert rx.feed(sent(S1, 30)) is not None  # the clock is fixed
    assert not rx.refusals.alarms and "verified again after 29 refusals" in caplog.text


def test_nonce_mismatch_and_unenrolled_are_named(caplog: pytest.LogCaptureFixture) -> None:
    rx = receiver()
    with caplog.at_level(logging.WARNING, logger="rfsas_hw.link.refusals"):
        for seq in range(1, 11):
            rx.feed(sent(S2, seq, nonce=bytes(32)))  # tagged with another authority's nonce
            rx.feed(sent(OUTSIDER, seq))
            assert rx.feed(sent(S1, seq)) is not None  # the others are not affected
    alarms = rx.refusals.alarms
    assert set(alarms) == {"rsu-2", "rsu-9"}
    assert alarms["rsu-2"].cause == "nonce mismatch" and alarms["rsu-2"].reasons == {
        "bad_preauth": 10
    }
    assert alarms["rsu-9"].cause == "unenrolled" and alarms["rsu-9"].offset_s is None
    assert "rsu-2: 10 messages in a row refused (bad_preauth 10): nonce mismatch" in caplog.text
    assert "rsu-9: 10 messages in a row refused (unknown_sender 10): unenrolled" in caplog.text
    assert rx.stats.rejected == {"bad_preauth": 10, "unknown_sender": 10}


def test_a_verified_message_between_refusals_ends_the_run() -> None:
    rx = receiver()
    for seq in range(1, 40):
        rx.feed(sent(S1, seq, 300_000_000 if seq % 5 else 0))  # one in five is on time
    assert rx.stats.verified == 7 and rx.stats.rejected["future"] == 32
    assert not rx.refusals.alarms


def test_claimed_ids_are_bounded_and_alarm_logs_rate_limited(
    caplog: pytest.LogCaptureFixture,
) -> None:
    watch = RefusalWatch(RefusalConfig(run=1, max_senders=50, max_alarm_logs=5), clock=lambda: 0.0)
    with caplog.at_level(logging.WARNING, logger="rfsas_hw.link.refusals"):
        for i in range(200):
            watch.refused(f"fake-{i}", "unknown_sender")
    assert len(watch.alarms) == 50 and watch.alarms_raised == 200
    assert caplog.text.count("unenrolled") == 5
    watch.refused("rsu-1", "replay")  # not a reason the watch follows
    assert "rsu-1" not in watch.alarms


def test_config_is_checked() -> None:
    with pytest.raises(ValueError, match="run"):
        RefusalConfig(run=0)
