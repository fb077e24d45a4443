"""Keyed hashing of MAC addresses: the only way from a raw MAC to an emitter id.

emitter id = first 8 bytes of HMAC-SHA256(nonce of the epoch, MAC as 6 bytes),
read big-endian as an unsigned 64-bit integer.

Why 64 bits: ids only need to be unique among the emitters heard in one epoch
by one deployment. With n = 10,000 emitters the birthday bound gives a
collision probability of n²/2⁶⁵ ≈ 3e-12 per epoch, while 8 bytes keep the
wire format and the numpy columns compact. Unlinkability does not depend on
the length: it comes from the secret, per-epoch nonce. Truncation also means
an id is not a full HMAC tag; nothing uses it as an authenticator.

Epoch numbering and the receiving side's grace period live in
:mod:`rfsas_hw.privacy.epochs`; where nonces come from in a deployment, in
:mod:`rfsas_hw.privacy.nonces`.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import stat
from collections import OrderedDict
from pathlib import Path
from typing import Protocol

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import DataFormatError, KeyStoreError, RfsasError
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, NS_PER_S, epoch_of
from rfsas_hw.records import MAC_MASK

__all__ = [
    "DEFAULT_EPOCH_S",
    "NS_PER_S",
    "FixedNonce",
    "MacHasher",
    "NonceExpiredError",
    "NonceProvider",
    "NonceUnavailableError",
    "epoch_of",
    "hash_mac",
]

ID_BYTES = 8
"""Length of an emitter id: the first 8 bytes of the HMAC-SHA256 tag."""


class NonceUnavailableError(RfsasError):
    """No nonce is known for the epoch a frame falls in (it may still arrive)."""


class NonceExpiredError(NonceUnavailableError):
    """The epoch's nonce is gone for good: the epoch and its grace period are over."""


class NonceProvider(Protocol):
    """Anything that knows the secret nonce of an epoch."""

    def nonce_for(self, epoch: int) -> bytes:
        """The nonce of ``epoch``.

        Raises:
            NonceUnavailableError: the epoch's nonce is not known here.
        """
        ...


def hash_mac(nonce: bytes, mac: int) -> int:
    """The 64-bit emitter id of one 48-bit MAC under ``nonce``."""
    return _hash_many(nonce, [int(mac)])[0]


def _hash_many(nonce: bytes, macs: list[int]) -> list[int]:
    """Emitter ids of 48-bit MACs: the first 8 bytes of HMAC-SHA256(nonce, MAC big-endian)."""
    # Keying HMAC costs two SHA-256 compressions; copying the keyed state
    # saves them for every MAC after the first.
    keyed = hmac.new(nonce, digestmod=hashlib.sha256)
    out = []
    for mac in macs:
        h = keyed.copy()
        h.update(mac.to_bytes(6, "big"))
        out.append(int.from_bytes(h.digest()[:ID_BYTES], "big"))
    return out


SMALL_BATCH = 8
"""Batches up to this size are looked up frame by frame (``hash_one``), not sorted.

Per batch of 1–8 cached MACs about 3–7 µs against 35–49 µs for the
``np.unique`` path (``bench/bench_small_batches.py``)."""


