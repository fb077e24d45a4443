"""``rfsas broker config``: certificates named by rfsas id, a config with mutual TLS
and TCP_NODELAY, and an ACL that confines each sensor to its own topics."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner
from cryptography import x509
from cryptography.x509.oid import NameOID

from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.link.keys import KeyStore


def test_cli_writes_certificates_config_and_acl(tmp_path: Path) -> None:
    auth = KeyStore.create(tmp_path / "auth-0", "authority")
    auth.trust.enroll(KeyStore.create(tmp_path / "rsu-1", "sensor").card)
    auth.trust.enroll(KeyStore.create(tmp_path / "be-a", "backend").card)
    _load_commands()
    out = tmp_path / "broker"
    args = ["broker", "config", "--keys", str(auth.path), "--out", str(out), "--port", "18883"]
    result = CliRunner().invoke(cli, [*args, "--vehicle", "car-7"])
    assert result.exit_code == 0, result.output
    cert = x509.load_pem_x509_certificate((out / "clients" / "rsu-1.crt").read_bytes())
    assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "rsu-1"
    assert (out / "clients" / "rsu-1.key").stat().st_mode & 0o077 == 0
    conf = (out / "broker" / "mosquitto.conf").read_text()
    for line in (
        "listener 18883 localhost",
        "require_certificate true",
        "use_identity_as_username true",
        "set_tcp_nodelay true",
        "allow_anonymous false",
    ):
        assert line in conf.splitlines()
    acl = (out / "broker" / "acl").read_text()
    block = acl.split("user rsu-1\n")[1].split("\n\n")[0].splitlines()
    assert block == [
        "topic write rfsas/v1/bearing/rsu-1/#",
        "topic read rfsas/v1/nonce/rsu-1/+",
    ]
    assert "user car-7\ntopic read rfsas/v1/advisory/#" in acl
    # a second run keeps the CA and the certificates
    again = CliRunner().invoke(cli, args)
    assert again.exit_code == 0 and "new certificate" not in again.output
    assert x509.load_pem_x509_certificate((out / "clients" / "rsu-1.crt").read_bytes()) == cert
