"""A twin worker: the roadside units of some tiles, twinned, their bearings signed onto the broker.

Each worker is a process of its own (:func:`worker_main`). Per simulation step
the main process sends it, over a pipe, the VRUs with a phone near its units
(:class:`Snapshot`); the worker

1. grows the live track of each VRU within ``hear_m`` of one of its units in
   its streaming twin (:class:`~rfsas_hw.twin.stream.StreamTwin`, one for all
   of the worker's units) and gives a newly seen VRU its phone (the device
   model the demand drew for it, the MAC
   :func:`~rfsas_hw.bridges.bridge.device_mac` draws from the seed, a new MAC
   every ``mac.rotate_s`` when the policy says so);
2. computes the frames each unit heard since the previous step — all units in
   one pass of the twin's physics, each unit only the phones within its reach
   (``hear_m`` plus the size of its junction: every phone near a junction is
   heard by all of that junction's units, a phone near another junction costs
   this unit nothing) — and runs each unit's
   :class:`~rfsas_hw.pipeline.SensorPipeline` (calibration, DF, keyed MAC
   hashing with the deployment's epoch nonces from the authority), all units
   in one :func:`~rfsas_hw.pipeline.process_units` call (one field-of-view
   guard for all of them, each unit's emitters under its own key);
3. signs each unit's bearings with that unit's key and publishes them on its
   bearing topic (:class:`~rfsas_hw.link.publisher.Publisher`, version 2 with
   the pre-authentication tag), each in the :data:`~rfsas_hw.city.slots.SLOT_S` slot of its frame's
   time, when that slot is over on the deployment's clock, stamped with that
   time (:class:`~rfsas_hw.city.slots.SlotSender`, a thread of its own): the
   main process runs the simulation ahead of the clock, so a step's frames are
   known before they are "heard" and go out as a sensor would send them, while
   the worker computes the next step. A slot whose time is already further
   behind the clock than the receivers' age limit when it comes up (the loop
   that far behind) is shed, not signed: every backend would refuse it.

Raw MACs exist only inside this process, as in a sensor. The worker answers
every step with ``("step", t_s, frames, bearings)`` so the main process knows it
has kept up, and ``("end", counters)`` when told to stop (``None``).

Why plain processes and not the sweep runner's Dask: a live step is 0.1 s of
simulated time that must be done in 0.1 s of wall time; the work of a tile
stays in one long-lived process with its twin's state (tracks, traffic
generators, random streams), and the only traffic between processes is the
snapshot in and a short acknowledgement out. Dask's task scheduling suits
independent batch runs (a sweep), not a stateful 10 Hz loop; the processes are
joined by the broker, which is the deployment's own transport.
"""

from __future__ import annotations

import datetime as dt
import math
import sys
import threading
import time
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from rfsas_hw.bridges.bridge import device_mac
from rfsas_hw.bridges.config import BridgeConfig, UnitSpec
from rfsas_hw.city.clock import SimClock, cpu_s
from rfsas_hw.city.handshake import answer_failure
from rfsas_hw.city.slots import SLOT_S, SlotSender
from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.fovchannels import ChannelConsistency
from rfsas_hw.df.fovguard import MAX_EMITTERS, FovGuard
from rfsas_hw.link.distribution import NonceInbox
from rfsas_hw.link.keys import KeyStore
from rfsas_hw.link.publisher import Publisher
from rfsas_hw.link.receiver import ReceiverConfig
from rfsas_hw.link.transport import open_transport
from rfsas_hw.pipeline import SensorPipeline, process_units
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.privacy.hashing import MacHasher, NonceUnavailableError
from rfsas_hw.records import BearingBatch, Pose, emitter_hex, int_to_mac
from rfsas_hw.sources.twinstream import StreamTwinSource
from rfsas_hw.twin.rfworld import blockage_db
from rfsas_hw.twin.scenario import (
    BuildingSpec,
    EmitterSpec,
    IntersectionSpec,
    Scenario,
    ScenarioSpec,
    SensorSpec,
)
from rfsas_hw.twin.stream import StreamTwin, extend_tracks

NS_PER_S = 1_000_000_000
NONCE_WAIT_S = 10.0
"""How long a worker waits for the authority's first envelope, seconds."""
TRAFFIC_LOOKAHEAD_S = 4.0
"""How far ahead the twin generates every phone's traffic in one go, seconds. The
frames do not depend on it; each generator's call has a fixed cost (a few dozen numpy
calls), so generating 4 s at a time costs a quarter of generating 1 s at a time."""

