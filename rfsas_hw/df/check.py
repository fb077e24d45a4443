"""How well a calibration table predicts bearings on samples it was not fitted on."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.estimate import DfFlag, estimate
from rfsas_hw.rf.synth import TurntableSamples

CONSISTENT_RATIO = 1.2
"""RMS error and RMS predicted σ agree when their ratio is within [1/1.2, 1.2]."""


@dataclass(frozen=True, slots=True)
class CheckReport:
    """Bearing error of a calibration on held-back samples."""

    samples: int
    """Samples read."""
    inside_fov: int
    """Samples whose true angle lies inside the table's field of view."""
    valid: int
    """Of those, samples that gave a valid bearing."""
    rms_error_deg: float
    """RMS of (estimated − true) angle over the valid samples, degrees."""
    rms_sigma_deg: float
    """RMS of the σ the estimator predicted for the same samples, degrees."""
    max_abs_error_deg: float
    """Largest absolute error, degrees."""
    rejected: dict[str, int]
    """Samples inside the FoV without a bearing, by reason."""

    @property
    def ratio(self) -> float:
        """RMS error divided by RMS predicted σ (1 is a perfectly honest σ)."""
        return self.rms_error_deg / self.rms_sigma_deg if self.rms_sigma_deg > 0 else float("inf")

    @property
    def consistent(self) -> bool:
        """True when the predicted σ matches the observed error within 1.2×."""
        return 1.0 / CONSISTENT_RATIO <= self.ratio <= CONSISTENT_RATIO


def check_calibration(cal: Calibration, samples: TurntableSamples) -> CheckReport:
    """Estimate every sample inside its table's FoV and compare with the true angle.

    Samples outside the FoV are left out: amplitude monopulse cannot tell them
    from angles inside it (the ψ curve folds back), which is what the FoV means.
    """
    channel = samples.channel if any(t.channel is not None for t in cal.tables) else None
    result = estimate(cal, samples.rssi1_dbm, samples.rssi2_dbm, channel)
    inside = np.zeros(len(samples.angle_deg), dtype=bool)
    for i, ch in enumerate(samples.channel.tolist()):
        table = cal.table_for(int(ch))
        if table is not None:
            lo, hi = table.fov_deg
            inside[i] = lo <= samples.angle_deg[i] <= hi
    ok = inside & result.valid
    err = result.angle_deg[ok] - samples.angle_deg[ok]
    rejected: Counter[str] = Counter()
    for flag in DfFlag:
        if flag is DfFlag.NONE or flag.name is None:
            continue
        count = int(np.count_nonzero(inside & ((result.flags & np.uint8(flag)) != 0)))
        if count:
            rejected[flag.name.lower()] = count
    n_ok = int(ok.sum())
    return CheckReport(
        samples=len(samples.angle_deg),
        inside_fov=int(inside.sum()),
        valid=n_ok,
        rms_error_deg=float(np.sqrt(np.mean(err**2))) if n_ok else float("nan"),
        rms_sigma_deg=float(np.sqrt(np.mean(result.sigma_deg[ok] ** 2))) if n_ok else float("nan"),
        max_abs_error_deg=float(np.max(np.abs(err))) if n_ok else float("nan"),
        rejected=dict(rejected),
    )
