"""A receiver's scan plan as a function of time: which channel it listens on."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.twin.scenario import ScanSpec

NOT_LISTENING = 0
"""Channel value returned while the radio is retuning."""


@dataclass(frozen=True)
class ScanPlan:
    """Channels visited in turn, ``dwell_s`` each, deaf for ``switch_s`` at each change."""

    channels: tuple[int, ...]
    """Channels in visiting order."""
    dwell_s: float
    """Time per channel including the switch, seconds."""
    switch_s: float = 0.0
    """Dead time at the start of each dwell, seconds (0 for a fixed channel)."""
    offset_s: float = 0.0
    """Start of the first dwell, seconds."""

    def __post_init__(self) -> None:
        if not self.channels:
            raise ValueError("a scan plan needs at least one channel")
        if self.dwell_s <= 0 or not 0.0 <= self.switch_s < self.dwell_s:
            raise ValueError("scan plan needs dwell_s > 0 and 0 <= switch_s < dwell_s")

    @classmethod
    def from_spec(cls, spec: ScanSpec) -> ScanPlan:
        """The plan of a scenario's ``scan`` section."""
        return cls(spec.channels, spec.dwell_ms / 1e3, spec.switch_ms / 1e3, spec.offset_ms / 1e3)

    @property
    def period_s(self) -> float:
        """Time to visit every channel once (the channel revisit time), seconds."""
        return self.dwell_s * len(self.channels)

    @property
    def hopping(self) -> bool:
        """True when the plan has more than one channel."""
        return len(self.channels) > 1

    def channel_at(self, t_s: npt.ArrayLike) -> npt.NDArray[np.int16]:
        """Channel listened to at each time, or :data:`NOT_LISTENING` while retuning."""
        t = np.asarray(t_s, dtype=np.float64) - self.offset_s
        slot = np.floor(t / self.dwell_s)
        into = t - slot * self.dwell_s
        idx = np.mod(slot, len(self.channels)).astype(np.intp)
        ch = np.asarray(self.channels, dtype=np.int16)[idx]
        if self.hopping and self.switch_s > 0:
            ch = np.where(into < self.switch_s, NOT_LISTENING, ch).astype(np.int16)
        return ch
