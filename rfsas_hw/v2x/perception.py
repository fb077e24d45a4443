"""From the backend's tracks to Collective Perception Messages: what goes in, and when.

:class:`CpmGenerator` keeps the state the standard's generation rules need
(ETSI TS 103 324 v2.1.1, clause 6.1) and turns each backend step's assessments
(the tracked state of every live emitter) into zero or more :class:`Cpm`:

- **Object ids** are numbers handed out in order (1, 2, 3, … wrapping at 65 535,
  skipping ids in use) when a track first appears, and kept while it lives. They
  carry no bit of the emitter id (itself a keyed hash of a MAC): an observer of
  CPMs learns nothing about the device from them.
- **Object inclusion** (the standard's rules, as this subset): a track is
  included when it is new; when it moved more than 4 m, changed speed by more
  than 0.5 m/s or direction by more than 4° since it was last included; or when
  it was last included 1 s ago or more (0.5 s for pedestrian-class objects). A
  message is generated when at least one object is due, at most once per
  ``min_interval_s``, and at least once per ``max_interval_s`` (then with only the
  sensor information if nothing is due).
- **Sensor information** is included in the first message and again whenever 1 s
  has passed since it was last sent or the set of units changed: id 0 is the
  backend's fusion (``localAggregation``), ids 1… the RF-SAS units (``rfid``), each
  with its field of view as a radial perception region.
- **Segmentation**: when one message would exceed ``max_message_bytes``, the
  objects are split over up to 8 messages of the same generation event, each
  with ``segmentationInfo`` and the total number of perceived objects; only the
  first carries the sensor information.

Each object's position is the track's east/north offset from the reference
position with the 95 % confidence of each coordinate (1.96 σ of the track's
covariance) and the x/y correlation coefficient (its
``lowerTriangularCorrelationMatrices``); velocity when the track has one. The
class mapping (an RF-SAS unit hears a device, not a body) is
:func:`classify`; the perception quality, :func:`perception_quality`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

from rfsas_hw.angles import wrap_deg_180, wrap_deg_360
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import ConfigError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import Assessment, Pose
from rfsas_hw.v2x.codec import encode_cpm, load_schema
from rfsas_hw.v2x.model import (
    CONFIDENCE_95_1D,
    CONFIDENCE_95_2D,
    LOCAL_AGGREGATION,
    RFID,
    Cpm,
    PerceivedObject,
    ReferencePoint,
    SensorEntry,
    VruClass,
)
from rfsas_hw.v2x.timestamp import its_ms_from_utc_ns

__all__ = [
    "AGGREGATION_SENSOR_ID",
    "CpmConfig",
    "CpmGenerator",
    "EncodedCpm",
    "ObjectIds",
    "classify",
    "perception_quality",
]

NS_PER_S = 1_000_000_000
NS_PER_MS = 1_000_000
AGGREGATION_SENSOR_ID = 0
"""Sensor id of the backend's fusion (``localAggregation``) in every message."""
MAX_SEGMENTS = 8
"""``MessageSegmentationInfo`` counts messages 1 … 8."""
MAX_OBJECTS = 255
"""Perceived objects one message holds."""
PEDESTRIAN_MAX_SPEED_MPS = 2.5
"""Fastest tracked speed still classed as a pedestrian, m/s (a brisk walk or a jog)."""
BICYCLIST_MAX_SPEED_MPS = 12.0
"""Fastest tracked speed still classed as a bicyclist, m/s (43 km/h)."""


