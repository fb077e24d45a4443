"""CPM encoding: the standard's example timestamps, round trips within the wire's
resolution, golden vectors, and pycrate (an independent ASN.1 compiler) reading every
message and writing the same bytes again."""

from __future__ import annotations

import calendar
import math
from dataclasses import replace

import pytest
from cpmhelp import REFERENCE, T0_MS, sample_cpm, sample_object
from golden import GOLDEN, GOLDEN_DIR
from hypothesis import given, settings
from hypothesis import strategies as st
from pycrate_cpm import PycrateCpm

from rfsas_hw.errors import CpmFormatError
from rfsas_hw.v2x.codec import decode_cpm, decode_cpm_tree, encode_cpm
from rfsas_hw.v2x.model import Cpm, PerceivedObject
from rfsas_hw.v2x.timestamp import its_ms_from_utc_ns, utc_ns_from_its_ms

S = 1_000_000_000


def utc_ns(*ymdhms: int) -> int:
    return calendar.timegm((*ymdhms, 0, 0, 0)[:6]) * S  # type: ignore[arg-type]


def test_timestamp_its_matches_the_standards_example() -> None:
    # TS 102 894-2, TimestampIts: 2007-01-01T00:00:00 UTC is 94 694 401 000 ms
    assert its_ms_from_utc_ns(utc_ns(2007, 1, 1, 0, 0, 0)) == 94_694_401_000
    assert its_ms_from_utc_ns(utc_ns(2004, 1, 1, 0, 0, 0)) == 0
    # five leap seconds since the epoch by 2022 ("5 seconds ahead of UTC")
    t = utc_ns(2022, 1, 1, 0, 0, 0)
    assert its_ms_from_utc_ns(t) == (t - utc_ns(2004, 1, 1, 0, 0, 0)) // 1_000_000 + 5_000


def test_timestamp_its_counts_the_leap_second_and_inverts() -> None:
    before = utc_ns(2016, 12, 31, 23, 59, 59)
    after = utc_ns(2017, 1, 1, 0, 0, 0)
    assert its_ms_from_utc_ns(after) - its_ms_from_utc_ns(before) == 2_000
    for t in (before, after, after + 123_000_000, utc_ns(2026, 11, 27, 12, 0, 0)):
        assert utc_ns_from_its_ms(its_ms_from_utc_ns(t)) == t
    # the inserted second 23:59:60 has no POSIX name: it maps to the next second
    assert utc_ns_from_its_ms(its_ms_from_utc_ns(before) + 1_500) == after
    with pytest.raises(ValueError, match="before the ITS epoch"):
        its_ms_from_utc_ns(utc_ns(2003, 12, 31, 23, 59, 59))


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_golden_vector_is_encoded_and_read_by_pycrate(name: str, pycrate_cpm: PycrateCpm) -> None:
    data = (GOLDEN_DIR / f"{name}.uper").read_bytes()
    assert encode_cpm(GOLDEN[name]) == data
    assert pycrate_cpm.reencode(data) == data
    value = pycrate_cpm.decode(data)
    assert value["header"] == {"protocolVersion": 2, "messageId": 14, "stationId": 4_000_000_123}
    assert value["payload"]["managementContainer"]["referenceTime"] == T0_MS
    containers = dict(c["containerData"] for c in value["payload"]["cpmContainers"])
    cpm = GOLDEN[name]
    assert ("OriginatingVehicleContainer" in containers) == (cpm.originating == "vehicle")
    assert ("OriginatingRsuContainer" in containers) == (cpm.originating == "rsu")
    objects = containers.get("PerceivedObjectContainer", {"perceivedObjects": []})
    assert len(objects["perceivedObjects"]) == len(cpm.objects)
    for obj, raw in zip(cpm.objects, objects["perceivedObjects"], strict=True):
        assert raw["objectId"] == obj.object_id
        assert raw["position"]["xCoordinate"]["value"] == round(obj.x_m * 100)
        assert raw["position"]["yCoordinate"]["value"] == round(obj.y_m * 100)
        assert raw["position"]["xCoordinate"]["confidence"] == math.ceil(obj.x_conf_m * 100)
        has_matrix = "lowerTriangularCorrelationMatrices" in raw
        assert has_matrix == math.isfinite(obj.xy_correlation)
        if has_matrix:
            cell = raw["lowerTriangularCorrelationMatrices"][0]["matrix"][0][0]
            assert cell == round(obj.xy_correlation * 100)
    segment = value["payload"]["managementContainer"].get("segmentationInfo")
    assert (segment is None) == (cpm.segment is None)


