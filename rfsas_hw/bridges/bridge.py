"""The bridge: one class a simulator adapter calls each step.

An adapter reads its simulator's world, converts it to the rfsas frame
(:mod:`rfsas_hw.bridges.coords`) and calls :meth:`Bridge.step` with the time,
the ego vehicle and every other entity. The bridge runs the real chain:

1. the streaming twin (:class:`~rfsas_hw.twin.stream.StreamTwin`) grows a
   knot per entity, gives new entities a device by kind and penetration rate,
   and computes the frames each unit heard since the last step;
2. each unit's :class:`~rfsas_hw.sources.twinstream.StreamTwinSource` hands
   them to a :class:`~rfsas_hw.pipeline.SensorPipeline` (calibration table,
   monopulse DF, keyed MAC hashing) that makes hashed bearings;
3. the :class:`~rfsas_hw.backend.service.BackendService` associates,
   triangulates, tracks and judges every emitter against the ego vehicle.

:meth:`Bridge.step` returns the bearings, the fixes, the assessments and the
advisory for the ego (the most severe one). Raw MACs stay inside the twin and
the pipeline; the truth (entity ↔ MAC ↔ emitter hash) goes only to the truth
file, for scoring, and never into the backend.

Example::

    from rfsas_hw.bridges.bridge import Bridge, Entity
    from rfsas_hw.bridges.config import load_bridge_config

    bridge = Bridge(load_bridge_config("units.yaml"), truth_path="truth.jsonl")
    for t in steps:
        ego = Entity("ego", "vehicle", x, y, heading, speed, 4.5, 1.8)
        out = bridge.step(t, ego, [Entity("p1", "pedestrian", px, py, ph, 1.3)])
        if out.advisory == "brake":
            ...                  # slow the ego down in the simulator
    bridge.close()
"""

from __future__ import annotations

import json
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Any, Literal

import numpy as np

from rfsas_hw.backend.risk import ADVISORY_RANK
from rfsas_hw.backend.service import BackendService, ResultSink
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.bridges.config import (
    BridgeConfig,
    EgoUnitSpec,
    EntityKind,
    UnitSpec,
    backend_config,
)
from rfsas_hw.bridges.coords import SimFrame
from rfsas_hw.closing import ClosingContext
from rfsas_hw.df.calfile import load_calibration
from rfsas_hw.df.calibration import Calibration
from rfsas_hw.errors import ConfigError, SimulationError
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import DerivedNonces, FixedNonce, MacHasher
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose, emitter_hex, int_to_mac
from rfsas_hw.sources.twinstream import StreamTwinSource
from rfsas_hw.twin.rng import stream
from rfsas_hw.twin.scenario import (
    BuildingSpec,
    EmitterSpec,
    IntersectionSpec,
    MoverSpec,
    Scenario,
    ScenarioSpec,
    SensorSpec,
    WaypointSpec,
    parse_utc_ns,
)
from rfsas_hw.twin.stream import StreamTwin
from rfsas_hw.twin.turntable import turntable_calibration

NS_PER_S = 1_000_000_000
EGO_MOVER = "ego"
"""Mover id of the ego vehicle inside the twin."""

__all__ = [
    "Bridge",
    "BridgeStats",
    "Entity",
    "StepResult",
    "device_mac",
    "device_model_of",
    "fitted_calibration",
]


