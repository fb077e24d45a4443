"""Nonce authority and envelopes: only enrolled receivers obtain a nonce, and only theirs."""

from __future__ import annotations

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric import x25519

from rfsas_hw.link import Receiver, TrustedKeys
from rfsas_hw.privacy.epochs import NS_PER_S, EpochSchedule
from rfsas_hw.privacy.hashing import MacHasher, NonceProvider, NonceUnavailableError
from rfsas_hw.privacy.nonces import (
    NonceAuthority,
    NonceEnvelopeError,
    NonceStore,
    parse_envelope,
)

SCHED = EpochSchedule(60.0, 5.0)
NOW = 1_763_800_030 * NS_PER_S  # 30 s into an epoch
K = SCHED.epoch_of(NOW)


class Party:
    def __init__(self, name: str) -> None:
        self.name = name
        self.key = x25519.X25519PrivateKey.generate()
        self.pub = self.key.public_key()


World = tuple[NonceAuthority, Party, Party, Party]


@pytest.fixture
def world() -> tuple[NonceAuthority, Party, Party, Party]:
    auth_party = Party("rsu-0")
    authority = NonceAuthority("rsu-0", auth_party.key, SCHED)
    sensor, backend = Party("rsu-1"), Party("obu-1")
    authority.enroll(sensor.name, sensor.pub)
    authority.enroll(backend.name, backend.pub)
    return authority, auth_party, sensor, backend


def store_of(party: Party, auth: Party, clock: int | None = NOW) -> NonceStore:
    return NonceStore(
        party.name,
        party.key,
        {auth.name: auth.pub},
        SCHED,
        clock=None if clock is None else (lambda: clock),
    )


def test_enrolled_receivers_get_the_authoritys_nonce(world: World) -> None:
    authority, auth, sensor, backend = world
    stores = [store_of(sensor, auth), store_of(backend, auth)]
    for epoch in authority.due(NOW):
        for rid, env in authority.issue(epoch).items():
            store = stores[0] if rid == "rsu-1" else stores[1]
            assert store.accept_envelope(env, NOW) == epoch
    assert authority.due(NOW) == [K, K + 1]
    for store in stores:
        assert store.epochs == (K, K + 1)
        assert store.nonce_for(K) == authority.nonce_for(K)
        assert store.nonce_for(K + 1) == authority.nonce_for(K + 1)
    assert authority.nonce_for(K) != authority.nonce_for(K + 1)
    assert len(authority.nonce_for(K)) == 32
    # hashing with distributed nonces: the sensor, the backend and the authority agree
    macs = np.array([0x3C22FB000001, 0x3C22FB000002], np.uint64)
    t = np.full(2, NOW, np.int64)
    providers: list[NonceProvider] = [*stores, authority]
    ids = [MacHasher(p, epoch_s=60.0).hash_batch(macs, t) for p in providers]
    np.testing.assert_array_equal(ids[0], ids[1])
    np.testing.assert_array_equal(ids[0], ids[2])


def test_an_unregistered_party_gets_nothing(world: World) -> None:
    authority, auth, _sensor, _ = world
    stranger = Party("eve")
    with pytest.raises(NonceEnvelopeError, match="not enrolled"):
        authority.seal("eve", K)
    assert "eve" not in authority.issue(K)
    # eve overhears rsu-1's envelope: with her key it does not open, under any name
    env = authority.seal("rsu-1", K)
    as_eve = NonceStore("rsu-1", stranger.key, {auth.name: auth.pub}, SCHED, clock=None)
    with pytest.raises(NonceEnvelopeError, match="not authentic"):
        as_eve.accept_envelope(env, NOW)
    # nor by rewriting the receiver id to her own
    redirected = env.replace(b"\x05rsu-1", b"\x05eve-1")
    as_eve2 = NonceStore("eve-1", stranger.key, {auth.name: auth.pub}, SCHED, clock=None)
    with pytest.raises(NonceEnvelopeError, match="not authentic"):
        as_eve2.accept_envelope(redirected, NOW)
    with pytest.raises(NonceUnavailableError):
        as_eve.nonce_for(K)
    # once revoked, a receiver is given no further nonces
    authority.revoke("rsu-1")
    with pytest.raises(NonceEnvelopeError, match="not enrolled"):
        authority.seal("rsu-1", K + 1)


def test_envelope_for_another_receiver_is_refused(world: World) -> None:
    authority, auth, sensor, _backend = world
    with pytest.raises(NonceEnvelopeError, match="is for 'obu-1', not for us"):
        store_of(sensor, auth).accept_envelope(authority.seal("obu-1", K), NOW)


def test_an_impostor_authority_is_refused(world: World) -> None:
    _authority, auth, sensor, _ = world
    mallory = Party("rsu-0")  # claims the authority's id with her own key
    fake = NonceAuthority("rsu-0", mallory.key, SCHED)
    fake.enroll("rsu-1", sensor.pub)
    with pytest.raises(NonceEnvelopeError, match="not authentic"):
        store_of(sensor, auth).accept_envelope(fake.seal("rsu-1", K), NOW)
    other = NonceAuthority("rsu-9", mallory.key, SCHED)
    other.enroll("rsu-1", sensor.pub)
    with pytest.raises(NonceEnvelopeError, match="'rsu-9' is not enrolled"):
        store_of(sensor, auth).accept_envelope(other.seal("rsu-1", K), NOW)