class MacHasher:
    """Vectorised MAC → emitter-id hashing with a per-epoch cache.

    Args:
        nonces: where the nonce of each epoch comes from.
        epoch_s: epoch length in seconds (every sensor of a deployment must agree).
        cache_epochs: how many epochs of (MAC → id) cache to keep.
        cache_size: most MACs cached per epoch; beyond it ids are computed, not stored,
            so a flood of random MACs cannot grow memory without bound.

    Raises:
        ValueError: on a non-positive epoch length.
    """

    def __init__(
        self,
        nonces: NonceProvider,
        epoch_s: float = DEFAULT_EPOCH_S,
        cache_epochs: int = 3,
        cache_size: int = 262_144,
    ) -> None:
        if epoch_s <= 0:
            raise ValueError(f"epoch length must be positive, got {epoch_s} s")
        self.nonces = nonces
        self.epoch_s = float(epoch_s)
        self._epoch_ns = int(self.epoch_s * NS_PER_S)
        self._cache: OrderedDict[int, dict[int, int]] = OrderedDict()
        self._cache_epochs = cache_epochs
        self._cache_size = cache_size

    @property
    def epoch_ns(self) -> int:
        """Epoch length, nanoseconds."""
        return self._epoch_ns

    def _table(self, epoch: int) -> dict[int, int]:
        table = self._cache.get(epoch)
        if table is None:
            table = {}
            self._cache[epoch] = table
            while len(self._cache) > self._cache_epochs:
                self._cache.popitem(last=False)
        return table

    def hash_one(self, mac: int, t_ns: int) -> int:
        """Emitter id of ``mac`` at time ``t_ns`` (UTC ns).

        Raises:
            NonceUnavailableError: no nonce for that epoch.
        """
        epoch = int(t_ns // self._epoch_ns)
        table = self._table(epoch)
        got = table.get(int(mac))
        if got is None:
            got = hash_mac(self.nonces.nonce_for(epoch), int(mac))
            if len(table) < self._cache_size:
                table[int(mac)] = got
        return got

    def hash_batch(
        self, macs: npt.NDArray[np.uint64], t_ns: npt.NDArray[np.int64]
    ) -> npt.NDArray[np.uint64]:
        """Emitter ids for arrays of MACs and capture times (same length).

        HMAC runs once per distinct (epoch, MAC); the rest is array indexing.

        Raises:
            NonceUnavailableError: no nonce for an epoch in the batch.
            DataFormatError: a MAC does not fit 48 bits, or the arrays differ in length.
        """
        n = len(macs)
        if n == 0:
            return np.empty(0, dtype=np.uint64)
        if len(t_ns) != n:
            raise DataFormatError(f"{n} MACs but {len(t_ns)} capture times")
        if n <= SMALL_BATCH:
            # a live sensor's few frames: sorting costs more than it saves
            mac_list = np.asarray(macs, dtype=np.uint64).tolist()
            for i, mac in enumerate(mac_list):
                if mac > MAC_MASK:
                    # the row, not the value: the value is (part of) a MAC
                    raise DataFormatError(f"MAC at row {i} does not fit 48 bits")
            hash_one = self.hash_one
            return np.array(
                [hash_one(mac, t) for mac, t in zip(mac_list, t_ns.tolist(), strict=True)],
                dtype=np.uint64,
            )
        out = np.empty(n, dtype=np.uint64)
        too_big = np.flatnonzero(np.asarray(macs, dtype=np.uint64) > np.uint64(MAC_MASK))
        if too_big.size:
            # the row, not the value: the value is (part of) a MAC
            raise DataFormatError(f"MAC at row {int(too_big[0])} does not fit 48 bits")
        epochs = np.asarray(t_ns, dtype=np.int64) // self._epoch_ns
        for epoch in np.unique(epochs):
            sel = epochs == epoch
            uniq, inverse = np.unique(np.asarray(macs)[sel], return_inverse=True)
            table = self._table(int(epoch))
            macs_u = uniq.tolist()
            got = [table.get(mac) for mac in macs_u]
            missing = [i for i, g in enumerate(got) if g is None]
            if missing:
                nonce = self.nonces.nonce_for(int(epoch))
                fresh = _hash_many(nonce, [macs_u[i] for i in missing])
                room = max(0, self._cache_size - len(table))
                for i, value in zip(missing, fresh, strict=True):
                    got[i] = value
                    if room:
                        table[macs_u[i]] = value
                        room -= 1
            out[sel] = np.array(got, dtype=np.uint64)[inverse.reshape(-1)]
        return out


class FixedNonce:
    """One nonce for every epoch: a per-run random key, or a fixed key for tests.

    Ids are then linkable across epochs by anyone who sees them; use an epoch
    nonce source for deployments.
    """

    def __init__(self, key: bytes) -> None:
        if len(key) < 16:
            raise ValueError("nonce must be at least 16 bytes")
        self._key = key

    def nonce_for(self, epoch: int) -> bytes:
        """The same key for every epoch."""
        return self._key


SECRET_MIN_BYTES = 16


class DerivedNonces:
    """Epoch nonces derived from one shared secret, for deployments without an authority.

    ``nonce(epoch) = HMAC-SHA256(secret, "rfsas-epoch-nonce" ‖ epoch as 8 bytes BE)``.
    Every sensor holding the secret derives the same ids; to anyone without
    it, ids of different epochs are unlinkable as with authority nonces. The
    difference: whoever obtains the secret can open every epoch, past and
    future, at once. The nonce authority (fresh random nonces, sealed to each
    receiver) does not have that weakness; use this for replaying recordings
    and for small test deployments.
    """

    def __init__(self, secret: bytes) -> None:
        if len(secret) < SECRET_MIN_BYTES:
            raise ValueError(f"the nonce secret must be at least {SECRET_MIN_BYTES} bytes")
        self._key = hmac.new(secret, b"", hashlib.sha256)

    @classmethod
    def from_file(cls, path: str | Path) -> DerivedNonces:
        """Read the secret from a file (raw bytes).

        Raises:
            KeyStoreError: unreadable, too short, or readable by other users.
        """
        p = Path(path)
        try:
            mode = p.stat().st_mode
            secret = p.read_bytes()
        except OSError as err:
            raise KeyStoreError(
                f"{p}: cannot read the nonce secret: {err.strerror or err}"
            ) from err
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise KeyStoreError(f"{p}: the nonce secret is readable by others; chmod 600 {p}")
        if len(secret) < SECRET_MIN_BYTES:
            raise KeyStoreError(
                f"{p}: {len(secret)} bytes; a nonce secret needs {SECRET_MIN_BYTES}+"
            )
        return cls(secret)

    def nonce_for(self, epoch: int) -> bytes:
        """The nonce of ``epoch``."""
        mac = self._key.copy()
        mac.update(b"rfsas-epoch-nonce" + int(epoch).to_bytes(8, "big", signed=True))
        return mac.digest()


def write_secret(path: str | Path, n_bytes: int = 32) -> None:
    """Create a new random nonce secret file with mode 0600; never overwrite one.

    Raises:
        KeyStoreError: the file exists or cannot be created.
    """
    p = Path(path)
    try:
        fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError as err:
        raise KeyStoreError(f"{p}: exists; refusing to overwrite a nonce secret") from err
    except OSError as err:
        raise KeyStoreError(f"{p}: cannot create: {err.strerror or err}") from err
    with os.fdopen(fd, "wb") as handle:
        handle.write(os.urandom(n_bytes))
