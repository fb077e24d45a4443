"""pcap/pcapng reading: containers, byte orders, interfaces, broken inputs, the source API."""

from __future__ import annotations

import io
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rt_writer as w

import rfsas_hw.sources
from rfsas_hw.errors import CaptureFormatError, SourceError
from rfsas_hw.records import FrameKind, ObservationBatch, ObsFlag
from rfsas_hw.sources.pcap import PcapSource
from rfsas_hw.sources.pcapfile import CaptureParser, iter_chunks

MESHID_RSSI = [[-39.0, -34.0], [-38.0, -44.0], [-40.0, -34.0]]
MESHID_T_NS = [1625401237867811000, 1625401238357687000, 1625401238358276000]
MESHID_SEQ = [268, 116, 0]


def read_all(spec: str, **options: object) -> tuple[ObservationBatch, PcapSource]:
    src = rfsas_hw.sources.open(spec, **options)
    assert isinstance(src, PcapSource)
    with src:
        batches = list(src)
    return ObservationBatch.concat(batches), src


@pytest.mark.parametrize(
    "name",
    [
        "ieee802.11_meshid.pcap",
        "meshid_big_endian.pcap",
        "meshid_little_endian.pcapng",
        "meshid_big_endian.pcapng",
    ],
)
@pytest.mark.parametrize("vector_min", [0, 1000])
def test_same_observations_in_every_container(data_dir: Path, name: str, vector_min: int) -> None:
    obs, src = read_all(f"pcap:{data_dir / name}", vector_min=vector_min)
    assert obs.rssi_dbm.tolist() == MESHID_RSSI
    assert obs.t_ns.tolist() == MESHID_T_NS
    assert obs.seq.tolist() == MESHID_SEQ
    assert obs.channel.tolist() == [149, 149, 149]
    assert obs.freq_mhz.tolist() == [5745] * 3
    assert obs.kind.tolist() == [
        FrameKind.BEACON,
        FrameKind.PROBE_REQUEST,
        FrameKind.PROBE_RESPONSE,
    ]
    assert obs.flags.tolist() == [0, 0, 0]
    assert src.stats.frames == 3
    assert not src.stats.skipped


def test_two_interfaces_with_own_link_type_and_resolution(data_dir: Path) -> None:
    obs, src = read_all(f"pcap:{data_dir / 'two_interfaces_radiotap_ns_and_80211_us.pcapng'}")
    assert len(obs) == 6
    # Interface 0 (ns resolution) and interface 1 (µs, one µs later) interleave.
    expected_t = [t + d for t in MESHID_T_NS for d in (0, 1000)]
    assert obs.t_ns.tolist() == expected_t
    np.testing.assert_array_equal(obs.rssi_dbm[0::2], MESHID_RSSI)
    assert np.isnan(obs.rssi_dbm[1::2]).all()
    assert (obs.flags[1::2] & ObsFlag.NO_SIGNAL).all()
    assert obs.seq.tolist() == [s for s in MESHID_SEQ for _ in (0, 1)]
    assert src.stats.extra["flagged"]["no per-antenna signal"] == 3


BROKEN = [
    # file, frames kept (seq numbers), skip reason, message parts (frame number, byte offset)
    ("broken_truncated_file.pcap", [268, 116], "truncated record", "frame 3 at byte 574"),
    (
        "broken_record_cut_inside_radiotap.pcap",
        [268, 0],
        "malformed radiotap header",
        "frame 2 at byte 279: radiotap: it_len 56 is larger than the captured frame (30 bytes)",
    ),
    (
        "broken_it_len_larger_than_packet.pcap",
        [268, 0],
        "malformed radiotap header",
        "frame 2 at byte 279: radiotap: it_len 500",
    ),
    ("broken_zero_length_frame.pcap", [268, 0], "zero-length frame", "frame 2 at byte 279"),
    (
        "broken_corrupt_record_header.pcap",
        [268, 0],
        "corrupt record header",
        "frame 2 at byte 279: record header says 2147483647 captured bytes",
    ),
    (
        "broken_unknown_block.pcapng",
        [268, 116, 0],
        "unknown pcapng block",
        "byte 320: unknown pcapng block type 0x00000777",
    ),
    (
        "broken_bad_byte_order_magic_second_section.pcapng",
        [268, 116, 0],
        "malformed pcapng block",
        "byte 320: bad pcapng byte-order magic 44332211",
    ),
]


@pytest.mark.parametrize(("name", "seqs", "reason", "message"), BROKEN)
def test_broken_capture_loses_only_the_damaged_frame(
    data_dir: Path, name: str, seqs: list[int], reason: str, message: str
) -> None:
    obs, src = read_all(f"pcap:{data_dir / name}")
    assert obs.seq.tolist() == seqs
    assert dict(src.stats.skipped) == {reason: 1}
    assert len(src.stats.errors) == 1
    assert message in src.stats.errors[0]
    assert name in src.stats.errors[0]


