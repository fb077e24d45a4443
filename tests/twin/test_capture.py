"""Generated captures: byte-identical per seed, read back identically by rfsas-hw and tshark."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.records import ObservationBatch
from rfsas_hw.sources import open_source
from rfsas_hw.sources import radiotap as rt
from rfsas_hw.sources.virtual import VirtualSource
from rfsas_hw.twin.capture_writer import read_truth, write_captures
from rfsas_hw.twin.frames import RadiotapInfo, radiotap_header
from rfsas_hw.twin.world import CHAIN_PRESENT, CHAIN_SENTINEL, World

from .conftest import small, small_mapping

TSHARK = shutil.which("tshark")


def _read(path: Path) -> ObservationBatch:
    with open_source(f"pcap:{path}", errors="raise") as src:
        return ObservationBatch.concat(list(src))


def _expected(world: World, sensor: str, card: int = 0) -> ObservationBatch:
    """What the capture of ``card`` must decode to: the world's readings, -128 as NaN."""
    rec = world.receptions(sensor)
    obs = rec.observations(card=None if rec.n_cards == 1 else card)
    return obs.select(np.argsort(obs.t_ns, kind="stable"))


def test_mac80211_header_layout_matches_the_documented_example() -> None:
    """Two chains: word0|NS|Ext, chain words dBm+Antenna, TSFT at 16, chains last."""
    hdr = radiotap_header(RadiotapInfo(9_526_800_862, 5745, 12, -34, [(-39, 0), (-34, 1)]))
    assert hdr[:4] == bytes([0, 0, len(hdr), 0])
    words = np.frombuffer(hdr[4:16], "<u4").tolist()
    assert words[1:] == [0xA0000820, 0x00000820]
    assert words[0] & ~(1 << 14) == 0xA000002F
    assert int.from_bytes(hdr[16:24], "little") == 9_526_800_862
    assert hdr[-4:] == bytes([0xD9, 0, 0xDE, 1])
    info = rt.parse(hdr)
    assert info.signal_dbm == -34 and info.channel_mhz == 5745 and info.tsft_us == 9_526_800_862
    assert info.chains == ((0, -39), (1, -34))


@pytest.mark.parametrize("fmt", ["pcap", "pcapng"])
def test_same_seed_gives_byte_identical_files(tmp_path: Path, fmt: str) -> None:
    a = write_captures(World(small()), tmp_path / "a", fmt)  # type: ignore[arg-type]
    b = write_captures(World(small()), tmp_path / "b", fmt)  # type: ignore[arg-type]
    c = write_captures(World(small(seed=99)), tmp_path / "c", fmt)  # type: ignore[arg-type]
    for name in ("rsu." + fmt, "truth.jsonl"):
        assert (a.directory / name).read_bytes() == (b.directory / name).read_bytes()
    assert (a.directory / f"rsu.{fmt}").read_bytes() != (c.directory / f"rsu.{fmt}").read_bytes()


