"""CPMs out and in: the export's pcap (tshark reads the GeoNetworking, BTP-B and ITS
header layers), ``rfsas v2x decode`` of files, the UDP listener's allow list, and the
sink over UDP (bare and BTP-B) and MQTT."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import time
from pathlib import Path

import pytest
from click.testing import CliRunner, Result
from cpmhelp import sample_cpm
from golden import GOLDEN_DIR
from pycrate_cpm import PycrateCpm

from rfsas_hw.cli.main import _load_commands, cli
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import Pose
from rfsas_hw.v2x.codec import decode_cpm, encode_cpm
from rfsas_hw.v2x.geonet import btp_b, read_pcap_cpms, split_datagram
from rfsas_hw.v2x.listen import CpmListener
from rfsas_hw.v2x.perception import CpmConfig
from rfsas_hw.v2x.sink import CpmSink

ORIGIN = SiteOrigin(52.2053, 0.1218, 12.0)
T0 = 1_795_737_600 * 1_000_000_000
MS = 1_000_000


def write_run(path: Path, steps: int = 12) -> None:
    """A backend run log: site, the units' bearings with poses, two tracked emitters."""
    lines = [
        {"record": "site", "origin": {"lat_deg": 52.2053, "lon_deg": 0.1218, "height_m": 12.0}}
    ]
    for k in range(steps):
        t = T0 + k * 100 * MS
        for sid, (x, y, h) in {"rsu-a": (-9.0, 9.0, 135.0), "rsu-b": (9.0, -9.0, 315.0)}.items():
            lines.append(
                {
                    "record": "bearing",
                    "t_ns": t - 5 * MS,
                    "sensor_id": sid,
                    "emitter": "ab" * 8,
                    "azimuth_deg": 100.0,
                    "sigma_deg": 3.0,
                    "x_m": x,
                    "y_m": y,
                    "heading_deg": h,
                }
            )
        for i, emitter in enumerate(("ab" * 8, "cd" * 8)):
            lines.append(
                {
                    "record": "assessment",
                    "t_ns": t,
                    "emitter": emitter,
                    "x_m": 2.0 + i + 0.5 * k,
                    "y_m": -3.0 - i,
                    "cov_xx_m2": 1.0,
                    "cov_xy_m2": 0.2,
                    "cov_yy_m2": 0.5,
                    "vx_mps": 5.0,
                    "vy_mps": 0.0,
                    "age_s": 0.05,
                    "sensors": ["rsu-a", "rsu-b"],
                    "fix_ok": True,
                    "fix_reason": "ok",
                    "p_collision": None,
                    "t_closest_s": None,
                    "distance_to_contact_m": None,
                    "impact_speed_mps": None,
                    "fatality_risk": None,
                    "risk": None,
                    "advisory": "none",
                    "reasons": [],
                    "link_alarm": False,
                }
            )
    lines.insert(5, "not json")
    path.write_text("\n".join(x if isinstance(x, str) else json.dumps(x) for x in lines) + "\n")


def invoke(*args: str) -> Result:
    _load_commands()
    return CliRunner().invoke(cli, list(args))


