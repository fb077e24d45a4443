"""A backend service fed the bearings of an emitter walking east, for the district tests."""

from __future__ import annotations

import numpy as np

from rfsas_hw.backend.service import BackendService
from rfsas_hw.records import BearingBatch, Pose

S = 1_000_000_000


def walk_east(
    service: BackendService, emitter: int, x0: float, y0: float, steps: int, now_ns: int
) -> None:
    """Bearings of ``emitter`` walking east at 2 m/s from (x0, y0) metres, heard by two
    units 30 m either side of its start, one service step per 0.1 s up to ``now_ns``."""
    stations = {"rsu-a": Pose(x0 - 30.0, 0.0, 45.0), "rsu-b": Pose(x0 + 30.0, 0.0, 315.0)}
    for k in range(steps):
        t = now_ns - (steps - k) * S // 10
        target = np.array([x0 + 0.2 * k, y0])
        for sid, pose in stations.items():
            az = float(np.degrees(np.arctan2(target[0] - pose.x_m, target[1] - pose.y_m)) % 360)
            batch = BearingBatch(
                sensor_id=sid,
                t_ns=np.array([t], np.int64),
                azimuth_deg=np.array([az]),
                sigma_deg=np.array([1.0]),
                snr_db=np.array([25.0]),
                channel=np.array([6], np.int16),
                emitter=np.array([emitter], np.uint64),
            )
            service.on_bearings(batch, pose)
        service.step(t)
