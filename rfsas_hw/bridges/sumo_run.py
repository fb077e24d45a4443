"""Closed loop in SUMO: run a scenario over seeds with RF-SAS steering the ego, and score it.

One run file configures both sides: the bridge (units, devices, backend
profile; :mod:`rfsas_hw.bridges.config`) and a ``sumo:`` section
(:class:`SumoRunConfig`: which vehicle is the ego, how advisories act, how
walking speeds vary by seed). Per seed, SUMO gets ``--seed``, the bridge the
same seed, and every person a walking speed drawn from it.

Seeds run on the project's runner (:func:`run_seeds` through
:mod:`rfsas_hw.parallel`): side by side on Dask workers, each a
:class:`SeedJob` with its own SUMO, or one after the other in this process;
the results do not depend on the number of workers.

Controllers: ``rfsas`` (advisories act on the ego), ``ignore`` (RF-SAS runs,
the ego ignores it: the baseline with advisory times) and ``off`` (no RF-SAS
at all: the fastest baseline).

Scored per seed (:class:`SeedResult`): collision with a vulnerable road user
(a person, or a ``bicycle``, ``moped`` or ``motorcycle`` vehicle) and the
ego's speed then, per VRU class the smallest gap between the ego's box and
the VRU's (oriented rectangles, :mod:`rfsas_hw.bridges.boxes`), whether SUMO's
own collision list saw the collision too, the first
CAUTION and BRAKE, how many fixes were trustworthy and their median error
against the truth (looked up beside the backend, never in it), and the wall
time of SUMO's steps and the bridge's.
"""

from __future__ import annotations

import datetime as dt
import io
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import IO, Any, Literal

import numpy as np

from rfsas_hw.bridges.bridge import Bridge, Entity, StepResult
from rfsas_hw.bridges.config import BridgeConfig, bridge_config_from_mapping
from rfsas_hw.bridges.sumo import (
    SumoAdapter,
    SumoApi,
    SumoControl,
    load_sumo,
    read_buildings,
    start_sumo,
)
from rfsas_hw.bridges.vru_score import VruScore, vru_class
from rfsas_hw.config import from_mapping, read_yaml
from rfsas_hw.errors import ConfigError, SimulationError
from rfsas_hw.parallel import completed, in_order
from rfsas_hw.twin.rng import stream

Controller = Literal["rfsas", "ignore", "off"]

__all__ = [
    "RunSummary",
    "SeedJob",
    "SeedResult",
    "SumoRunConfig",
    "load_run_file",
    "run_job",
    "run_seed",
    "run_seeds",
]


@dataclass(frozen=True)
class SumoRunConfig:
    """The ``sumo:`` section of a run file."""

    ego: str = "ego"
    """SUMO id of the ego vehicle."""
    hold_s: float = 1.0
    """A BRAKE holds the ego stopped until no BRAKE came for this long, seconds."""
    caution_speed_mps: float | None = None
    """Speed cap under CAUTION, m/s (None: no cap)."""
    person_speed_mps: tuple[float, float] | None = None
    """Range of each person's walking speed, drawn per seed, m/s (None: SUMO's own)."""
    end_s: float = 60.0
    """End a seed at this simulation time at the latest, seconds."""
    end_when_passed: bool = True
    """End a seed once every person is behind the ego's rear bumper."""
    ego_speed_mode: int | None = 38
    """SUMO speed mode given to the ego when it appears. 38 keeps the limits of
    acceleration and deceleration but drops SUMO's own yielding and safe-speed
    rules: the driver does not see the hidden pedestrian, so only RF-SAS can
    stop the car. None: SUMO's default (31)."""

    def __post_init__(self) -> None:
        if self.person_speed_mps is not None:
            lo, hi = self.person_speed_mps
            if not 0 < lo <= hi:
                raise ValueError("person_speed_mps must be [low, high] with 0 < low <= high")
        if not self.end_s > 0:
            raise ValueError("end_s must be positive")
        if not 0 <= self.hold_s < math.inf:
            raise ValueError("hold_s must be a number of seconds >= 0")
        if self.caution_speed_mps is not None and not 0 < self.caution_speed_mps < math.inf:
            raise ValueError("caution_speed_mps must be a positive speed, m/s")


