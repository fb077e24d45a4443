"""What one Collective Perception Message says, in SI units and the CPM's own frames.

These records are the encoder's input and the decoder's output
(:mod:`rfsas_hw.v2x.codec`); they hold exactly what rfsas-hw writes into a CPM,
at full float precision before encoding and at the wire's resolution after
decoding. Frames follow ETSI TS 103 324 v2.1.1:

- positions of perceived objects and sensors are metres east (x) and north (y) of
  the message's reference position;
- angles of a sensor's field of view are *mathematical* angles: degrees
  counter-clockwise from the x axis (east), not compass bearings;
- headings (the originating vehicle's orientation, the reference position's error
  ellipse) are WGS-84 angles: degrees clockwise from north, as compass bearings.

NaN (or None) means a field is absent or "unavailable" on the wire.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

__all__ = [
    "CONFIDENCE_95_1D",
    "CONFIDENCE_95_2D",
    "LOCAL_AGGREGATION",
    "RFID",
    "Cpm",
    "PerceivedObject",
    "ReferencePoint",
    "SensorEntry",
    "VruClass",
]

RFID = 14
"""``SensorType`` of a radio (Bluetooth, Wi-Fi) detector: an RF-SAS unit."""
LOCAL_AGGREGATION = 12
"""``SensorType`` of a local fusion system: the backend's triangulated tracks."""

CONFIDENCE_95_1D = 1.959963984540054
"""Half-width of the two-sided 95 % interval of one normal coordinate, in sigmas."""
CONFIDENCE_95_2D = math.sqrt(-2.0 * math.log(0.05))
"""Semi-axis of the 95 % ellipse of a 2-D normal, in sigmas (√χ²₂(0.95) ≈ 2.4477)."""

VruClass = Literal["pedestrian", "bicyclist", "unknown"]
"""Class a perceived object is given: ``vruSubClass`` pedestrian or bicyclist, or
``vehicleSubClass`` unknown."""


@dataclass(frozen=True, slots=True)
class ReferencePoint:
    """The message's reference position on WGS-84, with its 95 % error ellipse."""

    lat_deg: float
    """Latitude, degrees north (wire: 1e-7 °)."""
    lon_deg: float
    """Longitude, degrees east (wire: 1e-7 °)."""
    altitude_m: float = math.nan
    """Altitude, metres (wire: 0.01 m; NaN: unavailable)."""
    semi_major_m: float = math.nan
    """Semi-major axis of the 95 % ellipse, metres (wire: 0.01 m; NaN: unavailable)."""
    semi_minor_m: float = math.nan
    """Semi-minor axis of the 95 % ellipse, metres (wire: 0.01 m; NaN: unavailable)."""
    major_heading_deg: float = math.nan
    """Direction of the major axis, degrees clockwise from north (wire: 0.1 °)."""


@dataclass(frozen=True, slots=True)
class SensorEntry:
    """One entry of the sensor information container."""

    sensor_id: int
    """``Identifier1B``, 0–255, unique within the message."""
    sensor_type: int
    """``SensorType``: :data:`RFID` for a unit, :data:`LOCAL_AGGREGATION` for the fusion."""
    shadowing_applies: bool
    """Whether the standard shadowing approach applies to the perception region."""
    x_m: float = math.nan
    """Sensor east of the reference position, metres (wire: 0.01 m; NaN: no region)."""
    y_m: float = math.nan
    """Sensor north of the reference position, metres (wire: 0.01 m)."""
    range_m: float = math.nan
    """Radius of the perception region, metres (wire: 0.1 m)."""
    start_deg: float = math.nan
    """Start of the horizontal opening angle, mathematical degrees (CCW from east)."""
    end_deg: float = math.nan
    """End of the horizontal opening angle, mathematical degrees; the region spans
    counter-clockwise from ``start_deg`` to ``end_deg``."""
    confidence_pct: int | None = None
    """``perceptionRegionConfidence``, percent (None: absent)."""

    @property
    def has_region(self) -> bool:
        """Whether the entry carries a radial perception region."""
        return math.isfinite(self.range_m)


@dataclass(frozen=True, slots=True)
class PerceivedObject:
    """One perceived object: a fused RF-SAS track."""

    object_id: int
    """``Identifier2B``, 0–65535: stable per track, never derived from a MAC."""
    measurement_delta_ms: int
    """Measurement time minus the reference time, ms (wire: −2048 … 2047)."""
    x_m: float
    """East of the reference position, metres (wire: 0.01 m)."""
    y_m: float
    """North of the reference position, metres (wire: 0.01 m)."""
    x_conf_m: float = math.nan
    """95 % confidence of ``x_m``, metres (wire: 0.01 m; NaN: unavailable)."""
    y_conf_m: float = math.nan
    """95 % confidence of ``y_m``, metres (wire: 0.01 m; NaN: unavailable)."""
    xy_correlation: float = math.nan
    """Correlation coefficient of x and y, −1 … 1 (wire: 0.01; NaN: no matrix)."""
    vx_mps: float = math.nan
    """East velocity, m/s (wire: 0.01 m/s; NaN: no velocity)."""
    vy_mps: float = math.nan
    """North velocity, m/s (wire: 0.01 m/s)."""
    vx_conf_mps: float = math.nan
    """95 % confidence of ``vx_mps``, m/s (wire: 0.01 m/s; NaN: unavailable)."""
    vy_conf_mps: float = math.nan
    """95 % confidence of ``vy_mps``, m/s."""
    age_ms: int | None = None
    """Time since the object was first perceived, ms (wire: 0 … 2047; None: absent)."""
    quality: int | None = None
    """``ObjectPerceptionQuality``, 0 (none) … 15 (full) (None: absent)."""
    sensor_ids: tuple[int, ...] = ()
    """Ids of the sensor entries that perceived it (empty: absent)."""
    object_class: VruClass | None = None
    """Class (None: no classification)."""
    class_confidence_pct: int = 101
    """Confidence of the class, percent (101: unavailable)."""

    @property
    def has_velocity(self) -> bool:
        """Whether the object carries a velocity."""
        return math.isfinite(self.vx_mps) and math.isfinite(self.vy_mps)


@dataclass(frozen=True, slots=True)
class Cpm:
    """One Collective Perception Message."""

    station_id: int
    """``StationId`` of the originating station, 0 … 2³²−1."""
    reference_time_ms: int
    """``TimestampIts``: TAI ms since 2004-01-01 UTC (:mod:`rfsas_hw.v2x.timestamp`)."""
    reference: ReferencePoint
    """Reference position of every offset in the message."""
    originating: Literal["rsu", "vehicle"] = "rsu"
    """Which originating station container the message carries."""
    heading_deg: float = math.nan
    """Vehicle only: orientation, degrees clockwise from north (wire: 0.1 °)."""
    heading_conf_deg: float = math.nan
    """Vehicle only: 95 % confidence of the orientation, degrees (NaN: unavailable)."""
    sensors: tuple[SensorEntry, ...] = ()
    """Sensor information container (empty: absent)."""
    objects: tuple[PerceivedObject, ...] = ()
    """Perceived objects of this message."""
    perceived_total: int | None = None
    """``numberOfPerceivedObjects``: objects perceived at generation time, over every
    segment (None: the container is absent, which it is when ``objects`` is empty and
    this is None)."""
    segment: tuple[int, int] | None = None
    """(this message's number, total messages), both 1 … 8, when segmented."""
    extra: dict[str, object] = field(default_factory=dict, compare=False, repr=False)
    """Decoded containers rfsas-hw does not model (a foreign CPM's), by name."""
