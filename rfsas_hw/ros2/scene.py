"""rfsas records as ROS 2 messages: the custom ``rfsas_msgs`` and the standard types.

:class:`SceneBuilder` turns what a sensor or the backend produced (bearing
batches with the sensor pose, fixes, assessments, the vehicle state, link
counters) into :class:`Out` items: a topic, a stamp and a message object of
the ``rosbags`` typestore, ready to serialise to CDR.

Frames follow REP-103 and REP-105: ``map`` is the local east-north-up frame
of the site (x east, y north, z up, metres; origin the site origin of every
rfsas pose); each sensor has a frame ``rfsas/sensor/<id>`` whose x axis is
the array boresight; the vehicle is ``rfsas/ego``. Yaws are radians counter-
clockwise from east, converted from the compass degrees rfsas uses elsewhere
by ``yaw = 90° − azimuth``.
"""

from __future__ import annotations

import itertools
import math
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from rfsas_hw.angles import compass_to_math_rad
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose, emitter_hex
from rfsas_hw.ros2 import topics
from rfsas_hw.ros2.topics import Topic
from rfsas_hw.ros2.types import msg_class

NS_PER_S = 1_000_000_000
BEARING_ARRAY_SPAN_NS = 100_000_000
"""A ``BearingArray`` holds one sensor's bearings within this span of its first, ns
(a live batch, a replayed capture and an export are cut the same way)."""
ADVISORY_CODE = {"none": 0, "clear": 1, "caution": 2, "brake": 3}
"""``Assessment.advisory`` text → the ``rfsas_msgs/Assessment`` ADVISORY_* constant."""
ADVISORY_RGBA = {
    "none": (0.6, 0.6, 0.6, 0.8),
    "clear": (0.1, 0.8, 0.2, 0.9),
    "caution": (1.0, 0.8, 0.0, 0.9),
    "brake": (1.0, 0.1, 0.1, 1.0),
}
UNKNOWN_VARIANCE = 1.0e6
"""Variance put where rfsas estimates nothing (z, roll, pitch, yaw of a fix), m² or rad²."""


@dataclass(frozen=True, slots=True)
class SceneConfig:
    """Frame names and how the scene is drawn."""

    map_frame: str = "map"
    """The site's ENU frame."""
    frame_prefix: str = "rfsas/"
    """Prefix of the sensor (``<prefix>sensor/<id>``) and vehicle (``<prefix>ego``) frames."""
    ray_length_m: float = 60.0
    """Length of a drawn bearing ray, metres."""
    ray_lifetime_s: float = 0.5
    """How long a drawn ray stays, seconds."""
    marker_lifetime_s: float = 1.0
    """How long a track, ellipse or advisory marker stays unless redrawn, seconds."""
    ellipse_sigma: float = 2.0
    """Fix and track ellipses are drawn at this many sigma."""

    def sensor_frame(self, sensor_id: str) -> str:
        """The frame id of sensor ``sensor_id``."""
        return f"{self.frame_prefix}sensor/{sensor_id}"

    @property
    def ego_frame(self) -> str:
        """The frame id of the vehicle."""
        return f"{self.frame_prefix}ego"


@dataclass(frozen=True, slots=True)
class Out:
    """One message to publish or record."""

    topic: Topic
    stamp_ns: int
    """Header stamp (and log time in a recording), UTC nanoseconds."""
    message: Any
    """A message object of :func:`rfsas_hw.ros2.types.typestore`."""


# -- small builders ------------------------------------------------------------------


def stamp(t_ns: int) -> Any:
    """``builtin_interfaces/Time`` of UTC nanoseconds."""
    sec, nanosec = divmod(int(t_ns), NS_PER_S)
    return msg_class("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def header(t_ns: int, frame_id: str) -> Any:
    """``std_msgs/Header``."""
    return msg_class("std_msgs/msg/Header")(stamp=stamp(t_ns), frame_id=frame_id)


def point(x: float, y: float, z: float = 0.0) -> Any:
    """``geometry_msgs/Point``."""
    return msg_class("geometry_msgs/msg/Point")(x=float(x), y=float(y), z=float(z))


def vector3(x: float, y: float, z: float = 0.0) -> Any:
    """``geometry_msgs/Vector3``."""
    return msg_class("geometry_msgs/msg/Vector3")(x=float(x), y=float(y), z=float(z))


def yaw_quaternion(yaw_rad: float) -> Any:
    """``geometry_msgs/Quaternion`` of a rotation by ``yaw_rad`` about z."""
    half = 0.5 * float(yaw_rad)
    return msg_class("geometry_msgs/msg/Quaternion")(
        x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)
    )


