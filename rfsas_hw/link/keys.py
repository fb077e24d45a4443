"""Key files on disk: one directory per identity, and a trust directory of enrolled cards.

Layout of a key directory (``rfsas keys new --role sensor --id rsu-1 -o DIR``)::

    DIR/identity.yaml   the public card: id, role, public keys (share this)
    DIR/sign.key        ECDSA P-256 private key, PKCS#8 PEM, mode 0600 (sensors: bearings;
                        backends: advisories)
    DIR/kx.key          X25519 private key, PKCS#8 PEM, mode 0600 (every role)
    DIR/trust/ID.yaml   cards of the parties this identity trusts (enrolled)

Roles and what their keys do:

- ``sensor``: signs safety messages (``sign``) and receives epoch nonces (``kx``);
- ``authority``: hands out epoch nonces to enrolled receivers (``kx``);
- ``backend``: receives epoch nonces (``kx``), verifies enrolled sensors and signs
  its assessments (``sign``).

A card is YAML::

    rfsas-key-card: 1
    id: rsu-1
    role: sensor
    sign_p256: <base64 of the 65-byte uncompressed SEC1 point>
    kx_x25519: <base64 of the 32-byte public key>

Private keys are created with ``O_EXCL`` and mode 0600; an existing file is
never overwritten, and a private key readable by group or others is refused
on load (as ssh does).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import logging
import os
import stat
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, cast, get_args

import yaml
from cryptography.exceptions import UnsupportedAlgorithm
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import ec, x25519

from rfsas_hw.config import parse_yaml, read_text_input
from rfsas_hw.errors import KeyStoreError, LinkError
from rfsas_hw.link.message import check_sender_id
from rfsas_hw.link.signing import Signer
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.privacy.nonce_state import STATE_FILE
from rfsas_hw.privacy.nonces import NonceAuthority, NonceStore

log = logging.getLogger(__name__)

Role = Literal["sensor", "authority", "backend"]
ROLES: tuple[str, ...] = get_args(Role)
CARD_FILE = "identity.yaml"
SIGN_FILE = "sign.key"
KX_FILE = "kx.key"
TRUST_DIR = "trust"
CARD_VERSION = 1
CARD_MAX_BYTES = 64 * 1024
"""Largest key card read, bytes (a card is a few hundred)."""


@dataclass(frozen=True, slots=True)
class KeyCard:
    """The public half of an identity: what other parties enroll."""

    id: str
    role: Role
    sign_public: ec.EllipticCurvePublicKey | None
    """P-256 key that verifies this party's messages (sensors)."""
    kx_public: x25519.X25519PublicKey | None
    """X25519 key nonces are sealed to (receivers) or from (the authority)."""

    @property
    def fingerprint(self) -> str:
        """First 16 hex digits of SHA-256 over the public keys: compare out of band."""
        h = hashlib.sha256(self.id.encode() + b"\0" + self.role.encode())
        if self.sign_public is not None:
            h.update(_sign_bytes(self.sign_public))
        if self.kx_public is not None:
            h.update(_kx_bytes(self.kx_public))
        return h.hexdigest()[:16]

    def to_yaml(self) -> str:
        """The card as YAML text."""
        data: dict[str, object] = {"rfsas-key-card": CARD_VERSION, "id": self.id, "role": self.role}
        if self.sign_public is not None:
            data["sign_p256"] = base64.b64encode(_sign_bytes(self.sign_public)).decode()
        if self.kx_public is not None:
            data["kx_x25519"] = base64.b64encode(_kx_bytes(self.kx_public)).decode()
        return yaml.safe_dump(data, sort_keys=False)

    @classmethod
    def from_yaml(cls, text: str, where: str) -> KeyCard:
        """Parse a card.

        Raises:
            KeyStoreError: not a card, unknown keys, bad id or role, undecodable keys.
        """
        data = parse_yaml(text, where, KeyStoreError)
        if not isinstance(data, dict) or data.get("rfsas-key-card") != CARD_VERSION:
            raise KeyStoreError(f"{where}: not an rfsas key card (version {CARD_VERSION})")
        unknown = set(data) - {"rfsas-key-card", "id", "role", "sign_p256", "kx_x25519"}
        if unknown:
            raise KeyStoreError(f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))}")
        ident, role = data.get("id"), data.get("role")
        if not isinstance(ident, str):
            raise KeyStoreError(f"{where}: id missing")
        try:
            check_sender_id(ident)
        except LinkError as err:
            raise KeyStoreError(f"{where}: {err}") from err
        if role not in ROLES:
            raise KeyStoreError(f"{where}: role {role!r} is not one of {', '.join(ROLES)}")
        sign = kx = None
        try:
            if "sign_p256" in data:
                sign = ec.EllipticCurvePublicKey.from_encoded_point(
                    ec.SECP256R1(), _b64(data["sign_p256"])
                )
            if "kx_x25519" in data:
                kx = x25519.X25519PublicKey.from_public_bytes(_b64(data["kx_x25519"]))
        except (ValueError, TypeError, binascii.Error) as err:
            raise KeyStoreError(f"{where}: bad public key: {err}") from err
        card = cls(ident, cast(Role, role), sign, kx)
        if role == "sensor" and sign is None:
            raise KeyStoreError(f"{where}: a sensor card needs sign_p256")
        if kx is None:
            raise KeyStoreError(f"{where}: card needs kx_x25519")
        return card

    @classmethod
    def load(cls, path: str | Path) -> KeyCard:
        """Read a card file (an ``identity.yaml`` or an exported copy).

        Raises:
            KeyStoreError: unreadable or invalid.
        """
        p = Path(path)
        if p.is_dir():
            p = p / CARD_FILE
        text = read_text_input(p, "key card", CARD_MAX_BYTES, KeyStoreError)
        return cls.from_yaml(text, str(p))


