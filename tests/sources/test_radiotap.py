"""Radiotap parsing: tshark ground truth on real captures, round trips, malformed headers."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import rt_writer as w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rfsas_hw.errors import CaptureFormatError
from rfsas_hw.records import mac_to_int
from rfsas_hw.rf.channels import freq_to_channel
from rfsas_hw.sources import dot11, radiotap
from rfsas_hw.sources.frames import FrameDecoder, FrameSpans
from rfsas_hw.sources.pcapfile import iter_chunks

REAL = ["ieee802.11_meshid.pcap", "bad_rsn_parsing_overrides_ssid.pcap"]


def tshark_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a ``.tshark.txt`` ground-truth file (comment lines skipped)."""
    lines = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    header = lines[0].split("\t")
    return [dict(zip(header, ln.split("\t"), strict=True)) for ln in lines[1:]]


def raw_frames(path: Path) -> list[bytes]:
    chunks = iter_chunks(path.read_bytes(), path.name)
    out = []
    for c in chunks:
        for s, n in zip(c.start.tolist(), c.caplen.tolist(), strict=True):
            out.append(c.buf[s : s + n])
    return out


@pytest.mark.parametrize("name", REAL)
def test_chains_match_tshark_frame_by_frame(data_dir: Path, name: str) -> None:
    rows = tshark_rows(data_dir / f"{name}.tshark.txt")
    frames = raw_frames(data_dir / name)
    assert len(frames) == len(rows)
    for frame, row in zip(frames, rows, strict=True):
        info = radiotap.parse(frame)
        dbm = [int(x) for x in row["radiotap.dbm_antsignal"].split(",")]
        ants = [int(x) for x in row["radiotap.antenna"].split(",")]
        expected_chains = tuple(zip(ants, dbm[-len(ants) :], strict=True))
        assert info.chains == expected_chains, f"frame {row['frame.number']}"
        words = tuple(int(x, 16) for x in row["radiotap.present.word"].split(","))
        assert info.present == words
        if words[0] & (1 << radiotap.BIT_DBM_ANTSIGNAL):
            assert info.signal_dbm == dbm[0]
        assert info.tsft_us == int(row["radiotap.mactime"])
        assert info.length == int(row["radiotap.length"])
        hdr = dot11.parse_header(frame, info.length, len(frame) - info.length - 4)
        assert hdr.transmitter == mac_to_int(row["wlan.ta"])
        assert hdr.seq == int(row["wlan.seq"])
        assert hdr.retry == bool(int(row["wlan.fc.retry"]))
        assert hdr.type_subtype == int(row["wlan.fc.type_subtype"], 16)


@pytest.mark.parametrize("name", REAL)
@pytest.mark.parametrize("vector_min", [0, 1000])
def test_decoder_columns_match_tshark(data_dir: Path, name: str, vector_min: int) -> None:
    """Both decode paths put chain k's dBm into column k, as tshark lists them."""
    rows = tshark_rows(data_dir / f"{name}.tshark.txt")
    (chunk,) = iter_chunks((data_dir / name).read_bytes(), name)
    spans = FrameSpans(
        chunk.start, chunk.caplen, chunk.t_ns, chunk.frame_no, chunk.file_offset, chunk.linktype
    )
    result = FrameDecoder(n_antennas=3, vector_min=vector_min).decode(chunk.buf, spans)
    table = result.table
    assert len(table) == len(rows)
    for i, row in enumerate(rows):
        dbm = [int(x) for x in row["radiotap.dbm_antsignal"].split(",")]
        ants = [int(x) for x in row["radiotap.antenna"].split(",")]
        expected = np.full(3, np.nan)
        for ant, value in zip(ants, dbm[-len(ants) :], strict=True):
            expected[ant] = value
        np.testing.assert_array_equal(table.chain_dbm[i], expected)
        assert table.signal_dbm[i] == dbm[0]
        assert int(table.mac[i]) == mac_to_int(row["wlan.ta"])
        assert int(table.seq[i]) == int(row["wlan.seq"])
        assert int(table.tsft_us[i]) == int(row["radiotap.mactime"])


# -- round trips through an independent writer -------------------------------------

FIELD_BITS = sorted(w.SPEC)

rt_fields = st.dictionaries(
    st.sampled_from(FIELD_BITS), st.integers(min_value=0, max_value=2**64 - 1), max_size=12
)


