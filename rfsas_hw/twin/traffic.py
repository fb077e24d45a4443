"""Traffic models: when each emitter transmits, on which channel, which frame kind.

Models follow method.md §8: access points beacon about every 102.4 ms on one
channel; phones send probe requests in bursts that sweep the channel list;
BLE advertisers send one packet on each of channels 37/38/39 per event, with
events ``advInterval + advDelay`` apart (advDelay uniform in 0–10 ms); data
bursts are a few frames close together on one channel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.records import NO_SEQ, FrameKind
from rfsas_hw.twin.rng import stream
from rfsas_hw.twin.scenario import TrafficSpec

SEQ_MODULO = 4096


@dataclass(frozen=True)
class Transmissions:
    """Frames one emitter sends, sorted by time."""

    t_s: npt.NDArray[np.float64]
    """Start of each frame on air, scenario seconds."""
    channel: npt.NDArray[np.int16]
    """Channel of each frame."""
    kind: npt.NDArray[np.uint8]
    """:class:`~rfsas_hw.records.FrameKind` of each frame."""
    seq: npt.NDArray[np.int32]
    """802.11 sequence number, or -1 (BLE)."""

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


_EMPTY = Transmissions(
    t_s=np.empty(0),
    channel=np.empty(0, np.int16),
    kind=np.empty(0, np.uint8),
    seq=np.empty(0, np.int32),
)
"""No frames (shared; arrays of a frozen record are never written to)."""

_NO_EVENTS = np.empty(0)
"""No event starts (shared, never written to)."""

_DRAW_BLOCK = 256
"""Random numbers are drawn this many at a time; how they are used never depends on it."""


class TrafficGenerator:
    """The frames of one traffic model, generated window by window.

    The generator keeps its random stream and its position in it, so asking
    for ``[0, 2)`` and then ``[2, 5)`` gives exactly the frames that asking for
    ``[0, 5)`` once gives: the phase and the sequence-number start are drawn
    first, then one jitter (or advertising delay) per event, in event order.

    Args:
        spec: the traffic model.
        rng: the model's own random stream (consumed only by this generator).
        start_s: time the emitter appears, scenario seconds; events start
            ``phase`` after it.
    """

    def __init__(self, spec: TrafficSpec, rng: np.random.Generator, start_s: float = 0.0) -> None:
        self.spec = spec
        self._rng = rng
        self.interval_s = spec.effective_interval_s()
        self.jitter_s = spec.effective_jitter_ms() / 1e3
        self.channels = np.asarray(spec.effective_channels(), dtype=np.int16)
        phase = (
            float(spec.phase_s)
            if spec.phase_s is not None
            else float(rng.uniform(0.0, self.interval_s))
        )
        self.start_s = float(start_s)
        self._first_s = self.start_s + phase
        self._ble = spec.model == "ble-adv"
        self._seq = NO_SEQ if self._ble else int(rng.integers(0, SEQ_MODULO))
        self._events = 0
        """Events generated so far."""
        self._next_ble_s = self._first_s
        self._buffer = np.empty(0)
        self._used = 0
        gap = spec.gap_ms / 1e3
        if self._ble:
            self._offsets = gap * np.arange(len(self.channels))
            self._offset_ch = self.channels
            self.kind = FrameKind.BLE_ADV
        elif spec.model == "probe-bursts":
            per_ch = spec.channel_dwell_ms / 1e3 * np.arange(len(self.channels))
            within = gap * np.arange(spec.frames_per_channel)
            self._offsets = (per_ch[:, None] + within[None, :]).ravel()
            self._offset_ch = np.repeat(self.channels, spec.frames_per_channel)
            self.kind = FrameKind.PROBE_REQUEST
        elif spec.model == "data-bursts":
            self._offsets = gap * np.arange(spec.burst_frames)
            self._offset_ch = np.full(spec.burst_frames, self.channels[0], np.int16)
            self.kind = FrameKind.QOS_DATA
        else:
            self._offsets = np.zeros(1)
            self._offset_ch = self.channels[:1]
            self.kind = FrameKind.BEACON
        self._pending_t = np.empty(0)
        self._pending_ch = np.empty(0, np.int16)
        self.until_s = -np.inf
        """Frames before this time have been handed out, seconds."""

    def _uniform(self, n: int) -> npt.NDArray[np.float64]:
        """The next ``n`` draws of U(0, 1) from the stream, in order."""
        while len(self._buffer) - self._used < n:
            more = self._rng.random(max(_DRAW_BLOCK, n))
            self._buffer = np.concatenate([self._buffer[self._used :], more])
            self._used = 0
        out = self._buffer[self._used : self._used + n]
        self._used += n
        return out

    def _new_events(self, t_end_s: float) -> npt.NDArray[np.float64]:
        """Start times of the events that may have frames before ``t_end_s``."""
        if self._ble:
            if not self._next_ble_s < t_end_s:
                return _NO_EVENTS
            # advDelay accumulates: each event is advInterval + advDelay after the previous one
            times: list[float] = []
            while self._next_ble_s < t_end_s:
                times.append(self._next_ble_s)
                self._next_ble_s += self.interval_s + self.jitter_s * float(self._uniform(1)[0])
            self._events += len(times)
            return np.asarray(times, np.float64)
        # event k lies at or after first + k·interval (jitter is never negative)
        n_total = max(math.ceil((t_end_s - self._first_s) / self.interval_s), 0)
        if n_total <= self._events:
            return _NO_EVENTS
        k = np.arange(self._events, n_total)
        self._events = max(n_total, self._events)
        base = self._first_s + self.interval_s * k
        return np.asarray(base + self.jitter_s * self._uniform(len(k)), np.float64)

    def advance(self, t_end_s: float) -> Transmissions:
        """Frames that start in ``[until_s, t_end_s)``, sorted by time; ``until_s`` moves on.

        Frames before the emitter's ``start_s`` are never sent.
        """
        events = self._new_events(t_end_s)
        if not len(events) and not (len(self._pending_t) and self._pending_t[0] < t_end_s):
            # nothing starts in this window (the common case for sparse traffic)
            self.until_s = max(self.until_s, t_end_s)
            return _EMPTY
        t = np.concatenate([self._pending_t, (events[:, None] + self._offsets[None, :]).ravel()])
        ch = np.concatenate([self._pending_ch, np.tile(self._offset_ch, len(events))])
        order = np.argsort(t, kind="stable")
        t, ch = t[order], ch[order]
        cut = int(np.searchsorted(t, t_end_s, side="left"))
        self._pending_t, self._pending_ch = t[cut:], ch[cut:]
        t, ch = t[:cut], ch[:cut]
        keep = t >= self.start_s
        t, ch = t[keep], ch[keep]
        self.until_s = max(self.until_s, t_end_s)
        if self._ble:
            seq = np.full(len(t), NO_SEQ, np.int32)
        else:
            seq = ((self._seq + np.arange(len(t))) % SEQ_MODULO).astype(np.int32)
            self._seq = (self._seq + len(t)) % SEQ_MODULO
        return Transmissions(
            t_s=np.asarray(t, np.float64),
            channel=np.asarray(ch, np.int16),
            kind=np.full(len(t), int(self.kind), np.uint8),
            seq=seq,
        )


def transmissions(spec: TrafficSpec, duration_s: float, rng: np.random.Generator) -> Transmissions:
    """Frames sent in ``[0, duration_s)`` under the traffic model ``spec``."""
    return TrafficGenerator(spec, rng).advance(duration_s)


def merge_transmissions(parts: Sequence[Transmissions]) -> Transmissions:
    """Several models' frames in one time order (ties keep the order of ``parts``)."""
    nonempty = [p for p in parts if len(p)]
    if len(nonempty) <= 1:
        return nonempty[0] if nonempty else (parts[0] if parts else _EMPTY)
    t = np.concatenate([p.t_s for p in parts])
    order = np.argsort(t, kind="stable")
    return Transmissions(
        t_s=t[order],
        channel=np.concatenate([p.channel for p in parts])[order],
        kind=np.concatenate([p.kind for p in parts])[order],
        seq=np.concatenate([p.seq for p in parts])[order],
    )