@pytest.mark.parametrize("fmt", ["pcap", "pcapng"])
def test_project_reader_sees_what_the_world_produced(tmp_path: Path, fmt: str) -> None:
    world = World(small())
    out = write_captures(world, tmp_path, fmt)  # type: ignore[arg-type]
    got = _read(out.files["rsu"][0])
    want = _expected(world, "rsu")
    assert len(got) == len(want) == out.frames["rsu"][0]
    step = 1 if fmt == "pcap" else 1000  # pcapng here carries microseconds
    np.testing.assert_array_equal(got.t_ns // step, want.t_ns // step)
    np.testing.assert_array_equal(got.mac, want.mac)
    np.testing.assert_array_equal(got.seq, want.seq)
    np.testing.assert_array_equal(got.channel, want.channel)
    np.testing.assert_array_equal(got.freq_mhz, want.freq_mhz)
    np.testing.assert_array_equal(got.kind, want.kind)
    np.testing.assert_array_equal(got.rssi_dbm, want.rssi_dbm)


def test_two_single_chain_cards_write_one_file_each(tmp_path: Path) -> None:
    data = small_mapping()
    data["sensors"][0]["receiver"] = "two-single-chain-cards"
    data["sensors"][0]["driver"] = {"tsft_drift_ppm": 20}
    world = World(small(**{k: v for k, v in data.items() if k != "version"}, version=1))
    out = write_captures(world, tmp_path)
    assert [p.name for p in out.files["rsu"]] == ["rsu-card0.pcap", "rsu-card1.pcap"]
    for card in (0, 1):
        got = _read(out.files["rsu"][card])
        want = _expected(world, "rsu", card)
        np.testing.assert_array_equal(got.t_ns, want.t_ns)
        np.testing.assert_array_equal(got.rssi_dbm[:, 0], want.rssi_dbm[:, 0])
        assert np.all(np.isnan(got.rssi_dbm[:, 1]))


def _tshark(path: Path) -> list[list[str]]:
    assert TSHARK is not None
    res = subprocess.run(
        [
            TSHARK,
            "-r",
            str(path),
            "-o",
            "wlan.check_checksum:TRUE",
            "-T",
            "fields",
            "-e",
            "frame.time_epoch",
            "-e",
            "wlan.ta",
            "-e",
            "wlan.seq",
            "-e",
            "radiotap.channel.freq",
            "-e",
            "radiotap.dbm_antsignal",
            "-e",
            "radiotap.antenna",
            "-e",
            "radiotap.mactime",
            "-e",
            "wlan.fcs.status",
        ],
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    )
    return [line.split("\t") for line in res.stdout.splitlines()]


@pytest.mark.skipif(TSHARK is None, reason="tshark is not installed")
@pytest.mark.parametrize("fmt", ["pcap", "pcapng"])
def test_tshark_reads_the_same_frames(tmp_path: Path, fmt: str) -> None:
    world = World(small())
    out = write_captures(world, tmp_path, fmt)  # type: ignore[arg-type]
    rows = _tshark(out.files["rsu"][0])
    rec = world.receptions("rsu")
    assert len(rows) == len(rec)
    for i, row in enumerate(rows):
        t_s, ta, seq, freq, signals, antennas, mactime, fcs = row
        assert int(ta.replace(":", ""), 16) == int(rec.mac[i])
        assert int(seq) == int(rec.seq[i])
        assert int(freq) == int(rec.freq_mhz[i])
        assert int(mactime) == int(rec.tsft_us[i, 0])
        assert fcs == "1"  # good FCS
        assert abs(float(t_s) - rec.capture_ns[i, 0] / 1e9) < 2e-6
        listed = [int(v) for v in signals.split(",")]
        kept = rec.chain_state[i] != 2
        want_chains = [
            int(rec.chain_dbm[i, k]) if rec.chain_state[i, k] == CHAIN_PRESENT else -128
            for k in range(2)
            if kept[k]
        ]
        assert listed[0] == int(rec.combined_dbm[i])
        assert listed[1:] == want_chains
        assert antennas == ",".join(str(k) for k in range(2) if kept[k])
        if (rec.chain_state[i] == CHAIN_SENTINEL).any():
            assert -128 in listed


def test_ground_truth_round_trips(tmp_path: Path) -> None:
    world = World(small())
    out = write_captures(world, tmp_path)
    assert out.truth is not None
    truth = read_truth(out.truth)
    assert truth.scenario["seed"] == 5 and truth.scenario["t0_ns"] == world.t0_ns
    walker = truth.tracks["walker"]
    t_s = (walker.t_ns - world.t0_ns) / 1e9
    np.testing.assert_allclose(
        np.column_stack([walker.x_m, walker.y_m]), world.tracks["walker"].position(t_s), atol=1e-6
    )
    rec = world.receptions("rsu")
    pos = truth.emitter_position("phone", rec.t_ns[rec.emitter == 1])
    np.testing.assert_allclose(pos, rec.emitter_xy[rec.emitter == 1], atol=1e-6)
    np.testing.assert_allclose(truth.emitter_position("ap", [0]), [[15.0, 15.0]])
    assert "mac" not in truth.emitters["phone"]
    assert "02:00:00:00:00:0b" not in out.truth.read_text()
    pose = truth.sensor_poses["rsu"]
    assert np.all(pose.heading_deg == 90.0)


def test_virtual_source_yields_what_the_capture_holds(tmp_path: Path) -> None:
    """The virtual source and the capture file come from the same RF world."""
    world = World(small())
    out = write_captures(world, tmp_path)
    from_file = _read(out.files["rsu"][0])
    with VirtualSource(world.scenario, "rsu", world=world) as src:
        batches = list(src)
        assert src.exhausted and src.stats.observations == len(from_file)
    live = ObservationBatch.concat(batches)
    np.testing.assert_array_equal(live.t_ns, from_file.t_ns)
    np.testing.assert_array_equal(live.mac, from_file.mac)
    np.testing.assert_array_equal(live.rssi_dbm, from_file.rssi_dbm)
    assert len(batches) > 10  # streamed in 0.1 s slices, not in one block


def test_serial_board_stream_decodes_to_the_world(tmp_path: Path) -> None:
    """The board stream goes through the board protocol reader and gives back every reading."""
    import io

    from rfsas_hw.board import FrameReader
    from rfsas_hw.board.messages import Heartbeat, Info, MeasurementBatch

    data = small_mapping()
    data["sensors"][0]["receiver"] = "serial-board"
    data["emitters"].append(
        {
            "id": "tag",
            "mac": "02:00:00:00:00:0c",
            "tech": "ble",
            "position": [5.0, 2.0],
            "traffic": [{"model": "ble-adv", "interval_s": 0.1}],
        }
    )
    data["sensors"][0]["scan"] = {"channels": [6, 37], "dwell_ms": 250}
    world = World(small(**{k: v for k, v in data.items() if k != "version"}, version=1))
    out = write_captures(world, tmp_path)
    path = out.board_streams["rsu"]
    reader = FrameReader(io.BytesIO(path.read_bytes()), errors="raise")
    msgs = [m for _, m in reader]
    assert isinstance(msgs[0], Info) and msgs[0].n_antennas == 2
    assert sum(isinstance(m, Heartbeat) for m in msgs) == 3
    meas = [x for m in msgs if isinstance(m, MeasurementBatch) for x in m.measurements]
    rec = world.receptions("rsu")
    assert len(meas) == len(rec) == out.frames["rsu"][0]
    assert {int(c) for c in rec.channel} == {6, 37}  # Wi-Fi and BLE, by the scan plan
    assert out.truth is not None
    assert f'"board_boot_utc_ns": {out.board_boot_utc_ns["rsu"]}' in out.truth.read_text()
    t_ns = np.array([m.t_us for m in meas]) * 1000 + out.board_boot_utc_ns["rsu"]
    np.testing.assert_array_equal(t_ns // 1000, rec.capture_ns[:, 0] // 1000)
    got = np.array([[np.nan if v is None else v for v in m.rssi_dbm[:2]] for m in meas])
    np.testing.assert_array_equal(got, rec.chain_dbm)
    assert [m.mac for m in meas] == rec.mac.tolist()
    assert reader.stats.as_dict()["errors"] == []
    again = write_captures(World(world.scenario), tmp_path / "again")
    assert again.board_streams["rsu"].read_bytes() == path.read_bytes()


def test_two_card_captures_pair_back_into_two_antenna_observations(tmp_path: Path) -> None:
    """``pcap:A+B`` pairs the single-chain cards' frames despite their own TSF clocks."""
    data = small_mapping()
    data["sensors"][0]["receiver"] = "two-single-chain-cards"
    data["sensors"][0]["pose"] = {"x_m": -60, "y_m": 0, "heading_deg": 34}
    data["sensors"][0]["driver"] = {"tsft_drift_ppm": 30}
    data["duration_s"] = 10.0
    world = World(small(**{k: v for k, v in data.items() if k != "version"}, version=1))
    out = write_captures(world, tmp_path)
    a, b = out.files["rsu"]
    with open_source(f"pcap:{a}+{b}") as src:
        got = ObservationBatch.concat(list(src))
        stats = src.stats.as_dict()
    rec = world.receptions("rsu")
    both = rec.heard.all(axis=1)
    assert 50 < both.sum() < len(rec)  # the weak beam's card misses some frames
    assert len(got) == both.sum() and stats["ambiguous_dropped"] == 0
    order = np.argsort(rec.capture_ns[both, 0], kind="stable")
    np.testing.assert_array_equal(got.rssi_dbm, rec.chain_dbm[both][order])
    np.testing.assert_array_equal(got.seq, rec.seq[both][order])
    # the fitted relative drift is the difference of the two cards' own drifts
    assert abs(stats["clock_drift_ppm"]) > 0.5


def test_board_emulator_replays_the_twin() -> None:
    """The twin's measurements drive the board emulator's capture feed, in time order."""
    from rfsas_hw.board.emulator import CaptureFeed
    from rfsas_hw.twin.board_stream import board_measurements

    data = small_mapping()
    data["sensors"][0]["receiver"] = "serial-board"
    world = World(small(**{k: v for k, v in data.items() if k != "version"}, version=1))
    meas = board_measurements(world, "rsu", world.t0_ns)
    assert len(meas) == len(world.receptions("rsu"))
    feed = CaptureFeed(meas)
    got = feed.due(0, 10**12, lambda t: np.full(len(t), 2437, np.int64))
    assert [m.frame_seq for m in got] == [m.frame_seq for m in meas]
