"""``rfsas backend``: real key directories, real UDP, JSONL, the live table and the map."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from backendhelp import bearing_towards
from click.testing import CliRunner

from rfsas_hw.cli.backend import backend
from rfsas_hw.link import Publisher, open_transport
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.records import Pose

EMITTER = 0xC0FF_EE00_0000_0042
TARGET = np.array([-6.0, 22.0])
SENSORS = {"rsu-n": Pose(-35.0, 10.0, 90.0), "rsu-s": Pose(25.0, -5.0, 0.0)}


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


VEHICLE_JSON = b'{"x_m": -12, "y_m": 22, "heading_deg": 90, "speed_mps": 8}'


def send_rounds(
    url: str,
    stores: dict[str, KeyStore],
    delay_s: float,
    vehicle_url: str | None = None,
    stop: threading.Event | None = None,
) -> None:
    """Both sensors' bearings every 0.1 s: 20 rounds, or until ``stop`` (at most 600)."""
    time.sleep(delay_s)
    pubs = {sid: Publisher.to_url(url, stores[sid].signer(), pose) for sid, pose in SENSORS.items()}
    feed = None if vehicle_url is None else open_transport(vehicle_url, "send")
    try:
        # keep sending while the command starts up and runs: datagrams sent before
        # it binds the port are lost, as UDP does
        for i in range(600):
            if stop.is_set() if stop is not None else i == 20:
                break
            now = time.time_ns()
            if feed is not None:
                feed.send(VEHICLE_JSON)
            for sid, pose in SENSORS.items():
                pubs[sid].on_bearings(bearing_towards(sid, pose, TARGET, EMITTER, now))
            time.sleep(0.1)
    finally:
        for pub in pubs.values():
            pub.close()
        if feed is not None:
            feed.close()


@pytest.mark.extra("plot")
@pytest.mark.parametrize("vehicle_from", ["file", "udp"])
def test_backend_command_locates_and_judges(tmp_path: Path, vehicle_from: str) -> None:
    backend_keys = KeyStore.create(tmp_path / "backend", "backend", "obu-1")
    stores = {sid: KeyStore.create(tmp_path / sid, "sensor", sid) for sid in SENSORS}
    for store in stores.values():
        backend_keys.trust.enroll(store.card)
    # 6 m west of the emitter at 8 m/s: contact in 3.5 m, stopping needs 6.9 m
    vehicle = tmp_path / "vehicle.json"
    vehicle.write_bytes(VEHICLE_JSON)
    vehicle_url = f"udp://127.0.0.1:{free_port()}"
    vehicle_arg = str(vehicle) if vehicle_from == "file" else vehicle_url
    out, png = tmp_path / "run.jsonl", tmp_path / "map.png"
    url = f"udp://127.0.0.1:{free_port()}"
    # the sender keeps sending until the command has ended: however long a loaded machine
    # takes to start it, it hears bearings for its whole --duration
    done = threading.Event()
    sender = threading.Thread(
        target=send_rounds,
        args=(url, stores, 0.2, vehicle_url if vehicle_from == "udp" else None, done),
    )
    sender.start()
    result = CliRunner().invoke(
        backend,
        [
            "--listen", url, "--keys", str(tmp_path / "backend"), "--vehicle", vehicle_arg,
            "--out", str(out), "--plot", str(png), "--duration", "2.5",
        ],
        env={"COLUMNS": "160"},
    )  # fmt: skip
    done.set()
    sender.join(timeout=60)
    assert result.exit_code == 0, result.output
    assert f"{EMITTER:016x}" in result.output and "P_coll" in result.output
    records = [json.loads(line) for line in out.read_text().splitlines()]
    stats = records[-1]
    assert stats["record"] == "stats" and f"link.verified {stats['link.verified']}" in result.output
    assert stats["link.verified"] == stats["link.datagrams"] >= 6
    assert not any(k.startswith("link.rejected") for k in stats)
    fix = next(r for r in records if r["record"] == "fix")
    assert fix["ok"] and abs(fix["x_m"] - TARGET[0]) < 1e-3 and abs(fix["y_m"] - TARGET[1]) < 1e-3
    # while fixes are fresh the pedestrian ahead means brake; later, with the track
    # ageing and no vehicle update, its covariance grows and P(collision) falls
    judged = [r for r in records if r["record"] == "assessment"]
    assert any(r["advisory"] == "brake" and r["p_collision"] > 0.2 for r in judged)
    assert all(r["advisory"] in ("brake", "caution") for r in judged)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_backend_command_reports_bad_keys_in_one_line(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "rfsas_hw.cli.main", "backend", "--listen", "udp://127.0.0.1:9",
         "--keys", str(tmp_path / "missing"), "--duration", "0.1"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr.strip().startswith("error:") and "not a key directory" in proc.stderr
    assert "Traceback" not in proc.stderr
    empty = KeyStore.create(tmp_path / "lonely", "backend", "obu-2")
    result = CliRunner().invoke(
        backend, ["--listen", "udp://127.0.0.1:9", "--keys", str(empty.path)]
    )
    assert result.exit_code != 0 and "no enrolled sensors" in str(result.exception)


def test_backend_command_settings_file_and_flags(tmp_path: Path) -> None:
    settings = tmp_path / "backend.yaml"
    settings.write_text("association: {window_s: 0.5, epoch_s: 30}\n")
    args = ["--listen", "udp://127.0.0.1:9", "--keys", str(tmp_path / "none")]
    # the file's 30 s epoch makes a 40 s window invalid; a flag overrides the file
    result = CliRunner().invoke(backend, [*args, "--config", str(settings), "--window", "40"])
    assert "shorter than the nonce epoch (30.0 s)" in str(result.exception)
    result = CliRunner().invoke(
        backend, [*args, "--config", str(settings), "--window", "40", "--epoch", "60"]
    )
    assert "not a key directory" in str(result.exception)  # settings accepted, keys next
