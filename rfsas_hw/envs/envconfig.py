"""Typed configuration of the intersection environment (method.md §10).

Every field has a default that reproduces the documented set-up: a car
approaching the intersection from the south at 20 m/s, a cyclist with a phone
riding east on the cross street, hidden by the south-west building, a roadside
unit on the south-east corner looking west, and the car's own sensor. Built from
YAML or a mapping with :func:`env_config_from_mapping`, which rejects unknown
keys with the key path.

Geometry: metres east/north of the intersection centre; headings compass
degrees. The car drives north along the lane ``x = lane_x_m``; distances are
measured from the car's front bumper to the intersection centre.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from rfsas_hw.config import from_mapping, read_yaml
from rfsas_hw.errors import ConfigError
from rfsas_hw.twin.scenario import BuildingSpec, Detail

RewardKind = Literal["method", "risk-progress"]
ObstacleKind = Literal["pedestrian", "cyclist", "vehicle"]


def _default_buildings() -> tuple[BuildingSpec, ...]:
    """The four corner blocks of the bundled crossing scenario."""
    return (
        BuildingSpec(10.0, 60.0, -60.0, -10.0, "south-east", 25.0),
        BuildingSpec(10.0, 60.0, 10.0, 60.0, "north-east", 25.0),
        BuildingSpec(-60.0, -10.0, 10.0, 60.0, "north-west", 25.0),
        BuildingSpec(-60.0, -10.0, -60.0, -10.0, "south-west", 25.0),
    )


@dataclass(frozen=True)
class VehicleConfig:
    """The car the agent drives."""

    start_distance_m: float = 100.0
    """Distance of the front bumper south of the intersection centre at reset, metres."""
    initial_speed_mps: tuple[float, float] = (20.0, 20.0)
    """Range the speed at reset is drawn from (uniform), m/s."""
    max_speed_mps: float = 20.0
    """Speed limit; the speed is clamped to [0, max], m/s."""
    brake_mps2: float = 4.7
    """Deceleration of the brake action, m/s² (positive)."""
    accel_mps2: float = 2.0
    """Acceleration of the accelerate action, m/s²."""
    lane_x_m: float = 1.75
    """East coordinate of the lane centre, metres."""
    length_m: float = 4.5
    """Length of the car, metres."""
    width_m: float = 1.8
    """Width of the car, metres."""
    sigma_along_m: float = 3.0
    """One-sigma position error of the car along its heading (method.md §6), metres."""
    sigma_across_m: float = 1.0
    """One-sigma position error across its heading, metres."""

    def __post_init__(self) -> None:
        lo, hi = self.initial_speed_mps
        if not 0 < lo <= hi <= self.max_speed_mps:
            raise ValueError("initial_speed_mps must satisfy 0 < low <= high <= max_speed_mps")
        if self.brake_mps2 <= 0 or self.accel_mps2 < 0:
            raise ValueError("brake_mps2 must be > 0 and accel_mps2 >= 0")
        if self.start_distance_m <= 0 or self.length_m <= 0 or self.width_m <= 0:
            raise ValueError("start_distance_m, length_m and width_m must be positive")


@dataclass(frozen=True)
class ObstacleConfig:
    """The hidden road user crossing the car's path on the cross street.

    It rides at constant speed along ``crossing_y_m``; the building on the
    corner it comes from hides it from the car until shortly before the
    conflict, which is what makes an RF warning worth having.
    """

    kind: ObstacleKind = "cyclist"
    """What it is (sets its box, see :data:`rfsas_hw.backend.collision.THREAT_SIZES`)."""
    direction: Literal["east", "west"] = "east"
    """Which way it travels (east: it comes from behind the south-west building)."""
    crossing_y_m: float = -3.5
    """North coordinate of its path, metres (the near lane of the cross street)."""
    speed_mps: tuple[float, float] = (4.0, 7.0)
    """Range of its speed, m/s."""
    lane_arrival_s: tuple[float, float] = (4.0, 6.0)
    """Range of the time its centre reaches the car's lane centre, seconds after reset
    (a car holding 20 m/s reaches the path after about 4.9 s)."""
    tx_power_dbm: float = 20.0
    """Transmit power of the phone it carries (Wi-Fi), dBm."""
    channel: int = 6
    """Wi-Fi channel the phone transmits on."""

    @property
    def heading_deg(self) -> float:
        """Compass heading of its motion, degrees."""
        return 90.0 if self.direction == "east" else 270.0

    def __post_init__(self) -> None:
        for name in ("speed_mps", "lane_arrival_s"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ValueError(f"{name} must be (low, high) with low <= high")
        if self.speed_mps[0] <= 0:
            raise ValueError("speed_mps must be > 0")


@dataclass(frozen=True)
class SensingConfig:
    """How the car's backend learns about the obstacle (method.md §8, §10)."""

    detail: Detail = "low"
    """Level of detail: ``low`` (parametric state), ``medium`` (bearings with σ from
    the SNR formulas, triangulated), ``high`` (RSSI from the physical model through
    the DF pipeline, triangulated)."""
    reaction_delay_s: float = 0.2
    """Message transmission plus computation after the first intercept, seconds."""
    intercept_s: tuple[float, float] = (0.0, 4.0)
    """Range of the time to first intercept of the phone (scan over ~40 channels), seconds."""
    low_sigma_m: float = 0.7
    """``low`` detail: one-sigma error of each position fix, metres."""
    frame_interval_s: float = 0.1
    """Time between frames of the phone heard by each sensor, seconds."""
    roadside: tuple[tuple[float, float, float], ...] = ((8.5, -8.7, 275.0), (-8.5, 8.7, 225.0))
    """Roadside units as (x_m, y_m, boresight compass degrees): the south-east corner
    looking west along the cross street, and the north-west corner looking south-west."""
    obu_heading_offset_deg: float = -20.0
    """On-board unit boresight relative to the car's heading, degrees clockwise."""
    squint_deg: float = 30.0
    """Beam squint of both sensors' antenna pairs, degrees."""
    beamwidth_deg: float = 60.0
    """3 dB beamwidth of each beam, degrees."""
    min_snr_db: float = 3.0
    """Frames weaker than this above the sensitivity give no bearing, dB."""
    max_range_fraction: float = 0.3
    """Largest accepted one-sigma error ellipse axis over the shortest range of a fix
    (:class:`rfsas_hw.backend.TriangulationOptions`); the covariance carries the rest."""
    velocity_sigma_mps: float = 4.0
    """Prior one-sigma of the obstacle's velocity when the track starts, m/s."""
    accel_noise_mps2: float = 0.5
    """Process noise of the constant-velocity track, m/s² (one sigma)."""

    def __post_init__(self) -> None:
        lo, hi = self.intercept_s
        if not 0 <= lo <= hi:
            raise ValueError("intercept_s must be (low, high) with 0 <= low <= high")
        if self.reaction_delay_s < 0 or self.frame_interval_s <= 0 or self.low_sigma_m <= 0:
            raise ValueError("reaction_delay_s must be >= 0, frame_interval_s and low_sigma_m > 0")


