"""ROS 2 options of the commands: a bag, a Foxglove live view, DDS publishing.

:func:`live_options` (``--foxglove``, ``--ros2``) serves the sensor commands
and the backend; :func:`ros2_options` adds the backend's ``--rosbag2`` and
``--odom``. :func:`ros2_config` maps their values onto the applications'
:class:`~rfsas_hw.apps.ros2.Ros2Options`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import click

from rfsas_hw.apps.ros2 import Ros2Options
from rfsas_hw.cli.outopts import OutputPath

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


def ros2_config(opts: dict[str, Any]) -> Ros2Options:
    """The :class:`~rfsas_hw.apps.ros2.Ros2Options` that the values of
    :func:`live_options` / :func:`ros2_options` ask for (missing keys: defaults)."""
    return Ros2Options(
        foxglove_port=opts.get("foxglove_port"),
        foxglove_host=opts.get("foxglove_host") or "127.0.0.1",
        publish=bool(opts.get("ros2_publish")),
        domain_id=int(opts.get("ros2_domain") or 0),
        interface=opts.get("ros2_interface"),
        rosbag2_dir=opts.get("rosbag2_dir"),
        odom_topic=opts.get("odom_topic"),
    )
