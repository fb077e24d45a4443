"""A DF board in software: speaks the protocol, answers commands, streams measurements.

:class:`BoardEmulator` is the board's logic without any I/O: feed it the
bytes the host sent (:meth:`~BoardEmulator.receive`), advance its clock
(:meth:`~BoardEmulator.poll`) and take the frames it wants to send
(:meth:`~BoardEmulator.take`). What it hears comes from a
:class:`MeasurementFeed`: a :class:`Scenario` of fixed emitters at given
bearings seen through the antenna model (``rfsas_hw.rf``), with noise and
1 dB quantisation, or a :class:`CaptureFeed` that replays recorded
measurements. ``rfsas_hw.board.transport`` puts it on a pty or a TCP port.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import numpy.typing as npt

from rfsas_hw.board.codec import Encoder, decode_payload
from rfsas_hw.board.messages import (
    RSSI_SLOTS,
    Ack,
    BoardState,
    Capability,
    CompatFlag,
    Heartbeat,
    Hello,
    Info,
    Measurement,
    MeasurementBatch,
    Message,
    Nak,
    NakCode,
    PayloadError,
    SetChannel,
    SetScanPlan,
    Start,
    Stop,
    TimeSync,
    TimeSyncRequest,
)
from rfsas_hw.board.reader import FrameDecoder
from rfsas_hw.errors import ConfigError
from rfsas_hw.records import FrameKind, ObservationBatch, mac_to_int
from rfsas_hw.rf.antenna import GaussianBeamPair
from rfsas_hw.rf.channels import channel_to_freq_mhz, freq_to_channel
from rfsas_hw.rf.link_budget import link_budget
from rfsas_hw.rf.synth import ReceiverModel, rssi_pairs

log = logging.getLogger(__name__)

TunedFn = Callable[[npt.NDArray[np.int64]], npt.NDArray[np.int64]]
"""Board time (µs, array) → frequency the radio was on (MHz, array)."""


class MeasurementFeed(Protocol):
    """Where an emulated board's measurements come from."""

    def due(self, start_us: int, end_us: int, tuned: TunedFn) -> list[Measurement]:
        """Measurements heard in board time ``[start_us, end_us)``, in time order."""
        ...


@dataclass(frozen=True)
class Emitter:
    """A transmitter at a fixed position relative to the board's antenna pair."""

    bearing_deg: float
    """Angle from boresight, degrees clockwise."""
    distance_m: float = 20.0
    """Distance, metres (sets the received power through the link budget)."""
    channel: int = 6
    """Wi-Fi channel it transmits on (37–39 with ``radio="bt"``: BLE advertising)."""
    rate_hz: float = 20.0
    """Mean frame rate, frames per second (Poisson arrivals)."""
    mac: int = 0x020000000001
    """Transmitter address (48 bits)."""
    kind: int = int(FrameKind.PROBE_REQUEST)
    """Frame kind of its frames."""
    radio: str = "wifi"
    """Link-budget radio: ``wifi`` or ``bt``."""

    @property
    def freq_mhz(self) -> int:
        """Centre frequency of its channel, MHz."""
        return channel_to_freq_mhz(self.channel, self.radio)

    @classmethod
    def parse(cls, text: str, index: int = 0) -> Emitter:
        """Parse ``BEARING[,DISTANCE[,CHANNEL[,RATE]]]`` or ``key=value,…``.

        Keys: ``bearing``, ``distance``, ``channel``, ``rate``, ``mac``,
        ``radio``. Without a MAC, emitter ``index`` gets the locally
        administered ``02:00:00:00:00:<index+1>``.

        Raises:
            ConfigError: a malformed value, with the text.
        """
        names = ("bearing", "distance", "channel", "rate")
        values: dict[str, str] = {}
        for k, part in enumerate(p.strip() for p in text.split(",") if p.strip()):
            key, sep, value = part.partition("=")
            if not sep:
                if k >= len(names):
                    raise ConfigError(f"emitter {text!r}: too many positional values")
                key, value = names[k], part
            values[key.strip()] = value.strip()
        unknown = sorted(set(values) - {*names, "mac", "radio"})
        if unknown or "bearing" not in values:
            raise ConfigError(
                f"emitter {text!r}: needs a bearing; known keys are "
                f"bearing, distance, channel, rate, mac, radio"
            )
        try:
            em = cls(
                bearing_deg=float(values["bearing"]),
                distance_m=float(values.get("distance", 20.0)),
                channel=int(values.get("channel", 6)),
                rate_hz=float(values.get("rate", 20.0)),
                mac=mac_to_int(values["mac"]) if "mac" in values else 0x020000000001 + index,
                radio=values.get("radio", "wifi"),
            )
        except (ValueError, ConfigError) as err:
            raise ConfigError(f"emitter {text!r}: {err}") from err
        if em.distance_m <= 0 or em.rate_hz < 0:
            raise ConfigError(f"emitter {text!r}: distance must be > 0 and rate ≥ 0")
        try:
            channel_to_freq_mhz(em.channel, em.radio)
        except ConfigError as err:
            raise ConfigError(f"emitter {text!r}: {err}") from err
        return em