class EmitterTraffic:
    """Every traffic model of one emitter, generated window by window.

    Each model draws from its own stream (``rngs[j]`` for ``specs[j]``) and
    keeps its own sequence counter (802.11 data frames count per traffic
    class, management frames share one counter).
    """

    def __init__(
        self,
        specs: Sequence[TrafficSpec],
        rngs: Sequence[np.random.Generator],
        start_s: float = 0.0,
    ) -> None:
        self.models = [TrafficGenerator(s, r, start_s) for s, r in zip(specs, rngs, strict=True)]

    def advance(self, t_end_s: float) -> Transmissions:
        """Frames of every model that start before ``t_end_s`` and were not handed out yet."""
        return merge_transmissions([m.advance(t_end_s) for m in self.models])


def traffic_streams(seed: int, emitter_id: str, n: int) -> list[np.random.Generator]:
    """The random stream of each of an emitter's ``n`` traffic models under ``seed``."""
    return [stream(seed, "traffic", emitter_id, str(j)) for j in range(n)]


def emitter_transmissions(
    specs: Sequence[TrafficSpec], duration_s: float, rng: np.random.Generator
) -> Transmissions:
    """Frames of an emitter with several traffic models in ``[0, duration_s)``, merged in time.

    The models' streams are spawned from ``rng``.
    """
    children = rng.spawn(len(specs))
    return EmitterTraffic(specs, children).advance(duration_s)
