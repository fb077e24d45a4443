"""Two single-antenna receivers paired frame by frame, through offset and drift of their clocks."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import rt_writer as w

import rfsas_hw.sources
from rfsas_hw.records import ObservationBatch, ObsFlag
from rfsas_hw.sources.pairing import PairingConfig, pair_tables
from rfsas_hw.sources.pcap import read_frames

T0_NS = 1_700_000_000_000_000_000
DRIFT = 40e-6  # B's clock runs 40 ppm fast
OFFSET_B_US = 123_456_789.0


def single(signal: int, tsft_us: int | None) -> bytes:
    """A one-antenna receiver's header: TSFT, flags, channel 6, combined signal."""
    fields = {1: w.value(1, 0), 3: struct.pack("<HH", 2437, 0xA0), 5: w.value(5, signal)}
    if tsft_us is not None:
        fields[0] = w.value(0, tsft_us)
    return w.build([w.RtNamespace(fields)])


def scenario(rng: np.random.Generator, tsft: bool = True) -> tuple[bytes, bytes, dict[str, int]]:
    """Beacons from 3 APs and a phone's data frames with retries, heard by two receivers."""
    a: list[tuple[int, bytes]] = []
    b: list[tuple[int, bytes]] = []
    truth = {"both": 0, "only_a": 0, "only_b": 0}
    t_us = 0.0
    seq = {k: 0 for k in range(4)}
    for i in range(3000):
        t_us += float(rng.uniform(300, 3000))
        sender = i % 4
        ta = 0x00_11_22_33_44_00 + sender
        retry = sender == 3 and i % 8 == 7  # a retransmission of the phone's previous frame
        if not retry:
            seq[sender] = (seq[sender] + 1) % 4096
        subtype = 0x08 if sender < 3 else 0x28
        frame = w.dot11(type_subtype=subtype, ta=ta, seq=seq[sender], retry=retry)
        sig_a = -40 - (i % 30)
        sig_b = sig_a + (i % 7) - 3
        tsft_a = int(t_us + 5_000_000) if tsft else None
        tsft_b = int(t_us * (1 + DRIFT) + OFFSET_B_US + rng.normal(0, 3)) if tsft else None
        host_a = T0_NS + int(t_us * 1000)
        host_b = host_a + 150_000 + int(rng.normal(0, 100_000))  # other host clock, ±0.1 ms
        heard = rng.random()
        if heard < 0.9:
            a.append((host_a, single(sig_a, tsft_a) + frame))
            b.append((host_b, single(sig_b, tsft_b) + frame))
            truth["both"] += 1
        elif heard < 0.95:
            a.append((host_a, single(sig_a, tsft_a) + frame))
            truth["only_a"] += 1
        else:
            b.append((host_b, single(sig_b, tsft_b) + frame))
            truth["only_b"] += 1
    b.sort(key=lambda r: r[0])
    return w.pcap(a), w.pcap(b), truth


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict[str, int]]:
    data_a, data_b, truth = scenario(np.random.default_rng(7))
    d = tmp_path_factory.mktemp("pair")
    (d / "a.pcap").write_bytes(data_a)
    (d / "b.pcap").write_bytes(data_b)
    return d / "a.pcap", d / "b.pcap", truth


def test_pairs_match_the_truth_and_the_clock_fit_finds_the_drift(
    files: tuple[Path, Path, dict[str, int]],
) -> None:
    a, _ = read_frames(str(files[0]))
    b, _ = read_frames(str(files[1]))
    result = pair_tables(a, b, PairingConfig())
    truth = files[2]
    c = result.counters
    # Every frame both heard is paired except repeated keys too close to tell apart.
    assert c["paired"] + c["ambiguous"] == truth["both"]
    assert c["ambiguous"] <= truth["both"] * 0.01
    assert c["unpaired_a"] == truth["only_a"]
    assert c["unpaired_b"] == truth["only_b"] + c["ambiguous"]
    assert result.fits
    drift_ppm = np.median([(f.slope - 1) * 1e6 for f in result.fits])
    assert drift_ppm == pytest.approx(DRIFT * 1e6, abs=2.0)
    assert max(f.rms_us for f in result.fits) < 10
    obs = result.observations
    assert (obs.flags & ObsFlag.PAIRED).all()
    # Column 0 is receiver A's signal, column 1 receiver B's, for the same frame.
    index_a = {
        (int(m), int(s), int(t)): i
        for i, (m, s, t) in enumerate(zip(a.mac, a.seq, a.t_ns, strict=True))
    }
    for row in range(0, len(obs), 97):
        i = index_a[(int(obs.mac[row]), int(obs.seq[row]), int(obs.t_ns[row]))]
        assert obs.rssi_dbm[row, 0] == a.signal_dbm[i]
        assert abs(obs.rssi_dbm[row, 1] - obs.rssi_dbm[row, 0]) <= 3


