"""Faults ridden out are logged when they start and when they end, and do not fail the
run: ``rfsas nonces serve`` through a broker that is killed and restarted exits 0 and
says so; a publisher whose link comes back has no problem to report, one whose link is
still down at the end has."""

from __future__ import annotations

import logging
import select
import subprocess
import sys
import time

import pytest
from brokerhelp import Broker, Deployment
from cryptography.hazmat.primitives.asymmetric import ec
from fleethelp import bearings_now

from rfsas_hw.errors import LinkError
from rfsas_hw.link import Publisher, Signer
from rfsas_hw.link.transport import Transport
from rfsas_hw.records import Pose


def test_nonces_serve_rides_out_a_broker_outage(broker: Broker, deployment: Deployment) -> None:
    cmd = [
        sys.executable, "-m", "rfsas_hw.cli.main", "nonces", "serve",
        "--keys", str(deployment.authority.path),
        "--to", f"rsu-1={broker.url('auth-0')}", "--resend", "0.3", "--duration", "16",
    ]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready, "the authority did not start"
        first = proc.stdout.readline()  # printed once its transports are connected
        assert b"1 of 4 enrolled receivers reachable" in first, first
        time.sleep(1.0)
        broker.kill()
        time.sleep(2.0)
        broker.start()
        rest, err = proc.communicate(timeout=60)
        out = first + rest
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    text = err.decode(errors="replace")
    assert proc.returncode == 0, text + out.decode(errors="replace")
    assert "lost the broker" in text and "connected to the broker again" in text
    assert "nonces for rsu-1 cannot be sent" in text and "nonces for rsu-1 are sent again" in text
    summary = out.decode().splitlines()[-1]
    assert summary.startswith("envelopes sent: rsu-1 ") and "send errors: 0" not in summary


class Flaky(Transport):
    """Refuses sends while ``down``."""

    def __init__(self) -> None:
        self.down = False
        self.sent = 0

    def send(self, datagram: bytes) -> None:
        if self.down:
            raise LinkError("broker unreachable")
        self.sent += 1

    def recv(self, timeout: float | None = None) -> bytes | None:
        return None

    def close(self) -> None:
        pass


def test_a_publisher_reports_an_outage_only_while_it_lasts(
    caplog: pytest.LogCaptureFixture,
) -> None:
    link = Flaky()
    pub = Publisher(Signer("rsu-1", ec.generate_private_key(ec.SECP256R1())), link, Pose(0, 0, 0))
    with caplog.at_level(logging.WARNING, logger="rfsas_hw.link.publisher"):
        pub.on_bearings(bearings_now("rsu-1", 2, seed=1))
        link.down = True
        for seed in range(3):
            pub.on_bearings(bearings_now("rsu-1", 2, seed=seed))
        assert pub.problem() is not None and "still failing at the end" in str(pub.problem())
        link.down = False
        pub.on_bearings(bearings_now("rsu-1", 2, seed=9))
    assert pub.problem() is None  # ridden out: counted, logged, not a failed run
    assert pub.counters()["dropped.send_error"] == 6 and pub.counters()["sent"] == 4
    assert "cannot send (broker unreachable)" in caplog.text
    assert "sending again, 6 bearings lost meanwhile" in caplog.text
