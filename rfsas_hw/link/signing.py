"""ECDSA P-256 over SHA-256 signatures for safety messages (in the spirit of IEEE 1609.2).

Signatures travel as the fixed 64 bytes ``r ‖ s`` (each a 32-byte big-endian
integer) rather than DER, so every message has a length that follows from its
header and a receiver can reject bad lengths before any cryptography.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Protocol, runtime_checkable

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.utils import (
    decode_dss_signature,
    encode_dss_signature,
)

from rfsas_hw.errors import KeyStoreError, LinkError
from rfsas_hw.link.message import SIGNATURE_BYTES, SafetyMessage, check_sender_id, encode_body

_ECDSA = ec.ECDSA(hashes.SHA256())
_HALF = SIGNATURE_BYTES // 2


def _check_p256(key: ec.EllipticCurvePrivateKey | ec.EllipticCurvePublicKey, what: str) -> None:
    if not isinstance(key.curve, ec.SECP256R1):
        raise KeyStoreError(f"{what} is on curve {key.curve.name}, safety messages use P-256")


class Signer:
    """Signs safety messages as one sender.

    Args:
        sender_id: the id receivers know this key under (1-32 of A-Z a-z 0-9 . _ -).
        private_key: the sender's P-256 private key.

    Raises:
        KeyStoreError: the key is not a P-256 key.
        LinkError: the sender id cannot go on the wire.
    """

    def __init__(self, sender_id: str, private_key: ec.EllipticCurvePrivateKey) -> None:
        check_sender_id(sender_id)
        _check_p256(private_key, f"signing key of {sender_id!r}")
        self.sender_id = sender_id
        self._key = private_key

    @property
    def public_key(self) -> ec.EllipticCurvePublicKey:
        """The public half, for enrolment at receivers."""
        return self._key.public_key()

    def sign(self, data: bytes) -> bytes:
        """The 64-byte ``r ‖ s`` signature of ``data``."""
        r, s = decode_dss_signature(self._key.sign(data, _ECDSA))
        return r.to_bytes(_HALF, "big") + s.to_bytes(_HALF, "big")

    def encode(self, msg: SafetyMessage) -> bytes:
        """The signed datagram of ``msg`` (its sender id must be this signer's).

        Raises:
            LinkError: the message does not encode (see :func:`encode_body`), or
                names another sender.
        """
        if msg.sender_id != self.sender_id:
            raise LinkError(
                f"message from {msg.sender_id!r} cannot be signed as {self.sender_id!r}"
            )
        body = encode_body(msg)
        return body + self.sign(body)


def verify(public_key: ec.EllipticCurvePublicKey, data: bytes, signature: bytes) -> bool:
    """True when ``signature`` (64-byte ``r ‖ s``) is a valid signature of ``data``."""
    if len(signature) != SIGNATURE_BYTES:
        return False
    der = der_signature(signature)
    if der is None:
        return False
    try:
        public_key.verify(der, data, _ECDSA)
    except InvalidSignature:
        return False
    return True


def der_signature(signature: bytes) -> bytes | None:
    """The DER form ``cryptography`` takes of a 64-byte ``r ‖ s`` signature, or None
    when r or s is zero (never valid)."""
    r, s = signature[:_HALF], signature[_HALF:SIGNATURE_BYTES]
    if r[0] and s[0]:
        # the usual case, built directly: no leading zero bytes to strip, a 0x00 in
        # front of a first byte with its top bit set (DER integers are signed)
        der_r = (b"\x02\x21\x00" + r) if r[0] & 0x80 else (b"\x02\x20" + r)
        der_s = (b"\x02\x21\x00" + s) if s[0] & 0x80 else (b"\x02\x20" + s)
        return b"\x30" + bytes((len(der_r) + len(der_s),)) + der_r + der_s
    r_int, s_int = int.from_bytes(r, "big"), int.from_bytes(s, "big")
    if r_int == 0 or s_int == 0:
        return None
    return encode_dss_signature(r_int, s_int)


class SenderKeys(Protocol):
    """Where a receiver looks up the enrolled signing key of a sender."""

    def signing_key(self, sender_id: str) -> ec.EllipticCurvePublicKey | None:
        """The enrolled P-256 key of ``sender_id``, or None if it is not enrolled."""
        ...


@runtime_checkable
class RefreshingKeys(SenderKeys, Protocol):
    """Enrolled keys that can change while a receiver runs (a trust directory)."""

    def refresh(self, now_s: float | None = None) -> bool:
        """Take up enrolments and revocations made meanwhile; never raises."""
        ...


class TrustedKeys(Mapping[str, ec.EllipticCurvePublicKey]):
    """An in-memory set of enrolled senders: sender id → P-256 public key.

    Raises:
        KeyStoreError: a key is not P-256.
    """

    def __init__(self, keys: Mapping[str, ec.EllipticCurvePublicKey] | None = None) -> None:
        self._keys: dict[str, ec.EllipticCurvePublicKey] = {}
        for sender_id, key in (keys or {}).items():
            self.enroll(sender_id, key)

    def enroll(self, sender_id: str, key: ec.EllipticCurvePublicKey) -> None:
        """Trust ``key`` for messages from ``sender_id`` (replacing an earlier key)."""
        check_sender_id(sender_id)
        _check_p256(key, f"key of {sender_id!r}")
        self._keys[sender_id] = key

    def signing_key(self, sender_id: str) -> ec.EllipticCurvePublicKey | None:
        """The enrolled key of ``sender_id``, or None."""
        return self._keys.get(sender_id)

    def __getitem__(self, sender_id: str) -> ec.EllipticCurvePublicKey:
        return self._keys[sender_id]

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)