def compass_yaw(heading_deg: float) -> float:
    """Compass degrees (clockwise from north) → ENU yaw, radians in [-π, π]."""
    # scalar math: this runs for every marker and transform (compass_to_math_rad is numpy)
    return math.remainder(math.radians(90.0 - float(heading_deg)), 2.0 * math.pi)


def pose_msg(x_m: float, y_m: float, heading_deg: float) -> Any:
    """``geometry_msgs/Pose`` in the map frame of an rfsas position and compass heading."""
    return msg_class("geometry_msgs/msg/Pose")(
        position=point(x_m, y_m), orientation=yaw_quaternion(compass_yaw(heading_deg))
    )


def _cov4(xx: float, xy: float, yy: float) -> Any:
    return np.array([xx, xy, xy, yy], np.float64)


def _duration(seconds: float) -> Any:
    sec, nanosec = divmod(round(seconds * NS_PER_S), NS_PER_S)
    return msg_class("builtin_interfaces/msg/Duration")(sec=int(sec), nanosec=int(nanosec))


def _rgba(r: float, g: float, b: float, a: float) -> Any:
    return msg_class("std_msgs/msg/ColorRGBA")(r=r, g=g, b=b, a=a)


@cache
def _no_texture() -> Any:
    """The empty texture every marker carries (shared: serialising never changes it)."""
    return msg_class("sensor_msgs/msg/CompressedImage")(
        header=header(0, ""), format="", data=np.empty(0, np.uint8)
    )


@cache
def _no_mesh() -> Any:
    """The empty mesh every marker carries (shared)."""
    return msg_class("visualization_msgs/msg/MeshFile")(filename="", data=np.empty(0, np.uint8))


def marker_id(emitter: str) -> int:
    """A stable non-negative int32 marker id for an emitter id (its first 31 bits)."""
    return int(emitter[:8], 16) & 0x7FFF_FFFF


def sensor_marker_id(sensor_id: str) -> int:
    """A stable non-negative int32 marker id for a sensor id (CRC-32 of its text)."""
    return zlib.crc32(sensor_id.encode()) & 0x7FFF_FFFF


@cache
def _unit_circle(n: int) -> tuple[tuple[float, float], ...]:
    return tuple(
        (math.cos(2 * math.pi * k / n), math.sin(2 * math.pi * k / n)) for k in range(n + 1)
    )


def ellipse_points(
    x_m: float, y_m: float, cov: np.ndarray[Any, Any], n_sigma: float, n: int = 24
) -> list[tuple[float, float]]:
    """Closed outline of the ``n_sigma`` ellipse of 2×2 ``cov`` around (x, y), metres."""
    # closed-form eigen decomposition of a symmetric 2×2: this runs for every fix each step
    a, b, c = float(cov[0, 0]), 0.5 * float(cov[0, 1] + cov[1, 0]), float(cov[1, 1])
    mid, half = 0.5 * (a + c), math.hypot(0.5 * (a - c), b)
    r1 = n_sigma * math.sqrt(max(mid + half, 0.0))
    r2 = n_sigma * math.sqrt(max(mid - half, 0.0))
    theta = 0.5 * math.atan2(2.0 * b, a - c)
    ct, st = math.cos(theta), math.sin(theta)
    return [
        (x_m + ct * r1 * u - st * r2 * v, y_m + st * r1 * u + ct * r2 * v)
        for u, v in _unit_circle(n)
    ]


