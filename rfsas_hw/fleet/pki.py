"""A small certificate authority for the broker: a CA, a server certificate, and one
client certificate per rfsas identity whose subject common name is the rfsas id.

The broker maps that name to the MQTT user name (``use_identity_as_username``),
so its ACL can say what each identity may read and write. TLS keys are fresh
P-256 keys, separate from the identities' signing keys: the broker never sees
a key that signs safety messages.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from rfsas_hw.errors import KeyStoreError
from rfsas_hw.link.keys import write_new

CA_NAME = "rfsas broker CA"


@dataclass(frozen=True, slots=True)
class CertPair:
    """A certificate and its private key on disk (PEM)."""

    cert: Path
    key: Path


def _write(path: Path, data: bytes, mode: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_new(path, data, mode)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


class CertificateAuthority:
    """The CA of one deployment's broker.

    Args:
        cert: the CA certificate.
        key: the CA private key.
    """

    def __init__(self, cert: x509.Certificate, key: ec.EllipticCurvePrivateKey) -> None:
        self.cert = cert
        self.key = key

    @classmethod
    def create(cls, directory: Path, days: int = 3650) -> CertificateAuthority:
        """Make a new CA in ``directory`` (``ca.crt``, ``ca.key`` mode 0600).

        Raises:
            KeyStoreError: a file exists already or cannot be written.
        """
        key = ec.generate_private_key(ec.SECP256R1())
        now = dt.datetime.now(dt.UTC)
        cert = (
            x509.CertificateBuilder()
            .subject_name(_name(CA_NAME))
            .issuer_name(_name(CA_NAME))
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(
                x509.KeyUsage(
                    digital_signature=False,
                    content_commitment=False,
                    key_encipherment=False,
                    data_encipherment=False,
                    key_agreement=False,
                    key_cert_sign=True,
                    crl_sign=True,
                    encipher_only=False,
                    decipher_only=False,
                ),
                critical=True,
            )
            .sign(key, hashes.SHA256())
        )
        _write(directory / "ca.key", _key_pem(key), 0o600)
        _write(directory / "ca.crt", cert.public_bytes(serialization.Encoding.PEM), 0o644)
        return cls(cert, key)

    @classmethod
    def load(cls, directory: Path) -> CertificateAuthority:
        """Open the CA in ``directory``.

        Raises:
            KeyStoreError: missing or unreadable files.
        """
        try:
            cert = x509.load_pem_x509_certificate((directory / "ca.crt").read_bytes())
            key = serialization.load_pem_private_key(
                (directory / "ca.key").read_bytes(), password=None
            )
        except (OSError, ValueError) as err:
            raise KeyStoreError(f"{directory}: not a usable broker CA: {err}") from err
        if not isinstance(key, ec.EllipticCurvePrivateKey):
            raise KeyStoreError(f"{directory / 'ca.key'}: not an EC private key")
        return cls(cert, key)

    @classmethod
    def open_or_create(cls, directory: Path, days: int = 3650) -> CertificateAuthority:
        """The CA in ``directory``, made there first if it has none.

        Raises:
            KeyStoreError: unreadable or unwritable files.
        """
        if (directory / "ca.crt").exists():
            return cls.load(directory)
        return cls.create(directory, days)

    def issue(
        self,
        common_name: str,
        directory: Path,
        stem: str,
        *,
        server_names: tuple[str, ...] = (),
        days: int = 365,
    ) -> CertPair:
        """Issue a certificate for ``common_name`` into ``directory/stem.crt`` and
        ``stem.key`` (0600). With ``server_names`` it is a server certificate valid
        for those host names and addresses; otherwise a client certificate.

        Raises:
            KeyStoreError: a file exists already or cannot be written.
        """
        key = ec.generate_private_key(ec.SECP256R1())
        now = dt.datetime.now(dt.UTC)
        builder = (
            x509.CertificateBuilder()
            .subject_name(_name(common_name))
            .issuer_name(self.cert.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        )
        if server_names:
            alt: list[x509.GeneralName] = []
            for name in server_names:
                try:
                    alt.append(x509.IPAddress(ipaddress.ip_address(name)))
                except ValueError:
                    alt.append(x509.DNSName(name))
            builder = builder.add_extension(x509.SubjectAlternativeName(alt), critical=False)
            usage = ExtendedKeyUsageOID.SERVER_AUTH
        else:
            usage = ExtendedKeyUsageOID.CLIENT_AUTH
        builder = builder.add_extension(x509.ExtendedKeyUsage([usage]), critical=False)
        cert = builder.sign(self.key, hashes.SHA256())
        pair = CertPair(directory / f"{stem}.crt", directory / f"{stem}.key")
        _write(pair.key, _key_pem(key), 0o600)
        _write(pair.cert, cert.public_bytes(serialization.Encoding.PEM), 0o644)
        return pair
