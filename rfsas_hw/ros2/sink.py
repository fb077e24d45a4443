"""The ROS 2 scene as a listener of the sensor stream and a sink of the backend.

:class:`SceneSink` serialises every message once and hands the CDR bytes to
each writer (MCAP file, rosbag2 directory, DDS publisher, Foxglove server).
:class:`SensorScene` is a bearing listener (``rfsas replay/live --out
run.mcap``); :class:`BackendScene` is a result sink of the backend service
(``rfsas backend --out run.mcap``, ``--ros2``, ``--foxglove``); the service
also hands it every sensor's bearings with the sensor's pose.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import replace
from typing import Any

from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose
from rfsas_hw.ros2.bag import MessageWriter
from rfsas_hw.ros2.scene import Out, SceneBuilder
from rfsas_hw.ros2.types import serialize

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000


class SceneSink:
    """Serialise scene messages once and write them to every writer.

    A writer that fails is logged once (one line) and counted, and its first error
    kept (:attr:`error`) for the run's end; the others keep receiving.
    """

    def __init__(self, writers: Iterable[MessageWriter], builder: SceneBuilder | None = None):
        self.writers = list(writers)
        self.builder = builder or SceneBuilder()
        self.counts: dict[str, int] = {}
        """Messages written, by topic name."""
        self.failures: dict[str, int] = {}
        """Failed writes (and closes), by writer name."""
        self.error: str | None = None
        """The first failure (``run.mcap: No space left on device``), or None."""
        self._closed = False

    def _failed(self, writer: MessageWriter, err: Exception, what: str) -> None:
        name = str(getattr(writer, "path", None) or type(writer).__name__)
        self.failures[name] = self.failures.get(name, 0) + 1
        if self.error is None:
            self.error = f"{name}: {what}: {getattr(err, 'strerror', None) or err}"
        if self.failures[name] == 1:
            # one line: the run's summary counts the rest
            log.warning("scene writer %s %s: %s", name, what, err)
            log.debug("scene writer %s failure", name, exc_info=True)

    def emit(self, outs: Iterable[Out]) -> None:
        """Serialise and write each item to every writer."""
        for out in outs:
            data = serialize(out.message, out.topic.typename)
            self.counts[out.topic.name] = self.counts.get(out.topic.name, 0) + 1
            for writer in self.writers:
                try:
                    writer.write(out.topic, out.stamp_ns, data)
                except Exception as err:
                    self._failed(writer, err, "write failed")

    def close(self) -> None:
        """Close every writer; idempotent."""
        if self._closed:
            return
        self._closed = True
        for writer in self.writers:
            try:
                writer.close()
            except Exception as err:
                self._failed(writer, err, "could not be finished")


class SensorScene:
    """A bearing listener that records or publishes each batch as ROS 2 messages.

    Args:
        sink: where the messages go.
        pose_of: the pose of a sensor by id at the time of the call (None: unknown).
    """

    def __init__(self, sink: SceneSink, pose_of: Callable[[str], Pose | None]) -> None:
        self.sink = sink
        self.pose_of = pose_of

    @property
    def error(self) -> str | None:
        """The first write failure of the recording, or None (the run's summary reports it)."""
        return self.sink.error

    def on_bearings(self, batch: BearingBatch) -> None:
        """Bearing array, sensor TF and rays of one batch (one array per
        :meth:`~rfsas_hw.ros2.scene.SceneBuilder.spans` of it)."""
        builder = self.sink.builder
        for part in builder.spans(batch):
            self.sink.emit(builder.bearings(part, self.pose_of(part.sensor_id)))

    def close(self) -> None:
        """Close the sink (and its writers)."""
        self.sink.close()


class BackendScene:
    """A result sink of :class:`~rfsas_hw.backend.service.BackendService` that
    publishes the whole scene each step.

    Args:
        sink: where the messages go.
        stations: the latest pose of every sensor (the service's ``stations``).
        vehicle: the current vehicle state, or None.
        link: ``(alarm, counters)`` of the link, or None when there is no link.
        link_period_s: link health is sent at most this often, seconds of stamp time.
    """

    def __init__(
        self,
        sink: SceneSink,
        *,
        stations: Callable[[], Mapping[str, Pose]] = dict,
        vehicle: Callable[[], VehicleState | None] = lambda: None,
        link: Callable[[], tuple[bool, Mapping[str, int]]] | None = None,
        link_period_s: float = 1.0,
    ) -> None:
        self.sink = sink
        self.stations = stations
        self.vehicle = vehicle
        self.link = link
        self.link_period_ns = int(link_period_s * NS_PER_S)
        self._last_link_ns: int | None = None
        self._last_t_ns = 0

    @classmethod
    def for_service(cls, sink: SceneSink, service: Any, **kwargs: Any) -> BackendScene:
        """A scene reading stations, vehicle and link counters from ``service``."""

        def link() -> tuple[bool, Mapping[str, int]]:
            alarm = bool(service.link_alarm()) if service.link_alarm is not None else False
            counters = service.link_stats() if service.link_stats is not None else {}
            return alarm, counters

        return cls(
            sink,
            stations=lambda: dict(service.stations),
            vehicle=lambda: service.vehicle,
            link=link,
            **kwargs,
        )

    def on_bearings(self, batch: BearingBatch, pose: Pose) -> None:
        """Bearings the backend received from a sensor at ``pose``."""
        if len(batch):
            self.sink.emit(self.sink.builder.bearings(batch, pose))

    @property
    def error(self) -> str | None:
        """The first write failure of the scene's writers, or None."""
        return self.sink.error

    def on_results(self, fixes: Sequence[Fix], assessments: Sequence[Assessment]) -> None:
        """Publish one step: results, sensors, vehicle and (at most once per period) the link."""
        if assessments:
            t_ns = assessments[0].t_ns
        elif fixes:
            t_ns = max(f.t_ns for f in fixes)
        else:
            t_ns = self._last_t_ns
        if t_ns == 0:
            return  # nothing has happened yet: no time to stamp a message with
        self._last_t_ns = max(self._last_t_ns, t_ns)
        builder = self.sink.builder
        outs = builder.results(t_ns, fixes, assessments)
        outs += builder.sensors(t_ns, self.stations())
        state = self.vehicle()
        if state is not None:
            outs += builder.vehicle(t_ns, vehicle_at(state, t_ns))
        if self.link is not None and (
            self._last_link_ns is None or t_ns - self._last_link_ns >= self.link_period_ns
        ):
            alarm, counters = self.link()
            outs += builder.link(t_ns, alarm, counters)
            self._last_link_ns = t_ns
        self.sink.emit(outs)

    def close(self) -> None:
        """Close the sink (and its writers)."""
        self.sink.close()


def vehicle_at(state: VehicleState, t_ns: int) -> VehicleState:
    """``state`` moved along its heading to ``t_ns`` (as the backend judges it); a state
    without a time (``t_ns == 0``) is taken as current."""
    if state.t_ns == 0:
        return state
    dt = max(t_ns - state.t_ns, 0) / NS_PER_S
    x, y = state.position + state.velocity * dt
    return replace(state, x_m=float(x), y_m=float(y), t_ns=t_ns)