@dataclass(frozen=True, slots=True)
class Entity:
    """One simulator entity in the rfsas frame."""

    id: str
    """The simulator's id for it."""
    kind: EntityKind
    """``pedestrian``, ``cyclist`` or ``vehicle``."""
    x_m: float
    """East of the site origin, box centre, metres."""
    y_m: float
    """North of the site origin, box centre, metres."""
    heading_deg: float
    """Compass heading, degrees clockwise from north."""
    speed_mps: float = 0.0
    """Speed, m/s."""
    length_m: float = 0.5
    """Box length along the heading, metres."""
    width_m: float = 0.5
    """Box width, metres."""

    @classmethod
    def from_sim(
        cls,
        frame: SimFrame,
        eid: str,
        kind: EntityKind,
        position: tuple[float, float],
        heading: float,
        *,
        speed_mps: float,
        length_m: float,
        width_m: float,
        reference: Literal["centre", "front-bumper"] | None = None,
        origin: tuple[float, float] = (0.0, 0.0),
    ) -> Entity:
        """An entity from the simulator's position and heading in its ``frame``
        (:meth:`~rfsas_hw.bridges.coords.SimFrame.to_rfsas`: ``reference`` and
        ``origin`` as there; the length moves a front-bumper position to the centre)."""
        e, n, h = frame.to_rfsas(
            position[0], position[1], heading, length_m=length_m, reference=reference, origin=origin
        )
        return cls(
            id=eid,
            kind=kind,
            x_m=float(e),
            y_m=float(n),
            heading_deg=float(h),
            speed_mps=float(speed_mps),
            length_m=float(length_m),
            width_m=float(width_m),
        )


@dataclass
class StepResult:
    """What one bridge step produced."""

    t_s: float
    """Simulation time of the step, seconds."""
    t_ns: int
    """The same as UTC nanoseconds."""
    bearings: dict[str, BearingBatch]
    """Hashed bearings of each unit since the previous step."""
    fixes: list[Fix]
    """Fixes triangulated at this step."""
    assessments: list[Assessment]
    """Every live emitter judged against the ego, highest risk first."""
    advisory: Literal["brake", "caution", "clear", "none"]
    """The most severe advisory for the ego (``none``: nothing tracked)."""
    reasons: tuple[str, ...] = ()
    """Why, from the assessment that set the advisory."""

    @property
    def top(self) -> Assessment | None:
        """The assessment that set the advisory."""
        best = None
        for a in self.assessments:
            if best is None or ADVISORY_RANK[a.advisory] > ADVISORY_RANK[best.advisory]:
                best = a
        return best


@dataclass
class BridgeStats:
    """Counters of a bridge run."""

    steps: int = 0
    entities_seen: int = 0
    devices: int = 0
    """Devices handed out (entities with a detectable device; MAC rotations count again)."""
    frames: dict[str, int] = field(default_factory=dict)
    """Frames heard per unit."""
    bearings: dict[str, int] = field(default_factory=dict)
    """Bearings per unit."""

    def as_dict(self) -> dict[str, object]:
        """A JSON-friendly copy."""
        return {
            "steps": self.steps,
            "entities_seen": self.entities_seen,
            "devices": self.devices,
            "frames": dict(self.frames),
            "bearings": dict(self.bearings),
        }


@dataclass
class _Device:
    entity: str
    kind: EntityKind
    model: str
    mac: int
    index: int
    """Emitter index in the twin."""
    since_s: float
    rotation: int


def _unit_sensor(u: UnitSpec | EgoUnitSpec) -> SensorSpec:
    common = {
        "receiver": u.receiver,
        "antenna": u.antenna,
        "driver": u.driver,
        "scan": u.scan,
        "threshold_dbm": dict(u.threshold_dbm),
    }
    if isinstance(u, UnitSpec):
        return SensorSpec(id=u.id, kind="roadside", pose=u.pose, **common)  # type: ignore[arg-type]
    return SensorSpec(
        id=u.id,
        kind="on-board",
        mounted_on=EGO_MOVER,
        heading_offset_deg=u.heading_offset_deg,
        **common,  # type: ignore[arg-type]
    )


def device_mac(config: BridgeConfig, entity: str, rotation: int = 0) -> int:
    """The MAC an entity's device uses in its ``rotation``-th period (drawn from the seed).

    Randomised MACs are locally administered unicast addresses, as phones use.
    """
    value = int(stream(config.seed, "mac", entity, str(rotation)).integers(0, 1 << 48))
    if config.mac.randomise:
        return (value | (0x02 << 40)) & ~(0x01 << 40)
    return value & ~(0x03 << 40)


