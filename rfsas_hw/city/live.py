"""The distributed RF-SAS of a district, live: broker, authority, twin workers, backends, vehicles.

:class:`DistributedRfsas` sets up and runs the real path of a deployment on
this machine:

- the identities and broker files (:mod:`rfsas_hw.city.deploy`) and mosquitto
  with mutual TLS on a loopback port, unless a running broker is given
  (:class:`~rfsas_hw.city.deploy.BrokerAccess`);
- the nonce authority, in this process, publishing every receiver's retained
  envelopes per epoch (:class:`~rfsas_hw.link.distribution.NonceDistributor`);
- the twin workers (:mod:`rfsas_hw.city.tileworker`), each a process with the
  units of some junctions: bearings signed per unit, published on the broker;
- the backends (:mod:`rfsas_hw.city.backendproc`), each a process owning the
  tiles of its group in the tile plan (:mod:`rfsas_hw.city.partition`),
  advising every vehicle in its tiles on the vehicle's own topic;
- the vehicles' receivers behind the gateway connection, a process of their own
  (:mod:`rfsas_hw.city.vehicles`).

:meth:`DistributedRfsas.step` takes the simulation's vehicles and VRUs of one
step, hands the workers their VRUs with phones and the backends their
vehicles, and returns the advisories that reached vehicles (verified) and the
fixes the backends made, with the person each fix belongs to when the truth
knows it (the truth comes from the workers, beside the backends, never into
them). Simulation time ``t_s`` stands for UTC ``t0_ns + t_s``: the caller
paces the steps to the wall clock, as the backends and vehicles check message
ages against it.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import multiprocessing as mp
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
from cryptography.hazmat.primitives import serialization

from rfsas_hw.backend.service import BackendConfig
from rfsas_hw.bridges.bridge import fitted_calibration
from rfsas_hw.bridges.config import BridgeConfig, UnitSpec
from rfsas_hw.city.backendproc import (
    BackendCounters,
    BackendWork,
    VehicleStates,
    backend_main,
    tick_phase_s,
)
from rfsas_hw.city.childlog import LogRelay, child_main
from rfsas_hw.city.clock import SimClock
from rfsas_hw.city.deploy import (
    AUTHORITY_ID,
    GATEWAY_ID,
    BrokerAccess,
    Deployment,
    LocalBroker,
    make_deployment,
)
from rfsas_hw.city.handshake import proc_cpu_s, wait_ready
from rfsas_hw.city.latency import LatencyMatch, LatencyParts
from rfsas_hw.city.owners import VehicleOwners
from rfsas_hw.city.partition import Site, district_tiles, plan_tiles, split_units
from rfsas_hw.city.sumoio import Movers
from rfsas_hw.city.tileworker import (
    Snapshot,
    TileWork,
    WorkerCounters,
    unit_sensor,
    worker_main,
)
from rfsas_hw.city.vehicles import Arrival, GatewayStats, GatewayWork, arrivals_of, gateway_main
from rfsas_hw.closing import ClosingContext
from rfsas_hw.errors import SimulationError
from rfsas_hw.fleet.broker import BrokerFiles
from rfsas_hw.fleet.tiles import TilePlan
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link.distribution import NonceDistributor
from rfsas_hw.link.mqtt import open_mqtt
from rfsas_hw.link.receiver import ReceiverConfig
from rfsas_hw.link.topics import ROOT, TopicRouter, quadkeys
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.records import Assessment, Fix
from rfsas_hw.twin.scenario import BuildingSpec, PoseSpec

NS_PER_S = 1_000_000_000
STEP_TIMEOUT_S = 10.0
"""How long a worker may take to answer a step, seconds."""
END_TIMEOUT_S = 20.0
"""How long a worker or backend may take to stop, seconds."""
DRAIN_S = 1.0
"""Time the backends get to take the workers' last messages before they stop, seconds."""
STATES_BACKLOG_S = 0.5
"""A backend whose pipe holds vehicle states it has not taken spanning more than this
gets no new ones until it has taken them (the main process never blocks on a busy
backend's full pipe), seconds."""
OWNER_MEMORY_S = 1.0
"""An advisory from the backend of the tile a vehicle left this long ago still counts
as its owner's (it was judged there and is on its way), seconds."""

