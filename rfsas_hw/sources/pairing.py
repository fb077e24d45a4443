"""Pairing the frames of two single-antenna receivers into two-antenna observations.

Two monitor-mode cards hear the same transmission; each reports its own
signal and stamps the frame with its own MAC clock (TSFT). A frame is paired
when both receivers hold a frame with the same transmitter, type/subtype,
sequence and fragment number and retry bit (the key), at the same moment once
B's clock is mapped onto A's:

1. Anchors: key matches that are unique within ``anchor_window_s`` of host
   capture time (both cards usually sit in one host, or hosts run NTP).
2. Clock fit: ``tsft_b ≈ slope·tsft_a + offset`` by least squares on the
   anchors, with outliers (residual above ``outlier_us``) removed and the fit
   repeated; one fit per ``refit_s`` of capture when enough anchors fall in
   it (drift), else the global one.
3. Pairs: each frame of A takes the frame of B with its key nearest in mapped
   time, if within ``window_us``. A second candidate inside the window, or a
   frame of B claimed twice, makes the match ambiguous: dropped and counted.
   Without TSFT on both sides, host times and ``host_window_us`` are used.

Receiver A's signal becomes antenna column 0 and B's column 1. A receiver's
signal is its first per-chain value, else its combined value; sentinels
(-128, 0 dBm) count as missing. See radiotap.md §5 for the method.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import ConfigError
from rfsas_hw.records import ObservationBatch, ObsFlag
from rfsas_hw.rf.channels import freq_to_channel
from rfsas_hw.sources import dot11
from rfsas_hw.sources.frames import SENTINEL_DBM, FrameTable
from rfsas_hw.sources.pcapfile import FrameProblem

_TIME_BITS = 40
_TIME_MAX = (1 << _TIME_BITS) - 1


@dataclass(frozen=True)
class PairingConfig:
    """How strictly frames are paired."""

    window_us: float = 100.0
    """Largest mapped-TSFT difference of a pair, µs (under one inter-frame gap)."""
    host_window_us: float = 2_000.0
    """Largest host-time difference of a pair when TSFT is missing, µs."""
    anchor_window_s: float = 0.5
    """Host-time window in which an anchor's key must be unique, s."""
    outlier_us: float = 50.0
    """Anchors further than this from the fitted clock are dropped, µs."""
    refit_s: float = 30.0
    """Length of capture each piecewise clock fit covers, s."""
    min_anchors: int = 3
    """Fewest anchors a fit needs."""

    def __post_init__(self) -> None:
        for name in ("window_us", "host_window_us", "anchor_window_s", "outlier_us", "refit_s"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"pairing {name} must be positive, got {getattr(self, name)}")
        if self.min_anchors < 2:
            raise ConfigError(f"pairing min_anchors must be at least 2, got {self.min_anchors}")