@st.composite
def headers(draw: st.DrawFn) -> tuple[list[w.Namespace], dict[str, object]]:
    """A radiotap header with random namespace-0 fields, chains and vendor namespaces."""
    ns0_numbers = draw(rt_fields)
    ns0 = w.RtNamespace({bit: w.value(bit, n) for bit, n in ns0_numbers.items()})
    namespaces: list[w.Namespace] = [ns0]
    chains = []
    for _ in range(draw(st.integers(0, 4))):
        if draw(st.booleans()):
            namespaces.append(
                w.VendorNs(
                    oui=draw(st.integers(0, 2**24 - 1)),
                    subns=draw(st.integers(0, 255)),
                    data=draw(st.binary(max_size=24)),
                    present_bits=draw(st.integers(0, 2**29 - 1)),
                )
            )
        extra = draw(rt_fields)
        ant = draw(st.integers(0, 7))
        dbm = draw(st.integers(-128, 127))
        has_pair = draw(st.booleans())
        fields = {bit: w.value(bit, n) for bit, n in extra.items()}
        fields.pop(5, None)
        fields.pop(11, None)
        if has_pair:
            fields[5] = w.value(5, dbm)
            fields[11] = w.value(11, ant)
            chains.append((ant, dbm))
        namespaces.append(w.RtNamespace(fields))
    expected: dict[str, object] = {"chains": tuple(chains)}

    def num(bit: int, signed: bool = False) -> int | None:
        raw = ns0.fields.get(bit)
        return None if raw is None else int.from_bytes(raw[:8], "little", signed=signed)

    expected["tsft_us"] = num(0)
    expected["flags"] = num(1)
    expected["rate_500kbps"] = num(2)
    chan = ns0.fields.get(3)
    expected["channel_mhz"] = None if chan is None else struct.unpack("<H", chan[:2])[0]
    expected["channel_flags"] = None if chan is None else struct.unpack("<H", chan[2:])[0]
    expected["signal_dbm"] = num(5, signed=True)
    expected["noise_dbm"] = num(6, signed=True)
    expected["antenna"] = num(11)
    expected["rx_flags"] = num(14)
    expected["vendor_namespaces"] = tuple(
        radiotap.VendorNamespace(ns.oui, ns.subns, len(ns.data))
        for ns in namespaces
        if isinstance(ns, w.VendorNs)
    )
    return namespaces, expected


@settings(max_examples=150, deadline=None)
@given(headers(), st.binary(max_size=8))
def test_round_trip_independent_writer(
    case: tuple[list[w.Namespace], dict[str, object]], tail: bytes
) -> None:
    namespaces, expected = case
    hdr = w.build(namespaces)
    info = radiotap.parse(hdr + w.dot11() + tail)
    assert info.length == len(hdr)
    assert info.stopped_at_bit is None
    for key, value in expected.items():
        assert getattr(info, key) == value, key


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(headers(), min_size=1, max_size=6), st.integers(1, 40))
def test_vectorised_decode_equals_frame_walk(
    cases: list[tuple[list[w.Namespace], dict[str, object]]], repeat: int
) -> None:
    """Grouped numpy gathers and the per-frame walk give identical tables."""
    frames = []
    for k in range(repeat):
        for j, (namespaces, _) in enumerate(cases):
            frames.append((k * 1000 + j, w.build(namespaces) + w.dot11(seq=k % 4096)))
    (chunk,) = iter_chunks(w.pcap([(t * 1000, f) for t, f in frames]))
    spans = FrameSpans(
        chunk.start, chunk.caplen, chunk.t_ns, chunk.frame_no, chunk.file_offset, chunk.linktype
    )
    fast = FrameDecoder(n_antennas=8, vector_min=0).decode(chunk.buf, spans)
    slow = FrameDecoder(n_antennas=8, vector_min=10**9).decode(chunk.buf, spans)
    assert [p.detail for p in fast.problems] == [p.detail for p in slow.problems]
    assert fast.dropped == slow.dropped
    for name in ("frame_no", "tsft_us", "has_tsft", "rt_flags", "freq_mhz", "mac", "seq"):
        np.testing.assert_array_equal(getattr(fast.table, name), getattr(slow.table, name))
    np.testing.assert_array_equal(fast.table.chain_dbm, slow.table.chain_dbm)
    np.testing.assert_array_equal(fast.table.signal_dbm, slow.table.signal_dbm)


SCAPY_FIELDS = ["TSFT", "Flags", "Rate", "Channel", "dBm_AntSignal", "dBm_AntNoise", "Antenna"]
SCAPY_FIELDS.append("RXFlags")


