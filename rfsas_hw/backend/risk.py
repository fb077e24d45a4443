"""Stopping distance, impact speed, pedestrian fatality risk and the advisory (method.md §7).

- Braking deceleration ``a_b = 0.47 g`` with ``g = 9.80665 m/s²``.
- Stopping distance ``D_stop = u·τ + u²/(2·a_b)`` for speed ``u`` and reaction delay ``τ``.
- Impact speed ``v = √(u² − 2·a_b·x_b)`` with ``x_b`` the braking distance left
  after the reaction delay, 0 when the vehicle stops in time.
- Rosen's fatality risk ``P_f(v) = 1/(1 + e^(6.9 − 0.090·v))`` with v in km/h.
- Risk ``R = P_collision · P_f(v)``.

Every function takes floats or numpy arrays and returns the same kind.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any, overload

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import BackendError

Array = npt.NDArray[np.float64]

__all__ = [
    "BRAKE_DECEL_MPS2",
    "G_MPS2",
    "Advisory",
    "AdvisoryThresholds",
    "advise",
    "fatality_risk",
    "fatality_risk_of",
    "impact_speed",
    "impact_speed_of",
    "stopping_distance",
    "stopping_distance_of",
]

G_MPS2 = 9.80665
"""Standard gravity, m/s²."""
BRAKE_DECEL_MPS2 = 0.47 * G_MPS2
"""Braking deceleration of method.md §7: 0.47 g ≈ 4.609 m/s²."""
ROSEN_A = 6.9
"""Intercept of Rosen's logistic fatality model (v in km/h)."""
ROSEN_B = 0.090
"""Slope of Rosen's logistic fatality model, per km/h."""


def _same_kind(value: Any, result: Any) -> Any:
    return np.asarray(result, np.float64) if isinstance(value, np.ndarray) else float(result)


def _check(speed: Array, decel: float, reaction_s: float) -> None:
    if not (speed >= 0).all():
        raise BackendError(f"speed must be ≥ 0 m/s and finite, got {speed}")
    if not (decel > 0 and math.isfinite(decel)):
        raise BackendError(f"braking deceleration must be > 0 m/s², got {decel}")
    if not (reaction_s >= 0 and math.isfinite(reaction_s)):
        raise BackendError(f"reaction delay must be ≥ 0 s, got {reaction_s}")


@overload
def stopping_distance(
    speed_mps: float, decel_mps2: float = ..., reaction_s: float = ...
) -> float: ...
@overload
def stopping_distance(
    speed_mps: Array, decel_mps2: float = ..., reaction_s: float = ...
) -> Array: ...
def stopping_distance(
    speed_mps: float | Array, decel_mps2: float = BRAKE_DECEL_MPS2, reaction_s: float = 0.0
) -> float | Array:
    """Distance to stop from ``speed_mps``: ``u·τ + u²/(2·a_b)``, metres.

    Raises:
        BackendError: negative speed, non-positive deceleration or negative delay.
    """
    u = np.asarray(speed_mps, np.float64)
    _check(u, decel_mps2, reaction_s)
    return _same_kind(speed_mps, stopping_distance_of(u, decel_mps2, reaction_s))  # type: ignore[no-any-return]


def stopping_distance_of(speed_mps: Array, decel_mps2: float, reaction_s: float) -> Array:
    """:func:`stopping_distance` of inputs already known to be valid (the caller checked
    them), as an array: the computation without the checks."""
    d: Array = speed_mps * reaction_s + speed_mps * speed_mps / (2 * decel_mps2)
    return d


