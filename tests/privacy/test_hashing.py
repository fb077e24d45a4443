"""Keyed MAC hashing: same nonce → same ids, new epoch → unlinkable ids."""

from __future__ import annotations

import hashlib
import hmac
import os

import numpy as np
import pytest

from rfsas_hw.errors import DataFormatError
from rfsas_hw.privacy.epochs import NS_PER_S, EpochSchedule, epoch_of
from rfsas_hw.privacy.hashing import (
    FixedNonce,
    MacHasher,
    NonceUnavailableError,
    hash_mac,
)

EPOCH_S = 60.0
T0_NS = 1_700_000_040 * NS_PER_S  # start of an epoch of 60 s


class PerEpochNonces:
    """A fresh random nonce per epoch, as a nonce authority hands them out."""

    def __init__(self, seed: int = 0) -> None:
        self._rng = np.random.default_rng(seed)
        self._nonces: dict[int, bytes] = {}
        self.asked: list[int] = []

    def nonce_for(self, epoch: int) -> bytes:
        self.asked.append(epoch)
        if epoch not in self._nonces:
            self._nonces[epoch] = self._rng.bytes(32)
        return self._nonces[epoch]


def _macs(n: int, seed: int = 1) -> np.ndarray:
    # one vendor block (OUI 3c:22:fb) with random device parts
    rng = np.random.default_rng(seed)
    dev = rng.choice(1 << 24, size=n, replace=False).astype(np.uint64)
    return (np.uint64(0x3C22FB) << np.uint64(24)) | dev


def test_id_is_truncated_hmac_sha256_of_the_six_mac_bytes() -> None:
    nonce = bytes(range(32))
    mac = 0x3C22FB0102AB
    tag = hmac.new(nonce, bytes.fromhex("3c22fb0102ab"), hashlib.sha256).digest()
    assert hash_mac(nonce, mac) == int.from_bytes(tag[:8], "big")


def test_batch_matches_one_by_one_across_an_epoch_boundary() -> None:
    nonces = PerEpochNonces()
    hasher = MacHasher(nonces, epoch_s=EPOCH_S)
    macs = np.repeat(_macs(50), 3)
    t_ns = T0_NS + np.linspace(-30, 30, len(macs)).astype(np.int64) * NS_PER_S
    ids = hasher.hash_batch(macs, t_ns)
    for mac, t, got in zip(macs.tolist(), t_ns.tolist(), ids.tolist(), strict=True):
        assert got == hash_mac(nonces.nonce_for(epoch_of(t, EPOCH_S)), mac)
    assert {epoch_of(int(t), EPOCH_S) for t in t_ns} == {
        T0_NS // (60 * NS_PER_S) - 1,
        T0_NS // (60 * NS_PER_S),
    }


def test_two_sensors_with_the_same_nonce_give_the_same_ids() -> None:
    key = os.urandom(32)
    a = MacHasher(FixedNonce(key), epoch_s=EPOCH_S)
    b = MacHasher(FixedNonce(key), epoch_s=EPOCH_S)
    macs = _macs(200)
    t_a = np.full(200, T0_NS + 1_000, np.int64)
    # sensor b hears the same devices later in the epoch, in another order
    order = np.random.default_rng(3).permutation(200)
    t_b = np.full(200, T0_NS + 59 * NS_PER_S, np.int64)
    ids_a = a.hash_batch(macs, t_a)
    ids_b = b.hash_batch(macs[order], t_b)
    np.testing.assert_array_equal(ids_a[order], ids_b)


def test_sensors_with_different_nonces_do_not_agree() -> None:
    macs = _macs(200)
    t = np.full(200, T0_NS, np.int64)
    ids_a = MacHasher(FixedNonce(os.urandom(32))).hash_batch(macs, t)
    ids_b = MacHasher(FixedNonce(os.urandom(32))).hash_batch(macs, t)
    assert not set(ids_a.tolist()) & set(ids_b.tolist())


def _kendall_tau(x: np.ndarray, y: np.ndarray) -> float:
    n = len(x)
    sx = np.sign(np.subtract.outer(x.astype(np.float64), x.astype(np.float64)))
    sy = np.sign(np.subtract.outer(y.astype(np.float64), y.astype(np.float64)))
    return float((sx * sy).sum() / (n * (n - 1)))


def test_different_epochs_give_unrelated_ids() -> None:
    hasher = MacHasher(PerEpochNonces(), epoch_s=EPOCH_S)
    macs = _macs(1000)
    ids_1 = hasher.hash_batch(macs, np.full(1000, T0_NS, np.int64))
    ids_2 = hasher.hash_batch(macs, np.full(1000, T0_NS + 60 * NS_PER_S, np.int64))
    assert not set(ids_1.tolist()) & set(ids_2.tolist())
    # no order relation survives either: Kendall's tau of independent ranks has
    # sd sqrt(2(2n+5) / (9n(n-1))) ≈ 0.021 for n = 1000; 0.1 is about 5 sd
    assert abs(_kendall_tau(ids_1, ids_2)) < 0.1
    # the same relation under one nonce for every epoch is perfect
    fixed = MacHasher(FixedNonce(os.urandom(32)), epoch_s=EPOCH_S)
    same_1 = fixed.hash_batch(macs, np.full(1000, T0_NS, np.int64))
    same_2 = fixed.hash_batch(macs, np.full(1000, T0_NS + 60 * NS_PER_S, np.int64))
    assert _kendall_tau(same_1, same_2) == pytest.approx(1.0)


