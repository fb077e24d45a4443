"""ublox:URL — +UUDF events of a u-blox AoA anchor over a real pty and over TCP."""

from __future__ import annotations

import io
import logging
import math
import os
import re
import time
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.board.transport import PtyEndpoint, TcpEndpoint
from rfsas_hw.errors import ConfigError, SourceError
from rfsas_hw.output import BearingWriter
from rfsas_hw.privacy import FixedNonce, MacHasher
from rfsas_hw.records import BearingBatch
from rfsas_hw.sources import open_source
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.ublox import UbloxSource, mac_from_hex, sigma_from_rssi
from rfsas_hw.sources.ublox_emulator import Tag, UbloxEmulator, UbloxServer

# Example events as printed in u-blox's XPLR-AOA user guide and AT manual:
# a 10-field line (later firmware, with the periodic-advertising sequence number)
# and a 9-field line (the first firmware).
LINE_10 = b'+UUDF:CCF9578E0D8A,-42,20,0,-43,37,"CCF9578E0D89","",15869,23'
LINE_9 = b'+UUDF:6C1DEBA5F60C,-53,8,2,0,37,"6C1DEBA09862","",1437347'
# the same event with raw angles switched on (AT+UDFCFG=121,1): 12 fields
LINE_12 = b'+UUDF:CCF9578E0D8A,-42,-31,4,-43,38,"CCF9578E0D89","room 1, east",15900,24,-30,5'
TAGS = (0xCCF9578E0D8A, 0x6C1DEBA5F60C)
KEY = b"k" * 32


def _read_all(
    src: Source[BearingBatch], seconds: float = 0.4, want: int | None = None
) -> BearingBatch:
    parts = []
    end = time.monotonic() + seconds
    got = 0
    while time.monotonic() < end and (want is None or got < want):
        b = src.read(0.05)
        if b is not None and len(b):
            parts.append(b)
            got += len(b)
    if not parts:
        return BearingBatch.empty("none")
    return BearingBatch(
        parts[0].sensor_id,
        np.concatenate([p.t_ns for p in parts]),
        np.concatenate([p.azimuth_deg for p in parts]),
        np.concatenate([p.sigma_deg for p in parts]),
        np.concatenate([p.snr_db for p in parts]),
        np.concatenate([p.channel for p in parts]),
        np.concatenate([p.emitter for p in parts]),
        np.concatenate([p.relative_deg for p in parts]),
    )


def test_documented_lines_of_every_firmware(unit: tuple[int, str]) -> None:
    master, path = unit
    hasher = MacHasher(FixedNonce(KEY))
    with UbloxSource(path, boresight_deg=90.0, hasher=hasher) as src:
        os.write(master, b"\r\n+STARTUP\r\nAT+UDFENABLE=1\r\nOK\r\n" + LINE_10 + b"\r\n")
        os.write(master, LINE_9 + b"\r\n+UUDFP:CCF9578E0D8A,0201061AFF4C00\r\nERROR\r\n")
        # a line split across two reads is one line, not two bad ones
        os.write(master, LINE_12[:30])
        time.sleep(0.05)
        os.write(master, LINE_12[30:] + b"\r\n")
        batch = _read_all(src, want=3)
        extra = src.stats.extra
        assert (extra["startups"], extra["ok"], extra["error_replies"]) == (1, 1, 1)
        assert (extra["echoes"], extra["payloads"], extra["events"]) == (1, 1, 3)
        assert not src.stats.skipped
    assert batch.relative_deg.tolist() == [20.0, 8.0, -31.0]
    assert batch.azimuth_deg.tolist() == [110.0, 98.0, 59.0]
    assert batch.channel.tolist() == [37, 37, 38]
    # the stronger polarisation; a reserved second polarisation (0) is ignored
    assert batch.snr_db.tolist() == pytest.approx([-42 + 103.9, -53 + 103.9, -42 + 103.9])
    # the emitter id is the keyed hash of the tag address, never the address
    want = [hasher.hash_one(m, int(t)) for m, t in zip((*TAGS, TAGS[0]), batch.t_ns, strict=True)]
    assert batch.emitter.tolist() == want
    assert not set(batch.emitter.tolist()) & set(TAGS)
    assert batch.sigma_deg[0] == pytest.approx(sigma_from_rssi(-42, 20))


