"""How the car's backend sees the crossing obstacle, and the risk it estimates.

Three locators, one per level of detail (method.md §10), each turning the
true obstacle position at one instant into a position fix with covariance:

- :class:`ParametricLocator` (``low``): the true position plus Gaussian error
  of an assigned size; no RF at all.
- :class:`SnrLocator` (``medium``): a roadside unit and the car's own unit
  each measure a bearing whose σ comes from the link budget and the monopulse
  formula ``σ = β/(k_m·√SNR)``; the backend triangulates them.
- :class:`PipelineLocator` (``high``): the per-chain RSSI of one frame comes
  from the physical model (path loss, blockage by buildings, beam gains,
  thermal and measurement noise, 1 dB quantisation); it goes through the real
  :class:`~rfsas_hw.pipeline.SensorPipeline` with a turntable calibration, and
  the hashed bearings are triangulated by the backend.

Fixes feed the backend's constant-velocity Kalman filter (:class:`ThreatTrack`),
whose prediction to the moment the car reaches the crosswalk gives the
collision probability (:func:`assess_risk`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import math_rad_to_compass, wrap_deg_180
from rfsas_hw.backend import TriangulationOptions, triangulate
from rfsas_hw.backend.collision import THREAT_SIZES, collision_probability, heading_covariance
from rfsas_hw.backend.risk import BRAKE_DECEL_MPS2, fatality_risk, impact_speed
from rfsas_hw.backend.tracking import Tracker, TrackerConfig
from rfsas_hw.df.calibration import Calibration
from rfsas_hw.envs.envconfig import EnvConfig, SensingConfig
from rfsas_hw.errors import SimulationError
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.records import FrameKind, ObservationBatch, Pose
from rfsas_hw.rf.antenna import GaussianBeamPair
from rfsas_hw.rf.aoa import sigma_monopulse_deg
from rfsas_hw.rf.channels import channel_to_freq_mhz
from rfsas_hw.rf.noise import quantise_db, rssi_sigma_db
from rfsas_hw.twin.rfworld import blockage_db, building_array, link_path_loss_db
from rfsas_hw.twin.scenario import (
    DEFAULT_THRESHOLD_DBM,
    RfSpec,
    Scenario,
    scenario_from_mapping,
)

Array = npt.NDArray[np.float64]

PHONE_MAC = 0x3C22FB4E9107
"""MAC of the simulated phone (inside the simulated sensor only; bearings carry hashes)."""
_EMITTER = 1
"""Track key of the one obstacle the environment follows."""

_TX_ANTENNA_GAIN_DBI = 3.0
_FOV_DEG = 60.0
"""Bearings beyond this angle from boresight are not used (outside the monotonic curve)."""


@dataclass(frozen=True, slots=True)
class LineOfBearing:
    """One measured bearing, kept for drawing."""

    sensor_xy: tuple[float, float]
    """Sensor position, metres."""
    azimuth_deg: float
    """Measured compass azimuth, degrees."""
    sigma_deg: float
    """One-sigma error, degrees."""


@dataclass(frozen=True, slots=True)
class Fix:
    """A position fix of the obstacle at one instant."""

    position: Array
    """Estimated (x_m, y_m), metres."""
    covariance: Array
    """2×2 covariance, m²."""
    bearings: tuple[LineOfBearing, ...] = ()
    """The bearings it came from (empty for the parametric locator)."""


@dataclass(frozen=True, slots=True)
class SensorPoses:
    """Where the sensors are when a frame is heard."""

    roadside: tuple[Pose, ...]
    """The roadside units."""
    obu: Pose
    """The car's on-board unit."""

    def named(self) -> list[tuple[str, Pose]]:
        """``(sensor_id, pose)`` of every sensor."""
        rsus = [(f"rsu-{i}", p) for i, p in enumerate(self.roadside)]
        return [*rsus, ("obu", self.obu)]


class Locator(Protocol):
    """Something that locates the obstacle from its true position at one instant."""

    def locate(
        self, t_s: float, obstacle_xy: Array, poses: SensorPoses, rng: np.random.Generator
    ) -> Fix | None:
        """A fix, or None when this instant gives none (too few bearings, bad geometry)."""
        ...

    def reset(self) -> None:
        """Forget what earlier episodes left behind (their times start again at 0)."""
        ...