def test_the_epoch_is_bound_in(world: World) -> None:
    authority, auth, sensor, _ = world
    env = bytearray(authority.seal("rsu-1", K))
    parsed = parse_envelope(bytes(env))
    at = len(parsed.associated) - 32 - 8
    env[at : at + 8] = (K + 1).to_bytes(8, "big")
    with pytest.raises(NonceEnvelopeError, match="not authentic"):
        store_of(sensor, auth).accept_envelope(bytes(env), NOW)


def test_every_modified_byte_is_refused(world: World) -> None:
    authority, auth, sensor, _ = world
    env = authority.seal("rsu-1", K)
    store = store_of(sensor, auth)
    for pos in range(len(env)):
        bad = bytearray(env)
        bad[pos] ^= 0x20
        with pytest.raises(NonceEnvelopeError):
            store.accept_envelope(bytes(bad), NOW)
    assert store.epochs == ()
    for cut in range(len(env)):
        with pytest.raises(NonceEnvelopeError):
            store.accept_envelope(env[:cut], NOW)
    with pytest.raises(NonceEnvelopeError):
        store.accept_envelope(env + b"\x00", NOW)
    assert store.accept_envelope(env, NOW) == K


def test_grace_period_on_the_receiving_side(world: World) -> None:
    authority, auth, sensor, _ = world
    t = [NOW]
    store = NonceStore(sensor.name, sensor.key, {auth.name: auth.pub}, SCHED, clock=lambda: t[0])
    store.accept_envelope(authority.seal("rsu-1", K), NOW)
    boundary = SCHED.start_ns(K + 1)
    t[0] = boundary + 4 * NS_PER_S  # inside the 5 s grace period
    assert store.nonce_for(K) == authority.nonce_for(K)
    t[0] = boundary + 5 * NS_PER_S
    with pytest.raises(NonceUnavailableError, match="expired"):
        store.nonce_for(K)
    # envelopes for epochs that are over, or far ahead, are not taken
    with pytest.raises(NonceEnvelopeError, match="is over"):
        store.accept_envelope(authority.seal("rsu-1", K - 1), NOW)
    with pytest.raises(NonceEnvelopeError, match="too far ahead"):
        store.accept_envelope(authority.seal("rsu-1", K + 3), NOW)
    store.accept_envelope(authority.seal("rsu-1", K + 2), NOW)
    store.prune(SCHED.start_ns(K + 3) + 5 * NS_PER_S)
    assert store.epochs == ()


def test_a_second_different_nonce_for_a_held_epoch_is_refused(world: World) -> None:
    authority, auth, sensor, _ = world
    store = store_of(sensor, auth)
    store.accept_envelope(authority.seal("rsu-1", K), NOW)
    store.accept_envelope(authority.seal("rsu-1", K), NOW)  # a resend is fine
    rival = NonceAuthority("rsu-0", auth.key, SCHED)  # same keys, its own random nonces
    rival.enroll("rsu-1", sensor.pub)
    with pytest.raises(NonceEnvelopeError, match="already held"):
        store.accept_envelope(rival.seal("rsu-1", K), NOW)


def test_low_order_receiver_key_is_refused(world: World) -> None:
    authority = world[0]
    authority.enroll("bad", x25519.X25519PublicKey.from_public_bytes(bytes(32)))
    with pytest.raises(NonceEnvelopeError, match="unusable public key"):
        authority.seal("bad", K)


def test_receiver_takes_envelopes_on_the_link_port(world: World) -> None:
    authority, auth, _, backend = world
    store = store_of(backend, auth)
    rx = Receiver(TrustedKeys(), nonces=store)
    assert rx.feed(authority.seal("obu-1", K), NOW) is None
    assert rx.stats.nonces == 1 and store.epochs == (K,)
    assert rx.feed(authority.seal("rsu-1", K), NOW) is None
    assert rx.stats.rejected == {"nonce_rejected": 1}
    # a receiver without a nonce store counts envelopes as unexpected
    bare = Receiver(TrustedKeys())
    assert bare.feed(authority.seal("obu-1", K), NOW) is None
    assert bare.stats.rejected == {"nonce_unexpected": 1}


def test_authority_keeps_a_bounded_number_of_epochs() -> None:
    draws: list[int] = []

    def counting(n: int) -> bytes:
        draws.append(n)
        return bytes([len(draws)]) * n

    authority = NonceAuthority(
        "a", x25519.X25519PrivateKey.generate(), SCHED, random_bytes=counting, keep_epochs=3
    )
    for epoch in range(10):
        authority.nonce_for(epoch)
    assert authority.nonce_for(9) == bytes([10]) * 32
    authority.nonce_for(0)  # forgotten: a fresh draw, never reused
    assert len(draws) == 11