def test_sign_and_boresight_are_settings(unit: tuple[int, str]) -> None:
    master, path = unit
    with open_source(f"ublox:{path}#sign=-1&boresight=350&floor=3") as src:
        assert isinstance(src, UbloxSource)
        os.write(master, LINE_10 + b"\r\n")
        batch = _read_all(src, want=1)
    assert batch.relative_deg.tolist() == [-20.0]
    assert batch.azimuth_deg.tolist() == [330.0]
    assert batch.sigma_deg[0] == pytest.approx(sigma_from_rssi(-42, 20, floor_deg=3.0))


def test_garbage_and_partial_lines_are_counted(
    unit: tuple[int, str], caplog: pytest.LogCaptureFixture
) -> None:
    master, path = unit
    bad = [
        LINE_10[:25],  # cut short: too few fields
        b'+UUDF:CCF9578E0D8A,-42,200,0,-43,37,"A","",1,2',  # angle out of range
        b'+UUDF:CCF9578E0D8A,-42,20,0,-43,55,"A","",1,2',  # no such BLE channel
        b'+UUDF:ZZF9578E0D8A,-42,20,0,-43,37,"A","",1,2',  # not a hex address
        b'+UUDF:CCF9578E0D8A,-42,x,0,-43,37,"A","",1,2',  # not a number
        b'+UUDF:CCF9578E0D8A,0,20,0,0,37,"A","",1,2',  # no RSSI at all
        b'+UUDF:CCF9578E0D8A,99999,20,0,-43,37,"A","",1,2',  # RSSI beyond a signed byte
        b'+UUDF:CCF9578E0D8A,-99999,20,0,0,37,"A","",1,2',  # SNR -99,895 dB otherwise
        b"hello world",
    ]
    caplog.set_level(logging.DEBUG)
    with UbloxSource(path) as src:
        os.write(master, b"\r\n".join([*bad, LINE_10, b""]))
        batch = _read_all(src, want=1)
        assert len(batch) == 1
        assert src.stats.skipped["malformed"] == len(bad)
        messages = " ".join(src.stats.errors) + caplog.text
    # a rejected line may start with a tag address: messages give the line number only
    assert "CCF9578E0D8A" not in messages.upper()
    assert "line 2:" in messages


def test_binary_mode_is_refused(unit: tuple[int, str]) -> None:
    master, path = unit
    with UbloxSource(path) as src:
        os.write(master, b"\x01\x02\xfe\xff\x00\r\n" * 5)
        with pytest.raises(SourceError, match="binary data, not \\+UUDF text"):
            _read_all(src, seconds=0.3)


def test_options_are_checked() -> None:
    with pytest.raises(ConfigError, match="keys baud"):
        UbloxSource.from_spec("/dev/null#colour=red")
    with pytest.raises(ConfigError, match="sign must be 1 or -1"):
        UbloxSource("/dev/null", sign=2)
    with pytest.raises(SourceError, match="cannot open u-blox unit"):
        UbloxSource("/nonexistent/tty")
    with pytest.raises(ValueError):
        mac_from_hex("12")


def test_sigma_grows_at_low_snr_and_off_boresight() -> None:
    strong, weak = sigma_from_rssi(-40, 0), sigma_from_rssi(-95, 0)
    assert 5.0 <= strong < 5.1 < weak
    assert sigma_from_rssi(-80, 70) > sigma_from_rssi(-80, 0)
    assert math.isclose(sigma_from_rssi(-200, 0, floor_deg=0.0), math.degrees(2 / math.sqrt(1e-3)))


@pytest.mark.parametrize("fields", [9, 10, 12])
def test_emulator_on_a_pty(fields: int) -> None:
    emulator = UbloxEmulator(
        [Tag.parse("CCF9578E0D8A,20,-50"), Tag.parse("6C:1D:EB:A5:F6:0C,-40")],
        fields=fields,
        noise_deg=1.0,
        seed=1,
    )
    server = UbloxServer(emulator, PtyEndpoint(), rate_hz=50.0)
    try:
        with UbloxSource(server.endpoint.path) as src:
            server.start()
            batch = _read_all(src, seconds=3.0, want=40)
            assert src.stats.extra["startups"] == 1
    finally:
        server.stop()
    assert len(batch) >= 40
    rel = batch.relative_deg
    assert set(np.unique(batch.emitter).tolist()).isdisjoint(TAGS)
    assert len(np.unique(batch.emitter)) == 2
    assert np.all((np.abs(rel - 20) < 6) | (np.abs(rel + 40) < 6))


