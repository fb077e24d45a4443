"""Key directories: 0600 private keys, no overwrite, cards, enrolment, and the CLI."""

from __future__ import annotations

import stat
from pathlib import Path

import pytest
from linkhelp import NOW_NS, message

from rfsas_hw.cli.main import main
from rfsas_hw.errors import KeyStoreError
from rfsas_hw.link import Receiver
from rfsas_hw.link.keys import KeyCard, KeyStore


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    try:
        main(list(args))
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_new_sensor_writes_private_keys_0600_and_a_card(tmp_path: Path) -> None:
    store = KeyStore.create(tmp_path / "rsu-1", "sensor")
    assert store.id == "rsu-1" and store.role == "sensor"
    assert mode(tmp_path / "rsu-1" / "sign.key") == 0o600
    assert mode(tmp_path / "rsu-1" / "kx.key") == 0o600
    assert mode(tmp_path / "rsu-1") == 0o700
    card = KeyCard.load(tmp_path / "rsu-1")
    assert card.fingerprint == store.card.fingerprint
    assert "PRIVATE" not in (tmp_path / "rsu-1" / "identity.yaml").read_text()
    # the signer on disk matches the card, and a receiver trusting the card verifies it
    signer = KeyStore.open(tmp_path / "rsu-1").signer()
    trust_dir = KeyStore.create(tmp_path / "obu", "backend").trust
    trust_dir.enroll(card)
    rx = Receiver(trust_dir)
    assert rx.feed(signer.encode(message("rsu-1")), NOW_NS) is not None


def test_refuses_to_overwrite(tmp_path: Path) -> None:
    KeyStore.create(tmp_path / "a", "authority")
    before = (tmp_path / "a" / "kx.key").read_bytes()
    with pytest.raises(KeyStoreError, match="refusing to overwrite"):
        KeyStore.create(tmp_path / "a", "authority")
    assert (tmp_path / "a" / "kx.key").read_bytes() == before


def test_roles_hold_the_keys_they_need(tmp_path: Path) -> None:
    auth = KeyStore.create(tmp_path / "auth", "authority")
    backend = KeyStore.create(tmp_path / "be", "backend", "backend-1")
    assert not (tmp_path / "auth" / "sign.key").exists()
    assert backend.id == "backend-1"
    with pytest.raises(KeyStoreError, match="does not sign"):
        auth.signer()
    assert auth.kx_private().public_key().public_bytes_raw() == (
        auth.card.kx_public.public_bytes_raw()  # type: ignore[union-attr]
    )
    with pytest.raises(KeyStoreError, match="role 'car' is not one of"):
        KeyStore.create(tmp_path / "x", "car")
    with pytest.raises(KeyStoreError, match="sender id"):
        KeyStore.create(tmp_path / "y", "sensor", "no spaces")


def test_too_open_private_key_is_refused(tmp_path: Path) -> None:
    store = KeyStore.create(tmp_path / "s", "sensor")
    (tmp_path / "s" / "sign.key").chmod(0o644)
    with pytest.raises(KeyStoreError, match="0644 are too open"):
        store.signer()


def test_swapped_key_file_does_not_match_the_card(tmp_path: Path) -> None:
    a = KeyStore.create(tmp_path / "a", "sensor")
    KeyStore.create(tmp_path / "b", "sensor")
    (tmp_path / "a" / "sign.key").unlink()
    (tmp_path / "b" / "sign.key").rename(tmp_path / "a" / "sign.key")
    with pytest.raises(KeyStoreError, match="does not match"):
        a.signer()


def test_enrolment_refuses_a_different_key_under_the_same_id(tmp_path: Path) -> None:
    backend = KeyStore.create(tmp_path / "be", "backend")
    first = KeyStore.create(tmp_path / "one", "sensor", "rsu-1").card
    second = KeyStore.create(tmp_path / "two", "sensor", "rsu-1").card
    backend.trust.enroll(first)
    backend.trust.enroll(first)  # the same card again is fine
    with pytest.raises(KeyStoreError, match="already enrolled with fingerprint"):
        backend.trust.enroll(second)
    backend.trust.enroll(second, replace=True)
    reopened = KeyStore.open(tmp_path / "be")
    assert reopened.trust.signing_key("rsu-1") is not None
    assert reopened.trust.get("rsu-1").fingerprint == second.fingerprint  # type: ignore[union-attr]
    reopened.trust.revoke("rsu-1")
    assert KeyStore.open(tmp_path / "be").trust.signing_key("rsu-1") is None


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("just text", "not an rfsas key card"),
        ("rfsas-key-card: 1\nid: a\nrole: sensor\nkx_x25519: AAAA\n", "bad public key"),
        ("rfsas-key-card: 1\nid: a\nrole: king\n", "role 'king'"),
        ("rfsas-key-card: 1\nid: a\nrole: backend\nextra: 1\n", "unknown key"),
        ("rfsas-key-card: 1\nid: a\nrole: backend\n", "needs kx_x25519"),
        ("rfsas-key-card: [\n", "invalid YAML"),
    ],
)
def test_bad_cards(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "card.yaml"
    path.write_text(text)
    with pytest.raises(KeyStoreError, match=match):
        KeyCard.load(path)


def test_cli_new_show_export_enroll_revoke(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sensor, auth = str(tmp_path / "rsu-1"), str(tmp_path / "auth")
    code, out, _ = run(capsys, "keys", "new", "--role", "sensor", "-o", sensor)
    assert code == 0 and "fingerprint" in out
    assert run(capsys, "keys", "new", "--role", "authority", "-o", auth)[0] == 0
    code, _, err = run(capsys, "keys", "new", "--role", "sensor", "-o", sensor)
    assert code == 2 and "refusing to overwrite" in err
    card_file = tmp_path / "rsu-1.card.yaml"
    assert run(capsys, "keys", "export", sensor, "-o", str(card_file))[0] == 0
    code, _, err = run(capsys, "keys", "export", sensor, "-o", str(card_file))
    assert code == 2 and "refusing to overwrite" in err
    code, out, _ = run(capsys, "keys", "enroll", auth, str(card_file))
    assert code == 0 and "enrolled sensor 'rsu-1'" in out
    code, _, err = run(capsys, "keys", "enroll", auth, auth)
    assert code == 2 and "own card" in err
    code, out, _ = run(capsys, "keys", "show", auth)
    assert "rsu-1" in out and KeyCard.load(card_file).fingerprint in out
    assert run(capsys, "keys", "revoke", auth, "rsu-1")[0] == 0
    code, _, err = run(capsys, "keys", "revoke", auth, "rsu-1")
    assert code == 2 and "not enrolled" in err
    code, _, err = run(capsys, "keys", "show", str(tmp_path / "nowhere"))
    assert code == 2 and "not a key directory" in err