def _b64(value: object) -> bytes:
    if not isinstance(value, str):
        raise TypeError("expected base64 text")
    return base64.b64decode(value, validate=True)


def _sign_bytes(key: ec.EllipticCurvePublicKey) -> bytes:
    return key.public_bytes(
        serialization.Encoding.X962, serialization.PublicFormat.UncompressedPoint
    )


def _kx_bytes(key: x25519.X25519PublicKey) -> bytes:
    return key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


def write_new(path: Path, data: bytes, mode: int) -> None:
    """Write ``data`` to a file that must not exist yet, with permissions ``mode``
    exactly (whatever the umask): a key never lands in a file someone else made.

    Raises:
        KeyStoreError: the file exists, or cannot be created.
    """
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    except FileExistsError as err:
        raise KeyStoreError(f"{path}: already exists; refusing to overwrite") from err
    except OSError as err:
        raise KeyStoreError(f"{path}: cannot create: {err.strerror or err}") from err
    with os.fdopen(fd, "wb") as fh:
        os.fchmod(fh.fileno(), mode)  # the umask may have removed bits we did not ask to keep
        fh.write(data)


def _pem(key: ec.EllipticCurvePrivateKey | x25519.X25519PrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _read_private(path: Path) -> object:
    try:
        st = path.stat()
    except OSError as err:
        raise KeyStoreError(f"{path}: missing private key: {err.strerror or err}") from err
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise KeyStoreError(
            f"{path}: permissions {stat.S_IMODE(st.st_mode):04o} are too open; "
            f"a private key must be readable by its owner only (chmod 600 {path})"
        )
    try:
        data = path.read_bytes()
    except OSError as err:
        raise KeyStoreError(f"{path}: cannot read: {err.strerror or err}") from err
    if len(data) > 64 * 1024:
        raise KeyStoreError(f"{path}: {len(data):,} bytes is not a private key file")
    try:
        return serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError, UnsupportedAlgorithm) as err:
        # one line: the library's messages can span several
        reason = " ".join(str(err).split())[:120]
        raise KeyStoreError(f"{path}: not a readable private key: {reason}") from err


