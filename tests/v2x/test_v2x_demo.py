"""The demo's backend sends CPMs over UDP (with a BTP-B header); the independent decoder
reads every datagram, positions match the backend's tracks within the wire's
resolution, confidences match their covariance, and no bit of a MAC is in any of them."""

from __future__ import annotations

import json
import math
import socket
from pathlib import Path

import pytest
from pycrate_cpm import PycrateCpm

from rfsas_hw.records import mac_to_int
from rfsas_hw.studies.demo import DEMO_ORIGIN, run_demo
from rfsas_hw.twin.scenario import load_scenario
from rfsas_hw.v2x.codec import decode_cpm
from rfsas_hw.v2x.geonet import split_datagram
from rfsas_hw.v2x.model import CONFIDENCE_95_1D
from rfsas_hw.v2x.timestamp import utc_ns_from_its_ms


def bit_shifts(data: bytes) -> list[bytes]:
    """``data`` shifted left by 0 … 7 bits: a pattern at any bit offset is byte-aligned
    in one of them."""
    n = int.from_bytes(data, "big")
    width = len(data) * 8
    return [((n << k) & ((1 << width) - 1)).to_bytes(len(data), "big") for k in range(8)]


@pytest.mark.slow
def test_demo_backend_sends_cpms_every_decoder_reads(
    tmp_path: Path, pycrate_cpm: PycrateCpm
) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
        result = run_demo(None, tmp_path, plot=False, cpm_url=f"udp://127.0.0.1:{port}?btp=1")
        sock.settimeout(1.0)
        datagrams: list[bytes] = []
        while True:
            try:
                datagrams.append(sock.recv(65536))
            except TimeoutError:
                break
    finally:
        sock.close()
    counters = result.counters["cpm"]
    assert counters["cpm.sent"] == len(datagrams) > 5
    assert counters["cpm.dropped"] == 0 and counters["cpm.errors"] == 0

    tracks: dict[int, list[dict[str, float]]] = {}
    for line in (tmp_path / "backend.jsonl").read_text().splitlines():
        record = json.loads(line)
        if record["record"] == "assessment" and record["x_m"] is not None:
            tracks.setdefault(record["t_ns"], []).append(record)

    scenario = load_scenario(
        None or Path(__file__).resolve().parents[2] / "examples" / "crossing.yaml"
    )
    macs = [mac_to_int(e.mac).to_bytes(6, "big") for e in scenario.spec.emitters]
    hashes = {bytes.fromhex(a["emitter"]) for rows in tracks.values() for a in rows}
    objects = 0
    for datagram in datagrams:
        assert datagram[:2] == b"\x07\xd9"  # BTP-B, port 2009
        cpm_bytes = split_datagram(datagram)
        assert pycrate_cpm.reencode(cpm_bytes) == cpm_bytes
        raw = pycrate_cpm.decode(cpm_bytes)
        ref = raw["payload"]["managementContainer"]["referencePosition"]
        assert ref["latitude"] == round(DEMO_ORIGIN.lat_deg * 1e7)
        cpm = decode_cpm(cpm_bytes)
        t_ns = utc_ns_from_its_ms(cpm.reference_time_ms)
        for obj in cpm.objects:
            objects += 1
            # the assessment of this step the object was made from (positions are
            # offsets from the site origin, so the backend's local metres)
            state = min(
                tracks[t_ns], key=lambda a: math.hypot(a["x_m"] - obj.x_m, a["y_m"] - obj.y_m)
            )
            assert abs(state["x_m"] - obj.x_m) <= 0.005 + 1e-9
            assert abs(state["y_m"] - obj.y_m) <= 0.005 + 1e-9
            if state["cov_xx_m2"] is None or state["cov_yy_m2"] is None:
                # no finite variance (JSON null): out of range or unavailable, no correlation
                assert not (math.isfinite(obj.x_conf_m) and math.isfinite(obj.y_conf_m))
                assert math.isnan(obj.xy_correlation)
                continue
            sx, sy = math.sqrt(state["cov_xx_m2"]), math.sqrt(state["cov_yy_m2"])
            # 95 % confidence: 1.96 σ, rounded up to the next 0.01 m
            if CONFIDENCE_95_1D * max(sx, sy) <= 40.94:
                assert CONFIDENCE_95_1D * sx - 1e-9 <= obj.x_conf_m <= CONFIDENCE_95_1D * sx + 0.01
                assert CONFIDENCE_95_1D * sy - 1e-9 <= obj.y_conf_m <= CONFIDENCE_95_1D * sy + 0.01
                rho = state["cov_xy_m2"] / (sx * sy)
                assert abs(obj.xy_correlation - rho) <= 0.005 + 1e-9
        for shifted in bit_shifts(cpm_bytes):
            for mac in macs:
                assert mac not in shifted and mac[::-1] not in shifted
                for i in range(3):
                    assert mac[i : i + 4] not in shifted
            for h in hashes:
                for i in range(len(h) - 3):
                    assert h[i : i + 4] not in shifted
    assert objects > 10
