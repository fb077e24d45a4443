"""Advisory messages (type 4): round trip, tampering, addressing, unknown backends."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "link"))

from cryptography.hazmat.primitives.asymmetric import ec
from linkhelp import key

from rfsas_hw.fleet.advisory import (
    ITEM_BYTES,
    AdvisoryItem,
    AdvisoryMessage,
    AdvisoryReceiver,
    decode_advisory,
    encode_advisory_body,
    sign_advisory,
)
from rfsas_hw.link import Signer
from rfsas_hw.link.message import MessageFormatError
from rfsas_hw.link.preauth import PreauthKeys, derive_key
from rfsas_hw.privacy.hashing import FixedNonce

NOW_NS = 1_763_800_030_000_000_000
ITEM_DTYPE = np.dtype(
    [("t_us", ">i8"), ("emitter", ">u8"), ("f", ">f4", (11,)), ("advisory", "u1"), ("flags", "u1")]
)
"""An advisory item on the wire, as docs/protocol.md lays it out."""
NAN = math.nan


def item(emitter: str = "0123456789abcdef", advisory: str = "brake") -> AdvisoryItem:
    return AdvisoryItem(
        NOW_NS - 5_000_000, emitter, 20.0, 30.0, 1.5, 0.125, 2.5, 1.0, -0.5,
        0.375, 0.015625, 1.75, 7.5, advisory, True, False,
    )  # fmt: skip


def message(vehicle: str = "car-7", seq: int = 1, n: int = 2) -> AdvisoryMessage:
    items = (item(), item("fedcba9876543210", "caution"))[:n]
    return AdvisoryMessage("be-a", NOW_NS // 1000 - 10_000, seq, 29_396_667, vehicle, items)


class Keys:
    def __init__(self, keys: dict[str, ec.EllipticCurvePublicKey]) -> None:
        self.keys = keys

    def backend_key(self, backend_id: str) -> ec.EllipticCurvePublicKey | None:
        return self.keys.get(backend_id)


@pytest.fixture
def signer() -> Signer:
    return Signer("be-a", key(0xBEA))


def receiver(signer: Signer, vehicle: str = "car-7", **kw: object) -> AdvisoryReceiver:
    return AdvisoryReceiver(
        Keys({"be-a": signer.public_key}),
        vehicle_id=vehicle,
        clock=lambda: NOW_NS,
        **kw,  # type: ignore[arg-type]
    )


def test_round_trip(signer: Signer) -> None:
    msg = message()
    raw = sign_advisory(signer, msg)
    assert len(raw) == 6 + 4 + 8 + 4 + 8 + 1 + 5 + 1 + 2 * ITEM_BYTES + 64
    back = decode_advisory(raw)
    assert back.vehicle_id == "car-7" and back.seq == 1
    assert back.items[0] == item() and back.items[1].advisory == "caution"
    rx = receiver(signer)
    assert rx.feed(raw) is not None
    assert rx.latest["0123456789abcdef"][0].advisory == "brake"


def test_rows_are_the_documented_layout_and_decode_as_plain_python_values() -> None:
    # the rows of every item in one call: the same bytes as the layout filled in field
    # by field; and what decodes is Python's own int, float, str and bool
    rng = np.random.default_rng(4)
    items = tuple(
        AdvisoryItem(
            NOW_NS - int(rng.integers(0, 10**9)),
            f"{int(rng.integers(0, 2**63)):016x}",
            *(float(v) for v in rng.normal(0.0, 50.0, 11)),
            str(rng.choice(["none", "clear", "caution", "brake"])),
            bool(rng.integers(2)),
            bool(rng.integers(2)),
        )
        for _ in range(7)
    )
    msg = AdvisoryMessage("be-a", NOW_NS // 1000, 3, 29_396_667, "car-7", items)
    ref = np.zeros(len(items), ITEM_DTYPE)
    for i, it in enumerate(items):
        ref[i]["t_us"] = it.t_ns // 1000
        ref[i]["emitter"] = int(it.emitter, 16)
        ref[i]["f"] = (
            it.x_m,
            it.y_m,
            it.cov_xx_m2,
            it.cov_xy_m2,
            it.cov_yy_m2,
            it.vx_mps,
            it.vy_mps,
            it.p_collision,
            it.risk,
            it.t_closest_s,
            it.impact_speed_mps,
        )
        ref[i]["advisory"] = ("none", "clear", "caution", "brake").index(it.advisory)
        ref[i]["flags"] = int(it.fix_ok) | int(it.link_alarm) << 1
    body = encode_advisory_body(msg)
    assert body.endswith(ref.tobytes())
    back = decode_advisory(body + bytes(64))
    for got, sent in zip(back.items, items, strict=True):
        assert type(got.t_ns) is int and type(got.x_m) is float and type(got.fix_ok) is bool
        assert got.emitter == sent.emitter and got.advisory == sent.advisory
        assert got.impact_speed_mps == float(np.float32(sent.impact_speed_mps))


def test_not_located_values_travel_as_nan(signer: Signer) -> None:
    unlocated = AdvisoryItem(
        NOW_NS, "00000000000000ff", NAN, NAN, NAN, NAN, NAN, NAN, NAN,
        NAN, NAN, NAN, NAN, "caution", False, True,
    )  # fmt: skip
    raw = sign_advisory(signer, AdvisoryMessage("be-a", NOW_NS // 1000, 2, 0, "", (unlocated,)))
    got = decode_advisory(raw).items[0]
    assert math.isnan(got.x_m) and got.link_alarm and not got.fix_ok


def test_rejections_are_named(signer: Signer) -> None:
    rx = receiver(signer)
    good = sign_advisory(signer, message())
    tampered = bytearray(good)
    tampered[40] ^= 1
    other_car = sign_advisory(signer, message("car-9", seq=2))
    impostor = sign_advisory(Signer("be-a", key(0xBAD)), message(seq=3))
    stranger = sign_advisory(Signer("be-x", key(0xBAD)), message(seq=4).__class__(
        "be-x", NOW_NS // 1000, 4, 0, "car-7", (item(),)
    ))  # fmt: skip
    for raw in (bytes(tampered), other_car, impostor, stranger, good, good, good[:-1]):
        rx.feed(raw)
    assert rx.stats.verified == 1
    assert rx.stats.rejected == {
        "bad_signature": 2,
        "not_for_us": 1,
        "unknown_sender": 1,
        "replay": 1,
        "truncated": 1,
    }


def test_pre_authenticated_advisories(signer: Signer) -> None:
    nonce = os.urandom(32)
    msg = message()
    raw = sign_advisory(signer, msg, derive_key(nonce, "be-a"))
    assert raw[2] == 2
    with_keys = receiver(signer, preauth=PreauthKeys(FixedNonce(nonce)))
    assert with_keys.feed(raw) is not None
    assert with_keys.feed(raw[:-8] + bytes(8)) is None
    without = receiver(signer)
    assert without.feed(raw) is None
    assert with_keys.stats.rejected == {"bad_preauth": 1}
    assert without.stats.rejected == {"no_preauth_key": 1}


def test_bad_messages_do_not_encode(signer: Signer) -> None:
    from rfsas_hw.errors import LinkError

    with pytest.raises(LinkError, match="1-20"):
        sign_advisory(signer, AdvisoryMessage("be-a", 0, 0, 0, "", ()))
    with pytest.raises(LinkError, match="cannot be signed"):
        sign_advisory(signer, AdvisoryMessage("be-b", 0, 0, 0, "", (item(),)))
    with pytest.raises(MessageFormatError):
        decode_advisory(b"RF\x01\x01\x00\x01a")
