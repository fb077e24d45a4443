"""Exports of a backend run: GeoJSON against RFC 7946, KML structure, CoT parsed back,
coordinates back to local metres within a centimetre, no raw MAC, live CoT over UDP/TCP."""

from __future__ import annotations

import json
import math
import socket
import threading
from pathlib import Path
from xml.etree import ElementTree as ET

import jsonschema
import numpy as np
import pytest
from click.testing import CliRunner

from rfsas_hw.angles import math_rad_to_compass
from rfsas_hw.backend.service import BackendConfig, BackendService, JsonlSink
from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.errors import ExportError
from rfsas_hw.exports import export_run
from rfsas_hw.exports.cot import fix_event_local
from rfsas_hw.exports.kml import GX_NS, KML_NS
from rfsas_hw.exports.run import read_run
from rfsas_hw.exports.tak import CotSender
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import BearingBatch, Fix, Pose

SCHEMA = json.loads(
    (Path(__file__).parent / "data" / "geojson_rfc7946_subset.schema.json").read_text()
)
ORIGIN = SiteOrigin(52.2053, 0.1218, 12.0)
SENSORS = {"rsu-a": Pose(-30.0, 10.0, 90.0), "rsu-b": Pose(25.0, -20.0, 0.0)}
EMITTER = 0x0123_4567_89AB_CDEF
T0 = 1_767_268_800_000_000_000  # 2026-01-01T12:00:00Z
NS = 1_000_000_000
K = {"k": KML_NS, "gx": GX_NS}


def emitter_at(t_s: float) -> np.ndarray:
    return np.array([-5.0 + 1.5 * t_s, 20.0 - 0.5 * t_s])


def write_run(path: Path, origin: SiteOrigin | None = ORIGIN) -> Path:
    """A backend run: two sensors, one walking emitter, 3 s at 10 Hz, through JsonlSink."""
    sink = JsonlSink(path, origin=origin, bearings=True)
    service = BackendService(BackendConfig(), sinks=[sink], clock=lambda: T0)
    rng = np.random.default_rng(7)
    for k in range(30):
        t_ns = T0 + k * NS // 10
        target = emitter_at(k / 10)
        for sid, pose in SENSORS.items():
            d = target - np.array([pose.x_m, pose.y_m])
            az = float(math_rad_to_compass(np.arctan2(d[1], d[0]))) + rng.normal(0, 0.5)
            service.on_bearings(
                BearingBatch(
                    sid,
                    np.array([t_ns], np.int64),
                    np.array([az % 360.0]),
                    np.array([1.0]),
                    np.array([20.0]),
                    np.array([6], np.int16),
                    np.array([EMITTER], np.uint64),
                ),
                pose,
            )
        service.step(now_ns=t_ns + NS // 20)
    service.close()
    return path


@pytest.fixture(scope="module")
def run_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_run(tmp_path_factory.mktemp("run") / "run.jsonl")


def local_of(lon: float, lat: float) -> tuple[float, float]:
    e, n, _ = ORIGIN.to_local(lat, lon)
    return float(e), float(n)


def test_run_log_carries_origin_bearings_fixes_and_tracks(run_path: Path) -> None:
    run = read_run(run_path)
    assert run.origin == ORIGIN
    assert len(run.bearings) == 60 and not run.skipped
    assert sum(f.ok for f in run.fixes) >= 25
    assert any(math.isfinite(a.vx_mps) for a in run.assessments)


def test_geojson_is_rfc7946_and_round_trips_within_a_centimetre(
    run_path: Path, tmp_path: Path
) -> None:
    path, _, _ = export_run(run_path, "geojson", tmp_path / "run.geojson")
    run = read_run(run_path)  # the export streams the log; its records are read here
    doc = json.loads(path.read_text())
    jsonschema.validate(doc, SCHEMA)
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    assert kinds.count("sensor") == 2 and kinds.count("bearing") == 60
    assert kinds.count("fix") == kinds.count("fix_ellipse") == sum(f.ok for f in run.fixes)
    assert kinds.count("track") == 1
    fixes = {f.t_ns: f for f in run.fixes if f.ok}
    worst = 0.0
    for feat in doc["features"]:
        props, geom = feat["properties"], feat["geometry"]
        if props["kind"] == "fix":
            fix = fixes[props["t_ns"]]
            e, n = local_of(*geom["coordinates"])
            worst = max(worst, math.hypot(e - fix.x_m, n - fix.y_m))
        if props["kind"] == "fix_ellipse":
            ring = np.array(geom["coordinates"][0])
            assert (ring[0] == ring[-1]).all()
            # RFC 7946 §3.1.6: exterior rings counter-clockwise (positive shoelace area)
            x, y = ring[:, 0], ring[:, 1]
            assert np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]) > 0
            # every vertex lies on the 2σ ellipse of the fix's covariance
            fix = next(f for f in fixes.values() if props["time"][:23] in _iso(f.t_ns))
            cov = fix.covariance
            for lon, lat in ring[:-1]:
                d = np.array(local_of(lon, lat)) - fix.position
                assert float(np.sqrt(d @ np.linalg.solve(cov, d))) == pytest.approx(2.0, abs=0.01)
        if props["kind"] == "bearing":
            (lon0, lat0), (lon1, lat1) = geom["coordinates"]
            s = SENSORS[props["sensor_id"]]
            e0, n0 = local_of(lon0, lat0)
            e1, n1 = local_of(lon1, lat1)
            assert math.hypot(e0 - s.x_m, n0 - s.y_m) < 0.01
            az = math.degrees(math.atan2(e1 - e0, n1 - n0)) % 360
            assert az == pytest.approx(props["azimuth_deg"], abs=1e-3)
        if props["kind"] == "track":
            assert len(props["times"]) == len(geom["coordinates"]) >= 20
            assert props["times"] == sorted(props["times"])
    assert worst < 0.01


