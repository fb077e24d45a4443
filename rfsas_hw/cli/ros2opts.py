"""ROS 2 options of ``rfsas backend``: a bag, a Foxglove live view, DDS publishing.

:func:`ros2_options` adds the options; :func:`attach_scene` builds the
writers they ask for and hangs one scene sink on the backend service.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import click

F = TypeVar("F", bound=Callable[..., Any])


def ros2_options(func: F) -> F:
    """Add ``--rosbag2``, ``--foxglove``, ``--foxglove-host``, ``--ros2``, ``--ros2-domain``,
    ``--ros2-interface`` and ``--odom``."""
    options = [
        click.option(
            "--rosbag2",
            "rosbag2_dir",
            type=click.Path(file_okay=False, path_type=Path),
            help="Record the scene into this new rosbag2 directory (sqlite3 storage). "
            "An --out name ending in .mcap records an MCAP file instead of JSON lines.",
        ),
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
        if opts.get("foxglove_port") is not None:
            from rfsas_hw.ros2.foxglove_live import LAYOUT_FILE, FoxgloveServer

            server = FoxgloveServer(opts["foxglove_host"], opts["foxglove_port"])
            writers.append(server)
            result.lines.append(f"foxglove: open {server.url} in the Foxglove app")
            result.lines.append(f"foxglove: layout {LAYOUT_FILE}")
        if opts.get("ros2_publish") or opts.get("odom_topic"):
            from rfsas_hw.ros2.dds import DdsConfig, DdsPublisher, OdometryFeed

            dds = DdsConfig(domain_id=opts["ros2_domain"], interface=opts.get("ros2_interface"))
            if opts.get("ros2_publish"):
                writers.append(DdsPublisher(dds))
                result.lines.append(f"ros2: publishing on domain {dds.domain_id}")
            if opts.get("odom_topic"):
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
