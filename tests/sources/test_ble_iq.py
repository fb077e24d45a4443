"""BLE IQ reports: the Core specification's byte layouts, edge cases, fuzzing, CFO, DF."""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rfsas_hw.df import load_calibration
from rfsas_hw.df.array import C_MPS, ArrayGeometry
from rfsas_hw.df.arraycal import ArrayCalibration, ElementCalibration
from rfsas_hw.df.arraycsi import array_df_result
from rfsas_hw.df.arrayfit import crb_deg
from rfsas_hw.df.estimate import estimate
from rfsas_hw.errors import CaptureFormatError, SourceError
from rfsas_hw.sources import open_source
from rfsas_hw.sources.ble_iq import (
    IqReport,
    ble_channel_mhz,
    element_snapshots,
    encode_iq_event,
    estimate_cfo_hz,
    iter_btsnoop_events,
    iter_h4_events,
    parse_iq_event,
    remove_cfo,
    sample_times_us,
)
from rfsas_hw.sources.ble_iq_emulator import btsnoop_file, h4_stream, iq_reports

REPO = Path(__file__).resolve().parents[2]
SAMPLES_9 = bytes([10, 0, 9, 3, 7, 6, 4, 9, 0, 10, 0xFD, 9, 0xF9, 6, 0xF7, 3, 0xF6, 0])

# Connectionless IQ Report (7.7.65.21) written out field by field:
# 3E len | 15 | sync 0x0001 | ch 17 | RSSI −60.4 dBm = −604 = 0xFDA4 | ant 0 | AoA | 2 µs |
# CRC ok | counter 42 | 9 samples | 9 × (I, Q)
CONNECTIONLESS = (
    bytes([0x3E, 13 + 18, 0x15, 0x01, 0x00, 0x11, 0xA4, 0xFD, 0x00, 0x00, 0x02, 0x00])
    + bytes([0x2A, 0x00, 0x09])
    + SAMPLES_9
)
# Connection IQ Report (7.7.65.22): 16 | conn 0x0040 | PHY 2M | data ch 5 | RSSI −71.0 dBm =
# −710 = 0xFD3A | ant 1 | AoD 1 µs | 1 µs | CRC bad | counter 0x0102 | 9 samples
CONNECTION = (
    bytes([0x3E, 14 + 18, 0x16, 0x40, 0x00, 0x02, 0x05, 0x3A, 0xFD, 0x01, 0x01, 0x01, 0x01])
    + bytes([0x02, 0x01, 0x09])
    + SAMPLES_9
)


def test_connectionless_vector() -> None:
    r = parse_iq_event(CONNECTIONLESS, "v")
    assert r is not None and r.kind == "connectionless"
    assert (r.handle, r.channel_index, r.rssi_antenna, r.cte_type) == (1, 17, 0, 0)
    assert (r.slot_us, r.packet_status, r.event_counter, r.phy) == (2, 0, 42, 1)
    assert r.rssi_dbm == pytest.approx(-60.4)
    assert len(r.iq) == 9 and r.iq[0] == 10 + 0j and r.iq[5] == -3 + 9j
    assert encode_iq_event(r) == CONNECTIONLESS


def test_connection_vector() -> None:
    r = parse_iq_event(CONNECTION, "v")
    assert r is not None and r.kind == "connection"
    assert (r.handle, r.phy, r.channel_index, r.rssi_antenna) == (0x40, 2, 5, 1)
    assert (r.cte_type, r.slot_us, r.packet_status, r.event_counter) == (1, 1, 1, 0x0102)
    assert r.rssi_dbm == pytest.approx(-71.0)
    assert encode_iq_event(r) == CONNECTION


def test_other_events_are_not_reports() -> None:
    assert parse_iq_event(bytes([0x0E, 0x04, 0x01, 0x03, 0x0C, 0x00])) is None
    assert parse_iq_event(bytes([0x3E, 0x02, 0x02, 0x00])) is None  # an advertising report


