"""``rfsas city run`` as a library: a district in SUMO, RF-SAS off or on, scored, logged, mapped.

One run (:func:`run_city`):

1. reads the net (:mod:`rfsas_hw.city.net`; the Berlin-Adlershof net of the
   ``eclipse-sumo`` wheel by default), generates the demand
   (:mod:`rfsas_hw.city.demand`), places the units and finds the buildings
   (:mod:`rfsas_hw.city.placement`);
2. starts SUMO in this process (libsumo, 0.1 s steps) and, with RF-SAS on, the
   distributed path (:class:`~rfsas_hw.city.live.DistributedRfsas`: mosquitto,
   nonce authority, twin workers, backends, the vehicles' receivers);
3. steps: SUMO, everyone's state (:class:`~rfsas_hw.city.sumoio.SumoDistrict`),
   the scorer (:class:`~rfsas_hw.city.scoring.CityScorer`), the distributed
   path, and each vehicle's own advisories acted on in SUMO. With RF-SAS on
   the loop is paced so that simulation time runs ``LiveConfig.lead_s`` ahead of
   the deployment's clock (the twin workers send each frame when its time
   comes); with RF-SAS
   off it runs as fast as SUMO goes;
4. writes the run log (JSON lines: start, one line per advisory that reached a
   vehicle, one per simulated second, one per log record of any of the run's
   processes at the main process's logging level — WARNING unless set otherwise —,
   the end), the summary (JSON) and the map (PNG and GeoJSON) into the output
   directory. The other processes' records go only there
   (:mod:`rfsas_hw.city.childlog`), not to the console.

Raw MACs exist only inside the twin workers: the run log, the summary and the
map hold emitter ids (keyed hashes), SUMO ids and positions.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Literal

import numpy as np

from rfsas_hw.bridges.config import BACKEND_PROFILES, BridgeConfig, backend_config
from rfsas_hw.bridges.sumo import SumoControl, load_sumo, start_sumo
from rfsas_hw.city.childlog import redact_macs
from rfsas_hw.city.clock import cpu_s
from rfsas_hw.city.demand import Demand, DemandConfig, generate
from rfsas_hw.city.deploy import AUTHORITY_ID, BrokerAccess, make_identities
from rfsas_hw.city.latency import LatencyParts
from rfsas_hw.city.live import DistributedRfsas, LiveConfig, LiveStats, backend_names
from rfsas_hw.city.net import NetInfo, district_net, read_net, sumo_home
from rfsas_hw.city.placement import UnitSite, buildings, placed_units
from rfsas_hw.city.scoring import Actors, CityScorer, CitySummary, ScoringConfig
from rfsas_hw.city.sumoio import Movers, SumoDistrict
from rfsas_hw.city.vehicles import Arrival
from rfsas_hw.errors import ConfigError, OutputError, SimulationError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.outpaths import check_output, write_text_atomic
from rfsas_hw.twin.scenario import BuildingSpec

if TYPE_CHECKING:
    from rfsas_hw.city.dashboard import CityDashboard

STEP_S = 0.1
"""SUMO's step, seconds."""
Mode = Literal["off", "on"]

__all__ = [
    "CityRunConfig",
    "CityRunResult",
    "District",
    "Progress",
    "Runtime",
    "prepare_district",
    "run_city",
    "sumo_command",
    "write_identities",
]