@dataclass
class ClockFit:
    """``tsft_b ≈ slope·(tsft_a − a0) + offset`` over one span of A's host time."""

    a0_us: float
    slope: float
    offset_us: float
    rms_us: float
    anchors: int

    def map(self, tsft_a: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """A's TSFT values on B's clock, µs."""
        out: npt.NDArray[np.float64] = self.slope * (tsft_a - self.a0_us) + self.offset_us
        return out


@dataclass
class PairResult:
    """Paired observations and what happened to the rest."""

    observations: ObservationBatch
    counters: Counter[str] = field(default_factory=Counter)
    """paired, ambiguous, unpaired_a, unpaired_b, no_key."""
    fits: list[ClockFit] = field(default_factory=list)
    rows_a: npt.NDArray[np.int64] = field(default_factory=lambda: np.empty(0, np.int64))
    """Row of A behind each paired observation."""
    rows_b: npt.NDArray[np.int64] = field(default_factory=lambda: np.empty(0, np.int64))
    """Row of B behind each paired observation."""

    def extra(self, frames_a: int) -> dict[str, Any]:
        """Counters for ``SourceStats.extra``."""
        paired = self.counters["paired"]
        out: dict[str, Any] = {
            "pairing_rate": paired / frames_a if frames_a else 0.0,
            "paired": paired,
            "ambiguous_dropped": self.counters["ambiguous"],
            "unpaired_a": self.counters["unpaired_a"],
            "unpaired_b": self.counters["unpaired_b"],
            "clock_fits": len(self.fits),
        }
        if self.fits:
            out["clock_drift_ppm"] = float(np.median([(f.slope - 1.0) * 1e6 for f in self.fits]))
            out["clock_fit_rms_us"] = float(np.median([f.rms_us for f in self.fits]))
        return out


def _keys(t: FrameTable) -> tuple[npt.NDArray[np.uint64], npt.NDArray[np.uint64]]:
    """Exact pairing key as two integers: (MAC, seq, frag) and (type, subtype, retry)."""
    seq = np.where(t.seq < 0, 0xFFF, t.seq).astype(np.uint64)
    frag = np.where(t.frag < 0, 0xF, t.frag).astype(np.uint64)
    k1 = (t.mac << np.uint64(16)) | (seq << np.uint64(4)) | frag
    k2: npt.NDArray[np.uint64] = (
        (t.ftype.astype(np.uint64) << np.uint64(5))
        | (t.subtype.astype(np.uint64) << np.uint64(1))
        | t.retry.astype(np.uint64)
    ).astype(np.uint64)
    return k1.astype(np.uint64), k2


def match(
    key_a: tuple[npt.NDArray[np.uint64], npt.NDArray[np.uint64]],
    time_a: npt.NDArray[np.float64],
    key_b: tuple[npt.NDArray[np.uint64], npt.NDArray[np.uint64]],
    time_b: npt.NDArray[np.float64],
    window: float,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
    """For each row of A, the row of B with the same key nearest in time within ``window``.

    Times are in one unit (µs) on one clock. Returns (index into B or -1,
    ambiguous mask: a second candidate within the window, or a B row claimed
    by several A rows).
    """
    na, nb = len(time_a), len(time_b)
    found = np.full(na, -1, np.int64)
    ambiguous = np.zeros(na, bool)
    if na == 0 or nb == 0:
        return found, ambiguous
    stacked = np.stack([np.concatenate([key_a[0], key_b[0]]), np.concatenate([key_a[1], key_b[1]])])
    _, group = np.unique(stacked, axis=1, return_inverse=True)
    group = group.ravel().astype(np.int64)
    ga, gb = group[:na], group[na:]
    finite_a = np.isfinite(time_a)
    finite_b = np.isfinite(time_b)
    tmin = min(np.min(time_a[finite_a], initial=np.inf), np.min(time_b[finite_b], initial=np.inf))
    if not np.isfinite(tmin):
        return found, ambiguous
    rel_a = np.where(finite_a, time_a - tmin, -1.0)
    rel_b = np.where(finite_b, time_b - tmin, -1.0)
    usable_a = (rel_a >= 0) & (rel_a <= _TIME_MAX)
    usable_b = (rel_b >= 0) & (rel_b <= _TIME_MAX)
    ca = (ga << _TIME_BITS) | np.clip(rel_a, 0, _TIME_MAX).astype(np.int64)
    cb = (gb << _TIME_BITS) | np.clip(rel_b, 0, _TIME_MAX).astype(np.int64)
    cb = np.where(usable_b, cb, -1)
    order = np.argsort(cb, kind="stable")
    sorted_b = cb[order]
    pos = np.searchsorted(sorted_b, ca)
    big = np.iinfo(np.int64).max

    def distance(at: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        inside = (at >= 0) & (at < nb)
        safe = np.clip(at, 0, nb - 1)
        same = inside & ((sorted_b[safe] >> _TIME_BITS) == ga) & (sorted_b[safe] >= 0)
        return safe, np.where(same, np.abs(sorted_b[safe] - ca), big)

    # The nearest candidate and the runner-up are among two on each side.
    hi, d_hi = distance(pos)
    lo, d_lo = distance(pos - 1)
    _, d_hi2 = distance(pos + 1)
    _, d_lo2 = distance(pos - 2)
    take_hi = d_hi <= d_lo
    best = np.where(take_hi, hi, lo)
    best_d = np.minimum(d_hi, d_lo)
    other_d = np.minimum(np.maximum(d_hi, d_lo), np.where(take_hi, d_hi2, d_lo2))
    ok = usable_a & (best_d <= window)
    ambiguous = ok & (other_d <= window)
    found = np.where(ok & ~ambiguous, order[best], -1)
    claimed = found[found >= 0]
    if len(claimed):
        counts = np.bincount(claimed, minlength=nb)
        twice = (found >= 0) & (counts[np.maximum(found, 0)] > 1)
        ambiguous |= twice
        found[twice] = -1
    return found, ambiguous


def _robust_fit(
    a: npt.NDArray[np.float64], b: npt.NDArray[np.float64], cfg: PairingConfig
) -> ClockFit | None:
    if len(a) < cfg.min_anchors:
        return None
    a0 = float(a[0])
    x = a - a0
    keep = np.ones(len(a), bool)
    for _ in range(3):
        if keep.sum() < cfg.min_anchors:
            return None
        xs, ys = x[keep], b[keep]
        if np.ptp(xs) > 0:
            slope, offset = np.polyfit(xs, ys, 1)
        else:
            slope, offset = 1.0, float(np.median(ys - xs))
        resid = b - (slope * x + offset)
        new_keep = np.abs(resid) <= cfg.outlier_us
        if (new_keep == keep).all():
            break
        keep = new_keep
    if keep.sum() < cfg.min_anchors:
        return None
    rms = float(np.sqrt(np.mean(resid[keep] ** 2)))
    return ClockFit(a0, float(slope), float(offset), rms, int(keep.sum()))


def _signal(t: FrameTable) -> npt.NDArray[np.float32]:
    """Each frame's signal at one receiver: first per-chain value, else the combined one."""
    chains = t.chain_dbm.copy()
    chains[np.isin(chains, SENTINEL_DBM)] = np.nan
    first = np.full(len(t), np.nan, np.float32)
    for col in range(chains.shape[1] - 1, -1, -1):
        v = chains[:, col]
        first = np.where(np.isnan(v), first, v)
    combined = np.where(np.isin(t.signal_dbm, SENTINEL_DBM), np.nan, t.signal_dbm)
    out: npt.NDArray[np.float32] = np.where(np.isnan(first), combined, first).astype(np.float32)
    return out


def pair_tables(a: FrameTable, b: FrameTable, cfg: PairingConfig) -> PairResult:
    """Pair two receivers' frames (see the module docstring)."""
    counters: Counter[str] = Counter()
    key_a, key_b = _keys(a), _keys(b)
    host_a = a.t_ns.astype(np.float64) / 1e3
    host_b = b.t_ns.astype(np.float64) / 1e3
    use_tsft = bool(a.has_tsft.all() and b.has_tsft.all()) and len(a) > 0 and len(b) > 0
    fits: list[ClockFit] = []
    if use_tsft:
        # 1. anchors: unique key matches close in host time, first transmissions only
        first_a = ~a.retry
        idx, amb = match(key_a, host_a, key_b, host_b, cfg.anchor_window_s * 1e6)
        anchor = (idx >= 0) & ~amb & first_a
        ta = a.tsft_us.astype(np.float64)
        tb = b.tsft_us.astype(np.float64)
        global_fit = _robust_fit(ta[anchor], tb[idx[anchor]], cfg)
        if global_fit is None:
            use_tsft = False
        else:
            # 2. piecewise fits over spans of A's host time
            mapped = global_fit.map(ta)
            span = cfg.refit_s * 1e6
            piece = np.floor((host_a - host_a.min()) / span).astype(np.int64)
            for p in np.unique(piece).tolist():
                sel = piece == p
                fit = _robust_fit(ta[sel & anchor], tb[idx[sel & anchor]], cfg) or global_fit
                mapped[sel] = fit.map(ta[sel])
                fits.append(fit)
            found, amb = match(key_a, mapped, key_b, tb, cfg.window_us)
    if not use_tsft:
        found, amb = match(key_a, host_a, key_b, host_b, cfg.host_window_us)
    paired = found >= 0
    counters["paired"] = int(paired.sum())
    counters["ambiguous"] = int(amb.sum())
    counters["unpaired_a"] = int((~paired & ~amb).sum())
    used_b = np.zeros(len(b), bool)
    used_b[found[paired]] = True
    counters["unpaired_b"] = int((~used_b).sum())
    rows_a = np.flatnonzero(paired)
    rows_b = found[paired]
    sig_a, sig_b = _signal(a)[rows_a], _signal(b)[rows_b]
    rssi = np.stack([sig_a, sig_b], axis=1)
    flags = np.full(len(rows_a), int(ObsFlag.PAIRED), np.uint16)
    flags |= np.where(a.retry[rows_a], int(ObsFlag.RETRY), 0).astype(np.uint16)
    flags |= np.where(np.isnan(rssi).any(axis=1), int(ObsFlag.MISSING_CHAIN), 0).astype(np.uint16)
    flags |= np.where(np.isnan(rssi).all(axis=1), int(ObsFlag.NO_SIGNAL), 0).astype(np.uint16)
    obs = ObservationBatch(
        t_ns=a.t_ns[rows_a],
        mac=a.mac[rows_a],
        freq_mhz=a.freq_mhz[rows_a],
        channel=freq_to_channel(a.freq_mhz[rows_a]),
        rssi_dbm=rssi,
        seq=a.seq[rows_a],
        kind=dot11.kind_of(a.ftype[rows_a], a.subtype[rows_a]),
        flags=flags,
    )
    return PairResult(obs, counters, fits, rows_a, rows_b)


class OfflinePairing:
    """Pair two capture files (``pcap:A.pcap+B.pcap``), then hand out the pairs in batches.

    Raises:
        SourceError: a file cannot be opened.
        CaptureFormatError: a file is not a capture.
    """

    def __init__(
        self, path_a: str, path_b: str, config: PairingConfig, batch: int = 65_536
    ) -> None:
        from rfsas_hw.sources.pcap import read_frames

        self.paths = (path_a, path_b)
        table_a, read_a = read_frames(path_a, n_antennas=2)
        table_b, read_b = read_frames(path_b, n_antennas=2)
        self.problems: list[tuple[str, FrameProblem]] = [(path_a, p) for p in read_a.problems] + [
            (path_b, p) for p in read_b.problems
        ]
        self.dropped: Counter[str] = Counter()
        for label, got in (("A", read_a), ("B", read_b)):
            for reason, count in got.dropped.items():
                if count:
                    self.dropped[f"{reason} ({label})"] += count
        self.result = pair_tables(table_a, table_b, config)
        self.extra = self.result.extra(len(table_a))
        self.frames = (len(table_a), len(table_b))
        self._batch = batch
        self._pos = 0

    def next_batch(self) -> ObservationBatch | None:
        """The next slice of paired observations, or None when all were handed out."""
        obs = self.result.observations
        if self._pos >= len(obs):
            return None
        out = obs.select(slice(self._pos, self._pos + self._batch))
        self._pos += self._batch
        return out

    def close(self) -> None:
        """Nothing to release: both files were read at construction."""
