"""The dashboard's state does not grow with time: emitter ids change every nonce epoch,
and bearings no longer drawn are dropped, not kept for ever (the backend with the
dashboard grew 30-55 kB a minute)."""

from __future__ import annotations

import gc
import tracemalloc

import numpy as np

from rfsas_hw.backend.site import SiteConfig
from rfsas_hw.records import BearingBatch, Pose
from rfsas_hw.web.state import DashboardState

NS = 1_000_000_000


def run(state: DashboardState, clock: list[int], steps: int, start: int) -> None:
    for step in range(start, start + steps):
        clock[0] += NS // 10
        for sensor in ("rsu-1", "rsu-2"):
            state.on_bearings(
                BearingBatch(
                    sensor,
                    np.array([clock[0]], np.int64),
                    np.array([45.0]),
                    np.array([2.0]),
                    np.array([20.0]),
                    np.array([6], np.int16),
                    np.array([step + 1], np.uint64),  # a new id every step, as epochs bring
                ),
                Pose(0.0, 0.0, 0.0),
            )
        state.on_results([], [])


def test_memory_does_not_grow_with_new_emitter_ids() -> None:
    clock = [1_763_800_000 * NS]
    state = DashboardState(SiteConfig(), clock=lambda: clock[0])
    run(state, clock, 500, 0)  # past the 2 s a bearing is drawn: the steady state
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.take_snapshot()
        run(state, clock, 3000, 500)
        gc.collect()
        after = tracemalloc.take_snapshot()
    finally:
        tracemalloc.stop()
    grown = sum(s.size_diff for s in after.compare_to(before, "filename"))
    # 6,000 more (sensor, emitter) bearings kept would be megabytes; the timeline is
    # bounded, and nothing else may grow
    assert grown < 200_000, grown
    drawn = state.snapshot()["bearings"]
    assert 0 < len(drawn) <= 2 * 21  # the last 2 s of bearings of two sensors