@overload
def impact_speed(
    speed_mps: float, distance_m: float, decel_mps2: float = ..., reaction_s: float = ...
) -> float: ...
@overload
def impact_speed(
    speed_mps: Array, distance_m: Array | float, decel_mps2: float = ..., reaction_s: float = ...
) -> Array: ...
@overload
def impact_speed(
    speed_mps: float, distance_m: Array, decel_mps2: float = ..., reaction_s: float = ...
) -> Array: ...
def impact_speed(
    speed_mps: float | Array,
    distance_m: float | Array,
    decel_mps2: float = BRAKE_DECEL_MPS2,
    reaction_s: float = 0.0,
) -> float | Array:
    """Speed at which the vehicle reaches an obstacle ``distance_m`` ahead while braking.

    The vehicle keeps ``speed_mps`` for ``reaction_s`` seconds, then brakes at
    ``decel_mps2``: ``v = √(u² − 2·a_b·x_b)`` with ``x_b = distance − u·τ``
    (clipped at 0, so an obstacle already touching is hit at full speed), or 0
    when the vehicle stops within the distance.

    Raises:
        BackendError: negative speed, non-positive deceleration, negative delay
            or a non-finite distance.
    """
    u = np.asarray(speed_mps, np.float64)
    x = np.asarray(distance_m, np.float64)
    _check(u, decel_mps2, reaction_s)
    if not np.isfinite(x).all():
        raise BackendError(f"distance must be finite, got {distance_m}")
    kind = distance_m if isinstance(distance_m, np.ndarray) else speed_mps
    return _same_kind(kind, impact_speed_of(u, x, decel_mps2, reaction_s))  # type: ignore[no-any-return]


def impact_speed_of(
    speed_mps: Any, distance_m: Array, decel_mps2: float, reaction_s: float
) -> Array:
    """:func:`impact_speed` of inputs already known to be valid (the caller checked
    them), as an array: the computation without the checks."""
    x_b = np.maximum(distance_m - speed_mps * reaction_s, 0.0)
    v: Array = np.sqrt(np.maximum(speed_mps * speed_mps - 2 * decel_mps2 * x_b, 0.0))
    return v


@overload
def fatality_risk(speed_mps: float) -> float: ...
@overload
def fatality_risk(speed_mps: Array) -> Array: ...
def fatality_risk(speed_mps: float | Array) -> float | Array:
    """Rosen's pedestrian fatality probability at impact speed ``speed_mps`` (m/s).

    ``P_f(v) = 1/(1 + e^(6.9 − 0.090·v))`` with v in km/h: 0.001007 at rest,
    0.3965 at 72 km/h.

    Raises:
        BackendError: a negative or non-finite speed.
    """
    u = np.asarray(speed_mps, np.float64)
    if not ((u >= 0) & (u < math.inf)).all():  # NaN fails both
        raise BackendError(f"impact speed must be ≥ 0 m/s and finite, got {speed_mps}")
    return _same_kind(speed_mps, fatality_risk_of(u))  # type: ignore[no-any-return]


def fatality_risk_of(speed_mps: Array) -> Array:
    """:func:`fatality_risk` of speeds already known to be ≥ 0 and finite, as an
    array: the computation without the checks."""
    v_kmh = speed_mps * 3.6
    return 1.0 / (1.0 + np.exp(ROSEN_A - ROSEN_B * v_kmh))


class Advisory(enum.StrEnum):
    """What the vehicle should do about one threat."""

    BRAKE = "brake"
    CAUTION = "caution"
    CLEAR = "clear"


ADVISORY_RANK = {"none": 0, "clear": 1, "caution": 2, "brake": 3}
"""Severity of each advice (``none``: no advice given), for choosing the worst."""