def test_export_to_cpm_writes_a_pcap_tshark_reads(tmp_path: Path, pycrate_cpm: PycrateCpm) -> None:
    run = tmp_path / "run.jsonl"
    write_run(run)
    res = invoke("export", str(run), "--to", "cpm")
    assert res.exit_code == 0, res.output
    assert "skipped 1 line(s): not JSON" in res.output
    pcap = tmp_path / "run.pcap"
    found, problems = read_pcap_cpms(pcap.read_bytes(), str(pcap))
    assert problems == [] and len(found) >= 2
    for _, _, data in found:
        assert pycrate_cpm.reencode(data) == data
        cpm = decode_cpm(data)
        assert cpm.station_id == 1 and cpm.reference.lat_deg == pytest.approx(52.2053)
    # no bit of the emitter ids (keyed hashes of MACs) anywhere in the file
    blob = pcap.read_bytes()
    width = len(blob) * 8
    number = int.from_bytes(blob, "big")
    shifted = [((number << k) & ((1 << width) - 1)).to_bytes(len(blob), "big") for k in range(8)]
    for emitter in ("ab" * 8, "cd" * 8):
        raw = bytes.fromhex(emitter)
        assert not any(raw[:3] in s for s in shifted) and emitter.encode() not in blob
    first = decode_cpm(found[0][2])
    assert [s.sensor_id for s in first.sensors] == [0, 1, 2]
    assert len(first.objects) == 2
    if shutil.which("tshark") is None:
        pytest.skip("tshark is not installed: the pcap's layers were checked by our reader only")
    out = subprocess.run(
        [
            "tshark",
            "-r",
            str(pcap),
            "-T",
            "fields",
            "-E",
            "separator=,",
            "-e",
            "eth.type",
            "-e",
            "geonw.bh.version",
            "-e",
            "geonw.ch.nh",
            "-e",
            "geonw.ch.htype",
            "-e",
            "geonw.src_pos.lat",
            "-e",
            "btpb.dstport",
            "-e",
            "its.protocolVersion",
            "-e",
            "its.messageID",
            "-e",
            "its.stationID",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    rows = [r.split(",") for r in out.stdout.splitlines()]
    assert len(rows) == len(found)
    for row in rows:
        assert row == ["0x8947", "1", "2", "0x50", "522053000", "2009", "2", "14", "1"]


def test_decode_prints_json_of_files_and_refuses_a_broken_one(tmp_path: Path) -> None:
    run = tmp_path / "run.jsonl"
    write_run(run)
    pcap = tmp_path / "out.pcap"
    assert invoke("export", str(run), "--to", "cpm", "-o", str(pcap)).exit_code == 0
    res = invoke("v2x", "decode", str(pcap))
    assert res.exit_code == 0, res.output
    lines = [json.loads(x) for x in res.stdout.splitlines()]
    assert lines and all(x["cpm"]["header"]["messageId"] == 14 for x in lines)
    assert "decoded" in res.stderr
    one = GOLDEN_DIR / "vehicle_1_object.uper"
    res = invoke("v2x", "decode", str(one))
    tree = json.loads(res.stdout)["cpm"]
    assert "originatingVehicleContainer" in tree["containers"]
    broken = tmp_path / "broken.uper"
    broken.write_bytes(one.read_bytes()[:40])
    from rfsas_hw.cli.main import main

    with pytest.raises(SystemExit) as exit_info:
        main(["v2x", "decode", str(broken)])
    assert exit_info.value.code == 2


def test_listener_decodes_any_form_and_refuses_other_senders() -> None:
    data = encode_cpm(sample_cpm(2))
    listener = CpmListener("udp://127.0.0.1:0")
    others = CpmListener("udp://127.0.0.1:0", allow=["10.0.0.0/8"])
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for payload in (data, btp_b(data), b"\x02\x0egarbage"):
            tx.sendto(payload, listener.address)  # type: ignore[arg-type]
        got = [listener.receive(timeout=5.0) for _ in range(3)]
        assert [g is not None and g.cpm is not None for g in got] == [True, True, False]
        assert got[2] is not None and "CPM" in got[2].error
        assert listener.receive(timeout=0.05) is None
        assert listener.stats == {"received": 3, "decoded": 2, "bad": 1}
        tx.sendto(data, others.address)  # type: ignore[arg-type]
        assert others.receive(timeout=0.3) is None
        assert others.stats["refused_sender"] == 1
    finally:
        tx.close()
        listener.close()
        others.close()


@pytest.mark.parametrize("btp", [False, True])
def test_sink_sends_each_steps_cpms_over_udp(btp: bool, pycrate_cpm: PycrateCpm) -> None:
    from cpmhelp import assessment

    listener = CpmListener("udp://127.0.0.1:0")
    host, port = listener.address  # type: ignore[misc]
    sink = CpmSink.to_url(
        f"udp://{host}:{port}" + ("?btp=1" if btp else ""),
        CpmConfig(station_id=9, origin=ORIGIN),
    )
    try:
        sink.on_results([], [assessment("ab" * 8, T0, 1.0, 2.0)])
        got = listener.receive(timeout=5.0)
        assert got is not None and got.cpm is not None
        assert got.cpm["header"]["stationId"] == 9
        assert pycrate_cpm.reencode(got.data) == got.data
        assert sink.counters()["cpm.sent"] == 1
    finally:
        sink.close()
        listener.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_sink_publishes_on_an_mqtt_topic(tmp_path: Path, pycrate_cpm: PycrateCpm) -> None:
    from cpmhelp import assessment

    mosquitto = shutil.which("mosquitto") or (
        "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None
    )
    if mosquitto is None:
        pytest.skip("mosquitto is not installed (Debian package mosquitto)")
    port = free_port()
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\n")
    proc = subprocess.Popen(
        [mosquitto, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                time.sleep(0.05)
        listener = CpmListener(f"mqtt://127.0.0.1:{port}/its/cpm")
        sink = CpmSink.to_url(f"mqtt://127.0.0.1:{port}/its/cpm", CpmConfig(7, ORIGIN))
        sink.stations["rsu-a"] = Pose(0.0, 0.0, 90.0)
        try:
            sink.on_results([], [assessment("ab" * 8, T0, 1.0, 2.0)])
            got = listener.receive(timeout=10.0)
            assert got is not None and got.cpm is not None, listener.stats
            assert got.sender == "its/cpm"
            assert pycrate_cpm.reencode(got.data) == got.data
            objects = got.cpm["containers"]["perceivedObjectContainer"]["perceivedObjects"]
            assert objects[0]["position"]["xCoordinate"]["value"] == 100
        finally:
            sink.close()
            listener.close()
    finally:
        proc.terminate()
        proc.wait(10)


def test_backend_sink_needs_the_site_origin_and_takes_the_sites_fields_of_view() -> None:
    from rfsas_hw.backend.site import SiteConfig, SiteSensor
    from rfsas_hw.errors import ConfigError
    from rfsas_hw.v2x.sink import backend_cpm_sink

    with pytest.raises(ConfigError, match="site origin"):
        backend_cpm_sink("udp://127.0.0.1:9", 1, SiteConfig())
    site = SiteConfig(origin=ORIGIN, sensors=(SiteSensor("rsu-a", Pose(0, 0, 90), 60.0),))
    sink = backend_cpm_sink("udp://127.0.0.1:9?btp=1", 5, site)
    try:
        assert sink.generator.config.fov_deg == {"rsu-a": 60.0}
        assert sink.generator.config.station_id == 5 and sink.sender.btp
    finally:
        sink.close()
    with pytest.raises(ConfigError, match="expected udp"):
        backend_cpm_sink("tcp://127.0.0.1:9", 1, site)


def test_split_datagram_reads_the_three_forms() -> None:
    data = encode_cpm(sample_cpm(0))
    assert split_datagram(data) == data
    assert split_datagram(btp_b(data)) == data