@pytest.mark.parametrize(("name", "seqs", "reason", "message"), BROKEN)
def test_raise_policy_stops_at_the_damaged_frame(
    data_dir: Path, name: str, seqs: list[int], reason: str, message: str
) -> None:
    with pytest.raises(CaptureFormatError, match=message.split(":")[0]):
        read_all(f"pcap:{data_dir / name}", errors="raise")


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("broken_not_a_capture.pcap", "byte 0: not a pcap or pcapng file"),
        ("broken_bad_byte_order_magic.pcapng", "byte 0: bad pcapng byte-order magic"),
    ],
)
def test_not_a_capture_is_one_clear_error(data_dir: Path, name: str, message: str) -> None:
    with pytest.raises(CaptureFormatError, match=message):
        read_all(f"pcap:{data_dir / name}")


def test_missing_file_is_a_source_error(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match="no such capture file"):
        rfsas_hw.sources.open(f"pcap:{tmp_path / 'nope.pcap'}")


def test_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.pcap"
    path.write_bytes(b"")
    with pytest.raises(CaptureFormatError, match="empty or truncated capture"):
        read_all(f"pcap:{path}")


def test_byte_by_byte_feeding_equals_one_block(data_dir: Path) -> None:
    """The push parser gives the same frames however the stream is cut."""
    for name in ("broken_corrupt_record_header.pcap", "broken_unknown_block.pcapng"):
        data = (data_dir / name).read_bytes()
        whole = iter_chunks(data)
        parser = CaptureParser("x")
        pieces = []
        for i in range(len(data)):
            parser.feed(data[i : i + 1])
            while (chunk := parser.next_chunk()) is not None:
                pieces.append(chunk)
        while (chunk := parser.next_chunk(final=True)) is not None:
            pieces.append(chunk)

        def frames(chunks: list) -> list[tuple[int, bytes]]:  # type: ignore[type-arg]
            return [
                (int(n), c.buf[s : s + ln])
                for c in chunks
                for n, s, ln in zip(c.frame_no, c.start, c.caplen, strict=True)
            ]

        assert frames(pieces) == frames(whole)
        assert [p.detail for c in pieces for p in c.problems] == [
            p.detail for c in whole for p in c.problems
        ]


def _frames_file(tmp_path: Path, frames: list[bytes], linktype: int = 127) -> Path:
    path = tmp_path / "cap.pcap"
    path.write_bytes(
        w.pcap([(1_700_000_000_000_000_000 + i * 1000, f) for i, f in enumerate(frames)], linktype)
    )
    return path


CHAINS = [
    w.RtNamespace({1: w.value(1, 0), 3: b"\x6c\x09\xa0\x00", 5: w.value(5, -40)}),
    w.RtNamespace({5: w.value(5, -41), 11: w.value(11, 0)}),
    w.RtNamespace({5: w.value(5, -47), 11: w.value(11, 1)}),
]


@pytest.mark.parametrize("vector_min", [0, 1000])
def test_flags_sentinels_fcs_and_control_frames(tmp_path: Path, vector_min: int) -> None:
    def hdr(flags: int, c0: int, c1: int | None) -> bytes:
        ns = [
            w.RtNamespace({1: w.value(1, flags), 3: b"\x6c\x09\xa0\x00", 5: w.value(5, -40)}),
            w.RtNamespace({5: w.value(5, c0), 11: w.value(11, 0)}),
        ]
        if c1 is not None:
            ns.append(w.RtNamespace({5: w.value(5, c1), 11: w.value(11, 1)}))
        return w.build(ns)

    frames = [
        hdr(0x10, -41, -47) + w.dot11(ta=0xA, seq=1, fcs=True),  # good, FCS stripped
        hdr(0x50, -41, -47) + w.dot11(ta=0xB, seq=2, fcs=True),  # bad FCS: dropped
        hdr(0x00, -128, -47) + w.dot11(ta=0xC, seq=3),  # iwlwifi sentinel
        hdr(0x00, -41, None) + w.dot11(ta=0xD, seq=4, retry=True),  # one chain only, retry
        hdr(0x00, -41, -47) + w.dot11(type_subtype=0x1D),  # ACK: no transmitter
        w.build([w.RtNamespace({3: b"\x6c\x09\xa0\x00"})]) + w.dot11(ta=0xE, seq=5),  # no signal
        w.build([w.RtNamespace({5: w.value(5, -60)})]) + w.dot11(ta=0xF, type_subtype=0x28),
    ]
    obs, src = read_all(f"pcap:{_frames_file(tmp_path, frames)}", vector_min=vector_min)
    assert obs.mac.tolist() == [0xA, 0xC, 0xD, 0xE, 0xF]
    assert obs.seq.tolist() == [1, 3, 4, 5, 1]
    np.testing.assert_array_equal(
        obs.rssi_dbm,
        [[-41, -47], [np.nan, -47], [-41, np.nan], [np.nan, np.nan], [np.nan, np.nan]],
    )
    assert obs.flags.tolist() == [
        0,
        ObsFlag.SENTINEL_CHAIN | ObsFlag.MISSING_CHAIN,
        ObsFlag.RETRY | ObsFlag.MISSING_CHAIN,
        ObsFlag.MISSING_CHAIN | ObsFlag.NO_SIGNAL,
        ObsFlag.MISSING_CHAIN,
    ]
    assert obs.kind.tolist() == [FrameKind.BEACON] * 4 + [FrameKind.QOS_DATA]
    assert dict(src.stats.skipped) == {"bad FCS": 1, "no transmitter address (ACK/CTS)": 1}
    assert dict(src.stats.extra["flagged"]) == {
        "sentinel chain value": 1,
        "no per-antenna signal": 2,
        "no signal at all": 1,
    }


