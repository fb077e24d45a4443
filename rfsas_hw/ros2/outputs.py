"""``--out run.mcap`` / ``--format rosbag2`` for the sensor and backend commands.

The commands call :func:`sensor_recording` or :func:`backend_recording` with
their ``--out`` and ``--format``; these return None when the output is not a
ROS 2 recording, so the command falls back to its JSONL/CSV writer.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from rfsas_hw.errors import ConfigError
from rfsas_hw.records import Pose
from rfsas_hw.ros2.bag import open_recording, record_format
from rfsas_hw.ros2.sink import BackendScene, SceneSink, SensorScene

FORMATS = ("mcap", "rosbag2")
"""The ``--format`` values that mean a ROS 2 recording."""


def _open(out: str | Path, fmt: str | None) -> SceneSink | None:
    kind = record_format(out, fmt)
    if kind is None:
        return None
    if str(out) == "-":
        raise ConfigError(f"--out -: {kind} needs a file or directory name, not standard output")
    return SceneSink([open_recording(out, kind)])


def sensor_recording(
    out: str | Path, fmt: str | None, pose_of: Callable[[str], Pose | None]
) -> SensorScene | None:
    """A bearing listener recording to ``out`` when it is an MCAP/rosbag2 output, else None.

    Raises:
        ConfigError / MissingDependencyError: the recording cannot be created.
    """
    sink = _open(out, fmt)
    return None if sink is None else SensorScene(sink, pose_of)


def backend_recording(out: str | Path, fmt: str | None, service: Any) -> BackendScene | None:
    """A result sink of ``service`` recording to ``out`` when it is an MCAP/rosbag2
    output, else None.

    Raises:
        ConfigError / MissingDependencyError: the recording cannot be created.
    """
    sink = _open(out, fmt)
    return None if sink is None else BackendScene.for_service(sink, service)
