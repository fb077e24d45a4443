"""The source base class and the registry, with a small in-test driver."""

from __future__ import annotations

import gc
from typing import Any

import numpy as np
import pytest

from rfsas_hw import sources
from rfsas_hw.errors import CaptureFormatError, ConfigError, SourceError
from rfsas_hw.records import ObservationBatch
from rfsas_hw.sources import Source


class ListSource(Source[ObservationBatch]):
    """Yields given batches; a None entry stands for a corrupt frame."""

    def __init__(
        self, arg: str, batches: list[ObservationBatch | None] | None = None, **kw: Any
    ) -> None:
        super().__init__(**kw)
        self.arg = arg
        self._batches = list(batches or [])
        self.closed_calls = 0

    def _read_raw(self, timeout: float | None) -> ObservationBatch | None:
        if not self._batches:
            self._end()
            return None
        item = self._batches.pop(0)
        if item is None:
            self._bad("bad_frame", CaptureFormatError(f"{self.arg}: frame 2 at byte 40: broken"))
            return ObservationBatch.empty()
        return item

    def _close(self) -> None:
        self.closed_calls += 1


def _batch(macs: list[int]) -> ObservationBatch:
    n = len(macs)
    return ObservationBatch(
        t_ns=np.arange(n),
        mac=np.array(macs, np.uint64),
        freq_mhz=np.full(n, 2437),
        channel=np.full(n, 6),
        rssi_dbm=np.full((n, 2), -50.0),
    )


def test_iteration_skip_policy_and_counters() -> None:
    with ListSource("x.pcap", [_batch([1, 2]), None, _batch([3])]) as src:
        got = [b.mac.tolist() for b in src]
    assert got == [[1, 2], [3]]
    assert src.stats.frames == 3 and src.stats.batches == 2
    assert src.stats.skipped["bad_frame"] == 1
    assert "frame 2 at byte 40" in src.stats.errors[0]
    assert src.closed and src.closed_calls == 1
    src.close()
    assert src.closed_calls == 1
    with pytest.raises(SourceError, match="closed"):
        src.read()


def test_raise_policy() -> None:
    with ListSource("x.pcap", [None], errors="raise") as src, pytest.raises(CaptureFormatError):
        list(src)


def test_filter_counts_what_it_removes() -> None:
    keep_odd = lambda b: (b.mac % 2) == 1  # noqa: E731
    with ListSource("x", [_batch([1, 2, 3])], filter=keep_odd) as src:
        (batch,) = list(src)
    assert batch.mac.tolist() == [1, 3]
    assert src.stats.filtered == 1 and src.stats.observations == 2


def test_unclosed_source_warns() -> None:
    src = ListSource("x")
    with pytest.warns(ResourceWarning, match="never closed"):
        del src
        gc.collect()


def test_registry() -> None:
    sources.register("listtest", ListSource)
    with sources.open("listtest:some/arg", batches=[_batch([9])]) as src:
        assert isinstance(src, ListSource) and src.arg == "some/arg"
        assert [b.mac.tolist() for b in src] == [[9]]
    assert {"pcap", "wifi", "serial", "virtual", "agrelo", "listtest"} <= set(sources.schemes())
    with pytest.raises(ConfigError, match="unknown source 'nope'"):
        sources.open("nope:x")
    with pytest.raises(ConfigError, match="must look like SCHEME:ARG"):
        sources.open("capture.pcap")
