"""One sensor of a streaming twin as a source: the frames it heard since the last read.

A simulator bridge moves the twin's clock on (:attr:`StreamTwinSource.horizon_s`)
each step; :meth:`~rfsas_hw.sources.base.Source.read` then returns what the
sensor's driver would have delivered in the window since the previous read,
through the same base class as every other source (counters, filter, close).
It is not in the registry: it needs a live twin, not a spec string.
"""

from __future__ import annotations

from rfsas_hw.records import ObservationBatch
from rfsas_hw.sources.base import Source
from rfsas_hw.twin.stream import StreamTwin


class StreamTwinSource(Source[ObservationBatch]):
    """Observations of sensor ``sensor_id`` of ``twin``, window by window.

    Args:
        twin: the streaming twin.
        sensor_id: which sensor.

    Raises:
        ConfigError: no such sensor.
    """

    scheme = "twin-stream"

    def __init__(self, twin: StreamTwin, sensor_id: str, **options: object) -> None:
        twin.scenario.sensor(sensor_id)
        super().__init__(**options)  # type: ignore[arg-type]
        self.twin = twin
        self.sensor_id = sensor_id
        self.horizon_s = twin.cursor_s[sensor_id]
        """The twin's time up to which frames may be read, seconds (set by the caller)."""

    def __repr__(self) -> str:
        return f"StreamTwinSource({self.sensor_id!r})"

    def _read_raw(self, timeout: float | None) -> ObservationBatch | None:
        start = self.twin.cursor_s[self.sensor_id]
        if self.horizon_s <= start:
            return None
        rec = self.twin.receptions_between(self.sensor_id, start, self.horizon_s)
        return rec.observations()