@dataclass(frozen=True)
class CityRunConfig:
    """What one district run is made of."""

    net: Path | None = None
    """The SUMO net (None: the Berlin-Adlershof net of the ``eclipse-sumo`` wheel)."""
    origin: SiteOrigin | None = None
    """Where a net without a projection lies on the globe (None: the net module's
    default; a geo-referenced net keeps its own)."""
    demand: DemandConfig = field(default_factory=DemandConfig)
    """Traffic and VRUs."""
    placement: Path | None = None
    """Placement YAML (None: two units at every traffic-light junction)."""
    polygons: Path | None = None
    """SUMO polygon file with buildings (None: derived from the net's city blocks)."""
    duration_s: float = 300.0
    """Simulated time, seconds."""
    seed: int = 1
    """Seed of the demand, SUMO and the twin."""
    live: LiveConfig = field(default_factory=LiveConfig)
    """Layout of the distributed path."""
    scoring: ScoringConfig = field(default_factory=ScoringConfig)
    """Thresholds of the scorer."""
    backend_profile: str = "urban-intersection"
    """Named backend settings (``rfsas_hw.bridges.config.BACKEND_PROFILES``)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ConfigError(
                f"duration must be a positive number of seconds, not {self.duration_s}"
            )
        if self.backend_profile not in BACKEND_PROFILES:
            raise ConfigError(
                f"backend profile {self.backend_profile!r} is not known "
                f"(known: {', '.join(sorted(BACKEND_PROFILES))})"
            )


@dataclass(frozen=True)
class Progress:
    """Where a run is, for a progress display."""

    t_s: float
    duration_s: float
    vehicles: int
    vrus: int
    advisories: int
    """Advisories that reached vehicles so far."""
    brakes: int
    """Of them, BRAKEs."""
    realtime_factor: float
    """Simulated seconds per wall second so far."""


@dataclass
class Runtime:
    """What a run cost and what crossed the broker."""

    mode: str
    wall_s: float = 0.0
    """Wall time of the stepping loop, seconds."""
    realtime_factor: float = 0.0
    """Simulated seconds per wall second."""
    behind_s: float = 0.0
    """Largest lag of a step behind its wall-clock time (``LiveConfig.lead_s`` before its
    simulated time), wall seconds (RF-SAS on)."""
    cpu_s: dict[str, float] = field(default_factory=dict)
    """CPU seconds per component: sumo, read, scoring, path (this process's share of
    the distributed path: snapshots, pipes, acting), vehicles (the vehicles' receivers),
    twin-N, be-N, broker."""
    counts: dict[str, int] = field(default_factory=dict)
    """Messages: bearing messages sent and verified, advisories sent and received,
    advisories from a backend that does not own the vehicle's tile, and so on."""
    log_records: dict[str, int] = field(default_factory=dict)
    """Log records of the run's processes written to the run log, by level."""
    problems: list[str] = field(default_factory=list)
    stopped: Literal["end", "interrupted"] = "end"
    """How the run ended: ``end`` (its duration simulated) or ``interrupted`` (Ctrl-C or
    SIGTERM: the steps simulated until then are scored and written as for a whole run)."""
    simulated_s: float = 0.0
    """Simulated seconds done, seconds."""

    def cpu_share(self) -> dict[str, float]:
        """Each component's CPU seconds per wall second (1.0 = one core)."""
        return {k: v / self.wall_s for k, v in self.cpu_s.items()} if self.wall_s > 0 else {}


@dataclass
class CityRunResult:
    """What :func:`run_city` gives."""

    summary: CitySummary
    runtime: Runtime
    units: list[UnitSite]
    files: dict[str, Path]
    """What was written: ``log``, ``summary``, ``png``, ``geojson``."""


def _actors(m: Movers, vehicles: bool) -> Actors:
    return Actors.of(
        m.ids,
        ["vehicle"] * len(m) if vehicles else list(m.cls),
        m.x_m,
        m.y_m,
        m.speed_mps,
        m.heading_deg,
        m.length_m,
        m.width_m,
        m.odometer_m,
    )


class _Log:
    """The run log: one JSON object per line (written from the stepping loop and from
    the thread that takes the processes' log records)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = threading.Lock()
        # one encoder for every line (json.dumps with options builds a new one per call)
        self._encode = json.JSONEncoder(allow_nan=False, default=_plain).encode
        try:
            self.fh: IO[str] = path.open("w", encoding="utf-8")
        except OSError as err:
            raise OutputError(f"{path}: cannot write: {err.strerror or err}") from err

    def write(self, record: dict[str, Any]) -> None:
        line = self._encode(record) + "\n"
        try:
            with self._lock:
                self.fh.write(line)
                if record["record"] != "advisory":  # a reader following the log sees each second
                    self.fh.flush()
        except OSError as err:
            raise OutputError(f"{self.path}: cannot write: {err.strerror or err}") from err

    def close(self) -> None:
        with self._lock:
            self.fh.close()


class _LogRecords(logging.Handler):
    """Log records of every process of a run into the run log (``{"record": "log"}``:
    its wall-clock UTC seconds, process, level, logger and message, MAC-shaped text
    redacted), counted by level."""

    def __init__(self, log: _Log) -> None:
        super().__init__()
        self.log = log
        self.counts: Counter[str] = Counter()
        self.setFormatter(logging.Formatter("%(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        self.counts[record.levelname] += 1
        process = "main" if record.processName == "MainProcess" else record.processName
        try:
            self.log.write(
                {
                    "record": "log",
                    "utc_s": round(record.created, 3),
                    "process": process,
                    "level": record.levelname,
                    "logger": record.name,
                    "message": redact_macs(self.format(record)),
                }
            )
        except (OutputError, ValueError):  # the run's own writes report a run log gone bad
            self.counts["unwritten"] += 1


def _plain(v: Any) -> Any:
    if isinstance(v, float | np.floating):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, Path):
        return str(v)
    raise TypeError(f"not JSON: {type(v).__name__}")


def _finite(v: float) -> float | None:
    return v if math.isfinite(v) else None


@dataclass(frozen=True)
class District:
    """What the runs of one configuration share: the net, its demand, the units and the
    buildings (:func:`prepare_district`; the off and on runs of one seed take the same)."""

    net: Path
    """The SUMO net file."""
    info: NetInfo
    demand: Demand
    units: list[UnitSite]
    buildings: list[BuildingSpec]


def prepare_district(cfg: CityRunConfig, out_dir: Path) -> District:
    """Read the net, generate the demand into ``out_dir/demand``, place the units and
    find the buildings.

    Raises:
        MissingDependencyError: eclipse-sumo is missing.
        ConfigError: a bad net, placement or polygon file.
        SimulationError: SUMO's demand tools failed.
        OutputError: ``out_dir`` cannot be created.
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{out_dir}: cannot create: {err.strerror or err}") from err
    net = cfg.net if cfg.net is not None else district_net()
    info = read_net(net, cfg.origin)
    # the user's files are read before the demand, which takes SUMO's tools a while
    units = placed_units(info, cfg.placement)
    found = buildings(info, units, cfg.polygons)
    demand = generate(net, out_dir / "demand", cfg.demand, cfg.seed)
    return District(net, info, demand, units, found)


def write_identities(cfg: CityRunConfig, root: Path) -> list[str]:
    """The identities of ``cfg``'s district in ``root/keys``
    (:func:`~rfsas_hw.city.deploy.make_identities`: one sensor per unit of the placement,
    one backend per ``cfg.live.backends``, the nonce authority; those found kept), for a
    broker of its own (``rfsas broker config``) before ``run_city(broker=…)``; their ids.

    Raises:
        MissingDependencyError: eclipse-sumo is missing.
        ConfigError: a bad net or placement, or identities found that are not these.
        KeyStoreError: a key directory cannot be read or written.
    """
    net = cfg.net if cfg.net is not None else district_net()
    info = read_net(net, cfg.origin)
    units = [u.id for u in placed_units(info, cfg.placement)]
    backends = backend_names(cfg.live.backends)
    make_identities(root, units, backends)
    return [*units, *backends, AUTHORITY_ID]


def output_files(out_dir: Path, mode: Mode, *, png: bool = True) -> dict[str, Path]:
    """The files a run with RF-SAS ``mode`` writes in ``out_dir``: ``log``
    (``<mode>.log.jsonl``), ``summary`` (``<mode>.summary.json``), ``geojson``
    (``<mode>.map.geojson``) and, with ``png``, ``png`` (``<mode>.map.png``)."""
    files = {
        "log": out_dir / f"{mode}.log.jsonl",
        "summary": out_dir / f"{mode}.summary.json",
        "geojson": out_dir / f"{mode}.map.geojson",
    }
    if png:
        files["png"] = out_dir / f"{mode}.map.png"
    return files


def check_run_outputs(
    out_dir: Path, modes: Sequence[Mode], *, png: bool = True, force: bool = False
) -> None:
    """Check, before any work, that the runs of ``modes`` may write their files in
    ``out_dir`` (:func:`~rfsas_hw.outpaths.check_output`): an earlier run's are replaced
    only with ``force``.

    Raises:
        ConfigError: a file exists without ``force``, or cannot be created there.
    """
    for mode in modes:
        for path in output_files(out_dir, mode, png=png).values():
            check_output(path, force=force)


def run_city(
    cfg: CityRunConfig,
    out_dir: Path,
    mode: Mode = "on",
    *,
    district: District | None = None,
    on_progress: Callable[[Progress], None] | None = None,
    png: bool = True,
    work_dir: Path | None = None,
    broker: BrokerAccess | None = None,
    dashboard: CityDashboard | None = None,
) -> CityRunResult:
    """Run a district once with RF-SAS ``off`` or ``on`` (see the module docstring).

    Args:
        cfg: the run.
        out_dir: where the demand, run log, summary and map go (created); the
            files of a mode are named ``<mode>.log.jsonl``, ``<mode>.summary.json``,
            ``<mode>.map.png``, ``<mode>.map.geojson``.
        mode: ``off`` (SUMO and the scorer only) or ``on`` (the distributed path).
        on_progress: called about once a simulated second.
        png: also draw the map as PNG (needs matplotlib).
        district: the net, demand, units and buildings (:func:`prepare_district`; None:
            prepared here). The off and on runs of one configuration share one.
        work_dir: where the deployment's keys and broker files go (a new folder, or one
            an earlier run wrote; None: a temporary folder, deleted at the end). They
            hold private keys: keep them out of the outputs.
        broker: a running broker to use (None: mosquitto is started on loopback).
        dashboard: a live dashboard to show the run with RF-SAS on (its units, the
            backends' fixes and tracks); the caller starts and closes it.

    Raises:
        MissingDependencyError: eclipse-sumo, libsumo, mosquitto or matplotlib is missing.
        ConfigError: a bad net, placement, polygon file or setting; with ``broker``, a
            party without its certificate.
        SimulationError: SUMO or a process of the distributed path failed.
        OutputError: an output cannot be written.
    """
    if mode not in ("off", "on"):
        raise ConfigError(f"mode must be off or on, not {mode!r}")
    if district is None:
        district = prepare_district(cfg, out_dir)
    net, info, demand, units = district.net, district.info, district.demand, district.units
    files = output_files(out_dir, mode, png=png)
    log = _Log(files["log"])
    records = _LogRecords(log)
    root = logging.getLogger()
    root.addHandler(records)
    try:
        log.write(
            {
                "record": "start",
                "mode": mode,
                "net": str(net),
                "seed": cfg.seed,
                "duration_s": cfg.duration_s,
                "origin": {"lat_deg": info.origin.lat_deg, "lon_deg": info.origin.lon_deg},
                "units": [asdict(u) for u in units],
                "demand": {
                    "vehicles": len(demand.vehicles),
                    "vrus": len(demand.vrus),
                    "with_phone": sum(v.has_phone for v in demand.vrus.values()),
                    "reckless": sum(v.reckless for v in demand.vrus.values()),
                },
                "live": asdict(cfg.live),
            }
        )
        scorer = CityScorer(info.crossings, demand.vrus, cfg.scoring)
        runtime = _run_loop(
            cfg,
            district,
            scorer,
            log,
            mode,
            on_progress,
            work_dir,
            broker,
            dashboard,
            records,
        )
        runtime.log_records = dict(records.counts)
        summary = scorer.summary()
        log.write({"record": "end", "summary": summary.as_dict(), "runtime": asdict(runtime)})
    finally:
        root.removeHandler(records)
        log.close()
    doc = {"summary": summary.as_dict(), "runtime": asdict(runtime)}
    write_text_atomic(files["summary"], json.dumps(doc, indent=2, default=_plain) + "\n")
    from rfsas_hw.city.citymap import write_map

    write_map(scorer, units, info, files.get("png"), files["geojson"])
    return CityRunResult(summary, runtime, units, files)


def sumo_command(cfg: CityRunConfig, info: NetInfo, demand: Demand) -> list[str]:
    """The SUMO command line of a run of ``cfg`` over ``info``'s net and ``demand``."""
    return [
        "sumo",
        "-n",
        str(info.path),
        "-r",
        ",".join(str(p) for p in demand.route_files),
        "--step-length",
        f"{STEP_S:g}",
        "--seed",
        str(cfg.seed),
        "--end",
        f"{cfg.duration_s:g}",
        # SUMO's own collision check only warned (and warnings are off): the scorer finds
        # the collisions itself, so SUMO skips it (the same trajectories, less CPU)
        "--collision.action",
        "none",
        "--no-step-log",
        "true",
        "--no-warnings",
        "true",
        "--ignore-route-errors",
        "true",
    ]


def _run_loop(
    cfg: CityRunConfig,
    district: District,
    scorer: CityScorer,
    log: _Log,
    mode: Mode,
    on_progress: Callable[[Progress], None] | None,
    work_dir: Path | None,
    broker: BrokerAccess | None,
    dashboard: CityDashboard | None,
    log_records: logging.Handler,
) -> Runtime:
    info, demand, units = district.info, district.demand, district.units
    import os

    os.environ.setdefault("SUMO_HOME", str(sumo_home()))
    sumo = load_sumo("libsumo")
    phones = {v.id: v.device_model for v in demand.vrus.values() if v.has_phone and v.device_model}
    runtime = Runtime(mode)
    timers = dict.fromkeys(("sumo", "read", "scoring", "path"), 0.0)
    live: DistributedRfsas | None = None
    tmp: tempfile.TemporaryDirectory[str] | None = None
    cpu0 = cpu_s()
    advisories = brakes = 0
    try:
        if mode == "on":
            if work_dir is None:
                tmp = tempfile.TemporaryDirectory(prefix="rfsas-city-")
                work_dir = Path(tmp.name)
            bridge = BridgeConfig(seed=cfg.seed, backend_profile=cfg.backend_profile)
            live = DistributedRfsas(
                work_dir,
                units,
                district.buildings,
                info.origin,
                info.bounds_m,
                bridge,
                backend_config(bridge),
                replace(cfg.live, dashboard=dashboard is not None),
                broker=broker,
                log_handler=log_records,
            )
            if dashboard is not None:
                dashboard.use_clock(live.clock)
            log.write(
                {
                    "record": "tiles",
                    "plan": {g.name: list(g.tiles) for g in live.plan.groups.values()},
                }
            )
        try:
            start_sumo(sumo, sumo_command(cfg, info, demand))
        except SimulationError as err:
            raise SimulationError(f"{info.path}: {err}") from err
        sim = SumoDistrict(sumo, info.to_frame, info.heading_to_frame, SumoControl(cfg.live.hold_s))
        wall0 = time.monotonic()
        if live is not None:
            live.start()
        steps = round(cfg.duration_s / STEP_S)
        try:
            for k in range(1, steps + 1):
                t = k * STEP_S
                if live is not None:
                    # ahead of the clock (LiveConfig.lead_s): the workers send each frame on time
                    due_s = max(t - live.config.lead_s, 0.0)
                    ahead = live.clock.wall_s(due_s) - (time.monotonic() - wall0)
                    if ahead > 0:
                        time.sleep(ahead)
                    runtime.behind_s = max(runtime.behind_s, -ahead)
                # CPU time of this thread per phase (the wall time would count other
                # processes' turns on a busy machine)
                w = time.thread_time()
                sumo.simulationStep()
                w1 = time.thread_time()
                cars, vrus = sim.read()
                w2 = time.thread_time()
                timers["sumo"] += w1 - w
                timers["read"] += w2 - w1
                # the twin workers and backends get the step before it is scored: they have
                # only the lead's slack, the scorer has the rest of the step
                out = None if live is None else live.step(t, cars, vrus, phones)
                w3 = time.thread_time()
                scorer.step(t, _actors(cars, True), _actors(vrus, False))
                runtime.simulated_s = t
                w4 = time.thread_time()
                timers["scoring"] += w4 - w3
                if out is not None:
                    if dashboard is not None:
                        dashboard.take(out)
                    scorer.messages(out.messages)
                    advised: set[str] = set()
                    for f in out.fixes:
                        scorer.fix(f.t_s, f.emitter, f.person, f.x_m, f.y_m, f.sigma_m)
                    latencies = dict(out.latency)
                    for a in out.arrivals:
                        kind = a.advice
                        latency = latencies.pop((a.backend_id, a.seq), None)
                        scorer.advisory(t, a.vehicle_id, kind, latency)
                        sim.act(t, a.vehicle_id, kind)
                        advised.add(a.vehicle_id)
                        advisories += 1
                        brakes += kind == "brake"
                        _log_arrival(log, t, a, kind, latency)
                    for latency in latencies.values():
                        scorer.latency(latency)  # of an advisory that reached its car earlier
                    sim.release_idle(t, advised)
                    timers["path"] += (w3 - w2) + (time.thread_time() - w4)
                if k % round(1.0 / STEP_S) == 0:
                    elapsed = time.monotonic() - wall0
                    log.write(
                        {
                            "record": "second",
                            "t_s": round(t, 1),
                            "wall_s": round(elapsed, 3),
                            "vehicles": len(cars),
                            "vrus": len(vrus),
                            "vrus_with_phone": sum(v in phones for v in vrus.ids),
                            "advisories": advisories,
                            "brakes": brakes,
                        }
                    )
                    if on_progress is not None:
                        on_progress(
                            Progress(
                                t,
                                cfg.duration_s,
                                len(cars),
                                len(vrus),
                                advisories,
                                brakes,
                                t / max(elapsed, 1e-9),
                            )
                        )
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM: what was simulated is scored and written
            runtime.stopped = "interrupted"
        runtime.wall_s = time.monotonic() - wall0
        wall = runtime.wall_s
        runtime.realtime_factor = runtime.simulated_s / wall if wall > 0 else 0.0
    finally:
        with contextlib.suppress(Exception):  # libsumo raises when nothing runs
            sumo.close()
        stats = live.close() if live is not None else None
        if tmp is not None:
            tmp.cleanup()
    for a in live.late if live is not None else ():
        # reached its vehicle after the simulation's end: logged, not acted on
        _log_arrival(log, runtime.simulated_s, a, a.advice, None)
    _costs(runtime, timers, cpu_s() - cpu0, stats)
    return runtime


def _log_arrival(
    log: _Log, t_s: float, a: Arrival, kind: str, latency: LatencyParts | None
) -> None:
    log.write(
        {
            "record": "advisory",
            "t_s": round(t_s, 1),
            "vehicle": a.vehicle_id,
            "backend": a.backend_id,
            "advice": kind,
            "emitters": list(a.emitters),
            "latency_ms": None if latency is None else _finite(round(latency.total_s * 1e3, 2)),
            # frame → the backend's step, the step → signed, signed → verified at the car
            "latency_parts_ms": None
            if latency is None
            else [_finite(round(part * 1e3, 2)) for part in latency],
            "owned": a.owned,
            "tiles": list(a.tiles),
        }
    )


def _costs(
    runtime: Runtime, timers: dict[str, float], cpu_main: float, stats: LiveStats | None
) -> None:
    """CPU per component: this process's main thread by phase, the vehicles' receivers
    (their thread), the whole of this process (``main-total``: also the broker clients'
    threads), and the other processes' own CPU times."""
    runtime.cpu_s = {k: round(v, 3) for k, v in timers.items()}
    if stats is None:
        return
    vehicles = stats.gateway.get("cpu_s", 0.0)
    runtime.cpu_s["vehicles"] = round(float(vehicles), 3)
    runtime.cpu_s["main-total"] = round(cpu_main, 3)
    for name, w in stats.workers.items():
        runtime.cpu_s[name] = round(w.cpu_s, 3)
    for name, b in stats.backends.items():
        runtime.cpu_s[name] = round(b.cpu_s, 3)
    if stats.broker_cpu_s is not None:  # a broker this run started
        runtime.cpu_s["broker"] = round(stats.broker_cpu_s, 3)
    runtime.counts = {
        "bearing_messages_sent": stats.bearing_messages,
        "bearing_messages_received": stats.bearing_messages_received,
        "bearing_messages_verified": stats.bearing_messages_verified,
        "advisories_sent": stats.advisories_sent,
        "advisories_received": stats.advisories_received,
        "advisories_verified": int(stats.gateway.get("verified", 0)),
        "advisories_foreign": stats.foreign,
        "frames": sum(w.frames for w in stats.workers.values()),
        "bearings": sum(w.bearings for w in stats.workers.values()),
        "phones": sum(w.phones for w in stats.workers.values()),
        "vehicles_judged": sum(b.vehicles_judged for b in stats.backends.values()),
        # car-steps with an emitter within near_m but none within the car's reach
        "vehicles_out_of_reach": sum(b.out_of_reach for b in stats.backends.values()),
        "vehicles_unchanged": sum(b.vehicles_unchanged for b in stats.backends.values()),
        "vehicle_states_held": stats.states_held,
        # groups of bearings (a unit's frames of one 20 ms slot) the workers published
        # more than a slot after their time (the loop behind its lead)
        "bearing_slots": sum(w.slot_groups for w in stats.workers.values()),
        "bearing_slots_late": sum(w.slots_late for w in stats.workers.values()),
        # groups not published at all: older than the receivers' age limit when their
        # time came, so every backend would have refused them as stale
        "bearing_slots_shed": sum(w.slots_shed for w in stats.workers.values()),
    }
    for b in stats.backends.values():
        for k, v in b.stats.items():
            if k.startswith(("link.rejected.", "link.mqtt.dropped", "link.shed")):
                key = "bearing_messages_" + k.removeprefix("link.")
                runtime.counts[key] = runtime.counts.get(key, 0) + v
            elif k.startswith("link.latency.to_"):
                # units' links going silent when no phone is near, and back: counted, not
                # a warning each
                key = "link_state_changes." + k.removeprefix("link.latency.")
                runtime.counts[key] = runtime.counts.get(key, 0) + v
    runtime.problems = list(stats.problems)
