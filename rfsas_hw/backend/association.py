"""Grouping bearings from several sensors by emitter id, ready to triangulate.

Bearings carry the keyed hash of the transmitter's MAC, so the same emitter
heard by two sensors in the same nonce epoch has the same id; ids from
different epochs never match. For each (emitter, sensor) pair only the newest
bearing is kept. A group for one emitter is the newest bearing of each sensor
captured within ``window_s`` of the emitter's newest bearing; bearings older
than ``max_age_s`` before "now" are aged out.

The window must be shorter than the nonce epoch: a longer one would promise
groups across epochs that the hashing makes impossible, and it would mix
positions of a moving emitter over a long stretch of time.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import ConfigError
from rfsas_hw.privacy.epochs import DEFAULT_EPOCH_S, NS_PER_S
from rfsas_hw.records import BearingBatch, Pose

Array = npt.NDArray[np.float64]

__all__ = [
    "AssociationConfig",
    "AssociationStats",
    "Associator",
    "BearingGroups",
    "StationBearing",
]


@dataclass(frozen=True, slots=True)
class AssociationConfig:
    """Time limits of the association.

    Args:
        window_s: bearings of one emitter within this many seconds of its newest
            bearing are grouped (0 < window_s < epoch_s).
        epoch_s: the deployment's nonce epoch length, seconds.
        max_age_s: bearings older than this before now are aged out, seconds
            (default: ``window_s``; must be ≥ ``window_s``).
        min_sensors: sensors needed for a group (≥ 2).

    Raises:
        ConfigError: a window not shorter than the epoch, or a value out of range.
    """

    window_s: float = 1.0
    epoch_s: float = DEFAULT_EPOCH_S
    max_age_s: float | None = None
    min_sensors: int = 2

    def __post_init__(self) -> None:
        if not self.window_s > 0:
            raise ConfigError(f"association window_s must be > 0, got {self.window_s}")
        if not self.window_s < self.epoch_s:
            raise ConfigError(
                f"association window_s ({self.window_s} s) must be shorter than the nonce "
                f"epoch ({self.epoch_s} s): emitter ids do not match across epochs"
            )
        if self.max_age_s is not None and not self.max_age_s >= self.window_s:
            raise ConfigError(
                f"association max_age_s ({self.max_age_s} s) must be ≥ window_s ({self.window_s} s)"
            )
        if self.min_sensors < 2:
            raise ConfigError(f"association min_sensors must be ≥ 2, got {self.min_sensors}")

    @property
    def max_age_ns(self) -> int:
        """Age limit, nanoseconds."""
        return int((self.window_s if self.max_age_s is None else self.max_age_s) * NS_PER_S)


@dataclass(slots=True)
class AssociationStats:
    """Counts of the association."""

    bearings: int = 0
    """Bearings offered."""
    superseded: int = 0
    """Bearings replaced by a newer one of the same sensor and emitter (or older on arrival)."""
    aged_out: int = 0
    """Bearings dropped for age."""
    groups: int = 0
    """Groups handed out for triangulation."""


@dataclass(frozen=True, slots=True)
class BearingGroups:
    """``B`` emitters' grouped bearings, padded to ``N`` per row with NaN azimuths."""

    emitter: npt.NDArray[np.uint64]
    """Emitter id per group, shape (B,)."""
    t_ns: npt.NDArray[np.int64]
    """Newest bearing time per group, UTC ns, shape (B,)."""
    stations_xy: Array
    """Sensor positions, metres east/north, shape (B, N, 2)."""
    azimuth_deg: Array
    """Compass azimuths, shape (B, N); NaN where a row has fewer bearings."""
    sigma_deg: Array
    """One-sigma bearing errors, degrees, shape (B, N)."""
    bearing_t_ns: npt.NDArray[np.int64]
    """Capture time of each bearing, UTC ns, shape (B, N) (0 where padded)."""
    sensors: tuple[tuple[str, ...], ...]
    """Sensor ids of each group, in column order."""

    def __len__(self) -> int:
        return int(self.emitter.shape[0])


class StationBearing(NamedTuple):
    """One sensor's newest bearing of an emitter, with where the sensor was."""

    sensor: str
    """Sensor id."""
    t_ns: int
    """Capture time, UTC ns."""
    azimuth_deg: float
    """Compass azimuth, degrees."""
    sigma_deg: float
    """One-sigma bearing error, degrees."""
    x_m: float
    """Sensor position east, metres."""
    y_m: float
    """Sensor position north, metres."""
    heading_deg: float
    """Compass azimuth of the sensor's boresight, degrees."""


