"""--send: the bridge's bearings as signed safety messages over a real UDP socket, verified by
the link's receiver, and no raw MAC on the wire."""

from __future__ import annotations

import base64
import json
import re
import socket
from pathlib import Path

import pytest

from rfsas_hw.bridges.bridge import Bridge, Entity
from rfsas_hw.bridges.config import bridge_config_from_mapping
from rfsas_hw.errors import KeyStoreError
from rfsas_hw.link import Receiver, TrustedKeys
from rfsas_hw.link.keys import KeyStore

from .helpers import config_data


def _forms(mac: str) -> list[re.Pattern[bytes]]:
    raw = bytes.fromhex(mac.replace(":", ""))
    pairs = [f"{b:02x}".encode() for b in raw]
    return [
        re.compile(rb"[^0-9a-fA-F]{0,3}".join(pairs), re.IGNORECASE),
        re.compile(re.escape(raw)),
        re.compile(re.escape(raw[::-1])),
        re.compile(re.escape(base64.b64encode(raw))),
    ]


def test_signed_messages_verify_and_carry_no_mac(tmp_path: Path) -> None:
    cfg = bridge_config_from_mapping(config_data(), "u")
    trust = TrustedKeys()
    for uid in ("rsu-nw", "rsu-ne", "rsu-se", "ego-unit"):
        store = KeyStore.create(tmp_path / "keys" / uid, "sensor", uid)
        trust.enroll(uid, store.signer().public_key)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.5)
    host, port = sock.getsockname()
    datagrams: list[tuple[bytes, int]] = []
    truth = tmp_path / "truth.jsonl"
    with Bridge(cfg, truth_path=truth) as bridge:
        bridge.publish_to(f"udp://{host}:{port}", tmp_path / "keys")
        sent = 0
        for k in range(25):
            t = 0.1 * k
            car = Entity("car", "vehicle", 1.75, -60.0 + 10.0 * t, 0.0, 10.0, 4.5, 1.8)
            ped = Entity("p1", "pedestrian", -10.0 + 1.4 * t, -4.0, 90.0, 1.4)
            out = bridge.step(t, car, [ped])
            sent += sum(len(b) for b in out.bearings.values())
            sock.setblocking(False)
            while True:
                try:
                    datagrams.append((sock.recv(2048), out.t_ns))
                except BlockingIOError:
                    break
    sock.close()
    assert sent > 50 and len(datagrams) > 20
    receiver = Receiver(trust, clock=lambda: 0)
    verified = [receiver.feed(d, t_ns) for d, t_ns in datagrams]
    ok = [v for v in verified if v is not None]
    assert len(ok) == len(datagrams), receiver.stats.as_dict()
    assert sum(len(v.bearings) for v in ok) == sent
    assert {v.bearings.sensor_id for v in ok} >= {"rsu-nw", "rsu-se"}
    macs = [json.loads(x)["mac"] for x in truth.read_text().splitlines() if '"device"' in x]
    assert macs
    wire = b"".join(d for d, _ in datagrams)
    for mac in macs:
        for pattern in _forms(mac):
            assert not pattern.search(wire), f"{mac} on the wire as {pattern.pattern!r}"


def test_missing_keys_are_named(tmp_path: Path) -> None:
    cfg = bridge_config_from_mapping(config_data(), "u")
    with Bridge(cfg) as bridge, pytest.raises(KeyStoreError):
        bridge.publish_to("udp://127.0.0.1:9", tmp_path / "nokeys")
