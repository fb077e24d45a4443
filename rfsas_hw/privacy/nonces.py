"""Epoch nonces: the authority that makes them, the envelopes that carry them, the store
that keeps them.

A deployment has one nonce authority (the roadside unit in the method). For
every epoch it draws a fresh 32-byte random nonce and, ahead of time, seals it
to each enrolled receiver (sensors that hash, backends that compare) in an
envelope only that receiver can open. A party that is not enrolled is given
nothing; :meth:`NonceAuthority.seal` refuses it.

Envelope (one datagram, the same outer header as a safety message, type 2)::

    off  size  field
    0    2     magic "RF"
    2    1     version = 1
    3    1     type = 2 (nonce envelope)
    4    1     flags, reserved, 0
    5    1     A = authority id length, 1..32
    6    A     authority id
    6+A  1     R = receiver id length, 1..32
    7+A  R     receiver id
    7+A+R 8    epoch, uint64
    15+A+R 32  ephemeral X25519 public key E
    47+A+R 12  AEAD nonce (random)
    59+A+R 48  ChaCha20-Poly1305 ciphertext of the 32-byte epoch nonce, with its 16-byte tag

Key agreement and derivation (a one-pass, authority-authenticated exchange)::

    ikm = X25519(e, Rpub) ‖ X25519(a, Rpub)         e: ephemeral, a: authority key
    key = HKDF-SHA256(ikm, salt = E, info = "rfsas-hw nonce envelope v1" ‖ Apub ‖ Rpub)
    AEAD associated data = every byte before the AEAD nonce (ids, epoch, E)

The ephemeral term makes each envelope's key fresh (a leaked authority key
does not open past envelopes); the static term proves the envelope comes from
the enrolled authority. Binding the epoch and both ids as associated data
means an envelope cannot be replayed as another epoch's nonce or redirected to
another receiver.
"""

from __future__ import annotations

import logging
import os
import re
import struct
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import x25519
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from rfsas_hw.errors import KeyStoreError, LinkSecurityError
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.privacy.hashing import NonceExpiredError, NonceUnavailableError
from rfsas_hw.privacy.nonce_state import load_nonces, save_nonces

log = logging.getLogger(__name__)

MAGIC = b"RF"
VERSION = 1
TYPE_NONCE = 2
NONCE_BYTES = 32
"""Length of an epoch nonce (the HMAC key)."""
_AEAD_NONCE = 12
_TAG = 16
_INFO = b"rfsas-hw nonce envelope v1"
_ID_RE = re.compile(rb"[A-Za-z0-9._-]{1,32}")
_TAIL = 8 + 32 + _AEAD_NONCE + NONCE_BYTES + _TAG


class NonceEnvelopeError(LinkSecurityError):
    """A nonce envelope is malformed, not for this receiver, not authentic, or unwanted."""


def _raw(key: x25519.X25519PublicKey) -> bytes:
    return key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


def _id_bytes(ident: str, what: str) -> bytes:
    raw = ident.encode("ascii", "replace")
    if not _ID_RE.fullmatch(raw):
        raise NonceEnvelopeError(f"{what} id {ident!r} must be 1-32 of A-Z a-z 0-9 . _ -")
    return raw


def _derive(
    dh_eph: bytes,
    dh_static: bytes,
    eph_pub: bytes,
    authority_pub: bytes,
    receiver_pub: bytes,
) -> bytes:
    hkdf = HKDF(
        algorithm=hashes.SHA256(),
        length=32,
        salt=eph_pub,
        info=_INFO + authority_pub + receiver_pub,
    )
    return hkdf.derive(dh_eph + dh_static)


@dataclass(frozen=True, slots=True)
class Envelope:
    """The parsed, still sealed parts of a nonce envelope."""

    authority_id: str
    receiver_id: str
    epoch: int
    ephemeral: bytes
    aead_nonce: bytes
    ciphertext: bytes
    associated: bytes
    """Every byte before the AEAD nonce: authenticated, not encrypted."""