SWITCH_INTERVAL_S = 0.0005
"""The worker process's interpreter switch interval (``sys.setswitchinterval``), seconds:
how long the step's thread may keep the interpreter while the sending thread waits."""

__all__ = ["Snapshot", "TileWork", "TwinWorker", "unit_sensor", "utc_text", "worker_main"]


@dataclass(frozen=True)
class TileWork:
    """What one twin worker runs."""

    worker_id: str
    """Name of the worker (for logs and the CPU table)."""
    units: tuple[UnitSpec, ...]
    """Its roadside units (rfsas frame: metres east/north of the site origin)."""
    bridge: BridgeConfig
    """Radio settings, seed, device models and MAC policy (its ``units`` are not used)."""
    buildings: tuple[BuildingSpec, ...]
    """Building footprints near its units, rfsas frame."""
    urls: dict[str, str]
    """Broker URL per unit id (each with that unit's certificate and the site origin)."""
    nonce_url: str
    """Broker URL on which the first unit takes the authority's nonce envelopes."""
    keys: dict[str, Path]
    """Key directory per unit id."""
    epoch_s: float
    """Nonce epoch length, seconds."""
    calibrations: dict[str, Calibration]
    """Calibration per unit id (a unit build is calibrated once, not per worker)."""
    clock: SimClock
    """The deployment's clock."""
    groups: tuple[tuple[str, ...], ...]
    """Unit ids per junction: a phone near a junction is heard by all of its units."""
    hear_m: float = 150.0
    """The twin has the phones this close to one of the worker's units, metres."""


@dataclass(frozen=True)
class Snapshot:
    """The VRUs with a phone near a worker's units at one step (rfsas frame)."""

    t_s: float
    """Simulation time, seconds."""
    t0_ns: int
    """UTC time of simulation time 0, ns (whole microseconds)."""
    ids: tuple[str, ...]
    devices: tuple[str, ...]
    """Device model of each VRU."""
    x_m: np.ndarray
    y_m: np.ndarray
    heading_deg: np.ndarray


@dataclass
class _Phone:
    mover: str
    index: int
    since_s: float
    rotation: int
    mac: int
    reported_epoch: int = -1
    """The last epoch whose emitter id went to the truth."""


@dataclass
class WorkerCounters:
    """What a worker did."""

    steps: int = 0
    frames: int = 0
    bearings: int = 0
    phones: int = 0
    """Phones handed out (each MAC rotation counts again)."""
    sent: int = 0
    """Bearings the publishers sent."""
    slot_groups: int = 0
    """Groups of bearings (a unit's frames of one slot) published."""
    slots_late: int = 0
    """Of them, published more than a slot after their time."""
    slot_late_max_s: float = 0.0
    """The largest delay of a published group behind its time, seconds of the
    deployment's clock."""
    slots_shed: int = 0
    """Groups not published: already older than the receivers' age limit when their
    time came (the loop that far behind its clock)."""
    messages: int = 0
    """Signed messages the publishers sent."""
    send_problems: list[str] = field(default_factory=list)
    cpu_s: float = 0.0
    """The worker process's CPU time, seconds."""