def _iso(t_ns: int) -> str:
    from rfsas_hw.exports.shapes import iso_utc

    return iso_utc(t_ns)


def test_kml_has_the_expected_structure(run_path: Path, tmp_path: Path) -> None:
    path, _, _ = export_run(run_path, "kml", tmp_path / "run.kml")
    run = read_run(run_path)  # the export streams the log; its records are read here
    root = ET.parse(path).getroot()
    assert root.tag == f"{{{KML_NS}}}kml"
    doc = root.find("k:Document", K)
    assert doc is not None
    folders = {f.findtext("k:name", namespaces=K): f for f in doc.findall("k:Folder", K)}
    assert set(folders) == {"Sensors", "Fixes", "Bearings", "Tracks"}
    fixes = folders["Fixes"].findall("k:Placemark", K)
    ok = [f for f in run.fixes if f.ok]
    assert len(fixes) == len(ok)
    for pm, fix in zip(fixes, ok, strict=True):
        assert pm.findtext("k:TimeStamp/k:when", namespaces=K) == _iso(fix.t_ns)
        point = pm.findtext("k:MultiGeometry/k:Point/k:coordinates", namespaces=K)
        assert point is not None
        lon, lat, _ = (float(v) for v in point.split(","))
        e, n = local_of(lon, lat)
        assert math.hypot(e - fix.x_m, n - fix.y_m) < 0.01
        ring = pm.findtext(
            "k:MultiGeometry/k:Polygon/k:outerBoundaryIs/k:LinearRing/k:coordinates", namespaces=K
        )
        assert ring is not None and len(ring.split()) == 49
        data = {
            d.get("name"): d.findtext("k:value", namespaces=K)
            for d in pm.findall("k:ExtendedData/k:Data", K)
        }
        assert data["emitter"] == f"{EMITTER:016x}" and data["n_sigma"] == "2"
    assert len(folders["Bearings"].findall("k:Placemark/k:LineString", K)) == 60
    track = folders["Tracks"].find("k:Placemark/gx:Track", K)
    assert track is not None
    whens = track.findall("k:when", K)
    coords = track.findall("gx:coord", K)
    assert len(whens) == len(coords) >= 20