def parse_envelope(datagram: bytes) -> Envelope:
    """Split an envelope into its fields (nothing is decrypted or trusted yet).

    Raises:
        NonceEnvelopeError: wrong header or length.
    """
    size = len(datagram)
    if size < 7 or datagram[:2] != MAGIC or datagram[2] != VERSION or datagram[3] != TYPE_NONCE:
        raise NonceEnvelopeError("not a version-1 nonce envelope")
    if datagram[4] != 0:
        raise NonceEnvelopeError("reserved flags set")
    a_len = datagram[5]
    r_at = 6 + a_len
    if size <= r_at:
        raise NonceEnvelopeError(f"truncated: {size} bytes")
    r_len = datagram[r_at]
    tail_at = r_at + 1 + r_len
    if size != tail_at + _TAIL:
        raise NonceEnvelopeError(f"length {size} bytes, expected {tail_at + _TAIL}")
    authority = bytes(datagram[6:r_at])
    receiver = bytes(datagram[r_at + 1 : tail_at])
    if not (_ID_RE.fullmatch(authority) and _ID_RE.fullmatch(receiver)):
        raise NonceEnvelopeError("bad authority or receiver id")
    (epoch,) = struct.unpack_from(">Q", datagram, tail_at)
    eph_at = tail_at + 8
    nonce_at = eph_at + 32
    return Envelope(
        authority_id=authority.decode("ascii"),
        receiver_id=receiver.decode("ascii"),
        epoch=epoch,
        ephemeral=bytes(datagram[eph_at:nonce_at]),
        aead_nonce=bytes(datagram[nonce_at : nonce_at + _AEAD_NONCE]),
        ciphertext=bytes(datagram[nonce_at + _AEAD_NONCE :]),
        associated=bytes(datagram[:nonce_at]),
    )