def test_sentinel_and_no_samples_edge_cases() -> None:
    bad = bytearray(CONNECTIONLESS)
    bad[15 + 2 * 4] = 0x80  # sample 4's I is −128: "no valid sample" (or saturated)
    r = parse_iq_event(bytes(bad))
    assert r is not None and r.invalid == 1 and np.isnan(r.iq[4])
    # out of resources: Packet_Status 0xFF, Sample_Count 0, with or without one 0x80 pair
    head = [0x15, 0x01, 0x00, 0x11, 0xA4, 0xFD, 0x00, 0x00, 0x02, 0xFF, 0x2A, 0x00, 0x00]
    for tail in ([], [0x80, 0x80]):
        params = bytes(head + tail)
        r = parse_iq_event(bytes([0x3E, len(params)]) + params)
        assert r is not None and r.packet_status == 0xFF and len(r.iq) == 0
    # 16-bit samples (a vendor event): −32768 is the sentinel
    params16 = (
        bytes([*head[:9], 0x00, 0x2A, 0x00, 0x09])
        + np.array([100, -200] * 8 + [-32768, 5], "<i2").tobytes()
    )
    r16 = parse_iq_event(bytes([0x3E, len(params16)]) + params16, sample_bits=16)
    assert r16 is not None and r16.iq[0] == 100 - 200j and np.isnan(r16.iq[8])


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda b: b[:-1], "LE meta event says"),
        (lambda b: bytes([b[0], b[1] - 1]) + b[2:-1], "Sample_Count 9 needs 18"),
        (lambda b: b[:14] + bytes([5]) + b[15:], "Sample_Count 5"),
        (lambda b: b[:10] + bytes([3]) + b[11:], "Slot_Durations 3"),
        (lambda b: b[:5] + bytes([45]) + b[6:], "channel index 45"),
        (lambda b: bytes([0x3E, 8]) + b[2:10], "fixed part needs 13"),
    ],
)
def test_corrupted_reports_fail_cleanly(mutate, message: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(CaptureFormatError, match=message):
        parse_iq_event(mutate(CONNECTIONLESS), "cap.bin: byte 7")


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=200), st.sampled_from([0x15, 0x16]))
def test_fuzz_never_crashes(tail: bytes, sub: int) -> None:
    event = bytes([0x3E, len(tail) + 1, sub]) + tail
    with contextlib.suppress(CaptureFormatError):
        parse_iq_event(event[: min(len(event), 257)], "fuzz")
    with contextlib.suppress(CaptureFormatError):
        list(iter_h4_events(tail, "fuzz"))


@settings(max_examples=100, deadline=None)
@given(
    st.sampled_from(["connectionless", "connection"]),
    st.integers(0, 0x0EFF),
    st.integers(0, 39),
    st.integers(-1270, 200),
    st.integers(9, 82),
    st.integers(0, 2**32 - 1),
)
def test_round_trip(kind, handle, channel, rssi_ddbm, count, seed) -> None:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    iq = rng.integers(-127, 128, count) + 1j * rng.integers(-127, 128, count)
    r = IqReport(kind, handle, channel, 2 if kind == "connection" else 1, rssi_ddbm / 10.0, 0, 0,
                 1, 0, seed % 65536, iq)  # fmt: skip
    back = parse_iq_event(encode_iq_event(r))
    assert back is not None
    fields = [f.name for f in dataclasses.fields(IqReport) if f.name != "iq"]
    assert [getattr(back, f) for f in fields] == [getattr(r, f) for f in fields]
    np.testing.assert_array_equal(back.iq, iq)


