"""agrelo:URL: %BBB/Q bearings with interleaved NMEA, over a real pty."""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest

from rfsas_hw.errors import ConfigError, DataFormatError
from rfsas_hw.records import BearingBatch
from rfsas_hw.sources import open_source
from rfsas_hw.sources.agrelo import (
    AgreloSource,
    nmea_checksum_ok,
    sigma_from_quality,
    to_local_m,
)


def nmea(body: str) -> bytes:
    """A sentence with its checksum."""
    c = 0
    for ch in body:
        c ^= ord(ch)
    return f"${body}*{c:02X}\r\n".encode()


# 51°30.000'N 0°07.200'W, moving at 12 knots on course 090
RMC = nmea("GPRMC,120000.00,A,5130.000,N,00007.200,W,12.0,90.0,221126,,,A")
RMC_STOPPED = nmea("GPRMC,120001.00,A,5130.000,N,00007.200,W,0.1,270.0,221126,,,A")
GGA = nmea("GPGGA,120002.00,5130.060,N,00007.200,W,1,08,0.9,35.0,M,47.0,M,,")
ORIGIN = (51.5, -0.12)


def _read_all(src: AgreloSource, seconds: float = 0.5) -> list[BearingBatch]:
    out = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        b = src.read(0.05)
        if b is not None and len(b):
            out.append(b)
    return out


def test_quality_to_sigma_table() -> None:
    assert [sigma_from_quality(q, 0.0) for q in (9, 8, 7, 5, 1)] == [0.25, 0.5, 1.0, 4.0, 64.0]
    assert sigma_from_quality(9) == 2.0  # the floor
    with pytest.raises(ValueError, match="quality 0"):
        sigma_from_quality(0)


def test_nmea_checksum() -> None:
    assert nmea_checksum_ok(RMC.decode().strip())
    assert not nmea_checksum_ok(RMC.decode().strip().replace("12.0", "13.0"))


def test_local_frame_from_origin() -> None:
    # WGS-84 radii of curvature at 51.5° N: meridian M and prime vertical N
    a, e2 = 6_378_137.0, 6.69437999014e-3
    s2 = math.sin(math.radians(51.5)) ** 2
    meridian = a * (1 - e2) / (1 - e2 * s2) ** 1.5
    prime = a / math.sqrt(1 - e2 * s2)
    east, north = to_local_m(51.501, -0.12, ORIGIN)
    assert east == pytest.approx(0.0, abs=1e-6)
    assert north == pytest.approx(math.radians(0.001) * meridian, abs=0.01)  # ≈ 111.26 m
    east, _ = to_local_m(51.5, -0.119, ORIGIN)
    assert east == pytest.approx(
        math.radians(0.001) * prime * math.cos(math.radians(51.5)), abs=0.01
    )


def test_bearings_with_gps_course_and_position(unit: tuple[int, str]) -> None:
    master, path = unit
    with open_source(f"agrelo:{path}", origin=ORIGIN) as src:
        assert isinstance(src, AgreloSource)
        os.write(master, b"%045/7\r\n")  # no course yet: skipped
        gsv = nmea("GPGSV,3,1,11,01,40,083,46")
        os.write(master, RMC + b"%045/7\r\n%350/9\r\n" + gsv + b"%010/0\r\n" + GGA)
        os.write(master, b"garbage line\r\n%123/8\r\n")
        batches = _read_all(src)
        pose = src.pose
        stats = src.stats
    az = np.concatenate([x.azimuth_deg for x in batches])
    rel = np.concatenate([x.relative_deg for x in batches])
    sig = np.concatenate([x.sigma_deg for x in batches])
    # course 090 + relative bearing, wrapped; 350° relative is -10°
    assert az.tolist() == [135.0, 80.0, 213.0]
    assert rel.tolist() == [45.0, -10.0, 123.0]
    assert sig.tolist() == [2.0, 2.0, 2.0]  # Q 7, 9, 8 are all below the 2° floor
    assert all(x.sensor_id == "agrelo" for x in batches)
    assert stats.skipped["no_heading"] == 1 and stats.skipped["no_quality"] == 1
    assert stats.skipped["malformed"] == 1
    assert stats.extra["nmea_fixes"] == 2 and stats.extra["nmea_skipped"] == 1
    # GGA moved the unit 0.06' (111 m) north of the RMC fix
    assert pose is not None
    ref_e, ref_n = to_local_m(51.5, -0.12, ORIGIN)
    assert pose.x_m == pytest.approx(ref_e, abs=0.5)
    assert pose.y_m == pytest.approx(ref_n + 111.2, abs=0.5)
    assert pose.heading_deg == 90.0


