"""Every real CSI capture in tests/data/csi parses with the counts its provenance notes give.

The expected numbers are those of tests/data/csi/PROVENANCE.md (read there with
csiread 1.4.1 / CSIKit 2.5); the files carry no ground-truth bearing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.errors import CaptureFormatError, RfsasError, SourceError
from rfsas_hw.records import ObservationBatch, ObsFlag
from rfsas_hw.sources.csi import CsiSource, capture_frames, read_capture
from rfsas_hw.sources.registry import open_source

DATA = Path(__file__).resolve().parents[1] / "data" / "csi"


def _read(name: str, **options: object) -> tuple[CsiSource, list[ObservationBatch]]:
    src = CsiSource(str(DATA / name), **options)  # type: ignore[arg-type]
    with src:
        batches = list(src)
    assert batches
    return src, batches


def _span_s(t_ns: np.ndarray) -> float:
    return float(t_ns.max() - t_ns.min()) / 1e9


def test_intel_mixed_streams() -> None:
    cap = read_capture(DATA / "log.all_csi.6.7.6.dat")
    (block,) = cap.blocks
    assert len(block) == 29 and block.n_rx == 3
    streams = np.isfinite(block.h[:, 0, :, 0]).sum(axis=1)
    assert np.bincount(streams)[1:].tolist() == [10, 9, 10]


def test_intel_sample_ap_counts_and_rssi_order() -> None:
    cap = read_capture(DATA / "sample_0x1_ap.dat")
    (block,) = cap.blocks
    assert len(block) == 540
    assert block.h.shape == (540, 3, 2, 30)
    assert _span_s(block.t_ns) == pytest.approx(59.6, abs=0.05)
    assert cap.notes["antenna permutations"] == 1
    # rssi_a/b/c ≈ 31 / 40 / 35 dB on one AGC: b is 9 dB above a, c 4 dB above a
    mean = np.nanmean(block.rssi_dbm, axis=0)
    assert mean[1] - mean[0] == pytest.approx(9.0, abs=1.0)
    assert mean[2] - mean[0] == pytest.approx(4.0, abs=1.0)
    assert block.mac.max() == 0  # 0xBB records carry no address


def test_intel_los_four_permutations_and_wrap_free_time() -> None:
    cap = read_capture(DATA / "los_5.dat")
    (block,) = cap.blocks
    assert len(block) == 1006 and block.h.shape[1:3] == (3, 1)
    assert _span_s(block.t_ns) == pytest.approx(61.6, abs=0.05)
    assert cap.notes["antenna permutations"] == 4


def test_intel_permutation_is_undone() -> None:
    """Chain k carries antenna perm[k]: with perm [1,2,0] antenna 1 holds chain 0's row."""
    from rfsas_hw.sources.csi_intel import HEADER_BYTES, _unpack

    raw = (DATA / "sample_0x1_ap.dat").read_bytes()
    length = int.from_bytes(raw[0:2], "big")
    body = np.frombuffer(raw[3 : 2 + length], np.uint8)
    assert body[15] & 0x3F == (1 | 2 << 2 | 0 << 4)  # perm [1, 2, 0]
    chains = _unpack(body[None, HEADER_BYTES:], 3, 2)[0]
    cap = read_capture(DATA / "sample_0x1_ap.dat")
    h = cap.blocks[0].h[0]
    for chain, antenna in enumerate((1, 2, 0)):
        np.testing.assert_array_equal(h[antenna], chains[chain])


def test_intel_flags_2g4_phase_ambiguity_only_when_told() -> None:
    at_5g = read_capture(DATA / "sample_0x1_ap.dat", freq_mhz=5200).blocks[0]
    at_2g = read_capture(DATA / "sample_0x1_ap.dat", freq_mhz=2437).blocks[0]
    assert not np.any(at_5g.flags & ObsFlag.PHASE_AMBIGUOUS)
    assert np.all(at_2g.flags & ObsFlag.PHASE_AMBIGUOUS)
    assert at_2g.freq_mhz[0] == 2437