def _check_trusted_path(path: Path) -> None:
    """Refuse a trust directory or card that another local user could change: what
    decides trust gets the same protection as a private key.

    Raises:
        KeyStoreError: writable by group or others, or owned by another user (not root).
    """
    try:
        st = path.stat()
    except OSError as err:
        raise KeyStoreError(f"{path}: cannot read: {err.strerror or err}") from err
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise KeyStoreError(
            f"{path}: permissions {stat.S_IMODE(st.st_mode):04o} let other users change what "
            f"is trusted; chmod go-w {path}"
        )
    if st.st_uid not in (os.getuid(), 0):
        raise KeyStoreError(
            f"{path}: owned by user {st.st_uid}, not by you; another user decides what is trusted"
        )


class TrustDir:
    """The enrolled cards of one identity (``DIR/trust/*.yaml``).

    Also a ``SenderKeys`` for a :class:`~rfsas_hw.link.receiver.Receiver`:
    :meth:`signing_key` returns an enrolled sensor's key. A running receiver
    calls :meth:`refresh`, so an enrolment or a revocation made by another
    process (``rfsas keys revoke``) takes effect within ``reload_s`` seconds.

    Args:
        path: the trust directory.
        reload_s: least time between two looks at the directory, seconds.
    """

    def __init__(self, path: str | Path, reload_s: float = 2.0) -> None:
        self.path = Path(path)
        self.reload_s = reload_s
        self._cards: dict[str, KeyCard] = {}
        self._seen: tuple[tuple[str, int, int, int], ...] | None = None
        """The card files as last read (None: changed here since, read again)."""
        self._looked = time.monotonic()
        self.reload()

    def _files(self) -> tuple[tuple[str, int, int, int], ...]:
        """What the directory holds: (name, mtime ns, size, inode) of every card file."""
        try:
            with os.scandir(self.path) as entries:
                return tuple(
                    sorted(
                        (e.name, st.st_mtime_ns, st.st_size, st.st_ino)
                        for e in entries
                        if e.name.endswith(".yaml") and (st := e.stat())
                    )
                )
        except OSError:
            return ()

    def refresh(self, now_s: float | None = None) -> bool:
        """Re-read the directory when ``reload_s`` has passed since the last look
        (``now_s``: monotonic seconds, default the clock) and a card file was added,
        removed or replaced. True when it was re-read. Never raises: when a card no
        longer reads, the error is logged, the cards whose files are gone are dropped
        (a revocation is never missed) and the others are kept until it reads again.
        """
        now = time.monotonic() if now_s is None else now_s
        if now - self._looked < self.reload_s:
            return False
        self._looked = now
        files = self._files()
        if files == self._seen:
            return False
        before = {k: c.fingerprint for k, c in self._cards.items()}
        try:
            self.reload()
        except KeyStoreError as err:
            present = {name for name, *_ in files}
            self._cards = {k: c for k, c in self._cards.items() if f"{k}.yaml" in present}
            log.error("trust directory not re-read, enrolled cards kept: %s", err)
            return False
        after = {k: c.fingerprint for k, c in self._cards.items()}
        changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
        if changed:
            log.warning(
                "trust directory %s re-read: now %d enrolled; changed: %s",
                self.path,
                len(after),
                ", ".join(f"{k} ({'removed' if k not in after else 'enrolled'})" for k in changed),
            )
        return True

    def reload(self) -> None:
        """Re-read the directory.

        Raises:
            KeyStoreError: a card is invalid or filed under another id's name.
        """
        cards: dict[str, KeyCard] = {}
        if self.path.is_dir():
            _check_trusted_path(self.path)
            for file in sorted(self.path.glob("*.yaml")):
                _check_trusted_path(file)
                card = KeyCard.load(file)
                if file.stem != card.id:
                    raise KeyStoreError(f"{file}: holds the card of {card.id!r}")
                cards[card.id] = card
        self._cards = cards
        self._seen = self._files()

    def enroll(self, card: KeyCard, replace: bool = False) -> Path:
        """File ``card`` as trusted.

        Raises:
            KeyStoreError: a different card is enrolled under the same id and
                ``replace`` is false.
        """
        self.path.mkdir(mode=0o700, parents=True, exist_ok=True)
        dest = self.path / f"{card.id}.yaml"
        old = self._cards.get(card.id)
        if old is not None and old.fingerprint != card.fingerprint and not replace:
            raise KeyStoreError(
                f"{dest}: {card.id!r} is already enrolled with fingerprint {old.fingerprint}; "
                f"the new card has {card.fingerprint} (use replace to swap keys)"
            )
        tmp = dest.with_suffix(".yaml.tmp")
        tmp.write_text(card.to_yaml(), encoding="utf-8")
        tmp.chmod(0o644)  # whatever the umask: a group-writable card would not be trusted
        tmp.replace(dest)
        self._cards[card.id] = card
        self._seen = None
        return dest

    def revoke(self, ident: str) -> None:
        """Remove the card of ``ident``.

        Raises:
            KeyStoreError: ``ident`` is not enrolled.
        """
        if ident not in self._cards:
            raise KeyStoreError(f"{self.path}: {ident!r} is not enrolled")
        (self.path / f"{ident}.yaml").unlink(missing_ok=True)
        del self._cards[ident]
        self._seen = None

    def get(self, ident: str) -> KeyCard | None:
        """The card of ``ident``, or None."""
        return self._cards.get(ident)

    def __iter__(self) -> Iterator[KeyCard]:
        return iter(self._cards.values())

    def __len__(self) -> int:
        return len(self._cards)

    def signing_key(self, sender_id: str) -> ec.EllipticCurvePublicKey | None:
        """The enrolled P-256 key of sensor ``sender_id``, or None."""
        card = self._cards.get(sender_id)
        return None if card is None or card.role != "sensor" else card.sign_public

    def backend_key(self, backend_id: str) -> ec.EllipticCurvePublicKey | None:
        """The enrolled P-256 key of backend ``backend_id`` (it signs advisories), or None."""
        card = self._cards.get(backend_id)
        return None if card is None or card.role != "backend" else card.sign_public

    def receivers(self) -> dict[str, x25519.X25519PublicKey]:
        """Enrolled sensors and backends: who an authority hands nonces to."""
        return {
            c.id: c.kx_public
            for c in self._cards.values()
            if c.role in ("sensor", "backend") and c.kx_public is not None
        }

    def authorities(self) -> dict[str, x25519.X25519PublicKey]:
        """Enrolled nonce authorities: whose envelopes a receiver accepts."""
        return {
            c.id: c.kx_public
            for c in self._cards.values()
            if c.role == "authority" and c.kx_public is not None
        }