@dataclass(frozen=True, slots=True)
class CpmConfig:
    """What the generator needs to know about the station and its units."""

    station_id: int
    """``StationId`` of this station, 0 … 2³²−1."""
    origin: SiteOrigin
    """The site origin: local metres → WGS-84."""
    station: Literal["rsu", "vehicle"] = "rsu"
    """``rsu``: a roadside backend, reference position = the site origin;
    ``vehicle``: a vehicle's own unit, reference position and heading = the vehicle's."""
    reference_sigma_m: float = 0.1
    """RSU: one-sigma horizontal error of the surveyed site origin, metres."""
    fov_deg: Mapping[str, float] = field(default_factory=dict)
    """Full field of view of each unit by sensor id, degrees (others: ``default_fov_deg``)."""
    default_fov_deg: float = 90.0
    """Field of view of a unit the site does not describe, degrees."""
    range_m: float = 100.0
    """Radius of every unit's perception region, metres (wire limit 409.5 m)."""
    min_interval_s: float = 0.1
    """Least time between two generation events, seconds (T_GenCpmMin)."""
    max_interval_s: float = 1.0
    """Most time between two generation events, seconds (T_GenCpmMax)."""
    max_message_bytes: int = 1100
    """A message larger than this is segmented, bytes."""
    position_step_m: float = 4.0
    """An object moved farther than this since its last inclusion is included, metres."""
    speed_step_mps: float = 0.5
    """… or whose speed changed by more than this, m/s."""
    direction_step_deg: float = 4.0
    """… or whose direction of motion changed by more than this, degrees."""
    vru_interval_s: float = 0.5
    """A pedestrian-class object is included at least this often, seconds."""

    def __post_init__(self) -> None:
        if not 0 <= self.station_id < 2**32:
            raise ConfigError(f"CPM station id {self.station_id}: must be in 0 … 4294967295")
        if self.station not in ("rsu", "vehicle"):
            raise ConfigError(f"CPM station {self.station!r}: must be rsu or vehicle")
        if not 0 < self.range_m <= 409.5:
            raise ConfigError(f"CPM sensor range {self.range_m} m: must be in (0, 409.5]")
        if not 0 < self.min_interval_s <= self.max_interval_s:
            raise ConfigError("CPM intervals: need 0 < min_interval_s <= max_interval_s")
        if self.max_message_bytes < 200:
            raise ConfigError(f"CPM max_message_bytes {self.max_message_bytes}: at least 200")
        for sensor_id, fov in {**self.fov_deg, "default": self.default_fov_deg}.items():
            if not 0 < fov <= 360:
                raise ConfigError(f"CPM field of view of {sensor_id}: {fov} not in (0, 360]")


class ObjectIds:
    """Object ids handed out in order, kept while a track lives (no MAC-derived bits)."""

    def __init__(self) -> None:
        self._ids: dict[str, int] = {}
        self._next = 1

    def get(self, emitter: str) -> int:
        """The id of ``emitter``'s track, a new one on first sight.

        Raises:
            ConfigError: all 65 536 ids are in use.
        """
        if emitter in self._ids:
            return self._ids[emitter]
        used = set(self._ids.values())
        if len(used) >= 65536:
            raise ConfigError("CPM: 65536 live tracks, no object id left")
        while self._next in used:
            self._next = (self._next + 1) % 65536
        oid = self._next
        self._next = (self._next + 1) % 65536
        self._ids[emitter] = oid
        return oid

    def keep_only(self, emitters: set[str]) -> None:
        """Forget the tracks not in ``emitters`` (their ids become free)."""
        for emitter in [e for e in self._ids if e not in emitters]:
            del self._ids[emitter]


def classify(speed_mps: float) -> tuple[VruClass, int]:
    """The class and its confidence (percent) given to a track of this speed.

    An RF-SAS unit hears a radio, not a body: the class is a prior from how fast
    the device moves, never a detection. A device at walking pace (≤ 2.5 m/s, or
    with no speed yet) is most often carried by a pedestrian (``vruSubClass``
    pedestrian, 60 %); up to 12 m/s by a bicyclist or light VRU vehicle (50 %);
    faster, it rides in a vehicle, and the object is ``vehicleSubClass``
    unknown with the confidence unavailable (101).
    """
    if not math.isfinite(speed_mps) or speed_mps <= PEDESTRIAN_MAX_SPEED_MPS:
        return "pedestrian", 60
    if speed_mps <= BICYCLIST_MAX_SPEED_MPS:
        return "bicyclist", 50
    return "unknown", 101


