"""The generation rules: stable object ids with no MAC bits, when an object is included
again, the sensor information, segmentation, confidences from the covariance, and a
vehicle station's reference."""

from __future__ import annotations

import math

import pytest
from cpmhelp import assessment
from pycrate_cpm import PycrateCpm

from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import ConfigError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.records import Pose
from rfsas_hw.v2x.codec import decode_cpm
from rfsas_hw.v2x.model import CONFIDENCE_95_1D, CONFIDENCE_95_2D, LOCAL_AGGREGATION, RFID
from rfsas_hw.v2x.perception import CpmConfig, CpmGenerator, classify, perception_quality
from rfsas_hw.v2x.timestamp import its_ms_from_utc_ns

ORIGIN = SiteOrigin(52.2053, 0.1218, 12.0)
T0 = 1_795_737_600 * 1_000_000_000
MS = 1_000_000
STATIONS = {"rsu-a": Pose(-9.0, 9.0, 135.0), "rsu-b": Pose(9.0, -9.0, 315.0)}


def generator(**kw: object) -> CpmGenerator:
    return CpmGenerator(CpmConfig(station_id=7, origin=ORIGIN, **kw))  # type: ignore[arg-type]


def test_object_ids_are_handed_out_in_order_and_stay_with_the_track() -> None:
    for names in (["aa" * 8, "bb" * 8, "cc" * 8], ["0123456789abcdef", "ffff000000000001", "77"]):
        gen = generator()
        first = gen.step(T0, [assessment(n, T0, i, 0.0) for i, n in enumerate(names)], STATIONS)
        ids = [o.object_id for o in first[0].cpm.objects]
        # the same ids whatever the emitter ids: nothing of the hash is in them
        assert ids == [1, 2, 3]
        later = gen.step(
            T0 + 600 * MS, [assessment(n, T0, i, 0.0) for i, n in enumerate(names[::-1])], STATIONS
        )
        assert [o.object_id for o in later[0].cpm.objects] == [3, 2, 1]
    gen = generator()
    gen.step(T0, [assessment("a", T0, 0, 0), assessment("b", T0, 1, 0)], STATIONS)
    # "a" ends; a new track takes the next id, not a freed one
    out = gen.step(T0 + 600 * MS, [assessment("b", T0, 1, 0), assessment("c", T0, 2, 0)], STATIONS)
    assert sorted(o.object_id for o in out[0].cpm.objects) == [2, 3]


def test_position_confidence_and_correlation_come_from_the_covariance() -> None:
    gen = generator()
    a = assessment("a", T0 - 40 * MS, 12.346, -6.789, cov=(2.25, -0.9, 1.0), v=(1.1, -0.4))
    (msg,) = gen.step(T0, [a], STATIONS)
    o = decode_cpm(msg.data).objects[0]
    assert o.x_m == pytest.approx(12.35) and o.y_m == pytest.approx(-6.79)
    assert o.x_conf_m == pytest.approx(math.ceil(CONFIDENCE_95_1D * 1.5 * 100) / 100)
    assert o.y_conf_m == pytest.approx(math.ceil(CONFIDENCE_95_1D * 1.0 * 100) / 100)
    assert o.xy_correlation == pytest.approx(-0.6)
    assert (o.vx_mps, o.vy_mps) == pytest.approx((1.1, -0.4))
    assert o.measurement_delta_ms == -40
    assert o.sensor_ids == (1, 2)
    assert (o.object_class, o.class_confidence_pct) == ("pedestrian", 60)
    assert msg.cpm.reference_time_ms == its_ms_from_utc_ns(T0)
    assert o.age_ms == 40  # first seen at the assessment's time


def test_inclusion_rules() -> None:
    gen = generator()
    fast = (3.0, 0.0)  # a bicyclist: the 1 s rule, not the pedestrian 0.5 s rule
    assert len(gen.step(T0, [assessment("a", T0, 0, 0, v=fast)], STATIONS)) == 1

    def objects_at(dt_ms: int, x: float, v: tuple[float, float]) -> int | None:
        out = gen.step(T0 + dt_ms * MS, [assessment("a", T0 + dt_ms * MS, x, 0, v=v)], STATIONS)
        return None if not out else len(out[0].cpm.objects)

    assert objects_at(50, 0.1, fast) is None  # within T_GenCpmMin: nothing at all
    assert objects_at(200, 0.6, fast) is None  # nothing due
    assert objects_at(300, 4.5, fast) == 1  # moved more than 4 m
    assert objects_at(400, 4.7, (3.7, 0.0)) == 1  # speed changed by more than 0.5 m/s
    assert objects_at(500, 5.0, (3.7, 0.3)) == 1  # direction changed by more than 4°
    assert objects_at(600, 5.3, (3.7, 0.35)) is None
    assert objects_at(1500, 8.0, (3.7, 0.35)) == 1  # 1 s since it was last included

    ped = generator()
    ped.step(T0, [assessment("p", T0, 0, 0, v=(1.0, 0.0))], STATIONS)
    out = ped.step(T0 + 400 * MS, [assessment("p", T0, 0.4, 0, v=(1.0, 0.0))], STATIONS)
    assert out == []
    out = ped.step(T0 + 500 * MS, [assessment("p", T0, 0.5, 0, v=(1.0, 0.0))], STATIONS)
    assert len(out[0].cpm.objects) == 1  # a pedestrian-class object: every 0.5 s


