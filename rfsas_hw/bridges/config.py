"""The typed configuration of a simulator bridge (YAML; unknown keys are errors).

Example (every key optional except ``units``)::

    version: 1
    seed: 7
    origin_m: [100.0, 100.0]     # the site origin in the simulator's coordinates
    units:                       # roadside units, rfsas frame (east/north of the origin)
      - id: rsu-ne
        pose: {x_m: 9.0, y_m: 9.0, heading_deg: 225.0}
        calibration: turntable   # or a calibration file, relative to this file
        env_floor_deg: 3.0       # the site's bearing-sigma floor (default: the calibration's)
    ego_unit: {heading_offset_deg: 0.0}   # the ego vehicle's own unit (null: none)
    buildings:                   # added to what the simulator reports
      - {x_min_m: -60, x_max_m: -9, y_min_m: -60, y_max_m: -9, name: sw}
    devices:                     # what each entity kind carries, and how many do
      pedestrian: {model: phone-active, penetration: 1.0}
      cyclist: {model: ble-wearable, penetration: 0.5}
      vehicle: {model: hotspot, penetration: 0.0}
    device_models:               # more models, or replacements of the built-in ones
      phone-quiet: {tech: wifi, traffic: [{model: probe-bursts, interval_s: 10}]}
    mac: {randomise: true, rotate_s: null}
    backend_profile: urban-intersection
    backend_file: null           # a backend YAML that replaces the profile

Built-in device models (:data:`DEVICE_MODELS`): ``phone-active`` (a phone in
use: data bursts on channel 6 every 0.1 s and a probe sweep of channels 1, 6,
11 every 2 s), ``phone-idle`` (probe sweeps every 5 s), ``ble-wearable`` (BLE
advertising every 100 ms; only serial-board receivers hear BLE) and
``hotspot`` (a vehicle's Wi-Fi hotspot beaconing on channel 6).

Named backend profiles (:data:`BACKEND_PROFILES`): ``urban-intersection`` (the
default: units 7–30 m from the threats, so a fix's error ellipse may reach 30 %
of the shortest range before it is called ill-conditioned; a reaction delay of
0.3 s so that a controller that acts one 0.1 s step late still stops; brake
once contact is within twice the stopping distance, but only on a track of at
least 5 fixes since it (re)started), ``urban-intersection-path`` (the same, and a
brake only for a threat in the vehicle's path or moving into it by more than
2 sigma of its speed, see :class:`~rfsas_hw.backend.risk.AdvisoryThresholds`:
for units that see the threat at 10 Hz from its first steps, as in the Euro NCAP
matrix; too strict for threats that appear late and are seen only a few times),
``urban-intersection-bearings`` (the same as ``-path``, the tracks fed by each
unit's bearing within 50° of its boresight instead of by fixes, started with
twice the start fix's sigma, readings taken as censored by the units' edge rule,
see :mod:`rfsas_hw.backend.bearing_tracking`; a standing model beside the
constant velocity, :mod:`rfsas_hw.backend.stop_go`, and a change test on the
standing track that restarts the velocity of a target that starts,
:mod:`rfsas_hw.backend.start_test`; a brake by position only for
a threat inside the path by one sigma of its position: what the Euro NCAP matrix
uses)
and ``backend-defaults`` (the backend's own defaults, tuned for longer ranges).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from rfsas_hw.backend.association import AssociationConfig
from rfsas_hw.backend.bearing_tracking import BearingUpdateConfig
from rfsas_hw.backend.encounter import EncounterConfig
from rfsas_hw.backend.risk import AdvisoryThresholds
from rfsas_hw.backend.service import BackendConfig, load_backend_config
from rfsas_hw.backend.start_test import StartTestConfig
from rfsas_hw.backend.stop_go import StopGoConfig
from rfsas_hw.backend.triangulation import TriangulationOptions
from rfsas_hw.config import from_mapping, read_yaml
from rfsas_hw.errors import ConfigError
from rfsas_hw.twin.scenario import (
    DEFAULT_THRESHOLD_DBM,
    AntennaSpec,
    BuildingSpec,
    Detail,
    DriverSpec,
    PoseSpec,
    ReceiverType,
    RfSpec,
    ScanSpec,
    Tech,
    TrafficSpec,
)

CONFIG_VERSION = 1
"""The bridge configuration format this code reads."""

EntityKind = Literal["pedestrian", "cyclist", "vehicle"]
ENTITY_KINDS: tuple[EntityKind, ...] = ("pedestrian", "cyclist", "vehicle")


@dataclass(frozen=True, kw_only=True)
class UnitHardware:
    """What a unit is built from, roadside or on the ego vehicle (keyword fields,
    after the unit's own id and placement).

    Raises (from the constructor):
        ValueError: a negative or non-finite ``env_floor_deg``.
    """

    receiver: ReceiverType = "radiotap-2-chain"
    """Receiver hardware."""
    antenna: AntennaSpec = field(default_factory=AntennaSpec)
    """The two-beam antenna."""
    calibration: str = "turntable"
    """``turntable`` (fitted on a simulated turntable run) or a calibration file path."""
    driver: DriverSpec = field(default_factory=DriverSpec)
    """Driver quirks."""
    scan: ScanSpec = field(default_factory=ScanSpec)
    """Scan plan."""
    threshold_dbm: dict[str, float] = field(default_factory=dict)
    """Sensitivity per technology, dBm."""
    env_floor_deg: float | None = None
    """Environment floor of the unit's bearings where it is mounted, degrees: the
    angle error that multipath and scatter add beyond the calibration's σ model,
    as a check against known positions measures it there (None: the calibration's
    own floor; 0 for a turntable fit, which sees free space only)."""

    def __post_init__(self) -> None:
        floor = self.env_floor_deg
        if floor is not None and not (math.isfinite(floor) and floor >= 0.0):
            unit = getattr(self, "id", "?")
            raise ValueError(
                f"unit {unit!r}: env_floor_deg must be a finite number ≥ 0, got {floor}"
            )


@dataclass(frozen=True)
class UnitSpec(UnitHardware):
    """A roadside unit: a direction-finding sensor at a fixed pose."""

    id: str
    """Unit id (goes into bearings and messages)."""
    pose: PoseSpec
    """Position (metres east/north of the site origin) and boresight (compass degrees)."""


@dataclass(frozen=True)
class EgoUnitSpec(UnitHardware):
    """The ego vehicle's own unit, riding on it."""

    id: str = "ego-unit"
    """Unit id."""
    heading_offset_deg: float = 0.0
    """Boresight relative to the vehicle's heading, degrees clockwise."""


@dataclass(frozen=True)
class DeviceModel:
    """What a device sends: technology, power and traffic models."""

    tech: Tech
    """``wifi`` or ``ble``."""
    traffic: tuple[TrafficSpec, ...]
    """Traffic models (as in scenario files)."""
    tx_power_dbm: float | None = None
    """Transmit power, dBm (None: 27 for Wi-Fi, 7 for BLE)."""
    antenna_gain_dbi: float = 0.0
    """Transmit antenna gain, dBi."""

    def __post_init__(self) -> None:
        if not self.traffic:
            raise ValueError("a device model needs at least one traffic model")


@dataclass(frozen=True)
class KindDevices:
    """Which device an entity kind carries, and what share of entities carry one."""

    model: str | None = None
    """Device model name (None: nothing detectable)."""
    penetration: float = 1.0
    """Share of entities of this kind with a detectable device, 0–1."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.penetration <= 1.0:
            raise ValueError("penetration must be in [0, 1]")


@dataclass(frozen=True)
class MacPolicy:
    """How device MACs are made."""

    randomise: bool = True
    """Locally administered random MACs, as phones use (False: fixed vendor-style MACs)."""
    rotate_s: float | None = None
    """A randomised MAC changes this often, seconds (None: once per run)."""

    def __post_init__(self) -> None:
        if self.rotate_s is not None and not self.rotate_s > 0:
            raise ValueError("rotate_s must be positive")


DEVICE_MODELS: dict[str, DeviceModel] = {
    "phone-active": DeviceModel(
        tech="wifi",
        tx_power_dbm=20.0,
        traffic=(
            TrafficSpec(model="data-bursts", channels=(6,), interval_s=0.1, burst_frames=3),
            TrafficSpec(model="probe-bursts", channels=(1, 6, 11), interval_s=2.0),
        ),
    ),
    "phone-idle": DeviceModel(
        tech="wifi",
        tx_power_dbm=20.0,
        traffic=(TrafficSpec(model="probe-bursts", channels=(1, 6, 11), interval_s=5.0),),
    ),
    "ble-wearable": DeviceModel(
        tech="ble", tx_power_dbm=0.0, traffic=(TrafficSpec(model="ble-adv", interval_s=0.1),)
    ),
    "hotspot": DeviceModel(
        tech="wifi", tx_power_dbm=20.0, traffic=(TrafficSpec(model="beacon", channels=(6,)),)
    ),
}
"""The built-in device models (see the module docstring)."""


def _urban() -> BackendConfig:
    return BackendConfig(
        association=AssociationConfig(window_s=0.5),
        triangulation=TriangulationOptions(max_range_fraction=0.3),
        encounter=EncounterConfig(
            reaction_s=0.3,
            thresholds=AdvisoryThresholds(stop_margin=2.0, brake_min_fixes=5),
        ),
        step_s=0.1,
    )


def _urban_path() -> BackendConfig:
    base = _urban()
    th = replace(base.encounter.thresholds, brake_needs_path=True, brake_path_sigmas=2.0)
    return replace(base, encounter=replace(base.encounter, thresholds=th))


def _urban_bearings() -> BackendConfig:
    # the start fix's sigma doubled, and only bearings within 50° of a unit's boresight,
    # measured and as the track predicts them: the two-beam units are calibrated over
    # −58° to 57.5° and the DF's edge rule (3 sigma, the site floor at least) lets no
    # reading beyond 48.5° through, so a track predicted further out cannot be what the unit
    # saw, whose reading is then a direction folded back from its side. Measured on the
    # Euro NCAP matrix (docs/ncap.md)
    # Readings near a unit's edge are taken as the DF's edge rule lets them through
    # (censored, fov_deg: the units' calibrated field of view). A person who stops is
    # believed stopped through a standing model beside the constant-velocity one, and a
    # start through a change test on the standing track (docs/ncap.md, "A start
    # detected"; with two roadside units RF-SAS then brakes for the waiting bicyclist
    # of CBNAO at 4.2-4.3 s instead of 4.7 s). A
    # BRAKE by position needs the threat inside the path by one sigma of its position
    # across it (by motion: 2 sigma of its speed; docs/ncap.md, "Evidence of position")
    bearings = BearingUpdateConfig(
        start_sigma_scale=2.0,
        max_off_boresight_deg=50.0,
        fov_deg=(-58.0, 57.5),
        start_test=StartTestConfig(),
    )
    base = _urban_path()
    tracker = replace(base.tracker, stop_go=StopGoConfig())
    th = replace(base.encounter.thresholds, brake_position_sigmas=1.0)
    encounter = replace(base.encounter, thresholds=th)
    return replace(
        base, tracking="bearings", bearings=bearings, tracker=tracker, encounter=encounter
    )


BACKEND_PROFILES: dict[str, BackendConfig] = {
    "urban-intersection": _urban(),
    "urban-intersection-path": _urban_path(),
    "urban-intersection-bearings": _urban_bearings(),
    "backend-defaults": BackendConfig(),
}
"""Named backend settings (see the module docstring)."""


@dataclass(frozen=True)
class BridgeConfig:
    """Everything a :class:`~rfsas_hw.bridges.bridge.Bridge` is built from."""

    units: tuple[UnitSpec, ...] = ()
    """Roadside units."""
    version: int = CONFIG_VERSION
    """Format version."""
    seed: int = 0
    """Seed of every random draw (traffic, radio, devices, MACs, hashing key)."""
    start_utc: str = "2026-01-01T12:00:00Z"
    """UTC time of simulation time 0 (ISO 8601)."""
    origin_m: tuple[float, float] = (0.0, 0.0)
    """The site origin in the simulator's coordinates, metres (for adapters)."""
    ego_unit: EgoUnitSpec | None = field(default_factory=EgoUnitSpec)
    """The ego vehicle's unit (None: roadside units only)."""
    buildings: tuple[BuildingSpec, ...] = ()
    """Building footprints in the rfsas frame (added to any the simulator reports)."""
    buildings_from_simulator: bool = True
    """Whether adapters add the simulator's building polygons."""
    rf: RfSpec = field(default_factory=lambda: RfSpec(fading="rician", rician_k_db=10.0))
    """Propagation settings."""
    detail: Detail = "high"
    """Level of detail of the twin."""
    devices: dict[str, KindDevices] = field(
        default_factory=lambda: {
            "pedestrian": KindDevices("phone-active", 1.0),
            "cyclist": KindDevices("phone-active", 1.0),
            "vehicle": KindDevices("hotspot", 0.0),
        }
    )
    """Device per entity kind (``pedestrian``, ``cyclist``, ``vehicle``)."""
    device_models: dict[str, DeviceModel] = field(default_factory=dict)
    """More device models, or replacements of the built-in ones, by name."""
    mac: MacPolicy = field(default_factory=MacPolicy)
    """MAC randomisation."""
    backend_profile: str = "urban-intersection"
    """Named backend settings (:data:`BACKEND_PROFILES`)."""
    backend_file: str | None = None
    """A backend settings YAML that replaces the profile (relative to this file)."""
    threat_kind: EntityKind = "pedestrian"
    """The box the backend assumes for a located emitter."""
    calibration_seed: int = 0
    """Seed of the simulated turntable runs of units with ``calibration: turntable``."""
    nonce_file: str | None = None
    """A deployment secret for epoch nonces (None: a fixed key from the seed)."""

    def __post_init__(self) -> None:
        if self.version != CONFIG_VERSION:
            raise ValueError(
                f"version {self.version} is not supported (this version reads {CONFIG_VERSION})"
            )
        if not all(math.isfinite(v) for v in self.origin_m):
            raise ValueError("origin_m must be finite")

    def device_model(self, name: str) -> DeviceModel:
        """The model ``name`` (configured ones first, then the built-in ones).

        Raises:
            ConfigError: unknown model.
        """
        models = {**DEVICE_MODELS, **self.device_models}
        try:
            return models[name]
        except KeyError:
            raise ConfigError(
                f"device model {name!r} is not known (known: {', '.join(sorted(models))})"
            ) from None


def _check(cfg: BridgeConfig, where: str) -> None:
    ids = [u.id for u in cfg.units] + ([cfg.ego_unit.id] if cfg.ego_unit else [])
    if len(set(ids)) != len(ids):
        raise ConfigError(f"{where}: units: duplicate unit id")
    if len(ids) < 2:
        raise ConfigError(f"{where}: units: a fix needs at least two units (with the ego unit)")
    for kind in cfg.devices:
        if kind not in ENTITY_KINDS:
            raise ConfigError(
                f"{where}: devices: unknown entity kind {kind!r} (known: {', '.join(ENTITY_KINDS)})"
            )
    for kind, dev in cfg.devices.items():
        if dev.model is not None:
            try:
                model = cfg.device_model(dev.model)
            except ConfigError as err:
                raise ConfigError(f"{where}: devices.{kind}.model: {err}") from None
            for j, tr in enumerate(model.traffic):
                if (tr.model == "ble-adv") != (model.tech == "ble"):
                    raise ConfigError(
                        f"{where}: device model {dev.model!r}: traffic[{j}] {tr.model} "
                        f"does not fit tech {model.tech}"
                    )
    for name, model in cfg.device_models.items():
        if model.tech not in DEFAULT_THRESHOLD_DBM:
            raise ConfigError(f"{where}: device_models.{name}.tech: unknown")
    if cfg.backend_file is None and cfg.backend_profile not in BACKEND_PROFILES:
        raise ConfigError(
            f"{where}: backend_profile {cfg.backend_profile!r} is not known "
            f"(known: {', '.join(sorted(BACKEND_PROFILES))})"
        )


def bridge_config_from_mapping(
    data: Any, where: str = "<mapping>", base_dir: Path | None = None
) -> BridgeConfig:
    """Check and build a bridge configuration from parsed YAML.

    Relative file names (calibrations, ``backend_file``, ``nonce_file``) are
    resolved against ``base_dir``.

    Raises:
        ConfigError: unknown key, wrong type, bad value, broken reference.
    """
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping at the top level")
    cfg = from_mapping(BridgeConfig, data, where)
    _check(cfg, where)
    if base_dir is not None:
        cfg = _resolve(cfg, base_dir)
    return cfg


def _path(value: str, base: Path) -> str:
    p = Path(value)
    return str(p if p.is_absolute() else base / p)


def _resolve(cfg: BridgeConfig, base: Path) -> BridgeConfig:
    units = tuple(
        u if u.calibration == "turntable" else replace(u, calibration=_path(u.calibration, base))
        for u in cfg.units
    )
    ego = cfg.ego_unit
    if ego is not None and ego.calibration != "turntable":
        ego = replace(ego, calibration=_path(ego.calibration, base))
    return replace(
        cfg,
        units=units,
        ego_unit=ego,
        backend_file=None if cfg.backend_file is None else _path(cfg.backend_file, base),
        nonce_file=None if cfg.nonce_file is None else _path(cfg.nonce_file, base),
    )


def load_bridge_config(path: str | Path) -> BridgeConfig:
    """Read and check a bridge configuration file.

    Raises:
        ConfigError: unreadable file, invalid YAML, unknown key, bad value.
    """
    p = Path(path)
    return bridge_config_from_mapping(read_yaml(p), str(p), p.resolve().parent)


def backend_config(cfg: BridgeConfig) -> BackendConfig:
    """The backend settings of ``cfg``: its ``backend_file``, or its named profile.

    Raises:
        ConfigError: the file is invalid.
    """
    base = (
        load_backend_config(cfg.backend_file)
        if cfg.backend_file is not None
        else BACKEND_PROFILES[cfg.backend_profile]
    )
    enc = replace(base.encounter, threat_kind=cfg.threat_kind)
    return replace(base, encounter=enc)
