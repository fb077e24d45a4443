"""``--send``/``--keys``: a command's publisher signs as the sensor in the key directory."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import click
import pytest
from click.testing import CliRunner
from linkhelp import NOW_NS, bearings

from rfsas_hw.cli.linkopts import make_publisher, nonce_inbox, send_options
from rfsas_hw.errors import ConfigError, KeyStoreError
from rfsas_hw.link import Receiver, ReceiverConfig, open_transport
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.records import Pose


def test_no_send_no_publisher_and_send_needs_keys(tmp_path: Path) -> None:
    assert make_publisher(None, None, Pose(0, 0, 0)) is None
    with pytest.raises(ConfigError, match="--send needs --keys"):
        make_publisher("udp://127.0.0.1:9", None, Pose(0, 0, 0))
    KeyStore.create(tmp_path / "be", "backend")
    with pytest.raises(KeyStoreError, match="does not sign"):
        make_publisher("udp://127.0.0.1:9", tmp_path / "be", Pose(0, 0, 0))


def test_publisher_from_keys_is_verified_by_an_enrolling_backend(tmp_path: Path) -> None:
    sensor = KeyStore.create(tmp_path / "rsu-7", "sensor")
    backend = KeyStore.create(tmp_path / "obu", "backend")
    backend.trust.enroll(sensor.card)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"udp://127.0.0.1:{port}"
    rx = Receiver.listen(
        url, backend.trust, config=ReceiverConfig(check_epoch=False), clock=lambda: NOW_NS
    )
    pub = make_publisher(url, tmp_path / "rsu-7", Pose(1, 2, 3))
    assert pub is not None
    pub.clock = lambda: NOW_NS
    pub.on_bearings(bearings("any", 4, NOW_NS))
    pub.close()
    got = []
    for _ in range(20):
        got += rx.receive(0.05)
        if got:
            break
    rx.close()
    assert [m.sender_id for m in got] == ["rsu-7"] and len(got[0].bearings) == 4


def test_options_appear_on_a_command() -> None:
    seen: dict[str, object] = {}

    @click.command()
    @send_options
    def cmd(send: str | None, keys_dir: Path | None) -> None:
        seen.update(send=send, keys=keys_dir)

    result = CliRunner().invoke(cmd, ["--send", "udp://127.0.0.1:1", "--keys", "k"])
    assert result.exit_code == 0, result.output
    assert seen == {"send": "udp://127.0.0.1:1", "keys": Path("k")}
    assert "--send" in CliRunner().invoke(cmd, ["--help"]).output


def test_nonce_inbox_from_options(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="--nonces needs --keys"):
        nonce_inbox("udp://127.0.0.1:9", None)
    sensor = KeyStore.create(tmp_path / "rsu-7", "sensor")
    with pytest.raises(KeyStoreError, match="no nonce authority enrolled"):
        nonce_inbox("udp://127.0.0.1:9", sensor.path)
    auth = KeyStore.create(tmp_path / "auth", "authority")
    sensor.trust.enroll(auth.card)
    auth.trust.enroll(sensor.card)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    inbox = nonce_inbox(f"udp://127.0.0.1:{port}", sensor.path, wait_s=5.0)
    authority = auth.nonce_authority()
    epoch = authority.schedule.epoch_of(time.time_ns())
    try:
        with open_transport(f"udp://127.0.0.1:{port}", "send") as tx:
            tx.send(authority.seal("rsu-7", epoch))
        assert inbox.nonce_for(epoch) == authority.nonce_for(epoch)
    finally:
        inbox.close()
