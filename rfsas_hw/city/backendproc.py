"""A district backend process: a :class:`~rfsas_hw.apps.backend.BackendApp` that advises every
vehicle in its tiles.

The backend listens on the broker for the bearing topics of its tiles (the tile
plan) and for its own nonce topic, verifies, associates, triangulates and
tracks as ``rfsas backend`` does. What differs is the vehicle side: a district
backend judges every vehicle in its tiles, not one. Every 0.1 s

1. the service steps (fixes, tracks) — :meth:`BackendService.step`;
2. for each vehicle in its tiles (the states the vehicles report, arriving on a
   pipe from the simulator, which stands for their cooperative-awareness
   messages), the live emitters within :attr:`BackendWork.near_m` are judged
   against that vehicle — every such vehicle of the step in one batch
   (:meth:`BackendService.assess_many`: the tracks predicted once, every
   vehicle–emitter pair in one call of the same encounter model, each pair as it
   would be judged alone) —, and the assessments are signed and published on
   that vehicle's own topic ``rfsas/v1/vehicle/<id>/advisory`` through a
   per-vehicle :class:`~rfsas_hw.fleet.advisory.AdvisorySink` (its limits hold
   per vehicle).

Between two ticks, bearings verified since the last step make the service step
again just after the end of the sensors' slot they came in (:attr:`BackendWork.slot_s`,
at most once per slot; a new fix does not wait for the tick), and the vehicles
near an emitter it fixed are judged at once. The vehicles' states arrive ahead
of their time (the simulation runs ahead of the clock); each is used from its
own time on, never before.
Every batch of states taken from the pipe is acknowledged (``("states",
t_ns)``), so that the main process can tell a backend that does not read them
and hold them back instead of blocking on a full pipe.

When an advisory carries a fix made in this step, the process tells the main
process (over the pipe) its vehicle, sequence numbers, that fix's time (the
newest frame it was made of) and when the step began, so the frame → advisory
latency, and where it went (:class:`~rfsas_hw.city.latency.LatencyParts`), is
measured where the vehicle receives it, once per fix and vehicle (the repeats of
a track's state in later steps would measure the track's age, not the path).
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Literal

import numpy as np

from rfsas_hw.apps.backend import BackendApp, BackendAppConfig, SettingsOverrides
from rfsas_hw.backend.encounter import assess_encounters
from rfsas_hw.backend.risk import ADVISORY_RANK
from rfsas_hw.backend.service import BackendConfig
from rfsas_hw.backend.tracking import Tracker, predict_tracks
from rfsas_hw.backend.triangulation import triangulate_batch
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.city.clock import SimClock, cpu_s
from rfsas_hw.city.handshake import answer_failure
from rfsas_hw.city.slots import SLOT_S
from rfsas_hw.fleet.advisory import AdvisorySink
from rfsas_hw.fleet.advisory_limits import AdvisoryLimiter, AdvisoryLimits
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link.mqtt import open_mqtt
from rfsas_hw.link.topics import TopicRouter
from rfsas_hw.records import emitter_hex

NS_PER_S = 1_000_000_000

__all__ = [
    "BackendWork",
    "Cadence",
    "Reach",
    "StatesByTime",
    "VehicleStates",
    "backend_main",
    "fresh_first",
    "nothing_due",
    "tick_phase_s",
    "warm_kernels",
]


@dataclass(frozen=True)
class BackendWork:
    """What one district backend runs."""

    backend_id: str
    keys_dir: Path
    """Its key directory (trusts every unit and the authority)."""
    listen_url: str
    """Broker URL with its certificate, its tiles (``tiles=``) and nonce topic (``nonces=``)."""
    advise_url: str
    """Broker URL it publishes advisories with."""
    origin: SiteOrigin
    """Site origin of the rfsas frame."""
    settings: BackendConfig
    """The service's settings (association, tracking, encounter)."""
    epoch_s: float
    """Nonce epoch length, seconds."""
    near_m: float = 60.0
    """Emitters farther than this from a vehicle are not judged against it, metres."""
    reach_margin_m: float | None = 15.0
    """An emitter is judged against a vehicle only while they could meet within the
    encounter model's horizon: closer than (the vehicle's speed + the emitter's tracked
    speed) × ``horizon_s`` + this margin (:class:`Reach`), metres; None: within
    :attr:`near_m` alone. A vehicle last told more than ``clear`` about an emitter is
    judged against it within :attr:`near_m` until it has been told ``clear``."""
    slot_s: float = SLOT_S
    """The sensors' slot: between ticks, the service steps when bearings arrived, at
    most once per slot, on the slot grid (:class:`Cadence`), seconds."""
    tick_phase_s: float = 0.005
    """The ticks and the quick steps fall this long after their grid on the clock (whole
    multiples of the step, 0.1 s, and of the slot): just after a slot's end, when its
    bearings have arrived (:class:`Cadence`), seconds."""
    repeat_s: float = 1.0
    """Unchanged (or milder) advice about an emitter goes to a vehicle again after this
    long, seconds."""
    brake_repeat_s: float = 0.5
    """After a BRAKE about an emitter, its advice goes to the vehicle again after this
    long, seconds (``AdvisoryLimits.brake_interval_s``)."""
    ride_along_s: float = 0.25
    """Unchanged advice sent at least this long ago goes with any advisory to the same
    vehicle, so that its repeats travel together (``AdvisoryLimits.ride_along_s``),
    seconds."""
    clock: SimClock = field(default_factory=lambda: SimClock(0))
    """The deployment's clock."""
    dashboard: bool = False
    """Also report, every 0.1 s step, the service's fixes made since the last report and
    its assessments (tracks), for a live dashboard of the district."""