@pytest.mark.extra("csi")
def test_atheros_counts_rssi_and_phase_spread() -> None:
    src, batches = _read("ath_csi_1.dat")
    obs = batches[0]
    assert sum(len(b) for b in batches) == 401
    assert obs.csi is not None and obs.csi.h.shape[1:] == (3, 2, 56)
    assert set(obs.freq_mhz.tolist()) == {2437} and obs.channel[0] == 6
    assert _span_s(obs.t_ns) == pytest.approx(0.87, abs=0.01)
    lo = np.nanmin(obs.rssi_dbm, axis=0)
    hi = np.nanmax(obs.rssi_dbm, axis=0)
    for k, (a, b) in enumerate(((36, 40), (49, 54), (33, 37))):
        assert a - 1 <= lo[k] and hi[k] <= b + 1
    assert src.stats.extra["phase_std_deg_0_1"] == pytest.approx(7.6, abs=0.1)
    assert src.stats.extra["phase_std_deg_0_2"] == pytest.approx(15.6, abs=0.1)


@pytest.mark.extra("csi")
def test_picoscenes_qca9300() -> None:
    src, batches = _read("rx_by_qca9300.csi")
    obs = batches[0]
    assert len(obs) == 1000 and obs.csi is not None
    assert obs.csi.h.shape[1:] == (3, 1, 56)
    assert set(obs.freq_mhz.tolist()) == {5200}
    assert np.all(np.isfinite(obs.rssi_dbm))
    assert src.stats.extra["phase_std_deg_0_1"] == pytest.approx(11.0, abs=1.0)
    assert src.stats.extra["phase_std_deg_0_2"] == pytest.approx(11.0, abs=1.0)
    assert obs.mac.max() > 0


@pytest.mark.extra("csi")
def test_picoscenes_ax200_read_despite_csiread_default() -> None:
    src, batches = _read("rx_8_211119_171706.csi")
    obs = batches[0]
    assert len(obs) == 433 and obs.n_antennas == 2
    assert obs.rssi_dbm[0].tolist() == [-67.0, -65.0]
    assert _span_s(obs.t_ns) == pytest.approx(3.7, abs=0.05)
    assert src.stats.extra["absent chains (RSSI −128) beyond NumRx"] == 433


@pytest.mark.parametrize(
    ("name", "frames", "tones"), [("HT20_2452.csi", 48, 56), ("VHT80_5500.csi", 40, 242)]
)
def test_feitcsi(name: str, frames: int, tones: int) -> None:
    freq = int(name.split("_")[1].split(".")[0])
    with open_source(f"csi:{DATA / name}?freq={freq}") as src:
        via_spec = sum(len(b) for b in src)
    obs = capture_frames(DATA / name, freq_mhz=freq)
    assert via_spec == len(obs)
    assert len(obs) == frames and obs.csi is not None
    assert obs.csi.h.shape[1:] == (2, 1, tones)
    assert np.all(np.isfinite(obs.rssi_dbm)) and np.all(obs.rssi_dbm < 0)
    assert set(obs.freq_mhz.tolist()) == {freq}


@pytest.mark.extra("csi")
def test_nexmon_new_format_one_core() -> None:
    src, batches = _read("example_43455c0.pcap")
    obs = batches[0]
    assert len(obs) == 566 and obs.n_antennas == 1
    assert obs.csi is not None and obs.csi.h.shape[-1] == 256
    assert set(obs.freq_mhz.tolist()) == {5210}  # chanspec 0xe02a: channel 42, 80 MHz
    assert np.nanmin(obs.rssi_dbm) >= -59 and np.nanmax(obs.rssi_dbm) <= -58
    assert src.stats.extra["packets longer than the CSI they carry"] == 18


@pytest.mark.extra("csi")
def test_nexmon_old_format_core0() -> None:
    _, batches = _read("example_4366c0.pcap")
    obs = batches[0]
    assert len(obs) == 293 and obs.n_antennas == 1
    assert _span_s(obs.t_ns) == pytest.approx(29.9, abs=0.05)
    assert set(obs.freq_mhz.tolist()) == {5530}  # chanspec 0xe06a
    assert np.all(obs.flags & ObsFlag.NO_SIGNAL)


