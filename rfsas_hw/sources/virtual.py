"""The digital twin as a source: ``virtual:SCENARIO.yaml`` or ``virtual:SCENARIO.yaml#SENSOR``.

Observations come from the twin's RF world (:mod:`rfsas_hw.twin.world`), the
same code that writes the twin's capture files: path loss, blockage, beams,
fading, noise, quantisation and driver quirks. What a real driver would
report is what the source yields (sentinel chains as NaN, flagged); nothing
downstream (DF, hashing, backend) is bypassed.

Options: ``detail`` (low/medium/high, overrides the scenario), ``batch_s``
(simulated seconds per batch, default 0.1) and ``realtime`` (pace batches by
the wall clock instead of as fast as possible).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import ConfigError
from rfsas_hw.records import ObservationBatch, Pose
from rfsas_hw.sources.base import Source
from rfsas_hw.sources.schedule import CueScheduler, SchedulerConfig
from rfsas_hw.twin.scenario import Detail, Scenario, load_scenario
from rfsas_hw.twin.world import World


class VirtualSource(Source[ObservationBatch]):
    """Observations of one sensor of a scenario, from the twin.

    Args:
        scenario: a scenario file path or a loaded :class:`Scenario`.
        sensor_id: which sensor; may be omitted when the scenario has one.
        detail: level of detail override.
        batch_s: simulated seconds per batch.
        realtime: sleep so that batches arrive at the pace of simulated time.
        world: an already built world of the same scenario (shares its cache).
        clock: monotonic seconds, for ``realtime`` (injectable for tests).
        sleep: how to wait, for ``realtime`` (injectable for tests).
        cues: obey cues on the sensor's scan plan (:attr:`scheduler`, on the
            scenario clock, :meth:`now_s`): the twin hears every channel and the
            source keeps only frames on the channel the scheduler was on.

    Raises:
        ConfigError: bad scenario, unknown sensor, no sensor named while the
            scenario has several, or both ``world`` and ``cues`` given.
    """

    scheme = "virtual"

    def __init__(
        self,
        scenario: str | Path | Scenario,
        sensor_id: str | None = None,
        *,
        detail: Detail | None = None,
        batch_s: float = 0.1,
        realtime: bool = False,
        world: World | None = None,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        cues: SchedulerConfig | None = None,
        **options: Any,
    ) -> None:
        # everything that can fail runs before the base class marks the source open
        sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        sensors = [s.id for s in sc.spec.sensors]
        if sensor_id is None:
            if len(sensors) != 1:
                raise ConfigError(
                    f"{sc.source}: name the sensor as virtual:FILE#SENSOR (sensors: "
                    f"{', '.join(sensors)})"
                )
            sensor_id = sensors[0]
        self.sensor = sc.sensor(sensor_id)
        if batch_s <= 0:
            raise ConfigError("virtual source: batch_s must be positive")
        self.scheduler: CueScheduler | None = None
        if cues is not None and world is not None:
            raise ConfigError(
                "virtual source: with cues the source builds its own world (every channel "
                "computed); pass no world"
            )
        if cues is not None:
            scan = self.sensor.scan
            self.scheduler = CueScheduler(
                scan.channels,
                scan.dwell_ms / 1e3,
                cues,
                start_s=scan.offset_ms / 1e3 - scan.dwell_ms / 1e3 * len(scan.channels),
            )
            # the schedule is not known ahead: compute every channel, keep what was tuned
            world = World(sc, detail, listening={self.sensor.id: _every_channel})
        world = world if world is not None else World(sc, detail)
        super().__init__(**options)
        self.world = world
        self.batch_ns = int(batch_s * 1e9)
        self.realtime = realtime
        self._clock = clock
        self._sleep = sleep
        obs = self.world.receptions(self.sensor.id).observations()
        order = np.argsort(obs.t_ns, kind="stable")
        self._obs = obs.select(order)
        self._next_ns = self.world.t0_ns
        self._end_ns = self.world.t0_ns + int(self.world.duration_s * 1e9)
        self._cursor = 0
        self._wall0: float | None = None

    @classmethod
    def from_spec(cls, arg: str, **options: Any) -> VirtualSource:
        """``FILE`` or ``FILE#SENSOR``.

        Raises:
            ConfigError: empty path, bad scenario or unknown sensor.
        """
        path, _, sensor = arg.partition("#")
        if not path:
            raise ConfigError("virtual source needs a scenario file: virtual:SCENARIO.yaml#SENSOR")
        return cls(path, sensor or None, **options)

    def __repr__(self) -> str:
        return f"VirtualSource({self.world.scenario.source!r}, {self.sensor.id!r})"

    def now_s(self) -> float:
        """The scheduler's clock: scenario seconds up to which batches were handed out."""
        return (self._next_ns - self.world.t0_ns) / 1e9

    @property
    def scenario(self) -> Scenario:
        """The scenario being played."""
        return self.world.scenario

    def pose_at(self, t_ns: int) -> Pose:
        """The sensor's pose at UTC time ``t_ns`` (fixed for roadside units)."""
        t_s = (t_ns - self.world.t0_ns) / 1e9
        xy, heading = self.world.sensor_pose(self.sensor, [t_s])
        return Pose(float(xy[0, 0]), float(xy[0, 1]), float(heading[0]))

    def _read_raw(self, timeout: float | None) -> ObservationBatch | None:
        if self._next_ns >= self._end_ns:
            self._end()
            return None
        start_ns = self._next_ns
        stop_ns = min(self._next_ns + self.batch_ns, self._end_ns)
        if self.realtime:
            if self._wall0 is None:
                self._wall0 = self._clock()
            due = self._wall0 + (stop_ns - self.world.t0_ns) / 1e9
            wait = due - self._clock()
            if timeout is not None and wait > timeout:
                self._sleep(max(timeout, 0.0))
                return None
            if wait > 0:
                self._sleep(wait)
        stop = int(np.searchsorted(self._obs.t_ns, stop_ns, side="left"))
        batch = self._obs.select(slice(self._cursor, stop))
        self._cursor = stop
        self._next_ns = stop_ns
        if self._next_ns >= self._end_ns:
            if self._cursor < len(self._obs):
                # capture delays can push the last frames past the scenario's end
                tail = self._obs.select(slice(self._cursor, None))
                batch = ObservationBatch.concat([batch, tail])
                self._cursor = len(self._obs)
            self._end()
        if self.scheduler is not None:
            # cues that arrived by the start of this batch act on it
            self.scheduler.pull((start_ns - self.world.t0_ns) / 1e9)
            until_s = (stop_ns - self.world.t0_ns) / 1e9
            tl = self.scheduler.timeline(until_s)
            t_s = (batch.t_ns - self.world.t0_ns) / 1e9
            batch = batch.select(tl.channel_at(t_s) == batch.channel)
            self.stats.extra.update(self.scheduler.stats.as_dict())
        return batch


def _every_channel(
    t_s: npt.NDArray[np.float64], channel: npt.NDArray[np.int16]
) -> npt.NDArray[np.bool_]:
    return np.ones(len(t_s), bool)
