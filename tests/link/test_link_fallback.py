"""Out-of-band fallback: a stalled or congested primary moves traffic to the secondary and back.

The primary path runs through a relay on loopback that the test can stall
(drop everything) or congest (hold every datagram 300 ms); the secondary goes
straight to its listener. The sender's alarm is the latency watch of the
receiver's primary path.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import click
import pytest
from click.testing import CliRunner
from linkhelp import NOW_NS, bearings, key, message

from rfsas_hw.cli.linkopts import make_publisher, send_options
from rfsas_hw.cli.main import main
from rfsas_hw.errors import ConfigError, LinkError
from rfsas_hw.link import Signer, TrustedKeys
from rfsas_hw.link.fallback import FallbackConfig, FallbackReceiver, FallbackSender
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.latency import LatencyConfig
from rfsas_hw.link.receiver import ReceiverConfig
from rfsas_hw.link.transport import Transport, open_transport
from rfsas_hw.records import Pose

BUDGET_S = 0.1


class Relay:
    """Forwards UDP datagrams from its own port to ``target``: ``pass``, ``stall`` or ``delay``."""

    def __init__(self, target: tuple[str, int]) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.01)
        self.target = target
        self.mode = "pass"
        self._held: list[tuple[float, bytes]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"udp://127.0.0.1:{self.sock.getsockname()[1]}"

    def _run(self) -> None:
        out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                data = b""
            now = time.monotonic()
            if data and self.mode == "pass":
                out.sendto(data, self.target)
            elif data and self.mode == "delay":
                self._held.append((now + 0.3, data))
            while self._held and self._held[0][0] <= now:
                out.sendto(self._held.pop(0)[1], self.target)
        out.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()


@pytest.fixture
def link() -> Iterator[tuple[FallbackReceiver, Relay, FallbackSender, Signer]]:
    signer = Signer("backend", key(0x2468))
    trust = TrustedKeys({"backend": signer.public_key})
    config = ReceiverConfig(
        check_epoch=False,
        latency=LatencyConfig(budget_s=BUDGET_S, silent_s=0.25, min_samples=3),
    )
    rx = FallbackReceiver.listen("udp://127.0.0.1:0", "udp://127.0.0.1:0", trust, config)
    primary_addr = rx.primary.transport.address  # type: ignore[union-attr]
    secondary_addr = rx.secondary.transport.address  # type: ignore[union-attr]
    relay = Relay(primary_addr)
    tx = FallbackSender.to_urls(
        relay.url,
        f"udp://{secondary_addr[0]}:{secondary_addr[1]}",
        alarm=lambda: rx.primary_alarm,
        config=FallbackConfig(hold_s=0.4),
    )
    try:
        yield rx, relay, tx, signer
    finally:
        tx.close()
        rx.close()
        relay.close()


@pytest.mark.parametrize("trouble", ["stall", "delay"])
def test_traffic_moves_to_the_secondary_and_back_without_duplicates(
    link: tuple[FallbackReceiver, Relay, FallbackSender, Signer], trouble: str
) -> None:
    rx, relay, tx, signer = link
    sent_at: dict[int, float] = {}
    got: list[tuple[int, str, float]] = []
    phases = [("pass", 0.5), (trouble, 1.5), ("pass", 2.0)]
    seq = 0
    t_start = time.monotonic()
    trouble_from = trouble_to = 0.0
    for mode, length in phases:
        relay.mode = mode
        if mode != "pass":
            trouble_from = time.monotonic() - t_start
        elif trouble_from and not trouble_to:
            trouble_to = time.monotonic() - t_start
        end = time.monotonic() + length
        while time.monotonic() < end:
            t_ns = time.time_ns()
            tx.send(signer.encode(message("backend", n=1, t_gen_ns=t_ns, seq=seq)))
            sent_at[seq] = time.monotonic() - t_start
            seq += 1
            for path, m in rx.receive(timeout=0.02):
                got.append((m.message.seq, path, m.age_s))
    for path, m in rx.receive(timeout=0.4):
        got.append((m.message.seq, path, m.age_s))
    counts = Counter(s for s, _, _ in got)
    assert max(counts.values()) == 1, "a message reached the backend twice"
    assert tx.stats.switches == {"to_secondary": 1, "to_primary": 1}
    assert tx.active == "primary"
    # once the alarm is up (silence or lateness is seen within ~0.5 s), nothing is lost
    # and every message comes within the budget, through the secondary
    settled = [s for s, t in sent_at.items() if trouble_from + 0.5 <= t < trouble_to]
    assert len(settled) > 20
    by_seq = {s: (path, age) for s, path, age in got}
    for s in settled:
        assert s in by_seq, f"seq {s} lost after the switch"
        path, age = by_seq[s]
        assert path == "secondary" and age <= BUDGET_S
    # before the trouble and at the end, traffic is on the primary
    first = [s for s, t in sent_at.items() if t < trouble_from - 0.05]
    assert all(by_seq[s][0] == "primary" for s in first if s in by_seq)
    assert by_seq[seq - 1][0] == "primary"
    assert rx.duplicates > 0  # the copies on the primary were seen and dropped


class _Broken(Transport):
    def send(self, datagram: bytes) -> None:
        raise LinkError("no route")

    def recv(self, timeout: float | None = None) -> bytes | None:
        return None

    def close(self) -> None:
        pass


def test_send_errors_alone_raise_the_alarm_and_nothing_is_lost() -> None:
    listener = open_transport("udp://127.0.0.1:0", "recv")
    host, port = listener.address
    secondary = open_transport(f"udp://{host}:{port}", "send")
    clock = [0.0]
    tx = FallbackSender(
        _Broken(), secondary, config=FallbackConfig(hold_s=1.0), clock=lambda: clock[0]
    )
    try:
        for k in range(5):
            tx.send(bytes([k]))
            clock[0] += 0.1
        received = [listener.recv(1.0) for _ in range(5)]
        assert received == [bytes([k]) for k in range(5)]
        assert tx.active == "secondary" and tx.stats.primary_errors == 5
        with pytest.raises(LinkError, match="cannot receive"):
            tx.recv(0)
    finally:
        tx.close()
        listener.close()


def test_send_and_fallback_options_build_a_fallback_publisher(tmp_path: Path) -> None:
    sensor = KeyStore.create(tmp_path / "rsu-7", "sensor")
    primary = open_transport("udp://127.0.0.1:0", "recv")
    secondary = open_transport("udp://127.0.0.1:0", "recv")
    seen: dict[str, object] = {}

    @click.command()
    @send_options
    def cmd(send: str | None, keys_dir: Path | None) -> None:
        pub = make_publisher(send, keys_dir, Pose(1, 2, 3))
        assert pub is not None
        seen["transport"] = pub.transport
        pub.on_bearings(bearings("any", 2, NOW_NS))
        pub.close()

    def url(t: Transport) -> str:
        host, port = t.address  # type: ignore[attr-defined]
        return f"udp://{host}:{port}"

    try:
        args = ["--send", url(primary), "--fallback", url(secondary), "--keys", str(sensor.path)]
        result = CliRunner().invoke(cmd, args)
        assert result.exit_code == 0, result.output
        assert isinstance(seen["transport"], FallbackSender)
        # a healthy primary carries everything; the secondary stays quiet
        assert primary.recv(1.0) is not None and secondary.recv(0.2) is None
    finally:
        primary.close()
        secondary.close()

    @click.command()
    @send_options
    def lonely(send: str | None, keys_dir: Path | None) -> None:
        make_publisher(send, keys_dir, Pose(0, 0, 0))

    result = CliRunner().invoke(lonely, ["--fallback", "udp://127.0.0.1:9"])
    assert isinstance(result.exception, ConfigError)
    assert "give --send too" in str(result.exception)


def test_link_watch_with_a_fallback_counts_each_message_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    backend = KeyStore.create(tmp_path / "obu-1", "backend")
    backend.trust.enroll(sensor.card)
    ports = []
    for _ in range(2):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            ports.append(s.getsockname()[1])
    primary, secondary = (f"udp://127.0.0.1:{p}" for p in ports)
    stop = threading.Event()

    def send() -> None:
        # every message on the secondary; every other one also on the primary
        a, b = open_transport(primary, "send"), open_transport(secondary, "send")
        signer = sensor.signer()
        seq = 0
        while not stop.wait(0.02):
            now = time.time_ns()
            datagram = signer.encode(message("rsu-1", n=1, t_gen_ns=now, seq=seq))
            if seq % 2 == 0:
                a.send(datagram)
            b.send(datagram)
            seq += 1
        a.close()
        b.close()

    worker = threading.Thread(target=send)
    worker.start()
    try:
        main(["link", "watch", "--listen", primary, "--fallback", secondary, "--keys",
              str(backend.path), "--duration", "1.5", "--json", "--no-epoch-check"])  # fmt: skip
    finally:
        stop.set()
        worker.join()
    status = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    fb = status["fallback"]
    delivered = fb["delivered"]["primary"] + fb["delivered"]["secondary"]
    # everything was delivered once; what came both ways was counted as a duplicate
    assert fb["stats"]["verified"] + status["stats"]["verified"] == delivered + fb["duplicates"]
    assert fb["duplicates"] >= 10 and fb["delivered"]["secondary"] >= 10
    assert status["stats"]["verified"] >= 10
