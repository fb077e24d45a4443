"""A reference model of a car's own camera/radar AEB: it brakes for what it can see.

The sensor sits at the middle of the VUT's front bumper. A target is
*visible* when its centre is within the field of view (``fov_deg`` wide,
centred on the VUT's heading), within ``range_m``, and the straight line
from the sensor to it crosses no occluder (SUMO's buildings and parked
vehicles, as rectangles: the same segment test the radio model uses,
:func:`~rfsas_hw.twin.rfworld.segment_crossings`). A target is *confirmed*
once it has been visible without a break for ``confirm_s`` (detection plus
the tracker's confirmation), or ``confirm_cued_s`` when its bearing is cued
(:mod:`rfsas_hw.ncap.cue`). The model estimates a confirmed target's
velocity from its own track (the displacement over the last
``velocity_window_s``), predicts the target and the VUT at constant
velocity, and requests the brake when their boxes would touch within
``ttc_brake_s`` (a time-to-collision threshold).

Parameter values (chosen; docs/ncap.md gives the sources and reasoning):
a 90° field of view and 60 m range (a wide-angle front camera of the 2020s
detection), 0.5 s confirmation (about 15 frames at 30 Hz), 0.1 s cued,
TTC threshold 1.6 s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rfsas_hw.angles import math_rad_to_compass, wrap_deg_180
from rfsas_hw.bridges.boxes import overlap, reach
from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.twin.rfworld import building_array, segment_crossings
from rfsas_hw.twin.scenario import BuildingSpec

__all__ = ["LosAeb", "LosParams", "sensor_point"]


@dataclass(frozen=True)
class LosParams:
    """The LOS AEB's parameters (see the module docstring)."""

    fov_deg: float = 90.0
    range_m: float = 60.0
    confirm_s: float = 0.5
    confirm_cued_s: float = 0.1
    velocity_window_s: float = 0.2
    ttc_brake_s: float = 1.6
    ttc_step_s: float = 0.05
    """Time step of the prediction, seconds."""

    def __post_init__(self) -> None:
        if not (0 < self.fov_deg <= 360 and self.range_m > 0 and self.ttc_brake_s > 0):
            raise ValueError("fov_deg, range_m and ttc_brake_s must be positive")
        if not (0 <= self.confirm_cued_s <= self.confirm_s):
            raise ValueError("confirm_cued_s must be in [0, confirm_s]")


def sensor_point(ego: Entity) -> tuple[float, float]:
    """The middle of the VUT's front bumper, metres (rfsas frame)."""
    a = math.radians(ego.heading_deg)
    return ego.x_m + ego.length_m / 2 * math.sin(a), ego.y_m + ego.length_m / 2 * math.cos(a)


def bearing_deg(origin: tuple[float, float], x: float, y: float) -> float:
    """Compass bearing from ``origin`` to ``(x, y)``, degrees in [0, 360)."""
    return math_rad_to_compass(math.atan2(y - origin[1], x - origin[0]))


@dataclass
class _Track:
    since_s: float
    history: list[tuple[float, float, float]] = field(default_factory=list)


class LosAeb:
    """The LOS AEB of one run (see the module docstring).

    Args:
        params: its parameters.
        occluders: what blocks its sight.
    """

    def __init__(self, params: LosParams, occluders: Sequence[BuildingSpec]) -> None:
        self.params = params
        self._rects = building_array(list(occluders))
        self._tracks: dict[str, _Track] = {}
        self.first_confirmed_s: dict[str, float] = {}
        """When each target was first confirmed, seconds."""

    def visible(self, ego: Entity, target: Entity) -> bool:
        """Whether ``target``'s centre is in view, in range and in line of sight."""
        p = self.params
        sx, sy = sensor_point(ego)
        if math.hypot(target.x_m - sx, target.y_m - sy) > p.range_m:
            return False
        off = wrap_deg_180(bearing_deg((sx, sy), target.x_m, target.y_m) - ego.heading_deg)
        if abs(off) > p.fov_deg / 2:
            return False
        seg0 = np.array([[sx, sy]])
        seg1 = np.array([[target.x_m, target.y_m]])
        return not bool(segment_crossings(seg0, seg1, self._rects).any())

    def step(
        self,
        t_s: float,
        ego: Entity,
        targets: Sequence[Entity],
        cued: Sequence[bool] | None = None,
    ) -> bool:
        """Look once at ``t_s``; whether to request the brake.

        Args:
            t_s: run time, seconds.
            ego: the VUT.
            targets: every VRU now.
            cued: per target, whether its bearing is cued now (None: none is).
        """
        p = self.params
        request = False
        for k, tgt in enumerate(targets):
            if not self.visible(ego, tgt):
                self._tracks.pop(tgt.id, None)
                continue
            tr = self._tracks.setdefault(tgt.id, _Track(t_s))
            tr.history.append((t_s, tgt.x_m, tgt.y_m))
            while len(tr.history) > 2 and tr.history[1][0] <= t_s - p.velocity_window_s:
                tr.history.pop(0)
            need = p.confirm_cued_s if cued is not None and cued[k] else p.confirm_s
            if t_s - tr.since_s < need - 1e-9 or len(tr.history) < 2:
                continue
            self.first_confirmed_s.setdefault(tgt.id, t_s)
            (t0, x0, y0), (t1, x1, y1) = tr.history[0], tr.history[-1]
            vx, vy = (x1 - x0) / (t1 - t0), (y1 - y0) / (t1 - t0)
            if self._contact_within(ego, tgt, vx, vy, p.ttc_brake_s):
                request = True
        return request

    def _contact_within(
        self, ego: Entity, tgt: Entity, vx: float, vy: float, horizon_s: float
    ) -> bool:
        a = math.radians(ego.heading_deg)
        ex, ey = ego.speed_mps * math.sin(a), ego.speed_mps * math.cos(a)
        # the centres' closest approach within the horizon (both move straight on): beyond
        # the boxes' reach no sampled instant can overlap, so none is tested
        dx, dy, dvx, dvy = tgt.x_m - ego.x_m, tgt.y_m - ego.y_m, vx - ex, vy - ey
        dv2 = dvx * dvx + dvy * dvy
        tau_min = 0.0 if dv2 == 0 else min(max(-(dx * dvx + dy * dvy) / dv2, 0.0), horizon_s)
        if math.hypot(dx + dvx * tau_min, dy + dvy * tau_min) > reach(ego, tgt):
            return False
        n = math.ceil(horizon_s / self.params.ttc_step_s)
        for i in range(n + 1):
            tau = min(i * self.params.ttc_step_s, horizon_s)
            e = Entity(ego.id, ego.kind, ego.x_m + ex * tau, ego.y_m + ey * tau,
                       ego.heading_deg, ego.speed_mps, ego.length_m, ego.width_m)  # fmt: skip
            o = Entity(tgt.id, tgt.kind, tgt.x_m + vx * tau, tgt.y_m + vy * tau,
                       tgt.heading_deg, 0.0, tgt.length_m, tgt.width_m)  # fmt: skip
            if overlap(e, o):
                return True
        return False
