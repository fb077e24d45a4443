"""A district's deployment on one machine: identities, broker files and a mosquitto on loopback.

:func:`make_deployment` lays out a work directory as an operator would with
``rfsas keys new``, ``rfsas keys enroll`` and ``rfsas broker config``::

    WORK/keys/auth-0            the nonce authority (enrols every unit and backend)
    WORK/keys/<unit-id>         one sensor identity per roadside unit
    WORK/keys/<backend-id>      one backend identity per backend process (trusts every unit)
    WORK/broker/...             CA, client certificates, mosquitto.conf and ACL; the
                                vehicles' gateway is admitted with the ``gateway`` role

:class:`LocalBroker` starts mosquitto on the loopback port of those files and
stops it. With a broker elsewhere the same files are handed to it instead.
"""

from __future__ import annotations

import getpass
import os
import shutil
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from rfsas_hw.errors import ConfigError, LinkError, MissingDependencyError
from rfsas_hw.fleet.broker import BrokerFiles, write_broker_config
from rfsas_hw.link.keys import KeyStore

AUTHORITY_ID = "auth-0"
"""Id of the district's nonce authority."""
GATEWAY_ID = "vehicles"
"""Broker identity of the vehicles' gateway (the simulator standing for their modems)."""
START_TIMEOUT_S = 10.0
"""How long mosquitto may take to listen, seconds."""

__all__ = [
    "AUTHORITY_ID",
    "GATEWAY_ID",
    "Deployment",
    "LocalBroker",
    "find_mosquitto",
    "free_port",
    "make_deployment",
]


@dataclass(frozen=True)
class Deployment:
    """The key stores of a district and the broker files made from them."""

    root: Path
    authority: KeyStore
    units: dict[str, KeyStore]
    """Sensor identity per unit id."""
    backends: dict[str, KeyStore]
    """Backend identity per backend id."""
    files: BrokerFiles

    def url(self, ident: str, **options: str) -> str:
        """The ``mqtts://`` URL ``ident`` connects with (see :meth:`BrokerFiles.url`)."""
        return self.files.url(ident, **options)


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def make_deployment(
    root: Path, unit_ids: list[str], backend_ids: list[str], *, port: int | None = None
) -> Deployment:
    """Create every identity of the district under ``root`` and the broker's files
    for a broker on 127.0.0.1:``port`` (default: a free port).

    Raises:
        ConfigError: a unit or backend id is not a valid rfsas id, or ids repeat.
        KeyStoreError: a key directory cannot be written.
    """
    ids = [*unit_ids, *backend_ids, AUTHORITY_ID, GATEWAY_ID]
    if len(set(ids)) != len(ids):
        raise ConfigError("unit, backend, authority and gateway ids must all differ")
    keys = root / "keys"
    auth = KeyStore.create(keys / AUTHORITY_ID, "authority", AUTHORITY_ID)
    units = {u: KeyStore.create(keys / u, "sensor", u) for u in unit_ids}
    backends = {b: KeyStore.create(keys / b, "backend", b) for b in backend_ids}
    for party in (*units.values(), *backends.values()):
        party.trust.enroll(auth.card)
        auth.trust.enroll(party.card)
    for b in backends.values():
        for u in units.values():
            b.trust.enroll(u.card)
    files = write_broker_config(
        auth.path,
        root / "broker",
        host="127.0.0.1",
        port=free_port() if port is None else port,
        gateways=[GATEWAY_ID],
        run_as=getpass.getuser() if os.geteuid() == 0 else None,
    )
    return Deployment(root, auth, units, backends, files)


def find_mosquitto() -> str:
    """The mosquitto program.

    Raises:
        MissingDependencyError: it is not installed (names the package).
    """
    found = shutil.which("mosquitto") or next(
        (p for p in ("/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto") if os.path.exists(p)),
        None,
    )
    if found is None:
        raise MissingDependencyError(
            "mosquitto is not installed (Debian package mosquitto); or give --broker with the "
            "URL of a running one"
        )
    return found


class LocalBroker:
    """mosquitto on the loopback listener of ``files``, logging to ``log``.

    Raises (from the constructor):
        MissingDependencyError: mosquitto is not installed.
        LinkError: it exited or did not listen within :data:`START_TIMEOUT_S`.
    """

    def __init__(self, files: BrokerFiles, log: Path) -> None:
        self.files = files
        self.log = log
        program = find_mosquitto()
        with log.open("ab") as fh:
            self.proc = subprocess.Popen(
                [program, "-c", str(files.conf)], stdout=fh, stderr=subprocess.STDOUT
            )
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if self.proc.poll() is not None:
                raise LinkError(f"mosquitto exited with {self.proc.returncode}; see {log}")
            try:
                with socket.create_connection((files.host, files.port), timeout=0.2):
                    return
            except OSError as err:
                if time.monotonic() > deadline:
                    self.close()
                    raise LinkError(
                        f"mosquitto did not listen within {START_TIMEOUT_S:g} s"
                    ) from err
                time.sleep(0.05)

    @property
    def pid(self) -> int:
        """The broker's process id (for its CPU time)."""
        return int(self.proc.pid)

    def close(self) -> None:
        """Stop the broker; idempotent."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)

    def __enter__(self) -> LocalBroker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