def test_a_party_without_the_nonce_cannot_link_ids_across_epochs() -> None:
    """An eavesdropper knows the vendor block (2^16 candidates here), the algorithm,
    and one epoch's ids; it tries to tell which later id belongs to which device."""
    nonces = PerEpochNonces(seed=7)
    hasher = MacHasher(nonces, epoch_s=EPOCH_S)
    candidates = (np.uint64(0x3C22FB) << np.uint64(24)) | np.arange(1 << 16, dtype=np.uint64)
    devices = candidates[np.random.default_rng(5).choice(1 << 16, 20, replace=False)]
    seen_1 = hasher.hash_batch(devices, np.full(20, T0_NS, np.int64))
    seen_2 = hasher.hash_batch(devices, np.full(20, T0_NS + 60 * NS_PER_S, np.int64))

    def dictionary(nonce: bytes) -> dict[int, int]:
        ids = MacHasher(FixedNonce(nonce)).hash_batch(
            candidates, np.zeros(len(candidates), np.int64)
        )
        return dict(zip(ids.tolist(), candidates.tolist(), strict=True))

    def linked(table: dict[int, int]) -> int:
        back_1 = [table.get(i) for i in seen_1.tolist()]
        back_2 = [table.get(i) for i in seen_2.tolist()]
        return sum(1 for a, b in zip(back_1, back_2, strict=True) if a is not None and a == b)

    # guesses an attacker could try: an all-zero key, a key of its own
    assert linked(dictionary(bytes(32))) == 0
    assert linked(dictionary(os.urandom(32))) == 0
    # holding one epoch's nonce reverses that epoch only, not the next
    table_1 = dictionary(nonces.nonce_for(epoch_of(T0_NS, EPOCH_S)))
    assert [table_1.get(i) for i in seen_1.tolist()] == devices.tolist()
    assert all(table_1.get(i) is None for i in seen_2.tolist())
    # the same attack with both nonces links every device: the test can fail
    table_2 = dictionary(nonces.nonce_for(epoch_of(T0_NS, EPOCH_S) + 1))
    assert linked({**table_1, **table_2}) == 20


def test_nonce_is_fetched_once_per_epoch_and_cache_is_bounded() -> None:
    nonces = PerEpochNonces()
    hasher = MacHasher(nonces, epoch_s=EPOCH_S, cache_size=10)
    macs = _macs(30)
    t = np.full(30, T0_NS, np.int64)
    first = hasher.hash_batch(macs, t)
    again = hasher.hash_batch(macs, t)
    np.testing.assert_array_equal(first, again)
    assert nonces.asked.count(epoch_of(T0_NS, EPOCH_S)) == 2  # 20 MACs did not fit the cache
    assert hasher.hash_one(int(macs[0]), T0_NS) == int(first[0])


def test_missing_nonce_raises_nonce_unavailable() -> None:
    class Nothing:
        def nonce_for(self, epoch: int) -> bytes:
            raise NonceUnavailableError(f"no nonce for epoch {epoch}")

    with pytest.raises(NonceUnavailableError, match="epoch"):
        MacHasher(Nothing()).hash_batch(_macs(2), np.full(2, T0_NS, np.int64))


def test_empty_batch() -> None:
    out = MacHasher(FixedNonce(bytes(16))).hash_batch(np.empty(0, np.uint64), np.empty(0, np.int64))
    assert out.shape == (0,) and out.dtype == np.uint64


def test_schedule_grace_window_at_the_boundary() -> None:
    sched = EpochSchedule(epoch_s=60.0, grace_s=5.0)
    k = sched.epoch_of(T0_NS)
    assert sched.accepted_epochs(T0_NS + 30 * NS_PER_S) == (k,)
    assert sched.accepted_epochs(T0_NS + 2 * NS_PER_S) == (k - 1, k)
    assert sched.accepted_epochs(T0_NS + 56 * NS_PER_S) == (k, k + 1)
    assert not sched.accepts(k - 1, T0_NS + 5 * NS_PER_S)
    assert sched.accepts(k - 1, T0_NS + 5 * NS_PER_S - 1)
    assert not sched.expired(k - 1, T0_NS + 5 * NS_PER_S - 1)
    assert sched.expired(k - 1, T0_NS + 5 * NS_PER_S)
    assert EpochSchedule(60.0, 0.0).accepted_epochs(T0_NS) == (k,)


@pytest.mark.parametrize(("epoch_s", "grace_s"), [(0.5, 0.0), (60.0, -1.0), (60.0, 30.0)])
def test_schedule_rejects_bad_lengths(epoch_s: float, grace_s: float) -> None:
    with pytest.raises(ValueError, match="must be"):
        EpochSchedule(epoch_s, grace_s)


def test_bad_inputs_are_named_without_echoing_the_mac() -> None:
    hasher = MacHasher(FixedNonce(bytes(16)))
    macs = np.array([1, 1 << 48 | 0xABCDEF], np.uint64)
    with pytest.raises(DataFormatError, match="row 1 does not fit 48 bits") as info:
        hasher.hash_batch(macs, np.zeros(2, np.int64))
    assert "abcdef" not in str(info.value).lower()
    with pytest.raises(DataFormatError, match="2 MACs but 1 capture times"):
        hasher.hash_batch(macs, np.zeros(1, np.int64))