class Scenario:
    """Fixed emitters seen through a Gaussian beam pair with receiver noise.

    Each emitter transmits Poisson-distributed frames at ``rate_hz``; a frame
    is heard when the radio is tuned to its frequency and its SNR is
    positive. RSSI per antenna = received power at the beam peak + pattern
    offset + Gaussian noise, rounded to whole dB (``rfsas_hw.rf.synth``).
    """

    def __init__(
        self,
        emitters: Sequence[Emitter],
        *,
        antenna: GaussianBeamPair | None = None,
        receiver: ReceiverModel | None = None,
        seed: int = 0,
    ) -> None:
        self.emitters = list(emitters)
        self.antenna = antenna or GaussianBeamPair()
        self.receiver = receiver or ReceiverModel()
        self.rng = np.random.default_rng(seed)
        self._peak_dbm = [
            float(link_budget(e.distance_m, e.radio).rx_power_dbm) for e in self.emitters
        ]
        self._frame_seq = [0] * len(self.emitters)

    def due(self, start_us: int, end_us: int, tuned: TunedFn) -> list[Measurement]:
        """Frames heard in ``[start_us, end_us)``, time-ordered."""
        span = end_us - start_us
        if span <= 0:
            return []
        out: list[Measurement] = []
        for i, em in enumerate(self.emitters):
            n = int(self.rng.poisson(em.rate_hz * span * 1e-6))
            if n == 0:
                continue
            t_us = np.sort(self.rng.integers(start_us, end_us, n))
            heard = tuned(t_us) == em.freq_mhz
            peak = self._peak_dbm[i]
            if not heard.any() or peak <= self.receiver.noise_floor_dbm:
                continue
            t_us = t_us[heard]
            rssi = rssi_pairs(
                np.full(len(t_us), em.bearing_deg), peak, self.antenna, self.receiver, self.rng
            )
            rssi = np.clip(rssi, -127, 127).astype(int)
            for t, (r0, r1) in zip(t_us.tolist(), rssi.tolist(), strict=True):
                seq = self._frame_seq[i]
                self._frame_seq[i] = (seq + 1) % 4096
                out.append(
                    Measurement(
                        t, em.mac, em.freq_mhz, em.channel, em.kind, 0, seq, (r0, r1, None, None)
                    )
                )
        out.sort(key=lambda m: m.t_us)
        return out