@dataclass(frozen=True)
class RewardConfig:
    """What the agent is paid for.

    ``method`` (method.md §10): +1 for braking while the estimated risk is
    above ``risk_threshold``, +1 for accelerating while it is not, 0 otherwise.
    ``risk-progress``: ``progress_weight`` times the fraction of the approach
    covered in the step, minus ``risk_weight`` times the realised risk
    (``P_f`` of the impact speed) when a collision happens, minus
    ``time_weight`` per second of the episode, minus ``timeout_weight`` when
    the episode is truncated before the car crossed (stopping is not an exit:
    waiting costs time, and never crossing costs more).
    """

    kind: RewardKind = "method"
    """``method`` or ``risk-progress``."""
    progress_weight: float = 1.0
    """``risk-progress``: reward for covering the whole approach."""
    risk_weight: float = 50.0
    """``risk-progress``: penalty per unit of realised fatality risk."""
    time_weight: float = 0.1
    """``risk-progress``: penalty per second of the episode (a car holding 20 m/s pays
    about 0.53 for the approach)."""
    timeout_weight: float = 1.0
    """``risk-progress``: penalty when the episode times out (``max_steps``) before the
    car crossed."""

    def __post_init__(self) -> None:
        if min(self.progress_weight, self.risk_weight, self.time_weight, self.timeout_weight) < 0:
            raise ValueError("reward weights must be >= 0")


