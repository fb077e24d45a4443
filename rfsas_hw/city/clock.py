"""The deployment's clock of a district run: the wall clock, or the wall clock slowed down.

Every party of the distributed path (twin workers, backends, the vehicles'
receivers, the nonce authority) stamps and checks messages with one
:class:`SimClock`. At ``scale`` 1 it is the wall clock: the run is real time
and every age check (stale bearings, stale advisories, nonce epochs) is the
deployment's own. At ``scale`` < 1 UTC runs that much slower than the wall
clock from ``anchor_ns`` on, in every process alike, so a machine too slow to
keep up with real time still runs the whole path with the same checks, in
simulated seconds; wall-time figures (latency) are then the clock's divided by
``scale``.
"""

from __future__ import annotations

import resource
import time
from dataclasses import dataclass

__all__ = ["SimClock", "cpu_s"]


def cpu_s() -> float:
    """CPU time this process has used so far (user + system), seconds."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return float(r.ru_utime + r.ru_stime)


@dataclass(frozen=True)
class SimClock:
    """UTC of the run, ns: ``anchor_ns + (wall - anchor_ns) · scale`` (see the module docstring)."""

    anchor_ns: int
    """Wall-clock UTC from which the clock runs at ``scale``, ns."""
    scale: float = 1.0
    """Seconds of this clock per wall second, in (0, 1]."""

    def __post_init__(self) -> None:
        if not 0.0 < self.scale <= 1.0:
            raise ValueError(f"time scale must be in (0, 1], got {self.scale}")

    def __call__(self) -> int:
        """Now, UTC ns."""
        now = time.time_ns()
        if self.scale == 1.0:
            return now
        return self.anchor_ns + int((now - self.anchor_ns) * self.scale)

    def wall_s(self, clock_s: float) -> float:
        """Wall seconds that ``clock_s`` seconds of this clock take."""
        return clock_s / self.scale
