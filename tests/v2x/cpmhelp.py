"""Sample CPMs and backend records for the V2X tests, the golden vectors and the bench."""

from __future__ import annotations

import math

import numpy as np

from rfsas_hw.records import Assessment
from rfsas_hw.v2x.model import (
    LOCAL_AGGREGATION,
    RFID,
    Cpm,
    PerceivedObject,
    ReferencePoint,
    SensorEntry,
)

T0_MS = 722_822_405_123
"""A TimestampIts of 2026-11-27."""
REFERENCE = ReferencePoint(52.2053, 0.1218, 12.0, 0.25, 0.25, 0.0)
SENSORS = (
    SensorEntry(0, LOCAL_AGGREGATION, False),
    SensorEntry(1, RFID, False, x_m=-9.0, y_m=9.0, range_m=100.0, start_deg=285.0, end_deg=15.0),
    SensorEntry(2, RFID, False, x_m=9.0, y_m=-9.0, range_m=100.0, start_deg=105.0, end_deg=195.0),
)


def sample_object(i: int, *, correlation: bool = True, velocity: bool = True) -> PerceivedObject:
    """Object ``i`` of a crowd: positions spread over ±40 m, full covariance."""
    rng = np.random.default_rng(i)
    x, y = rng.uniform(-40, 40, 2)
    return PerceivedObject(
        object_id=i + 1,
        measurement_delta_ms=-int(rng.integers(0, 200)),
        x_m=float(x),
        y_m=float(y),
        x_conf_m=float(rng.uniform(0.3, 5.0)),
        y_conf_m=float(rng.uniform(0.3, 5.0)),
        xy_correlation=float(rng.uniform(-0.9, 0.9)) if correlation else math.nan,
        vx_mps=float(rng.uniform(-2, 2)) if velocity else math.nan,
        vy_mps=float(rng.uniform(-2, 2)) if velocity else math.nan,
        age_ms=int(rng.integers(0, 3000)),
        quality=int(rng.integers(0, 16)),
        sensor_ids=(1, 2),
        object_class="pedestrian" if i % 4 else "bicyclist",
        class_confidence_pct=60 if i % 4 else 50,
    )


def sample_cpm(
    n_objects: int,
    *,
    vehicle: bool = False,
    correlation: bool = True,
    sensors: bool = True,
    segment: tuple[int, int] | None = None,
) -> Cpm:
    """A CPM of ``n_objects`` sample objects."""
    return Cpm(
        station_id=4_000_000_123,
        reference_time_ms=T0_MS,
        reference=REFERENCE,
        originating="vehicle" if vehicle else "rsu",
        heading_deg=87.3 if vehicle else math.nan,
        heading_conf_deg=2.0 if vehicle else math.nan,
        sensors=SENSORS if sensors else (),
        objects=tuple(sample_object(i, correlation=correlation) for i in range(n_objects)),
        perceived_total=n_objects,
        segment=segment,
    )


def assessment(
    emitter: str,
    t_ns: int,
    x_m: float,
    y_m: float,
    *,
    cov: tuple[float, float, float] = (1.0, 0.3, 0.5),
    v: tuple[float, float] = (1.0, 0.2),
    sensors: tuple[str, ...] = ("rsu-a", "rsu-b"),
) -> Assessment:
    """A tracked emitter as the backend reports it."""
    return Assessment(
        t_ns=t_ns,
        emitter=emitter,
        x_m=x_m,
        y_m=y_m,
        cov_xx_m2=cov[0],
        cov_xy_m2=cov[1],
        cov_yy_m2=cov[2],
        vx_mps=v[0],
        vy_mps=v[1],
        age_s=0.05,
        sensors=sensors,
        fix_ok=True,
        fix_reason="ok",
        p_collision=math.nan,
        t_closest_s=math.nan,
        distance_to_contact_m=math.nan,
        impact_speed_mps=math.nan,
        fatality_risk=math.nan,
        risk=math.nan,
        advisory="none",
        reasons=(),
        link_alarm=False,
    )
