"""The timing of the distributed path without a broker: a worker's slots published at their
times from a thread, a backend's cadence (ticks and quick steps), vehicle states used from
their own time on, and the kernels loaded before a run. Clocks are the tests' own (no
wall-clock assertions); every wait has a timeout."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from rfsas_hw.backend.service import BackendConfig
from rfsas_hw.city.backendproc import Cadence, StatesByTime, VehicleStates, warm_kernels
from rfsas_hw.city.live import LiveConfig, StatesFlow
from rfsas_hw.city.slots import SlotSender
from rfsas_hw.records import BearingBatch

MS = 1_000_000
WAIT_S = 10.0


class ManualClock:
    """UTC ns set by the test; its seconds take 1/1000 of a wall second to wait for."""

    def __init__(self, now_ns: int) -> None:
        self.now_ns = now_ns

    def __call__(self) -> int:
        return self.now_ns

    def wall_s(self, clock_s: float) -> float:
        return clock_s / 1000.0


class Recorder:
    """A unit's publisher: what it was given, with the stamp the sender gave it."""

    def __init__(self, stamp: list[SlotSender]) -> None:
        self.stamp = stamp
        self.sent: list[tuple[int, int]] = []
        self.cond = threading.Condition()

    def on_bearings(self, batch: BearingBatch) -> None:
        with self.cond:
            self.sent.append((int(batch.t_ns[0]), self.stamp[0].stamp_ns()))
            self.cond.notify_all()

    def wait_for(self, count: int) -> list[tuple[int, int]]:
        with self.cond:
            assert self.cond.wait_for(lambda: len(self.sent) >= count, WAIT_S)
            return list(self.sent)


def batch_at(t_ns: int) -> BearingBatch:
    return BearingBatch(
        sensor_id="u",
        t_ns=np.array([t_ns], np.int64),
        emitter=np.array([1], np.uint64),
        channel=np.array([6], np.int16),
        azimuth_deg=np.array([10.0]),
        sigma_deg=np.array([2.0]),
        snr_db=np.array([20.0]),
    )


def test_a_slot_goes_out_when_its_time_has_come_stamped_with_that_time() -> None:
    clock = ManualClock(1_000 * MS)
    holder: list[SlotSender] = []
    a, b = Recorder(holder), Recorder(holder)
    sender = SlotSender({"a": a, "b": b}, clock, late_s=0.02)
    holder.append(sender)
    try:
        # queued out of order and across units: they go earliest first
        sender.put(
            [(1_040 * MS, "b", batch_at(1_035 * MS)), (1_020 * MS, "a", batch_at(1_015 * MS))]
        )
        time.sleep(0.05)  # nothing is due yet: nothing may go (a wrong sender sends now)
        assert a.sent == [] and b.sent == []
        clock.now_ns = 1_020 * MS
        assert a.wait_for(1) == [(1_015 * MS, 1_020 * MS)]  # stamped with its slot's time
        time.sleep(0.05)
        assert b.sent == []
        clock.now_ns = 1_100 * MS  # 60 ms after b's slot: it goes at once, counted late
        assert b.wait_for(1) == [(1_035 * MS, 1_040 * MS)]
        sender.put([(1_120 * MS, "a", batch_at(1_110 * MS))])
    finally:
        clock.now_ns = 2_000 * MS
        sender.close()  # publishes what is still queued
    assert a.wait_for(2)[1] == (1_110 * MS, 1_120 * MS)
    assert sender.stats.groups == 3
    assert sender.stats.late == 2  # b's 60 ms and the last one's 880 ms behind their times
    assert sender.stats.late_max_s == pytest.approx(0.88)
    sender.check()


def test_a_failing_publisher_stops_the_sender_and_is_reported() -> None:
    class Broken:
        def on_bearings(self, batch: BearingBatch) -> None:
            raise RuntimeError("socket gone")

    clock = ManualClock(5 * MS)
    sender = SlotSender({"a": Broken()}, clock)
    sender.put([(1 * MS, "a", batch_at(1 * MS))])
    deadline = time.monotonic() + WAIT_S
    while sender.error is None and time.monotonic() < deadline:
        time.sleep(0.01)
    with pytest.raises(RuntimeError, match="socket gone"):
        sender.check()
    sender.close()


