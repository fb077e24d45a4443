"""A district's deployment on one machine: identities, broker files and a mosquitto on loopback.

:func:`make_deployment` lays out a work directory as an operator would with
``rfsas keys new``, ``rfsas keys enroll`` and ``rfsas broker config``::

    WORK/keys/auth-0            the nonce authority (enrols every unit and backend)
    WORK/keys/<unit-id>         one sensor identity per roadside unit
    WORK/keys/<backend-id>      one backend identity per backend process (trusts every unit)
    WORK/broker/...             CA, client certificates, mosquitto.conf and ACL; the
                                vehicles' gateway is admitted with the ``gateway`` role

:class:`LocalBroker` starts mosquitto on the loopback port of those files and
stops it.

With a broker that already runs (:class:`BrokerAccess`, ``rfsas city run --broker
URL``) no broker files are written: every party connects with its own client
certificate from a folder the operator gives (``<id>.crt`` and ``<id>.key``, as
``rfsas broker config`` writes them into ``OUT/clients``), and the broker's ACL
must know the district's ids. A work directory is reused as it is: identities
found in it are kept, so one run can write them and the operator can make the
broker's files from them (``rfsas broker config --keys WORK/keys/auth-0 …
--gateway vehicles``) before the next.
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
from urllib.parse import parse_qs, urlsplit

from rfsas_hw.closing import ClosingContext
from rfsas_hw.errors import ConfigError, KeyStoreError, LinkError, MissingDependencyError
from rfsas_hw.fleet.broker import BrokerFiles, client_url, write_broker_config
from rfsas_hw.fleet.pki import CertPair
from rfsas_hw.link.keys import CARD_FILE, KeyStore
from rfsas_hw.link.mqtt import parse_mqtt_url

AUTHORITY_ID = "auth-0"
"""Id of the district's nonce authority."""
GATEWAY_ID = "vehicles"
"""Broker identity of the vehicles' gateway (the simulator standing for their modems)."""
START_TIMEOUT_S = 10.0
"""How long mosquitto may take to listen, seconds."""

__all__ = [
    "AUTHORITY_ID",
    "GATEWAY_ID",
    "BrokerAccess",
    "Deployment",
    "LocalBroker",
    "find_mosquitto",
    "free_port",
    "make_deployment",
    "make_identities",
]


@dataclass(frozen=True)
class BrokerAccess:
    """A running broker with mutual TLS, and where each party's certificate is."""

    host: str
    port: int
    ca_cert: Path
    """The CA certificate the broker's certificate is checked with."""
    gateway: CertPair
    """The vehicles' gateway's certificate (the one of the broker URL)."""
    certs: Path
    """Folder with ``<id>.crt`` and ``<id>.key`` of every other party."""

    @classmethod
    def from_url(cls, url: str, certs: Path | None = None) -> BrokerAccess:
        """The broker of ``mqtts://HOST[:PORT]?ca=CA&cert=CRT&key=KEY``, parsed as every
        broker URL is (:func:`~rfsas_hw.link.mqtt.parse_mqtt_url`): ``cert`` and ``key``
        are the certificate of the vehicles' gateway (:data:`GATEWAY_ID`, the
        connection of the command itself); every other party's are taken by its id
        from ``certs`` (default: the folder of ``cert``, as ``rfsas broker config``
        writes them all into ``OUT/clients``).

        Raises:
            LinkError: not a valid broker URL (a missing file, a bad port, …).
            ConfigError: not ``mqtts``, or options each party sets itself (``sub``,
                ``tiles``, ``origin``, …).
        """
        endpoint = parse_mqtt_url(url)
        if endpoint.ca is None or endpoint.cert is None or endpoint.key is None:
            raise ConfigError(
                f"--broker {endpoint.url()}: the district runs with mutual TLS; give "
                "mqtts://HOST:PORT?ca=CA&cert=CRT&key=KEY"
            )
        extra = set(parse_qs(urlsplit(url).query)) - {"ca", "cert", "key"}
        if extra:
            raise ConfigError(
                f"--broker {endpoint.url()}: only ca=, cert= and key= are taken (each "
                f"party sets its own subscriptions and origin), not {', '.join(sorted(extra))}"
            )
        folder = certs if certs is not None else endpoint.cert.parent
        return cls(
            endpoint.host,
            endpoint.port,
            endpoint.ca,
            CertPair(endpoint.cert, endpoint.key),
            folder,
        )

    def client(self, ident: str) -> CertPair:
        """Certificate and key of ``ident`` (whether they exist or not)."""
        if ident == GATEWAY_ID:
            return self.gateway
        return CertPair(self.certs / f"{ident}.crt", self.certs / f"{ident}.key")

    def missing(self, ids: list[str]) -> list[str]:
        """The ids of ``ids`` without a certificate or key."""
        pairs = {i: self.client(i) for i in ids}
        return [i for i, p in pairs.items() if not (p.cert.is_file() and p.key.is_file())]

    def url(self, ident: str, **options: str) -> str:
        """The ``mqtts://`` URL ``ident`` connects with (extra query ``options`` appended)."""
        return client_url(self.host, self.port, self.ca_cert, self.client(ident), **options)


