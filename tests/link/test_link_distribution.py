"""Nonce distribution end to end: key directories, enrolment, UDP, sensors and backends."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.cli.main import main
from rfsas_hw.errors import KeyStoreError
from rfsas_hw.link import Receiver, open_transport
from rfsas_hw.link.distribution import NonceDistributor, NonceInbox
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.privacy import MacHasher, NonceProvider, NonceUnavailableError
from rfsas_hw.privacy.epochs import NS_PER_S, EpochSchedule

SCHED = EpochSchedule(60.0, 5.0)
NOW = 1_763_800_030 * NS_PER_S
K = SCHED.epoch_of(NOW)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def deployment(tmp_path: Path) -> dict[str, KeyStore]:
    """An authority, a sensor and a backend, enrolled with each other as a user would."""
    auth = KeyStore.create(tmp_path / "auth", "authority", "rsu-0")
    sensor = KeyStore.create(tmp_path / "rsu-1", "sensor")
    backend = KeyStore.create(tmp_path / "obu-1", "backend")
    outsider = KeyStore.create(tmp_path / "eve", "backend")
    auth.trust.enroll(sensor.card)
    auth.trust.enroll(backend.card)
    sensor.trust.enroll(auth.card)
    backend.trust.enroll(auth.card)
    backend.trust.enroll(sensor.card)
    outsider.trust.enroll(auth.card)
    return {"auth": auth, "sensor": sensor, "backend": backend, "eve": outsider}


def test_nonces_reach_enrolled_sensors_and_backends_over_udp(
    deployment: dict[str, KeyStore],
) -> None:
    authority = deployment["auth"].nonce_authority(SCHED)
    assert sorted(authority.receivers) == ["obu-1", "rsu-1"]
    ports = {name: free_port() for name in ("rsu-1", "obu-1", "eve")}
    url = {name: f"udp://127.0.0.1:{port}" for name, port in ports.items()}
    sensor_store = deployment["sensor"].nonce_store(SCHED, clock=lambda: NOW)
    inbox = NonceInbox(sensor_store, open_transport(url["rsu-1"], "recv"), clock=lambda: NOW)
    backend_store = deployment["backend"].nonce_store(SCHED, clock=lambda: NOW)
    rx = Receiver.listen(
        url["obu-1"], deployment["backend"].trust, backend_store, clock=lambda: NOW
    )
    eve_store = deployment["eve"].nonce_store(SCHED, clock=lambda: NOW)
    eve_inbox = NonceInbox(eve_store, open_transport(url["eve"], "recv"), clock=lambda: NOW)
    # eve has an address but is not enrolled: she is sent nothing
    dist = NonceDistributor(
        authority,
        {rid: open_transport(u, "send") for rid, u in url.items()},
        resend_s=5.0,
        clock=lambda: NOW,
    )
    try:
        assert dist.tick() == 4  # two receivers, current and next epoch
        assert dist.tick() == 0  # nothing is due again yet
        assert dist.tick(NOW + 5 * NS_PER_S) == 4  # resent for late starters
        for _ in range(20):
            inbox.poll(0.05)
            rx.receive(0.05)
            if inbox.accepted == 4 and rx.stats.nonces == 4:
                break
        assert eve_inbox.poll(0.2) == 0
    finally:
        dist.close()
        inbox.close()
        eve_inbox.close()
        rx.close()
    assert sensor_store.epochs == backend_store.epochs == (K, K + 1)
    assert dist.sent == {"rsu-1": 4, "obu-1": 4}
    assert eve_store.epochs == () and eve_inbox.accepted == eve_inbox.rejected == 0
    # the sensor, the backend and the authority hash alike
    macs = np.array([0xA4C3F0123456, 0x3C22FB0102AB], np.uint64)
    t = np.full(2, NOW, np.int64)
    providers: list[NonceProvider] = [sensor_store, backend_store, authority]
    ids = [MacHasher(p).hash_batch(macs, t).tolist() for p in providers]
    assert ids[0] == ids[1] == ids[2]


def test_envelopes_for_someone_else_are_refused_by_the_inbox(
    deployment: dict[str, KeyStore],
) -> None:
    authority = deployment["auth"].nonce_authority(SCHED)
    port = free_port()
    store = deployment["sensor"].nonce_store(SCHED, clock=lambda: NOW)
    inbox = NonceInbox(store, open_transport(f"udp://127.0.0.1:{port}", "recv"), clock=lambda: NOW)
    with open_transport(f"udp://127.0.0.1:{port}", "send") as tx:
        tx.send(authority.seal("obu-1", K))
        tx.send(b"RF\x01\x02 junk")
    try:
        for _ in range(10):
            inbox.poll(0.05)
            if inbox.rejected == 2:
                break
    finally:
        inbox.close()
    assert inbox.rejected == 2 and inbox.accepted == 0 and store.epochs == ()


def test_role_checks(deployment: dict[str, KeyStore], tmp_path: Path) -> None:
    with pytest.raises(KeyStoreError, match="not a nonce authority"):
        deployment["sensor"].nonce_authority()
    with pytest.raises(KeyStoreError, match="does not receive them"):
        deployment["auth"].nonce_store()
    lonely = KeyStore.create(tmp_path / "lonely", "backend")
    with pytest.raises(KeyStoreError, match="no nonce authority enrolled"):
        lonely.nonce_store()


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    try:
        main(list(args))
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_serve_and_listen(
    deployment: dict[str, KeyStore], capsys: pytest.CaptureFixture[str]
) -> None:
    auth_dir = str(deployment["auth"].path)
    sensor_dir = str(deployment["sensor"].path)
    port = free_port()
    url = f"udp://127.0.0.1:{port}"
    code, _, err = run(capsys, "nonces", "serve", "--keys", auth_dir, "--to", f"eve={url}")
    assert code == 2 and "not enrolled" in err
    code, _, err = run(capsys, "nonces", "serve", "--keys", auth_dir, "--to", url)
    assert code == 2 and "ID=udp://HOST:PORT" in err

    # the listener holds the current and the next epoch's nonces; an epoch boundary
    # during the next few seconds would add a third: start well inside an epoch
    epoch_s = EpochSchedule().epoch_s
    left_s = epoch_s - time.time() % epoch_s
    if left_s < 5.0:
        time.sleep(left_s + 0.1)

    # serve in the background while `listen` waits for its envelopes
    def serve() -> None:
        dist = NonceDistributor(
            deployment["auth"].nonce_authority(),
            {"rsu-1": open_transport(url, "send")},
            resend_s=0.05,  # the listener may bind after the first send
        )
        while True:  # until the listener is done, however long it takes to start
            dist.tick()
            if stop.wait(0.1):
                break
        dist.close()

    stop = threading.Event()
    worker = threading.Thread(target=serve)
    worker.start()
    try:
        code, out, _ = run(
            capsys, "nonces", "listen", "--keys", sensor_dir, "--listen", url, "--duration", "0.6"
        )
    finally:
        stop.set()
        worker.join()
    # the current and the next epoch's envelopes arrive together or one after the other
    holding = [line for line in out.splitlines() if line.startswith("holding nonces of epochs")]
    assert code == 0 and 1 <= len(holding) <= 2
    assert len(holding[-1].split(",")) == 2
    assert "refused 0" in out and "accepted 0" not in out

    code, out, _ = run(
        capsys, "nonces", "serve", "--keys", auth_dir, "--to", f"rsu-1={url}", "--duration", "0.3"
    )
    assert code == 0 and "handed out" in out and "rsu-1 2" in out
    code, out, err = run(
        capsys, "nonces", "listen", "--keys", sensor_dir, "--listen", url, "--duration", "0.2"
    )
    # nothing arrived: the declared work failed (1), the input was fine
    assert code == 1 and "no nonce envelope" in err


def test_inbox_is_a_nonce_provider_that_waits_for_its_envelope(
    deployment: dict[str, KeyStore],
) -> None:
    authority = deployment["auth"].nonce_authority(SCHED)
    url = f"udp://127.0.0.1:{free_port()}"
    store = deployment["sensor"].nonce_store(SCHED, clock=lambda: NOW)
    inbox = NonceInbox(store, open_transport(url, "recv"), clock=lambda: NOW, wait_s=0.0)
    hasher = MacHasher(inbox)
    macs, t = np.array([0xA4C3F0123456], np.uint64), np.full(1, NOW, np.int64)
    try:
        with pytest.raises(NonceUnavailableError, match="not received"):
            hasher.hash_batch(macs, t)
        with open_transport(url, "send") as tx:
            threading.Timer(0.2, lambda: tx.send(authority.seal("rsu-1", K))).start()
            inbox.wait_s = 5.0
            ids = hasher.hash_batch(macs, t)
    finally:
        inbox.close()
    assert ids.tolist() == MacHasher(authority).hash_batch(macs, t).tolist()
