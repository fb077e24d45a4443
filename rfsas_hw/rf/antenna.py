"""Two squinted Gaussian beams: the antenna model of the monopulse pair.

``G_i(θ) = G_0 − 12·((θ ∓ θ_s)/β)²`` dB (method.md §4): antenna 0 peaks at
``+θ_s`` (clockwise of boresight), antenna 1 at ``−θ_s``. The −12 factor puts
the 3 dB points at ``±β/2`` from each peak. Real patches do not fall off for
ever: the gain is floored ``front_to_back_db`` below the peak, which is what
bounds the unambiguous field of view.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True, slots=True)
class GaussianBeamPair:
    """Two Gaussian beams squinted ±``squint_deg`` about boresight."""

    squint_deg: float = 20.0
    """Offset of each beam peak from boresight, degrees."""
    beamwidth_deg: float = 45.0
    """3 dB beamwidth of each beam, degrees."""
    peak_gain_dbi: float = 3.0
    """Gain at the beam peak, dBi."""
    front_to_back_db: float = 25.0
    """Floor of the pattern below the peak, dB."""

    def __post_init__(self) -> None:
        if self.beamwidth_deg <= 0:
            raise ValueError("beamwidth must be positive (degrees)")
        if self.front_to_back_db <= 0:
            raise ValueError("front-to-back ratio must be positive (dB)")

    def gains_db(self, theta_deg: Any) -> npt.NDArray[np.float64]:
        """Gain of each antenna at array-relative angles, dBi, shape ``(..., 2)``.

        ``theta_deg`` is clockwise from boresight; column 0 is the antenna
        squinted clockwise (``+θ_s``).
        """
        theta = np.asarray(theta_deg, dtype=np.float64)[..., None]
        peaks = np.array([self.squint_deg, -self.squint_deg])
        off = (theta - peaks + 180.0) % 360.0 - 180.0
        g = self.peak_gain_dbi - 12.0 * (off / self.beamwidth_deg) ** 2
        floor = self.peak_gain_dbi - self.front_to_back_db
        out: npt.NDArray[np.float64] = np.maximum(g, floor)
        return out

    def difference_slope_db_per_deg(self) -> float:
        """d(G_0 − G_1)/dθ inside the main lobes, dB per degree: ``48·θ_s/β²``."""
        return 48.0 * self.squint_deg / self.beamwidth_deg**2
