"""The board emulator's logic with an injected clock: commands, scan plan, queue, faults, feeds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.board.codec import decode_payload, encode
from rfsas_hw.board.emulator import BoardEmulator, CaptureFeed, Emitter, Scenario
from rfsas_hw.board.faults import FaultInjector, Faults
from rfsas_hw.board.framing import encode_frame
from rfsas_hw.board.messages import (
    Ack,
    Heartbeat,
    Hello,
    Info,
    Measurement,
    MeasurementBatch,
    Message,
    Nak,
    NakCode,
    SetChannel,
    SetScanPlan,
    Start,
    Stop,
    TimeSync,
    TimeSyncRequest,
)
from rfsas_hw.board.reader import FrameDecoder
from rfsas_hw.errors import ConfigError
from rfsas_hw.rf.antenna import GaussianBeamPair
from rfsas_hw.sources import open_source


class Clock:
    def __init__(self) -> None:
        self.ns = 1_000_000_000

    def __call__(self) -> int:
        return self.ns

    def advance(self, seconds: float) -> None:
        self.ns += int(seconds * 1e9)


def _replies(emu: BoardEmulator, dec: FrameDecoder) -> list[tuple[int, Message]]:
    out = []
    for frame_bytes in emu.take():
        for _, f in dec.feed(frame_bytes):
            out.append((f.compat, decode_payload(f)))
    return out


def _board(**kw: object) -> tuple[BoardEmulator, Clock, FrameDecoder]:
    clock = Clock()
    feed = Scenario([Emitter(20.0, 15.0, 6, 500.0, mac=0xAA)], seed=1)
    emu = BoardEmulator(feed, clock_ns=clock, **kw)  # type: ignore[arg-type]
    return emu, clock, FrameDecoder()


def test_boot_info_hello_and_time_sync() -> None:
    emu, clock, dec = _board()
    boot = _replies(emu, dec)
    assert isinstance(boot[0][1], Info) and boot[0][0] & 0x02  # RESTART on the first frame
    clock.advance(2.5)
    emu.receive(encode(Hello(), 0) + encode(TimeSyncRequest(123), 1))
    got = [m for _, m in _replies(emu, dec)]
    assert isinstance(got[0], Info) and got[0].board_id == emu.board_id
    assert got[1] == TimeSync(123, 2_500_000, 2_500_000)


def test_commands_ack_nak_and_scan_plan() -> None:
    emu, _clock, dec = _board(bands_mhz=[(2400, 2500)])
    _replies(emu, dec)
    emu.receive(
        encode(SetChannel(5180), 5)
        + encode(SetScanPlan(100, (2412, 2437, 2462)), 6)
        + encode(Start(), 7)
    )
    got = [m for _, m in _replies(emu, dec)]
    assert got == [
        Nak(5, SetChannel.TYPE, int(NakCode.BAD_VALUE), 5180),
        Ack(6, SetScanPlan.TYPE),
        Ack(7, Start.TYPE),
    ]
    t = np.array([0, 99_999, 100_000, 250_000, 300_000], np.int64) + emu.board_us()
    assert emu.tuned(t).tolist() == [2412, 2412, 2437, 2462, 2412]


def test_unknown_command_type_is_naked() -> None:
    emu, _, dec = _board()
    _replies(emu, dec)
    emu.receive(encode_frame(0x7E, 33, b"new", 0x55) + encode(Start(), 34))
    got = [m for _, m in _replies(emu, dec)]
    assert got == [Nak(33, 0x7E, int(NakCode.UNKNOWN_TYPE), 0), Ack(34, Start.TYPE)]


def test_streaming_follows_the_antenna_model() -> None:
    emu, clock, dec = _board()
    _replies(emu, dec)
    emu.receive(encode(SetChannel(2437), 1) + encode(Start(), 2))
    got: list[tuple[int, Message]] = []
    for _ in range(20):
        clock.advance(0.1)
        emu.poll()
        got += _replies(emu, dec)
    assert emu.counters.frames_dropped == 0
    ms = [m for _, m in got if isinstance(m, Measurement)]
    assert 800 < len(ms) < 1200  # 500 Hz Poisson for 2 s
    diff = np.array([m.rssi_dbm[0] - m.rssi_dbm[1] for m in ms])  # type: ignore[operator]
    g = GaussianBeamPair().gains_db(20.0)
    # mean difference within 0.3 dB of the pattern difference (noise ~1.4 dB per frame)
    assert abs(diff.mean() - (g[0] - g[1])) < 0.3
    assert all(m.rssi_dbm[2] is None and m.mac == 0xAA for m in ms)
    assert [m.t_us for m in ms] == sorted(m.t_us for m in ms)


def test_off_channel_emitter_is_not_heard_and_stop_stops() -> None:
    emu, clock, _dec = _board()
    emu.receive(encode(SetChannel(2412), 1) + encode(Start(), 2))
    clock.advance(0.5)
    emu.poll()
    assert emu.counters.frames_heard == 0
    emu.receive(encode(SetChannel(2437), 3))
    clock.advance(0.5)
    emu.poll()
    assert emu.counters.frames_heard > 100
    emu.receive(encode(Stop(), 4))
    emu.take()
    heard = emu.counters.frames_heard
    clock.advance(0.5)
    emu.poll()
    assert emu.counters.frames_heard == heard and emu.queue_depth == 0


def test_full_queue_drops_counts_and_flags_overflow() -> None:
    emu, clock, dec = _board(queue_capacity=50, heartbeat_s=0.5)
    emu.receive(encode(SetChannel(2437), 1) + encode(Start(), 2))
    clock.advance(1.0)
    emu.poll()
    assert emu.counters.frames_dropped > 300 and emu.queue_depth == 50
    got = _replies(emu, dec)
    meas = [(c, m) for c, m in got if isinstance(m, Measurement)]
    assert meas[0][0] & 0x01 and not any(c & 0x01 for c, _ in meas[1:])
    beats = [m for _, m in got if isinstance(m, Heartbeat)]
    assert beats and beats[-1].frames_dropped == emu.counters.frames_dropped


def test_batches_and_budget() -> None:
    emu, clock, dec = _board(batch_size=8)
    emu.receive(encode(SetChannel(2437), 1) + encode(Start(), 2))
    emu.take()
    clock.advance(0.2)
    emu.poll()
    queued = emu.queue_depth
    frames = emu.take(budget_bytes=500)
    assert sum(len(f) for f in frames) < 500 + 220  # stops once the budget is used
    rest = emu.take()
    msgs = []
    for f in frames + rest:
        for _, fr in dec.feed(f):
            msgs.append(decode_payload(fr))
    batches = [m for m in msgs if isinstance(m, MeasurementBatch)]
    assert sum(len(b.measurements) for b in batches) == queued
    assert all(len(b.measurements) <= 8 for b in batches)
    assert dec.stats.lost == 0


def test_reboot_restarts_clock_and_sequence() -> None:
    emu, clock, _dec = _board()
    emu.take()
    clock.advance(3.0)
    emu.reboot()
    assert emu.board_us() == 0 and emu.counters.reboots == 1
    (frame,) = emu.take()
    ((_, info),) = FrameDecoder().feed(frame)
    assert info.seq == 0 and info.compat & 0x02


def test_emitter_spec_parsing() -> None:
    e = Emitter.parse("-20,30,11,5")
    assert (e.bearing_deg, e.distance_m, e.channel, e.rate_hz, e.freq_mhz) == (
        -20.0, 30.0, 11, 5.0, 2462,
    )  # fmt: skip
    e = Emitter.parse("bearing=10,mac=02:00:00:00:00:09,radio=bt,channel=38", 3)
    assert e.mac == 0x020000000009 and e.freq_mhz == 2426
    assert Emitter.parse("5", 2).mac == 0x020000000003
    for bad in ("", "x", "1,2,3,4,5", "bearing=1,colour=red", "1,-5", "1,10,15"):
        with pytest.raises(ConfigError):
            Emitter.parse(bad)


def test_fault_parsing_and_injection() -> None:
    f = Faults.parse(["garbage=0.5", "bitflip=1", "stall=3:0.2", "disconnect=10", "seed=4"])
    assert (f.garbage, f.bitflip, f.stall_every_s, f.stall_s, f.disconnect_every_s) == (
        0.5, 1.0, 3.0, 0.2, 10.0,
    )  # fmt: skip
    with pytest.raises(ConfigError, match="probability"):
        Faults.parse(["drop=2"])
    with pytest.raises(ConfigError, match="NAME=VALUE"):
        Faults.parse(["garbage"])
    frames = [encode(Hello(), i) for i in range(200)]
    inj = FaultInjector(Faults(bitflip=0.1, drop=0.1, garbage=0.2, seed=2))
    wire = inj.apply(frames)
    dec = FrameDecoder()
    got = dec.feed(wire) + dec.feed(encode(Hello(), 200))
    assert 20 < inj.touched < 80
    assert len(got) == 201 - inj.touched
    assert dec.stats.lost == inj.touched


def test_capture_feed_replays_with_spacing_and_loops() -> None:
    ms = [Measurement(1_000 + 100_000 * i, i, 2437, 6, 0, 0, None, (-50, -51)) for i in range(5)]
    feed = CaptureFeed(ms, loop=True)
    tuned = lambda t: t  # noqa: E731 - ignored by a capture
    first = feed.due(7_000, 7_000 + 250_000, tuned)
    assert [m.mac for m in first] == [0, 1, 2]
    assert [m.t_us for m in first] == [7_000, 107_000, 207_000]
    later = feed.due(7_000 + 250_000, 7_000 + 1_100_000, tuned)
    # the recording spans 401 ms: replays start at 0, 401 and 802 ms
    assert [m.mac for m in later] == [3, 4, 0, 1, 2, 3, 4, 0, 1, 2]
    assert later[2].t_us == 7_000 + 401_000


def test_capture_feed_from_a_pcap(data_dir: Path) -> None:
    with open_source(f"pcap:{data_dir / 'ieee802.11_meshid.pcap'}") as src:
        batches = list(src)
    feed = CaptureFeed.from_observations(batches)
    n = sum(len(b) for b in batches)
    assert n > 0 and len(feed.measurements) == n
    m = feed.measurements[0]
    assert m.mac == int(batches[0].mac[0]) and m.freq_mhz == int(batches[0].freq_mhz[0])