def test_stopped_vehicle_keeps_last_course_and_fixed_heading_wins(unit: tuple[int, str]) -> None:
    master, path = unit
    with AgreloSource(path, heading_deg=200.0) as src:
        os.write(master, RMC + RMC_STOPPED + b"%010/5\r\n")
        batches = _read_all(src, 0.3)
        assert src.pose is None  # no origin: no local position
        assert src.position_deg == pytest.approx((51.5, -0.12))
    assert np.concatenate([b.azimuth_deg for b in batches]).tolist() == [210.0]
    assert np.concatenate([b.sigma_deg for b in batches]).tolist() == [4.0]
    with AgreloSource(path) as src:
        os.write(master, RMC + RMC_STOPPED + b"%010/5\r\n")
        # 0.1 kn is too slow to trust course 270: the 090 course stays
        assert np.concatenate([b.azimuth_deg for b in _read_all(src, 0.3)]).tolist() == [100.0]


def test_bad_lines_raise_under_raise_policy(unit: tuple[int, str]) -> None:
    master, path = unit
    with AgreloSource(path, heading_deg=0.0, errors="raise") as src:
        os.write(master, b"%12/5\r\n")
        with pytest.raises(DataFormatError, match=r"line 1: neither %BBB/Q nor NMEA: '%12/5'"):
            _read_all(src, 0.3)


def test_spec_options_and_bad_origin(unit: tuple[int, str]) -> None:
    _, path = unit
    with open_source(f"agrelo:{path}#origin=51.5,-0.12&heading=45&sensor_id=df1") as src:
        assert isinstance(src, AgreloSource)
        assert src.origin == ORIGIN and src.heading_deg == 45.0 and src.sensor_id == "df1"
    with pytest.raises(ConfigError, match="origin"):
        AgreloSource(path, origin="north")
    with pytest.raises(ConfigError, match="agrelo option 'speed=3'"):
        open_source(f"agrelo:{path}#speed=3")


def test_unit_unplugged_ends_the_source(unit: tuple[int, str]) -> None:
    master, path = unit
    src = AgreloSource(path, heading_deg=0.0)
    os.write(master, b"%090/6\r\n")
    first = _read_all(src, 0.2)
    os.close(master)
    rest = list(src)
    src.close()
    assert len(first) == 1 and rest == [] and src.exhausted


def test_live_command_writes_the_units_bearings_without_a_calibration(
    unit: tuple[int, str], tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`rfsas live agrelo:PTY --out FILE`: bearings from the unit go straight to the file."""
    import json
    import threading

    from rfsas_hw.cli.main import main

    master, path = unit

    out = tmp_path / "b.jsonl"
    done = threading.Event()

    def feed() -> None:
        # the port may be opened (and its input flushed) a moment after the command
        # starts: repeat the unit's output until the command has written bearings
        while not done.wait(0.3):
            os.write(master, RMC + b"%045/7\r\n%350/9\r\n%123/8\r\n")

    writer = threading.Thread(target=feed)
    writer.start()
    try:
        with pytest.raises(SystemExit) as exc:
            main(["live", f"agrelo:{path}", "--out", str(out), "--duration", "2.5"])
            raise SystemExit(0)
    finally:
        done.set()
        writer.join()
    assert exc.value.code in (0, None), capsys.readouterr().err
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    # course 090 + the unit's relative bearings 045, 350, 123, each at least once
    assert {r["azimuth_deg"] for r in rows} == {135.0, 80.0, 213.0}
    assert "bearings" in capsys.readouterr().out
