"""ROS 2 options of the commands: a bag, a Foxglove live view, DDS publishing.

:func:`live_options` (``--foxglove``, ``--ros2``) serves the sensor commands
and the backend; :func:`ros2_options` adds the backend's ``--rosbag2`` and
``--odom``. :func:`attach_scene` hangs one scene sink on the backend service;
:func:`sensor_scene` gives the sensor commands a bearing listener.
"""

from __future__ import annotations

import ipaddress
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import click

from rfsas_hw.cli.outopts import OutputPath
from rfsas_hw.errors import ConfigError

F = TypeVar("F", bound=Callable[..., Any])


def live_options(func: F) -> F:
    """Add ``--foxglove [PORT]``, ``--foxglove-host``, ``--ros2``, ``--ros2-domain`` and
    ``--ros2-interface`` (the sensor commands and the backend)."""
    options = [
        click.option(
            "--foxglove",
            "foxglove_port",
            type=click.IntRange(0, 65535),
            is_flag=False,
            flag_value=8765,
            default=None,
            metavar="[PORT]",
            help="Serve the live scene to the Foxglove app over WebSocket [port 8765].",
        ),
        click.option(
            "--foxglove-host",
            default="127.0.0.1",
            show_default=True,
            help="Address the Foxglove server binds (it has no authentication).",
        ),
        click.option(
            "--ros2",
            "ros2_publish",
            is_flag=True,
            help="Publish the scene on ROS 2 topics over DDS (Cyclone DDS; no ROS install needed).",
        ),
        click.option(
            "--ros2-domain",
            type=click.IntRange(0, 232),
            envvar="ROS_DOMAIN_ID",
            default=0,
            show_default=True,
            help="ROS 2 domain id (ROS_DOMAIN_ID).",
        ),
        click.option(
            "--ros2-interface",
            metavar="NAME|ADDRESS",
            help="Network interface DDS uses (default: Cyclone's choice; lo for this host only).",
        ),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def ros2_options(func: F) -> F:
    """Add :func:`live_options` and the backend's ``--rosbag2`` and ``--odom``."""
    options = [
        click.option(
            "--rosbag2",
            "rosbag2_dir",
            type=OutputPath("new_dir"),
            help="Record the scene into this new rosbag2 directory (sqlite3 storage). "
            "An --out name ending in .mcap records an MCAP file instead of JSON lines.",
        ),
        live_options,
        click.option(
            "--odom",
            "odom_topic",
            metavar="TOPIC",
            help="Take the vehicle state from this nav_msgs/Odometry topic (map frame, ENU).",
        ),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def wants_live(opts: dict[str, Any]) -> bool:
    """Whether the options ask for a live ROS 2 output (Foxglove or DDS)."""
    return opts.get("foxglove_port") is not None or bool(opts.get("ros2_publish"))


def live_writers(opts: dict[str, Any], writers: list[Any], lines: list[str]) -> None:
    """Append the Foxglove server and the DDS publisher the options ask for to ``writers``,
    and what to tell the user to ``lines``.

    Raises:
        ConfigError / MissingDependencyError: a server cannot start.
    """
    if opts.get("foxglove_port") is not None:
        from rfsas_hw.ros2.foxglove_live import LAYOUT_FILE, FoxgloveServer

        host = opts["foxglove_host"]
        server = FoxgloveServer(host, opts["foxglove_port"])
        writers.append(server)
        lines.append(f"foxglove: open {server.url} in the Foxglove app")
        if not _loopback(host):
            lines.append(
                f"foxglove: WARNING: the server has no authentication and listens on {host}: "
                "anyone who reaches this host sees the live scene"
            )
        lines.append(f"foxglove: layout {LAYOUT_FILE}")
    if opts.get("ros2_publish"):
        from rfsas_hw.ros2.dds import DdsConfig, DdsPublisher

        dds = DdsConfig(domain_id=opts["ros2_domain"], interface=_interface(opts))
        writers.append(DdsPublisher(dds))
        lines.append(f"ros2: publishing on domain {dds.domain_id}")


def _interface(opts: dict[str, Any]) -> str | None:
    """``--ros2-interface``: a network interface of this host by name or address.

    Raises:
        ConfigError: no interface of this host has that name, and it is no IP address.
    """
    name = opts.get("ros2_interface")
    if name is None:
        return None
    try:
        ipaddress.ip_address(name)
        return str(name)
    except ValueError:
        pass
    names = [n for _, n in socket.if_nameindex()]
    if name not in names:
        raise ConfigError(
            f"--ros2-interface {name!r}: no such network interface here "
            f"(there are: {', '.join(names)}); give a name or an address"
        )
    return str(name)


def _loopback(host: str) -> bool:
    """Whether ``host`` names this host only (localhost, 127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def sensor_scene(opts: dict[str, Any], pose_of: Callable[[str], Any]) -> tuple[Any, list[str]]:
    """A bearing listener publishing to the live outputs the options ask for, or None,
    and what to tell the user.

    Raises:
        ConfigError / MissingDependencyError: a server cannot start.
    """
    if not wants_live(opts):
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


def attach_scene(service: Any, out: Path | None, opts: dict[str, Any]) -> Ros2Outputs:
    """Add a scene sink to ``service`` for every ROS 2 output the options ask for.

    Raises:
        ConfigError / MissingDependencyError: an output cannot be started.
    """
    result = Ros2Outputs()
    writers: list[Any] = []
    try:
        if out is not None and out.suffix.lower() == ".mcap":
            from rfsas_hw.ros2.bag import McapFileWriter

            writers.append(McapFileWriter(out))
        if opts.get("rosbag2_dir") is not None:
            from rfsas_hw.ros2.bag import Rosbag2Writer

            writers.append(Rosbag2Writer(opts["rosbag2_dir"]))
        live_writers(opts, writers, result.lines)
        if opts.get("odom_topic"):
            from rfsas_hw.ros2.dds import DdsConfig, OdometryFeed

            dds = DdsConfig(domain_id=opts["ros2_domain"], interface=_interface(opts))
            feed = OdometryFeed(opts["odom_topic"], dds)
            result.vehicle_feed = feed
            result.closers.append(feed.close)
            result.lines.append(f"ros2: vehicle state from {opts['odom_topic']}")
    except Exception:
        for w in writers:
            w.close()
        result.close()
        raise
    if writers:
        from rfsas_hw.ros2.sink import BackendScene, SceneSink

        service.sinks.append(BackendScene.for_service(SceneSink(writers), service))
    return result
