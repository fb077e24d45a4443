"""What the broker set-up refuses: a host that would inject config lines, a client
certificate in the folder that this CA did not issue for its id, world-writable
files under umask 000, and a client started with another identity's certificate."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from cryptography import x509

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "cli"))

from clihelp import run, write_calibration, write_capture

from rfsas_hw.cli.exitcodes import BAD_INPUT, OK
from rfsas_hw.fleet.broker import write_broker_config
from rfsas_hw.fleet.pki import CertificateAuthority
from rfsas_hw.link.keys import KeyStore


@pytest.fixture
def authority(tmp_path: Path) -> Path:
    auth = KeyStore.create(tmp_path / "auth-0", "authority")
    auth.trust.enroll(KeyStore.create(tmp_path / "rsu-1", "sensor").card)
    auth.trust.enroll(KeyStore.create(tmp_path / "rsu-2", "sensor").card)
    return auth.path


@pytest.mark.parametrize(
    "host",
    ["localhost\nlistener 1883\nallow_anonymous true", "a b", "", "-x", "evil;host", "a" * 254],
)
def test_a_host_that_is_not_an_address_or_name_is_refused(
    tmp_path: Path, authority: Path, capsys: pytest.CaptureFixture[str], host: str
) -> None:
    out = tmp_path / "broker"
    args = ["broker", "config", "--keys", str(authority), "--out", str(out), "--host", host]
    code, _, err = run(args, capsys)
    assert code == BAD_INPUT and "--host" in err and "Traceback" not in err, err
    assert not (out / "broker" / "mosquitto.conf").exists()


def test_a_dns_name_is_not_the_bind_address(tmp_path: Path, authority: Path) -> None:
    files = write_broker_config(authority, tmp_path / "b", host="broker.example", run_as=None)
    lines = files.conf.read_text().splitlines()
    assert "listener 8883" in lines  # every address: the name need not be one of this host's
    server = x509.load_pem_x509_certificate((files.root / "broker" / "server.crt").read_bytes())
    names = server.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "broker.example" in names.get_values_for_type(x509.DNSName)
    local = write_broker_config(authority, tmp_path / "c", host="127.0.0.1", run_as=None)
    assert "listener 8883 127.0.0.1" in local.conf.read_text().splitlines()


def test_a_certificate_this_ca_did_not_issue_for_the_id_is_replaced(
    tmp_path: Path, authority: Path
) -> None:
    out = tmp_path / "b"
    files = write_broker_config(authority, out, run_as=None)
    ca = CertificateAuthority.load(out / "ca")
    other = CertificateAuthority.create(tmp_path / "other-ca")
    clients = out / "clients"
    # rsu-1's files: a certificate of another CA; rsu-2's: rsu-1's certificate copied over
    for path in (clients / "rsu-1.crt", clients / "rsu-1.key"):
        path.unlink()
    other.issue("rsu-1", clients, "rsu-1")
    for suffix in (".crt", ".key"):
        (clients / f"rsu-2{suffix}").unlink()
    ca.issue("rsu-1", tmp_path / "spare", "rsu-1")
    for suffix in (".crt", ".key"):
        copied = (tmp_path / "spare" / f"rsu-1{suffix}").read_bytes()
        (clients / f"rsu-2{suffix}").write_bytes(copied)
    again = write_broker_config(authority, out, run_as=None)
    assert set(again.replaced) == {"rsu-1", "rsu-2"}
    assert "auth-0" not in again.issued  # its own certificate is this CA's: kept
    for ident in ("rsu-1", "rsu-2"):
        cert = x509.load_pem_x509_certificate((clients / f"{ident}.crt").read_bytes())
        cert.verify_directly_issued_by(ca.cert)
        assert cert.subject.rfc4514_string() == f"CN={ident}"
    assert files.issued  # the first run issued them all


def test_files_are_not_writable_by_others_under_umask_000(tmp_path: Path, authority: Path) -> None:
    old = os.umask(0)
    try:
        files = write_broker_config(authority, tmp_path / "b", run_as=None)
    finally:
        os.umask(old)
    for path in (files.conf, files.acl):
        assert path.stat().st_mode & 0o777 == 0o644, path
    for d in ("ca", "broker", "clients"):
        assert (files.root / d).stat().st_mode & 0o022 == 0, d
    assert (files.root / "ca").stat().st_mode & 0o077 == 0


def test_a_sender_with_another_identitys_certificate_is_refused_at_start(
    tmp_path: Path, authority: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    files = write_broker_config(authority, tmp_path / "b", run_as=None)
    cap = write_capture(tmp_path / "cap.pcap", n=20, span_s=2.0)
    cal = write_calibration(tmp_path / "cal.yaml")
    url = files.url("rsu-2").replace(":8883", ":1")  # nothing listens: no connection is tried
    args = ["replay", str(cap), "--calibration", str(cal), "--keys", str(tmp_path / "rsu-1")]
    code, _, err = run([*args, "--send", url], capsys)
    assert code == BAD_INPUT and "Traceback" not in err, err
    assert "issued to 'rsu-2'" in err and "'rsu-1'" in err
    # the right certificate passes this check (and then fails to connect: nobody listens)
    code, _, err = run([*args, "--send", files.url("rsu-1").replace(":8883", ":1")], capsys)
    assert "issued to" not in err and code != OK
