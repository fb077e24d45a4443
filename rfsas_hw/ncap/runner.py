"""One run of the matrix: a cell, a controller, a deployment, a device model, a seed.

Each step (:data:`~rfsas_hw.ncap.world.STEP_S` = 0.05 s) the controllers look
at the world, the brake (:mod:`rfsas_hw.ncap.brake`) gives the VUT's speed,
SUMO moves everyone, and the VRU score (:class:`~rfsas_hw.bridges.vru_score.VruScore`:
boxes decide, SUMO's list is recorded) looks for contact. Controllers:

- ``none``: never brakes (the baseline; it checks the scenario geometry);
- ``los``: the LOS AEB (:mod:`rfsas_hw.ncap.los_aeb`), every step;
- ``rfsas``: the bridge's BRAKE advisories (:class:`~rfsas_hw.bridges.bridge.Bridge`),
  every second step (0.1 s, the backend's step);
- ``rfsas+los``: both; a BRAKE from either brakes, and RF-SAS tracks cue the
  LOS AEB (:mod:`rfsas_hw.ncap.cue`);
- ``los+cue``: the LOS AEB cued by RF-SAS, RF-SAS's own BRAKE ignored (only
  the LOS AEB brakes; RF-SAS only shortens its confirmation).

A run ends at contact, at standstill after braking, or 3 s after the planned
contact. At contact the first-contact instant is found within the step by
bisection (both boxes moved at constant velocity during it): the impact
location is the target centre's offset from the VUT's right edge then, and
the impact speed the VUT's speed (minus the target's along the VUT's heading
in the longitudinal scenarios). Seeds change the radio (the bridge's seed,
SUMO's seed); the LOS AEB and the paths are deterministic.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

from rfsas_hw.bridges.boxes import overlap
from rfsas_hw.bridges.bridge import Bridge, Entity
from rfsas_hw.bridges.vru_score import VruScore
from rfsas_hw.ncap.brake import Brake, BrakeModel
from rfsas_hw.ncap.cue import CueParams, Cues
from rfsas_hw.ncap.los_aeb import LosAeb, LosParams
from rfsas_hw.ncap.rfsas import Deployment, bridge_config
from rfsas_hw.ncap.scenarios import KMH, Cell, Plan, plan, scenario
from rfsas_hw.ncap.world import EGO, STEP_S, SumoWorld

Controller = Literal["none", "los", "rfsas", "rfsas+los", "los+cue"]
CONTROLLERS: tuple[Controller, ...] = ("none", "los", "rfsas", "rfsas+los", "los+cue")
_USES_RF = ("rfsas", "rfsas+los", "los+cue")
_USES_LOS = ("los", "rfsas+los", "los+cue")
_CUED = ("rfsas+los", "los+cue")
_RF_BRAKES = ("rfsas", "rfsas+los")
AFTER_S = 3.0
"""A run ends this long after the planned contact at the latest, seconds."""

__all__ = ["CONTROLLERS", "Controller", "RunResult", "RunSpec", "run_one"]


@dataclass(frozen=True)
class RunSpec:
    """What to run."""

    cell: Cell
    controller: Controller
    deployment: Deployment = "car+rsu"
    device: str = "phone-active"
    seed: int = 0

    @property
    def config(self) -> str:
        """The configuration's name: ``los``, ``rfsas+los/car+rsu/phone-active`` …"""
        if self.controller in ("none", "los"):
            return self.controller
        return f"{self.controller}/{self.deployment}/{self.device}"