@pytest.mark.parametrize(
    ("name", "frames", "channel"), [("example_csi.csv", 13, 1), ("example_data.csv", 60, 6)]
)
def test_esp32_one_antenna(name: str, frames: int, channel: int) -> None:
    src, batches = _read(name)
    obs = batches[0]
    assert len(obs) == frames and obs.n_antennas == 1
    assert obs.csi is not None and obs.csi.h.shape[1:] == (1, 1, 64)
    assert set(obs.channel.tolist()) == {channel}
    assert np.all(obs.rssi_dbm < -60) and obs.mac.max() > 0
    assert src.stats.extra["one antenna per packet"] == frames


def test_esp32_bad_line_costs_only_itself(tmp_path: Path) -> None:
    lines = (DATA / "example_data.csv").read_text().splitlines()
    lines[3] = lines[3].partition("[")[0] + "[1 2 3 ]"
    lines[5] = lines[5][:60]
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines) + "\n")
    with CsiSource(str(path)) as src:
        assert sum(len(b) for b in src) == 58
    assert src.stats.skipped["bad line"] == 2
    assert any("line 4:" in e for e in src.stats.errors)


def test_truncated_intel_file_costs_only_the_last_record(tmp_path: Path) -> None:
    raw = (DATA / "sample_0x1_ap.dat").read_bytes()
    cut = tmp_path / "cut.dat"
    cut.write_bytes(raw[:-100])
    with CsiSource(str(cut)) as src:
        n = sum(len(b) for b in src)
    assert n == 539
    assert src.stats.skipped["truncated record"] == 1
    assert "at byte" in src.stats.errors[0]
    strict = CsiSource(str(cut), errors="raise")
    with strict, pytest.raises(CaptureFormatError, match="runs past the end"):
        list(strict)


def test_corrupt_intel_record_is_skipped(tmp_path: Path) -> None:
    raw = bytearray((DATA / "log.all_csi.6.7.6.dat").read_bytes())
    raw[3 + 8] = 7  # first record: Nrx 7 is impossible (and mismatches its length)
    path = tmp_path / "bad.dat"
    path.write_bytes(bytes(raw))
    with CsiSource(str(path)) as src:
        assert sum(len(b) for b in src) == 28
    assert src.stats.skipped["bad record"] == 1


def test_truncated_feitcsi(tmp_path: Path) -> None:
    raw = (DATA / "HT20_2452.csi").read_bytes()
    path = tmp_path / "cut.csi"
    path.write_bytes(raw[:-10])
    with CsiSource(str(path), format="feitcsi") as src:
        assert sum(len(b) for b in src) == 47
    assert sum(src.stats.skipped.values()) == 1


@pytest.mark.parametrize(
    ("content", "fmt", "match"),
    [
        (b"\x00" * 400, "feitcsi", "not a FeitCSI frame"),
        (b"\x00\x05\x01abcd" * 10, "intel5300", "no Intel 5300 beamforming record"),
        pytest.param(
            b"\xd4\xc3\xb2\xa1" + b"\x00" * 60,
            "nexmon",
            "no UDP packet with a nexmon",
            marks=pytest.mark.extra("csi"),
        ),
        pytest.param(
            b"junk" * 50, "nexmon", "not a little-endian pcap", marks=pytest.mark.extra("csi")
        ),
    ],
)
def test_foreign_files_fail_clearly(tmp_path: Path, content: bytes, fmt: str, match: str) -> None:
    path = tmp_path / "x.bin"
    path.write_bytes(content)
    with pytest.raises(CaptureFormatError, match=match):
        CsiSource(str(path), format=fmt)


def test_spec_errors(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match="no such CSI capture"):
        open_source(f"csi:{tmp_path / 'missing.dat'}")
    with pytest.raises(SourceError, match="unknown option"):
        open_source(f"csi:{DATA / 'los_5.dat'}?band=5")
    with pytest.raises(SourceError, match="unknown format"):
        CsiSource(str(DATA / "los_5.dat"), format="esp")
    with pytest.raises(SourceError, match="not a channel frequency"):
        open_source(f"csi:{DATA / 'los_5.dat'}?freq={10**30}")
    with pytest.raises(SourceError, match="freq must be MHz"):
        open_source(f"csi:{DATA / 'los_5.dat'}?freq=2.4GHz")
    with pytest.raises(SourceError, match="not plausible"):
        open_source(f"csi:{DATA / 'los_5.dat'}?rssi_offset=nan")


