"""ROS 2 topics over DDS with Cyclone DDS, without a ROS installation.

A ROS 2 node sees these topics as its own: the DDS topic is ``rt`` + the ROS
name (``rt/rfsas/bearings``), the type is ``pkg::msg::dds_::Type_``, samples
are XCDR1 little-endian (the bytes ``rosbags`` produces for a bag), the QoS is
the topic table's (RELIABLE or BEST_EFFORT, VOLATILE or TRANSIENT_LOCAL,
KEEP_LAST depth), and each writer's USER_DATA carries ``typehash=RIHS01_…;``
as ``rmw_cyclonedds`` does (Iron and later).

The IDL classes are generated from the same message definitions the bags
use (:func:`idl_class`), and the publisher hands Cyclone the decoded sample
of the CDR bytes every other sink receives. :class:`OdometryFeed` subscribes
to a ``nav_msgs/Odometry`` topic and gives the backend its vehicle state.
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass
from functools import cache
from typing import Any

from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import ConfigError
from rfsas_hw.optional import require
from rfsas_hw.ros2 import topics
from rfsas_hw.ros2.topics import Topic
from rfsas_hw.ros2.types import type_hash, typestore

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
ODOMETRY = "nav_msgs/msg/Odometry"


@dataclass(frozen=True, slots=True)
class DdsConfig:
    """Where DDS talks.

    ``interface`` restricts Cyclone DDS to one network interface (a name such
    as ``lo``/``eth0`` or an address); with ``lo`` or ``127.0.0.1`` multicast
    is off and discovery uses unicast to 127.0.0.1, so nothing leaves the host.
    """

    domain_id: int = 0
    """ROS 2 domain id (``ROS_DOMAIN_ID``), 0–232."""
    interface: str | None = None
    """Network interface name or address; None: Cyclone's default choice."""

    def xml(self) -> str | None:
        """The Cyclone DDS configuration for this domain (None: Cyclone's defaults)."""
        if self.interface is None:
            return None
        iface = self.interface
        attr = "address" if iface[0].isdigit() or ":" in iface else "name"
        loopback = iface in ("lo", "127.0.0.1", "::1")
        peers = '<Peers><Peer address="127.0.0.1"/></Peers>' if loopback else ""
        multicast = "false" if loopback else "default"
        return (
            f'<CycloneDDS><Domain id="{self.domain_id}"><General><Interfaces>'
            f'<NetworkInterface {attr}="{iface}"/></Interfaces>'
            f"<AllowMulticast>{multicast}</AllowMulticast></General>"
            f"<Discovery><ParticipantIndex>auto</ParticipantIndex>"
            f"<MaxAutoParticipantIndex>64</MaxAutoParticipantIndex>{peers}</Discovery>"
            "</Domain></CycloneDDS>"
        )


LOOPBACK = DdsConfig(interface="lo")


def _idl_type(node: Any, types: Any) -> Any:
    kind, detail = node
    name = getattr(kind, "name", str(kind))
    if name == "BASE":
        base, bound = detail
        if base == "string":
            return types.bounded_str[bound] if bound else str
        if base == "bool":
            return bool
        return {"byte": types.byte, "char": types.uint8}.get(base) or getattr(types, base)
    if name == "NAME":
        return idl_class(detail)
    if name == "ARRAY":
        inner, size = detail
        return types.array[_idl_type(inner, types), size]
    if name == "SEQUENCE":
        inner, bound = detail
        t = _idl_type(inner, types)
        return types.sequence[t, bound] if bound else types.sequence[t]
    raise ConfigError(f"no IDL mapping for {node!r}")


