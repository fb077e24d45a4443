"""A signal that comes while bearings are delivered ends the run after the delivery: the
summary counts exactly what the listeners were given."""

from __future__ import annotations

import signal
from types import FrameType

import numpy as np
import pytest

from rfsas_hw.records import BearingBatch
from rfsas_hw.runner import Runner, Terminated, signals_held
from rfsas_hw.sources import Source


class _Bearings(Source[BearingBatch]):
    """Ten batches of two bearings, then the end."""

    def __init__(self) -> None:
        super().__init__()
        self._left = 10

    def _read_raw(self, timeout: float | None) -> BearingBatch | None:
        if not self._left:
            self._end()
            return None
        self._left -= 1
        return BearingBatch(
            sensor_id="s",
            t_ns=np.array([1, 2], np.int64),
            azimuth_deg=np.array([10.0, 20.0]),
            sigma_deg=np.array([3.0, 3.0]),
            snr_db=np.array([30.0, 30.0]),
            channel=np.array([6, 6], np.int16),
            emitter=np.array([7, 8], np.uint64),
        )

    def _close(self) -> None:
        pass


class _SignalledWhileWriting:
    """Takes each batch; SIGTERM reaches the process in the middle of the third."""

    def __init__(self) -> None:
        self.written = 0
        self.batches = 0

    def on_bearings(self, batch: BearingBatch) -> None:
        self.batches += 1
        if self.batches == 3:
            signal.raise_signal(signal.SIGTERM)
        self.written += len(batch)

    def close(self) -> None:
        pass


def _terminate(signum: int, frame: FrameType | None) -> None:
    raise Terminated


def test_sigterm_during_a_delivery_ends_the_run_after_it() -> None:
    before = signal.signal(signal.SIGTERM, _terminate)  # as the CLI sets it
    try:
        listener = _SignalledWhileWriting()
        summary = Runner(_Bearings(), None, listener).run()
    finally:
        signal.signal(signal.SIGTERM, before)
    assert summary.stopped == "terminated"
    assert listener.batches == 3
    assert summary.bearings == listener.written == 6


def test_held_signals_go_to_the_handler_in_place_before_and_only_after_the_block() -> None:
    came: list[str] = []
    before = signal.signal(signal.SIGTERM, lambda *_: came.append("handled"))
    try:
        with signals_held():
            signal.raise_signal(signal.SIGTERM)
            came.append("block ran on")
        assert came == ["block ran on", "handled"]
        with pytest.raises(KeyboardInterrupt), signals_held():
            signal.raise_signal(signal.SIGINT)
            came.append("the block ends before Ctrl-C")
        assert came[-1] == "the block ends before Ctrl-C"
    finally:
        signal.signal(signal.SIGTERM, before)