def load_run_file(path: str | Path) -> tuple[BridgeConfig, SumoRunConfig]:
    """The bridge settings and the ``sumo:`` section of a run file.

    Raises:
        ConfigError: unreadable file, invalid YAML, unknown key or bad value.
    """
    p = Path(path)
    data = read_yaml(p) or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a mapping at the top level")
    data = dict(data)
    section = data.pop("sumo", None) or {}
    if not isinstance(section, dict):
        raise ConfigError(f"{p}: sumo: expected a mapping")
    run = from_mapping(SumoRunConfig, section, f"{p}: sumo")
    return bridge_config_from_mapping(data, str(p), p.resolve().parent), run


@dataclass
class SeedResult:
    """The outcome of one seed."""

    seed: int
    controller: Controller
    collision: bool = False
    """The ego hit a VRU (a person or a two-wheeler)."""
    collision_t_s: float | None = None
    collision_class: str | None = None
    """The VRU class of what the ego hit (``pedestrian``, ``bicycle``, ``moped`` …)."""
    collision_seen_by: list[str] = field(default_factory=list)
    """Who saw the collision: ``boxes`` (the ego's and the VRU's boxes overlap) and/or
    ``sumo`` (SUMO's own collision list)."""
    impact_speed_mps: float = 0.0
    """The ego's speed at the collision, m/s (0 without one)."""
    min_gap_m: float = math.inf
    """Smallest distance between the ego's box and any VRU's box, metres."""
    min_gap_by_class: dict[str, float] = field(default_factory=dict)
    """The same per VRU class, metres."""
    first_caution_s: float | None = None
    first_brake_s: float | None = None
    stopped: bool = False
    """The ego came to a stop."""
    fixes_ok: int = 0
    fixes_flagged: int = 0
    median_fix_error_m: float = math.nan
    """Median distance of trustworthy fixes from the person they belong to, metres."""
    steps: int = 0
    sumo_ms: float = math.nan
    """Mean wall time of one SUMO step, milliseconds."""
    bridge_ms: float = math.nan
    """Mean wall time of one bridge step, milliseconds."""
    sent: int = 0
    """Bearings sent to a separate backend (``send``)."""
    send_problems: list[str] = field(default_factory=list)
    """Why sending failed, one line per unit (empty: it did not, or nothing was sent)."""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (non-finite numbers as None)."""
        return {k: _json_ready(v) for k, v in asdict(self).items()}


def _json_ready(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _json_ready(x) for k, x in v.items()}
    return v


@dataclass
class RunSummary:
    """Seeds of one controller, summed up."""

    controller: Controller
    results: list[SeedResult] = field(default_factory=list)

    @property
    def collisions(self) -> int:
        """Seeds with a collision."""
        return sum(r.collision for r in self.results)

    def collisions_by_class(self) -> dict[str, int]:
        """Seeds with a collision, per VRU class."""
        out: dict[str, int] = {}
        for r in self.results:
            if r.collision and r.collision_class is not None:
                out[r.collision_class] = out.get(r.collision_class, 0) + 1
        return out

    @property
    def brakes(self) -> int:
        """Seeds with at least one BRAKE."""
        return sum(r.first_brake_s is not None for r in self.results)

    def impact_speeds(self) -> list[float]:
        """Impact speeds of the seeds with a collision, m/s."""
        return [r.impact_speed_mps for r in self.results if r.collision]

    def row(self) -> dict[str, Any]:
        """One line of the docs table."""
        speeds = self.impact_speeds()
        brakes = [r.first_brake_s for r in self.results if r.first_brake_s is not None]
        errors = [r.median_fix_error_m for r in self.results if math.isfinite(r.median_fix_error_m)]
        gaps = [r.min_gap_m for r in self.results]
        return {
            "controller": self.controller,
            "seeds": len(self.results),
            "collisions": self.collisions,
            "collisions_by_class": self.collisions_by_class(),
            "mean_impact_mps": float(np.mean(speeds)) if speeds else 0.0,
            "max_impact_mps": max(speeds) if speeds else 0.0,
            "median_min_gap_m": float(np.median(gaps)) if gaps else math.nan,
            "seeds_with_brake": self.brakes,
            "median_first_brake_s": float(np.median(brakes)) if brakes else math.nan,
            "fixes_ok": sum(r.fixes_ok for r in self.results),
            "median_fix_error_m": float(np.median(errors)) if errors else math.nan,
            "sumo_ms": _mean([r.sumo_ms for r in self.results]),
            "bridge_ms": _mean([r.bridge_ms for r in self.results]),
        }


def _mean(values: list[float]) -> float:
    """Mean of the finite values (NaN when there is none)."""
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def _behind(ego: Entity, other: Entity) -> bool:
    """Whether ``other``'s centre is behind the ego's rear bumper (nothing left to hit)."""
    a = math.radians(ego.heading_deg)
    along = (other.x_m - ego.x_m) * math.sin(a) + (other.y_m - ego.y_m) * math.cos(a)
    return along < -ego.length_m / 2


def _vrus(adapter: SumoAdapter, others: Sequence[Entity]) -> list[tuple[Entity, str]]:
    """The VRUs among ``others``, each with its class."""
    out = []
    for o in others:
        cls = vru_class(o.kind, adapter.vehicle_class(o.id))
        if cls is not None:
            out.append((o, cls))
    return out


def _step_line(seed: int, res: StepResult, action: str, ego: Entity) -> dict[str, Any]:
    top = res.top
    return {
        "record": "step",
        "seed": seed,
        "t_s": round(res.t_s, 3),
        "advisory": res.advisory,
        "action": action,
        "ego": {
            "x_m": round(ego.x_m, 3),
            "y_m": round(ego.y_m, 3),
            "speed_mps": round(ego.speed_mps, 3),
        },
        "bearings": {k: len(v) for k, v in res.bearings.items()},
        "fixes": [f.as_dict() for f in res.fixes],
        "top": top.as_dict() if top is not None else None,
    }


def run_seed(
    sumocfg: str | Path,
    config: BridgeConfig,
    run: SumoRunConfig,
    seed: int,
    *,
    controller: Controller = "rfsas",
    api: SumoApi = "libsumo",
    gui: bool = False,
    out: IO[str] | None = None,
    truth_path: str | Path | None = None,
    fcd_path: str | Path | None = None,
    on_step: Callable[[float], None] | None = None,
    send: str | None = None,
    keys_dir: str | Path | None = None,
) -> SeedResult:
    """Run one seed of a SUMO scenario closed loop and score it.

    Args:
        sumocfg: a ``.sumocfg`` file (or a ``.net.xml`` with routes given in it).
        config: the bridge settings (their ``seed`` is replaced by ``seed``).
        run: the ``sumo:`` section.
        seed: SUMO's ``--seed``, the bridge's seed and the walking-speed draw.
        controller: ``rfsas``, ``ignore`` or ``off`` (see the module docstring).
        api: ``libsumo`` (in-process) or ``traci`` (a SUMO process; needed for ``gui``).
        gui: run ``sumo-gui`` (TraCI only).
        out: where step lines go (JSON per line; hashed ids only).
        truth_path: the bridge's truth file.
        fcd_path: SUMO's FCD output (for the offline path).
        on_step: called with the simulation time after every step (a progress bar).
        send: also send every unit's signed bearings to this URL (a separate
            ``rfsas backend``); the run is then paced to the wall clock and
            simulation time 0 is the moment it starts.
        keys_dir: one sensor key directory per unit id (needed with ``send``).

    Raises:
        MissingDependencyError: the SUMO API is missing.
        SimulationError: SUMO cannot start, or the ego never appears.
    """
    from dataclasses import replace

    if gui and api != "traci":
        raise ConfigError("--gui needs the TraCI API (sumo-gui runs as its own process)")
    sumo = load_sumo(api)
    cmd = ["sumo-gui" if gui else "sumo"]
    cfg_path = Path(sumocfg)
    cmd += ["-c", str(cfg_path)] if cfg_path.suffix == ".sumocfg" else ["-n", str(cfg_path)]
    cmd += ["--seed", str(seed), "--collision.check-junctions", "true"]
    cmd += ["--collision.action", "warn", "--no-step-log", "true", "--no-warnings", "true"]
    if fcd_path is not None:
        cmd += ["--fcd-output", str(fcd_path)]
    if gui:
        cmd += ["--start", "true", "--quit-on-end", "true"]
    try:
        start_sumo(sumo, cmd)
    except SimulationError as err:
        raise SimulationError(f"{cfg_path}: {err}") from err
    result = SeedResult(seed=seed, controller=controller)
    bridge: Bridge | None = None
    try:
        adapter = SumoAdapter(
            sumo,
            run.ego,
            origin=config.origin_m,
            control=SumoControl(run.hold_s, run.caution_speed_mps),
        )
        if controller != "off":
            buildings = read_buildings(sumo, config.origin_m)
            cfg = replace(config, seed=seed)
            if send is not None:
                now = dt.datetime.now(dt.UTC).isoformat().replace("+00:00", "Z")
                cfg = replace(cfg, start_utc=now)
            bridge = Bridge(cfg, buildings=buildings, truth_path=truth_path)
            if send is not None:
                if keys_dir is None:
                    raise ConfigError("sending needs the units' key directories (--keys)")
                bridge.publish_to(send, keys_dir)
        _loop(sumo, adapter, bridge, run, result, controller, out, on_step, send is not None)
    finally:
        if bridge is not None:
            bridge.close()
            result.sent = bridge.sent_bearings
            result.send_problems = list(bridge.send_problems)
        sumo.close()
    if not adapter.ego_seen:
        raise SimulationError(f"{cfg_path}: the ego vehicle {run.ego!r} never appeared")
    return result


def _loop(
    sumo: Any,
    adapter: SumoAdapter,
    bridge: Bridge | None,
    run: SumoRunConfig,
    result: SeedResult,
    controller: Controller,
    out: IO[str] | None,
    on_step: Callable[[float], None] | None,
    realtime: bool = False,
) -> None:
    speeds_set: set[str] = set()
    wall0 = time.monotonic()
    sumo_s: list[float] = []
    bridge_s: list[float] = []
    errors: list[float] = []
    score = VruScore()
    while True:
        w0 = time.perf_counter()
        sumo.simulationStep()
        sumo_s.append(time.perf_counter() - w0)
        t = float(sumo.simulation.getTime())
        if realtime:
            ahead = t - (time.monotonic() - wall0)
            if ahead > 0:
                time.sleep(ahead)
        if run.person_speed_mps is not None:
            for pid in sumo.person.getIDList():
                if pid not in speeds_set:
                    lo, hi = run.person_speed_mps
                    v = lo + (hi - lo) * float(stream(result.seed, "walk-speed", pid).random())
                    sumo.person.setSpeed(pid, v)
                    speeds_set.add(pid)
        seen_before = adapter.ego_seen
        ego, others = adapter.read()
        if ego is not None and not seen_before and run.ego_speed_mode is not None:
            sumo.vehicle.setSpeedMode(run.ego, run.ego_speed_mode)
        if on_step is not None:
            on_step(t)
        if ego is None:
            if adapter.ego_seen or t >= run.end_s or sumo.simulation.getMinExpectedNumber() == 0:
                break
            continue
        result.steps += 1
        vrus = _vrus(adapter, others)
        hit = score.update(run.ego, ego, vrus, sumo.simulation.getCollisions())
        if ego.speed_mps < 0.05 and result.steps > 1:
            result.stopped = True
        if bridge is not None:
            w0 = time.perf_counter()
            res = bridge.step(t, ego, others)
            bridge_s.append(time.perf_counter() - w0)
            action = adapter.act(t, res.advisory) if controller == "rfsas" and not hit else "none"
            if res.advisory == "caution" and result.first_caution_s is None:
                result.first_caution_s = t
            if res.advisory == "brake" and result.first_brake_s is None:
                result.first_brake_s = t
            where = {o.id: o for o in others}
            for f in res.fixes:
                if not f.ok:
                    result.fixes_flagged += 1
                    continue
                result.fixes_ok += 1
                who = bridge.entity_of(f.emitter, res.t_ns)
                if who is not None and who in where:
                    errors.append(math.hypot(f.x_m - where[who].x_m, f.y_m - where[who].y_m))
            if out is not None:
                out.write(json.dumps(_step_line(result.seed, res, action, ego)) + "\n")
        if hit:
            result.collision_t_s = t
            result.impact_speed_mps = ego.speed_mps
            break
        if t >= run.end_s or (
            run.end_when_passed and vrus and all(_behind(ego, p) for p, _ in vrus)
        ):
            break
    result.collision = score.collision
    result.collision_class = score.collision_class
    result.collision_seen_by = score.seen_by if score.collision else []
    result.min_gap_m = score.min_gap_m
    result.min_gap_by_class = score.min_gap_by_class
    result.sumo_ms = float(np.mean(sumo_s)) * 1e3 if sumo_s else math.nan
    result.bridge_ms = float(np.mean(bridge_s)) * 1e3 if bridge_s else math.nan
    result.median_fix_error_m = float(np.median(errors)) if errors else math.nan


@dataclass(frozen=True)
class SeedJob:
    """One seed of a ``sumo run`` as handed to the runner (picklable: it may run in a worker
    process)."""

    sumocfg: Path
    config: BridgeConfig
    run: SumoRunConfig
    seed: int
    controller: Controller = "rfsas"
    api: SumoApi = "libsumo"
    truth_path: Path | None = None
    fcd_path: Path | None = None
    keep_steps: bool = False
    """Give the step lines back (JSON lines, hashed ids only)."""
    gui: bool = False
    send: str | None = None
    keys_dir: Path | None = None


def run_job(job: SeedJob, on_step: Callable[[float], None] | None = None) -> tuple[SeedResult, str]:
    """:func:`run_seed` of ``job``; its result and its step lines (empty unless
    ``job.keep_steps``).

    Raises:
        as :func:`run_seed`.
    """
    lines = io.StringIO() if job.keep_steps else None
    result = run_seed(
        job.sumocfg, job.config, job.run, job.seed, controller=job.controller, api=job.api,
        gui=job.gui, out=lines, truth_path=job.truth_path, fcd_path=job.fcd_path,
        on_step=on_step, send=job.send, keys_dir=job.keys_dir,
    )  # fmt: skip
    return result, lines.getvalue() if lines is not None else ""


def run_seeds(
    sumocfg: str | Path,
    config: BridgeConfig,
    run: SumoRunConfig,
    seeds: Sequence[int],
    *,
    controller: Controller = "rfsas",
    api: SumoApi = "libsumo",
    out: IO[str] | None = None,
    on_seed: Callable[[SeedResult], None] | None = None,
    truth_paths: Mapping[int, Path] | None = None,
    fcd_path: Path | None = None,
    workers: int = 0,
    scheduler: str | None = None,
    on_step: Callable[[int, float], None] | None = None,
    gui: bool = False,
    send: str | None = None,
    keys_dir: Path | None = None,
) -> RunSummary:
    """:func:`run_seed` for every seed on the project's runner (:mod:`rfsas_hw.parallel`:
    ``workers`` processes of a local Dask cluster, a ``scheduler``, or this process with
    ``workers=0``); the summary, seeds in the given order.

    Every seed is its own SUMO run with its own seed, so the results do not depend on
    ``workers``. ``out`` gets each seed's step lines and then its ``seed`` record, seed by
    seed in the given order (a seed that finished early waits for the ones before it).

    Args:
        truth_paths: the bridge's truth file per seed.
        fcd_path: SUMO's FCD output of the first seed.
        on_seed: called with each seed's result, in the given order.
        on_step: called with the seed and the simulation time after every step; only
            when running here (``workers=0`` and no scheduler).
        gui, send, keys_dir: as :func:`run_seed`; only when running here.

    Raises:
        ConfigError: repeated seeds, or ``gui``/``send`` with workers or a scheduler.
        MissingDependencyError: Dask distributed is needed and not installed.
        as :func:`run_seed` (the first failing seed's error).
    """
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"seeds must be distinct, got {list(seeds)}")
    here = workers == 0 and scheduler is None
    if (gui or send is not None) and not here:
        raise ConfigError(
            "--gui and --send run the seeds in this process, one after the other "
            "(not with --workers or --scheduler)"
        )
    jobs = [
        SeedJob(
            Path(sumocfg), config, run, seed, controller, api,
            truth_path=(truth_paths or {}).get(seed),
            fcd_path=fcd_path if k == 0 else None,
            keep_steps=out is not None, gui=gui, send=send, keys_dir=keys_dir,
        )
        for k, seed in enumerate(seeds)
    ]  # fmt: skip
    fn: Callable[[SeedJob], tuple[SeedResult, str]] = run_job
    if here and on_step is not None:
        step = on_step

        def fn(job: SeedJob) -> tuple[SeedResult, str]:
            return run_job(job, lambda t: step(job.seed, t))

    summary = RunSummary(controller)
    pairs = completed(fn, jobs, workers=workers, scheduler=scheduler, name="sumo-seed")
    try:
        for _, (r, lines) in in_order(pairs):
            summary.results.append(r)
            if out is not None:
                out.write(lines)
                out.write(json.dumps({"record": "seed", **r.as_dict()}) + "\n")
            if on_seed is not None:
                on_seed(r)
    finally:
        pairs.close()
    return summary