def utc_text(t_ns: int) -> str:
    """ISO 8601 UTC text of ``t_ns`` (whole microseconds, exactly)."""
    when = dt.datetime(1970, 1, 1, tzinfo=dt.UTC) + dt.timedelta(microseconds=t_ns // 1000)
    return when.isoformat(timespec="microseconds").replace("+00:00", "Z")


def _reach(
    units: tuple[UnitSpec, ...], groups: tuple[tuple[str, ...], ...], hear_m: float
) -> dict[str, float]:
    """Per unit id, how far from it a phone is heard: ``hear_m`` plus the largest distance
    from it to another unit of its junction (a phone within ``hear_m`` of one unit of a
    junction is heard by all of them), metres."""
    pos = {u.id: (u.pose.x_m, u.pose.y_m) for u in units}
    reach = dict.fromkeys(pos, hear_m)
    for ids in groups:
        for a in ids:
            span = max(math.dist(pos[a], pos[b]) for b in ids)
            reach[a] = hear_m + span
    return reach


def unit_sensor(u: UnitSpec) -> SensorSpec:
    """The twin's sensor of a roadside unit."""
    return SensorSpec(
        id=u.id,
        kind="roadside",
        pose=u.pose,
        receiver=u.receiver,
        antenna=u.antenna,
        driver=u.driver,
        scan=u.scan,
        threshold_dbm=dict(u.threshold_dbm),
    )


class _UnitsTwin:
    """A worker's units and the phones near them, in one streaming twin.

    Every unit computes the frames of the phones within its reach only
    (:attr:`reach_m`), so one twin for all of a worker's units costs what a twin
    per junction cost, in one pass of the physics per step instead of one per
    junction.
    """

    def __init__(self, worker: TwinWorker) -> None:
        self.worker = worker
        units = worker.work.units
        self.sensors = tuple(unit_sensor(u) for u in units)
        self.x_m = np.array([u.pose.x_m for u in units])
        self.y_m = np.array([u.pose.y_m for u in units])
        self.reach_m = _reach(units, worker.work.groups, worker.work.hear_m)
        """Per unit id: ``hear_m`` plus the largest distance to a unit of its junction, m."""
        self.twin: StreamTwin | None = None
        self.sources: dict[str, StreamTwinSource] = {}
        self.phones: dict[str, _Phone] = {}
        self._visits: dict[str, int] = {}
        self.was_busy = False
        """Whether it had phones at the previous step (their last frames still count)."""

    def near(self, snap: Snapshot, reach_m: float) -> np.ndarray:
        """Indices of the snapshot's VRUs within ``reach_m`` of one of these units."""
        if not snap.ids:
            return np.zeros(0, np.intp)
        d2 = (snap.x_m[:, None] - self.x_m[None, :]) ** 2 + (
            snap.y_m[:, None] - self.y_m[None, :]
        ) ** 2
        return np.flatnonzero(d2.min(axis=1) < reach_m**2)

    def start(self, t_s: float, t0_ns: int) -> StreamTwin:
        work = self.worker.work
        cfg = work.bridge
        spec = ScenarioSpec(
            version=1,
            name=work.worker_id,
            seed=cfg.seed,
            duration_s=1.0,
            sensors=self.sensors,
            emitters=(),
            intersection=IntersectionSpec(buildings=work.buildings),
            rf=cfg.rf,
            detail=cfg.detail,
            start_utc=utc_text(t0_ns),
        )
        scenario = Scenario(spec=spec, source=f"<{work.worker_id}>", base_dir=Path.cwd())
        self.twin = StreamTwin(
            scenario, start_s=t_s, reach_m=self.reach_m, lookahead_s=TRAFFIC_LOOKAHEAD_S
        )
        for sensor in self.sensors:
            self.sources[sensor.id] = StreamTwinSource(self.twin, sensor.id)
        return self.twin

    def _give_phone(self, twin: StreamTwin, vru: str, mover: str, model: str, t_s: float) -> None:
        cfg = self.worker.work.bridge
        held = self.phones.get(vru)
        rotation = 0 if held is None else held.rotation + 1
        device = cfg.device_model(model)
        mac = device_mac(cfg, vru, rotation)
        while np.any(twin.emitter_macs == np.uint64(mac)):
            mac = (mac + 1) & ((1 << 48) - 1)
        index = twin.add_emitter(
            EmitterSpec(
                id=f"{mover}#{rotation}",
                mac=int_to_mac(mac),
                tech=device.tech,
                traffic=device.traffic,
                tx_power_dbm=device.tx_power_dbm,
                antenna_gain_dbi=device.antenna_gain_dbi,
                carried_by=mover,
            ),
            start_s=t_s,
        )
        self.phones[vru] = _Phone(mover, index, t_s, rotation, mac)
        self.worker.counters.phones += 1

    def update(self, snap: Snapshot, idx: np.ndarray) -> None:
        """Move the phones of the snapshot's rows ``idx``; the others have left."""
        twin = self.twin
        assert twin is not None
        t_s = snap.t_s
        rotate = self.worker.work.bridge.mac.rotate_s
        rows = idx.tolist()
        present = {snap.ids[i] for i in rows}
        for vru in [v for v in self.phones if v not in present]:
            twin.retire_emitter(self.phones.pop(vru).index, t_s)
        tracks = []
        for i in rows:
            vru = snap.ids[i]
            phone = self.phones.get(vru)
            if phone is None:
                # a VRU that comes back into range walks on as a new mover (the twin's
                # tracks only grow), with a phone of the same model
                visit = self._visits.get(vru, 0)
                self._visits[vru] = visit + 1
                mover = f"{vru}@{visit}"
                tracks.append(twin.add_mover(mover))
                self._give_phone(twin, vru, mover, snap.devices[i], t_s)
                continue
            tracks.append(twin.live[phone.mover])
            if rotate is not None and t_s - phone.since_s >= rotate:
                twin.retire_emitter(phone.index, t_s)
                self._give_phone(twin, vru, phone.mover, snap.devices[i], t_s)
        # every track's knot of this step in one go
        extend_tracks(tracks, t_s, snap.x_m[idx], snap.y_m[idx], snap.heading_deg[idx])

    def close(self) -> None:
        for src in self.sources.values():
            src.close()
        self.sources.clear()


class TwinWorker:
    """The units of some junctions (see the module docstring); driven by :meth:`step`.

    Raises (from the constructor):
        KeyStoreError: a unit's key directory is unusable.
        LinkError: the broker cannot be reached.
        CalibrationError: a unit's turntable fit fails.
    """

    def __init__(self, work: TileWork) -> None:
        self.work = work
        self.counters = WorkerCounters()
        self.t0_ns = 0
        self._started = False
        self._now_ns = 0
        """Simulation time of the last step, UTC ns."""
        self.air = _UnitsTwin(self)
        """The worker's units and the phones near them, twinned."""
        self.publishers: dict[str, Publisher] = {}
        self.sender = SlotSender(
            self.publishers, work.clock, late_s=SLOT_S, shed_after_s=ReceiverConfig().max_age_s
        )
        """Publishes each slot's bearings when its time has come."""
        first = work.units[0].id
        store = KeyStore.open(work.keys[first])
        schedule = EpochSchedule(work.epoch_s, min(5.0, work.epoch_s / 4))
        self.inbox = NonceInbox(
            store.nonce_store(schedule, work.clock),
            open_transport(work.nonce_url, "recv"),
            # envelopes are checked against the deployment's clock (the simulation is
            # paced to it and its step times are not known yet)
            clock=work.clock,
            wait_s=NONCE_WAIT_S,
        )
        # the first nonce is waited for here; afterwards a missing one holds the frames
        # in the pipeline (as a live sensor does) instead of stopping the worker
        self.inbox.nonce_for(schedule.epoch_of(work.clock()))
        self.inbox.wait_s = 0.0
        self.nonces = _SharedNonces(self.inbox)
        """The inbox as the pipelines (this thread) and the publishers (the sender's) ask it."""
        self.hasher = MacHasher(self.nonces, work.epoch_s)
        self.pipelines: dict[str, SensorPipeline] = {}
        # one field-of-view guard for all units (each unit's emitters under its own key),
        # so that the level rule judges every unit's frames of a step in one pass
        most = MAX_EMITTERS * len(work.units)
        guard = FovGuard(max_emitters=most, channels=ChannelConsistency(max_emitters=most))
        for k, u in enumerate(work.units):
            pose = Pose(u.pose.x_m, u.pose.y_m, u.pose.heading_deg)
            self.pipelines[u.id] = SensorPipeline(
                work.calibrations[u.id],
                self.hasher,
                u.id,
                pose,
                fov_guard=guard,
                guard_key=(k + 1) << 48,
            )
            signer = KeyStore.open(work.keys[u.id]).signer()
            self.publishers[u.id] = Publisher.to_url(
                work.urls[u.id],
                signer,
                pose,
                epoch_s=work.epoch_s,
                clock=self.sender.stamp_ns,
                preauth=self.nonces,
            )
        self._reported: dict[tuple[str, int], int] = {}

    def warm(self) -> None:
        """Load the twin's compiled loop of blockage (compile it, the first time in a source tree)
        now, not in the first step with phones."""
        blockage_db(np.zeros((1, 2)), np.ones((1, 2)), np.array([[0.25, 0.75, 0.25, 0.75, 1.0]]))

    def truth(self) -> list[tuple[str, str]]:
        """(emitter id, VRU id) of every phone whose id in this epoch was not told yet.

        The truth of who carries which emitter, for scoring beside the backends (it
        never goes to them); a phone whose epoch nonce has not arrived is told later.
        """
        out = []
        epoch = self._now_ns // self.hasher.epoch_ns
        for vru, phone in self.air.phones.items():
            if phone.reported_epoch == epoch:
                continue
            try:
                emitter = self.hasher.hash_one(phone.mac, self._now_ns)
            except NonceUnavailableError:
                continue
            phone.reported_epoch = epoch
            if self._reported.get((vru, phone.mac)) != epoch:
                self._reported[(vru, phone.mac)] = epoch
                out.append((emitter_hex(emitter), vru))
        return out

    def step(self, snap: Snapshot) -> tuple[int, int]:
        """Advance to ``snap.t_s``; the frames heard and bearings sent in this step."""
        first = not self._started
        if first:
            self._started = True
            self.t0_ns = snap.t0_ns
            self.air.start(snap.t_s, snap.t0_ns)
        self._now_ns = self.t0_ns + round(snap.t_s * NS_PER_S)
        air = self.air
        air.update(snap, air.near(snap, self.work.hear_m))
        self.counters.steps += 1
        if first:
            return 0, 0
        frames = bearings = 0
        slot_ns = round(SLOT_S * NS_PER_S)
        due_groups: list[tuple[int, str, BearingBatch]] = []
        if air.phones or air.was_busy:  # else nothing near, nothing in flight
            air.was_busy = bool(air.phones)
            assert air.twin is not None
            air.twin.prepare(snap.t_s)
            heard = []
            for sid, src in air.sources.items():
                src.horizon_s = snap.t_s
                obs = src.read()
                if obs is not None and len(obs):
                    heard.append((sid, obs))
                    frames += len(obs)
            # every unit's frames through its pipeline in one call (DF and the level
            # rule once for all units)
            batches = process_units([(self.pipelines[sid], obs) for sid, obs in heard])
            for (sid, _), batch in zip(heard, batches, strict=True):
                bearings += len(batch)
                if not len(batch):
                    continue
                # each frame leaves when its slot of the step is over, as a sensor sends
                # what it has heard as it hears it (not at the end of the simulator's step)
                due = -(-batch.t_ns // slot_ns) * slot_ns
                for when in np.unique(due).tolist():
                    due_groups.append((int(when), sid, batch.select(due == when)))
        self.sender.put(due_groups)
        self.counters.frames += frames
        self.counters.bearings += bearings
        return frames, bearings

    def close(self) -> WorkerCounters:
        """Publish what is still due (each at its time), close the publishers, sources and
        the nonce inbox; the counters. Idempotent."""
        self.sender.close(
            lambda left: self.counters.send_problems.append(f"{left} groups of bearings unsent")
        )
        self.counters.slot_groups = self.sender.stats.groups
        self.counters.slots_late = self.sender.stats.late
        self.counters.slot_late_max_s = self.sender.stats.late_max_s
        self.counters.slots_shed = self.sender.stats.shed
        for pub in self.publishers.values():
            pub.close()
            self.counters.sent += pub.stats.bearings
            self.counters.messages += pub.stats.messages
            problem = pub.problem()
            if problem is not None:
                self.counters.send_problems.append(f"{pub.signer.sender_id}: {problem}")
        self.publishers.clear()
        self.air.close()
        self.inbox.close()
        return self.counters


class _SharedNonces:
    """A nonce inbox asked from two threads (the pipelines' hasher and the publishers'
    pre-authentication keys): one at a time."""

    def __init__(self, inbox: NonceInbox) -> None:
        self.inbox = inbox
        self._lock = threading.Lock()

    def nonce_for(self, epoch: int) -> bytes:
        """The nonce of ``epoch`` (:meth:`NonceInbox.nonce_for`).

        Raises:
            NonceUnavailableError: not received, or expired.
        """
        with self._lock:
            return self.inbox.nonce_for(epoch)


def worker_main(work: TileWork, conn: Connection) -> None:
    """The body of a twin worker process: build, answer ``("warming",)``, load the kernels,
    answer ``("ready",)`` (:mod:`rfsas_hw.city.handshake`), then step on every
    :class:`Snapshot` received until ``None``; answer ``("end", counters)``. A failure
    is answered ``("error", message)`` (the main process ends the run with it)."""
    worker: TwinWorker | None = None
    # the sending thread takes the interpreter back after each of its socket writes; at
    # the default 5 ms switch interval every such hand-back waits up to 5 ms while the
    # step is computed, so a slot of many units' messages went out tens of ms late
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        worker = TwinWorker(work)
        conn.send(("warming",))  # built: the warm-up is judged by its CPU time
        worker.warm()
        conn.send(("ready",))
        while True:
            msg: Any = conn.recv()
            if msg is None:
                break
            t0 = time.perf_counter()
            frames, bearings = worker.step(msg)
            spent = time.perf_counter() - t0
            sent = sum(p.stats.messages for p in worker.publishers.values())
            conn.send(("step", msg.t_s, frames, bearings, spent, worker.truth(), sent))
            worker.sender.check()
        counters = worker.close()
        worker = None
        counters.cpu_s = cpu_s()
        conn.send(("end", counters))
    except Exception as err:  # reported to the main process, which ends the run
        answer_failure(conn, f"twin worker {work.worker_id}", err, worker)
    finally:
        conn.close()