class NonceAuthority:
    """Draws a fresh random nonce per epoch and seals it to enrolled receivers.

    Also a :class:`~rfsas_hw.privacy.hashing.NonceProvider`, so the sensor that
    hosts the authority hashes with the same nonces it hands out.

    With a ``state`` file every nonce is written there before it is handed out,
    and an authority started on the same file hands out the same nonces: a
    restart does not split the deployment (:mod:`rfsas_hw.privacy.nonce_state`).
    One authority process per state file: two running at once would each draw
    their own nonce for a new epoch.

    Args:
        authority_id: the authority's id (as on its key card).
        private_key: the authority's X25519 key.
        schedule: the deployment's epochs.
        random_bytes: source of randomness (``os.urandom``; injectable for tests).
        keep_epochs: how many epochs of nonces to keep.
        state: the state file (None: nonces live in memory only).

    Raises:
        KeyStoreError: the state file exists but cannot be read or is malformed.
    """

    def __init__(
        self,
        authority_id: str,
        private_key: x25519.X25519PrivateKey,
        schedule: EpochSchedule | None = None,
        *,
        random_bytes: Callable[[int], bytes] = os.urandom,
        keep_epochs: int = 8,
        state: str | Path | None = None,
    ) -> None:
        self.authority_id = authority_id
        self._id = _id_bytes(authority_id, "authority")
        self._key = private_key
        self._pub = _raw(private_key.public_key())
        self.schedule = schedule or EpochSchedule()
        self._random = random_bytes
        self._keep = keep_epochs
        self.state = None if state is None else Path(state)
        self.state_errors = 0
        """Nonces that could not be written to the state file (each one is logged)."""
        self._nonces: dict[int, bytes] = (
            {} if self.state is None else load_nonces(self.state, authority_id)
        )
        self._receivers: dict[str, x25519.X25519PublicKey] = {}

    @property
    def receivers(self) -> tuple[str, ...]:
        """Ids of the enrolled receivers."""
        return tuple(self._receivers)

    def enroll(self, receiver_id: str, public_key: x25519.X25519PublicKey) -> None:
        """Register a receiver: from now on it is given every epoch's nonce."""
        _id_bytes(receiver_id, "receiver")
        self._receivers[receiver_id] = public_key

    def revoke(self, receiver_id: str) -> None:
        """Stop giving nonces to ``receiver_id`` (it still holds what it was given)."""
        self._receivers.pop(receiver_id, None)

    def enroll_only(self, receivers: Mapping[str, x25519.X25519PublicKey]) -> None:
        """Make ``receivers`` the enrolled set: enroll the new ones, revoke the others
        (a trust directory re-read after ``rfsas keys enroll`` or ``revoke``)."""
        for rid in set(self._receivers) - set(receivers):
            self.revoke(rid)
        for rid, key in receivers.items():
            self.enroll(rid, key)

    def nonce_for(self, epoch: int) -> bytes:
        """The nonce of ``epoch``, drawn on first use (and written to the state file
        before it is returned; a failed write is logged and counted, and the nonce
        is still used: a restart before the next good write would split)."""
        nonce = self._nonces.get(epoch)
        if nonce is None:
            nonce = self._random(NONCE_BYTES)
            if len(nonce) != NONCE_BYTES:
                raise ValueError(f"random source gave {len(nonce)} bytes, not {NONCE_BYTES}")
            self._nonces[epoch] = nonce
            for old in sorted(self._nonces)[: -self._keep]:
                del self._nonces[old]
            if self.state is not None:
                try:
                    save_nonces(self.state, self.authority_id, self._nonces)
                except KeyStoreError as err:
                    self.state_errors += 1
                    log.error("nonce of epoch %d not persisted: %s", epoch, err)
        return nonce

    def seal(self, receiver_id: str, epoch: int) -> bytes:
        """The envelope carrying ``epoch``'s nonce to ``receiver_id``.

        Raises:
            NonceEnvelopeError: ``receiver_id`` is not enrolled.
        """
        recv_pub = self._receivers.get(receiver_id)
        if recv_pub is None:
            raise NonceEnvelopeError(f"{receiver_id!r} is not enrolled with this authority")
        recv_raw = _raw(recv_pub)
        eph = x25519.X25519PrivateKey.generate()
        eph_pub = _raw(eph.public_key())
        try:
            key = _derive(
                eph.exchange(recv_pub), self._key.exchange(recv_pub), eph_pub, self._pub, recv_raw
            )
        except ValueError as err:  # a low-order public key gives an all-zero secret
            raise NonceEnvelopeError(f"{receiver_id!r} has an unusable public key") from err
        receiver = _id_bytes(receiver_id, "receiver")
        header = (
            MAGIC
            + bytes([VERSION, TYPE_NONCE, 0, len(self._id)])
            + self._id
            + bytes([len(receiver)])
            + receiver
            + struct.pack(">Q", epoch)
            + eph_pub
        )
        aead_nonce = os.urandom(_AEAD_NONCE)
        sealed = ChaCha20Poly1305(key).encrypt(aead_nonce, self.nonce_for(epoch), header)
        return header + aead_nonce + sealed

    def due(self, now_ns: int, ahead: int = 1) -> list[int]:
        """Epochs whose nonces receivers should hold at ``now_ns``: the current one and
        the next ``ahead`` ones (handed out before they start)."""
        current = self.schedule.epoch_of(now_ns)
        return list(range(current, current + ahead + 1))

    def issue(self, epoch: int) -> dict[str, bytes]:
        """One envelope per enrolled receiver for ``epoch``."""
        return {rid: self.seal(rid, epoch) for rid in self._receivers}


