"""A deployment's key stores and a real mosquitto with mutual TLS and ACLs from
``rfsas broker config``, for fleet tests (the fixtures are in conftest.py)."""

from __future__ import annotations

import getpass
import os
import shutil
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from rfsas_hw.fleet.broker import BrokerFiles, write_broker_config
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.privacy.nonces import NonceAuthority

MOSQUITTO = shutil.which("mosquitto") or (
    "/usr/sbin/mosquitto" if os.path.exists("/usr/sbin/mosquitto") else None
)
SENSORS = ("rsu-1", "rsu-2")
BACKENDS = ("be-a", "be-b")
VEHICLE = "car-7"


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Deployment:
    """Key stores of one deployment and the broker files made from them."""

    root: Path
    authority: KeyStore
    sensors: dict[str, KeyStore]
    backends: dict[str, KeyStore]
    files: BrokerFiles
    nonces: NonceAuthority
    """The one nonce authority of the deployment (it draws each epoch's nonce once)."""


@dataclass
class Broker:
    """A running mosquitto."""

    files: BrokerFiles
    proc: subprocess.Popen[bytes]
    log: Path

    def url(self, ident: str, **options: str) -> str:
        return self.files.url(ident, **options)

    def start(self) -> None:
        self.proc = _spawn(self.files, self.log)

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait(5)


def _spawn(files: BrokerFiles, log: Path) -> subprocess.Popen[bytes]:
    assert MOSQUITTO is not None
    with log.open("ab") as fh:
        proc = subprocess.Popen([MOSQUITTO, "-c", str(files.conf)], stdout=fh, stderr=fh)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"mosquitto exited {proc.returncode}: {log.read_text()}")
        try:
            with socket.create_connection((files.host, files.port), timeout=0.2):
                return proc
        except OSError:
            time.sleep(0.05)
    proc.kill()
    raise RuntimeError(f"mosquitto did not listen within 10 s: {log.read_text()}")


def make_deployment(root: Path, port: int) -> Deployment:
    auth = KeyStore.create(root / "keys" / "auth-0", "authority")
    sensors = {s: KeyStore.create(root / "keys" / s, "sensor") for s in SENSORS}
    backends = {b: KeyStore.create(root / "keys" / b, "backend") for b in BACKENDS}
    for party in (*sensors.values(), *backends.values()):
        party.trust.enroll(auth.card)
        auth.trust.enroll(party.card)
    for b in backends.values():
        for s in sensors.values():
            b.trust.enroll(s.card)
    user = getpass.getuser()
    files = write_broker_config(
        auth.path,
        root / "broker",
        host="127.0.0.1",
        port=port,
        vehicles=[VEHICLE],
        run_as=user if os.geteuid() == 0 else None,
    )
    nonces = auth.nonce_authority(EpochSchedule(60.0, 5.0))
    return Deployment(root, auth, sensors, backends, files, nonces)
