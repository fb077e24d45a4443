"""Across channels: an emitter's bearings on two channels moments apart must agree.

Inside the field of view a direction finder's curves are calibrated per
channel and agree; outside it the back lobes and folds differ from channel to
channel (the antennas are resonant, the board's ground plane is not), so an
emitter outside the FoV heard on two channels tends to give two bearings that
do not fit together. :class:`ChannelConsistency` remembers each emitter's
latest bearing per channel and marks a bearing that disagrees with one on
another channel less than ``window_s`` earlier by more than
``k·√(σ₁² + σ₂²) + allowance_deg`` (the allowance covers the emitter's own
motion in the window).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.floating[Any]]

WINDOW_S = 0.5
"""Bearings on other channels older than this are not compared, seconds."""
K_SIGMA = 3.0
"""Disagreement beyond this many combined σ (plus the allowance) is inconsistent."""
ALLOWANCE_DEG = 2.0
"""Motion of the emitter within the window that is not a disagreement, degrees."""
MAX_EMITTERS = 65_536
"""Emitters remembered at most (the least recently heard are forgotten)."""


class ChannelConsistency:
    """Marks bearings that disagree with the same emitter's bearing on another channel.

    Args:
        window_s, k_sigma, allowance_deg, max_emitters: see the module constants.
    """

    def __init__(
        self,
        window_s: float = WINDOW_S,
        k_sigma: float = K_SIGMA,
        allowance_deg: float = ALLOWANCE_DEG,
        max_emitters: int = MAX_EMITTERS,
    ) -> None:
        if not (window_s >= 0 and k_sigma > 0 and allowance_deg >= 0 and max_emitters >= 1):
            raise ValueError("window_s ≥ 0, k_sigma > 0, allowance_deg ≥ 0, max_emitters ≥ 1")
        self.window_ns = int(window_s * 1e9)
        self.k_sigma = float(k_sigma)
        self.allowance_deg = float(allowance_deg)
        self.max_emitters = int(max_emitters)
        self._last: dict[int, dict[int, tuple[int, float, float]]] = {}
        """Per emitter, per channel: time (ns), angle and σ (degrees) of its latest bearing."""

    def __len__(self) -> int:
        return len(self._last)

    def inconsistent(
        self,
        keys: npt.ArrayLike,
        t_ns: npt.ArrayLike,
        channel: npt.ArrayLike,
        angle_deg: Array,
        sigma_deg: Array,
    ) -> npt.NDArray[np.bool_]:
        """True for each bearing (in order) that disagrees with its emitter's latest one
        on another channel within the window; every bearing is remembered."""
        out = self.walk(
            np.asarray(keys).tolist(),
            np.asarray(t_ns).tolist(),
            np.asarray(channel).tolist(),
            np.asarray(angle_deg).tolist(),
            np.asarray(sigma_deg).tolist(),
        )
        return np.array(out, dtype=bool)

    def walk(
        self,
        keys: list[int],
        t_ns: list[int],
        channel: list[int],
        angle_deg: list[float],
        sigma_deg: list[float],
    ) -> list[bool]:
        """:meth:`inconsistent` on the columns as lists (a caller that holds them so
        saves the conversions). NaN angles (no bearing) give False and are not kept.

        Raises:
            ValueError: the lists differ in length.
        """
        last = self._last
        window, k, allow = self.window_ns, self.k_sigma, self.allowance_deg
        out: list[bool] = []
        for key, t, ch, angle, sigma in zip(keys, t_ns, channel, angle_deg, sigma_deg, strict=True):
            if angle != angle:  # NaN: no bearing
                out.append(False)
                continue
            mine = last.pop(key, None) or {}
            bad = False
            for other, (t_o, a_o, s_o) in mine.items():
                if other != ch and 0 <= t - t_o <= window:
                    diff = abs((angle - a_o + 180.0) % 360.0 - 180.0)
                    if diff > k * math.sqrt(sigma * sigma + s_o * s_o) + allow:
                        bad = True
                        break
            mine[ch] = (t, angle, sigma)
            last[key] = mine  # re-inserted: the dict stays in hearing order
            out.append(bad)
        while len(last) > self.max_emitters:
            del last[next(iter(last))]
        return out
