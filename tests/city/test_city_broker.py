"""``rfsas city run --broker``: the district through a broker the command did not start.

The documented way: ``rfsas city keys`` writes the district's identities, ``rfsas
broker config`` makes the broker's certificates and ACL from them (with the vehicles'
gateway), mosquitto runs with those files (started here on loopback, as the fleet tests
start theirs), and ``rfsas city run --broker URL --work DIR`` uses it: every party with
its own certificate, the command's own broker start never called.

The same run serves its live dashboard (``--web``): read over loopback while the run
goes, it shows every unit of the district and the backends' fixes and tracks, refuses
a request from another origin (the dashboard server's own check) and holds no MAC.
"""

from __future__ import annotations

import getpass
import json
import threading
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

pytest.importorskip("libsumo", reason="needs the city extra: pip install 'rfsas-hw[city]'")

from rfsas_hw.bridges.bridge import device_mac
from rfsas_hw.bridges.config import BridgeConfig
from rfsas_hw.city.deploy import (
    GATEWAY_ID,
    BrokerAccess,
    LocalBroker,
    find_mosquitto,
    free_port,
    make_deployment,
)
from rfsas_hw.cli.broker import broker
from rfsas_hw.cli.city import city
from rfsas_hw.errors import ConfigError, LinkError, MissingDependencyError
from rfsas_hw.fleet.broker import BrokerFiles
from rfsas_hw.records import int_to_mac


def _url(broker_dir: Path, port: int, **extra: str) -> str:
    clients = broker_dir / "clients"
    query = {
        "ca": broker_dir / "ca" / "ca.crt",
        "cert": clients / f"{GATEWAY_ID}.crt",
        "key": clients / f"{GATEWAY_ID}.key",
        **extra,
    }
    return f"mqtts://127.0.0.1:{port}?" + "&".join(f"{k}={v}" for k, v in query.items())


