"""Traffic models: when each emitter transmits, on which channel, which frame kind.

Models follow method.md §8: access points beacon about every 102.4 ms on one
channel; phones send probe requests in bursts that sweep the channel list;
BLE advertisers send one packet on each of channels 37/38/39 per event, with
events ``advInterval + advDelay`` apart (advDelay uniform in 0–10 ms); data
bursts are a few frames close together on one channel.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.records import NO_SEQ, FrameKind
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


def _event_times(
    interval_s: float, jitter_s: float, phase_s: float, t_end_s: float, rng: np.random.Generator
) -> npt.NDArray[np.float64]:
    n = max(int(np.ceil((t_end_s - phase_s) / interval_s)) + 1, 0)
    base = phase_s + interval_s * np.arange(n)
    return base + rng.uniform(0.0, jitter_s, n)


def transmissions(spec: TrafficSpec, duration_s: float, rng: np.random.Generator) -> Transmissions:
    """Frames sent in ``[0, duration_s)`` under the traffic model ``spec``."""
    interval = spec.effective_interval_s()
    jitter = spec.effective_jitter_ms() / 1e3
    channels = np.asarray(spec.effective_channels(), dtype=np.int16)
    phase = float(spec.phase_s) if spec.phase_s is not None else float(rng.uniform(0.0, interval))
    gap = spec.gap_ms / 1e3
    if spec.model == "ble-adv":
        # advDelay accumulates: each event is advInterval + advDelay after the previous one
        n = int(np.ceil((duration_s - phase) / interval)) + 1
        steps = interval + rng.uniform(0.0, jitter, max(n, 0))
        events = phase + np.concatenate([[0.0], np.cumsum(steps)[:-1]]) if n > 0 else np.empty(0)
        offsets = gap * np.arange(len(channels))
        t = (events[:, None] + offsets[None, :]).ravel()
        ch = np.tile(channels, len(events))
        kind = FrameKind.BLE_ADV
    elif spec.model == "probe-bursts":
        events = _event_times(interval, jitter, phase, duration_s, rng)
        per_ch = spec.channel_dwell_ms / 1e3 * np.arange(len(channels))
        within = gap * np.arange(spec.frames_per_channel)
        offsets = (per_ch[:, None] + within[None, :]).ravel()
        t = (events[:, None] + offsets[None, :]).ravel()
        ch = np.tile(np.repeat(channels, spec.frames_per_channel), len(events))
        kind = FrameKind.PROBE_REQUEST
    elif spec.model == "data-bursts":
        events = _event_times(interval, jitter, phase, duration_s, rng)
        t = (events[:, None] + gap * np.arange(spec.burst_frames)[None, :]).ravel()
        ch = np.full(len(t), channels[0], np.int16)
        kind = FrameKind.QOS_DATA
    else:
        t = _event_times(interval, jitter, phase, duration_s, rng)
        ch = np.full(len(t), channels[0], np.int16)
        kind = FrameKind.BEACON
    order = np.argsort(t, kind="stable")
    t = t[order]
    ch = ch[order]
    keep = (t >= 0.0) & (t < duration_s)
    t, ch = t[keep], ch[keep]
    if kind == FrameKind.BLE_ADV:
        seq = np.full(len(t), NO_SEQ, np.int32)
    else:
        start = int(rng.integers(0, SEQ_MODULO))
        seq = ((start + np.arange(len(t))) % SEQ_MODULO).astype(np.int32)
    return Transmissions(
        t_s=np.asarray(t, np.float64),
        channel=np.asarray(ch, np.int16),
        kind=np.full(len(t), int(kind), np.uint8),
        seq=seq,
    )


def emitter_transmissions(
    specs: Sequence[TrafficSpec], duration_s: float, rng: np.random.Generator
) -> Transmissions:
    """Frames of an emitter with several traffic models, merged in time order.

    Each model keeps its own sequence counter (802.11 data frames count per
    traffic class, management frames share one counter).
    """
    parts = [transmissions(s, duration_s, rng) for s in specs]
    if len(parts) == 1:
        return parts[0]
    t = np.concatenate([p.t_s for p in parts])
    order = np.argsort(t, kind="stable")
    return Transmissions(
        t_s=t[order],
        channel=np.concatenate([p.channel for p in parts])[order],
        kind=np.concatenate([p.kind for p in parts])[order],
        seq=np.concatenate([p.seq for p in parts])[order],
    )