def perception_quality(fix_ok: bool, semi_major_95_m: float, age_s: float) -> int:
    """``ObjectPerceptionQuality`` 0 … 15 of a track.

    0 when its latest fix was not trustworthy or its error is unknown; otherwise
    15 scaled down linearly by the 95 % semi-major axis (to 0 at 20 m) and by the
    time since the newest bearing (to 0 at 5 s).
    """
    if not fix_ok or not math.isfinite(semi_major_95_m) or not math.isfinite(age_s):
        return 0
    size = max(0.0, 1.0 - semi_major_95_m / 20.0)
    fresh = max(0.0, 1.0 - max(age_s, 0.0) / 5.0)
    return round(15 * size * fresh)


def _semi_major_1sigma(cxx: float, cxy: float, cyy: float) -> float:
    half = 0.5 * (cxx + cyy)
    return math.sqrt(max(half + math.sqrt(max(0.25 * (cxx - cyy) ** 2 + cxy * cxy, 0.0)), 0.0))


@dataclass(frozen=True, slots=True)
class EncodedCpm:
    """A generated message and its UPER bytes."""

    cpm: Cpm
    data: bytes


@dataclass(slots=True)
class _Included:
    t_ns: int
    x_m: float
    y_m: float
    speed_mps: float
    direction_deg: float


