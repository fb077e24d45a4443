"""A small district end to end: a 3 × 3 grid of traffic lights, its units, a real
mosquitto with mutual TLS on loopback, two backend and two twin-worker processes, every
car advised.

The grid is placed on the globe across a zoom-16 tile corner, so its units fall in
more than one tile and both backends own some. The deployment's clock runs at 0.3 ×
real time (:mod:`rfsas_hw.city.clock`), so the whole path keeps its checks (stale
messages, epochs) on a machine too busy for real time; nothing is judged on the wall
clock. The off and on runs share the demand, and the server the processes fork from
starts while the off run goes, so the test takes about a minute on a busy 2-core
machine: 10 simulated seconds, departures in the first 5.

Checked: every advisory that reached a vehicle was signed by the backend that owned
a tile the vehicle was in; no raw MAC of any phone in the broker's traffic (bearings
and advisories, read by a spy with a backend's and the gateway's certificates), the
run log, the summary or the map; and RF-SAS on has fewer conflicts than off on the
same seed (seed 5: 11 against 7 and 8 in two runs, on a machine with a load
average of 15-17).
"""

from __future__ import annotations

import json
import math
import threading
from pathlib import Path
from typing import Any
from urllib.parse import quote

import pytest

from rfsas_hw.bridges.bridge import device_mac
from rfsas_hw.bridges.config import BridgeConfig
from rfsas_hw.records import int_to_mac

pytest.importorskip("sumo", reason="needs the city extra: pip install 'rfsas-hw[city]'")
pytest.importorskip("libsumo", reason="needs the city extra: pip install 'rfsas-hw[city]'")

from rfsas_hw.city.demand import DemandConfig
from rfsas_hw.city.deploy import GATEWAY_ID, find_mosquitto
from rfsas_hw.city.live import LiveConfig, prestart
from rfsas_hw.city.run import CityRunConfig, prepare_district, run_city
from rfsas_hw.errors import MissingDependencyError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link.mqtt import open_mqtt

SEED = 5
DURATION_S = 10.0


def _tile_corner(lat: float, lon: float) -> SiteOrigin:
    """A point just inside the north-west corner of the zoom-16 tile holding (lat, lon)."""
    n = 1 << 16
    x = int((lon + 180.0) / 360.0 * n)
    s = math.sin(math.radians(lat))
    y = int((0.5 - math.log((1 + s) / (1 - s)) / (4 * math.pi)) * n)
    corner_lat = math.degrees(math.atan(math.sinh(math.pi * (1 - 2 * y / n))))
    return SiteOrigin(corner_lat - 0.0001, x / n * 360.0 - 180.0 + 0.0001)


class _Spy:
    """Reads every bearing and every vehicle advisory crossing the broker."""

    def __init__(self, work: Path) -> None:
        self.work = work
        self.payloads: list[bytes] = []
        self.started = False
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def _url(self, ident: str, sub: str) -> str:
        conf = (self.work / "broker" / "broker" / "mosquitto.conf").read_text()
        port = next(ln.split()[1] for ln in conf.splitlines() if ln.startswith("listener "))
        root = self.work / "broker"
        query = {
            "ca": root / "ca" / "ca.crt",
            "cert": root / "clients" / f"{ident}.crt",
            "key": root / "clients" / f"{ident}.key",
            "sub": sub,
        }
        return f"mqtts://127.0.0.1:{port}?" + "&".join(
            f"{k}={quote(str(v), safe='/')}" for k, v in query.items()
        )

    def start(self) -> None:
        self.started = True
        for ident, sub in (
            ("be-1", "rfsas/v1/bearing/#"),
            (GATEWAY_ID, "rfsas/v1/vehicle/+/advisory"),
        ):
            rx = open_mqtt(self._url(ident, sub), "recv")
            t = threading.Thread(target=self._take, args=(rx,), daemon=True)
            t.start()
            self._threads.append(t)

    def _take(self, rx: Any) -> None:
        try:
            while not self._stop.is_set():
                got = rx.recv(0.1)
                while got is not None:
                    self.payloads.append(bytes(got))
                    got = rx.recv(0)
        finally:
            rx.close()

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(10)


