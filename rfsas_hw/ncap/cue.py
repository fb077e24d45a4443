"""The cue: an RF-SAS track steers the camera/radar's attention to its bearing.

Definition. At every RF-SAS step, each assessment whose advisory is CAUTION
or BRAKE and whose latest fix is trustworthy gives a *cue*: the compass
bearing from the LOS sensor (the middle of the VUT's front) to the track's
position, valid for ``ttl_s`` after that step. A target seen by the LOS model
is *cued* while some valid cue lies within ``half_width_deg`` of the bearing
to the target; a cued target needs ``confirm_cued_s`` of uninterrupted
visibility instead of ``confirm_s`` before the LOS model acts on it
(:class:`~rfsas_hw.ncap.los_aeb.LosAeb`). The cue never makes a hidden
target visible and never brakes by itself: it only shortens confirmation.

Values (chosen): ``ttl_s`` = 1.0 s, ``half_width_deg`` = 10°, about three
times the median bearing error of a fix 10–20 m away (a 1 m position error).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from rfsas_hw.angles import wrap_deg_180
from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.ncap.los_aeb import bearing_deg, sensor_point
from rfsas_hw.records import Assessment

__all__ = ["CueParams", "Cues"]


@dataclass(frozen=True)
class CueParams:
    """How long and how wide a cue counts."""

    ttl_s: float = 1.0
    half_width_deg: float = 10.0


class Cues:
    """The live cues of one run (see the module docstring)."""

    def __init__(self, params: CueParams) -> None:
        self.params = params
        self._cues: list[tuple[float, float]] = []
        """(valid until, seconds; compass bearing, degrees)."""

    def add(self, t_s: float, ego: Entity, assessments: Sequence[Assessment]) -> int:
        """Add a cue per CAUTION/BRAKE assessment with a trustworthy fix; how many."""
        origin = sensor_point(ego)
        n = 0
        for a in assessments:
            if a.advisory in ("caution", "brake") and a.fix_ok:
                b = bearing_deg(origin, a.x_m, a.y_m)
                self._cues.append((t_s + self.params.ttl_s, b))
                n += 1
        return n

    def cued(self, t_s: float, ego: Entity, targets: Sequence[Entity]) -> list[bool]:
        """Per target, whether a valid cue points at it now."""
        self._cues = [c for c in self._cues if c[0] >= t_s]
        if not self._cues:
            return [False] * len(targets)
        origin = sensor_point(ego)
        out = []
        for tgt in targets:
            b = bearing_deg(origin, tgt.x_m, tgt.y_m)
            out.append(
                any(abs(wrap_deg_180(b - c)) <= self.params.half_width_deg for _, c in self._cues)
            )
        return out