class _Page:
    """Reads the dashboard's state over loopback every 0.5 s while the run goes."""

    def __init__(self, port: int) -> None:
        self.url = f"http://127.0.0.1:{port}/api/state"
        self.states: list[str] = []
        self.foreign_origin: int | None = None
        """The status a request with another site's Origin got."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, daemon=True)

    def __enter__(self) -> _Page:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(10)

    def _poll(self) -> None:
        while not self._stop.wait(0.5):
            try:
                with urllib.request.urlopen(self.url, timeout=5) as reply:
                    self.states.append(reply.read().decode())
            except OSError:
                continue  # not serving yet
            if self.foreign_origin is None:
                ask = urllib.request.Request(self.url, headers={"Origin": "http://example.com"})
                try:
                    with urllib.request.urlopen(ask, timeout=5) as reply:
                        self.foreign_origin = reply.status
                except urllib.error.HTTPError as err:
                    self.foreign_origin = err.code
                    err.close()


def _no_broker_of_its_own(*_: Any, **__: Any) -> None:
    raise AssertionError("the command started a broker of its own")


def test_city_run_uses_a_running_broker(
    grid_net: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    try:
        find_mosquitto()
    except MissingDependencyError:
        pytest.skip("mosquitto is not installed (Debian package mosquitto)")
    work, broker_dir, out = tmp_path / "work", tmp_path / "broker", tmp_path / "out"
    port = free_port()
    runner = CliRunner()
    res = runner.invoke(city, ["keys", "--net", str(grid_net), "--out", str(work)])
    assert res.exit_code == 0, res.output
    assert "rfsas broker config" in res.output
    args = ["config", "--keys", str(work / "keys" / "auth-0"), "--out", str(broker_dir)]
    args += ["--host", "127.0.0.1", "--port", str(port), "--gateway", GATEWAY_ID]
    res = runner.invoke(broker, [*args, "--run-as", getpass.getuser()])
    assert res.exit_code == 0, res.output
    assert f"gateway   {GATEWAY_ID}" in res.output

    files = BrokerFiles(broker_dir, "127.0.0.1", port, ())
    monkeypatch.setattr("rfsas_hw.city.live.LocalBroker", _no_broker_of_its_own)
    web = free_port()
    with LocalBroker(files, tmp_path / "mosquitto.log"), _Page(web) as page:
        args = ["run", "--net", str(grid_net), "--out", str(out), "--work", str(work)]
        args += ["--broker", _url(broker_dir, port), "--rfsas", "on", "--duration", "4"]
        args += ["--vehicles", "20", "--pedestrians", "30", "--bicycles", "0"]
        args += ["--phones", "1", "--active-share", "1", "--time-scale", "0.5", "--no-png"]
        res = runner.invoke(city, [*args, "--web", f"127.0.0.1:{web}"])
    assert res.exit_code == 0, (res.output, res.exception)

    doc = json.loads((out / "on.summary.json").read_text())
    counts, cpu = doc["runtime"]["counts"], doc["runtime"]["cpu_s"]
    # bearings and advisories went through the running broker, nothing lost
    assert counts["bearing_messages_received"] == counts["bearing_messages_sent"] > 0
    assert counts["bearing_messages_verified"] > 0
    assert counts["advisories_received"] == counts["advisories_sent"]
    # no broker of its own: no broker files, no broker log, no broker CPU reading
    assert "broker" not in cpu
    assert not (work / "broker").exists() and not (work / "mosquitto.log").exists()

    # the dashboard: every unit, the backends' fixes and tracks, another origin refused
    start = json.loads((out / "on.log.jsonl").read_text().splitlines()[0])
    units = {u["id"] for u in start["units"]}
    states = [json.loads(text) for text in page.states]
    assert states, "the dashboard never answered"
    assert {u["id"] for u in states[-1]["sensors"]} == units
    assert any(st["fixes"] for st in states) and any(st["tracks"] for st in states)
    assert page.foreign_origin == 403
    vrus = [ln.split(",")[0] for ln in (out / "demand" / "vrus.csv").read_text().splitlines()[1:]]
    macs = [int_to_mac(device_mac(BridgeConfig(seed=1), v, r) + bump).lower()
            for v in vrus for r in range(3) for bump in range(2)]  # fmt: skip
    text = "".join(page.states).lower()
    assert not any(m in text or m.replace(":", "") in text for m in macs)


def test_a_running_broker_without_the_districts_certificates_is_refused(
    tmp_path: Path,
) -> None:
    port = free_port()
    ca = tmp_path / "ca.crt"
    ca.write_text("not used before the check\n")
    clients = tmp_path / "clients"
    clients.mkdir()
    for name in (f"{GATEWAY_ID}.crt", f"{GATEWAY_ID}.key"):
        (clients / name).write_text("placeholder\n")
        (clients / name).chmod(0o600)
    url = f"mqtts://127.0.0.1:{port}?ca={ca}&cert={clients}/{GATEWAY_ID}.crt"
    url += f"&key={clients}/{GATEWAY_ID}.key"
    access = BrokerAccess.from_url(url)
    assert access.certs == clients
    with pytest.raises(ConfigError) as err:
        make_deployment(tmp_path / "work", ["rsu-1", "rsu-2"], ["be-1"], broker=access)
    text = str(err.value)
    assert "rsu-1" in text and "be-1" in text and "auth-0" in text
    assert f"rfsas broker config --keys {tmp_path / 'work' / 'keys' / 'auth-0'}" in text
    assert f"--gateway {GATEWAY_ID}" in text
    # the identities were written, for rfsas broker config to read
    assert (tmp_path / "work" / "keys" / "rsu-1" / "identity.yaml").is_file()

    # options each party sets itself, and URLs without TLS, are refused with the reason
    with pytest.raises(ConfigError, match="tiles"):
        BrokerAccess.from_url(url + "&tiles=1202")
    with pytest.raises(LinkError):
        BrokerAccess.from_url(f"mqtts://127.0.0.1:{port}?ca={ca}")
    with pytest.raises(ConfigError, match="mutual TLS"):
        BrokerAccess.from_url(f"mqtt://127.0.0.1:{port}")