ScenarioKind = Literal["single", "corners"]
CornerKind = Literal["quiet", "busy"]
CORNERS: tuple[CornerKind, CornerKind] = ("quiet", "busy")
"""Corner kinds of the ``corners`` scenario, in the order of the per-corner pairs."""


@dataclass(frozen=True)
class ScenarioConfig:
    """Which episodes ``reset`` draws.

    ``single`` (default): every episode has the one crosser of
    :class:`ObstacleConfig`. ``corners``: each episode is at a *quiet* or a
    *busy* blind corner (``busy_fraction``). The two kinds differ in their
    history (``history_rate_per_h`` crossings per hour, from which the RF
    activity prior is built) and, as that history says, in the traffic they
    produce: at a busy corner fewer episodes are empty (``empty_fraction``,
    no crosser and so no warning) and more crossers are *late*
    (``late_fraction``: arriving at the car's lane in ``late_arrival_s``,
    when a car holding its speed is there); the others pass early
    (``early_arrival_s``). At either kind a crosser is heard (a warning comes)
    with probability ``heard_fraction``. Pairs are (quiet, busy).
    """

    kind: ScenarioKind = "single"
    """``single`` or ``corners``."""
    busy_fraction: float = 0.5
    """``corners``: probability that an episode is at a busy corner."""
    history_rate_per_h: tuple[float, float] = (2.0, 40.0)
    """Crossings per hour in each corner's history (quiet, busy)."""
    history_h: float = 24.0
    """Length of the simulated history the prior is built from, hours."""
    history_seed: int = 0
    """Seed of the simulated history."""
    empty_fraction: tuple[float, float] = (0.4, 0.1)
    """``corners``: probability of an episode without a crosser (quiet, busy)."""
    late_fraction: tuple[float, float] = (0.15, 0.75)
    """``corners``: probability that a crosser is late (quiet, busy)."""
    heard_fraction: float = 0.75
    """``corners``: probability that a crosser's phone is heard in time (the others carry
    no phone, or one that stays silent: no warning comes). Independent of the corner."""
    late_arrival_s: tuple[float, float] = (4.4, 5.4)
    """Arrival time range of a late crosser at the car's lane, seconds after reset."""
    early_arrival_s: tuple[float, float] = (1.5, 3.5)
    """Arrival time range of an early crosser, seconds after reset."""

    def __post_init__(self) -> None:
        if not 0 <= self.busy_fraction <= 1 or not 0 <= self.heard_fraction <= 1:
            raise ValueError("busy_fraction and heard_fraction must be in [0, 1]")
        for name in ("empty_fraction", "late_fraction"):
            if not all(0 <= p <= 1 for p in getattr(self, name)):
                raise ValueError(f"{name} must be probabilities in [0, 1]")
        for name in ("late_arrival_s", "early_arrival_s"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ValueError(f"{name} must be (low, high) with low <= high")
        if self.history_h <= 0 or min(self.history_rate_per_h) < 0:
            raise ValueError("history_h must be > 0 and history_rate_per_h >= 0")


@dataclass(frozen=True)
class PriorObsConfig:
    """The RF activity prior in the observation (:mod:`rfsas_hw.backend.prior`).

    With ``observe`` the observation grows by one entry: the expected number
    of RF-detected road users per hour in a ``corridor_m`` corridor along the
    next ``horizon_m`` of the car's lane, as ``1 − exp(−density/scale_per_h)``.
    The prior comes from ``path`` (a file written by the backend) or, without
    one, from a simulated history of the episode's corner
    (:class:`ScenarioConfig`).
    """

    observe: bool = False
    """Add the prior ahead of the car to the observation."""
    path: str | None = None
    """A prior file (``ActivityPrior.save``) used for every corner instead of the history."""
    horizon_m: float = 60.0
    """How far ahead along the lane the prior is summed, metres."""
    corridor_m: float = 2.0
    """Half-width of the corridor around the lane, metres."""
    scale_per_h: float = 20.0
    """Density (road users per hour) at which the observation reaches 1 − 1/e."""
    tile_m: float = 5.0
    """Tile size of the prior built from the simulated history, metres."""
    hour: int | None = None
    """UTC hour of day (0–23) of every episode for a prior whose history is long enough
    to be per hour (:attr:`ActivityPrior.hourly`); None: drawn uniformly per episode.
    A pooled prior ignores it."""

    def __post_init__(self) -> None:
        if self.horizon_m <= 0 or self.corridor_m < 0 or self.scale_per_h <= 0:
            raise ValueError("horizon_m and scale_per_h must be > 0, corridor_m >= 0")
        if self.hour is not None and not 0 <= self.hour < 24:
            raise ValueError("hour must be in 0..23")
        if self.tile_m <= 0:
            raise ValueError("tile_m must be > 0")


@dataclass(frozen=True)
class EnvConfig:
    """Everything :class:`rfsas_hw.envs.env.IntersectionEnv` needs."""

    dt_s: float = 0.1
    """Decision interval, seconds."""
    max_steps: int = 600
    """Steps before the episode is truncated."""
    end_y_m: float = 5.0
    """The episode ends when the front bumper reaches this north coordinate, metres
    (5 m past the centre: the car has cleared the near lane of the cross street)."""
    risk_threshold: float = 0.0015
    """Estimated-risk threshold of the reward and of the rule-based policy."""
    road_half_width_m: float = 7.0
    """Half the width of each road (drawn, and the kerb of the obstacle), metres."""
    buildings: tuple[BuildingSpec, ...] = field(default_factory=_default_buildings)
    """Building footprints that block line of sight."""
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    """The car."""
    obstacle: ObstacleConfig = field(default_factory=ObstacleConfig)
    """The crossing road user."""
    sensing: SensingConfig = field(default_factory=SensingConfig)
    """How the obstacle is located."""
    reward: RewardConfig = field(default_factory=RewardConfig)
    """The reward."""
    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    """Which episodes are drawn (one crosser, or quiet and busy corners)."""
    prior: PriorObsConfig = field(default_factory=PriorObsConfig)
    """The RF activity prior in the observation."""
    observe_drive_on: bool = False
    """Add the risk of driving on to the observation: the estimated collision
    probability and risk the car would face if it drove on now at its initial
    speed (two entries; see :mod:`rfsas_hw.envs.env`)."""

    def __post_init__(self) -> None:
        if self.dt_s <= 0 or self.max_steps < 1:
            raise ValueError("dt_s must be > 0 and max_steps >= 1")
        if not 0 < self.risk_threshold < 1:
            raise ValueError("risk_threshold must be in (0, 1)")
        if not -self.vehicle.start_distance_m < self.obstacle.crossing_y_m - self.vehicle.length_m:
            raise ValueError("the car must start south of the obstacle's path by its length")
        if self.obstacle.crossing_y_m + self.vehicle.length_m > self.end_y_m:
            raise ValueError("end_y_m must lie a car length beyond the obstacle's path")


def env_config_from_mapping(data: Mapping[str, Any], where: str = "env") -> EnvConfig:
    """Build an :class:`EnvConfig` from parsed YAML or keyword data.

    Raises:
        ConfigError: unknown key (named with its path), wrong type or bad value.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping at the top level")
    return from_mapping(EnvConfig, data, where)


def load_env_config(path: str | Path) -> EnvConfig:
    """Read an environment configuration file (YAML).

    Raises:
        ConfigError: unreadable file, invalid YAML, unknown key or bad value.
    """
    data = read_yaml(path)
    return env_config_from_mapping(data or {}, str(path))