def device_model_of(config: BridgeConfig, entity: str, kind: EntityKind) -> str | None:
    """The device model an entity carries, or None (drawn once per entity from the seed
    against the kind's penetration rate)."""
    dev = config.devices.get(kind)
    if dev is None or dev.model is None:
        return None
    draw = float(stream(config.seed, "penetration", entity).random())
    return dev.model if draw < dev.penetration else None


_FITTED: dict[tuple[str, int], Calibration] = {}


def fitted_calibration(sensor: SensorSpec, *, seed: int = 0) -> Calibration:
    """A unit's calibration from a simulated turntable run (fitted once per process).

    A real unit is calibrated once and then used in many runs, so the fit is
    seeded by ``seed`` (not by a run's seed) and kept for later bridges.

    Raises:
        CalibrationError: the fit fails (e.g. a field of view too narrow).
    """
    # where the unit stands does not matter on the turntable: units of one build share a fit
    bare = replace(sensor, id="unit", pose=None, mounted_on=None, heading_offset_deg=0.0)
    key = (repr(bare), seed)
    if key not in _FITTED:
        spec = ScenarioSpec(
            version=1, name="turntable", seed=seed, duration_s=1.0, sensors=(bare,), emitters=()
        )
        bench = Scenario(spec=spec, source="<turntable>", base_dir=Path.cwd())
        _FITTED[key] = turntable_calibration(bench, bare.id)
    return _FITTED[key]


