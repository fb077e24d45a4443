"""Pre-authentication: a cheap check an outsider cannot pass, run before the signature.

An ECDSA P-256 verify costs ~150 µs; a flood of well-formed messages with bad
signatures from an enrolled sender id used to cost one each, and valid
messages starved. Version-2 messages carry an 8-byte tag, the first 8 bytes of
HMAC-SHA256 over the signed message, under the sender's pre-authentication key
for the message's nonce epoch::

    K(sender, epoch) = HMAC-SHA256(nonce(epoch), "rfsas-hw preauth v2" ‖ 0x00 ‖ sender id)

The epoch nonce is the one the nonce authority already seals to every enrolled
sensor and backend (:mod:`rfsas_hw.privacy.nonces`), so no new key has to be
agreed, keys change every epoch, and a party that is not enrolled cannot make a
tag: its forgeries cost a receiver one HMAC (a few µs) each. An enrolled party
holds every nonce and could make tags for another sender's id; the signature
still stops it from forging content, and :class:`RateLimiter` bounds how many
signature checks it can cost per sender id.
"""

from __future__ import annotations

import hashlib
import hmac
from collections.abc import Callable
from typing import Protocol, runtime_checkable

from rfsas_hw.errors import LinkError
from rfsas_hw.link.message import (
    PREAUTH_BYTES,
    VERSION,
    VERSION_PREAUTH,
    SafetyMessage,
    encode_body,
)
from rfsas_hw.link.signing import Signer
from rfsas_hw.privacy.hashing import NonceUnavailableError

_LABEL = b"rfsas-hw preauth v2\0"


@runtime_checkable
class NonceSource(Protocol):
    """Anything that gives an epoch's nonce (a nonce store, inbox or authority)."""

    def nonce_for(self, epoch: int) -> bytes:
        """The 32-byte nonce of ``epoch``.

        Raises:
            NonceUnavailableError: not held (never received, or expired).
        """
        ...


def derive_key(nonce: bytes, sender_id: str) -> bytes:
    """The pre-authentication key of ``sender_id`` for the epoch of ``nonce`` (32 bytes)."""
    return hmac.digest(nonce, _LABEL + sender_id.encode("ascii"), hashlib.sha256)


def make_tag(key: bytes, data: bytes) -> bytes:
    """The 8-byte pre-authentication tag of ``data``."""
    return hmac.digest(key, data, hashlib.sha256)[:PREAUTH_BYTES]


def tag_ok(key: bytes, datagram: bytes) -> bool:
    """True when the version-2 ``datagram`` ends with the right tag under ``key``."""
    mac = hmac.digest(key, datagram[:-PREAUTH_BYTES], "sha256")
    return hmac.compare_digest(mac[:PREAUTH_BYTES], datagram[-PREAUTH_BYTES:])


_BLOCK = 64
"""SHA-256's block size, bytes: the longest key :class:`TagKey` takes."""


class TagKey:
    """A pre-authentication key made ready for many tags: one keyed HMAC-SHA256
    object, copied per tag, so a tag costs no key schedule; same tags as
    :func:`make_tag` and :func:`tag_ok`.

    Args:
        key: the 32-byte pre-authentication key (any length up to 64 bytes).

    Raises:
        ValueError: a key longer than 64 bytes.
    """

    __slots__ = ("_keyed", "key")

    def __init__(self, key: bytes) -> None:
        if len(key) > _BLOCK:
            raise ValueError(f"a {len(key)}-byte key: at most {_BLOCK} bytes")
        self.key = key
        self._keyed = hmac.new(key, digestmod=hashlib.sha256)

    def mac(self, data: bytes | memoryview) -> bytes:
        """HMAC-SHA256 of ``data`` under the key, 32 bytes."""
        h = self._keyed.copy()
        h.update(data)
        return h.digest()

    def tag_ok(self, datagram: bytes) -> bool:
        """True when the version-2 ``datagram`` ends with the right tag under the key."""
        view = memoryview(datagram)
        mac = self.mac(view[:-PREAUTH_BYTES])
        return hmac.compare_digest(mac[:PREAUTH_BYTES], view[-PREAUTH_BYTES:])


class PreauthKeys:
    """Pre-authentication keys derived from epoch nonces, cached per (sender, epoch).

    Args:
        nonces: where epoch nonces come from.
        keep: most keys cached (the oldest go first).
    """

    def __init__(self, nonces: NonceSource, keep: int = 4096) -> None:
        self.nonces = nonces
        self.keep = keep
        self._keys: dict[tuple[str, int], bytes] = {}

    def key_for(self, sender_id: str, epoch: int) -> bytes | None:
        """The key of ``sender_id`` in ``epoch``, or None when its nonce is not held."""
        cache_key = (sender_id, epoch)
        key = self._keys.get(cache_key)
        if key is None:
            try:
                nonce = self.nonces.nonce_for(epoch)
            except NonceUnavailableError:
                return None
            key = derive_key(nonce, sender_id)
            if len(self._keys) >= self.keep:
                del self._keys[next(iter(self._keys))]
            self._keys[cache_key] = key
        return key


def sign_datagram(
    signer: Signer,
    sender_id: str,
    what: str,
    encode: Callable[[int], bytes],
    key: bytes | None,
) -> bytes:
    """The datagram of a message of any type: its body (``encode(version)``),
    the signature, and with ``key`` the pre-authentication tag.

    Version 2 when ``key`` is given, else version 1. ``what`` names the kind of
    message in the error.

    Raises:
        LinkError: ``sender_id`` is not the signer's, or the body does not encode.
    """
    if sender_id != signer.sender_id:
        raise LinkError(f"{what} from {sender_id!r} cannot be signed as {signer.sender_id!r}")
    body = encode(VERSION if key is None else VERSION_PREAUTH)
    signed = body + signer.sign(body)
    return signed if key is None else signed + make_tag(key, signed)


def seal(signer: Signer, msg: SafetyMessage, key: bytes) -> bytes:
    """The version-2 datagram of ``msg``: signed by ``signer``, tagged with ``key``.

    Raises:
        LinkError: the message does not encode, or names another sender.
    """
    return sign_datagram(signer, msg.sender_id, "message", lambda v: encode_body(msg, v), key)


class RateLimiter:
    """A token bucket per sender: at most ``rate_hz`` signature checks per second
    on average, ``burst`` at once.

    Args:
        rate_hz: refill rate, per second.
        burst: bucket size.
        clock: seconds, monotonic.

    Raises:
        ValueError: a non-positive rate or burst.
    """

    def __init__(self, rate_hz: float, burst: float, clock: Callable[[], float]) -> None:
        if rate_hz <= 0 or burst < 1:
            raise ValueError("rate_hz must be positive and burst at least 1")
        self.rate_hz = float(rate_hz)
        self.burst = float(burst)
        self.clock = clock
        self._buckets: dict[str, tuple[float, float]] = {}

    def allow(self, sender_id: str) -> bool:
        """Take one token of ``sender_id``'s bucket; False when it is empty."""
        now = self.clock()
        tokens, last = self._buckets.get(sender_id, (self.burst, now))
        tokens = min(self.burst, tokens + (now - last) * self.rate_hz)
        if tokens < 1.0:
            self._buckets[sender_id] = (tokens, now)
            return False
        self._buckets[sender_id] = (tokens - 1.0, now)
        return True