def test_unsupported_link_type_is_counted(tmp_path: Path) -> None:
    obs, src = read_all(f"pcap:{_frames_file(tmp_path, [b'x' * 60] * 3, linktype=1)}")
    assert len(obs) == 0
    assert dict(src.stats.skipped) == {"unsupported link type 1": 3}


def test_pcapng_binary_resolution_and_big_endian() -> None:
    frame = w.build(CHAINS) + w.dot11()
    for big in (False, True):
        data = w.pcapng([(127, 0x80 | 20)], [(0, 5 * 2**20 + 2**19, frame)], big_endian=big)
        (chunk,) = iter_chunks(data)
        assert chunk.t_ns.tolist() == [5_500_000_000]


def test_pcapng_undefined_interface_and_skipped_blocks() -> None:
    frame = w.build(CHAINS) + w.dot11()
    data = w.pcapng(
        [(127, None)],
        [(0, 1, frame), (3, 2, frame), (0, 3, frame)],
        extra_blocks=[(1, 5, bytes(16)), (2, 4, bytes(8))],  # statistics, name resolution
    )
    (chunk,) = iter_chunks(data, "x.pcapng")
    assert chunk.frame_no.tolist() == [1, 3]
    assert [p.reason for p in chunk.problems] == ["undefined pcapng interface"]
    assert "frame 2 at byte" in str(chunk.problems[0].error("x.pcapng"))


def test_pcapng_simple_packet_block_is_reported() -> None:
    frame = w.build(CHAINS) + w.dot11()
    data = bytearray(w.pcapng([(127, None)], [(0, 1, frame)]))
    body = struct.pack("<I", len(frame)) + frame + bytes(-len(frame) % 4)
    data += struct.pack("<II", 3, len(body) + 12) + body + struct.pack("<I", len(body) + 12)
    (chunk,) = iter_chunks(bytes(data))
    assert chunk.frame_no.tolist() == [1]
    assert [(p.reason, p.frame_no) for p in chunk.problems] == [
        ("pcapng simple packet (no timestamp)", 2)
    ]


def test_stream_option_reads_an_open_binary_stream(data_dir: Path) -> None:
    stream = io.BytesIO((data_dir / "ieee802.11_meshid.pcap").read_bytes())
    obs, _ = read_all("pcap:-", stream=stream)
    assert obs.rssi_dbm.tolist() == MESHID_RSSI


def test_pipe_from_a_real_subprocess_honours_timeouts(data_dir: Path) -> None:
    """``pcap:-`` style reading of a pipe that delivers the capture in two parts."""
    split = 24 + 16 + 239 + 100  # inside frame 2
    script = (
        "import sys, time\n"
        f"d = open({str(data_dir / 'ieee802.11_meshid.pcap')!r}, 'rb').read()\n"
        f"sys.stdout.buffer.write(d[:{split}]); sys.stdout.flush()\n"
        "sys.stdin.readline()\n"
        f"sys.stdout.buffer.write(d[{split}:]); sys.stdout.flush()\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE
    )
    assert proc.stdin is not None and proc.stdout is not None
    try:
        with PcapSource("-", stream=proc.stdout) as src:
            first = None
            while first is None:
                first = src.read(timeout=5.0)
            assert first.seq.tolist() == [268]
            assert src.read(timeout=0.05) is None  # frame 2 is incomplete: timeout
            assert not src.exhausted
            proc.stdin.write(b"go\n")
            proc.stdin.flush()
            rest = []
            while not src.exhausted:
                got = src.read(timeout=5.0)
                if got is not None:
                    rest.append(got)
            assert ObservationBatch.concat(rest).seq.tolist() == [116, 0]
    finally:
        proc.stdin.close()
        proc.wait(timeout=10)
        proc.stdout.close()


