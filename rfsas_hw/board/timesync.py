"""Board time (µs since boot) → host time (UTC ns) from TIME_SYNC exchanges.

Each exchange gives, NTP-style, the board-minus-host offset and the round
trip. Exchanges with a long round trip carry queueing delay, so only those
within ``rtt_slack_ns`` of the best are used; over a window that spans at
least ``min_span_s`` of board time, offset and rate are fitted by least
squares, so a board crystal a few tens of ppm off is followed.

Before the first exchange (or for a board without TIME_SYNC) the mapping
falls back to arrival times: a measurement always arrives after it happened,
so ``t_us·1000 − arrival_ns`` bounds the offset from below, and the largest
such bound is the best estimate available.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True, slots=True)
class SyncSample:
    """One TIME_SYNC exchange."""

    board_ns: float
    """Board time at the middle of the exchange, ns."""
    offset_ns: float
    """Board time minus host time, ns."""
    rtt_ns: float
    """Round trip minus the board's processing time, ns."""


class TimeMapper:
    """Maps board microseconds to host UTC nanoseconds.

    Args:
        window: exchanges kept.
        rtt_slack_ns: exchanges whose round trip exceeds the best by more
            than this are ignored.
        min_span_s: board-time span needed before the rate is fitted.
    """

    def __init__(
        self, window: int = 32, rtt_slack_ns: float = 2e6, min_span_s: float = 5.0
    ) -> None:
        self.samples: deque[SyncSample] = deque(maxlen=window)
        self.rtt_slack_ns = rtt_slack_ns
        self.min_span_ns = min_span_s * 1e9
        self._offset_ns = 0.0
        self._rate = 0.0  # d(offset)/d(board time)
        self._ref_ns = 0.0
        self._arrival_bound: float | None = None

    @property
    def synced(self) -> bool:
        """True once at least one exchange was added."""
        return bool(self.samples)

    def reset(self) -> None:
        """Forget everything (the board rebooted: its clock started over)."""
        self.samples.clear()
        self._offset_ns = self._rate = self._ref_ns = 0.0
        self._arrival_bound = None

    def add(self, t0_ns: int, t3_ns: int, board_rx_us: int, board_tx_us: int) -> SyncSample:
        """Add an exchange: host send/receive times (ns), board receive/send times (µs)."""
        rx, tx = board_rx_us * 1000.0, board_tx_us * 1000.0
        sample = SyncSample(
            board_ns=(rx + tx) / 2.0,
            offset_ns=((rx - t0_ns) + (tx - t3_ns)) / 2.0,
            rtt_ns=(t3_ns - t0_ns) - (tx - rx),
        )
        self.samples.append(sample)
        self._fit()
        return sample

    def _fit(self) -> None:
        best = min(s.rtt_ns for s in self.samples)
        good = [s for s in self.samples if s.rtt_ns <= best + self.rtt_slack_ns]
        b = np.array([s.board_ns for s in good])
        o = np.array([s.offset_ns for s in good])
        self._ref_ns = float(b.mean())
        if len(good) >= 3 and np.ptp(b) >= self.min_span_ns:
            slope, intercept = np.polyfit(b - self._ref_ns, o, 1)
            self._rate, self._offset_ns = float(slope), float(intercept)
        else:
            self._rate, self._offset_ns = 0.0, float(o.mean())

    def observe_arrival(self, board_us_max: int, arrival_ns: int) -> None:
        """Note that a measurement of board time ``board_us_max`` had arrived by ``arrival_ns``."""
        bound = board_us_max * 1000.0 - arrival_ns
        if self._arrival_bound is None or bound > self._arrival_bound:
            self._arrival_bound = bound

    @property
    def offset_ns(self) -> float:
        """Current board-minus-host offset at the reference point, ns."""
        if not self.samples and self._arrival_bound is not None:
            return self._arrival_bound
        return self._offset_ns

    @property
    def rate_ppm(self) -> float:
        """Fitted board clock rate error, parts per million."""
        return self._rate * 1e6

    def to_host_ns(
        self, board_us: npt.NDArray[np.uint64] | npt.NDArray[np.int64]
    ) -> npt.NDArray[np.int64]:
        """Host UTC nanoseconds of board times in microseconds."""
        b = np.asarray(board_us, dtype=np.int64) * 1000
        if not self.samples:
            return b - np.int64(round(self.offset_ns))
        off = self._offset_ns + self._rate * (b.astype(np.float64) - self._ref_ns)
        return b - np.round(off).astype(np.int64)