class CaptureFeed:
    """Replays recorded measurements with their original spacing in time.

    The first recorded measurement is heard when the board starts streaming;
    the radio's tuning is ignored (the capture already says what was heard).
    With ``loop`` the recording starts over at its end.
    """

    def __init__(self, measurements: Sequence[Measurement], *, loop: bool = False) -> None:
        ordered = sorted(measurements, key=lambda m: m.t_us)
        self.measurements = ordered
        self.loop = loop
        self._t0 = ordered[0].t_us if ordered else 0
        self._span = (ordered[-1].t_us - self._t0 + 1000) if ordered else 0
        self._times = np.array([m.t_us - self._t0 for m in ordered], dtype=np.int64)
        self._origin: int | None = None

    def due(self, start_us: int, end_us: int, tuned: TunedFn) -> list[Measurement]:
        """Recorded measurements whose replay time falls in ``[start_us, end_us)``."""
        if not self.measurements:
            return []
        if self._origin is None:
            self._origin = start_us
        out: list[Measurement] = []
        lo, hi = start_us - self._origin, end_us - self._origin
        rep = 0 if not self.loop else max(0, lo // self._span)
        while True:
            base = rep * self._span
            if base >= hi or (rep > 0 and not self.loop):
                break
            a = int(np.searchsorted(self._times, lo - base, "left"))
            b = int(np.searchsorted(self._times, hi - base, "left"))
            for k in range(a, b):
                m = self.measurements[k]
                out.append(
                    Measurement(
                        int(self._origin + base + self._times[k]),
                        m.mac,
                        m.freq_mhz,
                        m.channel,
                        m.kind,
                        m.flags,
                        m.frame_seq,
                        m.rssi_dbm,
                    )
                )
            rep += 1
        return out

    @classmethod
    def from_observations(cls, batches: Sequence[ObservationBatch], **kw: bool) -> CaptureFeed:
        """A feed from observation batches (a pcap or any other source)."""
        rows: list[Measurement] = []
        for batch in batches:
            rssi = np.where(np.isnan(batch.rssi_dbm), -128, np.round(batch.rssi_dbm))
            rssi = np.clip(rssi, -128, 127).astype(int)
            for i in range(len(batch)):
                vals = [None if v == -128 else v for v in rssi[i, :RSSI_SLOTS].tolist()]
                seq = int(batch.seq[i])
                freq = int(batch.freq_mhz[i])
                rows.append(
                    Measurement(
                        int(batch.t_ns[i]) // 1000,
                        int(batch.mac[i]),
                        freq,
                        int(batch.channel[i]) or freq_to_channel(freq),
                        int(batch.kind[i]),
                        int(batch.flags[i]) & 0x03,
                        None if not 0 <= seq <= 4095 else seq,
                        tuple(vals),
                    )
                )
        return cls(rows, **kw)


@dataclass
class EmulatorCounters:
    """What the emulated board did (the truth a test compares the host against)."""

    frames_sent: int = 0
    """Protocol frames handed to the transport."""
    measurements_sent: int = 0
    """Measurements in those frames."""
    frames_heard: int = 0
    """Measurements generated while streaming."""
    frames_dropped: int = 0
    """Measurements dropped because the queue was full."""
    commands: dict[str, int] = field(default_factory=dict)
    """Commands received, by message class name."""
    naks: int = 0
    """Commands refused."""
    reboots: int = 0
    """Reboots after the first boot (a disconnect power-cycles the board)."""


BANDS_MHZ = ((2400, 2500), (4900, 5900))
"""Frequency ranges the emulated radio tunes to by default, MHz."""


class BoardEmulator:
    """The protocol logic of a DF board, without I/O.

    Args:
        feed: where measurements come from (None: a board that hears nothing).
        board_id: the id in INFO.
        batch_size: measurements per frame; above 1 the board sends
            MEASUREMENT_BATCH frames.
        queue_capacity: measurements the transmit queue holds before it drops.
        heartbeat_s: seconds between heartbeats.
        bands_mhz: frequency ranges the radio can tune to (others are NAKed).
        clock_ns: monotonic clock, nanoseconds (injectable for tests).
    """

    def __init__(
        self,
        feed: MeasurementFeed | None = None,
        *,
        board_id: int = 0x5246_0000_0000_0001,
        batch_size: int = 1,
        queue_capacity: int = 512,
        heartbeat_s: float = 1.0,
        bands_mhz: Sequence[tuple[int, int]] = BANDS_MHZ,
        clock_ns: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.bands_mhz = tuple(bands_mhz)
        if not 1 <= batch_size <= MeasurementBatch.MAX_COUNT:
            raise ConfigError(f"batch size {batch_size} outside 1..{MeasurementBatch.MAX_COUNT}")
        self.feed = feed
        self.board_id = board_id
        self.batch_size = batch_size
        self.queue_capacity = queue_capacity
        self.heartbeat_us = int(heartbeat_s * 1e6)
        self.clock_ns = clock_ns
        self.counters = EmulatorCounters()
        self.counters.reboots = -1
        self.reboot()

    # -- state ----------------------------------------------------------------

    def reboot(self) -> None:
        """Power-cycle: clock, sequence numbers and settings start over; INFO is sent."""
        self.counters.reboots += 1
        self._boot_ns = self.clock_ns()
        self._encoder = Encoder()
        self._decoder = FrameDecoder()
        self._control: list[bytes] = []
        self._queue: deque[Measurement] = deque()
        self._overflow = False
        self.state = BoardState.IDLE
        self.freq_mhz = 2437
        self._plan: tuple[int, ...] = ()
        self._dwell_us = 0
        self._plan_start_us = 0
        self._polled_us = 0
        self._next_beat_us = self.heartbeat_us
        self._send(self.info())

    def info(self) -> Info:
        """The INFO message this board sends."""
        caps = (
            Capability.WIFI_2G4
            | Capability.WIFI_5G
            | Capability.BLE
            | Capability.TIME_SYNC
            | Capability.SCAN_PLAN
            | Capability.FRAME_SEQ
        )
        if self.batch_size > 1:
            caps |= Capability.BATCH
        return Info(1, 1, 0, 0, 2, int(caps), self.board_id)

    def board_us(self, now_ns: int | None = None) -> int:
        """Board time, microseconds since (re)boot."""
        now = self.clock_ns() if now_ns is None else now_ns
        return (now - self._boot_ns) // 1000

    def tuned(self, t_us: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """Frequency the radio was on at board times ``t_us``, MHz."""
        if not self._plan or self._dwell_us <= 0:
            return np.full(len(t_us), self.freq_mhz, np.int64)
        plan = np.asarray(self._plan, np.int64)
        slot = ((t_us - self._plan_start_us) // self._dwell_us) % len(plan)
        return plan[slot]

    def _tunable(self, freq_mhz: int) -> bool:
        return any(lo <= freq_mhz <= hi for lo, hi in self.bands_mhz)

    def _send(self, msg: Message) -> None:
        self._control.append(self._encoder.encode(msg))

    # -- host → board ---------------------------------------------------------

    def receive(self, data: bytes) -> None:
        """Bytes from the host: decode and answer every complete command."""
        frames = self._decoder.feed(data)
        for err in self._decoder.new_errors:
            if err.kind == "unknown_type" and err.header is not None:
                self._nak(err.header[1], err.header[0], NakCode.UNKNOWN_TYPE)
        for _, frame in frames:
            name = f"0x{frame.msg_type:02x}"
            try:
                msg = decode_payload(frame)
                name = type(msg).__name__
                self.counters.commands[name] = self.counters.commands.get(name, 0) + 1
                self._handle(msg, frame.seq)
            except PayloadError as err:
                log.debug("bad command payload %s: %s", name, err)
                self._nak(frame.seq, frame.msg_type, NakCode.BAD_PAYLOAD)

    def _nak(self, seq: int, msg_type: int, code: NakCode, detail: int = 0) -> None:
        self.counters.naks += 1
        self._send(Nak(seq, msg_type, int(code), detail & 0xFFFF))

    def _handle(self, msg: Message, seq: int) -> None:
        now_us = self.board_us()
        if isinstance(msg, Hello):
            self._send(self.info())
        elif isinstance(msg, TimeSyncRequest):
            self._send(TimeSync(msg.host_time_ns, now_us, self.board_us()))
        elif isinstance(msg, SetChannel):
            if not self._tunable(msg.freq_mhz):
                self._nak(seq, msg.TYPE, NakCode.BAD_VALUE, msg.freq_mhz)
                return
            self.freq_mhz, self._plan = msg.freq_mhz, ()
            self._send(Ack(seq, msg.TYPE))
        elif isinstance(msg, SetScanPlan):
            bad = [f for f in msg.freqs_mhz if not self._tunable(f)]
            if bad or msg.dwell_ms == 0:
                self._nak(seq, msg.TYPE, NakCode.BAD_VALUE, bad[0] if bad else 0)
                return
            self._plan, self._dwell_us = msg.freqs_mhz, msg.dwell_ms * 1000
            self._plan_start_us = now_us
            if self._plan:
                self.freq_mhz = self._plan[0]
            self._send(Ack(seq, msg.TYPE))
        elif isinstance(msg, Start):
            if self.state != BoardState.STREAMING:
                self._polled_us = now_us
            self.state = BoardState.STREAMING
            self._send(Ack(seq, msg.TYPE))
        elif isinstance(msg, Stop):
            self.state = BoardState.IDLE
            self._queue.clear()
            self._send(Ack(seq, msg.TYPE))
        else:
            self._nak(seq, msg.TYPE, NakCode.UNSUPPORTED)

    # -- board → host ---------------------------------------------------------

    def poll(self, now_ns: int | None = None) -> None:
        """Advance to ``now``: queue what was heard since the last poll, heartbeats."""
        now_us = self.board_us(now_ns)
        if self.state == BoardState.STREAMING and self.feed is not None:
            heard = self.feed.due(self._polled_us, now_us, self.tuned)
            self.counters.frames_heard += len(heard)
            room = self.queue_capacity - len(self._queue)
            if len(heard) > room:
                self.counters.frames_dropped += len(heard) - max(room, 0)
                heard = heard[: max(room, 0)]
                self._overflow = True
            self._queue.extend(heard)
        self._polled_us = max(self._polled_us, now_us)
        if self._plan and self._dwell_us:
            self.freq_mhz = int(self.tuned(np.array([now_us], np.int64))[0])
        if now_us >= self._next_beat_us:
            self._next_beat_us = now_us + self.heartbeat_us
            self._send(
                Heartbeat(
                    now_us,
                    self.counters.frames_heard & 0xFFFF_FFFF,
                    self.counters.frames_dropped & 0xFFFF_FFFF,
                    min(len(self._queue), 0xFFFF),
                    min(self.queue_capacity, 0xFFFF),
                    int(self.state),
                    self.freq_mhz,
                )
            )

    @property
    def queue_depth(self) -> int:
        """Measurements waiting to be sent."""
        return len(self._queue)

    def take(self, budget_bytes: int | None = None) -> list[bytes]:
        """Frames to send now, replies first, at most about ``budget_bytes`` (None: all)."""
        out: list[bytes] = []
        used = 0
        while self._control:
            frame = self._control.pop(0)
            out.append(frame)
            used += len(frame)
        while self._queue and (budget_bytes is None or used < budget_bytes):
            n = min(self.batch_size, len(self._queue))
            group = [self._queue.popleft() for _ in range(n)]
            compat = int(CompatFlag.OVERFLOW) if self._overflow else 0
            self._overflow = False
            msg: Message = group[0] if n == 1 else MeasurementBatch(tuple(group))
            frame = self._encoder.encode(msg, compat=compat)
            out.append(frame)
            used += len(frame)
            self.counters.measurements_sent += n
        self.counters.frames_sent += len(out)
        return out