@dataclass
class RunResult:
    """The outcome of one run."""

    scenario: str
    cell: str
    vut_speed_kmh: float
    impact: float
    """Planned impact location, fraction of the VUT width from its right edge."""
    config: str
    controller: str
    deployment: str
    device: str
    seed: int
    true_negative: bool
    contact: bool = False
    impact_speed_kmh: float = 0.0
    """Relative impact speed, km/h (0 without contact)."""
    impact_location_m: float | None = None
    """Where the target's centre was at first contact, metres from the VUT's right edge."""
    contact_t_s: float | None = None
    first_brake_s: float | None = None
    """First brake request, seconds (None: no brake)."""
    first_rf_brake_s: float | None = None
    """First BRAKE advisory of RF-SAS, seconds."""
    first_los_confirm_s: float | None = None
    """When the LOS AEB first confirmed a target, seconds."""
    cued_steps: int = 0
    """Steps in which the LOS AEB saw a cued target."""
    min_gap_m: float = math.inf
    seen_by: list[str] = field(default_factory=list)
    final_speed_kmh: float = 0.0
    steps: int = 0
    wall_s: float = 0.0
    """Wall time of the run, seconds."""
    cpu_s: float = 0.0
    """CPU time of the run in its thread (SUMO through libsumo included), seconds."""

    @property
    def nuisance(self) -> bool:
        """A brake in a true-negative scenario."""
        return self.true_negative and self.first_brake_s is not None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (non-finite numbers as None)."""
        out = asdict(self)
        out["nuisance"] = self.nuisance
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in out.items()}  # fmt: skip


def _lerp(a: Entity, b: Entity, s: float) -> Entity:
    return Entity(a.id, a.kind, a.x_m + (b.x_m - a.x_m) * s, a.y_m + (b.y_m - a.y_m) * s,
                  b.heading_deg, b.speed_mps, b.length_m, b.width_m)  # fmt: skip


def _first_contact(e0: Entity, e1: Entity, v0: Entity, v1: Entity) -> tuple[Entity, Entity]:
    """The VUT and the target at first contact within a step (bisection, 16 halvings)."""
    lo, hi = 0.0, 1.0
    for _ in range(16):
        mid = (lo + hi) / 2
        if overlap(_lerp(e0, e1, mid), _lerp(v0, v1, mid)):
            hi = mid
        else:
            lo = mid
    return _lerp(e0, e1, hi), _lerp(v0, v1, hi)


def _right_edge_offset(ego: Entity, tgt: Entity) -> float:
    """The target centre's offset from the VUT's right edge, metres (positive: to its left)."""
    a = math.radians(ego.heading_deg)
    left = -(tgt.x_m - ego.x_m) * math.cos(a) + (tgt.y_m - ego.y_m) * math.sin(a)
    return left + ego.width_m / 2


def run_one(spec: RunSpec) -> RunResult:
    """Run ``spec`` (see the module docstring).

    Raises:
        KeyError: an unknown scenario.
        ValueError: an unknown controller, deployment or device.
        MissingDependencyError: libsumo is missing.
        SimulationError: SUMO fails.
    """
    if spec.controller not in CONTROLLERS:
        raise ValueError(f"unknown controller {spec.controller!r} (known: {CONTROLLERS})")
    wall0 = time.perf_counter()
    cpu0 = time.thread_time()
    p = plan(spec.cell)
    sc = scenario(spec.cell.scenario)
    res = RunResult(
        sc.name, spec.cell.key, spec.cell.vut_speed_kmh, spec.cell.impact, spec.config,
        spec.controller, spec.deployment, spec.device, spec.seed, sc.true_negative,
    )  # fmt: skip
    uses_rf = spec.controller in _USES_RF
    bridge = (
        Bridge(bridge_config(spec.deployment, spec.device, spec.seed, p.obstacles))
        if uses_rf
        else None
    )
    try:
        with SumoWorld(p, seed=spec.seed) as world:
            _loop(world, p, spec, bridge, res)
    finally:
        if bridge is not None:
            bridge.close()
    res.wall_s = time.perf_counter() - wall0
    res.cpu_s = time.thread_time() - cpu0
    return res


def _loop(world: SumoWorld, p: Plan, spec: RunSpec, bridge: Bridge | None, res: RunResult) -> None:
    brake = Brake(BrakeModel(), p.vut_speed_mps)
    los = LosAeb(LosParams(), world.occluders()) if spec.controller in _USES_LOS else None
    cues = Cues(CueParams()) if spec.controller in _CUED else None
    rf_brakes = spec.controller in _RF_BRAKES
    score = VruScore(sumo_counts=False)
    ego, vrus = world.read()
    t = 0.0
    k = 0
    end_s = p.contact_t_s + AFTER_S
    while True:
        targets = [e for e, _ in vrus]
        if bridge is not None and k % 2 == 0:
            out = bridge.step(t, ego, targets)
            if out.advisory == "brake":
                if rf_brakes:
                    brake.request(t)
                if res.first_rf_brake_s is None:
                    res.first_rf_brake_s = t
            if cues is not None:
                cues.add(t, ego, out.assessments)
        if los is not None:
            cued = cues.cued(t, ego, targets) if cues is not None else None
            if cued is not None:
                res.cued_steps += sum(cued)
            if los.step(t, ego, targets, cued):
                brake.request(t)
        speed = brake.advance(t, STEP_S)
        prev_ego, prev = ego, {e.id: e for e, _ in vrus}
        t = world.step(speed)
        k += 1
        ego, vrus = world.read()
        if score.update(EGO, ego, vrus, world.collisions()):
            hit = next(e for e, _ in vrus if e.id == score.collision_with)
            e_c, v_c = _first_contact(prev_ego, ego, prev.get(hit.id, hit), hit)
            res.contact = True
            res.contact_t_s = t - STEP_S + STEP_S * _fraction(prev_ego, ego, e_c)
            res.impact_location_m = _right_edge_offset(e_c, v_c)
            rel = ego.speed_mps
            if p.relative_speed:
                a = math.radians(ego.heading_deg)
                tgt = next(tp for tp in p.targets if hit.id.endswith(tp.id))
                x0, y0, _ = tgt.at(t - STEP_S)
                x1, y1, _ = tgt.at(t)
                rel -= ((x1 - x0) * math.sin(a) + (y1 - y0) * math.cos(a)) / STEP_S
            res.impact_speed_kmh = max(rel, 0.0) / KMH
            break
        if brake.engaged and speed <= 0.0:
            break
        if t >= end_s:
            break
    res.first_brake_s = brake.first_request_s
    res.min_gap_m = score.min_gap_m
    res.seen_by = score.seen_by
    res.final_speed_kmh = ego.speed_mps / KMH
    res.steps = k
    if los is not None and los.first_confirmed_s:
        res.first_los_confirm_s = min(los.first_confirmed_s.values())


def _fraction(e0: Entity, e1: Entity, e_c: Entity) -> float:
    d = math.hypot(e1.x_m - e0.x_m, e1.y_m - e0.y_m)
    return 0.0 if d == 0 else math.hypot(e_c.x_m - e0.x_m, e_c.y_m - e0.y_m) / d
