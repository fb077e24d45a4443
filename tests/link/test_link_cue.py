"""The cue message (type 3): golden vector, round trips, and every rejection counted."""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from linkhelp import NOW_NS, SCHEDULE, key

from rfsas_hw.errors import LinkError
from rfsas_hw.link import Signer, TrustedKeys
from rfsas_hw.link.cue import (
    CUE_FIXED_BYTES,
    Band,
    Cue,
    CueKind,
    Phy,
    band_of,
    decode_cue,
    encode_cue_body,
    sign_cue,
)
from rfsas_hw.link.cue_receiver import CueReceiver, CueReceiverConfig
from rfsas_hw.link.message import MessageFormatError
from rfsas_hw.link.preauth import PreauthKeys
from rfsas_hw.link.signing import verify
from rfsas_hw.privacy.hashing import NonceUnavailableError

GOLDEN = Path(__file__).parent.parent / "data" / "link_cue_v1_bearing.bin"
T_GEN_US = (NOW_NS - 20_000_000) // 1000


def cue(**changes: object) -> Cue:
    base = Cue(
        sender_id="rsu-1",
        t_gen_us=T_GEN_US,
        seq=42,
        epoch=SCHEDULE.epoch_of(NOW_NS),
        emitter=0x8BADF00DDEADBEEF,
        t_obs_us=T_GEN_US - 5000,
        valid_until_us=T_GEN_US - 5000 + 2_000_000,
        channel=11,
        band=Band.WIFI_2G4,
        phy=Phy.HT,
        kind=CueKind.BEARING,
        risk=0.75,
        x_m=10.0,
        y_m=-20.0,
        a=123.5,
        b=2.5,
        c=0.0,
    )
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


def receiver(trust: TrustedKeys, **cfg: float) -> CueReceiver:
    config = CueReceiverConfig(epoch_s=SCHEDULE.epoch_s, grace_s=SCHEDULE.grace_s, **cfg)
    return CueReceiver(trust, config, position=lambda: (0.0, 0.0))


def test_golden_cue_reads_field_by_field(signer: Signer) -> None:
    raw = GOLDEN.read_bytes()
    assert len(raw) == CUE_FIXED_BYTES + 5 == 149
    assert raw[:6] == b"RF\x01\x03\x00\x05" and raw[6:11] == b"rsu-1"
    t_gen, seq, epoch, emitter = struct.unpack_from(">qIQQ", raw, 11)
    assert (t_gen, seq, epoch, emitter) == (T_GEN_US, 42, 29396667, 0x8BADF00DDEADBEEF)
    t_obs, valid_until, channel = struct.unpack_from(">qqH", raw, 39)
    assert (t_obs, valid_until, channel) == (T_GEN_US - 5000, T_GEN_US + 1_995_000, 11)
    assert raw[57:61] == bytes([1, 2, 1, 0])  # band 2.4 GHz, PHY HT, kind bearing, reserved
    assert struct.unpack_from(">6f", raw, 61) == (0.75, 10.0, -20.0, 123.5, 2.5, 0.0)
    assert decode_cue(raw) == cue()
    assert encode_cue_body(cue()) == raw[:-64]
    assert verify(signer.public_key, raw[:-64], raw[-64:])


@given(
    seq=st.integers(0, 2**32 - 1),
    emitter=st.integers(0, 2**64 - 1),
    channel=st.integers(1, 0x7FFF),
    risk=st.floats(0.0, 1.0, width=32),
    az=st.floats(0.0, 359.875, width=32),
    sigma=st.floats(0.0625, 90.0, width=32),
)
def test_round_trip(
    seq: int, emitter: int, channel: int, risk: float, az: float, sigma: float
) -> None:
    c = cue(seq=seq, emitter=emitter, channel=channel, risk=risk, a=az, b=sigma)
    s = Signer("rsu-1", key(0x1234))
    assert decode_cue(sign_cue(s, c)) == c