@dataclass
class ParametricLocator:
    """``low`` detail: the true position with an assigned isotropic error."""

    sigma_m: float

    def reset(self) -> None:
        """Nothing to forget: each fix is drawn on its own."""

    def locate(
        self, t_s: float, obstacle_xy: Array, poses: SensorPoses, rng: np.random.Generator
    ) -> Fix | None:
        """The true position plus N(0, σ²) per axis."""
        cov = np.eye(2) * self.sigma_m**2
        return Fix(obstacle_xy + self.sigma_m * rng.standard_normal(2), cov)


def _triangulate(bearings: list[LineOfBearing], options: TriangulationOptions) -> Fix | None:
    if len(bearings) < 2:
        return None
    fix = triangulate(
        [b.sensor_xy for b in bearings],
        [b.azimuth_deg for b in bearings],
        [b.sigma_deg for b in bearings],
        options,
    )
    if not fix.ok:
        return None
    return Fix(fix.position, fix.covariance, tuple(bearings))


@dataclass
class _Link:
    """Geometry and budget of the phone → sensor link for one frame."""

    distance_m: float
    azimuth_deg: float
    relative_deg: float
    rx_dbm: Array
    """Received power per chain, dBm, shape (2,)."""
    threshold_dbm: float


@dataclass
class SnrLocator:
    """``medium`` detail: bearings with σ from the SNR formulas, triangulated."""

    sensing: SensingConfig
    tx_power_dbm: float
    channel: int
    rf: RfSpec = field(default_factory=RfSpec)

    def __post_init__(self) -> None:
        self.antenna = GaussianBeamPair(
            squint_deg=self.sensing.squint_deg, beamwidth_deg=self.sensing.beamwidth_deg
        )
        self.freq_mhz = channel_to_freq_mhz(self.channel)
        self.threshold_dbm = DEFAULT_THRESHOLD_DBM["wifi"]
        self.options = TriangulationOptions(max_range_fraction=self.sensing.max_range_fraction)

    def reset(self) -> None:
        """Nothing to forget: each instant's bearings are drawn on their own."""

    def _link(self, pose: Pose, xy: Array, extra_loss_db: float = 0.0) -> _Link:
        dx, dy = float(xy[0] - pose.x_m), float(xy[1] - pose.y_m)
        distance = math.hypot(dx, dy)
        azimuth = math_rad_to_compass(math.atan2(dy, dx))
        relative = wrap_deg_180(azimuth - pose.heading_deg)
        pl = float(link_path_loss_db(np.array([distance]), self.freq_mhz, self.rf)[0])
        gains = self.antenna.gains_db(np.array([relative]))[0]
        # transmit antenna gain as in the link budget (method.md §2)
        rx = (
            self.tx_power_dbm
            + _TX_ANTENNA_GAIN_DBI
            - pl
            - self.rf.margin_db
            - extra_loss_db
            + gains
        )
        return _Link(distance, azimuth, relative, np.asarray(rx, np.float64), self.threshold_dbm)

    def locate(
        self, t_s: float, obstacle_xy: Array, poses: SensorPoses, rng: np.random.Generator
    ) -> Fix | None:
        """Bearings from every sensor, σ from the SNR, triangulated; None without a fix."""
        bearings: list[LineOfBearing] = []
        for _, pose in poses.named():
            link = self._link(pose, obstacle_xy)
            snr = float(np.max(link.rx_dbm)) - link.threshold_dbm
            if snr < self.sensing.min_snr_db or abs(link.relative_deg) > _FOV_DEG:
                continue
            sigma = float(sigma_monopulse_deg(snr, beamwidth_deg=self.sensing.beamwidth_deg))
            measured = link.azimuth_deg + sigma * float(rng.standard_normal())
            bearings.append(LineOfBearing((pose.x_m, pose.y_m), measured % 360.0, sigma))
        return _triangulate(bearings, self.options)


@functools.lru_cache(maxsize=4)
def _calibration(squint_deg: float, beamwidth_deg: float, channel: int) -> Calibration:
    """A turntable calibration of the sensors' antenna pair (fitted once per process)."""
    from rfsas_hw.twin.turntable import turntable_calibration

    scenario = _calibration_scenario(squint_deg, beamwidth_deg, channel)
    return turntable_calibration(scenario, "bench")