class Bridge(ClosingContext):
    """RF-SAS for a simulator (see the module docstring).

    Args:
        config: units, buildings, devices, MAC policy, backend profile.
        buildings: building footprints the simulator reports (added to the
            configured ones; used when ``config.buildings_from_simulator``).
        truth_path: where to write the truth (JSONL); None: no truth file.
        sinks: listeners of the backend's fixes and assessments (e.g. a
            :class:`~rfsas_hw.backend.service.JsonlSink`).

    Raises:
        ConfigError: a calibration file is invalid.
        CalibrationError: the turntable fit fails.
    """

    def __init__(
        self,
        config: BridgeConfig,
        *,
        buildings: Sequence[BuildingSpec] = (),
        truth_path: str | Path | None = None,
        sinks: Sequence[ResultSink] = (),
    ) -> None:
        self.config = config
        extra = tuple(buildings) if config.buildings_from_simulator else ()
        units = [_unit_sensor(u) for u in config.units]
        if config.ego_unit is not None:
            units.append(_unit_sensor(config.ego_unit))
        spec = ScenarioSpec(
            version=1,
            name="bridge",
            seed=config.seed,
            duration_s=1.0,
            sensors=tuple(units),
            emitters=(),
            movers=(MoverSpec(id=EGO_MOVER, kind="vehicle", waypoints=(WaypointSpec(0, 0),)),),
            intersection=IntersectionSpec(buildings=config.buildings + extra),
            rf=config.rf,
            detail=config.detail,
            start_utc=config.start_utc,
        )
        self.scenario = Scenario(spec=spec, source="<bridge>", base_dir=Path.cwd())
        self.t0_ns = parse_utc_ns(config.start_utc)
        nonces = (
            DerivedNonces.from_file(config.nonce_file)
            if config.nonce_file is not None
            else FixedNonce(stream(config.seed, "bridge-nonce").bytes(32))
        )
        self.hasher = MacHasher(nonces)
        specs: list[UnitSpec | EgoUnitSpec] = list(config.units)
        if config.ego_unit is not None:
            specs.append(config.ego_unit)
        self.calibrations: dict[str, Calibration] = {
            u.id: self._calibration(u.id, u) for u in specs
        }
        self.backend = BackendService(backend_config(config), sinks=sinks, clock=self._clock)
        self.stats = BridgeStats()
        self.twin: StreamTwin | None = None
        self._sources: dict[str, StreamTwinSource] = {}
        self._pipelines: dict[str, SensorPipeline] = {}
        self._publishers: dict[str, Any] = {}
        self.sent_bearings = 0
        """Bearings the units' publishers sent (``publish_to``), counted on close."""
        self.send_problems: list[str] = []
        """Why a unit's sending failed (one line per unit), found on close."""
        """Per unit, the publisher of signed messages (with :meth:`publish_to`)."""
        self._mounted = {s.id for s in self.scenario.spec.sensors if s.mounted_on is not None}
        """Units on a vehicle (their pose is looked up every step)."""
        self._devices: dict[str, _Device] = {}
        """Live devices by entity id."""
        self._retired: list[_Device] = []
        self._known: set[str] = set()
        self._present: set[str] = set()
        self._now_ns = self.t0_ns
        self.t_s: float | None = None
        """Time of the last step, seconds."""
        self._truth: IO[str] | None = None
        if truth_path is not None:
            try:
                self._truth = Path(truth_path).open("w", encoding="utf-8")  # noqa: SIM115
            except OSError as err:
                raise SimulationError(f"{truth_path}: cannot write: {err.strerror or err}") from err

    def _clock(self) -> int:
        return self._now_ns

    def publish_to(self, url: str, keys_dir: str | Path) -> None:
        """Also sign every unit's bearings and send them to ``url`` (a separate backend).

        ``keys_dir`` holds one sensor key directory per unit, named by the unit
        id (``rfsas keys new --role sensor --id UNIT -o DIR/UNIT``). Message
        times are simulation times (UTC from ``start_utc``): a backend on the
        wall clock accepts them when the simulation runs in real time from
        ``start_utc`` = now.

        Raises:
            KeyStoreError: a unit's key directory is missing or invalid.
            ConfigError: a key directory belongs to another identity.
            LinkError: the URL is bad or the transport cannot be opened.
        """
        from rfsas_hw.link.keys import KeyStore
        from rfsas_hw.link.publisher import Publisher

        for uid in self.unit_ids:
            store = KeyStore.open(Path(keys_dir) / uid)
            if store.id != uid:
                raise ConfigError(f"{Path(keys_dir) / uid}: keys of {store.id!r}, not of {uid!r}")
            self._publishers[uid] = Publisher.to_url(
                url,
                store.signer(),
                (lambda u=uid: self._pose_of(u)),  # type: ignore[misc]
                clock=self._clock,
                epoch_s=self.hasher.epoch_s,
            )

    def _pose_of(self, unit_id: str) -> Pose:
        pipe = self._pipelines.get(unit_id)
        return pipe.pose if pipe is not None else Pose(0.0, 0.0, 0.0)

    def _calibration(self, sensor_id: str, unit: UnitSpec | EgoUnitSpec) -> Calibration:
        if unit.calibration != "turntable":
            cal = load_calibration(unit.calibration)
        else:
            cal = fitted_calibration(
                self.scenario.sensor(sensor_id), seed=self.config.calibration_seed
            )
        if unit.env_floor_deg is None:
            return cal
        # the site's floor replaces the calibration's own in every table's σ model
        tables = tuple(replace(t, env_floor_deg=unit.env_floor_deg) for t in cal.tables)
        return replace(cal, tables=tables)

    @property
    def unit_ids(self) -> list[str]:
        """Every unit id (roadside units, then the ego's)."""
        return [s.id for s in self.scenario.spec.sensors]

    # -- entities --------------------------------------------------------------------

    def _start(self, t_s: float) -> StreamTwin:
        twin = StreamTwin(self.scenario, start_s=t_s)
        self.twin = twin
        for s in self.scenario.spec.sensors:
            self._sources[s.id] = StreamTwinSource(twin, s.id)
        return twin

    def _pipelines_for(self, twin: StreamTwin, t_s: float) -> None:
        for s in self.scenario.spec.sensors:
            xy, heading = twin.sensor_pose(s, [t_s])
            pose = Pose(float(xy[0, 0]), float(xy[0, 1]), float(heading[0]))
            self._pipelines[s.id] = SensorPipeline(self.calibrations[s.id], self.hasher, s.id, pose)

    def _give_device(self, twin: StreamTwin, e: Entity, t_s: float, rotation: int) -> None:
        name = device_model_of(self.config, e.id, e.kind)
        if name is None:
            return
        model = self.config.device_model(name)
        mac = device_mac(self.config, e.id, rotation)
        while np.any(twin.emitter_macs == np.uint64(mac)):
            mac = (mac + 1) & ((1 << 48) - 1)
        spec = EmitterSpec(
            id=f"{e.id}#{rotation}",
            mac=int_to_mac(mac),
            tech=model.tech,
            traffic=model.traffic,
            tx_power_dbm=model.tx_power_dbm,
            antenna_gain_dbi=model.antenna_gain_dbi,
            carried_by=e.id,
        )
        index = twin.add_emitter(spec, start_s=t_s)
        self._devices[e.id] = _Device(e.id, e.kind, name, mac, index, t_s, rotation)
        self.stats.devices += 1
        self._write_truth(
            {
                "record": "device",
                "t_s": t_s,
                "entity": e.id,
                "kind": e.kind,
                "device": name,
                "mac": int_to_mac(mac),
                "emitter": emitter_hex(self.hasher.hash_one(mac, self._ns(t_s))),
            }
        )

    def _write_truth(self, record: dict[str, object]) -> None:
        if self._truth is not None:
            self._truth.write(json.dumps(record) + "\n")

    def _ns(self, t_s: float) -> int:
        return self.t0_ns + round(t_s * NS_PER_S)

    def _update_entities(self, twin: StreamTwin, t_s: float, entities: Sequence[Entity]) -> None:
        present: set[str] = set()
        rotate = self.config.mac.rotate_s
        for e in entities:
            if e.id == EGO_MOVER:
                raise SimulationError(f"entity id {EGO_MOVER!r} is reserved for the ego vehicle")
            if e.id in present:
                raise SimulationError(f"entity {e.id!r} appears twice in one step")
            present.add(e.id)
            if e.id not in self._known:
                if e.id in twin.live:
                    raise SimulationError(f"entity id {e.id!r} came back after it left")
                twin.add_mover(e.id)
                self._known.add(e.id)
                self.stats.entities_seen += 1
            twin.live[e.id].extend(t_s, e.x_m, e.y_m, e.heading_deg)
            dev = self._devices.get(e.id)
            if dev is None and e.id not in self._present:
                self._give_device(twin, e, t_s, 0)
            elif dev is not None and rotate is not None and t_s - dev.since_s >= rotate:
                twin.retire_emitter(dev.index, t_s)
                self._retired.append(self._devices.pop(e.id))
                self._give_device(twin, e, t_s, dev.rotation + 1)
        for gone in self._present - present:
            dev = self._devices.pop(gone, None)
            if dev is not None:
                twin.retire_emitter(dev.index, t_s)
                self._retired.append(dev)
                self._write_truth({"record": "gone", "t_s": t_s, "entity": gone})
        self._present = present

    # -- the step --------------------------------------------------------------------

    def step(self, t_s: float, ego: Entity, entities: Sequence[Entity]) -> StepResult:
        """Advance to simulation time ``t_s`` and run the whole chain once.

        Args:
            t_s: simulation time, seconds (increasing from step to step).
            ego: the ego vehicle (box centre, rfsas frame).
            entities: every other entity now (rfsas frame); an entity missing
                from a step has left for good.

        Raises:
            SimulationError: time not increasing, an entity id reused or doubled.
        """
        if not math.isfinite(t_s):
            raise SimulationError(f"step time {t_s} is not finite")
        if self.t_s is not None and not t_s > self.t_s:
            raise SimulationError(f"step time {t_s} s is not after the previous {self.t_s} s")
        first = self.twin is None
        twin = self._start(t_s) if self.twin is None else self.twin
        twin.live[EGO_MOVER].extend(t_s, ego.x_m, ego.y_m, ego.heading_deg)
        if first:
            self._pipelines_for(twin, t_s)
        self._update_entities(twin, t_s, entities)
        t_ns = self._ns(t_s)
        self._now_ns = t_ns
        bearings: dict[str, BearingBatch] = {}
        if not first:
            twin.prepare(t_s)  # every unit's window in one pass
            for sid, src in self._sources.items():
                src.horizon_s = t_s
                obs = src.read()
                pipe = self._pipelines[sid]
                if obs is None or not len(obs):
                    bearings[sid] = BearingBatch.empty(sid)
                    continue
                if sid in self._mounted:  # a roadside unit's pose never changes
                    mid_s = (float(statistics.median(obs.t_ns.tolist())) - self.t0_ns) / NS_PER_S
                    xy, heading = twin.sensor_pose(sid, [mid_s])
                    pipe.pose = Pose(float(xy[0, 0]), float(xy[0, 1]), float(heading[0]))
                batch = pipe.process(obs)
                bearings[sid] = batch
                self.stats.frames[sid] = self.stats.frames.get(sid, 0) + len(obs)
                self.stats.bearings[sid] = self.stats.bearings.get(sid, 0) + len(batch)
                if len(batch):
                    self.backend.on_bearings(batch, pipe.pose)
                    publisher = self._publishers.get(sid)
                    if publisher is not None:
                        publisher.on_bearings(batch)
        self.backend.set_vehicle(
            VehicleState(
                x_m=ego.x_m,
                y_m=ego.y_m,
                heading_deg=ego.heading_deg % 360.0,
                speed_mps=max(ego.speed_mps, 0.0),
                length_m=ego.length_m,
                width_m=ego.width_m,
                t_ns=t_ns,
            )
        )
        before = dict(self.backend.fixes)
        assessments = self.backend.step(now_ns=t_ns)
        fixes = [f for k, f in self.backend.fixes.items() if before.get(k) is not f]
        self.t_s = t_s
        self.stats.steps += 1
        result = StepResult(t_s, t_ns, bearings, fixes, assessments, "none")
        top = result.top
        if top is not None:
            result.advisory = top.advisory  # type: ignore[assignment]
            result.reasons = top.reasons
        return result

    # -- scoring -----------------------------------------------------------------------

    def entity_of(self, emitter: str, t_ns: int) -> str | None:
        """Which entity an emitter id (16 hex digits) belonged to at ``t_ns`` (for scoring).

        Looks the id up in the truth kept beside the backend, never in it.
        """
        target = int(emitter, 16)
        for dev in [*self._devices.values(), *self._retired]:
            if self.hasher.hash_one(dev.mac, t_ns) == target:
                return dev.entity
        return None

    def device_of(self, entity: str) -> str | None:
        """The device model an entity carries now (None: no detectable device)."""
        dev = self._devices.get(entity)
        return dev.model if dev is not None else None

    def close(self) -> None:
        """Close the sources, the backend's sinks and the truth file; idempotent."""
        for src in self._sources.values():
            src.close()
        for pub in self._publishers.values():
            pub.close()
            self.sent_bearings += pub.stats.bearings
            problem = pub.problem()
            if problem is not None:
                self.send_problems.append(f"{pub.signer.sender_id}: {problem}")
        self._publishers.clear()
        self.backend.close()
        if self._truth is not None:
            self._write_truth({"record": "stats", **self.stats.as_dict()})
            self._truth.close()
            self._truth = None