def test_sensor_information_describes_the_units_and_their_view() -> None:
    gen = CpmGenerator(CpmConfig(station_id=7, origin=ORIGIN, fov_deg={"rsu-a": 90.0}))
    (msg,) = gen.step(T0, [assessment("a", T0, 0, 0)], STATIONS)
    sensors = decode_cpm(msg.data).sensors
    assert [(s.sensor_id, s.sensor_type) for s in sensors] == [
        (0, LOCAL_AGGREGATION),
        (1, RFID),
        (2, RFID),
    ]
    a = sensors[1]
    assert (a.x_m, a.y_m, a.range_m) == pytest.approx((-9.0, 9.0, 100.0))
    # boresight compass 135° (south-east) ± 45°: compass 90° … 180°, i.e. math -90° … 0°
    assert (a.start_deg, a.end_deg) == pytest.approx((270.0, 0.0))
    assert not a.shadowing_applies
    # again only after 1 s, or when the set of units changes
    out = gen.step(T0 + 600 * MS, [assessment("a", T0, 0, 0)], STATIONS)
    assert out[0].cpm.sensors == ()
    out = gen.step(T0 + 1200 * MS, [assessment("a", T0, 0, 0)], STATIONS)
    assert len(out[0].cpm.sensors) == 3


def test_heartbeat_without_objects_carries_the_sensors() -> None:
    gen = generator()
    (first,) = gen.step(T0, [], STATIONS)
    assert first.cpm.objects == () and first.cpm.perceived_total is None
    assert gen.step(T0 + 500 * MS, [], STATIONS) == []
    assert len(gen.step(T0 + 1000 * MS, [], STATIONS)) == 1


def test_many_objects_are_segmented(pycrate_cpm: PycrateCpm) -> None:
    gen = generator(max_message_bytes=400)
    crowd = [assessment(f"{i:016x}", T0, i * 1.5 - 40, i % 7 - 3.0) for i in range(50)]
    messages = gen.step(T0, crowd, STATIONS)
    assert 2 <= len(messages) <= 8
    assert all(len(m.data) <= 400 for m in messages)
    decoded = [decode_cpm(m.data) for m in messages]
    assert [d.segment for d in decoded] == [(i + 1, len(messages)) for i in range(len(messages))]
    assert all(d.perceived_total == 50 for d in decoded)
    assert decoded[0].sensors and all(not d.sensors for d in decoded[1:])
    ids = [o.object_id for d in decoded for o in d.objects]
    assert sorted(ids) == list(range(1, 51))
    for m in messages:
        assert pycrate_cpm.reencode(m.data) == m.data


def test_more_objects_than_one_message_holds_are_segmented() -> None:
    gen = generator(max_message_bytes=1_000_000)
    crowd = [assessment(f"{i:016x}", T0, i * 0.1, 0.0) for i in range(300)]
    messages = gen.step(T0, crowd, STATIONS)
    assert [len(m.cpm.objects) for m in messages] == [150, 150]
    assert [m.cpm.segment for m in messages] == [(1, 2), (2, 2)]


def test_singular_covariance_has_no_correlation() -> None:
    gen = generator()
    a = assessment("a", T0, 1.0, 2.0, cov=(math.inf, 0.5, 1.0))
    o = decode_cpm(gen.step(T0, [a], STATIONS)[0].data).objects[0]
    assert o.x_conf_m == math.inf and math.isnan(o.xy_correlation)
    assert o.quality == 0


def test_vehicle_station_references_the_vehicle() -> None:
    gen = generator(station="vehicle")
    car = VehicleState(x_m=10.0, y_m=-20.0, heading_deg=30.0, speed_mps=12.0)
    with pytest.raises(ConfigError, match="vehicle state"):
        gen.step(T0, [assessment("a", T0, 0, 0)], STATIONS)
    (msg,) = gen.step(T0, [assessment("a", T0, 13.0, -16.0)], STATIONS, vehicle=car)
    cpm = decode_cpm(msg.data)
    assert cpm.originating == "vehicle"
    assert cpm.heading_deg == pytest.approx(30.0)
    lat, lon, _ = ORIGIN.to_geodetic(10.0, -20.0)
    assert cpm.reference.lat_deg == pytest.approx(float(lat), abs=1e-7)
    assert cpm.reference.lon_deg == pytest.approx(float(lon), abs=1e-7)
    semi = CONFIDENCE_95_2D * car.sigma_along_m
    assert cpm.reference.semi_major_m == pytest.approx(
        max(semi, CONFIDENCE_95_2D * car.sigma_across_m), abs=0.01
    )
    o = cpm.objects[0]
    assert (o.x_m, o.y_m) == pytest.approx((3.0, 4.0))


def test_class_mapping_and_quality() -> None:
    assert classify(math.nan) == ("pedestrian", 60)
    assert classify(1.4) == ("pedestrian", 60)
    assert classify(5.0) == ("bicyclist", 50)
    assert classify(20.0) == ("unknown", 101)
    assert perception_quality(False, 1.0, 0.0) == 0
    assert perception_quality(True, 0.0, 0.0) == 15
    assert perception_quality(True, 10.0, 0.0) == 8
    assert perception_quality(True, 25.0, 0.0) == 0
    assert perception_quality(True, math.inf, 0.0) == 0


def test_config_is_checked() -> None:
    with pytest.raises(ConfigError, match="station id"):
        CpmConfig(station_id=-1, origin=ORIGIN)
    with pytest.raises(ConfigError, match="range"):
        CpmConfig(station_id=1, origin=ORIGIN, range_m=500.0)
    with pytest.raises(ConfigError, match="field of view"):
        CpmConfig(station_id=1, origin=ORIGIN, fov_deg={"x": 0.0})
