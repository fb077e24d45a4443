"""The backend application from Python: settings precedence, a run on loopback UDP, closing."""

from __future__ import annotations

import json
import socket
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from backendhelp import bearing_towards

from rfsas_hw.apps.backend import (
    BackendApp,
    BackendAppConfig,
    SettingsOverrides,
    resolve_settings,
)
from rfsas_hw.backend.association import AssociationConfig
from rfsas_hw.backend.service import BackendConfig
from rfsas_hw.errors import ConfigError, MissingDependencyError
from rfsas_hw.link import Publisher
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.records import Pose

EMITTER = 0x0BAD_CAFE_0000_0007
TARGET = np.array([10.0, 30.0])
SENSORS = {"rsu-w": Pose(-20.0, 0.0, 45.0), "rsu-e": Pose(40.0, 0.0, 315.0)}


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _keys(tmp_path: Path) -> dict[str, KeyStore]:
    backend = KeyStore.create(tmp_path / "obu-1", "backend", "obu-1")
    stores = {sid: KeyStore.create(tmp_path / sid, "sensor", sid) for sid in SENSORS}
    for store in stores.values():
        backend.trust.enroll(store.card)
    return {"obu-1": backend, **stores}


def _send_until(url: str, stores: dict[str, KeyStore], stop: threading.Event) -> None:
    """Both sensors' bearings of the emitter every 0.1 s (at most 300 rounds) until ``stop``."""
    pubs = [Publisher.to_url(url, stores[sid].signer(), pose) for sid, pose in SENSORS.items()]
    try:
        for _ in range(300):
            now = time.time_ns()
            for pub, (sid, pose) in zip(pubs, SENSORS.items(), strict=True):
                pub.on_bearings(bearing_towards(sid, pose, TARGET, EMITTER, now))
            if stop.wait(0.1):
                return
    finally:
        for pub in pubs:
            pub.close()


def test_settings_file_replaces_the_base_and_overrides_replace_the_file(tmp_path: Path) -> None:
    settings = tmp_path / "backend.yaml"
    settings.write_text("association: {window_s: 0.5, epoch_s: 30}\nstep_s: 0.2\n")
    base = BackendConfig(association=AssociationConfig(window_s=2.0, epoch_s=120.0), step_s=0.3)
    assert resolve_settings(base) == base
    from_file = resolve_settings(base, settings)
    assert from_file.association.window_s == 0.5 and from_file.association.epoch_s == 30.0
    assert from_file.step_s == 0.2
    both = resolve_settings(base, settings, SettingsOverrides(epoch_s=90.0, threat_kind="cyclist"))
    assert both.association.epoch_s == 90.0 and both.association.window_s == 0.5
    assert both.encounter.threat_kind == "cyclist" and both.step_s == 0.2
    with pytest.raises(ConfigError, match="shorter than the nonce epoch"):
        resolve_settings(base, settings, SettingsOverrides(window_s=40.0))


def test_an_app_built_in_python_locates_the_emitter(tmp_path: Path) -> None:
    stores = _keys(tmp_path)
    url = f"udp://127.0.0.1:{_free_port()}"
    out = tmp_path / "run.jsonl"
    config = BackendAppConfig(
        listen=(url,),
        keys_dir=stores["obu-1"].path,
        out=out,
        duration_s=60.0,  # an upper bound: the run stops once the emitter is located
        overrides=SettingsOverrides(window_s=0.5),
    )
    stop = threading.Event()
    with BackendApp(config) as app:
        assert app.enrolled == 2 and app.settings.association.window_s == 0.5
        sender = threading.Thread(target=_send_until, args=(url, stores, stop))
        sender.start()
        try:
            app.run(should_stop=lambda: EMITTER in app.service.fixes)
        finally:
            stop.set()
            sender.join(timeout=30)
    assert not sender.is_alive()
    fix = app.service.fixes[EMITTER]
    assert fix.ok and np.allclose([fix.x_m, fix.y_m], TARGET, atol=1e-3)
    stats = app.stats()
    assert stats["link.verified"] >= 2 and stats["fixes.ok"] >= 1
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert records[-1]["record"] == "stats"  # written when the app closed
    assert any(r["record"] == "fix" and r["emitter"] == f"{EMITTER:016x}" for r in records)
    app.close()  # closing twice is harmless
    # the listening port is free again
    host, port = url.removeprefix("udp://").split(":")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, int(port)))


def test_an_app_refuses_bad_combinations_before_binding_anything(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    stores = _keys(tmp_path)
    url = f"udp://127.0.0.1:{_free_port()}"
    settings = tmp_path / "backend.yaml"
    settings.write_text("step_s: 0.1\n")
    base = BackendAppConfig(listen=(url,), keys_dir=stores["obu-1"].path, settings_file=settings)
    for bad, message in [
        ({"cot": "udp://127.0.0.1:9"}, "--cot needs the site origin"),
        ({"advise": "mqtt://127.0.0.1"}, "--advise needs the site origin"),
        ({"cues_fallback": "udp://127.0.0.1:9"}, "out-of-band path of --send-cues"),
        ({"out": settings}, "is also an input"),
        ({"plot": stores["obu-1"].path / "trust" / "rsu-w.yaml"}, "is also an input"),
    ]:
        with pytest.raises(ConfigError, match=message):
            BackendApp(replace(base, **bad))
    # a map needs matplotlib: said before the run rather than after it
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(MissingDependencyError, match=r"pip install 'rfsas-hw\[plot\]'"):
        BackendApp(replace(base, plot=tmp_path / "map.png"))
    lonely = KeyStore.create(tmp_path / "lonely", "backend", "obu-2")
    with pytest.raises(ConfigError, match="no enrolled sensors"):
        BackendApp(BackendAppConfig(listen=(url,), keys_dir=lonely.path))
    # nothing was left bound
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", int(url.rsplit(":", 1)[1])))