@cache
def idl_class(typename: str) -> Any:
    """The Cyclone DDS ``IdlStruct`` class of a ROS 2 message type (``pkg/msg/Type``).

    Raises:
        MissingDependencyError: ``cyclonedds`` is not installed.
        ConfigError: the type is unknown.
    """
    idl = require("cyclonedds.idl")
    types = require("cyclonedds.idl.types")
    store = typestore()
    if typename not in store.fielddefs:
        raise ConfigError(f"unknown ROS 2 message type {typename!r}")
    _, fields = store.fielddefs[typename]
    pkg, kind, name = typename.split("/")
    if not fields:
        # ROS 2 gives an empty message one uint8 member so that it has a size
        fields = [("structure_needs_at_least_one_member", (_base_kind(), ("uint8", 0)))]
    members = {fname: _idl_type(node, types) for fname, node in fields}
    return idl.make_idl_struct(f"{pkg}_{name}", f"{pkg}::{kind}::dds_::{name}_", members)


def _base_kind() -> Any:
    return require("rosbags.interfaces").Nodetype.BASE


def qos_of(topic: Topic) -> Any:
    """Cyclone DDS QoS of ``topic`` (with the type hash in USER_DATA)."""
    qos = require("cyclonedds.qos")
    util = require("cyclonedds.util")
    policies = [
        qos.Policy.Reliability.Reliable(max_blocking_time=util.duration(milliseconds=100))
        if topic.reliable
        else qos.Policy.Reliability.BestEffort,
        qos.Policy.Durability.TransientLocal
        if topic.transient_local
        else qos.Policy.Durability.Volatile,
        qos.Policy.History.KeepLast(depth=topic.depth),
        qos.Policy.Userdata(data=f"typehash={type_hash(topic.typename)};".encode()),
    ]
    return qos.Qos(*policies)


_DOMAINS: dict[int, tuple[str | None, Any]] = {}
"""Configured Cyclone domains of this process by id: a domain is configured once."""
_DOMAINS_LOCK = threading.Lock()


def _participant(config: DdsConfig) -> tuple[Any, Any]:
    """A participant on ``config``'s domain (configuring the domain on first use).

    Raises:
        ConfigError: the domain cannot start, or this process already uses the
            domain with another interface.
    """
    domain = require("cyclonedds.domain")
    xml = config.xml()
    try:
        with _DOMAINS_LOCK:
            known = _DOMAINS.get(config.domain_id)
            if known is None:
                dom = domain.Domain(config.domain_id, xml) if xml is not None else None
                _DOMAINS[config.domain_id] = (xml, dom)
            elif known[0] != xml:
                raise ConfigError(
                    f"DDS domain {config.domain_id} is already in use by this process with "
                    "another interface setting"
                )
            dom = _DOMAINS[config.domain_id][1]
        return dom, domain.DomainParticipant(config.domain_id)
    except ConfigError:
        raise
    except Exception as err:  # cyclonedds raises DDSException
        raise ConfigError(f"DDS domain {config.domain_id}: cannot start: {err}") from err


class DdsPublisher:
    """Publishes CDR messages on their ROS 2 topics (one DDS writer per topic).

    Args:
        config: domain and interface.

    Raises:
        MissingDependencyError: ``cyclonedds`` is not installed.
        ConfigError: the domain cannot be created.
    """

    def __init__(self, config: DdsConfig | None = None) -> None:
        self.config = config or DdsConfig()
        self._pub = require("cyclonedds.pub")
        self._topic_mod = require("cyclonedds.topic")
        self._domain, self.participant = _participant(self.config)
        self._writers: dict[str, Any] = {}
        self.messages = 0
        self._closed = False

    def writer(self, topic: Topic) -> Any:
        """The DDS writer of ``topic`` (created on first use)."""
        w = self._writers.get(topic.name)
        if w is None:
            t = self._topic_mod.Topic(
                self.participant, topic.dds_name, idl_class(topic.typename), qos=qos_of(topic)
            )
            w = self._pub.DataWriter(self.participant, t, qos=qos_of(topic))
            self._writers[topic.name] = w
        return w

    def write(self, topic: Topic, log_time_ns: int, data: bytes) -> None:
        """Publish one CDR message (its stamp is in its header; DDS adds its own)."""
        if self._closed:
            return
        sample = idl_class(topic.typename).deserialize(data)
        self.writer(topic).write(sample)
        self.messages += 1

    def wait_for_acks(self, timeout_s: float) -> bool:
        """Wait until every matched reader acknowledged every sample; False on timeout."""
        util = require("cyclonedds.util")
        deadline = util.duration(seconds=timeout_s)
        return all(bool(w.wait_for_acks(deadline)) for w in self._writers.values())

    def matched(self, topic: Topic) -> int:
        """Subscriptions currently matched on ``topic``."""
        return len(self.writer(topic).get_matched_subscriptions())

    def close(self) -> None:
        """Drop the writers and the participant; idempotent."""
        if self._closed:
            return
        self._closed = True
        self._writers.clear()
        self.participant = None
        self._domain = None


