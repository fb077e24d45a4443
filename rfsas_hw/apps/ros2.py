"""ROS 2 outputs of the applications: a bag, a Foxglove live view, DDS publishing.

:func:`attach_scene` hangs one scene sink on a backend service for every
output a :class:`Ros2Options` asks for; :func:`sensor_scene` gives a sensor a
bearing listener publishing to the live outputs. The modules behind them
(``rfsas_hw.ros2.*``) are imported only when an output is asked for, so that
the applications run without the ``ros2`` extra.
"""

from __future__ import annotations

import ipaddress
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rfsas_hw.errors import ConfigError


@dataclass(frozen=True, slots=True)
class Ros2Options:
    """Which ROS 2 outputs to start (the default: none)."""

    foxglove_port: int | None = None
    """Serve the live scene to the Foxglove app on this TCP port (None: no server)."""
    foxglove_host: str = "127.0.0.1"
    """Address the Foxglove server binds (it has no authentication)."""
    publish: bool = False
    """Publish the scene on ROS 2 topics over DDS."""
    domain_id: int = 0
    """ROS 2 domain id for DDS."""
    interface: str | None = None
    """Network interface (name or address) DDS uses (None: Cyclone DDS's choice)."""
    rosbag2_dir: Path | None = None
    """Record the backend's scene into this new rosbag2 directory (None: no bag)."""
    odom_topic: str | None = None
    """Take the backend's vehicle state from this nav_msgs/Odometry topic (None: not)."""

    @property
    def wants_live(self) -> bool:
        """Whether a live output (Foxglove or DDS) is asked for."""
        return self.foxglove_port is not None or self.publish


def live_writers(opts: Ros2Options, writers: list[Any], lines: list[str]) -> None:
    """Append the Foxglove server and the DDS publisher ``opts`` asks for to ``writers``,
    and what to tell the user to ``lines``.

    Raises:
        ConfigError / MissingDependencyError: a server cannot start.
    """
    if opts.foxglove_port is not None:
        from rfsas_hw.ros2.foxglove_live import LAYOUT_FILE, FoxgloveServer

        host = opts.foxglove_host
        server = FoxgloveServer(host, opts.foxglove_port)
        writers.append(server)
        lines.append(f"foxglove: open {server.url} in the Foxglove app")
        if not _loopback(host):
            lines.append(
                f"foxglove: WARNING: the server has no authentication and listens on {host}: "
                "anyone who reaches this host sees the live scene"
            )
        lines.append(f"foxglove: layout {LAYOUT_FILE}")
    if opts.publish:
        from rfsas_hw.ros2.dds import DdsConfig, DdsPublisher

        dds = DdsConfig(domain_id=opts.domain_id, interface=_interface(opts.interface))
        writers.append(DdsPublisher(dds))
        lines.append(f"ros2: publishing on domain {dds.domain_id}")


def _interface(name: str | None) -> str | None:
    """The DDS network interface ``name``: an interface of this host by name, or an address.

    Raises:
        ConfigError: no interface of this host has that name, and it is no IP address.
    """
    if name is None:
        return None
    try:
        ipaddress.ip_address(name)
        return name
    except ValueError:
        pass
    names = [n for _, n in socket.if_nameindex()]
    if name not in names:
        raise ConfigError(
            f"--ros2-interface {name!r}: no such network interface here "
            f"(there are: {', '.join(names)}); give a name or an address"
        )
    return name


def _loopback(host: str) -> bool:
    """Whether ``host`` names this host only (localhost, 127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def sensor_scene(opts: Ros2Options, pose_of: Callable[[str], Any]) -> tuple[Any, list[str]]:
    """A bearing listener publishing to the live outputs ``opts`` asks for, or None,
    and what to tell the user.

    Raises:
        ConfigError / MissingDependencyError: a server cannot start.
    """
    if not opts.wants_live:
        return None, []
    writers: list[Any] = []
    lines: list[str] = []
    try:
        live_writers(opts, writers, lines)
    except Exception:
        for w in writers:
            w.close()
        raise
    from rfsas_hw.ros2.sink import SceneSink, SensorScene

    return SensorScene(SceneSink(writers), pose_of), lines


@dataclass
class Ros2Outputs:
    """What :func:`attach_scene` started; close it when the service is closed."""

    lines: list[str] = field(default_factory=list)
    """What to tell the user (URLs, topics)."""
    vehicle_feed: Any = None
    """An odometry subscription with ``poll()``, or None."""
    closers: list[Callable[[], None]] = field(default_factory=list)

    def close(self) -> None:
        """Stop the subscription (the scene's writers close with the service's sinks)."""
        for close in self.closers:
            close()
        self.closers.clear()


def attach_scene(service: Any, out: Path | None, opts: Ros2Options) -> Ros2Outputs:
    """Add a scene sink to ``service`` for every ROS 2 output ``opts`` asks for (and an
    MCAP recording when ``out`` ends in ``.mcap``).

    Raises:
        ConfigError / MissingDependencyError: an output cannot be started.
    """
    result = Ros2Outputs()
    writers: list[Any] = []
    try:
        if out is not None and out.suffix.lower() == ".mcap":
            from rfsas_hw.ros2.bag import McapFileWriter

            writers.append(McapFileWriter(out))
        if opts.rosbag2_dir is not None:
            from rfsas_hw.ros2.bag import Rosbag2Writer

            writers.append(Rosbag2Writer(opts.rosbag2_dir))
        live_writers(opts, writers, result.lines)
        if opts.odom_topic:
            from rfsas_hw.ros2.dds import DdsConfig, OdometryFeed

            dds = DdsConfig(domain_id=opts.domain_id, interface=_interface(opts.interface))
            feed = OdometryFeed(opts.odom_topic, dds)
            result.vehicle_feed = feed
            result.closers.append(feed.close)
            result.lines.append(f"ros2: vehicle state from {opts.odom_topic}")
    except Exception:
        for w in writers:
            w.close()
        result.close()
        raise
    if writers:
        from rfsas_hw.ros2.sink import BackendScene, SceneSink

        service.sinks.append(BackendScene.for_service(SceneSink(writers), service))
    return result