def test_fix_cue_round_trips_and_needs_a_covariance() -> None:
    s = Signer("backend", key(0x4321))
    c = cue(sender_id="backend", kind=CueKind.FIX, x_m=3.0, y_m=4.0, a=4.0, b=1.0, c=9.0)
    assert decode_cue(sign_cue(s, c)) == c
    with pytest.raises(LinkError, match="positive-definite"):
        sign_cue(s, dataclasses.replace(c, b=7.0))


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"risk": 1.5}, "risk"),
        ({"valid_until_us": T_GEN_US - 5000}, "validity"),
        ({"channel": 0}, "channel"),
        ({"a": 400.0}, "azimuth"),
        ({"x_m": float("nan")}, "finite"),
        ({"sender_id": "bad id!"}, "sender id"),
    ],
)
def test_bad_values_do_not_encode(changes: dict[str, object], match: str) -> None:
    with pytest.raises(LinkError, match=match):
        encode_cue_body(cue(**changes))


def test_band_of_channels() -> None:
    assert band_of(6) is Band.WIFI_2G4 and band_of(149) is Band.WIFI_5G
    assert band_of(37, "ble") is Band.BLE
    with pytest.raises(LinkError):
        band_of(20)


def test_structural_damage_is_named() -> None:
    raw = GOLDEN.read_bytes()
    cases = {
        "truncated": raw[:-1],
        "oversized": raw + b"\x00",
        "bad_magic": b"XX" + raw[2:],
        "bad_version": raw[:2] + b"\x09" + raw[3:],
        "bad_type": raw[:3] + b"\x01" + raw[4:],
        "malformed": raw[:4] + b"\x01" + raw[5:],
    }
    for reason, data in cases.items():
        with pytest.raises(MessageFormatError) as info:
            decode_cue(data)
        assert info.value.reason == reason


def test_receiver_accepts_a_good_cue_once_and_counts_each_rejection(
    signer: Signer, trust: TrustedKeys
) -> None:
    rx = receiver(trust)
    good = sign_cue(signer, cue())
    assert rx.feed(good, NOW_NS) == cue()
    # replayed: the very same datagram again
    assert rx.feed(good, NOW_NS + 1_000_000) is None
    # forged: signed by a key that is not rsu-1's
    forged = sign_cue(Signer("rsu-1", key(0x5555)), cue(seq=43))
    assert rx.feed(forged, NOW_NS) is None
    # altered after signing: channel 11 → 12
    altered = bytearray(sign_cue(signer, cue(seq=44)))
    altered[56] = 12
    assert rx.feed(bytes(altered), NOW_NS) is None
    # expired: its validity ended before it arrived (though freshly generated)
    late = cue(seq=45, t_obs_us=T_GEN_US - 3_000_000, valid_until_us=T_GEN_US - 1)
    assert rx.feed(sign_cue(signer, late), NOW_NS) is None
    # wrong epoch: hashed with a nonce the vehicle does not hold now
    assert rx.feed(sign_cue(signer, cue(seq=46, epoch=12)), NOW_NS) is None
    # stale and from an unknown unit
    assert rx.feed(sign_cue(signer, cue(seq=47, t_gen_us=T_GEN_US - 5_000_000)), NOW_NS) is None
    assert rx.feed(sign_cue(Signer("rsu-x", key(0x77)), cue(sender_id="rsu-x")), NOW_NS) is None
    # too far: the cueing unit is 5 km from this vehicle
    assert rx.feed(sign_cue(signer, cue(seq=48, x_m=5000.0)), NOW_NS) is None
    assert rx.stats.accepted == 1 and rx.stats.datagrams == 9
    assert dict(rx.stats.rejected) == {
        "replay": 1,
        "bad_signature": 2,
        "expired": 1,
        "wrong_epoch": 1,
        "stale": 1,
        "unknown_sender": 1,
        "too_far": 1,
    }


def test_receiver_never_raises_on_junk(trust: TrustedKeys) -> None:
    rx = receiver(trust)
    for junk in (b"", b"RF", b"RF\x01\x03\x00\x00", bytes(149), GOLDEN.read_bytes()[:80]):
        assert rx.feed(junk, NOW_NS) is None
    assert rx.stats.accepted == 0 and sum(rx.stats.rejected.values()) == 5