@settings(max_examples=60, deadline=None)
@given(
    tsft=st.integers(0, 2**64 - 1),
    flags=st.integers(0, 255),
    rate_mbps=st.integers(0, 127),
    freq=st.integers(0, 2**16 - 1),
    chan_flags=st.integers(0, 2**16 - 1),
    signal=st.integers(-128, 127),
    noise=st.integers(-128, 127),
    antenna=st.integers(0, 255),
    rx=st.integers(0, 2**16 - 1),
    which=st.sets(st.sampled_from(SCAPY_FIELDS)),
)
def test_scapy_built_headers(
    tsft: int, flags: int, rate_mbps: int, freq: int, chan_flags: int, signal: int,
    noise: int, antenna: int, rx: int, which: set[str],
) -> None:  # fmt: skip
    """Headers built by scapy (another writer) parse to the values it was given."""
    from scapy.layers.dot11 import RadioTap

    values = {
        "TSFT": {"mac_timestamp": tsft},
        "Flags": {"Flags": flags},
        "Rate": {"Rate": rate_mbps},
        "Channel": {"ChannelFrequency": freq, "ChannelFlags": chan_flags},
        "dBm_AntSignal": {"dBm_AntSignal": signal},
        "dBm_AntNoise": {"dBm_AntNoise": noise},
        "Antenna": {"Antenna": antenna},
        "RXFlags": {"RXFlags": rx},
    }
    kwargs: dict[str, int] = {}
    for name in which:
        kwargs.update(values[name])
    present = "+".join(sorted(which)) if which else 0
    built = bytes(RadioTap(present=present, **kwargs))
    info = radiotap.parse(built)
    assert info.length == len(built)
    assert info.tsft_us == (tsft if "TSFT" in which else None)
    assert info.flags == (flags if "Flags" in which else None)
    assert info.rate_500kbps == (rate_mbps * 2 if "Rate" in which else None)
    assert info.channel_mhz == (freq if "Channel" in which else None)
    assert info.channel_flags == (chan_flags if "Channel" in which else None)
    assert info.signal_dbm == (signal if "dBm_AntSignal" in which else None)
    assert info.noise_dbm == (noise if "dBm_AntNoise" in which else None)
    assert info.antenna == (antenna if "Antenna" in which else None)
    assert info.rx_flags == (rx if "RXFlags" in which else None)
    assert info.chains == ()


# -- namespace rules and malformed headers -------------------------------------------


def test_site_example_extended_bitmap_indexes_continue() -> None:
    """Words without namespace bits continue the index (32, 33, …): unknown, so the walk stops."""
    hdr = struct.pack("<BBHIII", 0, 0, 20, 0x80000002, 0x80000006, 0x00000003) + b"\x10\x00"
    info = radiotap.parse(hdr + bytes(6))
    assert info.flags == 0x10
    assert info.stopped_at_bit == 33
    assert info.present == (0x80000002, 0x80000006, 0x00000003)


def test_tlv_stops_the_walk_but_it_len_is_used() -> None:
    body = struct.pack("<BBHI", 0, 0, 0, (1 << 1) | (1 << 28)) + b"\x10" + bytes(3) + bytes(8)
    hdr = body[:2] + struct.pack("<H", len(body)) + body[4:]
    info = radiotap.parse(hdr + w.dot11())
    assert info.flags == 0x10
    assert info.stopped_at_bit == 28
    assert info.length == len(hdr)


def test_vendor_namespace_data_is_skipped_by_length() -> None:
    hdr = w.build(
        [
            w.RtNamespace({5: w.value(5, -30)}),
            w.VendorNs(0x001122, 3, b"\xaa" * 7, present_bits=0x7),
            w.RtNamespace({5: w.value(5, -41), 11: w.value(11, 1)}),
        ]
    )
    info = radiotap.parse(hdr)
    assert info.chains == ((1, -41),)
    assert info.vendor_namespaces == (radiotap.VendorNamespace(0x001122, 3, 7),)


def test_sentinel_chains_are_reported_as_written() -> None:
    hdr = w.build(
        [
            w.RtNamespace({5: w.value(5, -50)}),
            w.RtNamespace({5: w.value(5, -128), 11: w.value(11, 0)}),
            w.RtNamespace({5: w.value(5, 0), 11: w.value(11, 1)}),
        ]
    )
    assert radiotap.parse(hdr).chains == ((0, -128), (1, 0))


def _meshid_frame(data_dir: Path) -> bytes:
    return raw_frames(data_dir / "ieee802.11_meshid.pcap")[0]


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda b: b[:6], "shorter than the 8-byte radiotap header"),
        (lambda b: b"\x01" + b[1:], "unsupported radiotap version 1"),
        (lambda b: b[:2] + struct.pack("<H", 4) + b[4:], "it_len 4 is shorter"),
        (lambda b: b[:2] + struct.pack("<H", 60000) + b[4:], "it_len 60000 is larger than"),
        (lambda b: b[:2] + struct.pack("<H", 12) + b[4:], "present word 3 at header offset 12"),
        (lambda b: b[:2] + struct.pack("<H", 40) + b[4:], "offset 40 runs past it_len 40"),
        (lambda b: b[:4] + struct.pack("<I", 0xE040402F) + b[8:], "sets both namespace bits"),
    ],
)
def test_malformed_headers_name_the_offset(data_dir: Path, mutate: object, message: str) -> None:
    frame = _meshid_frame(data_dir)
    with pytest.raises(CaptureFormatError, match=message):
        radiotap.parse(mutate(frame))  # type: ignore[operator]


def test_flags_properties() -> None:
    hdr = w.build([w.RtNamespace({1: bytes([0x50])})])
    info = radiotap.parse(hdr)
    assert info.fcs_at_end and info.bad_fcs


def test_freq_to_channel() -> None:
    freqs = np.array([2412, 2437, 2472, 2484, 5180, 5745, 5825, 5955, 5935, 4920, 0, 1234])
    expected = [1, 6, 13, 14, 36, 149, 165, 1, 2, 184, 0, 0]
    assert freq_to_channel(freqs).tolist() == expected