@dataclass(frozen=True)
class Deployment:
    """The key stores of a district and the broker files made from them (or the
    running broker it uses)."""

    root: Path
    authority: KeyStore
    units: dict[str, KeyStore]
    """Sensor identity per unit id."""
    backends: dict[str, KeyStore]
    """Backend identity per backend id."""
    files: BrokerFiles | BrokerAccess

    def url(self, ident: str, **options: str) -> str:
        """The ``mqtts://`` URL ``ident`` connects with (see :meth:`BrokerFiles.url`)."""
        return self.files.url(ident, **options)


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _identity(path: Path, role: str, ident: str) -> KeyStore:
    """The key store of ``ident`` at ``path``: the one an earlier run left, or a new one.

    Raises:
        ConfigError: the one found is of another id or role.
        KeyStoreError: a key directory cannot be read or written.
    """
    if not (path / CARD_FILE).exists():
        return KeyStore.create(path, role, ident)
    store = KeyStore.open(path)
    if store.id != ident or store.role != role:
        raise ConfigError(f"{path}: holds {store.role} {store.id!r}, not {role} {ident!r}")
    return store


def make_identities(
    root: Path, unit_ids: list[str], backend_ids: list[str]
) -> tuple[KeyStore, dict[str, KeyStore], dict[str, KeyStore]]:
    """The district's identities in ``root/keys`` (those found there kept, the others
    created): the nonce authority, which enrols every unit and backend; one sensor per
    unit; one backend per backend id, trusting every unit. ``rfsas broker config --keys
    root/keys/auth-0 --gateway vehicles`` makes a broker's files from them.

    Raises:
        ConfigError: ids repeat or are not valid rfsas ids, or the identities found
            are not these.
        KeyStoreError: a key directory cannot be read or written.
    """
    ids = [*unit_ids, *backend_ids, AUTHORITY_ID, GATEWAY_ID]
    if len(set(ids)) != len(ids):
        raise ConfigError("unit, backend, authority and gateway ids must all differ")
    keys = root / "keys"
    auth = _identity(keys / AUTHORITY_ID, "authority", AUTHORITY_ID)
    units = {u: _identity(keys / u, "sensor", u) for u in unit_ids}
    backends = {b: _identity(keys / b, "backend", b) for b in backend_ids}
    try:
        for party in (*units.values(), *backends.values()):
            party.trust.enroll(auth.card)
            auth.trust.enroll(party.card)
        for b in backends.values():
            for u in units.values():
                b.trust.enroll(u.card)
    except KeyStoreError as err:
        raise ConfigError(f"{keys}: the identities found do not fit together: {err}") from err
    return auth, units, backends


def make_deployment(
    root: Path,
    unit_ids: list[str],
    backend_ids: list[str],
    *,
    port: int | None = None,
    broker: BrokerAccess | None = None,
) -> Deployment:
    """Every identity of the district under ``root`` (kept from an earlier run, or
    created) and the broker's files for a broker on 127.0.0.1:``port`` (default: a
    free port); with ``broker``, no broker files: the parties' certificates must be
    in ``broker.certs``.

    Raises:
        ConfigError: a unit or backend id is not a valid rfsas id, or ids repeat; with
            ``broker``, a party has no certificate there (the message says how to
            make them).
        KeyStoreError: a key directory cannot be read or written.
    """
    ids = [*unit_ids, *backend_ids, AUTHORITY_ID, GATEWAY_ID]
    auth, units, backends = make_identities(root, unit_ids, backend_ids)
    keys = root / "keys"
    if broker is not None:
        missing = broker.missing(ids)
        if missing:
            more = f" and {len(missing) - 5} more" if len(missing) > 5 else ""
            raise ConfigError(
                f"{broker.certs}: no certificate and key for {', '.join(missing[:5])}{more}; "
                f"make them with: rfsas broker config --keys {keys / AUTHORITY_ID} --out DIR "
                f"--host {broker.host} --port {broker.port} --gateway {GATEWAY_ID} "
                "(and run the broker with DIR's ACL)"
            )
        return Deployment(root, auth, units, backends, broker)
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


class LocalBroker(ClosingContext):
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
