"""Serial DF-board byte streams from the twin, in the board protocol (``rfsas_hw.board``).

What a board on a serial line would send while the scenario runs: an
``INFO`` frame at boot, then ``MEASUREMENT_BATCH`` frames holding what it
heard in each ``batch_ms`` window, and a ``HEARTBEAT`` about once a second.
Board time is microseconds since the board booted, ``boot_offset_s`` before
scenario time 0; the stream's :class:`BoardStreamInfo` says when that was
in UTC, which is what a host learns from time sync.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from rfsas_hw.board.codec import Encoder
from rfsas_hw.board.messages import (
    BoardState,
    Capability,
    Heartbeat,
    Info,
    Measurement,
    MeasurementBatch,
)
from rfsas_hw.errors import SimulationError
from rfsas_hw.twin.world import CHAIN_PRESENT, World

QUEUE_CAPACITY = 256


@dataclass(frozen=True)
class BoardStreamInfo:
    """Facts about a generated board stream."""

    board_id: int
    """The board id in the INFO frame (derived from the sensor id)."""
    boot_utc_ns: int
    """UTC time at board time 0, nanoseconds."""
    measurements: int
    """Measurements in the stream."""
    frames: int
    """Protocol frames in the stream."""


def board_measurements(world: World, sensor_id: str, boot_utc_ns: int) -> list[Measurement]:
    """Every frame the sensor hears as a board ``Measurement`` (board time since ``boot_utc_ns``).

    What :class:`rfsas_hw.board.emulator.CaptureFeed` replays to make the
    board emulator hear the twin.

    Raises:
        ConfigError: no such sensor.
    """
    rec = world.receptions(sensor_id)
    t_us = (rec.capture_ns[:, 0] - boot_utc_ns) // 1000
    out = []
    for k in np.argsort(t_us, kind="stable"):
        rssi = tuple(
            int(rec.chain_dbm[k, c]) if rec.chain_state[k, c] == CHAIN_PRESENT else None
            for c in range(2)
        )
        seq = int(rec.seq[k])
        out.append(
            Measurement(
                t_us=int(t_us[k]),
                mac=int(rec.mac[k]),
                freq_mhz=int(rec.freq_mhz[k]),
                channel=int(rec.channel[k]),
                kind=int(rec.kind[k]),
                flags=0,
                frame_seq=None if seq < 0 else seq,
                rssi_dbm=rssi,
            )
        )
    return out


def board_stream(
    world: World, sensor_id: str, *, batch_ms: float = 50.0, boot_offset_s: float = 12.5
) -> tuple[bytes, BoardStreamInfo]:
    """The bytes a serial board would send during the scenario, and facts about them.

    Raises:
        ConfigError: no such sensor.
        SimulationError: the sensor is not a serial board.
    """
    s = world.scenario.sensor(sensor_id)
    if s.receiver != "serial-board":
        raise SimulationError(f"sensor {sensor_id!r} is a {s.receiver}, not a serial-board")
    rec = world.receptions(sensor_id)
    boot_utc_ns = world.t0_ns - int(boot_offset_s * 1e9)
    board_id = zlib.crc32(sensor_id.encode()) | (0x5246 << 48)
    enc = Encoder()
    caps = Capability.WIFI_2G4 | Capability.BLE | Capability.BATCH | Capability.FRAME_SEQ
    out = [enc.encode(Info(1, 1, 0, 0, 2, int(caps), board_id))]
    meas = board_measurements(world, sensor_id, boot_utc_ns)
    batch_us = int(batch_ms * 1000)
    start_us = (world.t0_ns - boot_utc_ns) // 1000
    end_us = start_us + int(world.duration_s * 1e6) + batch_us
    next_beat = start_us + 1_000_000
    heard = 0
    frames = 1
    i = 0
    for window in range(start_us, end_us, batch_us):
        stop = window + batch_us
        group: list[Measurement] = []
        while i < len(meas) and meas[i].t_us < stop:
            group.append(meas[i])
            i += 1
        for j in range(0, len(group), MeasurementBatch.MAX_COUNT):
            chunk = tuple(group[j : j + MeasurementBatch.MAX_COUNT])
            out.append(enc.encode(MeasurementBatch(chunk)))
            frames += 1
        heard += len(group)
        if stop >= next_beat:
            freq = int(rec.freq_mhz[0]) if len(rec) else 2437
            beat = Heartbeat(stop, heard, 0, 0, QUEUE_CAPACITY, int(BoardState.STREAMING), freq)
            out.append(enc.encode(beat))
            frames += 1
            next_beat += 1_000_000
    return b"".join(out), BoardStreamInfo(board_id, boot_utc_ns, heard, frames)