def _macs(vru_ids: list[str]) -> list[bytes]:
    """Every MAC a phone of these VRUs can have had (first rotations), as raw bytes."""
    cfg = BridgeConfig(seed=SEED)
    return [
        (device_mac(cfg, v, r) + bump).to_bytes(6, "big")
        for v in vru_ids
        for r in range(3)
        for bump in range(2)
    ]


def test_small_district_end_to_end(grid_net: Path, tmp_path: Path) -> None:
    try:
        find_mosquitto()
    except MissingDependencyError:
        pytest.skip("mosquitto is not installed (Debian package mosquitto)")
    cfg = CityRunConfig(
        net=grid_net,
        origin=_tile_corner(52.4306, 13.5325),
        duration_s=DURATION_S,
        seed=SEED,
        demand=DemandConfig(
            vehicles=60,
            pedestrians=80,
            bicycles=20,
            end_s=5.0,
            phone_penetration=1.0,
            device_mix={"phone-active": 1.0},
            reckless_share=0.5,
        ),
        live=LiveConfig(backends=2, workers=2, time_scale=0.3),
    )
    out = tmp_path / "out"
    prestart()  # the processes' server imports while the demand is made and the off run goes
    district = prepare_district(cfg, out)
    off = run_city(cfg, out, "off", png=False, district=district)
    work = tmp_path / "work"
    spy = _Spy(work)

    def on_progress(_: Any) -> None:
        if not spy.started:
            spy.start()

    try:
        on = run_city(
            cfg,
            out,
            "on",
            district=district,
            png=False,
            on_progress=on_progress,
            work_dir=work,
        )
    finally:
        spy.stop()

    # the real path ran: two backends, bearings verified, advisories reached vehicles
    counts = on.runtime.counts
    records = [json.loads(ln) for ln in on.files["log"].read_text().splitlines()]
    plan = next(r["plan"] for r in records if r["record"] == "tiles")
    assert len(plan) == 2, plan
    # the broker lost nothing (a message the run was too late for is refused as stale,
    # after it arrived)
    assert counts["bearing_messages_received"] == counts["bearing_messages_sent"] > 0
    assert counts["bearing_messages_verified"] > 0.5 * counts["bearing_messages_sent"]
    assert counts["advisories_received"] == counts["advisories_sent"] > 0
    # the workers published their slots (some late when the machine is loaded)
    assert counts["bearing_slots"] > 0
    assert 0 <= counts["bearing_slots_late"] <= counts["bearing_slots"]
    assert counts["bearing_slots_shed"] >= 0  # none at the test's slow clock, unless stalled

    # every advisory that reached a vehicle: signed by a backend owning a tile it was in
    advisories = [r for r in records if r["record"] == "advisory"]
    assert len(advisories) == counts["advisories_verified"]
    for r in advisories:
        assert r["tiles"] and any(t in plan[r["backend"]] for t in r["tiles"]), r
    assert counts["advisories_foreign"] == 0
    # the latency of an advisory that carried a fresh fix, in its three parts: in order
    # on one clock (none negative), adding up to the whole
    timed = [r for r in advisories if r["latency_ms"] is not None]
    assert timed and on.summary.latency_n >= len(timed)
    for r in timed:
        parts = r["latency_parts_ms"]
        assert len(parts) == 3 and min(parts) >= 0, r
        assert sum(parts) == pytest.approx(r["latency_ms"], abs=0.02), r
    p99 = on.summary.latency_parts_ms
    assert set(p99) == {"to_step", "judging", "delivery"}
    assert all(0 <= p99[part]["p50"] <= p99[part]["p99"] for part in p99), p99

    # no raw MAC in the broker's traffic, the run log, the summary or the map
    demand = [ln.split(",")[0] for ln in (out / "demand" / "vrus.csv").read_text().splitlines()[1:]]
    macs = _macs(demand)
    texts = [on.files[k].read_text().lower() for k in ("log", "summary", "geojson")]
    for mac in macs:
        text = int_to_mac(int.from_bytes(mac, "big")).lower()
        assert not any(text in t or text.replace(":", "") in t for t in texts), text
    assert len(spy.payloads) > 100
    blob = b"".join(spy.payloads)
    assert not any(mac in blob for mac in macs)

    # RF-SAS on: fewer conflicts than off on the same seed
    assert off.summary.conflicts > 0
    assert on.summary.conflicts < off.summary.conflicts, (
        off.summary.conflicts_by_class,
        on.summary.conflicts_by_class,
    )