class CpmGenerator:
    """Keeps the generation state of one station; :meth:`step` gives each step's CPMs.

    Raises:
        MissingDependencyError: ``asn1tools`` is not installed (the ``v2x`` extra).
    """

    def __init__(self, config: CpmConfig) -> None:
        load_schema()
        self.config = config
        self.ids = ObjectIds()
        self._first_seen: dict[str, int] = {}
        self._included: dict[str, _Included] = {}
        self._sensor_ids: dict[str, int] = {}
        self._last_event_ns: int | None = None
        self._last_sensors_ns: int | None = None
        self._sent_units: frozenset[str] = frozenset()
        self.generated = 0
        """Messages generated."""

    def _unit_id(self, sensor_id: str) -> int:
        if sensor_id not in self._sensor_ids:
            if len(self._sensor_ids) >= 254:
                raise ConfigError("CPM: more than 254 RF-SAS units")
            self._sensor_ids[sensor_id] = len(self._sensor_ids) + 1
        return self._sensor_ids[sensor_id]

    def _reference(self, vehicle: VehicleState | None) -> tuple[ReferencePoint, float, float]:
        """The reference point and the local (east, north) metres it stands at."""
        cfg = self.config
        if cfg.station == "vehicle":
            if vehicle is None:
                raise ConfigError("CPM from a vehicle station needs the vehicle state")
            lat, lon, h = cfg.origin.to_geodetic(vehicle.x_m, vehicle.y_m)
            along = CONFIDENCE_95_2D * vehicle.sigma_along_m
            across = CONFIDENCE_95_2D * vehicle.sigma_across_m
            major_heading = vehicle.heading_deg if along >= across else vehicle.heading_deg + 90
            return (
                ReferencePoint(
                    float(lat),
                    float(lon),
                    float(h),
                    max(along, across),
                    min(along, across),
                    wrap_deg_360(major_heading),
                ),
                vehicle.x_m,
                vehicle.y_m,
            )
        semi = CONFIDENCE_95_2D * cfg.reference_sigma_m
        o = cfg.origin
        return ReferencePoint(o.lat_deg, o.lon_deg, o.height_m, semi, semi, 0.0), 0.0, 0.0

    def _sensors(
        self, stations: Mapping[str, Pose], ref_x: float, ref_y: float
    ) -> tuple[SensorEntry, ...]:
        cfg = self.config
        out = [SensorEntry(AGGREGATION_SENSOR_ID, LOCAL_AGGREGATION, shadowing_applies=False)]
        for sensor_id in sorted(stations, key=self._unit_id):
            pose = stations[sensor_id]
            fov = cfg.fov_deg.get(sensor_id, cfg.default_fov_deg)
            # compass boresight ± half the field of view, as counter-clockwise math angles:
            # the compass-clockwise end of the view is the math start
            out.append(
                SensorEntry(
                    self._unit_id(sensor_id),
                    RFID,
                    shadowing_applies=False,
                    x_m=pose.x_m - ref_x,
                    y_m=pose.y_m - ref_y,
                    range_m=cfg.range_m,
                    start_deg=wrap_deg_360(90.0 - (pose.heading_deg + fov / 2.0)),
                    end_deg=wrap_deg_360(90.0 - (pose.heading_deg - fov / 2.0)),
                )
            )
        return tuple(out)

    def _due(self, a: Assessment, pedestrian: bool, now: int) -> bool:
        cfg = self.config
        last = self._included.get(a.emitter)
        if last is None:
            return True
        elapsed_s = (now - last.t_ns) / NS_PER_S
        if elapsed_s >= (cfg.vru_interval_s if pedestrian else cfg.max_interval_s):
            return True
        if math.hypot(a.x_m - last.x_m, a.y_m - last.y_m) > cfg.position_step_m:
            return True
        speed = math.hypot(a.vx_mps, a.vy_mps)
        if math.isfinite(speed) and math.isfinite(last.speed_mps):
            if abs(speed - last.speed_mps) > cfg.speed_step_mps:
                return True
            direction = math.degrees(math.atan2(a.vy_mps, a.vx_mps))
            if abs(wrap_deg_180(direction - last.direction_deg)) > cfg.direction_step_deg:
                return True
        return False

    def _object(
        self, a: Assessment, now: int, ref_x: float, ref_y: float
    ) -> tuple[PerceivedObject, bool]:
        sx = math.sqrt(a.cov_xx_m2) if a.cov_xx_m2 >= 0 else math.nan
        sy = math.sqrt(a.cov_yy_m2) if a.cov_yy_m2 >= 0 else math.nan
        finite = math.isfinite(sx * sy * a.cov_xy_m2)
        rho = a.cov_xy_m2 / (sx * sy) if finite and sx > 0 and sy > 0 else math.nan
        speed = math.hypot(a.vx_mps, a.vy_mps)
        kind, confidence = classify(speed)
        semi95 = CONFIDENCE_95_2D * _semi_major_1sigma(a.cov_xx_m2, a.cov_xy_m2, a.cov_yy_m2)
        first = self._first_seen.setdefault(a.emitter, a.t_ns)
        units = tuple(sorted(self._unit_id(s) for s in a.sensors))
        obj = PerceivedObject(
            object_id=self.ids.get(a.emitter),
            measurement_delta_ms=round((a.t_ns - now) / NS_PER_MS),
            x_m=a.x_m - ref_x,
            y_m=a.y_m - ref_y,
            x_conf_m=CONFIDENCE_95_1D * sx,
            y_conf_m=CONFIDENCE_95_1D * sy,
            xy_correlation=rho,
            vx_mps=a.vx_mps,
            vy_mps=a.vy_mps,
            age_ms=round((now - first) / NS_PER_MS),
            quality=perception_quality(a.fix_ok, semi95, a.age_s),
            sensor_ids=units,
            object_class=kind,
            class_confidence_pct=confidence,
        )
        return obj, kind == "pedestrian"

    def step(
        self,
        now_ns: int,
        assessments: Sequence[Assessment],
        stations: Mapping[str, Pose],
        vehicle: VehicleState | None = None,
    ) -> list[EncodedCpm]:
        """The CPMs of one backend step (often none: see the module docstring).

        Args:
            now_ns: the step's time, UTC ns (the messages' reference time).
            assessments: every live track's state at this step.
            stations: the latest pose of every unit heard, by sensor id.
            vehicle: the vehicle's state (a ``vehicle`` station's reference).

        Raises:
            ConfigError: a vehicle station without a vehicle state, more objects due
                at once than 8 segments hold (2040), or no object id left.
        """
        cfg = self.config
        live = [a for a in assessments if math.isfinite(a.x_m) and math.isfinite(a.y_m)]
        names = {a.emitter for a in live}
        self.ids.keep_only(names)
        for gone in [e for e in self._included if e not in names]:
            del self._included[gone]
        for gone in [e for e in self._first_seen if e not in names]:
            del self._first_seen[gone]
        if self._last_event_ns is not None:
            since = (now_ns - self._last_event_ns) / NS_PER_S
            if since < cfg.min_interval_s - 1e-9:
                return []
        reference, ref_x, ref_y = self._reference(vehicle)
        due: list[tuple[Assessment, PerceivedObject]] = []
        for a in live:
            obj, pedestrian = self._object(a, now_ns, ref_x, ref_y)
            if self._due(a, pedestrian, now_ns):
                due.append((a, obj))
        units = frozenset(stations)
        sensors_due = (
            self._last_sensors_ns is None
            or units != self._sent_units
            or (now_ns - self._last_sensors_ns) / NS_PER_S >= 1.0 - 1e-9
        )
        heartbeat = (
            self._last_event_ns is None
            or (now_ns - self._last_event_ns) / NS_PER_S >= cfg.max_interval_s - 1e-9
        )
        if not due and not heartbeat:
            return []
        base = Cpm(
            station_id=cfg.station_id,
            reference_time_ms=its_ms_from_utc_ns(now_ns),
            reference=reference,
            originating=cfg.station,
            heading_deg=vehicle.heading_deg if cfg.station == "vehicle" and vehicle else math.nan,
            sensors=self._sensors(stations, ref_x, ref_y) if sensors_due else (),
            perceived_total=len(live) if due else None,
        )
        messages = self._segment(base, [obj for _, obj in due])
        self._last_event_ns = now_ns
        if sensors_due:
            self._last_sensors_ns = now_ns
            self._sent_units = units
        sent = {obj.object_id for m in messages for obj in m.cpm.objects}
        for a, obj in due:
            if obj.object_id in sent:
                speed = math.hypot(a.vx_mps, a.vy_mps)
                self._included[a.emitter] = _Included(
                    now_ns, a.x_m, a.y_m, speed, math.degrees(math.atan2(a.vy_mps, a.vx_mps))
                )
        self.generated += len(messages)
        return messages

    def _segment(self, base: Cpm, objects: list[PerceivedObject]) -> list[EncodedCpm]:
        """One message, or up to 8 segments each within ``max_message_bytes``."""
        if len(objects) <= MAX_OBJECTS:
            whole = replace(base, objects=tuple(objects))
            data = encode_cpm(whole)
            if len(data) <= self.config.max_message_bytes or len(objects) <= 1:
                return [EncodedCpm(whole, data)]
            n = math.ceil(len(data) / self.config.max_message_bytes)
        else:
            n = math.ceil(len(objects) / MAX_OBJECTS)
        if len(objects) > MAX_SEGMENTS * MAX_OBJECTS:
            raise ConfigError(
                f"CPM: {len(objects)} objects due at once; 8 segments hold at most "
                f"{MAX_SEGMENTS * MAX_OBJECTS}"
            )
        n = min(MAX_SEGMENTS, max(2, n))
        while True:
            chunk = math.ceil(len(objects) / n)
            parts = [objects[i : i + chunk] for i in range(0, len(objects), chunk)]
            segments = [
                replace(
                    base,
                    sensors=base.sensors if i == 0 else (),
                    objects=tuple(part),
                    segment=(i + 1, len(parts)),
                )
                for i, part in enumerate(parts)
            ]
            messages = [EncodedCpm(m, encode_cpm(m)) for m in segments]
            too_big = any(len(m.data) > self.config.max_message_bytes for m in messages)
            if not too_big or n >= MAX_SEGMENTS or chunk == 1:
                # with 8 segments still too big the last resort is the messages as they are:
                # the transport may still carry them (the limit is a policy, not the MTU)
                return messages
            n += 1
