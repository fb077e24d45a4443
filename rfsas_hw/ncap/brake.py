"""The VUT's brake: one model for every controller, so that they differ only in when they brake.

A brake request at time t engages the brake after ``latency_s`` (the brake
system's pressure build-up delay); the deceleration then rises at
``jerk_mps3`` to ``decel_mps2`` and stays there until the car stands still.
The brake holds while requests keep coming and for ``hold_s`` after the
last one; released, the deceleration falls at the same jerk and the car
keeps the speed it came down to (an AEB does not accelerate the car again;
the protocol's driver has released the accelerator). A car that has come to
a standstill stays there (a crossing test ends at VUT speed 0).

Values (chosen; docs/ncap.md gives the reasoning): 0.1 s latency, 25 m/s³
jerk, 9 m/s² full deceleration — a dry-road AEB reaches about 0.9 g within
about 0.4 s of its decision.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Brake", "BrakeModel"]


@dataclass(frozen=True)
class BrakeModel:
    """Brake dynamics (see the module docstring)."""

    decel_mps2: float = 9.0
    """Full deceleration, m/s²."""
    jerk_mps3: float = 25.0
    """Rate at which the deceleration builds up and falls, m/s³."""
    latency_s: float = 0.1
    """From a request to the brake engaging, seconds."""
    hold_s: float = 1.0
    """The brake holds this long after the last request, seconds."""

    def __post_init__(self) -> None:
        if not (self.decel_mps2 > 0 and self.jerk_mps3 > 0):
            raise ValueError("decel_mps2 and jerk_mps3 must be positive")
        if self.latency_s < 0 or self.hold_s < 0:
            raise ValueError("latency_s and hold_s must be >= 0")


class Brake:
    """The brake of one run: requests in, the VUT's speed out.

    Args:
        model: brake dynamics.
        speed_mps: the VUT's speed at the start, m/s.
    """

    def __init__(self, model: BrakeModel, speed_mps: float) -> None:
        self.model = model
        self.speed_mps = speed_mps
        self.decel_mps2 = 0.0
        self.first_request_s: float | None = None
        """When the brake was first requested, seconds (None: never)."""
        self._engage_at: float | None = None
        self._hold_until = -1.0

    @property
    def engaged(self) -> bool:
        """Whether the brake was ever requested."""
        return self.first_request_s is not None

    def request(self, t_s: float) -> None:
        """A controller asks for the brake at ``t_s``."""
        if self.first_request_s is None:
            self.first_request_s = t_s
        if self._engage_at is None or t_s > self._hold_until:
            self._engage_at = t_s + self.model.latency_s
        self._hold_until = t_s + self.model.latency_s + self.model.hold_s

    def advance(self, t_s: float, dt_s: float) -> float:
        """The speed over the step from ``t_s`` to ``t_s + dt_s``, m/s."""
        m = self.model
        on = self._engage_at is not None and self._engage_at <= t_s <= self._hold_until
        target = m.decel_mps2 if on else 0.0
        step = m.jerk_mps3 * dt_s
        if self.decel_mps2 < target:
            self.decel_mps2 = min(target, self.decel_mps2 + step)
        else:
            self.decel_mps2 = max(target, self.decel_mps2 - step)
        self.speed_mps = max(0.0, self.speed_mps - self.decel_mps2 * dt_s)
        return self.speed_mps