@dataclass(frozen=True, slots=True)
class AdvisoryThresholds:
    """When :func:`advise` says brake or caution.

    Args:
        brake_risk: risk ``R`` at or above which to brake.
        caution_risk: risk at or above which to take care.
        brake_p_collision: P(collision) at or above which to brake, if the
            contact is within ``stop_margin`` times the stopping distance.
        caution_p_collision: P(collision) at or above which to take care.
        stop_margin: factor on the stopping distance for ``brake_p_collision``.
        caution_on_link_alarm: a latency alarm on the link means at least caution.
        caution_on_bad_fix: an emitter heard but not located means at least caution.
        brake_min_fixes: fewest fixes a track must have taken since it (re)started
            before it may cause a brake; a younger track (one just restarted by a
            fix outside its gate) gives at most caution. 1: any track.
        brake_needs_path: brake only for a threat already in the vehicle's lane
            (its centre within the two half-widths of the vehicle's path, by
            ``brake_position_sigmas`` of its position's one-sigma across it) or
            moving into it with evidence: its speed towards the path less
            ``brake_path_sigmas`` of its one-sigma still reaches the path by closest
            approach. Without that evidence at most caution. False: no such test.
        brake_path_sigmas: how many sigmas of the speed towards the path must be
            left over for ``brake_needs_path``.
        brake_position_sigmas: for ``brake_needs_path``, how many sigmas of the
            threat's position across the path its centre must lie inside the path
            by, to count as in it by position (0: its centre inside is enough).

    Raises:
        BackendError: thresholds out of order or outside [0, 1], fewer than one
            fix, or a negative number of sigmas.
    """

    brake_risk: float = 0.01
    caution_risk: float = 0.001
    brake_p_collision: float = 0.2
    caution_p_collision: float = 0.02
    stop_margin: float = 1.5
    caution_on_link_alarm: bool = True
    caution_on_bad_fix: bool = True
    brake_min_fixes: int = 1
    brake_needs_path: bool = False
    brake_path_sigmas: float = 2.0
    brake_position_sigmas: float = 0.0

    def __post_init__(self) -> None:
        for name in ("brake_risk", "caution_risk", "brake_p_collision", "caution_p_collision"):
            value = getattr(self, name)
            if not 0 <= value <= 1:
                raise BackendError(f"{name} must be in [0, 1], got {value}")
        if self.caution_risk > self.brake_risk:
            raise BackendError("caution_risk must not exceed brake_risk")
        if self.caution_p_collision > self.brake_p_collision:
            raise BackendError("caution_p_collision must not exceed brake_p_collision")
        if not self.stop_margin >= 1:
            raise BackendError(f"stop_margin must be ≥ 1, got {self.stop_margin}")
        if not self.brake_min_fixes >= 1:
            raise BackendError(f"brake_min_fixes must be ≥ 1, got {self.brake_min_fixes}")
        for name in ("brake_path_sigmas", "brake_position_sigmas"):
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise BackendError(f"{name} must be ≥ 0, got {value}")


DEFAULT_THRESHOLDS = AdvisoryThresholds()


def advise(
    p_collision: float,
    risk: float,
    distance_to_contact_m: float,
    stopping_distance_m: float,
    *,
    fix_ok: bool = True,
    fix_reason: str = "",
    link_alarm: bool = False,
    brake_held: str = "",
    thresholds: AdvisoryThresholds = DEFAULT_THRESHOLDS,
) -> tuple[Advisory, tuple[str, ...]]:
    """The advisory for one threat and every reason that led to it.

    Args:
        p_collision: probability that the boxes overlap at closest approach.
        risk: ``P_collision · P_f(impact speed)``.
        distance_to_contact_m: along-track distance until the boxes would touch, metres.
        stopping_distance_m: distance the vehicle needs to stop, metres.
        fix_ok: whether the threat's position is trustworthy.
        fix_reason: why it is not (shown in the reasons).
        link_alarm: whether the link's latency watch is alarmed.
        brake_held: why a brake is not supported by the track (a young track, no
            evidence of a path into the lane; see :class:`AdvisoryThresholds`);
            non-empty turns a brake into caution with this reason.
        thresholds: the decision thresholds.

    Returns:
        ``(advisory, reasons)``; reasons are short sentences with the numbers.
    """
    t = thresholds
    brake: list[str] = []
    caution: list[str] = []
    if risk >= t.brake_risk:
        brake.append(f"risk {risk:.3g} ≥ {t.brake_risk:g}")
    elif risk >= t.caution_risk:
        caution.append(f"risk {risk:.3g} ≥ {t.caution_risk:g}")
    near = distance_to_contact_m <= t.stop_margin * stopping_distance_m
    if p_collision >= t.brake_p_collision and near:
        brake.append(
            f"P(collision) {p_collision:.3g} ≥ {t.brake_p_collision:g} with contact in "
            f"{distance_to_contact_m:.1f} m, stopping needs {stopping_distance_m:.1f} m"
        )
    elif p_collision >= t.caution_p_collision:
        caution.append(f"P(collision) {p_collision:.3g} ≥ {t.caution_p_collision:g}")
    if link_alarm and t.caution_on_link_alarm:
        caution.append("link latency alarm")
    if not fix_ok and t.caution_on_bad_fix:
        caution.append(f"emitter not located: {fix_reason}".rstrip(": "))
    if brake and brake_held:
        return Advisory.CAUTION, (f"brake held: {brake_held}", *brake, *caution)
    if brake:
        return Advisory.BRAKE, tuple(brake + caution)
    if caution:
        return Advisory.CAUTION, tuple(caution)
    return Advisory.CLEAR, (f"risk {risk:.3g}, P(collision) {p_collision:.3g}",)