def test_bearings_between_ticks_make_a_quick_step_at_the_next_point_of_the_slot_grid() -> None:
    c = Cadence(step_ns=100 * MS, slot_ns=20 * MS, now_ns=0)
    assert c.wait_ns(0) == 100 * MS
    assert c.due(50 * MS) is None  # nothing arrived: wait for the tick
    c.bearings()
    assert c.wait_ns(50 * MS) == 0  # the slot grid's point after the start has passed
    assert c.due(50 * MS) == "quick"
    # bearings 5 ms after that step: due at the next point of the grid, 60 ms,
    # without more bearings
    c.bearings()
    assert c.due(55 * MS) is None
    assert c.wait_ns(55 * MS) == 5 * MS
    assert c.due(60 * MS) == "quick"
    assert c.due(70 * MS) is None  # nothing new since
    assert c.wait_ns(70 * MS) == 30 * MS
    assert c.due(100 * MS) == "tick"
    c.bearings()
    assert c.due(110 * MS) is None  # within the tick's slot
    assert c.due(120 * MS) == "quick"


def test_a_late_tick_is_made_once_and_the_next_keeps_the_beat() -> None:
    c = Cadence(step_ns=100 * MS, slot_ns=20 * MS, now_ns=0)
    assert c.due(350 * MS) == "tick"  # ticks at 100, 200, 300 were missed: one step
    assert c.due(399 * MS) is None
    assert c.due(400 * MS) == "tick"


def states(t_ns: int) -> VehicleStates:
    z = np.zeros(1)
    return VehicleStates(t_ns, ("car",), z, z, z, z, z + 4.5, z + 1.8)


def test_vehicle_states_are_used_from_their_own_time_on() -> None:
    held = StatesByTime()
    assert held.at(0) is None
    for t in (100, 200, 300):
        held.add(states(t * MS))
    assert held.at(50 * MS) is None  # the first states are of the future
    first = held.at(100 * MS)
    assert first is not None and first.t_ns == 100 * MS
    newest = held.at(250 * MS)
    assert newest is not None and newest.t_ns == 200 * MS
    last = held.at(10_000 * MS)
    assert last is not None and last.t_ns == 300 * MS
    assert held.at(10_100 * MS) is last  # nothing newer: the last ones still hold


def test_every_kernel_of_a_backend_step_is_loaded_before_the_run() -> None:
    from rfsas_hw.backend import _encounter_kernel, _tracking_kernel, _triangulation_kernel

    warm_kernels(BackendConfig())
    for kernel in (
        _tracking_kernel.update,
        _tracking_kernel.predict,
        _triangulation_kernel.solve,
        _encounter_kernel.encounter_geometry,
    ):
        assert kernel.signatures, kernel


def test_the_simulation_runs_ahead_of_the_clock_by_a_bounded_lead() -> None:
    assert LiveConfig().lead_s >= 0.2 - 1e-9  # the step's CPU time is not in a frame's latency
    with pytest.raises(ValueError, match="lead_s"):
        LiveConfig(lead_s=-0.1)
    with pytest.raises(ValueError, match="lead_s"):
        LiveConfig(lead_s=2.0)


def test_a_held_vehicle_hears_its_next_brake_before_its_hold_ends() -> None:
    cfg = LiveConfig()
    assert cfg.brake_repeat_s < cfg.hold_s and cfg.brake_repeat_s <= cfg.repeat_s
    with pytest.raises(ValueError, match="brake_repeat_s"):
        LiveConfig(hold_s=0.5, brake_repeat_s=0.5)
    with pytest.raises(ValueError, match="brake_repeat_s"):
        LiveConfig(repeat_s=0.3, brake_repeat_s=0.4)


def test_a_backend_that_does_not_take_its_states_gets_none_until_it_has() -> None:
    flow = StatesFlow(t0_ns=0, backlog_s=0.5)
    for k in range(1, 7):  # be-1 takes nothing: 0.1 … 0.6 s are given
        assert flow.may_send("be-1", k * 100 * MS)
        assert flow.may_send("be-2", k * 100 * MS)
        flow.taken("be-2", k * 100 * MS)
    # be-1 has 0.6 s of states untaken: held back, and counted; be-2 goes on
    assert not flow.may_send("be-1", 700 * MS)
    assert not flow.may_send("be-1", 800 * MS)
    assert flow.may_send("be-2", 700 * MS)
    assert flow.held == 2
    flow.taken("be-1", 300 * MS)  # an old acknowledgement: still 0.3 s untaken
    assert flow.may_send("be-1", 900 * MS)
    flow.taken("be-1", 200 * MS)  # acknowledgements never go back
    flow.taken("be-1", 900 * MS)
    assert flow.may_send("be-1", 1_000 * MS)
    assert flow.held == 2