def test_cot_events_parse_back(run_path: Path, tmp_path: Path) -> None:
    path, _, _ = export_run(run_path, "cot", tmp_path / "run.cot")
    run = read_run(run_path)  # the export streams the log; its records are read here
    events = [ET.fromstring(line) for line in path.read_bytes().splitlines()]
    times = [e.get("time") or "" for e in events]
    assert times == sorted(times)
    by_kind: dict[str, list[ET.Element]] = {}
    for ev in events:
        assert ev.tag == "event" and ev.get("version") == "2.0"
        for key in ("uid", "type", "how", "time", "start", "stale"):
            assert ev.get(key), key
        rf = ev.find("detail/rfsas")
        assert rf is not None
        by_kind.setdefault(rf.get("kind", ""), []).append(ev)
    assert len(by_kind["sensor"]) == 2 and len(by_kind["bearing"]) == 60
    ok = {f.t_ns: f for f in run.fixes if f.ok}
    assert len(by_kind["fix"]) == len(ok)
    for ev in by_kind["fix"]:
        point = ev.find("point")
        assert point is not None and ev.get("type") == "a-u-G"
        fix = next(f for f in ok.values() if _iso(f.t_ns) == ev.get("time"))
        e, n = local_of(float(point.get("lon", "nan")), float(point.get("lat", "nan")))
        assert math.hypot(e - fix.x_m, n - fix.y_m) < 0.01
        assert float(point.get("ce", "nan")) == pytest.approx(
            math.sqrt(max(np.linalg.eigvalsh(fix.covariance))), rel=1e-3
        )
        ellipse = ev.find("detail/shape/ellipse")
        assert ellipse is not None and float(ellipse.get("major", "0")) >= float(
            ellipse.get("minor", "1")
        )
    track = by_kind["track"]
    assert len(track) >= 20 and all(ev.find("detail/track") is not None for ev in track)


def test_exports_carry_no_raw_mac(tmp_path: Path) -> None:
    from rfsas_hw.studies.demo import run_demo

    demo = run_demo(out_dir=tmp_path / "demo", plot=False)
    macs = [e.mac.lower() for e in demo.scenario.spec.emitters]
    for fmt in ("geojson", "kml", "cot"):
        path, scene, _ = export_run(
            demo.files["backend jsonl"], fmt, tmp_path / f"demo.{fmt}", origin=ORIGIN
        )
        assert scene.fixes
        text = path.read_text().lower()
        for mac in macs:
            assert mac not in text and mac.replace(":", "") not in text


def test_a_corrupted_line_costs_only_that_line(run_path: Path, tmp_path: Path) -> None:
    lines = run_path.read_text().splitlines()
    lines[5] = lines[5][:20]
    lines[9] = json.dumps({"record": "fix", "t_ns": 1})
    bad = tmp_path / "bad.jsonl"
    bad.write_text("\n".join(lines) + "\n")
    run = read_run(bad)
    assert run.skipped == {"not JSON": 1, "bad record": 1}
    assert "line 6" in run.errors[0] and "line 10: missing key" in run.errors[1]
    good = read_run(run_path)
    assert len(run.bearings) + len(run.fixes) + len(run.assessments) == (
        len(good.bearings) + len(good.fixes) + len(good.assessments) - 2
    )


def test_an_emitter_id_that_is_not_64_bit_hex_costs_only_its_line(
    run_path: Path, tmp_path: Path
) -> None:
    lines = run_path.read_text().splitlines()
    rows = [i for i, line in enumerate(lines) if '"record": "bearing"' in line][:3]
    for i, emitter in zip(rows, ("-5", "1" * 17, "0x12"), strict=True):
        data = json.loads(lines[i])
        data["emitter"] = emitter
        lines[i] = json.dumps(data)
    bad = tmp_path / "bad.jsonl"
    bad.write_text("\n".join(lines) + "\n")
    run = read_run(bad)
    assert run.skipped == {"bad record": 3}
    assert all("is not 1 to 16 hex digits" in e for e in run.errors)
    assert len(run.bearings) == len(read_run(run_path).bearings) - 3