def odometry_to_vehicle(odom: Any, *, t_ns: int | None = None) -> VehicleState:
    """A :class:`VehicleState` from a ``nav_msgs/Odometry`` whose pose is in the map frame.

    Heading is the pose's yaw as a compass angle (``90° − yaw``); speed is the
    norm of the body-frame linear twist; the time is the header stamp.

    Raises:
        ConfigError: non-finite position or orientation.
    """
    p = odom.pose.pose.position
    q = odom.pose.pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    v = odom.twist.twist.linear
    stamp = odom.header.stamp
    when = t_ns if t_ns is not None else int(stamp.sec) * NS_PER_S + int(stamp.nanosec)
    try:
        return VehicleState(
            x_m=float(p.x),
            y_m=float(p.y),
            heading_deg=(90.0 - math.degrees(yaw)) % 360.0,
            speed_mps=math.hypot(float(v.x), float(v.y)),
            t_ns=when,
        )
    except ValueError as err:
        raise ConfigError(f"odometry: {err}") from err


class OdometryFeed:
    """The latest vehicle state from a ROS 2 ``nav_msgs/Odometry`` topic.

    Has the ``poll()`` of :class:`~rfsas_hw.backend.vehicle.VehicleFeed`, so the
    backend service takes it as its vehicle feed. Samples with a non-finite
    pose are counted under ``rejected`` and skipped.

    Args:
        topic: ROS 2 topic name (``/odom``).
        config: domain and interface.
    """

    def __init__(self, topic: str, config: DdsConfig | None = None) -> None:
        if not topic.startswith("/"):
            topic = "/" + topic
        self.topic = Topic(topic, ODOMETRY, "vehicle odometry", depth=10)
        self.config = config or DdsConfig()
        sub = require("cyclonedds.sub")
        topic_mod = require("cyclonedds.topic")
        self._domain, self.participant = _participant(self.config)
        t = topic_mod.Topic(
            self.participant, self.topic.dds_name, idl_class(ODOMETRY), qos=qos_of(self.topic)
        )
        self._reader: Any = sub.DataReader(self.participant, t, qos=qos_of(self.topic))
        self.latest: VehicleState | None = None
        self.received = 0
        self.rejected = 0
        self._lock = threading.Lock()

    def poll(self, timeout: float | None = 0.0) -> VehicleState | None:
        """Take every queued sample and return the newest vehicle state (or the last one)."""
        del timeout  # samples are queued by DDS; taking them never waits
        with self._lock:
            for sample in self._reader.take(N=64):
                if is_state_change(sample):
                    continue
                try:
                    self.latest = odometry_to_vehicle(sample)
                    self.received += 1
                except ConfigError as err:
                    self.rejected += 1
                    if self.rejected == 1:
                        log.warning("%s", err)
            return self.latest

    def close(self) -> None:
        """Drop the reader and participant; idempotent."""
        self._reader = _Closed()
        self.participant = None
        self._domain = None


def is_state_change(sample: Any) -> bool:
    """True for a reader's instance-state notice (a writer left or disposed), not data.

    Cyclone DDS hands these out of ``take()`` as ``InvalidSample`` objects
    beside the real samples, for example when a publisher closes.
    """
    return type(sample).__name__ == "InvalidSample"


class _Closed:
    def take(self, N: int = 1) -> list[Any]:
        return []


__all__ = [
    "LOOPBACK",
    "DdsConfig",
    "DdsPublisher",
    "OdometryFeed",
    "idl_class",
    "odometry_to_vehicle",
    "qos_of",
    "topics",
]
