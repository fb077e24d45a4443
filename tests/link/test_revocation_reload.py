"""A revocation reaches a running receiver: the trust directory is looked at again at
most every ``reload_s`` seconds by :meth:`Receiver.receive`, so a sensor revoked with
``rfsas keys revoke`` (another process) is refused from then on without a restart."""

from __future__ import annotations

import logging
import socket
import time
from pathlib import Path

import pytest
from click.testing import CliRunner
from linkhelp import POSE, bearings

from rfsas_hw.cli.keys import keys
from rfsas_hw.link import Publisher, Receiver
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.privacy.nonces import NonceEnvelopeError


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_trust_directory_refresh_is_bounded_and_fail_safe(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    backend = KeyStore.create(tmp_path / "obu-1", "backend")
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    other = KeyStore.create(tmp_path / "rsu-2", "sensor")
    trust = backend.trust
    trust.reload_s = 5.0
    KeyStore.open(backend.path).trust.enroll(sensor.card)  # by another process
    t0 = time.monotonic() + 100
    assert trust.refresh(t0) and trust.signing_key("rsu-1") is not None
    KeyStore.open(backend.path).trust.revoke("rsu-1")
    assert not trust.refresh(t0 + 1.0)  # not looked at again before reload_s ...
    assert trust.signing_key("rsu-1") is not None
    assert trust.refresh(t0 + 5.0)  # ... and taken up at reload_s
    assert trust.signing_key("rsu-1") is None
    assert not trust.refresh(t0 + 10.0)  # nothing changed: not re-read
    # a card that does not read keeps the others, but never a revoked one
    KeyStore.open(backend.path).trust.enroll(sensor.card)
    KeyStore.open(backend.path).trust.enroll(other.card)
    assert trust.refresh(t0 + 15.0) and len(trust) == 2
    (trust.path / "rsu-2.yaml").write_text("rfsas-key-card: 1\nid: rsu-2\n")
    (trust.path / "rsu-1.yaml").unlink()
    with caplog.at_level(logging.ERROR, logger="rfsas_hw.link.keys"):
        assert not trust.refresh(t0 + 20.0)
    assert "rsu-2.yaml" in caplog.text
    assert trust.signing_key("rsu-1") is None and trust.signing_key("rsu-2") is not None


def test_a_running_receiver_refuses_a_revoked_sensor(tmp_path: Path) -> None:
    backend = KeyStore.create(tmp_path / "obu-1", "backend")
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    backend.trust.enroll(sensor.card)
    backend.trust.reload_s = 0.2
    url = f"udp://127.0.0.1:{free_port()}"
    rx = Receiver.listen(url, backend.trust)
    pub = Publisher.to_url(url, sensor.signer(), POSE)
    try:

        def send_and_receive() -> tuple[int, int]:
            before = rx.stats.rejected["unknown_sender"]
            pub.on_bearings(bearings("rsu-1", 2, time.time_ns()))
            got = rx.receive(timeout=0.5)
            return len(got), rx.stats.rejected["unknown_sender"] - before

        assert send_and_receive() == (1, 0)
        result = CliRunner().invoke(keys, ["revoke", str(backend.path), "rsu-1"])
        assert result.exit_code == 0, result.output
        deadline = time.monotonic() + 20
        outcome = send_and_receive()
        while outcome != (0, 1) and time.monotonic() < deadline:
            outcome = send_and_receive()
        assert outcome == (0, 1)  # refused as unknown, without a restart
        assert [send_and_receive() for _ in range(3)] == [(0, 1)] * 3  # and stays refused
    finally:
        pub.close()
        rx.close()


def test_a_running_authority_stops_sealing_for_a_revoked_receiver(tmp_path: Path) -> None:
    auth = KeyStore.create(tmp_path / "rsu-0", "authority")
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    auth.trust.enroll(sensor.card)
    authority = auth.nonce_authority()
    assert authority.receivers == ("rsu-1",) and authority.seal("rsu-1", 1)
    KeyStore.open(auth.path).trust.revoke("rsu-1")
    # what `rfsas nonces serve` does every loop
    assert auth.trust.refresh(time.monotonic() + auth.trust.reload_s)
    authority.enroll_only(auth.trust.receivers())
    assert authority.receivers == ()
    with pytest.raises(NonceEnvelopeError, match="not enrolled"):
        authority.seal("rsu-1", 1)
