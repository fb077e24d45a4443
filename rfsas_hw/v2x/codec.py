"""UPER encoding and decoding of Collective Perception Messages (ETSI TS 103 324 v2.1.1).

The wire format is the standard's own ASN.1 (carried as package data in
``rfsas_hw/v2x/asn1/``, with its licence and provenance) compiled by ``asn1tools``
(the ``v2x`` extra) once per process. :func:`encode_cpm` turns a :class:`Cpm` into
bytes; :func:`decode_cpm` reads them back into a :class:`Cpm` at the wire's
resolution. :func:`decode_cpm_tree` gives the whole decoded message as plain JSON
values, for CPMs of other stations that carry containers rfsas-hw does not write.

Every decode is strict: the bytes must be exactly what encoding the decoded value
gives (no trailing bytes, no out-of-range values), otherwise a
:class:`~rfsas_hw.errors.CpmFormatError` says why. The message names the field.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from rfsas_hw.errors import CpmFormatError
from rfsas_hw.optional import require
from rfsas_hw.v2x.model import (
    Cpm,
    PerceivedObject,
    ReferencePoint,
    SensorEntry,
    VruClass,
)

__all__ = ["ASN1_DIR", "decode_cpm", "decode_cpm_tree", "encode_cpm", "load_schema"]

ASN1_DIR = Path(__file__).with_name("asn1")
"""The ETSI ASN.1 modules (CPM v2.1.1 and the Common Data Dictionary v2.4.1)."""

PROTOCOL_VERSION = 2
MESSAGE_ID_CPM = 14
_CONTAINER_TYPES = {
    1: "OriginatingVehicleContainer",
    2: "OriginatingRsuContainer",
    3: "SensorInformationContainer",
    4: "PerceptionRegionContainer",
    5: "PerceivedObjectContainer",
}
_MATRIX_XY = (b"\xc0\x00", 13)
"""``MatrixIncludedComponents`` with xPosition and yPosition (bits 0 and 1)."""


@functools.cache
def _spec() -> Any:
    asn1tools = require("asn1tools")
    files = sorted(str(p) for p in ASN1_DIR.glob("*.asn"))
    return asn1tools.compile_files(files, "uper")


def load_schema() -> None:
    """Compile the ASN.1 modules now (about a second, once per process) rather than at
    the first message, so that a live sink does not stall its first step.

    Raises:
        MissingDependencyError: ``asn1tools`` is not installed (the ``v2x`` extra).
    """
    _spec()


# --- SI → wire ---------------------------------------------------------------------


def _scaled(value: float, unit: float, lo: int, hi: int) -> int:
    """``value / unit`` rounded, clamped to [lo, hi] (the out-of-range codes at the ends)."""
    return max(lo, min(hi, round(value / unit)))


def _confidence(value: float, unit: float, out_of_range: int, unavailable: int) -> int:
    """A 95 % confidence as the smallest n with ``value ≤ n·unit`` (1 … out_of_range);
    NaN is unavailable, infinity out of range."""
    if math.isnan(value) or value < 0:
        return unavailable
    if math.isinf(value):
        return out_of_range
    return max(1, min(out_of_range, math.ceil(value / unit - 1e-9)))


def _angle_01(deg: float, unavailable: int) -> int:
    """Degrees as 0.1 ° in [0, 3600), or ``unavailable``."""
    if not math.isfinite(deg):
        return unavailable
    return round((deg % 360.0) * 10.0) % 3600


def _reference(ref: ReferencePoint) -> dict[str, Any]:
    return {
        "latitude": round(ref.lat_deg * 1e7),
        "longitude": round(ref.lon_deg * 1e7),
        "positionConfidenceEllipse": {
            "semiMajorConfidence": _confidence(ref.semi_major_m, 0.01, 4094, 4095),
            "semiMinorConfidence": _confidence(ref.semi_minor_m, 0.01, 4094, 4095),
            "semiMajorOrientation": _angle_01(ref.major_heading_deg, 3601),
        },
        "altitude": {
            "altitudeValue": (
                _scaled(ref.altitude_m, 0.01, -100000, 800000)
                if math.isfinite(ref.altitude_m)
                else 800001
            ),
            "altitudeConfidence": "unavailable",
        },
    }


def _sensor(s: SensorEntry) -> dict[str, Any]:
    out: dict[str, Any] = {"sensorId": s.sensor_id, "sensorType": s.sensor_type}
    if s.has_region:
        out["perceptionRegionShape"] = (
            "radial",
            {
                "shapeReferencePoint": {
                    "xCoordinate": _scaled(s.x_m, 0.01, -32768, 32767),
                    "yCoordinate": _scaled(s.y_m, 0.01, -32768, 32767),
                },
                "range": _scaled(s.range_m, 0.1, 0, 4095),
                "horizontalOpeningAngleStart": _angle_01(s.start_deg, 3601),
                "horizontalOpeningAngleEnd": _angle_01(s.end_deg, 3601),
            },
        )
    if s.confidence_pct is not None:
        out["perceptionRegionConfidence"] = s.confidence_pct
    out["shadowingApplies"] = s.shadowing_applies
    return out


def _coordinate(value_m: float, conf_m: float) -> dict[str, int]:
    return {
        "value": _scaled(value_m, 0.01, -131072, 131071),
        "confidence": _confidence(conf_m, 0.01, 4095, 4096),
    }


def _velocity(value: float, conf: float) -> dict[str, int]:
    return {
        "value": _scaled(value, 0.01, -16383, 16382),
        "confidence": _confidence(conf, 0.01, 126, 127),
    }


def _class(kind: VruClass, confidence: int) -> dict[str, Any]:
    if kind == "pedestrian":
        cls: tuple[str, Any] = ("vruSubClass", ("pedestrian", 0))
    elif kind == "bicyclist":
        cls = ("vruSubClass", ("bicyclistAndLightVruVehicle", 1))
    else:
        cls = ("vehicleSubClass", 0)
    return {"objectClass": cls, "confidence": confidence}


def _object(o: PerceivedObject) -> dict[str, Any]:
    out: dict[str, Any] = {
        "objectId": o.object_id,
        "measurementDeltaTime": max(-2048, min(2047, o.measurement_delta_ms)),
        "position": {
            "xCoordinate": _coordinate(o.x_m, o.x_conf_m),
            "yCoordinate": _coordinate(o.y_m, o.y_conf_m),
        },
    }
    if o.has_velocity:
        out["velocity"] = (
            "cartesianVelocity",
            {
                "xVelocity": _velocity(o.vx_mps, o.vx_conf_mps),
                "yVelocity": _velocity(o.vy_mps, o.vy_conf_mps),
            },
        )
    if math.isfinite(o.xy_correlation):
        rho = max(-100, min(100, round(o.xy_correlation * 100.0)))
        out["lowerTriangularCorrelationMatrices"] = [
            {"componentsIncludedIntheMatrix": _MATRIX_XY, "matrix": [[rho]]}
        ]
    if o.age_ms is not None:
        out["objectAge"] = max(0, min(2047, o.age_ms))
    if o.quality is not None:
        out["objectPerceptionQuality"] = o.quality
    if o.sensor_ids:
        out["sensorIdList"] = list(o.sensor_ids)
    if o.object_class is not None:
        out["classification"] = [_class(o.object_class, o.class_confidence_pct)]
    return out


def _encode(spec: Any, type_name: str, value: Any, what: str) -> bytes:
    try:
        return bytes(spec.encode(type_name, value, check_types=False, check_constraints=False))
    except Exception as err:  # asn1tools raises its own Error tree and ValueError/TypeError
        raise CpmFormatError(f"cannot encode {what}: {err}") from err


def _in(value: int, lo: int, hi: int, what: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise CpmFormatError(f"cannot encode {what} {value!r}: must be an integer in {lo} … {hi}")


def _check(cpm: Cpm) -> None:
    """The ranges asn1tools is not asked to check (its constraint check costs a third
    of the encoding time; every other value is clamped on the way in)."""
    _in(cpm.station_id, 0, 2**32 - 1, "station id")
    _in(cpm.reference_time_ms, 0, 4398046511103, "reference time (TimestampIts)")
    ref = cpm.reference
    if not (abs(ref.lat_deg) <= 90 and abs(ref.lon_deg) <= 180):
        raise CpmFormatError(f"cannot encode reference position {ref.lat_deg}, {ref.lon_deg}")
    if cpm.segment is not None:
        _in(cpm.segment[1], 1, 8, "total number of segments")
        _in(cpm.segment[0], 1, cpm.segment[1], "segment number")
    if len(cpm.sensors) > 128:
        raise CpmFormatError(f"cannot encode {len(cpm.sensors)} sensors: at most 128")
    if len(cpm.objects) > 255:
        raise CpmFormatError(f"cannot encode {len(cpm.objects)} objects: at most 255")
    for s in cpm.sensors:
        _in(s.sensor_id, 0, 255, "sensor id")
        _in(s.sensor_type, 0, 31, "sensor type")
        if s.confidence_pct is not None:
            _in(s.confidence_pct, 1, 101, "perception region confidence")
    for o in cpm.objects:
        _in(o.object_id, 0, 65535, "object id")
        _in(o.class_confidence_pct, 1, 101, "class confidence")
        if o.quality is not None:
            _in(o.quality, 0, 15, "perception quality")
        if not (math.isfinite(o.x_m) and math.isfinite(o.y_m)):
            raise CpmFormatError(f"cannot encode object {o.object_id}: position not finite")
        if len(o.sensor_ids) > 128:
            raise CpmFormatError(f"object {o.object_id}: more than 128 sensor ids")
        for sid in o.sensor_ids:
            _in(sid, 0, 255, f"object {o.object_id}: sensor id")


def encode_cpm(cpm: Cpm) -> bytes:
    """The UPER bytes of ``cpm`` (a ``CollectivePerceptionMessage``).

    Values outside a field's range are clamped to its out-of-range code, as the
    standard prescribes; confidences round up to the next wire step.

    Raises:
        CpmFormatError: a value the message cannot hold (an id out of range, more
            than 255 objects or 128 sensors, a station id over 2³²−1).
        MissingDependencyError: ``asn1tools`` is not installed (the ``v2x`` extra).
    """
    _check(cpm)
    spec = _spec()
    management: dict[str, Any] = {
        "referenceTime": cpm.reference_time_ms,
        "referencePosition": _reference(cpm.reference),
    }
    if cpm.segment is not None:
        management["segmentationInfo"] = {"thisMsgNo": cpm.segment[0], "totalMsgNo": cpm.segment[1]}
    containers: list[tuple[int, str, Any]] = []
    if cpm.originating == "vehicle":
        containers.append(
            (
                1,
                "OriginatingVehicleContainer",
                {
                    "orientationAngle": {
                        "value": _angle_01(cpm.heading_deg, 3601),
                        "confidence": _confidence(cpm.heading_conf_deg, 0.1, 126, 127),
                    }
                },
            )
        )
    else:
        containers.append((2, "OriginatingRsuContainer", {}))
    if cpm.sensors:
        containers.append((3, "SensorInformationContainer", [_sensor(s) for s in cpm.sensors]))
    if cpm.objects or cpm.perceived_total is not None:
        total = len(cpm.objects) if cpm.perceived_total is None else cpm.perceived_total
        containers.append(
            (
                5,
                "PerceivedObjectContainer",
                {
                    "numberOfPerceivedObjects": min(total, 255),
                    "perceivedObjects": [_object(o) for o in cpm.objects],
                },
            )
        )
    wrapped = [
        {"containerId": cid, "containerData": _encode(spec, name, value, name)}
        for cid, name, value in containers
    ]
    message = {
        "header": {
            "protocolVersion": PROTOCOL_VERSION,
            "messageId": MESSAGE_ID_CPM,
            "stationId": cpm.station_id,
        },
        "payload": {"managementContainer": management, "cpmContainers": wrapped},
    }
    return _encode(spec, "CollectivePerceptionMessage", message, "the CPM")


# --- wire → values -----------------------------------------------------------------


def _strict(spec: Any, type_name: str, data: bytes, what: str) -> Any:
    """Decode ``data`` as ``type_name`` and require that it re-encodes to the same bytes."""
    try:
        value = spec.decode(type_name, data, check_constraints=True)
    except Exception as err:
        raise CpmFormatError(f"{what}: {err}") from err
    try:
        again = bytes(spec.encode(type_name, value, check_constraints=True))
    except Exception as err:
        raise CpmFormatError(f"{what}: decoded value does not encode again: {err}") from err
    if again != data:
        if data.startswith(again):
            raise CpmFormatError(
                f"{what}: {len(data) - len(again)} byte(s) after the end of the encoding"
            )
        raise CpmFormatError(f"{what}: not the canonical UPER encoding of its value")
    return value


def _message(data: bytes) -> tuple[Any, dict[str, Any]]:
    """The decoded message and its containers by name (their data decoded)."""
    if not isinstance(data, bytes | bytearray | memoryview):
        raise CpmFormatError(f"a CPM is bytes, got {type(data).__name__}")
    data = bytes(data)
    if len(data) < 6:
        raise CpmFormatError(f"CPM of {len(data)} bytes is too short for a header")
    spec = _spec()
    msg = _strict(spec, "CollectivePerceptionMessage", data, "CPM")
    header = msg["header"]
    if header["messageId"] != MESSAGE_ID_CPM:
        raise CpmFormatError(f"CPM: messageId {header['messageId']} is not cpm (14)")
    if header["protocolVersion"] != PROTOCOL_VERSION:
        raise CpmFormatError(
            f"CPM: protocolVersion {header['protocolVersion']}; only CPM v2 (2) is decoded"
        )
    containers: dict[str, Any] = {}
    for i, wrapped in enumerate(msg["payload"]["cpmContainers"]):
        cid = wrapped["containerId"]
        type_name = _CONTAINER_TYPES.get(cid)
        where = f"CPM container {i} (id {cid})"
        if type_name is None:
            containers[f"container{cid}"] = wrapped["containerData"]
            continue
        name = type_name[0].lower() + type_name[1:]
        if name in containers:
            raise CpmFormatError(f"{where}: a second {type_name}")
        containers[name] = _strict(spec, type_name, bytes(wrapped["containerData"]), where)
    if "originatingVehicleContainer" in containers and "originatingRsuContainer" in containers:
        raise CpmFormatError("CPM: both an originating vehicle and an originating RSU container")
    return msg, containers


def _jsonable(value: Any) -> Any:
    """asn1tools values as JSON: CHOICE → {name: value}, BIT STRING → bit list, bytes → hex."""
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, tuple) and len(value) == 2 and isinstance(value[0], str):
        return {value[0]: _jsonable(value[1])}
    if isinstance(value, tuple) and len(value) == 2 and isinstance(value[0], bytes):
        bits, n = value
        return [i for i in range(n) if bits[i // 8] >> (7 - i % 8) & 1]
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, bytes | bytearray):
        return bytes(value).hex()
    return value


def decode_cpm_tree(data: bytes) -> dict[str, Any]:
    """The whole CPM as JSON values, its containers decoded (any station's CPM v2).

    ``CHOICE`` values become one-key objects, ``BIT STRING`` the list of set bit
    numbers, unknown containers their bytes in hex.

    Raises:
        CpmFormatError: not a strict UPER CPM v2.
        MissingDependencyError: ``asn1tools`` is not installed.
    """
    msg, containers = _message(data)
    payload = msg["payload"]
    return {
        "header": _jsonable(msg["header"]),
        "managementContainer": _jsonable(payload["managementContainer"]),
        "containers": _jsonable(containers),
    }


def _unscale(value: int, unit: float, unavailable: int | None = None) -> float:
    return math.nan if value == unavailable else value * unit


def _conf_back(value: int, unit: float, out_of_range: int, unavailable: int) -> float:
    if value == unavailable:
        return math.nan
    if value == out_of_range:
        return math.inf
    return value * unit


def _angle_back(value: int) -> float:
    return math.nan if value >= 3600 else value / 10.0


def _decode_reference(raw: Mapping[str, Any]) -> ReferencePoint:
    ell = raw["positionConfidenceEllipse"]
    return ReferencePoint(
        lat_deg=raw["latitude"] / 1e7,
        lon_deg=raw["longitude"] / 1e7,
        altitude_m=_unscale(raw["altitude"]["altitudeValue"], 0.01, 800001),
        semi_major_m=_conf_back(ell["semiMajorConfidence"], 0.01, 4094, 4095),
        semi_minor_m=_conf_back(ell["semiMinorConfidence"], 0.01, 4094, 4095),
        major_heading_deg=_angle_back(ell["semiMajorOrientation"]),
    )


def _decode_sensor(raw: Mapping[str, Any]) -> SensorEntry:
    shape = raw.get("perceptionRegionShape")
    region: dict[str, float] = {}
    if shape is not None and shape[0] == "radial":
        r = shape[1]
        point = r.get("shapeReferencePoint", {"xCoordinate": 0, "yCoordinate": 0})
        region = {
            "x_m": point["xCoordinate"] * 0.01,
            "y_m": point["yCoordinate"] * 0.01,
            "range_m": r["range"] * 0.1,
            "start_deg": _angle_back(r["horizontalOpeningAngleStart"]),
            "end_deg": _angle_back(r["horizontalOpeningAngleEnd"]),
        }
    return SensorEntry(
        sensor_id=raw["sensorId"],
        sensor_type=raw["sensorType"],
        shadowing_applies=raw["shadowingApplies"],
        confidence_pct=raw.get("perceptionRegionConfidence"),
        **region,
    )


def _decode_class(raw: Sequence[Mapping[str, Any]]) -> tuple[VruClass | None, int]:
    for entry in raw:
        kind, value = entry["objectClass"]
        if kind == "vruSubClass" and value[0] == "pedestrian":
            return "pedestrian", entry["confidence"]
        if kind == "vruSubClass" and value[0] == "bicyclistAndLightVruVehicle":
            return "bicyclist", entry["confidence"]
        if kind == "vehicleSubClass" and value == 0:
            return "unknown", entry["confidence"]
    return None, 101


def _correlation_xy(raw: Sequence[Mapping[str, Any]]) -> float:
    for m in raw:
        bits, n = m["componentsIncludedIntheMatrix"]
        included = [i for i in range(n) if bits[i // 8] >> (7 - i % 8) & 1]
        if included[:2] == [0, 1] and m["matrix"] and m["matrix"][0]:
            cell = m["matrix"][0][0]
            return math.nan if cell == 101 else cell / 100.0
    return math.nan


def _decode_object(raw: Mapping[str, Any]) -> PerceivedObject:
    pos = raw["position"]
    x, y = pos["xCoordinate"], pos["yCoordinate"]
    velocity: dict[str, float] = {}
    if "velocity" in raw and raw["velocity"][0] == "cartesianVelocity":
        v = raw["velocity"][1]
        velocity = {
            "vx_mps": _unscale(v["xVelocity"]["value"], 0.01, 16383),
            "vy_mps": _unscale(v["yVelocity"]["value"], 0.01, 16383),
            "vx_conf_mps": _conf_back(v["xVelocity"]["confidence"], 0.01, 126, 127),
            "vy_conf_mps": _conf_back(v["yVelocity"]["confidence"], 0.01, 126, 127),
        }
    elif "velocity" in raw and raw["velocity"][0] == "polarVelocity":
        # another station's polar velocity, as east/north components (speed 0.01 m/s,
        # direction a mathematical angle); its confidences do not split into x and y
        v = raw["velocity"][1]
        speed = _unscale(v["velocityMagnitude"]["speedValue"], 0.01, 16383)
        direction = math.radians(_angle_back(v["velocityDirection"]["value"]))
        velocity = {"vx_mps": speed * math.cos(direction), "vy_mps": speed * math.sin(direction)}
    kind, confidence = _decode_class(raw.get("classification", ()))
    return PerceivedObject(
        object_id=raw.get("objectId", -1),
        measurement_delta_ms=raw["measurementDeltaTime"],
        x_m=x["value"] * 0.01,
        y_m=y["value"] * 0.01,
        x_conf_m=_conf_back(x["confidence"], 0.01, 4095, 4096),
        y_conf_m=_conf_back(y["confidence"], 0.01, 4095, 4096),
        xy_correlation=_correlation_xy(raw.get("lowerTriangularCorrelationMatrices", ())),
        age_ms=raw.get("objectAge"),
        quality=raw.get("objectPerceptionQuality"),
        sensor_ids=tuple(raw.get("sensorIdList", ())),
        object_class=kind,
        class_confidence_pct=confidence,
        **velocity,
    )


def decode_cpm(data: bytes) -> Cpm:
    """Read a CPM's bytes back into a :class:`Cpm` (at the wire's resolution).

    Containers rfsas-hw does not write (a perception region, a foreign
    container) are kept, decoded, in :attr:`Cpm.extra`.

    Raises:
        CpmFormatError: truncated, corrupted or not a CPM v2, or a segment number beyond
            the total (the message says where).
        MissingDependencyError: ``asn1tools`` is not installed.
    """
    msg, containers = _message(data)
    management = msg["payload"]["managementContainer"]
    vehicle = containers.pop("originatingVehicleContainer", None)
    containers.pop("originatingRsuContainer", None)
    sensors = containers.pop("sensorInformationContainer", [])
    objects = containers.pop("perceivedObjectContainer", None)
    segment = management.get("segmentationInfo")
    if segment is not None and segment["thisMsgNo"] > segment["totalMsgNo"]:
        raise CpmFormatError(
            f"CPM segmentation info: message {segment['thisMsgNo']} of "
            f"{segment['totalMsgNo']} segments"
        )
    heading: dict[str, float] = {}
    if vehicle is not None:
        angle = vehicle["orientationAngle"]
        heading = {
            "heading_deg": _angle_back(angle["value"]),
            "heading_conf_deg": _conf_back(angle["confidence"], 0.1, 126, 127),
        }
    return Cpm(
        station_id=msg["header"]["stationId"],
        reference_time_ms=management["referenceTime"],
        reference=_decode_reference(management["referencePosition"]),
        originating="vehicle" if vehicle is not None else "rsu",
        sensors=tuple(_decode_sensor(s) for s in sensors),
        objects=tuple(_decode_object(o) for o in (objects or {}).get("perceivedObjects", ())),
        perceived_total=None if objects is None else objects["numberOfPerceivedObjects"],
        segment=None if segment is None else (segment["thisMsgNo"], segment["totalMsgNo"]),
        extra={k: _jsonable(v) for k, v in containers.items()},
        **heading,
    )