def test_emulator_over_tcp_with_garbage_counts_it() -> None:
    emulator = UbloxEmulator([Tag.parse("CCF9578E0D8A,10")], garbage=0.3, seed=4)
    server = UbloxServer(emulator, TcpEndpoint(0), rate_hz=200.0)
    try:
        with UbloxSource(server.endpoint.path) as src:
            server.start()
            batch = _read_all(src, seconds=2.0, want=100)
            skipped = src.stats.skipped["malformed"]
    finally:
        server.stop()
    assert len(batch) >= 50 and skipped > 5
    # every event is a bearing or a counted bad line (the last few may be in flight)
    assert len(batch) + skipped <= emulator.events


def test_emulated_binary_output_is_refused() -> None:
    server = UbloxServer(UbloxEmulator([Tag("CCF9578E0D8A", 0.0)], binary=True), PtyEndpoint())
    try:
        with UbloxSource(server.endpoint.path) as src:
            server.start()
            with pytest.raises(SourceError, match="binary"):
                _read_all(src, seconds=2.0)
    finally:
        server.stop()


def test_emulator_options_are_checked() -> None:
    with pytest.raises(ConfigError, match="9, 10 or 12"):
        UbloxEmulator([Tag("CCF9578E0D8A", 0.0)], fields=11)
    with pytest.raises(ConfigError, match="MAC,AZIMUTH"):
        Tag.parse("nonsense")
    with pytest.raises(ConfigError, match=r"outside -90\.\.90"):
        Tag.parse("CCF9578E0D8A,120")


def _leaks(blob: bytes, mac: int) -> bool:
    raw = mac.to_bytes(6, "big")
    hex_any_sep = rb"[^0-9A-Fa-f]{0,3}".join(f"{b:02x}".encode() for b in raw)
    return bool(
        re.search(hex_any_sep, blob, re.IGNORECASE)
        or raw in blob
        or re.search(rb"(?<![0-9])" + str(mac).encode() + rb"(?![0-9])", blob)
    )


@pytest.mark.parametrize("fmt", ["jsonl", "csv"])
def test_no_raw_mac_in_the_bearings_written(unit: tuple[int, str], fmt: str) -> None:
    master, path = unit
    with UbloxSource(path) as src:
        os.write(master, LINE_10 + b"\r\n" + LINE_9 + b"\r\n")
        batch = _read_all(src, want=2)
        stats = repr(src.stats.as_dict())
    assert len(batch) == 2
    buf = io.StringIO()
    writer = BearingWriter(buf, fmt)
    writer.on_bearings(batch)
    writer.close()
    blob = (buf.getvalue() + stats).encode()
    assert not any(_leaks(blob, mac) for mac in TAGS)


class _NoNonce:
    def nonce_for(self, epoch: int) -> bytes:
        from rfsas_hw.privacy.hashing import NonceUnavailableError

        raise NonceUnavailableError(f"no nonce for epoch {epoch}")


def test_events_without_a_nonce_are_dropped_not_sent_raw(unit: tuple[int, str]) -> None:
    master, path = unit
    with UbloxSource(path, hasher=MacHasher(_NoNonce())) as src:
        os.write(master, LINE_10 + b"\r\n")
        batch = _read_all(src, seconds=0.3)
        assert len(batch) == 0
        assert src.stats.skipped["no_nonce"] == 1


def test_replay_of_an_aoa_unit_needs_no_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The unit measures the angle itself: ``replay ublox:…`` goes straight to opening it
    (here a missing one) instead of asking for a calibration."""
    from rfsas_hw.cli.main import main

    out = tmp_path / "b.jsonl"
    with pytest.raises(SystemExit) as exit_info:
        main(["replay", f"ublox:{tmp_path / 'ttyNONE'}", "--out", str(out)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "--calibration" not in err and "u-blox unit" in err
    assert not out.exists()
