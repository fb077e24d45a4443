"""The serial:URL driver against the board emulator on a real pty (and a real TCP socket)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.board.emulator import BoardEmulator, Emitter, Scenario
from rfsas_hw.board.faults import Faults
from rfsas_hw.board.timesync import TimeMapper
from rfsas_hw.board.transport import EmulatorRunner, PtyEndpoint, TcpEndpoint
from rfsas_hw.errors import ConfigError, SourceError
from rfsas_hw.records import ObservationBatch
from rfsas_hw.sources import open_source
from rfsas_hw.sources.serial_board import SerialSource, parse_options

MAC_RIGHT = 0x020000000001
MAC_LEFT = 0x020000000002

Board = tuple[BoardEmulator, EmulatorRunner, str]


def _scenario(rate_hz: float = 150.0) -> Scenario:
    return Scenario(
        [
            Emitter(bearing_deg=25.0, distance_m=15.0, channel=6, rate_hz=rate_hz, mac=MAC_RIGHT),
            Emitter(bearing_deg=-25.0, distance_m=15.0, channel=6, rate_hz=rate_hz, mac=MAC_LEFT),
        ],
        seed=7,
    )


@pytest.fixture
def make_board(tmp_path: Path) -> Iterator[Callable[..., Board]]:
    runners: list[EmulatorRunner] = []

    def make(
        *, faults: Faults | None = None, tcp: bool = False, batch: int = 1, **kw: object
    ) -> Board:
        emu = BoardEmulator(_scenario(), batch_size=batch, **kw)  # type: ignore[arg-type]
        ep = TcpEndpoint() if tcp else PtyEndpoint(tmp_path / "ttyBOARD")
        runner = EmulatorRunner(emu, ep, faults=faults).start()
        runners.append(runner)
        return emu, runner, ep.path

    yield make
    for r in runners:
        r.stop()


def _collect(src: SerialSource, seconds: float) -> ObservationBatch:
    out = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        b = src.read(0.05)
        if b is not None and len(b):
            out.append(b)
    return ObservationBatch.concat(out)


def _drain(src: SerialSource, quiet_s: float = 0.3) -> list[ObservationBatch]:
    out = []
    last = time.monotonic()
    while time.monotonic() - last < quiet_s:
        b = src.read(0.05)
        if b is not None and len(b):
            out.append(b)
            last = time.monotonic()
    return out


def test_measurements_flow_with_bearing_and_host_time(make_board: Callable[..., Board]) -> None:
    emu, _, path = make_board()
    with open_source(f"serial:{path}", channel=6) as src:
        assert isinstance(src, SerialSource)
        before = time.time_ns()
        obs = _collect(src, 1.0)
        after = time.time_ns()
        assert src.info is not None and src.info.board_id == emu.board_id
    assert len(obs) > 100
    assert set(obs.mac.tolist()) == {MAC_RIGHT, MAC_LEFT}
    assert (obs.freq_mhz == 2437).all() and (obs.channel == 6).all()
    # antenna 0 is squinted clockwise: the emitter right of boresight is louder on it
    diff = obs.rssi_dbm[:, 0] - obs.rssi_dbm[:, 1]
    assert np.median(diff[obs.mac == MAC_RIGHT]) > 3
    assert np.median(diff[obs.mac == MAC_LEFT]) < -3
    # whole dB, as the emulated card quantises
    assert np.array_equal(obs.rssi_dbm, np.round(obs.rssi_dbm))
    # board time mapped to host UTC: inside the read window (plus sync slack)
    assert before - 0.3e9 < obs.t_ns.min() and obs.t_ns.max() < after + 0.05e9
    assert (np.diff(obs.t_ns) >= 0).all()


def test_commands_are_acknowledged_and_applied(make_board: Callable[..., Board]) -> None:
    emu, _, path = make_board()
    with SerialSource(path, channels=[1, 6, 11], dwell_ms=40) as src:
        obs = _collect(src, 0.6)
        assert src.stats.extra["naks"] == 0
    assert emu.counters.commands["SetScanPlan"] == 1
    assert emu.counters.commands["Start"] == 1
    assert emu.counters.commands["TimeSyncRequest"] >= 4
    # STOP is sent on close; the emulator thread handles it a moment later
    deadline = time.monotonic() + 2
    while "Stop" not in emu.counters.commands and time.monotonic() < deadline:
        time.sleep(0.01)
    assert emu.counters.commands.get("Stop") == 1
    # both emitters are on channel 6: only the channel-6 dwell hears them
    assert len(obs) > 0 and set(obs.channel.tolist()) == {6}


def test_refused_command_raises_with_the_reason(make_board: Callable[..., Board]) -> None:
    _, _, path = make_board(bands_mhz=[(2400, 2500)])
    with pytest.raises(SourceError, match=r"refused SET_CHANNEL: BAD_VALUE \(detail 5180\)"):
        SerialSource(path, channel=36)


def test_disconnect_is_followed_by_reconnect(
    make_board: Callable[..., Board], caplog: pytest.LogCaptureFixture
) -> None:
    emu, runner, path = make_board(faults=Faults(disconnect_every_s=0.8, disconnect_s=0.3))
    caplog.set_level(logging.INFO)
    with SerialSource(path, channel=6, backoff_s=0.05) as src:
        first = _collect(src, 0.7)
        deadline = time.monotonic() + 5
        while src.stats.extra["reconnects"] == 0 and time.monotonic() < deadline:
            src.read(0.05)
        after = _collect(src, 0.5)
        extra = src.stats.extra
    assert runner.stats.disconnects >= 1 and emu.counters.reboots >= 1
    assert extra["disconnects"] >= 1 and extra["reconnects"] >= 1
    assert len(first) > 0 and len(after) > 0
    # measurements after the reconnect carry host times after those before it,
    # although the rebooted board's clock started again at zero
    assert after.t_ns.min() > first.t_ns.max()
    text = caplog.text
    assert "disconnected" in text and "reconnecting" in text and "reconnected after" in text
    # a board reboot is not counted as lost frames
    assert extra["lost"] == 0


def test_garbage_costs_only_touched_frames(make_board: Callable[..., Board]) -> None:
    faults = Faults(garbage=0.3, bitflip=0.05, drop=0.05, seed=3)
    emu, runner, path = make_board(faults=faults)
    with SerialSource(path, channel=6) as src:
        got = [_collect(src, 1.5)]
        # stop damaging, let clean frames through so the last gap is visible
        runner.injector.faults = Faults()
        time.sleep(0.1)
        emu.feed = None
        got += _drain(src)
        obs = ObservationBatch.concat(got)
        extra = dict(src.stats.extra)
    touched = runner.injector.touched
    assert touched > 10 and runner.injector.garbage_bytes > 100
    assert extra["resyncs"] > 0
    # exactly the damaged frames are lost, no frame more
    assert extra["lost"] == touched
    assert runner.stats.overrun_bytes == 0
    assert len(obs) <= emu.counters.measurements_sent
    assert len(obs) >= emu.counters.measurements_sent - touched


def test_stalls_cost_nothing_and_a_mute_board_is_asked_again(
    make_board: Callable[..., Board],
) -> None:
    _, runner, path = make_board(faults=Faults(stall_every_s=0.5, stall_s=0.3))
    with SerialSource(path, channel=6) as src:
        obs = _collect(src, 1.5)
        extra = dict(src.stats.extra)
    assert runner.stats.stalls >= 2 and len(obs) > 0
    assert extra["lost"] == 0 and extra["disconnects"] == 0 and extra["silences"] == 0
    _, runner, path = make_board(faults=Faults(stall_every_s=0.6, stall_s=1.2))
    with SerialSource(path, channel=6, silence_s=0.4, handshake_timeout_s=0.2) as src:
        before = _collect(src, 0.5)
        after = _collect(src, 2.5)
        extra = dict(src.stats.extra)
    assert extra["silences"] >= 1
    assert len(before) > 0 and len(after) > 0


def test_batched_board_over_tcp(make_board: Callable[..., Board]) -> None:
    emu, _, url = make_board(tcp=True, batch=8)
    assert url.startswith("socket://")
    with SerialSource(url, channel=6) as src:
        got = [_collect(src, 0.8)]
        emu.feed = None
        got += _drain(src)
        extra = src.stats.extra
    obs = ObservationBatch.concat(got)
    assert len(obs) == emu.counters.measurements_sent
    assert extra["lost"] == 0 and extra["crc_errors"] == 0


def test_spy_url_writes_a_hex_trace(make_board: Callable[..., Board], tmp_path: Path) -> None:
    _, _, path = make_board()
    trace = tmp_path / "trace.txt"
    with SerialSource(f"spy://{path}?file={trace}", channel=6) as src:
        assert len(_collect(src, 0.3)) > 0
    text = trace.read_text()
    # the HELLO frame (COBS 02 d1 01 01 ...) went out and frames came back
    assert " TX " in text and " RX " in text and "D1" in text


def test_no_board_on_loopback_is_a_clear_error() -> None:
    with pytest.raises(SourceError, match=r"did not answer HELLO within 0.1 s \(2 tries\)"):
        SerialSource("loop://", handshake_timeout_s=0.1, retries=2)


def test_missing_device_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match=r"cannot open serial port .*nothing-here"):
        SerialSource(str(tmp_path / "nothing-here"))


def test_without_reconnect_the_source_ends(make_board: Callable[..., Board]) -> None:
    _, _, path = make_board(faults=Faults(disconnect_every_s=0.5, disconnect_s=2.0))
    with SerialSource(path, channel=6, reconnect=False) as src:
        batches = list(src)  # ends when the device goes away
        assert src.exhausted
        assert any("disconnected" in e for e in src.stats.errors)
    assert sum(len(b) for b in batches) > 0


def test_spec_options_after_hash() -> None:
    assert parse_options("baud=115200,channels=1+6+11,dwell_ms=150") == {
        "baudrate": 115200,
        "channels": [1, 6, 11],
        "dwell_ms": 150,
    }
    with pytest.raises(ConfigError, match="serial option 'speed=3'"):
        parse_options("speed=3")


def test_time_mapper_follows_a_fast_crystal() -> None:
    mapper = TimeMapper(window=64, min_span_s=5)
    rng = np.random.default_rng(1)
    boot_host_ns = 1_700_000_000_000_000_000
    ppm = 40e-6
    for k in range(60):
        t0 = boot_host_ns + k * 1_000_000_000
        out_ns = 200_000 + rng.uniform(0, 100_000)  # host → board
        back_ns = 200_000 + rng.uniform(0, 100_000)  # board → host
        if k % 5 == 2:
            back_ns += 5e6  # a reply stuck in a queue: long round trip, filtered out
        board_rx_us = int((t0 + out_ns - boot_host_ns) * (1 + ppm) / 1000)
        board_tx_us = board_rx_us + 50
        t3 = int(t0 + out_ns + 50_000 + back_ns)
        mapper.add(t0, t3, board_rx_us, board_tx_us)
    # asymmetry of at most 100 µs over a 60 s span: the rate is good to ~2 ppm
    assert mapper.rate_ppm == pytest.approx(40, abs=2)
    probe_host = boot_host_ns + 30_000_000_000
    probe_us = int((probe_host - boot_host_ns) * (1 + ppm) / 1000)
    mapped = int(mapper.to_host_ns(np.array([probe_us]))[0])
    assert abs(mapped - probe_host) < 100_000  # within 0.1 ms


def test_time_mapper_falls_back_to_arrival_times() -> None:
    mapper = TimeMapper()
    mapper.observe_arrival(5_000_000, 1_000_000_000_000)  # board 5 s arrived at host 1000 s
    mapper.observe_arrival(6_000_000, 1_000_900_000_000)  # a faster delivery: tighter bound
    t = int(mapper.to_host_ns(np.array([6_000_000]))[0])
    assert t == 1_000_900_000_000


@pytest.mark.hardware
def test_real_board_handshakes_and_streams(request: pytest.FixtureRequest) -> None:
    """The same checks on a real board: ``pytest --serial-url /dev/ttyUSB0 -m hardware``."""
    url = request.config.getoption("--serial-url")
    if not url:
        pytest.skip("no --serial-url given: the emulator tests above cover this")
    with SerialSource(str(url)) as src:
        assert src.info is not None and src.info.protocol_version == 1
        obs = _collect(src, 5.0)
        extra = src.stats.extra
    assert extra["crc_errors"] == 0 and extra["lost"] == 0
    if len(obs):
        assert (np.abs(obs.t_ns - time.time_ns()) < 10e9).all()
