"""Kinematic tracks: positions, velocities and headings along waypoints.

A track is piecewise linear in time: the mover waits ``start_s`` at the first
waypoint, then each leg is covered at its constant speed, with an optional
pause at each waypoint; after the last waypoint it stands still. Everything
is vectorised over time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import math_rad_to_compass
from rfsas_hw.twin.scenario import MoverSpec

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Track:
    """Knots of a piecewise-linear trajectory (time in scenario seconds, metres)."""

    t_s: Array
    """Knot times, non-decreasing, seconds."""
    x_m: Array
    """East at each knot, metres."""
    y_m: Array
    """North at each knot, metres."""

    @classmethod
    def from_spec(cls, spec: MoverSpec) -> Track:
        """Build the knots of a mover's route."""
        t = spec.start_s
        ts: list[float] = []
        xs: list[float] = []
        ys: list[float] = []
        wps = spec.waypoints
        for i, wp in enumerate(wps):
            ts.append(t)
            xs.append(wp.x_m)
            ys.append(wp.y_m)
            if i == len(wps) - 1:
                break
            if wp.pause_s > 0:
                t += wp.pause_s
                ts.append(t)
                xs.append(wp.x_m)
                ys.append(wp.y_m)
            nxt = wps[i + 1]
            t += float(np.hypot(nxt.x_m - wp.x_m, nxt.y_m - wp.y_m)) / wp.speed_mps
        return cls(np.asarray(ts, float), np.asarray(xs, float), np.asarray(ys, float))

    @property
    def end_s(self) -> float:
        """Time the mover reaches its last waypoint, seconds."""
        return float(self.t_s[-1])

    def position(self, t_s: npt.ArrayLike) -> Array:
        """Positions at times ``t_s``, shape ``(n, 2)`` (east, north), metres."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        if len(self.t_s) == 1:
            return np.tile([self.x_m[0], self.y_m[0]], (len(t), 1))
        return np.stack([np.interp(t, self.t_s, self.x_m), np.interp(t, self.t_s, self.y_m)], -1)

    def _leg(self, t: Array) -> npt.NDArray[np.intp]:
        """Index of the knot interval in effect at each time (the last moving one at the end)."""
        idx = np.searchsorted(self.t_s, t, side="right") - 1
        return np.clip(idx, 0, max(len(self.t_s) - 2, 0))

    def velocity(self, t_s: npt.ArrayLike) -> Array:
        """Velocities at times ``t_s``, shape ``(n, 2)`` (east, north), m/s."""
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        out = np.zeros((len(t), 2))
        if len(self.t_s) < 2:
            return out
        i = self._leg(t)
        dt = self.t_s[i + 1] - self.t_s[i]
        moving = (t >= self.t_s[0]) & (t < self.t_s[-1]) & (dt > 0)
        safe = np.where(dt > 0, dt, 1.0)
        out[:, 0] = np.where(moving, (self.x_m[i + 1] - self.x_m[i]) / safe, 0.0)
        out[:, 1] = np.where(moving, (self.y_m[i + 1] - self.y_m[i]) / safe, 0.0)
        return out

    def heading_deg(self, t_s: npt.ArrayLike) -> Array:
        """Compass heading at times ``t_s``, degrees.

        While standing (before the start, during a pause, after the end) the
        heading of the nearest leg with movement is kept.
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        if len(self.t_s) < 2:
            return np.zeros(len(t))
        dx = np.diff(self.x_m)
        dy = np.diff(self.y_m)
        moving = np.hypot(dx, dy) > 0
        if not moving.any():
            return np.zeros(len(t))
        legs = np.flatnonzero(moving)
        leg_heading = math_rad_to_compass(np.arctan2(dy[legs], dx[legs]))
        i = self._leg(t)
        # nearest moving leg at or after i, else the last one before
        pos = np.searchsorted(legs, i, side="left")
        pos = np.clip(pos, 0, len(legs) - 1)
        return np.asarray(leg_heading[pos], dtype=np.float64)

    def speed_mps(self, t_s: npt.ArrayLike) -> Array:
        """Speed at times ``t_s``, m/s."""
        v = self.velocity(t_s)
        return np.asarray(np.hypot(v[:, 0], v[:, 1]), dtype=np.float64)


def static_track(x_m: float, y_m: float) -> Track:
    """A track that stands at one point."""
    return Track(np.zeros(1), np.array([float(x_m)]), np.array([float(y_m)]))