class NonceStore:
    """A receiver's nonces: opens envelopes from enrolled authorities, keeps nonces
    through their epoch's grace period, then forgets them.

    A :class:`~rfsas_hw.privacy.hashing.NonceProvider` for sensors and backends,
    and an envelope sink for :class:`~rfsas_hw.link.receiver.Receiver`.

    Args:
        receiver_id: this party's id (envelopes for others are refused).
        private_key: this party's X25519 key.
        authorities: enrolled authority id → X25519 public key.
        schedule: the deployment's epochs (grace period included).
        clock: UTC ns; ``nonce_for`` refuses epochs past their grace period at this time.
            None: never expire (offline processing of recorded data).
        max_ahead: how many epochs into the future an envelope may be for.
    """

    def __init__(
        self,
        receiver_id: str,
        private_key: x25519.X25519PrivateKey,
        authorities: Mapping[str, x25519.X25519PublicKey],
        schedule: EpochSchedule | None = None,
        *,
        clock: Callable[[], int] | None = time.time_ns,
        max_ahead: int = 2,
    ) -> None:
        self.receiver_id = receiver_id
        self._key = private_key
        self._pub = _raw(private_key.public_key())
        self._authorities = {k: _raw(v) for k, v in authorities.items()}
        self._authority_keys = dict(authorities)
        self.schedule = schedule or EpochSchedule()
        self.clock = clock
        self.max_ahead = max_ahead
        self._nonces: dict[int, bytes] = {}

    def accept_envelope(self, datagram: bytes, now_ns: int) -> int:
        """Open an envelope received at ``now_ns`` and keep its nonce; return the epoch.

        Raises:
            NonceEnvelopeError: malformed, for another receiver, from an unknown
                authority, for an expired or far-future epoch, or not authentic.
        """
        env = parse_envelope(datagram)
        if env.receiver_id != self.receiver_id:
            raise NonceEnvelopeError(f"envelope is for {env.receiver_id!r}, not for us")
        auth_key = self._authority_keys.get(env.authority_id)
        if auth_key is None:
            raise NonceEnvelopeError(f"authority {env.authority_id!r} is not enrolled")
        if self.schedule.expired(env.epoch, now_ns):
            raise NonceEnvelopeError(f"epoch {env.epoch} is over")
        if env.epoch > self.schedule.epoch_of(now_ns) + self.max_ahead:
            raise NonceEnvelopeError(f"epoch {env.epoch} is too far ahead")
        try:
            eph = x25519.X25519PublicKey.from_public_bytes(env.ephemeral)
            key = _derive(
                self._key.exchange(eph),
                self._key.exchange(auth_key),
                env.ephemeral,
                self._authorities[env.authority_id],
                self._pub,
            )
            nonce = ChaCha20Poly1305(key).decrypt(env.aead_nonce, env.ciphertext, env.associated)
        except (InvalidTag, ValueError) as err:
            raise NonceEnvelopeError(
                f"envelope from {env.authority_id!r} for epoch {env.epoch} is not authentic"
            ) from err
        held = self._nonces.get(env.epoch)
        if held is not None and held != nonce:
            raise NonceEnvelopeError(f"a different nonce for epoch {env.epoch} is already held")
        self._nonces[env.epoch] = nonce
        self.prune(now_ns)
        return env.epoch

    def prune(self, now_ns: int) -> None:
        """Forget nonces whose epoch and grace period are over at ``now_ns``."""
        for epoch in [e for e in self._nonces if self.schedule.expired(e, now_ns)]:
            del self._nonces[epoch]

    @property
    def epochs(self) -> tuple[int, ...]:
        """Epochs whose nonces are held."""
        return tuple(sorted(self._nonces))

    def nonce_for(self, epoch: int) -> bytes:
        """The nonce of ``epoch``.

        Raises:
            NonceUnavailableError: never received (yet).
            NonceExpiredError: past its grace period (it will never be given out again).
        """
        if self.clock is not None:
            now = self.clock()
            if self.schedule.expired(epoch, now):
                self._nonces.pop(epoch, None)
                raise NonceExpiredError(f"the nonce of epoch {epoch} has expired")
        nonce = self._nonces.get(epoch)
        if nonce is None:
            raise NonceUnavailableError(
                f"no nonce for epoch {epoch}: not received from the authority (yet)"
            )
        return nonce