def test_missing_csiread_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    from rfsas_hw.errors import MissingDependencyError

    monkeypatch.setitem(sys.modules, "csiread", None)
    with pytest.raises(MissingDependencyError, match=r"rfsas-hw\[csi\]"):
        CsiSource(str(DATA / "ath_csi_1.dat"))
    # the formats read without csiread still work
    with CsiSource(str(DATA / "los_5.dat")) as src:
        assert sum(len(b) for b in src) == 1006


def test_intel_frame_records_give_the_transmitter(tmp_path: Path) -> None:
    """connector_log 0x5: each 0xC1 record (the 802.11 frame) names the k-th frame's MAC."""
    raw = (DATA / "log.all_csi.6.7.6.dat").read_bytes()
    out = bytearray()
    pos, k = 0, 0
    while pos < len(raw):
        length = int.from_bytes(raw[pos : pos + 2], "big")
        header = bytes([0x08, 0x00, 0, 0]) + bytes(6) + (0x020000000100 + k).to_bytes(6, "big")
        header += bytes(6) + ((k + 7) << 4).to_bytes(2, "little")
        out += (len(header) + 1).to_bytes(2, "big") + bytes([0xC1]) + header
        out += raw[pos : pos + 2 + length]
        pos += 2 + length
        k += 1
    path = tmp_path / "with_frames.dat"
    path.write_bytes(bytes(out))
    obs = capture_frames(path)
    assert len(obs) == 29
    assert obs.mac.tolist() == [0x020000000100 + i for i in range(29)]
    assert obs.seq.tolist() == [i + 7 for i in range(29)]


THROUGH_CSIREAD = {"atheros", "picoscenes", "nexmon"}
"""Formats read through csiread (the csi extra)."""

CORRUPTIBLE = {
    "intel5300": "los_5.dat",
    "atheros": "ath_csi_1.dat",
    "picoscenes": "rx_by_qca9300.csi",
    "feitcsi": "HT20_2452.csi",
    "nexmon": "example_4366c0.pcap",
    "esp32": "example_data.csv",
}


@pytest.mark.parametrize(
    "fmt",
    [
        pytest.param(fmt, marks=[pytest.mark.extra("csi")] if fmt in THROUGH_CSIREAD else [])
        for fmt in sorted(CORRUPTIBLE)
    ],
)
def test_corrupted_bytes_fail_only_with_rfsas_errors(tmp_path: Path, fmt: str) -> None:
    """Flipped bytes, cuts and noise: frames or one clear error, never a crash."""
    raw = (DATA / CORRUPTIBLE[fmt]).read_bytes()
    rng = np.random.default_rng(17)
    path = tmp_path / "x"
    outcomes = []
    for trial in range(12):
        data = bytearray(raw)
        if trial % 3 == 0:
            data = data[: int(rng.integers(1, len(data)))]
        else:
            for _ in range(int(rng.integers(1, 40))):
                data[int(rng.integers(0, len(data)))] = int(rng.integers(0, 256))
        path.write_bytes(bytes(data))
        try:
            with CsiSource(str(path), format=fmt) as src:
                outcomes.append(sum(len(b) for b in src))
        except RfsasError:
            outcomes.append(-1)
    assert any(n > 0 for n in outcomes)


def test_feitcsi_resynchronises_after_a_broken_header(tmp_path: Path) -> None:
    raw = bytearray((DATA / "HT20_2452.csi").read_bytes())
    frame = len(raw) // 48
    raw[10 * frame + 46] = 9  # frame 10 claims 9 RX chains
    path = tmp_path / "x.csi"
    path.write_bytes(bytes(raw))
    with CsiSource(str(path)) as src:
        assert sum(len(b) for b in src) == 47
    assert src.stats.skipped["bad frame"] == 1
    assert f"skipped to byte {11 * frame}" in src.stats.errors[0]
