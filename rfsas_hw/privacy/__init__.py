"""Privacy: keyed MAC hashing with epoch nonces, and nonce distribution."""

from rfsas_hw.privacy.epochs import DEFAULT_GRACE_S, EpochSchedule
from rfsas_hw.privacy.hashing import (
    DEFAULT_EPOCH_S,
    DerivedNonces,
    FixedNonce,
    MacHasher,
    NonceProvider,
    NonceUnavailableError,
    epoch_of,
    hash_mac,
    write_secret,
)
from rfsas_hw.privacy.nonces import NonceAuthority, NonceEnvelopeError, NonceStore

__all__ = [
    "DEFAULT_EPOCH_S",
    "DEFAULT_GRACE_S",
    "DerivedNonces",
    "EpochSchedule",
    "FixedNonce",
    "MacHasher",
    "NonceAuthority",
    "NonceEnvelopeError",
    "NonceProvider",
    "NonceStore",
    "NonceUnavailableError",
    "epoch_of",
    "hash_mac",
    "write_secret",
]