def test_golden_vectors_cover_the_required_cases() -> None:
    counts = {len(c.objects) for c in GOLDEN.values()}
    assert {0, 1, 20} <= counts
    assert {c.originating for c in GOLDEN.values()} == {"rsu", "vehicle"}
    assert any(c.segment for c in GOLDEN.values())
    assert any(o.xy_correlation != o.xy_correlation for c in GOLDEN.values() for o in c.objects)
    assert len(GOLDEN) >= 10


def close(a: float, b: float, tol: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or abs(a - b) <= tol + 1e-9


finite = st.floats(allow_nan=False, allow_infinity=False)
objects = st.builds(
    PerceivedObject,
    object_id=st.integers(0, 65535),
    measurement_delta_ms=st.integers(-2048, 2047),
    x_m=st.floats(-1310.0, 1310.0),
    y_m=st.floats(-1310.0, 1310.0),
    x_conf_m=st.floats(0.0, 40.9) | st.just(math.nan),
    y_conf_m=st.floats(0.0, 40.9) | st.just(math.nan),
    xy_correlation=st.floats(-1.0, 1.0) | st.just(math.nan),
    vx_mps=st.floats(-160.0, 160.0),
    vy_mps=st.floats(-160.0, 160.0),
    vx_conf_mps=st.floats(0.0, 1.25) | st.just(math.nan),
    vy_conf_mps=st.floats(0.0, 1.25) | st.just(math.nan),
    age_ms=st.none() | st.integers(0, 2047),
    quality=st.none() | st.integers(0, 15),
    sensor_ids=st.lists(st.integers(0, 255), max_size=5).map(tuple),
    object_class=st.none() | st.sampled_from(["pedestrian", "bicyclist", "unknown"]),
    class_confidence_pct=st.integers(1, 101),
)


@settings(max_examples=60, deadline=None)
@given(
    objs=st.lists(objects, max_size=6),
    station=st.integers(0, 2**32 - 1),
    t_ms=st.integers(0, 4398046511103),
    vehicle=st.booleans(),
    heading=st.floats(0.0, 359.94),
)
def test_round_trip_within_the_field_resolutions(
    objs: list[PerceivedObject], station: int, t_ms: int, vehicle: bool, heading: float
) -> None:
    cpm = Cpm(
        station_id=station,
        reference_time_ms=t_ms,
        reference=REFERENCE,
        originating="vehicle" if vehicle else "rsu",
        heading_deg=heading if vehicle else math.nan,
        objects=tuple(objs),
        perceived_total=len(objs),
    )
    back = decode_cpm(encode_cpm(cpm))
    assert back.station_id == station and back.reference_time_ms == t_ms
    assert back.originating == cpm.originating
    if vehicle:
        assert abs((back.heading_deg - heading + 180) % 360 - 180) <= 0.05 + 1e-9
    assert len(back.objects) == len(objs)
    for o, b in zip(objs, back.objects, strict=True):
        assert b.object_id == o.object_id and b.measurement_delta_ms == o.measurement_delta_ms
        assert close(b.x_m, o.x_m, 0.005) and close(b.y_m, o.y_m, 0.005)
        for conf, got in ((o.x_conf_m, b.x_conf_m), (o.y_conf_m, b.y_conf_m)):
            # a confidence rounds up to the next 0.01 m (at least 0.01 m)
            assert math.isnan(conf) == math.isnan(got)
            if not math.isnan(conf):
                assert conf - 1e-9 <= got <= max(conf, 0.0) + 0.01 + 1e-9
        assert close(b.xy_correlation, o.xy_correlation, 0.005)
        assert close(b.vx_mps, o.vx_mps, 0.005) and close(b.vy_mps, o.vy_mps, 0.005)
        assert b.age_ms == o.age_ms and b.quality == o.quality
        assert b.sensor_ids == o.sensor_ids
        assert b.object_class == o.object_class
        if o.object_class is not None:
            assert b.class_confidence_pct == o.class_confidence_pct


def test_sensor_regions_and_reference_round_trip() -> None:
    cpm = sample_cpm(1, vehicle=True)
    back = decode_cpm(encode_cpm(cpm))
    assert back.sensors == cpm.sensors
    assert back.reference == REFERENCE
    assert back.heading_deg == pytest.approx(87.3) and back.heading_conf_deg == pytest.approx(2.0)


def test_out_of_range_values_take_the_standards_codes() -> None:
    far = replace(sample_object(0), x_m=5000.0, y_m=-5000.0, x_conf_m=80.0, y_conf_m=math.nan)
    back = decode_cpm(encode_cpm(replace(sample_cpm(0), objects=(far,))))
    o = back.objects[0]
    assert o.x_m == pytest.approx(1310.71) and o.y_m == pytest.approx(-1310.72)
    assert o.x_conf_m == math.inf and math.isnan(o.y_conf_m)


@pytest.mark.parametrize(
    ("change", "what"),
    [
        ({"station_id": 2**32}, "station id"),
        ({"segment": (3, 2)}, "segment number"),
        ({"objects": (replace(sample_object(0), object_id=65536),)}, "object id"),
        ({"objects": (replace(sample_object(0), x_m=math.nan),)}, "position not finite"),
        ({"objects": (replace(sample_object(0), sensor_ids=(300,)),)}, "sensor id"),
    ],
)
def test_values_a_cpm_cannot_hold_are_refused(change: dict[str, object], what: str) -> None:
    with pytest.raises(CpmFormatError, match=what):
        encode_cpm(replace(sample_cpm(0), **change))  # type: ignore[arg-type]


def test_a_segment_number_beyond_the_total_is_refused(pycrate_cpm: PycrateCpm) -> None:
    # each number is in its ASN.1 range (1 … 8), but message 5 of 2 does not exist
    value = pycrate_cpm.decode((GOLDEN_DIR / "rsu_segment_2_of_2.uper").read_bytes())
    value["payload"]["managementContainer"]["segmentationInfo"]["thisMsgNo"] = 5
    with pytest.raises(CpmFormatError, match="message 5 of 2 segments"):
        decode_cpm(pycrate_cpm.encode(value))


def test_truncated_or_padded_cpm_is_refused_with_a_reason() -> None:
    data = encode_cpm(sample_cpm(3))
    for cut in (0, 1, 5, 10, len(data) // 2, len(data) - 1):
        with pytest.raises(CpmFormatError, match="CPM"):
            decode_cpm(data[:cut])
    with pytest.raises(CpmFormatError, match="after the end"):
        decode_cpm(data + b"\x00\x00")


def test_other_messages_are_refused() -> None:
    data = bytearray(encode_cpm(sample_cpm(0)))
    data[1] = 2  # messageId cam
    with pytest.raises(CpmFormatError, match="messageId 2"):
        decode_cpm(bytes(data))
    data = bytearray(encode_cpm(sample_cpm(0)))
    data[0] = 1  # protocolVersion 1
    with pytest.raises(CpmFormatError, match="protocolVersion 1"):
        decode_cpm(bytes(data))


def test_tree_is_json_of_every_container() -> None:
    import json

    tree = decode_cpm_tree(encode_cpm(sample_cpm(2, vehicle=True)))
    text = json.dumps(tree)
    assert tree["header"]["messageId"] == 14
    assert set(tree["containers"]) == {
        "originatingVehicleContainer",
        "sensorInformationContainer",
        "perceivedObjectContainer",
    }
    obj = tree["containers"]["perceivedObjectContainer"]["perceivedObjects"][0]
    assert obj["lowerTriangularCorrelationMatrices"][0]["componentsIncludedIntheMatrix"] == [0, 1]
    assert "cartesianVelocity" in obj["velocity"]
    assert json.loads(text) == tree


def foreign_cpm() -> bytes:
    """A CPM as another station might send it: a perception region, a polar velocity,
    an object without classification, written with asn1tools directly."""
    import asn1tools

    from rfsas_hw.v2x.codec import ASN1_DIR

    spec = asn1tools.compile_files(sorted(str(p) for p in ASN1_DIR.glob("*.asn")), "uper")
    region = [
        {
            "measurementDeltaTime": -10,
            "perceptionRegionConfidence": 90,
            "perceptionRegionShape": ("circular", {"radius": 500}),
            "shadowingApplies": True,
        }
    ]
    objects = {
        "numberOfPerceivedObjects": 1,
        "perceivedObjects": [
            {
                "objectId": 42,
                "measurementDeltaTime": 5,
                "position": {
                    "xCoordinate": {"value": 1234, "confidence": 50},
                    "yCoordinate": {"value": -567, "confidence": 60},
                },
                "velocity": (
                    "polarVelocity",
                    {
                        "velocityMagnitude": {"speedValue": 300, "speedConfidence": 10},
                        "velocityDirection": {"value": 450, "confidence": 20},
                    },
                ),
            }
        ],
    }
    message = {
        "header": {"protocolVersion": 2, "messageId": 14, "stationId": 99},
        "payload": {
            "managementContainer": {
                "referenceTime": T0_MS,
                "referencePosition": {
                    "latitude": 500000000,
                    "longitude": 60000000,
                    "positionConfidenceEllipse": {
                        "semiMajorConfidence": 100,
                        "semiMinorConfidence": 50,
                        "semiMajorOrientation": 900,
                    },
                    "altitude": {"altitudeValue": 800001, "altitudeConfidence": "unavailable"},
                },
            },
            "cpmContainers": [
                {"containerId": 2, "containerData": spec.encode("OriginatingRsuContainer", {})},
                {
                    "containerId": 4,
                    "containerData": spec.encode("PerceptionRegionContainer", region),
                },
                {
                    "containerId": 5,
                    "containerData": spec.encode("PerceivedObjectContainer", objects),
                },
            ],
        },
    }
    return bytes(spec.encode("CollectivePerceptionMessage", message))


def test_a_foreign_cpm_is_read_with_what_rfsas_does_not_write(pycrate_cpm: PycrateCpm) -> None:
    data = foreign_cpm()
    assert pycrate_cpm.reencode(data) == data
    cpm = decode_cpm(data)
    assert cpm.station_id == 99 and math.isnan(cpm.reference.altitude_m)
    assert cpm.reference.semi_major_m == pytest.approx(1.0)
    (obj,) = cpm.objects
    assert (obj.object_id, obj.x_m, obj.y_m) == (42, pytest.approx(12.34), pytest.approx(-5.67))
    # a polar velocity (3 m/s at 45°) is read as east/north components
    assert (obj.vx_mps, obj.vy_mps) == (pytest.approx(2.1213, abs=1e-4),) * 2
    assert math.isnan(obj.vx_conf_mps) and obj.object_class is None
    region = cpm.extra["perceptionRegionContainer"]
    assert region[0]["perceptionRegionShape"] == {"circular": {"radius": 500}}
    tree = decode_cpm_tree(data)
    velocity = tree["containers"]["perceivedObjectContainer"]["perceivedObjects"][0]["velocity"]
    assert velocity["polarVelocity"]["velocityMagnitude"]["speedValue"] == 300
