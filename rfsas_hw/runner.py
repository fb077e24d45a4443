"""The sensor loop: a source's observations through the pipeline to every listener.

:class:`Runner` drives ``source → SensorPipeline → listener`` (usually a
:class:`~rfsas_hw.stream.Fanout` of file writers and the link), either as
fast as the source delivers or at the pace the frames were recorded
(``realtime``, ``speed``). The clock is injectable, so a test replays a
minute of capture in milliseconds. It stops at the end of the input, after
``duration_s``, on :meth:`Runner.stop`, on Ctrl-C or SIGTERM (delivered as
:class:`Terminated` by the CLI), and always returns a :class:`RunSummary`:
frames held for a missing nonce are released or counted, and every
listener is closed, so the outputs and the summary are complete.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from rfsas_hw.errors import ConfigError
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.records import BearingBatch, ObservationBatch
from rfsas_hw.sources.base import Source
from rfsas_hw.stream import BearingListener

NS_PER_S = 1_000_000_000


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread so that it ends a run as Ctrl-C does."""


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) and SIGTERM for the block, then deliver the first that came
    to the handler that was in place before: a delivery of bearings that is counted
    and written is not cut between the two. Outside the main thread (where Python
    runs no signal handler) it holds nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []

    def hold(signum: int, _frame: object) -> None:
        came.append(signum)

    before = {sig: signal.signal(sig, hold) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
        if came:
            signal.raise_signal(came[0])


class Clock(Protocol):
    """Where the runner reads time and waits (monotonic)."""

    def monotonic_ns(self) -> int:
        """Monotonic time, nanoseconds."""
        ...

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds``."""
        ...


class SystemClock:
    """The real clock."""

    def monotonic_ns(self) -> int:
        """``time.monotonic_ns()``."""
        return time.monotonic_ns()

    def sleep(self, seconds: float) -> None:
        """``time.sleep``."""
        time.sleep(seconds)


class ManualClock:
    """A clock that only moves when slept on: replays run instantly, durations stay exact."""

    def __init__(self, start_ns: int = 0) -> None:
        self.now_ns = start_ns
        self.slept_s = 0.0
        """Total seconds the runner asked to sleep."""

    def monotonic_ns(self) -> int:
        """The current manual time."""
        return self.now_ns

    def sleep(self, seconds: float) -> None:
        """Advance the clock by ``seconds`` without waiting."""
        self.now_ns += max(0, round(seconds * NS_PER_S))
        self.slept_s += max(0.0, seconds)


ProgressFn = Callable[[int, "int | None"], None]
"""Called after each batch with (bytes read, total bytes or None)."""


@dataclass
class RunSummary:
    """What one run did; the CLI prints it as a table."""

    frames: int = 0
    """Frames read from the input (kept or dropped)."""
    observations: int = 0
    """Observations handed to the pipeline."""
    per_antenna: list[int] = field(default_factory=list)
    """Observations with a signal value on antenna ``i`` (index = antenna)."""
    all_antennas: int = 0
    """Observations with a value on every antenna (usable for DF)."""
    skipped: Counter[str] = field(default_factory=Counter)
    """Frames dropped by the source, by reason."""
    flagged: Counter[str] = field(default_factory=Counter)
    """Frames kept with a quality flag (no per-antenna signal, sentinel chains, …)."""
    rejected: Counter[str] = field(default_factory=Counter)
    """Observations without a bearing, by the pipeline's reason."""
    emitters: int = 0
    """Distinct emitter ids among the bearings."""
    bearings: int = 0
    """Bearings produced and sent to the listeners."""
    errors: list[str] = field(default_factory=list)
    """The first error messages (frame numbers, byte offsets)."""
    extra: dict[str, Any] = field(default_factory=dict)
    """Source-specific counters (pairing rate, …)."""
    stopped: str = "end of input"
    """Why the run ended: end of input, duration, stopped, interrupted."""
    elapsed_s: float = 0.0
    """Run time on the runner's clock, seconds."""
    capture_span_s: float = 0.0
    """Time between the first and last observation, seconds."""
    outputs: dict[str, dict[str, int]] = field(default_factory=dict)
    """Per output (file, link): ``written``/``sent``/``lost``/``dropped.*`` counters."""
    problems: list[str] = field(default_factory=list)
    """Outputs whose work failed (write error, nothing sent), one line each."""
    nonces: dict[str, int] = field(default_factory=dict)
    """Frames that waited for a nonce: ``held_max``, ``released``, ``alarms``."""

    def as_dict(self) -> dict[str, Any]:
        """A JSON-friendly copy (the ``--json`` summary)."""
        return {
            "frames": self.frames,
            "observations": self.observations,
            "per_antenna": list(self.per_antenna),
            "all_antennas": self.all_antennas,
            "skipped": dict(self.skipped),
            "flagged": dict(self.flagged),
            "rejected": dict(self.rejected),
            "emitters": self.emitters,
            "bearings": self.bearings,
            "outputs": {k: dict(v) for k, v in self.outputs.items()},
            "problems": list(self.problems),
            "nonces": dict(self.nonces),
            "errors": list(self.errors),
            "extra": {k: v for k, v in self.extra.items() if isinstance(v, int | float | str)},
            "stopped": self.stopped,
            "elapsed_s": round(self.elapsed_s, 3),
            "capture_span_s": round(self.capture_span_s, 3),
        }


class Runner:
    """Run a source through a pipeline into listeners.

    Args:
        source: where observations come from (opened; the runner closes it).
        pipeline: observations → bearings; None for a source that yields
            bearings itself (they go to the listener as they are).
        listener: receives every bearing batch (a Fanout for several).
        clock: time source (``SystemClock`` by default).
        realtime: pace the frames at their recorded times.
        speed: pace factor with ``realtime`` (2.0 = twice as fast).
        duration_s: stop after this long on the clock (None: until the input ends).
        progress: called after each batch with bytes read and total.
        poll_s: longest wait for the source before checking for stop/duration.
        retime: map capture times to "now" on ``utc_ns``: the first frame gets
            the start time, later ones their recorded spacing divided by
            ``speed``. A receiver rejects bearings from an old capture as stale
            or from the wrong nonce epoch; retimed and paced (``realtime``), a
            replay feeds a live backend the way a sensor would.
        utc_ns: wall clock for ``retime``, UTC nanoseconds.

    Raises:
        ConfigError: a non-positive speed or duration.
    """

    def __init__(
        self,
        source: Source[Any],
        pipeline: SensorPipeline | None,
        listener: BearingListener,
        *,
        clock: Clock | None = None,
        realtime: bool = False,
        speed: float = 1.0,
        duration_s: float | None = None,
        progress: ProgressFn | None = None,
        poll_s: float = 0.2,
        retime: bool = False,
        utc_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        if speed <= 0:
            raise ConfigError(f"--speed must be positive, got {speed}")
        if duration_s is not None and duration_s <= 0:
            raise ConfigError(f"--duration must be positive, got {duration_s}")
        self.source = source
        self.pipeline = pipeline
        self.listener = listener
        self.clock: Clock = clock or SystemClock()
        self.realtime = realtime
        self.speed = speed
        self.duration_s = duration_s
        self.progress = progress
        self.poll_s = poll_s
        self.summary = RunSummary()
        self._stop = threading.Event()
        self._start_ns = 0
        self._t0_capture: int | None = None
        self._last_due = -(2**62)
        self._first_t: int | None = None
        self._last_t: int | None = None
        self.retime = retime
        self._utc_ns = utc_ns
        self._retime_offset_ns: int | None = None
        self._retime_t0 = 0
        self._source_emitters: set[int] = set()

    def stop(self) -> None:
        """Ask the loop to end after the current batch (safe from another thread)."""
        self._stop.set()

    # -- loop ------------------------------------------------------------------------

    def _deadline_passed(self) -> bool:
        if self.duration_s is None:
            return False
        return self.clock.monotonic_ns() - self._start_ns >= self.duration_s * NS_PER_S

    def _timeout(self) -> float:
        if self.duration_s is None:
            return self.poll_s
        left = self.duration_s - (self.clock.monotonic_ns() - self._start_ns) / NS_PER_S
        return max(0.0, min(self.poll_s, left))

    def run(self) -> RunSummary:
        """Run until the input ends, the duration passes, :meth:`stop`, or Ctrl-C.

        The source and listener are closed at the end. Errors from the source
        under the ``raise`` policy propagate after both are closed.
        """
        self._start_ns = self.clock.monotonic_ns()
        try:
            while True:
                if self._stop.is_set():
                    self.summary.stopped = "stopped"
                    break
                if self._deadline_passed():
                    self.summary.stopped = "duration"
                    break
                if self.source.exhausted:
                    break
                batch = self.source.read(timeout=self._timeout())
                if batch is not None and len(batch):
                    if not self._deliver(batch):
                        break
                elif self.pipeline is not None:
                    self._emit(self.pipeline.release())
                self._report_progress()
        except Terminated:
            self.summary.stopped = "terminated"
        except KeyboardInterrupt:
            self.summary.stopped = "interrupted"
        finally:
            try:
                self.source.close()
            finally:
                try:
                    if self.pipeline is not None:
                        # at the end of the input held frames may still get their nonce;
                        # an interrupted run does not wait
                        ended = self.summary.stopped == "end of input"
                        self._emit(self.pipeline.finish(self.pipeline.end_wait_s if ended else 0))
                finally:
                    self.listener.close()
                    self._finish()
        return self.summary

    def _emit(self, bearings: BearingBatch) -> None:
        if len(bearings):
            with signals_held():  # counted and written, or neither
                self.summary.bearings += len(bearings)
                self.listener.on_bearings(bearings)

    def _deliver(self, batch: ObservationBatch) -> bool:
        """Process ``batch`` (paced in realtime mode); False when the run must end."""
        if self.retime:
            if self._retime_offset_ns is None:
                self._retime_t0 = int(batch.t_ns.min())
                self._retime_offset_ns = self._utc_ns()
            batch = batch.select(slice(None))
            elapsed = (batch.t_ns - self._retime_t0) / self.speed
            batch.t_ns = self._retime_offset_ns + elapsed.astype(np.int64)
        if not self.realtime:
            self._process(batch)
            return True
        t = np.maximum.accumulate(batch.t_ns)
        if self._t0_capture is None:
            self._t0_capture = int(t[0])
        due = self._start_ns + ((t - self._t0_capture) / self.speed).astype(np.int64)
        # Keep due times monotonic across batches too.
        due = np.maximum(due, self._last_due)
        self._last_due = int(due[-1])
        done = 0
        while done < len(batch):
            if self._stop.is_set() or self._deadline_passed():
                self.summary.stopped = "stopped" if self._stop.is_set() else "duration"
                return False
            now = self.clock.monotonic_ns()
            ready = int(np.searchsorted(due, now, side="right"))
            if ready > done:
                self._process(batch.select(slice(done, ready)))
                done = ready
                continue
            wait_s = (int(due[done]) - now) / NS_PER_S
            if self.duration_s is not None:
                left = self.duration_s - (now - self._start_ns) / NS_PER_S
                wait_s = min(wait_s, max(left, 0.0))
            self.clock.sleep(min(max(wait_s, 0.0), 1.0))
        return True

    def _process(self, batch: ObservationBatch | BearingBatch) -> None:
        s = self.summary
        if isinstance(batch, BearingBatch):
            with signals_held():  # counted and written, or neither
                s.bearings += len(batch)
                self._source_emitters.update(batch.emitter.tolist())
                self.listener.on_bearings(batch)
            return
        if self.pipeline is None:
            raise ConfigError("observations need a calibration: this source does not give bearings")
        s.observations += len(batch)
        present = ~np.isnan(batch.rssi_dbm)
        counts = present.sum(axis=0).tolist()
        if len(s.per_antenna) < len(counts):
            s.per_antenna.extend([0] * (len(counts) - len(s.per_antenna)))
        for i, c in enumerate(counts):
            s.per_antenna[i] += int(c)
        s.all_antennas += int(present.all(axis=1).sum())
        first, last = int(batch.t_ns.min()), int(batch.t_ns.max())
        self._first_t = first if self._first_t is None else min(self._first_t, first)
        self._last_t = last if self._last_t is None else max(self._last_t, last)
        self._emit(self.pipeline.process(batch))

    def _report_progress(self) -> None:
        if self.progress is None:
            return
        extra = self.source.stats.extra
        done = int(extra.get("bytes_read", 0) or 0)
        total = extra.get("bytes_total")
        self.progress(done, int(total) if total else None)

    def _finish(self) -> None:
        s = self.summary
        stats = self.source.stats
        s.skipped = Counter(stats.skipped)
        s.frames = stats.frames + sum(stats.skipped.values())
        s.errors = list(stats.errors)
        flagged = stats.extra.get("flagged")
        if isinstance(flagged, Counter | dict):
            s.flagged = Counter(flagged)
        s.extra = {
            k: v
            for k, v in stats.extra.items()
            if k not in ("flagged", "bytes_read", "bytes_total")
        }
        if self.pipeline is not None:
            ps = self.pipeline.stats
            s.rejected = Counter(ps.rejected)
            s.emitters = len(ps.emitters)
            if ps.nonce_alarms:
                s.nonces = {
                    "held_max": ps.held_max,
                    "released": ps.released,
                    "alarms": ps.nonce_alarms,
                }
        else:
            s.emitters = len(self._source_emitters)
        counters = getattr(self.listener, "counters", None)
        if callable(counters):
            s.outputs = dict(counters())
        problems = getattr(self.listener, "problems", None)
        if callable(problems):
            s.problems = list(problems())
        s.elapsed_s = (self.clock.monotonic_ns() - self._start_ns) / NS_PER_S
        if self._first_t is not None and self._last_t is not None:
            s.capture_span_s = (self._last_t - self._first_t) / NS_PER_S
