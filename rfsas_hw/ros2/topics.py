"""The topics rfsas publishes and records, with their types and ROS 2 QoS.

Every sink (MCAP file, rosbag2 directory, DDS, Foxglove) uses this one table,
so a topic means the same thing wherever it is read.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Topic:
    """One ROS 2 topic: its name, message type and QoS."""

    name: str
    """ROS 2 topic name (absolute, e.g. ``/rfsas/bearings``)."""
    typename: str
    """Message type, ``pkg/msg/Type``."""
    description: str
    """What it carries, for the docs and the recording's metadata."""
    reliable: bool = True
    """RELIABLE (True) or BEST_EFFORT delivery."""
    transient_local: bool = False
    """TRANSIENT_LOCAL durability (late joiners get the last ``depth`` samples)."""
    depth: int = 10
    """KEEP_LAST history depth."""

    @property
    def dds_name(self) -> str:
        """The DDS topic name ROS 2 uses: ``rt`` prefix, no leading double slash."""
        return "rt" + self.name

    @property
    def dds_typename(self) -> str:
        """The DDS type name ROS 2 uses: ``pkg::msg::dds_::Type_``."""
        pkg, kind, name = self.typename.split("/")
        return f"{pkg}::{kind}::dds_::{name}_"


BEARINGS = Topic(
    "/rfsas/bearings",
    "rfsas_msgs/msg/BearingArray",
    "bearings of one sensor batch: azimuth, sigma, SNR, channel, hashed emitter id, sensor pose",
    depth=100,
)
FIXES = Topic(
    "/rfsas/fixes",
    "rfsas_msgs/msg/FixArray",
    "triangulated emitter positions with their 2x2 covariance, per backend step",
)
ASSESSMENTS = Topic(
    "/rfsas/assessments",
    "rfsas_msgs/msg/AssessmentArray",
    "tracks judged against the vehicle: P(collision), impact speed, risk, advisory",
)
LINK = Topic(
    "/rfsas/link",
    "rfsas_msgs/msg/LinkHealth",
    "link counters (verified, rejected by reason) and the latency alarm",
)
TRACKS = Topic(
    "/rfsas/tracks",
    "radar_msgs/msg/RadarTracks",
    "emitter tracks as radar_msgs/RadarTracks (position, velocity, position covariance)",
)
FIX_POSE = Topic(
    "/rfsas/fix_pose",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "one message per trustworthy fix, position with covariance",
)
MARKERS = Topic(
    "/rfsas/markers",
    "visualization_msgs/msg/MarkerArray",
    "sensors, bearing rays, 2-sigma fix ellipses, tracks, advisories and the ego",
    depth=50,
)
EGO = Topic(
    "/rfsas/ego",
    "nav_msgs/msg/Odometry",
    "the vehicle state the backend judged risk against",
)
DIAGNOSTICS = Topic(
    "/diagnostics",
    "diagnostic_msgs/msg/DiagnosticArray",
    "link health as a diagnostic status (OK, or WARN on a latency alarm)",
)
TF = Topic(
    "/tf",
    "tf2_msgs/msg/TFMessage",
    "map -> rfsas/sensor/<id> and map -> rfsas/ego transforms",
    depth=100,
)

ALL: tuple[Topic, ...] = (
    BEARINGS,
    FIXES,
    ASSESSMENTS,
    LINK,
    TRACKS,
    FIX_POSE,
    MARKERS,
    EGO,
    DIAGNOSTICS,
    TF,
)
"""Every topic, in the order the docs list them."""

BY_NAME = {t.name: t for t in ALL}