def _calibration_scenario(squint_deg: float, beamwidth_deg: float, channel: int) -> Scenario:
    return scenario_from_mapping(
        {
            "version": 1,
            "name": "env-turntable",
            "seed": 7,
            "duration_s": 1.0,
            "emitters": [
                {
                    "id": "phone",
                    "mac": "02:00:00:00:00:01",
                    "tech": "wifi",
                    "position": [0.0, 0.0],
                    "traffic": [{"model": "beacon", "channels": [channel]}],
                }
            ],
            "sensors": [
                {
                    "id": "bench",
                    "kind": "roadside",
                    "pose": {"x_m": 0.0, "y_m": 0.0, "heading_deg": 0.0},
                    "antenna": {"squint_deg": squint_deg, "beamwidth_deg": beamwidth_deg},
                    "scan": {"channels": [channel]},
                }
            ],
        },
        "<env turntable>",
    )


class PipelineLocator(SnrLocator):
    """``high`` detail: per-chain RSSI from the physical model through the real DF pipeline."""

    measurement_floor_db = 1.0
    step_db = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        self.calibration = _calibration(
            self.sensing.squint_deg, self.sensing.beamwidth_deg, self.channel
        )
        self.rects = building_array(())
        self.hasher = MacHasher(FixedNonce(b"rfsas-sim-environment-nonce"))
        self._pipelines: dict[str, SensorPipeline] = {}

    def with_buildings(self, rects: Array) -> PipelineLocator:
        """Use these building rectangles (``(m, 5)``: x_min, x_max, y_min, y_max, loss_db)."""
        self.rects = rects
        return self

    def reset(self) -> None:
        """Start the pipelines afresh: their field-of-view guard remembers each emitter's
        levels by time, and a new episode's times start again at 0."""
        self._pipelines.clear()

    def _pipeline(self, sensor_id: str, pose: Pose) -> SensorPipeline:
        pipe = self._pipelines.get(sensor_id)
        if pipe is None:
            pipe = SensorPipeline(self.calibration, self.hasher, sensor_id, pose)
            self._pipelines[sensor_id] = pipe
        pipe.pose = pose
        return pipe

    def locate(
        self, t_s: float, obstacle_xy: Array, poses: SensorPoses, rng: np.random.Generator
    ) -> Fix | None:
        """One frame per sensor through the DF pipeline, triangulated; None without a fix."""
        bearings: list[LineOfBearing] = []
        t_ns = round(t_s * 1e9)
        for sensor_id, pose in poses.named():
            block, _ = blockage_db(
                np.array([[pose.x_m, pose.y_m]]), obstacle_xy[None, :], self.rects
            )
            link = self._link(pose, obstacle_xy, float(block[0]))
            snr = link.rx_dbm - link.threshold_dbm
            if float(np.max(snr)) < self.sensing.min_snr_db:
                continue
            sigma = rssi_sigma_db(snr, self.measurement_floor_db)
            reading = quantise_db(link.rx_dbm + sigma * rng.standard_normal(2), self.step_db)
            batch = ObservationBatch(
                t_ns=np.array([t_ns], np.int64),
                mac=np.array([PHONE_MAC], np.uint64),
                freq_mhz=np.array([self.freq_mhz], np.int32),
                channel=np.array([self.channel], np.int16),
                rssi_dbm=reading[None, :].astype(np.float32),
                seq=np.array([-1], np.int32),
                kind=np.array([FrameKind.QOS_DATA], np.uint8),
                flags=np.zeros(1, np.uint16),
            )
            out = self._pipeline(sensor_id, pose).process(batch)
            if len(out) == 0:
                continue
            bearings.append(
                LineOfBearing(
                    (pose.x_m, pose.y_m), float(out.azimuth_deg[0]), float(out.sigma_deg[0])
                )
            )
        return _triangulate(bearings, self.options)


def make_locator(config: EnvConfig) -> Locator:
    """The locator of the configured level of detail."""
    s = config.sensing
    o = config.obstacle
    if s.detail == "low":
        return ParametricLocator(s.low_sigma_m)
    if s.detail == "medium":
        return SnrLocator(s, o.tx_power_dbm, o.channel)
    return PipelineLocator(s, o.tx_power_dbm, o.channel).with_buildings(
        building_array(config.buildings)
    )