def test_the_ticks_fall_on_the_clocks_grid_whatever_the_start() -> None:
    # two backends started at different times tick at the same phase of the clock,
    # 5 ms after a multiple of the step (after the end of a 20 ms slot)
    for start in (1_234 * MS, 1_203 * MS, 1_205 * MS, 1_299 * MS):
        c = Cadence(step_ns=100 * MS, slot_ns=20 * MS, now_ns=start, phase_ns=5 * MS)
        assert c.next_ns % (100 * MS) == 5 * MS and start < c.next_ns <= start + 100 * MS
        tick = c.next_ns
        assert c.due(tick - 1) is None and c.due(tick) == "tick"
        # the next slot ends 15 ms after the tick and its bearings arrive 2 ms later:
        # they wait 3 ms for the step (5 ms after the slot's end)
        c.bearings()
        assert c.due(tick + 17 * MS) is None
        assert c.wait_ns(tick + 17 * MS) == 3 * MS
        assert c.due(tick + 20 * MS) == "quick"


@pytest.mark.parametrize("slot_ms", [20, 40, 50])
def test_a_slots_bearings_wait_only_for_the_phase_whatever_the_slot(slot_ms: int) -> None:
    # bearings that arrive 2 ms after the end of any slot are stepped on 3 ms later
    # (5 ms after the slot's end), also when the slot does not divide the tick's step
    c = Cadence(step_ns=100 * MS, slot_ns=slot_ms * MS, now_ns=1_000 * MS, phase_ns=5 * MS)
    stepped = []
    for end in range(1_000 + slot_ms, 2_000, slot_ms):
        if c.next_ns <= end * MS:  # the ticks in between, on time
            assert c.due(c.next_ns) == "tick"
        c.bearings()
        assert c.wait_ns(end * MS + 2 * MS) == 3 * MS
        assert c.due(end * MS + 2 * MS) is None
        what = c.due(end * MS + 5 * MS)
        stepped.append(what)
    # every slot stepped on, once: as a quick step, or as the tick that fell just then
    assert all(w is not None for w in stepped)
    assert stepped.count("quick") >= len(stepped) * (1 - slot_ms / 100) - 1


def test_a_late_quick_step_is_made_at_once_and_the_next_keeps_the_slot_grid() -> None:
    c = Cadence(step_ns=100 * MS, slot_ns=40 * MS, now_ns=10 * MS, phase_ns=5 * MS)
    assert c.due(105 * MS) == "tick"
    c.bearings()  # a slot's bearings that came late (the backend busy): at once
    assert c.wait_ns(131 * MS) == 0 and c.due(131 * MS) == "quick"
    c.bearings()  # at most one step per slot: the next point of the grid, 165 ms
    assert c.due(150 * MS) is None
    assert c.wait_ns(150 * MS) == 15 * MS
    assert c.due(165 * MS) == "quick"


def test_a_slot_older_than_the_receivers_limit_is_shed_not_published() -> None:
    clock = ManualClock(1_000 * MS)
    holder: list[SlotSender] = []
    a = Recorder(holder)
    with pytest.raises(ValueError, match="shed_after_s"):
        SlotSender({"a": a}, clock, late_s=0.02, shed_after_s=0.02)
    sender = SlotSender({"a": a}, clock, late_s=0.02, shed_after_s=1.0)
    holder.append(sender)
    try:
        clock.now_ns = 2_500 * MS  # the loop 1.5 s behind: the first slot is past the limit
        sender.put([(1_000 * MS, "a", batch_at(995 * MS)), (1_600 * MS, "a", batch_at(1_590 * MS))])
        # the second, 0.9 s behind, still goes (late), the first never
        assert a.wait_for(1) == [(1_590 * MS, 1_600 * MS)]
    finally:
        sender.close()
    assert a.sent == [(1_590 * MS, 1_600 * MS)]
    assert sender.stats.shed == 1 and sender.stats.groups == 1 and sender.stats.late == 1
    assert sender.stats.late_max_s == pytest.approx(0.9)
    sender.check()