class KeyStore:
    """One identity's key directory (see the module docstring)."""

    def __init__(self, path: Path, card: KeyCard) -> None:
        self.path = path
        self.card = card
        self.trust = TrustDir(path / TRUST_DIR)

    @property
    def id(self) -> str:
        """The identity's id (sender id on the wire for a sensor)."""
        return self.card.id

    @property
    def role(self) -> Role:
        """The identity's role."""
        return self.card.role

    @classmethod
    def create(cls, path: str | Path, role: str, ident: str | None = None) -> KeyStore:
        """Generate the keys of a new identity in ``path``.

        Args:
            path: the directory (created if missing, may exist if empty of key files).
            role: ``sensor``, ``authority`` or ``backend``.
            ident: the id; default: the directory name.

        Raises:
            KeyStoreError: bad role or id, or a key file already exists.
        """
        p = Path(path)
        ident = ident if ident is not None else p.resolve().name
        if role not in ROLES:
            raise KeyStoreError(f"role {role!r} is not one of {', '.join(ROLES)}")
        try:
            check_sender_id(ident)
        except LinkError as err:
            raise KeyStoreError(f"{p}: {err}") from err
        for name in (CARD_FILE, SIGN_FILE, KX_FILE):
            if (p / name).exists():
                raise KeyStoreError(f"{p / name}: already exists; refusing to overwrite")
        try:
            p.mkdir(mode=0o700, parents=True, exist_ok=True)
        except OSError as err:
            raise KeyStoreError(f"{p}: cannot create directory: {err.strerror or err}") from err
        # sensors sign bearings; backends sign their assessments (advisories)
        signing = role in ("sensor", "backend")
        sign = ec.generate_private_key(ec.SECP256R1()) if signing else None
        kx = x25519.X25519PrivateKey.generate()
        if sign is not None:
            write_new(p / SIGN_FILE, _pem(sign), 0o600)
        write_new(p / KX_FILE, _pem(kx), 0o600)
        card = KeyCard(
            ident,
            cast(Role, role),
            None if sign is None else sign.public_key(),
            kx.public_key(),
        )
        write_new(p / CARD_FILE, card.to_yaml().encode(), 0o644)
        return cls(p, card)

    @classmethod
    def open(cls, path: str | Path) -> KeyStore:
        """Open an existing key directory (private keys are read when first used).

        Raises:
            KeyStoreError: missing or invalid card.
        """
        p = Path(path)
        if not p.is_dir():
            raise KeyStoreError(f"{p}: not a key directory (make one with: rfsas keys new)")
        return cls(p, KeyCard.load(p / CARD_FILE))

    def signer(self) -> Signer:
        """The signing identity of a sensor (bearings) or a backend (advisories).

        Raises:
            KeyStoreError: an authority, a backend made before backends had signing
                keys, or the key file is missing, too open or does not match the card.
        """
        if self.role not in ("sensor", "backend"):
            raise KeyStoreError(f"{self.path}: a {self.role} identity does not sign messages")
        if self.card.sign_public is None:
            raise KeyStoreError(
                f"{self.path}: this {self.role} identity has no signing key (made by an older "
                "release); make a new one with: rfsas keys new --role backend"
            )
        key = _read_private(self.path / SIGN_FILE)
        if not isinstance(key, ec.EllipticCurvePrivateKey):
            raise KeyStoreError(f"{self.path / SIGN_FILE}: not an EC private key")
        pub = self.card.sign_public
        if pub is None or _sign_bytes(key.public_key()) != _sign_bytes(pub):
            raise KeyStoreError(f"{self.path / SIGN_FILE}: does not match {CARD_FILE}")
        return Signer(self.id, key)

    def kx_private(self) -> x25519.X25519PrivateKey:
        """The X25519 private key.

        Raises:
            KeyStoreError: the key file is missing, too open or does not match the card.
        """
        key = _read_private(self.path / KX_FILE)
        if not isinstance(key, x25519.X25519PrivateKey):
            raise KeyStoreError(f"{self.path / KX_FILE}: not an X25519 private key")
        pub = self.card.kx_public
        if pub is None or _kx_bytes(key.public_key()) != _kx_bytes(pub):
            raise KeyStoreError(f"{self.path / KX_FILE}: does not match {CARD_FILE}")
        return key

    def nonce_authority(self, schedule: EpochSchedule | None = None) -> NonceAuthority:
        """The nonce authority of an ``authority`` identity, with every sensor and
        backend in its trust directory enrolled. Its nonces are kept in the key
        directory's ``nonces.state``, so that the authority restarted on this
        directory hands out the nonces it handed out before.

        Raises:
            KeyStoreError: not an authority, its key cannot be read, or its
                ``nonces.state`` is unreadable or malformed.
        """
        if self.role != "authority":
            raise KeyStoreError(f"{self.path}: a {self.role} identity is not a nonce authority")
        authority = NonceAuthority(
            self.id, self.kx_private(), schedule, state=self.path / STATE_FILE
        )
        for rid, key in self.trust.receivers().items():
            authority.enroll(rid, key)
        return authority

    def nonce_store(
        self,
        schedule: EpochSchedule | None = None,
        clock: Callable[[], int] | None = time.time_ns,
    ) -> NonceStore:
        """A nonce store for this sensor or backend, accepting envelopes from the
        authorities in its trust directory.

        Raises:
            KeyStoreError: an authority identity, no authority enrolled, or the key
                cannot be read.
        """
        if self.role == "authority":
            raise KeyStoreError(
                f"{self.path}: the authority makes nonces, it does not receive them"
            )
        authorities = self.trust.authorities()
        if not authorities:
            raise KeyStoreError(
                f"{self.path}: no nonce authority enrolled (rfsas keys enroll {self.path} CARD)"
            )
        return NonceStore(self.id, self.kx_private(), authorities, schedule, clock=clock)
