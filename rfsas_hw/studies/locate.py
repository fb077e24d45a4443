"""Run the twin's sensors through the real sensor pipeline and triangulate what they hear.

The way every higher-level simulation (the braking case, benchmarks, the
learning environment) gets an obstacle's position: observations from the
``virtual`` source, bearings from :class:`~rfsas_hw.pipeline.SensorPipeline`
(calibration table, keyed MAC hashing), and a fix from
:func:`rfsas_hw.backend.triangulate`. Nothing is taken from the ground truth
except for scoring.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.backend import Triangulation, triangulate
from rfsas_hw.df import Calibration, load_calibration
from rfsas_hw.errors import SimulationError
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.records import BearingBatch, mac_to_int
from rfsas_hw.sources.virtual import VirtualSource
from rfsas_hw.twin.turntable import turntable_calibration
from rfsas_hw.twin.world import World

Array = npt.NDArray[np.float64]


@dataclass
class SensorBearings:
    """One sensor's bearings from the pipeline, with where the sensor was for each."""

    sensor_id: str
    """The sensor."""
    bearings: BearingBatch
    """Hashed bearings, as the pipeline produced them."""
    station_xy: Array
    """Sensor position at each bearing's capture time, metres, shape (n, 2)."""
    stats: dict[str, object]
    """The pipeline's counters."""


def sensor_calibration(world: World, sensor_id: str) -> Calibration:
    """The sensor's calibration file, or a simulated turntable run when it names none.

    Raises:
        CalibrationError: the file is missing or invalid.
    """
    path = world.scenario.calibration_path(sensor_id)
    if path is None:
        return turntable_calibration(world.scenario, sensor_id)
    return load_calibration(path)


def default_hasher(key: bytes = b"rfsas-simulation-nonce") -> MacHasher:
    """The hasher simulations use: one fixed nonce (ids linkable across epochs; fine in a twin)."""
    return MacHasher(FixedNonce(key))


def run_pipelines(
    world: World,
    sensor_ids: Sequence[str] | None = None,
    *,
    hasher: MacHasher | None = None,
    batch_s: float = 0.1,
) -> dict[str, SensorBearings]:
    """Bearings of every named sensor (default: all) over the whole scenario.

    A moving sensor's pose is updated before each batch; batches are short
    (``batch_s``) so the heading used stays current.
    """
    hasher = hasher or default_hasher()
    ids = (
        list(sensor_ids) if sensor_ids is not None else [s.id for s in world.scenario.spec.sensors]
    )
    out: dict[str, SensorBearings] = {}
    for sid in ids:
        cal = sensor_calibration(world, sid)
        src = VirtualSource(world.scenario, sid, world=world, batch_s=batch_s)
        with src:
            pipe = SensorPipeline(cal, hasher, sid, src.pose_at(world.t0_ns))
            parts: list[BearingBatch] = []
            for batch in src:
                pipe.pose = src.pose_at(int(np.median(batch.t_ns)))
                parts.append(pipe.process(batch))
        bearings = BearingBatch.concat(sid, parts)
        t_s = (bearings.t_ns - world.t0_ns) / 1e9
        xy, _ = world.sensor_pose(sid, t_s)
        out[sid] = SensorBearings(sid, bearings, xy, pipe.stats.as_dict())
    return out


def emitter_hash(world: World, emitter_id: str, hasher: MacHasher, t_ns: int) -> int:
    """The hashed id the pipeline gives an emitter's MAC at ``t_ns`` (for scoring).

    Raises:
        SimulationError: no such emitter.
    """
    for e in world.scenario.spec.emitters:
        if e.id == emitter_id:
            return hasher.hash_one(mac_to_int(e.mac), t_ns)
    raise SimulationError(f"no emitter {emitter_id!r} in {world.scenario.source}")


def locate(
    world: World,
    emitter_id: str,
    bearings: dict[str, SensorBearings],
    *,
    t_start_s: float = 0.0,
    t_end_s: float | None = None,
    hasher: MacHasher | None = None,
) -> Triangulation:
    """Fix of one emitter from every bearing on it in ``[t_start_s, t_end_s)``.

    All bearings of all sensors in the window take part, each from the
    sensor's position at its capture time; the emitter is picked by its
    hashed id, as the backend would associate it.

    Raises:
        SimulationError: fewer than two sensors heard the emitter in the window.
    """
    hasher = hasher or default_hasher()
    t_end = world.duration_s if t_end_s is None else t_end_s
    lo = world.t0_ns + int(t_start_s * 1e9)
    hi = world.t0_ns + int(t_end * 1e9)
    xy: list[Array] = []
    az: list[Array] = []
    sig: list[Array] = []
    sensors = 0
    for sb in bearings.values():
        b = sb.bearings
        target = emitter_hash(world, emitter_id, hasher, lo)
        sel = (b.t_ns >= lo) & (b.t_ns < hi) & (b.emitter == np.uint64(target))
        if sel.any():
            sensors += 1
            xy.append(sb.station_xy[sel])
            az.append(b.azimuth_deg[sel])
            sig.append(b.sigma_deg[sel])
    if sensors < 2:
        raise SimulationError(
            f"emitter {emitter_id!r} heard by {sensors} sensor(s) between "
            f"{t_start_s:g} s and {t_end:g} s; a fix needs two"
        )
    return triangulate(np.concatenate(xy), np.concatenate(az), np.concatenate(sig))
