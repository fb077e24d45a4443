"""The sensor pipeline: observations → DF → hashed bearings.

This is the one place where an observation (with its raw MAC) becomes
something that may leave the sensor: a :class:`~rfsas_hw.records.BearingBatch`
whose emitter column holds keyed hashes only.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from rfsas_hw.angles import relative_to_compass
from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.estimate import DfFlag, estimate
from rfsas_hw.privacy.hashing import MacHasher
from rfsas_hw.records import BearingBatch, ObservationBatch, Pose


@dataclass
class PipelineStats:
    """What the pipeline did with the observations it was given."""

    observations: int = 0
    """Observations received."""
    bearings: int = 0
    """Valid bearings produced."""
    rejected: Counter[str] = field(default_factory=Counter)
    """Observations without a bearing, by reason (a frame may count under several)."""
    emitters: set[int] = field(default_factory=set)
    """Distinct emitter ids seen (hashed)."""

    def as_dict(self) -> dict[str, object]:
        """A JSON-friendly copy."""
        return {
            "observations": self.observations,
            "bearings": self.bearings,
            "rejected": dict(self.rejected),
            "emitters": len(self.emitters),
        }


class SensorPipeline:
    """Turn observation batches into bearing batches for one sensor.

    Args:
        calibration: the antenna pair's calibration (one table per channel or one for all).
        hasher: MAC → emitter id (the privacy stage).
        sensor_id: id written into every bearing.
        pose: where the sensor is and which way its boresight points (compass).
        min_snr_db: frames whose stronger antenna is below this are rejected (None: keep all).
    """

    def __init__(
        self,
        calibration: Calibration,
        hasher: MacHasher,
        sensor_id: str,
        pose: Pose,
        *,
        min_snr_db: float | None = None,
    ) -> None:
        self.calibration = calibration
        self.hasher = hasher
        self.sensor_id = sensor_id
        self.pose = pose
        self.min_snr_db = min_snr_db
        self.stats = PipelineStats()

    def process(self, batch: ObservationBatch) -> BearingBatch:
        """Valid bearings of ``batch``, in order; invalid frames are counted by reason.

        Raises:
            NonceUnavailableError: the hasher has no nonce for a frame's epoch.
        """
        n = len(batch)
        self.stats.observations += n
        if n == 0:
            return BearingBatch.empty(self.sensor_id)
        if batch.n_antennas < 2:
            self.stats.rejected["missing_chain"] += n
            return BearingBatch.empty(self.sensor_id)
        rssi = batch.rssi_dbm
        result = estimate(
            self.calibration, rssi[:, 0], rssi[:, 1], batch.channel, min_snr_db=self.min_snr_db
        )
        valid = result.flags == 0
        if not valid.all():
            for flag in DfFlag:
                if flag is DfFlag.NONE or flag.name is None:
                    continue
                count = int(np.count_nonzero(result.flags & np.uint8(flag)))
                if count:
                    self.stats.rejected[flag.name.lower()] += count
        if not valid.any():
            return BearingBatch.empty(self.sensor_id)
        good = batch.select(valid)
        emitters = self.hasher.hash_batch(good.mac, good.t_ns)
        self.stats.emitters.update(np.unique(emitters).tolist())
        relative = result.angle_deg[valid].astype(np.float64)
        out = BearingBatch(
            sensor_id=self.sensor_id,
            t_ns=good.t_ns,
            azimuth_deg=relative_to_compass(relative, self.pose.heading_deg),
            sigma_deg=result.sigma_deg[valid],
            snr_db=result.snr_db[valid],
            channel=good.channel,
            emitter=emitters,
            relative_deg=relative,
        )
        self.stats.bearings += len(out)
        return out