def test_no_origin_is_one_clear_error(tmp_path: Path) -> None:
    path = write_run(tmp_path / "plain.jsonl", origin=None)
    with pytest.raises(ExportError, match="no site origin; give --origin"):
        export_run(path, "kml", tmp_path / "x.kml")
    _load_commands()
    res = CliRunner().invoke(
        cli,
        ["export", str(path), "--to", "geojson", "-o", str(tmp_path / "x.geojson"),
         "--origin", "52.2053,0.1218,12"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "wrote" in res.output and "60 bearings" in res.output
    jsonschema.validate(json.loads((tmp_path / "x.geojson").read_text()), SCHEMA)


@pytest.mark.parametrize("scheme", ["udp", "tcp"])
def test_live_cot_reaches_a_tak_listener(scheme: str) -> None:
    kind = socket.SOCK_DGRAM if scheme == "udp" else socket.SOCK_STREAM
    server = socket.socket(socket.AF_INET, kind)
    server.bind(("127.0.0.1", 0))
    server.settimeout(5.0)
    received: list[bytes] = []
    if scheme == "tcp":
        server.listen(1)

        def accept() -> None:
            conn, _ = server.accept()
            with conn:
                conn.settimeout(5.0)
                while chunk := conn.recv(65536):
                    received.append(chunk)

        thread = threading.Thread(target=accept)
        thread.start()
    fix = Fix(T0, f"{EMITTER:016x}", 3.0, -4.0, 4.0, 1.0, 2.0, True, "ok", "", ("a", "b"), 1, 1)
    sender = CotSender(f"{scheme}://127.0.0.1:{server.getsockname()[1]}", ORIGIN)
    sender.on_results([fix], [])
    sender.send(fix_event_local(fix, ORIGIN))
    sender.close()
    if scheme == "udp":
        received = [server.recv(65536), server.recv(65536)]
    else:
        thread.join(5.0)
    server.close()
    data = b"".join(received)
    events = (
        [ET.fromstring(x) for x in data.split(b"\n") if x.strip()]
        if scheme == "tcp"
        else [ET.fromstring(x) for x in received]
    )
    assert sender.sent == 2 and sender.dropped == 0 and len(events) == 2
    point = events[0].find("point")
    assert point is not None
    e, n = local_of(float(point.get("lon", "nan")), float(point.get("lat", "nan")))
    assert math.hypot(e - 3.0, n + 4.0) < 0.01


def test_live_cot_to_nobody_counts_drops() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: nothing listens there
    sender = CotSender(f"tcp://127.0.0.1:{port}", ORIGIN, retry_s=60)
    fix = Fix(T0, f"{EMITTER:016x}", 3.0, -4.0, 4.0, 1.0, 2.0, True, "ok", "", ("a", "b"), 1, 1)
    sender.on_results([fix, fix], [])
    sender.close()
    assert sender.sent == 0 and sender.dropped == 2


def test_cli_writes_beside_the_run_by_default(run_path: Path, tmp_path: Path) -> None:
    run = tmp_path / "run.jsonl"
    run.write_bytes(run_path.read_bytes())
    _load_commands()
    res = CliRunner().invoke(cli, ["export", str(run), "--to", "kml"])
    assert res.exit_code == 0, res.output
    assert f"wrote {tmp_path / 'run.kml'}" in res.output
    assert ET.parse(tmp_path / "run.kml").getroot().tag == f"{{{KML_NS}}}kml"
    res = CliRunner().invoke(cli, ["export", str(run), "--to", "rosbag2"])
    assert res.exit_code != 0 and "needs --out" in res.output