class _Nonces:
    def __init__(self, epoch: int) -> None:
        self.epoch = epoch

    def nonce_for(self, epoch: int) -> bytes:
        if epoch != self.epoch:
            raise NonceUnavailableError(f"no nonce for epoch {epoch}")
        return bytes(range(32))


def test_version_2_cue_is_tagged_and_the_tag_is_checked_first(
    signer: Signer, trust: TrustedKeys
) -> None:
    epoch = SCHEDULE.epoch_of(NOW_NS)
    keys = PreauthKeys(_Nonces(epoch))
    pk = keys.key_for("rsu-1", epoch)
    assert pk is not None
    raw = sign_cue(signer, cue(), pk)
    assert raw[2] == 2 and len(raw) == CUE_FIXED_BYTES + 5 + 8
    assert decode_cue(raw) == cue()
    rx = CueReceiver(
        trust, CueReceiverConfig(epoch_s=SCHEDULE.epoch_s, grace_s=SCHEDULE.grace_s), preauth=keys
    )
    assert rx.feed(raw, NOW_NS) == cue()
    # an outsider without the nonce: wrong tag, rejected before the signature
    outsider = sign_cue(signer, cue(seq=50), bytes(32))
    assert rx.feed(outsider, NOW_NS) is None
    # stripping the tag and the version byte breaks the signature, which covers the version
    stripped = bytearray(raw[:-8])
    stripped[2] = 1
    assert rx.feed(bytes(stripped), NOW_NS) is None
    # a receiver without the epoch's nonce cannot check the tag
    blind = CueReceiver(trust, CueReceiverConfig(epoch_s=SCHEDULE.epoch_s))
    assert blind.feed(sign_cue(signer, cue(seq=51), pk), NOW_NS) is None
    assert dict(rx.stats.rejected) == {"bad_preauth": 1, "bad_signature": 1}
    assert dict(blind.stats.rejected) == {"no_preauth_key": 1}


def test_the_header_times_are_judged_before_the_tag_and_the_signature(
    signer: Signer, trust: TrustedKeys, monkeypatch: pytest.MonkeyPatch
) -> None:
    import rfsas_hw.link.cue_receiver as module

    verified: list[bytes] = []

    def counting_verify(key: object, body: bytes, signature: bytes) -> bool:
        verified.append(body)
        return verify(key, body, signature)  # type: ignore[arg-type]

    monkeypatch.setattr(module, "verify", counting_verify)
    epoch = SCHEDULE.epoch_of(NOW_NS)
    keys = PreauthKeys(_Nonces(epoch))
    pk = keys.key_for("rsu-1", epoch)
    rx = CueReceiver(
        trust, CueReceiverConfig(epoch_s=SCHEDULE.epoch_s, grace_s=SCHEDULE.grace_s), preauth=keys
    )
    old = cue(seq=60, t_gen_us=T_GEN_US - 5_000_000)
    ahead = cue(seq=61, t_gen_us=T_GEN_US + 1_000_000)
    forged_and_old = sign_cue(
        Signer("rsu-1", key(0x5555)), cue(seq=62, t_gen_us=T_GEN_US - 5_000_000), pk
    )
    other_epoch = cue(seq=63, epoch=epoch + 7)
    for datagram in (sign_cue(signer, old, pk), sign_cue(signer, ahead, pk), forged_and_old):
        assert rx.feed(datagram, NOW_NS) is None
    assert rx.feed(sign_cue(signer, other_epoch), NOW_NS) is None
    # refused from the header alone: no signature was checked
    assert verified == []
    assert dict(rx.stats.rejected) == {"stale": 2, "future": 1, "wrong_epoch": 1}
    # refusals leave the replay window alone: the good cue of a refused number still enters
    assert rx.feed(sign_cue(signer, cue(seq=60), pk), NOW_NS) == cue(seq=60)
    assert len(verified) == 1