@dataclass(frozen=True)
class Reach:
    """Which emitters a vehicle could meet within the encounter model's horizon.

    Both move at constant velocity in the encounter model
    (:mod:`rfsas_hw.backend.encounter`), so within ``horizon_s`` a vehicle at speed
    ``u`` and an emitter at speed ``w`` close in by at most ``(u + w)·horizon_s``; one
    farther than that plus ``margin_m`` (the two boxes and the position errors) is
    judged ``clear`` by its geometry, and is not judged. An emitter of unknown speed
    (not tracked) is judged within the fixed distance as before, and so is every
    emitter in ``owed`` of a vehicle (it was last told more than ``clear`` about it:
    it gets its ``clear``).
    """

    horizon_s: float
    """The encounter model's horizon, seconds."""
    margin_m: float
    """Metres added to the distance they close in by."""
    emitter_speed_mps: np.ndarray
    """Per emitter, its tracked speed, m/s (NaN: unknown)."""
    owed: dict[str, set[str]] = field(default_factory=dict)
    """Per vehicle id, the emitters (16 hex digits) it was last told more than ``clear``
    about."""


@dataclass(frozen=True)
class VehicleStates:
    """The vehicles in a backend's tiles at one moment (rfsas frame, box centres)."""

    t_ns: int
    """UTC time of the states, ns."""
    ids: tuple[str, ...]
    x_m: np.ndarray
    y_m: np.ndarray
    heading_deg: np.ndarray
    """Compass degrees."""
    speed_mps: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray

    def within(
        self,
        emitters: np.ndarray,
        x_m: np.ndarray,
        y_m: np.ndarray,
        near_m: float,
        reach: Reach | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per (vehicle, emitter) — emitter ids ``emitters`` at ``x_m``, ``y_m`` (rfsas
        frame, metres) —, whether the emitter is closer than ``near_m`` metres to the
        vehicle's box centre (V × E), and of those the pairs to judge: all of them
        without ``reach``, with it those within the vehicle's reach (:class:`Reach`)."""
        # every vehicle against every emitter at once
        d2 = (x_m[None, :] - self.x_m[:, None]) ** 2 + (y_m[None, :] - self.y_m[:, None]) ** 2
        close = d2 < near_m**2
        if reach is None:
            return close, close
        speed = np.maximum(self.speed_mps, 0.0)
        limit = (speed[:, None] + reach.emitter_speed_mps[None, :]) * reach.horizon_s
        limit += reach.margin_m
        # an emitter of unknown speed (NaN limit) is judged within near_m
        judged = close & ~(d2 >= limit * limit)
        if reach.owed:
            row = {v: i for i, v in enumerate(self.ids)}
            col = {emitter_hex(e): j for j, e in enumerate(emitters.tolist())}
            for vid, owed in reach.owed.items():
                i = row.get(vid)
                if i is None:
                    continue
                for e in owed:
                    j = col.get(e)
                    if j is not None and close[i, j]:
                        judged[i, j] = True
        return close, judged

    def near(
        self, emitters: np.ndarray, judged: np.ndarray, now_ns: int
    ) -> list[tuple[int, VehicleState, list[int]]]:
        """The vehicles with an emitter (ids ``emitters``) to judge (``judged``, V × E, as
        :meth:`within` gives it): per such vehicle, in the order of :attr:`ids`, its
        index, its state at ``now_ns`` (UTC ns; moved along its heading at its speed
        since :attr:`t_ns`) and those emitters' ids."""
        out = []
        for i in np.flatnonzero(judged.any(axis=1)).tolist():
            vehicle = VehicleState(
                x_m=float(self.x_m[i]),
                y_m=float(self.y_m[i]),
                heading_deg=float(self.heading_deg[i]) % 360.0,
                speed_mps=max(float(self.speed_mps[i]), 0.0),
                length_m=float(self.length_m[i]),
                width_m=float(self.width_m[i]),
                t_ns=self.t_ns,
            ).at(now_ns)
            out.append((i, vehicle, emitters[judged[i]].tolist()))
        return out


@dataclass
class BackendCounters:
    """What a district backend did."""

    stats: dict[str, int] = field(default_factory=dict)
    """The service's and the link's counters (:meth:`BackendApp.stats`)."""
    advisories_sent: int = 0
    advisories_failed: int = 0
    vehicles_judged: int = 0
    """Vehicle-steps with at least one emitter near."""
    vehicles_unchanged: int = 0
    """Vehicle-steps not judged: every emitter near them untracked and told them within
    its repeat interval, so nothing would have gone out."""
    out_of_reach: int = 0
    """Vehicle-steps with an emitter within ``near_m`` but none within reach, not judged
    (:attr:`BackendWork.reach_margin_m`)."""
    pairs_out_of_reach: int = 0
    """(Vehicle, emitter) pairs within ``near_m`` not judged, out of reach."""
    judge_s: float = 0.0
    """Wall time spent judging vehicles, seconds."""
    cpu_s: float = 0.0
    problems: list[str] = field(default_factory=list)


def tick_phase_s(
    index: int, count: int, step_s: float, slot_s: float = SLOT_S, after_s: float = 0.005
) -> float:
    """The tick phase (:attr:`BackendWork.tick_phase_s`) of backend ``index`` of
    ``count``: the backends' ticks spread over the slots of a ``step_s`` step (every
    one judges all its vehicles at its tick, and two at once would queue for the same
    cores), each ``after_s`` after the end of a slot of ``slot_s``, seconds.

    Raises:
        ValueError: ``index`` not in ``[0, count)``, or a step shorter than a slot.
    """
    if not 0 <= index < count or step_s < slot_s:
        raise ValueError(f"need 0 <= index < count and step_s >= slot_s, got {index}, {count}")
    slots = max(1, round(step_s / slot_s))
    return index * slots // count * slot_s + after_s


def warm_kernels(settings: BackendConfig) -> None:
    """Load (or compile, the first time on a machine) every numeric kernel a backend's
    step uses — triangulation, the tracker's update and prediction, the encounter
    model — before the run: a first fix must not wait for them (seconds, during
    which the backend takes no bearings)."""
    assess_encounters(
        VehicleState(x_m=0.0, y_m=-30.0, heading_deg=0.0, speed_mps=10.0),
        np.array([[0.0, 0.0, 1.0, 0.0]]),
        np.eye(4)[None, :, :],
        settings.encounter,
    )
    stations = np.array([[[-10.0, 0.0], [10.0, 0.0]]])
    triangulate_batch(
        stations, np.array([[45.0, 315.0]]), np.array([[2.0, 2.0]]), settings.triangulation
    )
    # a track started, then updated, then predicted
    tracker = Tracker(settings.tracker)
    for t_ns in (NS_PER_S, 2 * NS_PER_S):
        tracker.update_many([1], [t_ns], np.zeros((1, 2)), np.eye(2)[None], [("a", "b")])
    predict_tracks(list(tracker.tracks.values()), 3 * NS_PER_S, settings.tracker.accel_sigma_mps2)


class StatesByTime:
    """Vehicle states that arrive ahead of their time (the simulation runs ahead of the
    clock), each used from its own time on: a backend learns where a vehicle is when
    the vehicle says so, not earlier."""

    def __init__(self) -> None:
        self.current: VehicleStates | None = None
        self.coming: deque[VehicleStates] = deque()
        """States not of now yet, oldest first."""

    def add(self, states: VehicleStates) -> None:
        """Take states that arrived (in time order, as the simulation steps)."""
        self.coming.append(states)

    def at(self, now_ns: int) -> VehicleStates | None:
        """The newest states of ``now_ns`` (UTC ns) or before; None before the first."""
        while self.coming and self.coming[0].t_ns <= now_ns:
            self.current = self.coming.popleft()
        return self.current


class Cadence:
    """When a district backend steps: every ``step_ns`` (a tick: every vehicle near a
    live emitter is judged), and between ticks on the sensors' slot grid once bearings
    were verified since the last step (a quick step: the vehicles near a new fix are
    judged at once). Times are UTC ns of the deployment's clock.

    Both fall ``phase_ns`` after the grid they follow, just after a slot's bearings
    have arrived: the ticks after whole multiples of ``step_ns``, the quick steps
    after whole multiples of ``slot_ns`` (the sensors publish each slot when it is
    over, :data:`~rfsas_hw.city.slots.SLOT_S`), at most one step per slot, and the
    first point of that grid after the last step at the earliest. A phase of the
    backend's own start would make every slot's bearings wait for it.

    Args:
        step_ns: time between ticks, ns.
        slot_ns: the sensors' slot, ns: bearings arrive on its grid.
        now_ns: now; the first tick is the first of the grid after it.
        phase_ns: the offset of both grids from the multiples of ``step_ns`` and
            ``slot_ns``, ns.
    """

    def __init__(self, step_ns: int, slot_ns: int, now_ns: int, phase_ns: int = 0) -> None:
        self.step_ns = step_ns
        self.slot_ns = slot_ns
        self.phase_ns = phase_ns
        self.next_ns = self._after(now_ns, step_ns)
        """The next tick."""
        self.quick_at_ns = self._after(now_ns, slot_ns)
        """The earliest quick step: the first point of the slot grid after the last step."""
        self.unstepped = False
        """Bearings were verified since the last step."""

    def _after(self, now_ns: int, grid_ns: int) -> int:
        """The first point of the grid of ``grid_ns`` (at its phase) after ``now_ns``."""
        return (now_ns - self.phase_ns) // grid_ns * grid_ns + grid_ns + self.phase_ns

    def bearings(self) -> None:
        """Bearings were verified."""
        self.unstepped = True

    def wait_ns(self, now_ns: int) -> int:
        """How long to wait for bearings before the next step may be due, ns (≥ 0)."""
        due = self.next_ns
        if self.unstepped:
            due = min(due, self.quick_at_ns)
        return max(due - now_ns, 0)

    def due(self, now_ns: int) -> Literal["tick", "quick"] | None:
        """The step due at ``now_ns`` (then counted as made), or None."""
        if now_ns >= self.next_ns:
            # a tick missed (a long step) is not made up for
            self.next_ns += self.step_ns * max(1, math.ceil((now_ns - self.next_ns) / self.step_ns))
            what: Literal["tick", "quick"] = "tick"
        elif self.unstepped and now_ns >= self.quick_at_ns:
            what = "quick"
        else:
            return None
        self.quick_at_ns = self._after(now_ns, self.slot_ns)
        self.unstepped = False
        return what


class CityBackend:
    """One district backend (see the module docstring); :meth:`run` until told to stop.

    Raises (from the constructor):
        as :class:`BackendApp`, and LinkError when the broker cannot be reached.
    """

    def __init__(self, work: BackendWork) -> None:
        self.work = work
        self.clock = work.clock
        self.app = BackendApp(
            BackendAppConfig(
                listen=(work.listen_url,),
                keys_dir=work.keys_dir,
                settings=work.settings,
                overrides=SettingsOverrides(epoch_s=work.epoch_s, origin=work.origin),
            ),
            clock=self.clock,
        )
        try:
            self.transport = open_mqtt(work.advise_url, "send")
        except BaseException:
            self.app.close()
            raise
        # a unit falls silent whenever no phone is near it: its link's state changes are
        # counted (link.latency.to_*), not a warning each
        watch = self.app.receiver.latency
        watch.config = replace(watch.config, log_changes=False)
        self.router = TopicRouter(work.origin)
        self.home_tile = self.router.tile_of(0.0, 0.0)
        self.signer = self.app.store.signer()
        self.sinks: dict[str, AdvisorySink] = {}
        self.vehicles = StatesByTime()
        """The vehicles' states, each used from its own time on."""
        self.counters = BackendCounters()
        self._new_fixes: list[Any] = []
        """The trustworthy fixes the service's steps made since :meth:`new_fixes`."""
        self._shown: dict[int, Any] = {}
        """The fixes as they were at the last dashboard report."""

    def warm(self) -> None:
        """Load (or compile, the first time on a machine) the numeric kernels before the
        run (:func:`warm_kernels`)."""
        warm_kernels(self.app.service.config)

    def _sink(self, vehicle_id: str) -> AdvisorySink:
        sink = self.sinks.get(vehicle_id)
        if sink is None:
            sink = AdvisorySink(
                self.signer,
                self.transport,
                self.router,
                self.home_tile,
                vehicle_id=vehicle_id,
                epoch_s=self.work.epoch_s,
                clock=self.clock,
                limits=AdvisoryLimits(
                    min_interval_s=self.work.repeat_s,
                    ride_along_s=self.work.ride_along_s,
                    brake_interval_s=self.work.brake_repeat_s,
                ),
                monotonic=lambda: self.clock() / NS_PER_S,
                tile_topics=False,
            )
            self.sinks[vehicle_id] = sink
        return sink

    def new_fixes(self) -> list[tuple[int, str, float, float, float]]:
        """The trustworthy fixes made since the last call (by the service's steps in
        :meth:`judge`): (UTC ns, emitter id, x, y, one-sigma metres from the
        covariance's larger eigenvalue)."""
        out = []
        made, self._new_fixes = self._new_fixes, []
        for fix in made:
            tr = (fix.cov_xx_m2 + fix.cov_yy_m2) / 2
            det = fix.cov_xx_m2 * fix.cov_yy_m2 - fix.cov_xy_m2**2
            sigma = math.sqrt(max(tr + math.sqrt(max(tr * tr - det, 0.0)), 0.0))
            out.append((fix.t_ns, fix.emitter, fix.x_m, fix.y_m, sigma))
        return out

    def judge(self, now_ns: int, fresh_only: bool = False) -> list[tuple[str, int, int, int, int]]:
        """Step the service and advise every vehicle near a live emitter (``fresh_only``:
        near an emitter fixed in this step, judged against those emitters only); per
        advisory that carried a fix made in this step, (vehicle id, first and last
        sequence number, time of that fix's newest frame and ``now_ns``, UTC ns)."""
        service = self.app.service
        # the service's own vehicle is none: its assessments only feed the dashboard
        service.step(now_ns, assess=self.work.dashboard)
        fresh_ns = {e: f.t_ns for e, f in service.stepped.items() if f.ok}
        self._new_fixes += [f for f in service.stepped.values() if f.ok]
        states = self.vehicles.at(now_ns)
        if states is None or not len(states.ids) or not service.fixes:
            self._forget(set() if states is None else set(states.ids))
            return []
        if fresh_only and not fresh_ns:
            return []
        t0 = time.perf_counter()
        emitters, predicted = service.predicted(now_ns, fresh_ns if fresh_only else None)
        chosen = np.isfinite(predicted[:, 0]) & np.isfinite(predicted[:, 1])
        emitters, predicted = emitters[chosen], predicted[chosen]
        out: list[tuple[str, int, int, int, int]] = []
        close, judged = states.within(
            emitters, predicted[:, 0], predicted[:, 1], self.work.near_m, self._reach(predicted)
        )
        if judged is not close:
            self.counters.pairs_out_of_reach += int(close.sum() - judged.sum())
            self.counters.out_of_reach += int((close.any(axis=1) & ~judged.any(axis=1)).sum())
        near = states.near(emitters, judged, now_ns)
        # a vehicle near only untracked emitters, each told to it within its repeat
        # interval, would be sent nothing: not judged (the same advice goes out)
        tracked = set(emitters[np.isfinite(predicted[:, 2])].tolist())
        unlocated = ADVISORY_RANK[service.unlocated_advice()]
        kept = []
        for entry in near:
            sink = self.sinks.get(states.ids[entry[0]])
            if sink is None or not nothing_due(
                sink.limiter, sink.monotonic(), entry[2], tracked, unlocated
            ):
                kept.append(entry)
        self.counters.vehicles_unchanged += len(near) - len(kept)
        for batch in fresh_first(kept, fresh_ns):
            with self.transport.together() as held:  # a batch's advisories in one write
                out += self._advise(states, batch, now_ns, fresh_ns)
            # the sinks counted a message sent when it was held
            self.counters.advisories_failed += held.lost
            self.counters.advisories_sent -= held.lost
        self._forget(set(states.ids))
        self.counters.judge_s += time.perf_counter() - t0
        return out

    def _advise(
        self,
        states: VehicleStates,
        batch: list[tuple[int, VehicleState, list[int]]],
        now_ns: int,
        fresh_ns: dict[int, int],
    ) -> list[tuple[str, int, int, int, int]]:
        """Judge the vehicles of ``batch`` (:meth:`VehicleStates.near`) at ``now_ns`` and
        publish their advice; per advisory that carried a fix made in this step (its
        emitter a key of ``fresh_ns``, with that fix's time), as :meth:`judge` gives it."""
        out: list[tuple[str, int, int, int, int]] = []
        requests = [(vehicle, mine) for _, vehicle, mine in batch]
        service = self.app.service
        for (i, _, _), assessed in zip(batch, service.assess_many(requests, now_ns), strict=True):
            if not assessed:
                continue
            vid = states.ids[i]
            self.counters.vehicles_judged += 1
            sink = self._sink(vid)
            first, sent = sink.seq, sink.stats.messages
            sink.on_results([], assessed)
            n = sink.stats.messages - sent
            if n == 0 or not fresh_ns:
                continue
            fresh = [fresh_ns[e] for e in (int(a.emitter, 16) for a in assessed) if e in fresh_ns]
            if fresh:
                # the advisory that carries a fix made in this step: its latency counts
                out.append((vid, first, (first + n - 1) % (1 << 32), max(fresh), now_ns))
        return out

    def _reach(self, predicted: np.ndarray) -> Reach | None:
        """The reach rule for emitters of predicted states ``predicted`` (rows ``[x, y,
        vx, vy]``), with what each vehicle is owed; None when it is off."""
        if self.work.reach_margin_m is None:
            return None
        owed = {vid: sink.limiter.unsettled for vid, sink in self.sinks.items()}
        return Reach(
            self.app.service.config.encounter.horizon_s,
            self.work.reach_margin_m,
            np.hypot(predicted[:, 2], predicted[:, 3]),
            owed,
        )

    def _forget(self, present: set[str]) -> None:
        """Drop the sinks of vehicles no longer in the tiles (their counts are kept)."""
        for vid in [v for v in self.sinks if v not in present]:
            sink = self.sinks.pop(vid)
            self.counters.advisories_sent += sink.stats.messages
            self.counters.advisories_failed += sink.stats.errors

    def run(self, conn: Connection) -> None:
        """Receive and judge, reporting to ``conn``, until ``None`` arrives on it.

        Every ``step_s`` (0.1 s) every vehicle near a live emitter is judged; between
        those steps, once bearings were verified since the last step, the service
        steps again just after the end of the sensors' slot (:class:`Cadence`) and
        the vehicles near an emitter it fixed are judged against it at once (a new fix
        does not wait for the tick, nor for more bearings).
        """
        receiver = self.app.receiver
        service = self.app.service
        clock = self.clock
        cadence = Cadence(
            int(service.config.step_s * NS_PER_S),
            round(self.work.slot_s * NS_PER_S),
            clock(),
            round(self.work.tick_phase_s * NS_PER_S),
        )
        while True:
            wait_s = clock.wall_s(cadence.wait_ns(clock()) / NS_PER_S)
            got = receiver.receive(timeout=min(wait_s, clock.wall_s(self.work.slot_s)))
            for message in got:
                service.on_verified(message)
            if got:
                cadence.bearings()
            if not self._take_pipe(conn):
                return
            now = clock()
            what = cadence.due(now)
            if what is None:
                continue
            sent = self.judge(now, fresh_only=what == "quick")
            if what == "tick" and self.work.dashboard:
                self._report_dashboard(conn)
            if sent:
                conn.send(("sent", sent))
            fixes = self.new_fixes()
            if fixes:
                conn.send(("fixes", fixes))

    def _take_pipe(self, conn: Connection) -> bool:
        """Take what the main process sent (vehicle states, acknowledged by the time of
        the newest); False when told to stop."""
        newest: int | None = None
        while conn.poll():
            msg: Any = conn.recv()
            if msg is None:
                return False
            self.vehicles.add(msg)
            newest = msg.t_ns
        if newest is not None:
            conn.send(("states", newest))
        return True

    def _report_dashboard(self, conn: Connection) -> None:
        """Send the fixes made since the last report and every current assessment."""
        service = self.app.service
        fixes = [f for e, f in service.fixes.items() if self._shown.get(e) is not f]
        self._shown = dict(service.fixes)
        conn.send(("dashboard", fixes, list(service.assessments.values())))

    def close(self) -> BackendCounters:
        """Close the advisory transport and the app; the counters. Idempotent."""
        self._forget(set())
        self.counters.stats = self.app.stats()
        self.counters.problems = self.app.service.problems()
        self.transport.close()
        self.app.close()
        return self.counters


def nothing_due(
    limiter: AdvisoryLimiter, now_s: float, emitters: list[int], tracked: set[int], unlocated: int
) -> bool:
    """Whether judging a vehicle against ``emitters`` (ids) at ``now_s`` (its limiter's
    monotonic seconds) could send it nothing: every one is untracked (not in
    ``tracked``), so its advice is the rank ``unlocated`` for every vehicle at any time,
    and none of them is due (:meth:`AdvisoryLimiter.due`: each was told to this vehicle,
    as severe, within its repeat interval; without a due item no rider goes either)."""
    return not any(e in tracked or limiter.due(emitter_hex(e), unlocated, now_s) for e in emitters)


def fresh_first(
    near: list[tuple[int, VehicleState, list[int]]], fresh_ns: dict[int, int]
) -> list[list[tuple[int, VehicleState, list[int]]]]:
    """The vehicles to judge (:meth:`VehicleStates.near`) in the order their advice goes:
    first those near an emitter fixed in this step (keys of ``fresh_ns``), whose advice
    carries news, then the others, whose advice is mostly a repeat; each vehicle once."""
    if not fresh_ns:
        return [near]
    first: list[tuple[int, VehicleState, list[int]]] = []
    rest: list[tuple[int, VehicleState, list[int]]] = []
    for entry in near:
        (first if any(e in fresh_ns for e in entry[2]) else rest).append(entry)
    return [batch for batch in (first, rest) if batch]


def backend_main(work: BackendWork, conn: Connection) -> None:
    """The body of a backend process: build, answer ``("warming",)``, load the kernels,
    answer ``("ready",)`` (:mod:`rfsas_hw.city.handshake`), run until ``None``,
    answer ``("end", counters)``; a failure is answered ``("error", message)``."""
    backend: CityBackend | None = None
    try:
        backend = CityBackend(work)
        conn.send(("warming",))  # built: the warm-up is judged by its CPU time
        backend.warm()
        conn.send(("ready",))
        backend.run(conn)
        counters = backend.close()
        backend = None
        counters.cpu_s = cpu_s()
        conn.send(("end", counters))
    except Exception as err:  # reported to the main process, which ends the run
        answer_failure(conn, f"backend {work.backend_id}", err, backend)
    finally:
        conn.close()
