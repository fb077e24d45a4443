"""``rfsas backend`` with a nonce authority enrolled requires version 2: an outsider's
flood of version-1 datagrams under an enrolled sensor's id is refused for the price of
a header check and never spends that sensor's signature budget; ``--accept-v1`` is the
explicit opt-out for a fleet still migrating."""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from backendhelp import bearing_towards
from click.testing import CliRunner
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.cli.backend import backend
from rfsas_hw.link import Publisher, Signer, open_transport
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.message import SafetyMessage
from rfsas_hw.privacy.epochs import EpochSchedule, epoch_of
from rfsas_hw.records import BearingBatch, Pose

POSE = Pose(-35.0, 10.0, 90.0)
ROUNDS = 15
FLOOD_PER_ROUND = 150
"""Forged version-1 datagrams per legitimate message (2,250 in all: more than the
sender's burst of 2,000 signature checks)."""


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def bound(port: int) -> bool:
    """True once someone (the backend) has bound the UDP port."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False


def run_flood(tmp_path: Path, *extra: str) -> tuple[dict[str, int], int, int]:
    """Run the backend for a few seconds against one honest version-2 sensor and a
    version-1 flood under its id; the final stats line, honest and forged sent."""
    auth = KeyStore.create(tmp_path / "auth", "authority", "auth-0")
    be = KeyStore.create(tmp_path / "be", "backend", "be-1")
    rsu = KeyStore.create(tmp_path / "rsu", "sensor", "rsu-n")
    be.trust.enroll(rsu.card)
    be.trust.enroll(auth.card)
    auth.trust.enroll(be.card)
    auth.trust.enroll(rsu.card)
    authority = auth.nonce_authority(EpochSchedule(60.0, 5.0))
    port = free_port()
    url = f"udp://127.0.0.1:{port}"
    sent = {"honest": 0, "forged": 0}
    failure: list[BaseException] = []

    def send() -> None:
        try:
            deadline = time.monotonic() + 20
            while not bound(port) and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(0.2)  # the command binds, then enters its loop
            link = open_transport(url, "send")
            honest = Publisher.to_url(url, rsu.signer(), POSE, preauth=authority)
            outsider = Signer("rsu-n", ec.generate_private_key(ec.SECP256R1()))
            try:
                for epoch in authority.due(time.time_ns()):
                    link.send(authority.seal("be-1", epoch))
                time.sleep(0.1)
                for i in range(ROUNDS):
                    now = time.time_ns()
                    batch = bearing_towards("rsu-n", POSE, np.array([0.0, 20.0]), 7 + i, now)
                    honest.on_bearings(batch)
                    sent["honest"] += 1
                    for j in range(FLOOD_PER_ROUND):
                        forged = outsider.encode(forgery(batch, i * 1000 + j))
                        link.send(forged)
                        sent["forged"] += 1
                        if j % 25 == 24:
                            time.sleep(0.002)  # paced: the socket buffer is not the test
                    time.sleep(0.05)
            finally:
                honest.close()
                link.close()
        except BaseException as err:  # reported by the test, not lost in the thread
            failure.append(err)

    sender = threading.Thread(target=send)
    sender.start()
    out = tmp_path / "run.jsonl"
    args = ["--listen", url, "--keys", str(be.path), "--out", str(out), "--duration", "6"]
    result = CliRunner().invoke(backend, [*args, "--no-table", *extra])
    sender.join(30)
    assert not sender.is_alive() and not failure, failure
    assert result.exit_code == 0, result.output
    stats = json.loads(out.read_text().splitlines()[-1])
    return stats, sent["honest"], sent["forged"]


def forgery(batch: BearingBatch, seq: int) -> SafetyMessage:
    """A version-1 message under the honest sensor's id and pose (signed by an outsider)."""
    t_ns = int(batch.t_ns.min())
    return SafetyMessage("rsu-n", POSE, t_ns // 1000, seq, epoch_of(t_ns), batch)


def test_version_1_flood_is_refused_by_default(tmp_path: Path) -> None:
    stats, honest, forged = run_flood(tmp_path)
    rejected = {k: v for k, v in stats.items() if k.startswith("link.rejected.")}
    # every forged datagram that arrived is refused for its version, none costs a
    # signature check, and every honest message is verified
    assert stats["link.verified"] == honest
    assert set(rejected) == {"link.rejected.v1_refused"}
    assert rejected["link.rejected.v1_refused"] == stats["link.datagrams"] - honest - 2
    assert rejected["link.rejected.v1_refused"] > 0.9 * forged


@pytest.mark.parametrize("flag", ["--accept-v1"])
def test_accept_v1_is_the_explicit_opt_out(tmp_path: Path, flag: str) -> None:
    stats, _, _ = run_flood(tmp_path, flag)
    # version 1 is read again: the forgeries reach the signature check and fail there
    assert stats.get("link.rejected.v1_refused", 0) == 0
    assert stats.get("link.rejected.bad_signature", 0) > 0