@dataclass(slots=True)
class Associator:
    """Keeps the newest bearing per (emitter, sensor) and hands out groups to triangulate."""

    config: AssociationConfig = field(default_factory=AssociationConfig)
    stats: AssociationStats = field(default_factory=AssociationStats)
    _latest: dict[int, dict[str, StationBearing]] = field(default_factory=dict)
    _dirty: set[int] = field(default_factory=set)

    def add(self, batch: BearingBatch, pose: Pose) -> None:
        """Take the bearings one sensor (``batch.sensor_id``) measured from ``pose``."""
        n = len(batch)
        self.stats.bearings += n
        if n == 0:
            return
        sensor = batch.sensor_id
        emitters, times = batch.emitter.tolist(), batch.t_ns.tolist()
        # newest bearing of each emitter in the batch (the later row on a tie): one pass
        # over the rows as Python numbers, linear like the loop below; a sort costs more
        # than it saves on the few rows a sensor sends per step
        newest: dict[int, int] = {}
        for i, emitter in enumerate(emitters):
            j = newest.get(emitter)
            if j is None or times[i] >= times[j]:
                newest[emitter] = i
        self.stats.superseded += n - len(newest)
        azimuths, sigmas = batch.azimuth_deg.tolist(), batch.sigma_deg.tolist()
        for emitter, i in newest.items():
            t_ns = times[i]
            per_sensor = self._latest.setdefault(emitter, {})
            old = per_sensor.get(sensor)
            if old is not None:
                self.stats.superseded += 1
                if old.t_ns > t_ns:
                    continue
            per_sensor[sensor] = StationBearing(
                sensor,
                t_ns,
                azimuths[i],
                sigmas[i],
                pose.x_m,
                pose.y_m,
                pose.heading_deg,
            )
            self._dirty.add(emitter)

    def prune(self, now_ns: int) -> None:
        """Age out bearings captured more than ``max_age_s`` before ``now_ns``."""
        limit = now_ns - self.config.max_age_ns
        for emitter in list(self._latest):
            per_sensor = self._latest[emitter]
            stale = [s for s, b in per_sensor.items() if b.t_ns < limit]
            for s in stale:
                del per_sensor[s]
            self.stats.aged_out += len(stale)
            if not per_sensor:
                del self._latest[emitter]
                self._dirty.discard(emitter)

    def groups(
        self,
        now_ns: int,
        only_new: bool = True,
        admit: Callable[[int, StationBearing], bool] | None = None,
    ) -> BearingGroups:
        """Groups of at least ``min_sensors`` bearings, after ageing out at ``now_ns``.

        Args:
            now_ns: current time, UTC ns.
            only_new: only emitters that received a bearing since the last call.
            admit: called with an emitter id and each bearing that would join its
                group; a bearing it refuses is left out (it is kept for later groups and
                for :meth:`newest`), and the group's time is that of its newest member.
                None: every bearing.
        """
        self.prune(now_ns)
        window_ns = int(self.config.window_s * NS_PER_S)
        candidates = self._dirty if only_new else set(self._latest)
        chosen: list[tuple[int, int, list[tuple[str, StationBearing]]]] = []
        for emitter in sorted(candidates):
            per_sensor = self._latest.get(emitter)
            if not per_sensor:
                continue
            newest = max(b.t_ns for b in per_sensor.values())
            members = sorted(
                ((s, b) for s, b in per_sensor.items() if b.t_ns >= newest - window_ns),
                key=lambda item: item[0],
            )
            if admit is not None:
                members = [(s, b) for s, b in members if admit(emitter, b)]
                newest = max((b.t_ns for _, b in members), default=newest)
            if len(members) >= self.config.min_sensors:
                chosen.append((emitter, newest, members))
        if only_new:
            self._dirty.clear()
        self.stats.groups += len(chosen)
        B = len(chosen)
        N = max((len(m) for _, _, m in chosen), default=self.config.min_sensors)
        # rows as lists, padded (station 0, 0; azimuth NaN; sigma 1; time 0), one array each
        xy_rows, az_rows, sig_rows, t_rows = [], [], [], []
        for _, _, members in chosen:
            pad = N - len(members)
            xy_rows.append([(b.x_m, b.y_m) for _, b in members] + [(0.0, 0.0)] * pad)
            az_rows.append([b.azimuth_deg for _, b in members] + [math.nan] * pad)
            sig_rows.append([b.sigma_deg for _, b in members] + [1.0] * pad)
            t_rows.append([b.t_ns for _, b in members] + [0] * pad)
        stations = np.array(xy_rows, np.float64).reshape(B, N, 2)
        az = np.array(az_rows, np.float64).reshape(B, N)
        sig = np.array(sig_rows, np.float64).reshape(B, N)
        bt = np.array(t_rows, np.int64).reshape(B, N)
        return BearingGroups(
            emitter=np.array([e for e, _, _ in chosen], np.uint64),
            t_ns=np.array([t for _, t, _ in chosen], np.int64),
            stations_xy=stations,
            azimuth_deg=az,
            sigma_deg=sig,
            bearing_t_ns=bt,
            sensors=tuple(tuple(s for s, _ in m) for _, _, m in chosen),
        )

    def newest(self, emitter: int) -> list[StationBearing]:
        """The newest bearing of ``emitter`` from each sensor that heard it (not yet aged
        out at the last :meth:`prune`), oldest first."""
        per_sensor = self._latest.get(emitter, {})
        out = list(per_sensor.values())
        out.sort(key=lambda b: (b.t_ns, b.sensor))
        return out

    def __len__(self) -> int:
        """Emitters with at least one live bearing."""
        return len(self._latest)