class ThreatTrack:
    """The backend's constant-velocity track of the obstacle, fed with the locator's fixes.

    Wraps :class:`rfsas_hw.backend.tracking.Tracker` for the one emitter the
    environment follows; times are seconds since reset.
    """

    def __init__(self, locator: Locator, sensing: SensingConfig) -> None:
        self.locator = locator
        locator.reset()  # times are seconds since this reset
        self.tracker = Tracker(
            TrackerConfig(
                accel_sigma_mps2=sensing.accel_noise_mps2,
                initial_speed_sigma_mps=sensing.velocity_sigma_mps,
            )
        )

    @property
    def started(self) -> bool:
        """Whether a fix has been received."""
        return len(self.tracker) > 0

    def observe(
        self, t_s: float, obstacle_xy: Array, poses: SensorPoses, rng: np.random.Generator
    ) -> Fix | None:
        """Locate the obstacle once and fold the fix (if any) into the track."""
        fix = self.locator.locate(t_s, obstacle_xy, poses, rng)
        if fix is not None:
            self.tracker.update(_EMITTER, _ns(t_s), fix.position, fix.covariance)
        return fix

    def predict(self, t_s: float) -> tuple[Array, Array, Array]:
        """Position (2,), its covariance (2, 2) and the velocity (2,) predicted at ``t_s``.

        Raises:
            SimulationError: the track has not started.
        """
        track = self.tracker.tracks.get(_EMITTER)
        if track is None:
            raise SimulationError("the obstacle has no track yet")
        x, p = track.predict(_ns(t_s), self.tracker.config.accel_sigma_mps2)
        return x[:2], p[:2, :2], x[2:]


def _ns(t_s: float) -> int:
    return round(t_s * 1e9)


@functools.lru_cache(maxsize=8)
def _vehicle_cov(sigma_along_m: float, sigma_across_m: float) -> Array:
    """Position covariance of the northbound car, m² (constant, so computed once)."""
    cov = heading_covariance(0.0, sigma_along_m, sigma_across_m)
    cov.setflags(write=False)
    return cov


@dataclass(frozen=True, slots=True)
class Assessment:
    """The backend's estimate of the risk at one instant (method.md §6, §7)."""

    p_collision: float
    """Probability that the car's and the obstacle's boxes overlap at the crosswalk."""
    impact_speed_mps: float
    """Speed at impact if the car brakes now at 0.47 g, m/s (0: it stops in time)."""
    p_fatality: float
    """Pedestrian fatality risk at that impact speed."""
    risk: float
    """``p_collision · p_fatality``."""
    obstacle_xy: Array
    """Predicted obstacle position at the conflict, metres."""
    obstacle_cov: Array
    """Its covariance, m²."""


NO_RISK = Assessment(0.0, 0.0, 0.0, 0.0, np.full(2, np.nan), np.full((2, 2), np.nan))
"""What the car knows before any warning: no threat."""


def assess_risk(
    config: EnvConfig,
    t_s: float,
    front_y_m: float,
    speed_mps: float,
    track: ThreatTrack,
) -> Assessment:
    """Collision probability, impact speed, fatality risk and risk for the car's state.

    The car is assumed to hold its speed to find when it reaches the obstacle's
    crossing line; the track is predicted to that moment and the two boxes'
    overlap probability comes from the backend's exact method. The impact speed
    is the one of braking now at 0.47 g over the gap to the obstacle.
    """
    if not track.started:
        return NO_RISK
    v = config.vehicle
    size = THREAT_SIZES[config.obstacle.kind]
    centre_y = front_y_m - v.length_m / 2
    now_xy, _, _ = track.predict(t_s)
    ahead_m = float(now_xy[1]) - centre_y
    if ahead_m > 0 and speed_mps > 0:
        dt = ahead_m / speed_mps
        car_y = float(now_xy[1])
    else:
        dt = 0.0
        car_y = centre_y
    xy, cov, vel = track.predict(t_s + dt)
    heading = (
        math_rad_to_compass(math.atan2(float(vel[1]), float(vel[0])))
        if math.hypot(float(vel[0]), float(vel[1])) > 1e-6
        else 270.0
    )
    p = collision_probability(
        (v.lane_x_m, car_y),
        0.0,
        _vehicle_cov(v.sigma_along_m, v.sigma_across_m),
        (v.length_m, v.width_m),
        xy,
        heading,
        cov,
        size,
    )
    gap = max(float(now_xy[1]) - size[0] / 2 - front_y_m, 0.0)
    v_imp = float(impact_speed(speed_mps, gap, BRAKE_DECEL_MPS2))
    p_f = float(fatality_risk(v_imp))
    return Assessment(p, v_imp, p_f, p * p_f, xy, cov)