def test_h4_and_btsnoop_framing(tmp_path: Path) -> None:
    stream = b"\x01\x03\x0c\x00" + b"\x04" + CONNECTIONLESS + b"\x02\x01\x00\x02\x00ab"
    events = list(iter_h4_events(stream, "s"))
    assert [e for _, e in events] == [CONNECTIONLESS]
    with pytest.raises(CaptureFormatError, match="byte 0: 0x07 is not an HCI packet"):
        list(iter_h4_events(b"\x07\x00", "s"))
    with pytest.raises(CaptureFormatError, match="cut short"):
        list(iter_h4_events(b"\x04" + CONNECTIONLESS[:-3], "s"))
    r = parse_iq_event(CONNECTIONLESS)
    assert r is not None
    snoop = btsnoop_file([r, r], t0_ns=1_700_000_000_000_000_000)
    got = list(iter_btsnoop_events(snoop, "f"))
    assert [e for _, _, e in got] == [CONNECTIONLESS, CONNECTIONLESS]
    assert got[0][1] == 1_700_000_000_000_000_000
    with pytest.raises(CaptureFormatError, match=r"record 2 .* cut short"):
        list(iter_btsnoop_events(snoop[:-5], "f"))
    with pytest.raises(CaptureFormatError, match="not a btsnoop"):
        list(iter_btsnoop_events(b"pcap", "f"))


FREQ_CH = 17
LAM = C_MPS / (ble_channel_mhz(FREQ_CH) * 1e6)
UCA = ArrayGeometry.uca(8, 0.6 * LAM)


@pytest.mark.parametrize("cfo_hz", [-150_000.0, -40_000.0, 0.0, 90_000.0, 150_000.0])
def test_cfo_up_to_the_ble_limit_is_removed(cfo_hz: float) -> None:
    rng = np.random.default_rng(int(abs(cfo_hz)) + 1)
    reports = iq_reports(UCA, list(range(8)), np.zeros(50), 30.0, cfo_hz, rng)
    est = np.array([estimate_cfo_hz(r.iq) for r in reports])
    # 8 reference samples at 30 dB: the estimate spreads by about 2 kHz
    assert np.max(np.abs(est - cfo_hz)) < 10_000.0
    iq, cfo = remove_cfo(reports[0], list(range(8)))
    # the revisits of each antenna refine it to a few hundred Hz
    assert abs(cfo - cfo_hz) < 1_000.0
    # after removal the reference period's phase no longer turns
    ref = iq[:8]
    assert abs(np.angle(np.sum(ref[1:] * np.conj(ref[:-1])))) < 0.05


def test_snapshots_follow_the_switching_pattern() -> None:
    iq = np.arange(8 + 9, dtype=np.complex128)
    snaps = element_snapshots(iq, [2, 0, 1], 3)
    # slot 0 used pattern[1] = 0, slot 1 pattern[2] = 1, slot 2 pattern[0] = 2, …
    np.testing.assert_array_equal(snaps[0], [8, 9, 10])
    assert snaps.shape == (3, 3)
    assert sample_times_us(10, 2)[8:].tolist() == [10.0, 14.0]
    with pytest.raises(ValueError, match="pattern"):
        element_snapshots(iq, [0, 3], 3)


def _array_cal():  # type: ignore[no-untyped-def]
    base = load_calibration(REPO / "calibration" / "example_cal.yaml")
    none = ElementCalibration(np.zeros(8), np.zeros(8))
    return dataclasses.replace(base, array=ArrayCalibration(UCA, none, ble_channel_mhz(FREQ_CH)))