__all__ = [
    "DistributedRfsas",
    "FixRecord",
    "LiveConfig",
    "LiveStats",
    "StatesFlow",
    "StepOut",
    "backend_names",
    "deployment_process",
    "prestart",
    "send_or_end",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LiveConfig:
    """How the distributed path is laid out."""

    backends: int = 2
    """Backend processes (one tile group each)."""
    workers: int = 2
    """Twin worker processes."""
    epoch_s: float = 60.0
    """Nonce epoch length, seconds."""
    hear_m: float = 150.0
    """A VRU goes to a worker while it is this close to one of its units, metres."""
    near_m: float = 60.0
    """A backend judges an emitter against the vehicles this close to it, metres."""
    hold_s: float = 1.0
    """A BRAKE holds a vehicle stopped until no BRAKE came for this long, seconds."""
    repeat_s: float = 1.0
    """A vehicle is told an emitter's unchanged (or milder) advice again after this
    long; new emitters and more severe advice go at once, seconds. A vehicle does not
    act on CAUTION or CLEAR by time, so their repeats only keep it informed."""
    brake_repeat_s: float = 0.5
    """After a BRAKE, the vehicle is told that emitter's advice again (the BRAKE, or
    what is milder) after this long, seconds: below :attr:`hold_s`, so a vehicle
    held stopped hears the next BRAKE before its hold ends."""
    epoch_overlap_s: float | None = 2.0
    """The backends drop the tracks and fixes of an earlier nonce epoch this long into a
    new one (``TrackerConfig.epoch_overlap_s``; None: after the tracker's
    ``drop_after_s``, 10 s, as for any silent emitter), seconds: every phone's id
    changes at once at an epoch's start, and each comes back under its new id within
    seconds; kept 10 s, the old ids doubled the emitters judged against every car.
    Above the receivers' age limit (1 s), below the epoch."""
    lead_s: float = 0.2
    """The simulation runs this far ahead of the deployment's clock, seconds: a step's
    frames are computed before they are heard, so each leaves the worker when its
    slot is over, not when the simulator and the worker are done with the step
    (their CPU time). Advice reaches the simulator's vehicles this much later (a
    step already simulated cannot be changed)."""
    time_scale: float = 1.0
    """Simulated seconds per wall second the deployment's clock runs at (1: real time;
    below 1 for a machine that cannot keep up, see :mod:`rfsas_hw.city.clock`)."""
    nice: int = 0
    """How much lower the deployment's processes (twin workers, backends, the vehicles'
    receivers) run than the simulator: each adds this to its nice value when it starts
    (0: the same priority; see :func:`deployment_process`). The simulator stands for the
    physical world, which never waits; those processes have the slack of
    :attr:`lead_s`."""
    dashboard: bool = False
    """The backends also report their fixes and tracks every step, for a live
    dashboard (:attr:`StepOut.dashboard`)."""

    def __post_init__(self) -> None:
        if not 0.0 < self.time_scale <= 1.0:
            raise ValueError("time_scale must be in (0, 1]")
        if self.backends < 1 or self.workers < 1:
            raise ValueError("backends and workers must be at least 1")
        if not self.epoch_s > 0 or not self.hear_m > 0 or not self.near_m > 0:
            raise ValueError("epoch_s, hear_m and near_m must be positive")
        if not 0.0 < self.brake_repeat_s < self.hold_s or self.repeat_s < self.brake_repeat_s:
            raise ValueError(
                "need 0 < brake_repeat_s < hold_s and brake_repeat_s <= repeat_s, got "
                f"{self.brake_repeat_s:g}, {self.hold_s:g}, {self.repeat_s:g}"
            )
        overlap = self.epoch_overlap_s
        if overlap is not None and not ReceiverConfig().max_age_s < overlap < self.epoch_s:
            raise ValueError(
                f"epoch_overlap_s must be above the receivers' age limit "
                f"({ReceiverConfig().max_age_s:g} s) and below the epoch, got {overlap:g}"
            )
        if not 0.0 <= self.lead_s <= 1.0:
            raise ValueError("lead_s must be in [0, 1] seconds")
        if not 0 <= self.nice <= 19:
            raise ValueError("nice must be in [0, 19]")


def _context() -> Any:
    """The multiprocessing context of the workers and backends: they fork from one
    server that imported their modules once (spawning each would import them again,
    seconds on a busy machine)."""
    ctx = mp.get_context("forkserver")
    # numba: the backends' kernels (imported when first needed, so not by backendproc)
    ctx.set_forkserver_preload(
        ["rfsas_hw.city.tileworker", "rfsas_hw.city.backendproc", "rfsas_hw.city.vehicles", "numba"]
    )
    return ctx


def prestart() -> None:
    """Start the server the workers and backends fork from now, so that its imports
    overlap other work (preparing the demand, a run with RF-SAS off) instead of
    delaying the start of the distributed path."""
    from multiprocessing import forkserver

    _context()
    forkserver.ensure_running()


def deployment_process(
    target: Callable[[Any, Connection], None], nice: int, work: Any, conn: Connection
) -> None:
    """The body of one of the deployment's processes (a twin worker, a backend, the
    vehicles' receivers): ``nice`` added to the process's nice value (it runs that much
    behind the simulator when the cores are short, :attr:`LiveConfig.nice`), then
    ``target(work, conn)``."""
    if nice:
        os.nice(nice)
    target(work, conn)


def send_or_end(name: str, conn: Connection, msg: Any) -> None:
    """Send ``msg`` to the district process ``name``.

    Raises:
        SimulationError: the process has ended (its end of the pipe is closed): with the
            error it reported before it ended, when it did, else saying it ended.
    """
    try:
        conn.send(msg)
    except (BrokenPipeError, ConnectionResetError):
        reason = f"{name} ended during the run"
        with contextlib.suppress(EOFError, OSError):
            while conn.poll():
                got = conn.recv()
                if got[0] == "error":
                    reason = str(got[1])
                    break
        raise SimulationError(reason) from None


def backend_names(count: int) -> list[str]:
    """The ids of a district's ``count`` backends: ``be-1`` … ``be-<count>``."""
    return [f"be-{i + 1}" for i in range(count)]


@dataclass(frozen=True, slots=True)
class FixRecord:
    """A trustworthy fix a backend made, with the truth beside it."""

    t_s: float
    """Simulation time of the fix, seconds."""
    emitter: str
    """Emitter id (16 hex digits)."""
    person: str | None
    """The VRU the emitter belonged to (truth), or None when unknown."""
    x_m: float
    y_m: float
    sigma_m: float
    """One-sigma position error, sqrt of the covariance's larger eigenvalue, metres."""


@dataclass
class StepOut:
    """What one step of the distributed path gave."""

    arrivals: list[Arrival] = field(default_factory=list)
    """Advisories verified at their vehicle this step."""
    latency: dict[tuple[str, int], LatencyParts] = field(default_factory=dict)
    """Frame → advisory latency and its parts, seconds of the deployment's clock (wall
    seconds at time scale 1), of the advisories that carried a fix of their step (the
    others repeat a track's state), by (backend, sequence number): of this step's
    arrivals, and of earlier arrivals whose backend reported the fix they carried only
    now (:class:`~rfsas_hw.city.latency.LatencyMatch`)."""
    fixes: list[FixRecord] = field(default_factory=list)
    foreign: int = 0
    """Arrivals signed by a backend that does not own the vehicle's tile."""
    messages: int = 0
    """Signed bearing messages the workers published since the previous step."""
    dashboard: list[tuple[str, list[Fix], list[Assessment]]] = field(default_factory=list)
    """With :attr:`LiveConfig.dashboard`: per backend report since the previous step,
    (backend id, fixes made since its last report, its current assessments)."""


@dataclass
class LiveStats:
    """Counters and CPU of a run of the distributed path."""

    workers: dict[str, WorkerCounters] = field(default_factory=dict)
    backends: dict[str, BackendCounters] = field(default_factory=dict)
    gateway: dict[str, Any] = field(default_factory=dict)
    broker_cpu_s: float | None = None
    """CPU seconds of the broker the run started (None: a broker it did not start)."""
    bearing_messages: int = 0
    """Signed bearing messages the workers published."""
    bearing_messages_received: int = 0
    """Of them, taken from the broker by the backends."""
    bearing_messages_verified: int = 0
    """Of them, verified by the backends (the others refused, e.g. ``stale`` when the
    run fell behind its clock)."""
    advisories_sent: int = 0
    advisories_received: int = 0
    """Advisory datagrams the gateway took from the broker."""
    foreign: int = 0
    states_held: int = 0
    """Steps whose vehicle states a backend did not get because it had not taken
    those of :data:`STATES_BACKLOG_S` before (it was busy)."""
    problems: list[str] = field(default_factory=list)


class StatesFlow:
    """Which backends get a step's vehicle states: each backend acknowledges the newest
    states it has taken from its pipe, and one that has left states spanning more than
    ``backlog_s`` untaken (it is busy) gets none until it has taken them, so the
    simulator never blocks on a busy backend's full pipe.

    Args:
        t0_ns: UTC of the first states, ns.
        backlog_s: most untaken states a backend may have, seconds of their times.
    """

    def __init__(self, t0_ns: int = 0, backlog_s: float = STATES_BACKLOG_S) -> None:
        self.t0_ns = t0_ns
        self.backlog_ns = round(backlog_s * NS_PER_S)
        self.given: dict[str, int] = {}
        """Per backend, the time of the newest states sent to it, UTC ns."""
        self.taken_ns: dict[str, int] = {}
        """Per backend, the time of the newest states it has taken, UTC ns."""
        self.held = 0
        """States not sent to a busy backend."""

    def may_send(self, backend: str, t_ns: int) -> bool:
        """Whether ``backend`` gets the states of ``t_ns`` (then counted as sent)."""
        given = self.given.get(backend, self.t0_ns)
        if given - self.taken_ns.get(backend, self.t0_ns) > self.backlog_ns:
            self.held += 1
            return False
        self.given[backend] = t_ns
        return True

    def taken(self, backend: str, t_ns: int) -> None:
        """``backend`` has taken the states of ``t_ns`` and every earlier one."""
        self.taken_ns[backend] = max(self.taken_ns.get(backend, self.t0_ns), t_ns)


def _backend_keys(deployment: Deployment) -> dict[str, bytes]:
    """The backends' public signing keys (DER), as every vehicle holds them."""
    out = {}
    for b, store in deployment.backends.items():
        key = store.card.sign_public
        if key is not None:
            out[b] = key.public_bytes(
                serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
            )
    return out


class DistributedRfsas(ClosingContext):
    """The distributed path of a district (see the module docstring).

    Args:
        work_dir: where keys, broker files and the broker log go (created).
        units: the unit sites (rfsas frame).
        buildings: building footprints, rfsas frame.
        origin: the site origin of the frame.
        bounds_m: the district's bounds (x_min, y_min, x_max, y_max), frame metres.
        bridge: radio settings, seed, device models and MAC policy.
        settings: the backends' service settings.
        config: the layout.
        broker: a running broker to use (None: mosquitto is started on loopback with
            the deployment's own files).
        log_handler: where the log records of the processes go
            (:mod:`rfsas_hw.city.childlog`; None: this process's loggers, as if logged
            here).

    Raises:
        MissingDependencyError: mosquitto is not installed (and no ``broker``).
        ConfigError: with ``broker``, a party has no certificate.
        LinkError / SimulationError: a process or the broker did not start.
    """

    def __init__(
        self,
        work_dir: Path,
        units: Sequence[Site],
        buildings: Sequence[BuildingSpec],
        origin: SiteOrigin,
        bounds_m: tuple[float, float, float, float],
        bridge: BridgeConfig,
        settings: BackendConfig,
        config: LiveConfig | None = None,
        *,
        broker: BrokerAccess | None = None,
        log_handler: logging.Handler | None = None,
    ) -> None:
        self.config = cfg = config or LiveConfig()
        self.origin = origin
        self.router = TopicRouter(origin)
        self.clock = SimClock(time.time_ns() // 1000 * 1000, cfg.time_scale)
        """The deployment's clock (the wall clock at time scale 1)."""
        self.t0_ns = 0
        """UTC of simulation time 0 on :attr:`clock`, ns (set by :meth:`start`)."""
        backend_ids = backend_names(cfg.backends)
        self.plan: TilePlan = plan_tiles(units, backend_ids, district_tiles(self.router, bounds_m))
        # fewer groups of tiles than backends asked for: the others would own nothing
        backend_ids = [b for b in backend_ids if b in self.plan.groups]
        self.owner = {t: g.name for g in self.plan.groups.values() for t in g.tiles}
        self.deployment = make_deployment(
            work_dir, [u.id for u in units], backend_ids, broker=broker
        )
        self.stats = LiveStats()
        self._procs: list[Any] = []
        self._pids: dict[str, int] = {}
        """Each process's id, by name."""
        self._workers: dict[str, tuple[Connection, np.ndarray, np.ndarray]] = {}
        self._backends: dict[str, Connection] = {}
        self._states = StatesFlow()
        """Which backends get the vehicles' states (a busy one does not)."""
        self._truth: dict[str, str] = {}
        self._sent: dict[str, int] = {}
        self._pending: dict[str, int] = {}
        """Steps sent to each worker and not answered yet."""
        self._latency = LatencyMatch()
        """The backends' reports of fixes carried, matched with the arrivals."""
        self._owners = VehicleOwners(OWNER_MEMORY_S)
        """Per vehicle, the backends and tiles it was in lately."""
        self._codes: dict[str | None, int] = {}
        """Each backend's position in :attr:`_backends` (a tile nobody owns: -1)."""
        self.broker: LocalBroker | None = None
        self._gateway: Connection | None = None
        """The pipe to the vehicles' gateway process."""
        self._present: frozenset[str] = frozenset()
        """The vehicles the gateway was last told of."""
        self._auth_transport: Any = None
        self._closed = False
        self._logs: LogRelay | None = None
        """The processes' log records, to ``log_handler``."""
        self.late: list[Arrival] = []
        """Advisories that reached vehicles after the last step (taken by :meth:`close`)."""
        try:
            if isinstance(self.deployment.files, BrokerFiles):
                self.broker = LocalBroker(self.deployment.files, work_dir / "mosquitto.log")
            self._start_authority()
            ctx = _context()
            self._logs = LogRelay(ctx, log_handler)
            self._start_backends(ctx, backend_ids, settings)
            self._start_workers(ctx, units, buildings, bridge)
            gateway = GatewayWork(
                url=self.deployment.url(GATEWAY_ID, sub=f"{ROOT}/vehicle/+/advisory"),
                backend_keys=_backend_keys(self.deployment),
                clock=self.clock,
            )
            self._gateway = self._spawn(ctx, gateway_main, gateway, "vehicles")
            self._wait_ready()
        except BaseException:
            self.close()
            raise

    # -- start ------------------------------------------------------------------------

    def start(self) -> int:
        """Now is simulation time 0: its UTC in ns (whole microseconds, as the twin's
        start time is written). Call right before the first step."""
        self.t0_ns = self.clock() // 1000 * 1000
        self._states = StatesFlow(self.t0_ns)
        return self.t0_ns

    def _start_authority(self) -> None:
        schedule = EpochSchedule(self.config.epoch_s, min(5.0, self.config.epoch_s / 4))
        authority = self.deployment.authority.nonce_authority(schedule)
        self._auth_transport = open_mqtt(self.deployment.url(AUTHORITY_ID), "send")
        # the retained envelopes expire at the end of their epoch on the deployment's clock
        self._auth_transport.clock = self.clock
        self.distributor = NonceDistributor(
            authority, dict.fromkeys(authority.receivers, self._auth_transport), clock=self.clock
        )
        self.distributor.tick()

    def _start_backends(self, ctx: Any, backend_ids: list[str], settings: BackendConfig) -> None:
        tracker = replace(settings.tracker, epoch_overlap_s=self.config.epoch_overlap_s)
        settings = replace(settings, tracker=tracker)
        origin = f"{self.origin.lat_deg:.7f},{self.origin.lon_deg:.7f}"
        for k, b in enumerate(backend_ids):
            group = self.plan.group_of(b)
            work = BackendWork(
                backend_id=b,
                keys_dir=self.deployment.backends[b].path,
                listen_url=self.deployment.url(
                    b, tiles=",".join(group.tiles), nonces=b, origin=origin
                ),
                advise_url=self.deployment.url(b, origin=origin),
                origin=self.origin,
                settings=settings,
                epoch_s=self.config.epoch_s,
                near_m=self.config.near_m,
                repeat_s=self.config.repeat_s,
                brake_repeat_s=self.config.brake_repeat_s,
                tick_phase_s=tick_phase_s(k, len(backend_ids), settings.step_s),
                clock=self.clock,
                dashboard=self.config.dashboard,
            )
            self._backends[b] = self._spawn(ctx, backend_main, work, b)
        self._codes = {None: -1, **{b: k for k, b in enumerate(self._backends)}}

    def _spawn(self, ctx: Any, target: Any, work: Any, name: str) -> Any:
        """Start ``target(work, pipe)`` as the daemon process ``name``, logging here
        (:func:`~rfsas_hw.city.childlog.child_main`); our end of the pipe."""
        assert self._logs is not None
        parent, child = ctx.Pipe()
        body = functools.partial(deployment_process, target, self.config.nice)
        args = (body, work, child, self._logs.child())
        proc = ctx.Process(target=child_main, args=args, name=name, daemon=True)
        proc.start()
        child.close()
        self._procs.append(proc)
        self._pids[proc.name] = proc.pid
        return parent

    def _start_workers(
        self,
        ctx: Any,
        units: Sequence[Site],
        buildings: Sequence[BuildingSpec],
        bridge: BridgeConfig,
    ) -> None:
        origin = f"{self.origin.lat_deg:.7f},{self.origin.lon_deg:.7f}"
        for k, part in enumerate(split_units(units, self.config.workers)):
            wid = f"twin-{k + 1}"
            specs = tuple(
                UnitSpec(id=u.id, pose=PoseSpec(u.x_m, u.y_m, _boresight(u))) for u in part
            )
            xs = np.array([u.x_m for u in part])
            ys = np.array([u.y_m for u in part])
            reach = self.config.hear_m + 50.0
            near = tuple(
                b
                for b in buildings
                if b.x_max_m > xs.min() - reach
                and b.x_min_m < xs.max() + reach
                and b.y_max_m > ys.min() - reach
                and b.y_min_m < ys.max() + reach
            )
            work = TileWork(
                worker_id=wid,
                units=specs,
                bridge=bridge,
                buildings=near,
                urls={u.id: self.deployment.url(u.id, origin=origin) for u in part},
                nonce_url=self.deployment.url(part[0].id, nonces=part[0].id),
                keys={u.id: self.deployment.units[u.id].path for u in part},
                epoch_s=self.config.epoch_s,
                calibrations={
                    s.id: fitted_calibration(unit_sensor(s), seed=bridge.calibration_seed)
                    for s in specs
                },
                clock=self.clock,
                groups=_junction_groups(part),
                hear_m=self.config.hear_m,
            )
            self._workers[wid] = (self._spawn(ctx, worker_main, work, wid), xs, ys)

    def _wait_ready(self) -> None:
        """Wait for every process's ``("ready",)`` (:func:`~rfsas_hw.city.handshake.wait_ready`:
        a warm-up that compiles kernels is judged by its CPU time, not the wall clock)."""
        pids = self._pids
        conns = {w: (c, pids[w]) for w, (c, _, _) in self._workers.items()}
        conns.update((b, (c, pids[b])) for b, c in self._backends.items())
        if self._gateway is not None:
            conns["vehicles' gateway"] = (self._gateway, pids["vehicles"])
        wait_ready(conns, self.distributor.tick)

    # -- step -------------------------------------------------------------------------

    def _tiles(self, cars: Movers) -> list[str]:
        lat, lon, _ = self.origin.to_geodetic(cars.x_m, cars.y_m)
        return quadkeys(lat, lon)

    def step(self, t_s: float, cars: Movers, vrus: Movers, phones: dict[str, str]) -> StepOut:
        """Run the distributed path for one step (see the module docstring).

        Args:
            t_s: simulation time, seconds.
            cars: the vehicles to advise.
            vrus: every VRU.
            phones: device model of each VRU that carries a phone, by VRU id.

        Raises:
            SimulationError: a worker or backend failed or stopped answering, or
                :meth:`start` was not called.
        """
        if not self.t0_ns:
            raise SimulationError("DistributedRfsas.start() must be called before the first step")
        now_ns = self.t0_ns + round(t_s * NS_PER_S)
        self.distributor.tick(now_ns)
        has = np.flatnonzero(np.fromiter(map(phones.__contains__, vrus.ids), bool, len(vrus)))
        hear = self.config.hear_m
        for wid, (conn, xs, ys) in self._workers.items():
            # the VRUs with a phone in the box around the worker's units grown by the
            # hearing range (and a metre for rounding), then the exact distance of those
            box = has[
                (vrus.x_m[has] > xs.min(initial=np.inf) - hear - 1.0)
                & (vrus.x_m[has] < xs.max(initial=-np.inf) + hear + 1.0)
                & (vrus.y_m[has] > ys.min(initial=np.inf) - hear - 1.0)
                & (vrus.y_m[has] < ys.max(initial=-np.inf) + hear + 1.0)
            ]
            d2 = (vrus.x_m[box, None] - xs[None, :]) ** 2 + (vrus.y_m[box, None] - ys[None, :]) ** 2
            idx = box[d2.min(axis=1, initial=np.inf) < hear**2]
            ids = tuple(map(vrus.ids.__getitem__, idx.tolist()))
            send_or_end(
                wid,
                conn,
                Snapshot(
                    t_s,
                    self.t0_ns,
                    ids,
                    tuple(map(phones.__getitem__, ids)),
                    vrus.x_m[idx],
                    vrus.y_m[idx],
                    vrus.heading_deg[idx],
                ),
            )
        tiles = self._tiles(cars)
        owners = list(map(self.owner.get, tiles))
        self._owners.update(t_s, cars.ids, owners, tiles)
        codes = np.fromiter(map(self._codes.get, owners), np.intp, len(owners))
        for k, (b, conn) in enumerate(self._backends.items()):
            if self._states.may_send(b, now_ns):
                sel = np.flatnonzero(codes == k)
                send_or_end(
                    b,
                    conn,
                    VehicleStates(
                        now_ns,
                        tuple(map(cars.ids.__getitem__, sel.tolist())),
                        cars.x_m[sel],
                        cars.y_m[sel],
                        cars.heading_deg[sel],
                        cars.speed_mps[sel],
                        cars.length_m[sel],
                        cars.width_m[sel],
                    ),
                )
        out = StepOut()
        self._from_backends(out)
        present = frozenset(cars.ids)
        if present != self._present:
            assert self._gateway is not None
            send_or_end("vehicles' gateway", self._gateway, tuple(present))
            self._present = present
        for arrival in self._arrivals():
            self._arrival(out, arrival)
        self._latency.forget(now_ns)
        out.messages = self._wait_workers(t_s)
        self.stats.foreign += out.foreign
        return out

    def _arrivals(self) -> list[Arrival]:
        """The advisories the gateway verified since the last call, oldest first."""
        out: list[Arrival] = []
        conn = self._gateway
        assert conn is not None
        while conn.poll():
            msg = conn.recv()
            if msg[0] == "arrivals":
                out += arrivals_of(msg[1])
            elif msg[0] == "error":
                raise SimulationError(str(msg[1]))
        return out

    def _from_backends(self, out: StepOut) -> None:
        for b, conn in self._backends.items():
            while conn.poll():
                msg = conn.recv()
                if msg[0] == "sent":
                    for _vid, first, last, fix_ns, step_ns in msg[1]:
                        seq = first
                        while True:
                            latency = self._latency.sent((b, seq), fix_ns, step_ns)
                            if latency is not None:  # it arrived at an earlier step
                                out.latency[(b, seq)] = latency
                            if seq == last:
                                break
                            seq = (seq + 1) % (1 << 32)
                elif msg[0] == "fixes":
                    for t_ns, emitter, x, y, sigma in msg[1]:
                        out.fixes.append(
                            FixRecord(
                                (t_ns - self.t0_ns) / NS_PER_S,
                                emitter,
                                self._truth.get(emitter),
                                x,
                                y,
                                sigma,
                            )
                        )
                elif msg[0] == "states":
                    self._states.taken(b, int(msg[1]))
                elif msg[0] == "dashboard":
                    out.dashboard.append((b, msg[1], msg[2]))
                elif msg[0] == "error":
                    raise SimulationError(str(msg[1]))

    def _arrival(self, out: StepOut, arrival: Arrival) -> None:
        """Take one verified advisory: its owner check, its vehicle's tiles, its latency
        when its backend said which fix it carried."""
        key = (arrival.backend_id, arrival.seq)
        latency = self._latency.arrived(key, arrival.t_ns, arrival.signed_ns)
        if latency is not None:
            out.latency[key] = latency
        vid = arrival.vehicle_id
        owned = self._owners.owns(arrival.backend_id, vid)
        out.foreign += not owned
        out.arrivals.append(replace(arrival, owned=owned, tiles=self._owners.tiles(vid)))

    def _wait_workers(self, t_s: float) -> int:
        """Wait until every worker has answered all steps but this one (a worker has the
        time of one step to compute the next, while this process goes on); the bearing
        messages they sent since their previous answers."""
        messages = 0
        for wid, (conn, _, _) in self._workers.items():
            self._pending[wid] = self._pending.get(wid, 0) + 1
            while self._pending[wid] > 1 or conn.poll(0):
                if not conn.poll(STEP_TIMEOUT_S):
                    raise SimulationError(
                        f"{wid} did not answer step {t_s:.1f} s within {STEP_TIMEOUT_S:g} s"
                    )
                messages += self._answer(wid, conn.recv())
        return messages

    def _answer(self, wid: str, msg: Any) -> int:
        """Take one answer of a worker; the bearing messages it sent since the last one."""
        if msg[0] == "error":
            raise SimulationError(str(msg[1]))
        if msg[0] != "step":
            return 0
        self._pending[wid] -= 1
        for emitter, vru in msg[5]:
            self._truth[emitter] = vru
        messages = int(msg[6]) - self._sent.get(wid, 0)
        self._sent[wid] = int(msg[6])
        return messages

    # -- end --------------------------------------------------------------------------

    def _stop(self, conns: dict[str, Connection], deadline: float) -> None:
        """Tell the processes behind ``conns`` to stop and take their counters."""
        for conn in conns.values():
            with contextlib.suppress(OSError):
                conn.send(None)
        for name, conn in conns.items():
            try:
                while conn.poll(max(deadline - time.monotonic(), 0.0)):
                    msg = conn.recv()
                    if msg[0] == "end":
                        if name in self._backends:
                            self.stats.backends[name] = msg[1]
                        else:
                            self.stats.workers[name] = msg[1]
                        break
                    if msg[0] == "error":
                        self.stats.problems.append(str(msg[1]))
                        break
            except (EOFError, OSError):
                self.stats.problems.append(f"{name} ended without its counters")
            conn.close()

    def _stop_gateway(self, conn: Connection, deadline: float) -> list[Arrival]:
        """Tell the gateway to stop; the advisories it verified since the last step (its
        counters go to :attr:`stats`)."""
        late: list[Arrival] = []
        with contextlib.suppress(OSError):
            conn.send(None)
        try:
            while conn.poll(max(deadline - time.monotonic(), 0.0)):
                msg = conn.recv()
                if msg[0] == "arrivals":
                    late += arrivals_of(msg[1])
                    continue
                if msg[0] == "end":
                    totals: GatewayStats = msg[1]
                    self.stats.gateway = {
                        "datagrams": totals.datagrams,
                        "verified": totals.verified,
                        "unknown_vehicle": totals.unknown_vehicle,
                        "rejected": dict(totals.rejected),
                        "cpu_s": float(msg[2]),
                    }
                    self.stats.advisories_received = totals.datagrams
                elif msg[0] == "error":
                    self.stats.problems.append(str(msg[1]))
                break
        except (EOFError, OSError):
            self.stats.problems.append("the vehicles' gateway ended without its counters")
        conn.close()
        return late

    def close(self) -> LiveStats:
        """Stop every process and the broker; the counters (collected once). Idempotent."""
        if self._closed:
            return self.stats
        self._closed = True
        deadline = time.monotonic() + END_TIMEOUT_S
        # the workers first: the backends take what they sent last before they stop
        self._stop({w: c for w, (c, _, _) in self._workers.items()}, deadline)
        time.sleep(DRAIN_S)
        self._stop(dict(self._backends), deadline)
        if self._gateway is not None:
            time.sleep(DRAIN_S)
            for arrival in self._stop_gateway(self._gateway, deadline):
                owned = self._owners.owns(arrival.backend_id, arrival.vehicle_id)
                self.stats.foreign += not owned
                lately = self._owners.tiles(arrival.vehicle_id)
                self.late.append(replace(arrival, owned=owned, tiles=lately))
        for proc in self._procs:
            proc.join(max(deadline - time.monotonic(), 1.0))
            if proc.is_alive():
                proc.terminate()
                proc.join(5)
        if self._logs is not None:
            self._logs.close()
        if self._auth_transport is not None:
            self._auth_transport.close()
        if self.broker is not None:
            self.stats.broker_cpu_s = proc_cpu_s(self.broker.pid)
            self.broker.close()
        self.stats.states_held = self._states.held
        for w in self.stats.workers.values():
            self.stats.bearing_messages += w.messages
            self.stats.problems += w.send_problems
        for bc in self.stats.backends.values():
            self.stats.bearing_messages_verified += bc.stats.get("link.verified", 0)
            # what came on the bearing topics: every datagram but the nonce envelopes
            # (whatever became of them: taken, refused, or shed under overload)
            st = bc.stats
            self.stats.bearing_messages_received += st.get("link.datagrams", 0) - st.get(
                "link.envelopes", 0
            )
            self.stats.advisories_sent += bc.advisories_sent
            self.stats.problems += bc.problems
        return self.stats


def _junction_groups(units: Sequence[Site]) -> tuple[tuple[str, ...], ...]:
    """Unit ids per junction (a unit of no junction alone)."""
    groups: dict[str, list[str]] = {}
    for u in units:
        groups.setdefault(u.junction or f"unit:{u.id}", []).append(u.id)
    return tuple(tuple(ids) for ids in groups.values())


def _boresight(u: Site) -> float:
    return float(getattr(u, "boresight_deg", 0.0))