def test_filename_with_plus_is_a_single_file(tmp_path: Path, data_dir: Path) -> None:
    path = tmp_path / "a+b.pcap"
    path.write_bytes((data_dir / "ieee802.11_meshid.pcap").read_bytes())
    obs, _ = read_all(f"pcap:{path}")
    assert len(obs) == 3


def _big_capture(kind: str, big_endian: bool, corrupt: bool) -> bytes:
    """~6,000 frames of varied sizes (several MB), optionally with damage in the middle."""
    rng = np.random.default_rng(11)
    header = w.mac80211_header(-40, -44)
    frames = [
        header + w.dot11(ta=0xC0FFEE, seq=i % 4096, payload=bytes(int(rng.integers(0, 900))))
        for i in range(6000)
    ]
    if kind == "pcap":
        stamped = [(1_700_000_000 * 10**9 + i * 10**6, f) for i, f in enumerate(frames)]
        data = bytearray(w.pcap(stamped, big_endian=big_endian))
        if corrupt:
            pos = 24
            for _ in range(3000):
                pos += 16 + struct.unpack_from(">I" if big_endian else "<I", data, pos + 8)[0]
            struct.pack_into(">I" if big_endian else "<I", data, pos + 8, 0x7FFFFFFF)
        return bytes(data)
    extra = [(k, 5, bytes(32)) for k in range(100, 6000, 700)]  # statistics blocks in between
    data = bytearray(
        w.pcapng([(127, 9)], [(0, i * 10**6, f) for i, f in enumerate(frames)], big_endian, extra)
    )
    if corrupt:
        e = ">" if big_endian else "<"
        pos = 0
        for _ in range(3000):  # the 3000th block: its trailing length no longer matches
            pos += struct.unpack_from(e + "I", data, pos + 4)[0]
        blen = struct.unpack_from(e + "I", data, pos + 4)[0]
        struct.pack_into(e + "I", data, pos + blen - 4, blen + 4)
    return bytes(data)


@pytest.mark.parametrize("big_endian", [False, True])
@pytest.mark.parametrize("corrupt", [False, True])
def test_numpy_record_walk_equals_record_by_record(
    monkeypatch: pytest.MonkeyPatch, big_endian: bool, corrupt: bool
) -> None:
    """The lock-step numpy walk over a large pcap finds the records the plain loop finds."""
    from rfsas_hw.sources import pcapfile

    data = _big_capture("pcap", big_endian, corrupt)
    assert len(data) > 20 * pcapfile.FAST_MIN_BYTES

    def run(max_frames: int) -> tuple[list[int], list[int], list[str]]:
        chunks = iter_chunks(data, max_frames=max_frames)
        offsets = [int(x) for c in chunks for x in c.file_offset]
        numbers = [int(x) for c in chunks for x in c.frame_no]
        return offsets, numbers, [p.detail for c in chunks for p in c.problems]

    fast = run(2500)
    whole = run(1 << 30)
    monkeypatch.setattr(pcapfile, "FAST_MIN_BYTES", 1 << 60)
    plain = run(2500)
    assert fast == plain
    assert whole == plain
    assert len(plain[0]) >= 5990 and bool(plain[2]) == corrupt


@pytest.mark.parametrize("kind", ["pcap", "pcapng"])
@pytest.mark.parametrize("corrupt", [False, True])
@pytest.mark.parametrize("block", [700, 100_003])
def test_file_read_in_small_blocks_equals_one_read(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, kind: str, corrupt: bool, block: int
) -> None:
    """Each read starts again at the first unconsumed byte; records wider than a block still fit."""
    from rfsas_hw.sources import pcap

    path = tmp_path / f"big.{kind}"
    path.write_bytes(_big_capture(kind, False, corrupt))
    whole, src = read_all(f"pcap:{path}")
    monkeypatch.setattr(pcap, "BLOCK_BYTES", block)
    pieces, small = read_all(f"pcap:{path}")
    assert len(whole) >= 5990
    for name in ("t_ns", "mac", "seq", "rssi_dbm", "flags"):
        assert np.array_equal(getattr(pieces, name), getattr(whole, name), equal_nan=True)
    assert small.stats.skipped == src.stats.skipped
    assert small.stats.errors == src.stats.errors
    assert bool(src.stats.errors) == corrupt
    assert small.stats.extra["bytes_read"] == path.stat().st_size