@pytest.mark.parametrize("container", ["h4", "btsnoop"])
def test_emulated_reports_give_bearings_all_round(tmp_path: Path, container: str) -> None:
    rng = np.random.default_rng(21)
    theta = rng.uniform(-180.0, 180.0, 300)
    cfo = rng.uniform(-150_000.0, 150_000.0, 300)
    pattern = [0, 3, 6, 1, 4, 7, 2, 5]  # any order the board switches in
    reports = iq_reports(UCA, pattern, theta, 25.0, cfo, rng, channel_index=FREQ_CH)
    path = tmp_path / f"iq.{container}"
    data = h4_stream(reports) if container == "h4" else btsnoop_file(reports, 1_700_000_000 * 10**9)
    path.write_bytes(data)
    spec = f"bleiq:{path}?elements=8&pattern={','.join(map(str, pattern))}"
    with open_source(spec) as src:
        batch = next(iter(src))
    assert len(batch) == 300 and batch.csi is not None
    passes = batch.csi.h.shape[2]  # 37 slots: 4 full passes through 8 antennas
    assert passes == 4
    cal = _array_cal()
    mono = estimate(cal, batch.rssi_dbm[:, 0], batch.rssi_dbm[:, 1], batch.channel)
    res = array_df_result(cal, batch, mono)
    v = res.valid
    assert v.mean() > 0.98
    err = (res.angle_deg[v] - theta[v] + 180.0) % 360.0 - 180.0
    crb = crb_deg(UCA, theta[v], 25.0, ble_channel_mhz(FREQ_CH), snapshots=passes)
    rms, bound = float(np.sqrt(np.mean(err**2))), float(np.sqrt(np.mean(crb**2)))
    assert rms <= 1.2 * bound, (rms, bound)
    assert np.mean(np.abs(err) < 90.0) >= 0.99


def test_without_cfo_removal_the_bearings_are_lost() -> None:
    # the same packets, the carrier offset left in: the phase turns by up to 0.94 rad per
    # µs between antennas and the fit no longer finds the emitter
    rng = np.random.default_rng(22)
    theta = rng.uniform(-180.0, 180.0, 200)
    reports = iq_reports(UCA, list(range(8)), theta, 25.0, 120_000.0, rng, channel_index=FREQ_CH)
    from rfsas_hw.df.arrayfit import estimate_array

    kept = np.stack([element_snapshots(r.iq, list(range(8)), 8)[:4] for r in reports])
    pat = list(range(8))
    fixed = np.stack([element_snapshots(remove_cfo(r, pat)[0], pat, 8)[:4] for r in reports])
    f = ble_channel_mhz(FREQ_CH)
    raw, good = estimate_array(UCA, kept, f).df, estimate_array(UCA, fixed, f).df

    def rms(res):  # type: ignore[no-untyped-def]
        v = res.valid
        e = (res.angle_deg[v] - theta[v] + 180.0) % 360.0 - 180.0
        return float(np.sqrt(np.mean(e**2))) if v.any() else 180.0

    assert rms(good) < 2.0 and rms(raw) > 10 * rms(good)


def test_bad_reports_are_counted_not_fatal(tmp_path: Path) -> None:
    rng = np.random.default_rng(23)
    good = iq_reports(UCA, list(range(8)), np.zeros(3), 25.0, 0.0, rng, channel_index=FREQ_CH)
    empty = dataclasses.replace(good[0], packet_status=0xFF, iq=np.zeros(0, complex))
    corrupt = bytearray(b"\x04" + encode_iq_event(good[1]))
    corrupt[15] = 5  # Sample_Count 5: not a count a report may carry
    path = tmp_path / "mixed.h4"
    path.write_bytes(h4_stream([good[0], empty]) + bytes(corrupt) + h4_stream([good[2]]))
    with open_source(f"bleiq:{path}?elements=8") as src:
        batch = next(iter(src))
        stats = src.stats
    assert len(batch) == 2
    assert stats.skipped["no_samples"] == 1 and stats.skipped["bad_report"] == 1
    with pytest.raises(CaptureFormatError), open_source(f"bleiq:{path}?elements=8", errors="raise"):
        pass


def test_spec_errors_name_the_option(tmp_path: Path) -> None:
    path = tmp_path / "x.h4"
    path.write_bytes(b"")
    with pytest.raises(SourceError, match="elements=N"):
        open_source(f"bleiq:{path}")
    with pytest.raises(SourceError, match="unknown option 'colour'"):
        open_source(f"bleiq:{path}?elements=4&colour=red")
    with pytest.raises(SourceError, match="pattern"):
        open_source(f"bleiq:{path}?elements=4&pattern=0,9")
    with pytest.raises(SourceError, match="no such file"):
        open_source(f"bleiq:{tmp_path / 'nope.h4'}?elements=4")