class SceneBuilder:
    """Builds the messages of every topic in :mod:`rfsas_hw.ros2.topics` from rfsas records.

    Stateless apart from its configuration: the same records give the same
    messages, so a live run and an export of its JSONL agree.
    """

    def __init__(self, config: SceneConfig | None = None) -> None:
        self.config = config or SceneConfig()

    # -- pieces ----------------------------------------------------------------------

    def _marker(
        self,
        t_ns: int,
        ns: str,
        ident: int,
        kind: str,
        *,
        pose: Any = None,
        scale: tuple[float, float, float] = (1.0, 1.0, 1.0),
        rgba: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0),
        lifetime_s: float = 0.0,
        points: Iterable[tuple[float, float]] = (),
        text: str = "",
    ) -> Any:
        m = msg_class("visualization_msgs/msg/Marker")
        cls_point = msg_class("geometry_msgs/msg/Point")
        return m(
            header=header(t_ns, self.config.map_frame),
            ns=ns,
            id=int(ident),
            type=int(getattr(m, kind)),
            action=int(m.ADD),
            pose=pose if pose is not None else pose_msg(0.0, 0.0, 90.0),
            scale=vector3(*scale),
            color=_rgba(*rgba),
            lifetime=_duration(lifetime_s),
            frame_locked=False,
            points=[cls_point(x=float(px), y=float(py), z=0.0) for px, py in points],
            colors=[],
            texture_resource="",
            texture=_no_texture(),
            uv_coordinates=[],
            text=text,
            mesh_resource="",
            mesh_file=_no_mesh(),
            mesh_use_embedded_materials=False,
        )

    def _transform(self, t_ns: int, child: str, x: float, y: float, heading_deg: float) -> Any:
        tf = msg_class("geometry_msgs/msg/Transform")(
            translation=vector3(x, y), rotation=yaw_quaternion(compass_yaw(heading_deg))
        )
        return msg_class("geometry_msgs/msg/TransformStamped")(
            header=header(t_ns, self.config.map_frame), child_frame_id=child, transform=tf
        )

    def _tf(self, t_ns: int, transforms: list[Any]) -> Out:
        return Out(topics.TF, t_ns, msg_class("tf2_msgs/msg/TFMessage")(transforms=transforms))

    def sensors(self, t_ns: int, stations: Mapping[str, Pose]) -> list[Out]:
        """TF of every sensor and a marker per sensor (an arrow along its boresight)."""
        if not stations:
            return []
        ids = sorted(stations)
        tfs = [
            self._transform(
                t_ns,
                self.config.sensor_frame(s),
                stations[s].x_m,
                stations[s].y_m,
                stations[s].heading_deg,
            )
            for s in ids
        ]
        markers = [
            self._marker(
                t_ns,
                "sensors",
                sensor_marker_id(s),
                "ARROW",
                pose=pose_msg(stations[s].x_m, stations[s].y_m, stations[s].heading_deg),
                scale=(3.0, 0.6, 0.6),
                rgba=(0.2, 0.5, 1.0, 1.0),
                lifetime_s=self.config.marker_lifetime_s,
            )
            for s in ids
        ] + [
            self._marker(
                t_ns,
                "sensor_labels",
                sensor_marker_id(s),
                "TEXT_VIEW_FACING",
                pose=pose_msg(stations[s].x_m, stations[s].y_m + 2.0, 90.0),
                scale=(1.0, 1.0, 1.5),
                rgba=(0.2, 0.5, 1.0, 1.0),
                lifetime_s=self.config.marker_lifetime_s,
                text=s,
            )
            for s in ids
        ]
        return [
            self._tf(t_ns, tfs),
            Out(
                topics.MARKERS,
                t_ns,
                msg_class("visualization_msgs/msg/MarkerArray")(markers=markers),
            ),
        ]

    # -- records ---------------------------------------------------------------------

    @staticmethod
    def spans(batch: BearingBatch) -> list[BearingBatch]:
        """``batch`` cut into consecutive runs of rows, each within
        :data:`BEARING_ARRAY_SPAN_NS` of its first row: one message each, stamped
        with its own time (a replayed capture arrives as one large batch)."""
        times = batch.t_ns.tolist()
        if not times or max(times) - min(times) <= BEARING_ARRAY_SPAN_NS:
            return [batch] if times else []
        cuts = [0]
        first = times[0]
        for i, t in enumerate(times):
            if abs(t - first) > BEARING_ARRAY_SPAN_NS:
                cuts.append(i)
                first = t
        cuts.append(len(times))
        return [batch.select(slice(a, b)) for a, b in itertools.pairwise(cuts)]

    def bearings(self, batch: BearingBatch, pose: Pose | None) -> list[Out]:
        """A ``BearingArray``, the sensor's TF and its bearing rays (when its pose is known).

        Bearings of a sensor whose pose is unknown are still recorded; their
        ``sensor_pose`` is NaN and no ray or transform is drawn.
        """
        if len(batch) == 0:
            return []
        cfg = self.config
        t_last = int(batch.t_ns.max())
        frame = cfg.sensor_frame(batch.sensor_id)
        nan = math.nan
        spose = pose_msg(nan, nan, 0.0) if pose is None else pose_msg(*_pose3(pose))
        yaws = compass_to_math_rad(batch.azimuth_deg)
        bearing = msg_class("rfsas_msgs/msg/Bearing")
        items = [
            bearing(
                header=header(t, frame),
                sensor_id=batch.sensor_id,
                sensor_pose=spose,
                azimuth_deg=az,
                yaw_rad=yaw,
                sigma_deg=sig,
                relative_deg=rel,
                snr_db=snr,
                channel=ch,
                emitter_id=emitter_hex(e),
            )
            for t, az, yaw, sig, rel, snr, ch, e in zip(
                batch.t_ns.tolist(),
                batch.azimuth_deg.tolist(),
                np.asarray(yaws).tolist(),
                batch.sigma_deg.tolist(),
                batch.relative_deg.tolist(),
                batch.snr_db.tolist(),
                batch.channel.tolist(),
                batch.emitter.tolist(),
                strict=True,
            )
        ]
        out = [
            Out(
                topics.BEARINGS,
                t_last,
                msg_class("rfsas_msgs/msg/BearingArray")(
                    header=header(t_last, cfg.map_frame), bearings=items
                ),
            )
        ]
        if pose is None:
            return out
        out.extend(self.sensors(t_last, {batch.sensor_id: pose}))
        ends: list[tuple[float, float]] = []
        for yaw in np.asarray(yaws).tolist():
            ends.append((pose.x_m, pose.y_m))
            ends.append(
                (
                    pose.x_m + cfg.ray_length_m * math.cos(yaw),
                    pose.y_m + cfg.ray_length_m * math.sin(yaw),
                )
            )
        ray = self._marker(
            t_last,
            f"bearings/{batch.sensor_id}",
            0,
            "LINE_LIST",
            scale=(0.15, 0.0, 0.0),
            rgba=(0.3, 0.7, 1.0, 0.6),
            lifetime_s=cfg.ray_lifetime_s,
            points=ends,
        )
        out.append(
            Out(
                topics.MARKERS,
                t_last,
                msg_class("visualization_msgs/msg/MarkerArray")(markers=[ray]),
            )
        )
        return out

    def fix_message(self, fix: Fix) -> Any:
        """One ``rfsas_msgs/Fix``."""
        return msg_class("rfsas_msgs/msg/Fix")(
            header=header(fix.t_ns, self.config.map_frame),
            emitter_id=fix.emitter,
            position=point(fix.x_m, fix.y_m),
            covariance=_cov4(fix.cov_xx_m2, fix.cov_xy_m2, fix.cov_yy_m2),
            ok=bool(fix.ok),
            status=fix.status,
            reason=fix.reason,
            sensor_ids=list(fix.sensors),
            gdop=float(fix.gdop),
            condition=float(fix.condition),
        )

    def assessment_message(self, a: Assessment) -> Any:
        """One ``rfsas_msgs/Assessment`` (with its ``Track``)."""
        track = msg_class("rfsas_msgs/msg/Track")(
            header=header(a.t_ns, self.config.map_frame),
            emitter_id=a.emitter,
            position=point(a.x_m, a.y_m),
            velocity=vector3(a.vx_mps, a.vy_mps),
            position_covariance=_cov4(a.cov_xx_m2, a.cov_xy_m2, a.cov_yy_m2),
            age_s=float(a.age_s),
            sensor_ids=list(a.sensors),
        )
        return msg_class("rfsas_msgs/msg/Assessment")(
            track=track,
            fix_ok=bool(a.fix_ok),
            fix_reason=a.fix_reason,
            p_collision=float(a.p_collision),
            t_closest_s=float(a.t_closest_s),
            distance_to_contact_m=float(a.distance_to_contact_m),
            impact_speed_mps=float(a.impact_speed_mps),
            fatality_risk=float(a.fatality_risk),
            risk=float(a.risk),
            advisory=ADVISORY_CODE.get(a.advisory, 0),
            reasons=list(a.reasons),
            link_alarm=bool(a.link_alarm),
        )

    def results(
        self, t_ns: int, fixes: Sequence[Fix], assessments: Sequence[Assessment]
    ) -> list[Out]:
        """One backend step at ``t_ns``: fixes, assessments, radar tracks, fix poses, markers.

        The ``FixArray`` is sent only when the step made fixes; the
        ``AssessmentArray`` and ``RadarTracks`` every step (empty when nothing
        is tracked, so a viewer clears).
        """
        cfg = self.config
        out: list[Out] = []
        if fixes:
            out.append(
                Out(
                    topics.FIXES,
                    t_ns,
                    msg_class("rfsas_msgs/msg/FixArray")(
                        header=header(t_ns, cfg.map_frame),
                        fixes=[self.fix_message(f) for f in fixes],
                    ),
                )
            )
        out.append(
            Out(
                topics.ASSESSMENTS,
                t_ns,
                msg_class("rfsas_msgs/msg/AssessmentArray")(
                    header=header(t_ns, cfg.map_frame),
                    assessments=[self.assessment_message(a) for a in assessments],
                ),
            )
        )
        out.append(self._radar_tracks(t_ns, assessments))
        for fix in fixes:
            if fix.ok:
                out.append(self._fix_pose(fix))
        markers = self._result_markers(t_ns, fixes, assessments)
        if markers:
            out.append(
                Out(
                    topics.MARKERS,
                    t_ns,
                    msg_class("visualization_msgs/msg/MarkerArray")(markers=markers),
                )
            )
        return out

    def _radar_tracks(self, t_ns: int, assessments: Sequence[Assessment]) -> Out:
        track = msg_class("radar_msgs/msg/RadarTrack")
        uuid = msg_class("unique_identifier_msgs/msg/UUID")
        nan6 = np.full(6, np.nan, np.float32)
        items = []
        for a in assessments:
            if not (math.isfinite(a.x_m) and math.isfinite(a.y_m)):
                continue
            moving = math.isfinite(a.vx_mps) and math.hypot(a.vx_mps, a.vy_mps) > 0.2
            items.append(
                track(
                    uuid=uuid(uuid=np.frombuffer(bytes.fromhex(a.emitter) + bytes(8), np.uint8)),
                    position=point(a.x_m, a.y_m),
                    velocity=vector3(a.vx_mps, a.vy_mps),
                    acceleration=vector3(0.0, 0.0),
                    size=vector3(0.6, 0.6, 1.8),
                    classification=int(track.DYNAMIC if moving else track.NO_CLASSIFICATION),
                    position_covariance=np.array(
                        [a.cov_xx_m2, a.cov_xy_m2, 0.0, a.cov_yy_m2, 0.0, UNKNOWN_VARIANCE],
                        np.float32,
                    ),
                    velocity_covariance=nan6.copy(),
                    acceleration_covariance=nan6.copy(),
                    size_covariance=nan6.copy(),
                )
            )
        return Out(
            topics.TRACKS,
            t_ns,
            msg_class("radar_msgs/msg/RadarTracks")(
                header=header(t_ns, self.config.map_frame), tracks=items
            ),
        )

    def _fix_pose(self, fix: Fix) -> Out:
        cov = np.zeros(36, np.float64)
        cov[0], cov[1], cov[6], cov[7] = fix.cov_xx_m2, fix.cov_xy_m2, fix.cov_xy_m2, fix.cov_yy_m2
        for i in (14, 21, 28, 35):
            cov[i] = UNKNOWN_VARIANCE
        pwc = msg_class("geometry_msgs/msg/PoseWithCovariance")(
            pose=pose_msg(fix.x_m, fix.y_m, 90.0), covariance=cov
        )
        return Out(
            topics.FIX_POSE,
            fix.t_ns,
            msg_class("geometry_msgs/msg/PoseWithCovarianceStamped")(
                header=header(fix.t_ns, self.config.map_frame), pose=pwc
            ),
        )

    def _result_markers(
        self, t_ns: int, fixes: Sequence[Fix], assessments: Sequence[Assessment]
    ) -> list[Any]:
        cfg = self.config
        life = cfg.marker_lifetime_s
        markers = []
        for fix in fixes:
            cov = np.array([[fix.cov_xx_m2, fix.cov_xy_m2], [fix.cov_xy_m2, fix.cov_yy_m2]])
            if not (fix.ok and np.isfinite(cov).all() and math.isfinite(fix.x_m)):
                continue
            markers.append(
                self._marker(
                    t_ns,
                    "fix_ellipses",
                    marker_id(fix.emitter),
                    "LINE_STRIP",
                    scale=(0.2, 0.0, 0.0),
                    rgba=(1.0, 0.5, 0.0, 1.0),
                    lifetime_s=life,
                    points=ellipse_points(fix.x_m, fix.y_m, cov, cfg.ellipse_sigma),
                )
            )
        for a in assessments:
            if not (math.isfinite(a.x_m) and math.isfinite(a.y_m)):
                continue
            ident = marker_id(a.emitter)
            rgba = ADVISORY_RGBA.get(a.advisory, ADVISORY_RGBA["none"])
            markers.append(
                self._marker(
                    t_ns,
                    "tracks",
                    ident,
                    "SPHERE",
                    pose=pose_msg(a.x_m, a.y_m, 90.0),
                    scale=(1.0, 1.0, 1.0),
                    rgba=rgba,
                    lifetime_s=life,
                )
            )
            if math.isfinite(a.vx_mps) and math.isfinite(a.vy_mps):
                markers.append(
                    self._marker(
                        t_ns,
                        "track_velocity",
                        ident,
                        "ARROW",
                        scale=(0.2, 0.4, 0.4),
                        rgba=rgba,
                        lifetime_s=life,
                        points=[(a.x_m, a.y_m), (a.x_m + a.vx_mps, a.y_m + a.vy_mps)],
                    )
                )
            label = a.advisory.upper()
            if math.isfinite(a.p_collision):
                label += f" P={a.p_collision:.2f}"
            markers.append(
                self._marker(
                    t_ns,
                    "advisories",
                    ident,
                    "TEXT_VIEW_FACING",
                    pose=pose_msg(a.x_m, a.y_m + 2.0, 90.0),
                    scale=(1.0, 1.0, 1.2),
                    rgba=rgba,
                    lifetime_s=life,
                    text=f"{a.emitter[:6]} {label}",
                )
            )
        return markers

    def vehicle(self, t_ns: int, state: VehicleState) -> list[Out]:
        """The vehicle as TF ``map → rfsas/ego``, ``nav_msgs/Odometry`` and a box marker."""
        cfg = self.config
        cov = np.zeros(36, np.float64)
        c = state.covariance
        cov[0], cov[1], cov[6], cov[7] = c[0, 0], c[0, 1], c[1, 0], c[1, 1]
        for i in (14, 21, 28, 35):
            cov[i] = UNKNOWN_VARIANCE
        odom = msg_class("nav_msgs/msg/Odometry")(
            header=header(t_ns, cfg.map_frame),
            child_frame_id=cfg.ego_frame,
            pose=msg_class("geometry_msgs/msg/PoseWithCovariance")(
                pose=pose_msg(state.x_m, state.y_m, state.heading_deg), covariance=cov
            ),
            twist=msg_class("geometry_msgs/msg/TwistWithCovariance")(
                twist=msg_class("geometry_msgs/msg/Twist")(
                    linear=vector3(state.speed_mps, 0.0), angular=vector3(0.0, 0.0)
                ),
                covariance=np.zeros(36, np.float64),
            ),
        )
        box = self._marker(
            t_ns,
            "ego",
            0,
            "CUBE",
            pose=pose_msg(state.x_m, state.y_m, state.heading_deg),
            scale=(state.length_m, state.width_m, 1.5),
            rgba=(0.9, 0.9, 0.9, 0.9),
            lifetime_s=cfg.marker_lifetime_s,
        )
        return [
            self._tf(
                t_ns,
                [self._transform(t_ns, cfg.ego_frame, state.x_m, state.y_m, state.heading_deg)],
            ),
            Out(topics.EGO, t_ns, odom),
            Out(
                topics.MARKERS, t_ns, msg_class("visualization_msgs/msg/MarkerArray")(markers=[box])
            ),
        ]

    def link(self, t_ns: int, alarm: bool, counters: Mapping[str, int]) -> list[Out]:
        """``rfsas_msgs/LinkHealth`` and a ``diagnostic_msgs/DiagnosticArray`` of the link."""
        kv = msg_class("diagnostic_msgs/msg/KeyValue")
        pairs = [kv(key=k, value=str(int(v))) for k, v in sorted(counters.items())]
        rejected = sum(int(v) for k, v in counters.items() if k.startswith("rejected"))
        health = msg_class("rfsas_msgs/msg/LinkHealth")(
            header=header(t_ns, self.config.map_frame),
            latency_alarm=bool(alarm),
            verified=int(counters.get("verified", 0)),
            rejected=rejected,
            counters=pairs,
        )
        status = msg_class("diagnostic_msgs/msg/DiagnosticStatus")
        diag = status(
            level=status.WARN if alarm else status.OK,
            name="rfsas: link",
            message="latency alarm: a sender is late or silent" if alarm else "ok",
            hardware_id="rfsas-backend",
            values=pairs,
        )
        array = msg_class("diagnostic_msgs/msg/DiagnosticArray")(
            header=header(t_ns, self.config.map_frame), status=[diag]
        )
        return [Out(topics.LINK, t_ns, health), Out(topics.DIAGNOSTICS, t_ns, array)]


def _pose3(pose: Pose) -> tuple[float, float, float]:
    return (pose.x_m, pose.y_m, pose.heading_deg)