def test_wrong_clock_model_pairs_nothing_at_a_tight_window(
    files: tuple[Path, Path, dict[str, int]],
) -> None:
    """The window is real: with too few anchors allowed, no fit, host times at 1 µs pair nothing."""
    a, _ = read_frames(str(files[0]))
    b, _ = read_frames(str(files[1]))
    cfg = PairingConfig(min_anchors=10**6, host_window_us=1.0)
    result = pair_tables(a, b, cfg)
    assert result.counters["paired"] < 0.01 * len(a)


def test_host_time_pairing_without_tsft(tmp_path: Path) -> None:
    data_a, data_b, truth = scenario(np.random.default_rng(3), tsft=False)
    (tmp_path / "a.pcap").write_bytes(data_a)
    (tmp_path / "b.pcap").write_bytes(data_b)
    a, _ = read_frames(str(tmp_path / "a.pcap"))
    b, _ = read_frames(str(tmp_path / "b.pcap"))
    result = pair_tables(a, b, PairingConfig(host_window_us=1000))
    assert not result.fits
    assert result.counters["paired"] >= 0.97 * truth["both"]


def test_source_spec_pairs_two_files(files: tuple[Path, Path, dict[str, int]]) -> None:
    with rfsas_hw.sources.open(f"pcap:{files[0]}+{files[1]}") as src:
        obs = ObservationBatch.concat(list(src))
        extra = dict(src.stats.extra)
        skipped = dict(src.stats.skipped)
    truth = files[2]
    assert len(obs) == extra["paired"]
    assert extra["pairing_rate"] == pytest.approx(
        extra["paired"] / (truth["both"] + truth["only_a"])
    )
    assert extra["clock_drift_ppm"] == pytest.approx(DRIFT * 1e6, abs=2.0)
    assert skipped["pairing: unpaired a"] == truth["only_a"]
    assert not np.isnan(obs.rssi_dbm).any()


def test_duplicate_key_in_b_is_an_ambiguous_drop(tmp_path: Path) -> None:
    frame = w.dot11(ta=0xAA, seq=5)
    a = w.pcap([(T0_NS + k * 10**8, single(-50, 1000 + k * 100_000) + w.dot11(ta=0xAA, seq=k))
                for k in range(10)])  # fmt: skip
    rows_b = [(T0_NS + k * 10**8, single(-52, 5000 + k * 100_000) + w.dot11(ta=0xAA, seq=k))
              for k in range(10)]  # fmt: skip
    rows_b.append((T0_NS + 5 * 10**8 + 10, single(-60, 5000 + 5 * 100_000 + 20) + frame))
    rows_b.sort(key=lambda r: r[0])
    (tmp_path / "a.pcap").write_bytes(a)
    (tmp_path / "b.pcap").write_bytes(w.pcap(rows_b))
    ta, _ = read_frames(str(tmp_path / "a.pcap"))
    tb, _ = read_frames(str(tmp_path / "b.pcap"))
    result = pair_tables(ta, tb, PairingConfig())
    assert result.counters["ambiguous"] == 1
    assert result.counters["paired"] == 9
    assert 5 not in result.observations.seq.tolist()


def test_bad_config_is_rejected() -> None:
    from rfsas_hw.errors import ConfigError

    with pytest.raises(ConfigError, match="window_us"):
        PairingConfig(window_us=0)
