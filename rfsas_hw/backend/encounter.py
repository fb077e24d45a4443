"""One threat against the vehicle: closest approach, P(collision), impact speed, risk, advisory.

Both move at constant velocity from their current states. The closest approach
is at ``t* = −r·w/|w|²`` (relative position ``r``, relative velocity ``w``),
clipped to ``[0, horizon_s]``. At ``t*`` the vehicle box (default position
error 3 m along, 1 m across its heading) and the threat box (its track's
position covariance propagated to ``t*``) give P(collision) by the exact
Gaussian integral. The impact speed assumes the vehicle brakes now (after the
reaction delay) and that the threat sits where it will be at ``t*``: the
distance to contact is the along-track gap between the vehicle's front and the
near side of the threat's box.

A brake can be held back to caution by the thresholds
(:class:`~rfsas_hw.backend.risk.AdvisoryThresholds`): a track with too few
fixes since it (re)started, or — with ``brake_needs_path`` — a threat neither
in the vehicle's path (lateral offset ``d`` of its centre from the path's
centre line within ``h``, the sum of the two boxes' half-widths, the threat's
larger side for its box; with ``brake_position_sigmas`` ``k_d``, within
``h − k_d·σ_d``, ``σ_d`` the one-sigma of ``d``) nor moving into it with evidence: with ``w`` its
speed towards the centre line and ``σ_w`` that speed's one-sigma (from the
velocity covariance), ``w − k·σ_w > 0`` and ``|d| − h ≤ (w − k·σ_w)·t*``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import math_rad_to_compass
from rfsas_hw.backend.collision import (
    Size,
    collision_probability_batch,
    threat_box,
)
from rfsas_hw.backend.risk import (
    BRAKE_DECEL_MPS2,
    DEFAULT_THRESHOLDS,
    Advisory,
    AdvisoryThresholds,
    advise,
    fatality_risk_of,
    impact_speed_of,
    stopping_distance_of,
)
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.errors import BackendError

Array = npt.NDArray[np.float64]

__all__ = ["Encounter", "EncounterConfig", "assess_encounter", "assess_encounters", "assess_pairs"]

MOVING_MPS = 0.3
"""Below this speed a threat's heading is taken as north (its velocity direction is noise)."""


@dataclass(frozen=True, slots=True)
class EncounterConfig:
    """How a threat is judged.

    Args:
        threat_kind: box of the threat: ``pedestrian``, ``cyclist`` or ``vehicle``.
        horizon_s: latest closest-approach time considered, seconds.
        reaction_s: total reaction delay (scan + message + computation), seconds.
        decel_mps2: braking deceleration, m/s².
        thresholds: advisory thresholds.

    Raises:
        BackendError: unknown kind or a value out of range.
    """

    threat_kind: str = "pedestrian"
    horizon_s: float = 10.0
    reaction_s: float = 0.0
    decel_mps2: float = BRAKE_DECEL_MPS2
    thresholds: AdvisoryThresholds = field(default_factory=lambda: DEFAULT_THRESHOLDS)

    def __post_init__(self) -> None:
        threat_box(self.threat_kind)
        if not self.horizon_s >= 0:
            raise BackendError(f"horizon_s must be ≥ 0, got {self.horizon_s}")
        if not self.reaction_s >= 0:
            raise BackendError(f"reaction_s must be ≥ 0, got {self.reaction_s}")
        if not self.decel_mps2 > 0:
            raise BackendError(f"decel_mps2 must be > 0, got {self.decel_mps2}")

    @property
    def threat_size(self) -> Size:
        """``(length_m, width_m)`` of the threat box."""
        return threat_box(self.threat_kind)


@dataclass(frozen=True, slots=True)
class Encounter:
    """The judgement of one threat."""

    p_collision: float
    """Probability that the boxes overlap at closest approach."""
    t_closest_s: float
    """Time to closest approach from the states' time, seconds."""
    distance_to_contact_m: float
    """Along-track gap from the vehicle's front to the threat's box, metres (inf: behind)."""
    stopping_distance_m: float
    """Distance the vehicle needs to stop, reaction included, metres."""
    impact_speed_mps: float
    """Speed at contact when braking now, m/s (0: stops in time)."""
    fatality_risk: float
    """Rosen's P_f at the impact speed."""
    risk: float
    """``p_collision · fatality_risk``."""
    advisory: Advisory
    """Brake, caution or clear."""
    reasons: tuple[str, ...]
    """Why, with numbers."""


def assess_encounter(
    vehicle: VehicleState,
    threat_state: Array,
    threat_cov: Array,
    config: EncounterConfig | None = None,
    *,
    fix_ok: bool = True,
    fix_reason: str = "",
    link_alarm: bool = False,
    track_fixes: int | None = None,
) -> Encounter:
    """Judge one threat against the vehicle: :func:`assess_encounters` of one row.

    Args:
        vehicle: the vehicle's state.
        threat_state: ``[x_m, y_m, vx_mps, vy_mps]`` at the vehicle state's time.
        threat_cov: 4×4 covariance of ``threat_state``.
        config: threat kind, horizon, reaction delay, thresholds.
        fix_ok: whether the threat's latest fix was trustworthy.
        fix_reason: why not.
        link_alarm: whether the link's latency watch is alarmed.
        track_fixes: fixes the threat's track took since it (re)started (None: enough).

    Raises:
        BackendError: a state or covariance of the wrong shape or not finite.
    """
    x = np.asarray(threat_state, np.float64)
    P = np.asarray(threat_cov, np.float64)
    if x.shape != (4,) or P.shape != (4, 4) or not (np.isfinite(x).all() and np.isfinite(P).all()):
        raise BackendError("threat state must be a finite [x, y, vx, vy] with a 4×4 covariance")
    return assess_encounters(
        vehicle,
        x[None],
        P[None],
        config,
        fix_ok=[fix_ok],
        fix_reason=[fix_reason],
        link_alarm=link_alarm,
        track_fixes=None if track_fixes is None else [track_fixes],
    )[0]


def assess_encounters(
    vehicle: VehicleState,
    threat_states: Array,
    threat_covs: Array,
    config: EncounterConfig | None = None,
    *,
    fix_ok: Sequence[bool] | None = None,
    fix_reason: Sequence[str] | None = None,
    link_alarm: bool = False,
    track_fixes: Sequence[int] | None = None,
) -> list[Encounter]:
    """Judge ``B`` threats against one vehicle: :func:`assess_pairs` with that vehicle
    in every pair.

    Args:
        vehicle: the vehicle's state.
        threat_states: ``[x_m, y_m, vx_mps, vy_mps]`` per threat, shape (B, 4).
        threat_covs: 4×4 covariance per threat, shape (B, 4, 4).
        config: threat kind, horizon, reaction delay, thresholds.
        fix_ok: per threat, whether its latest fix was trustworthy (default: all).
        fix_reason: per threat, why not (default: empty).
        link_alarm: whether the link's latency watch is alarmed.
        track_fixes: per threat, fixes its track took since it (re)started
            (default: enough for any brake).

    Raises:
        BackendError: as :func:`assess_pairs`.
    """
    x = np.asarray(threat_states, np.float64)
    return assess_pairs(
        (vehicle,),
        np.zeros(len(x), np.int64),
        x,
        threat_covs,
        config,
        fix_ok=fix_ok,
        fix_reason=fix_reason,
        link_alarm=link_alarm,
        track_fixes=track_fixes,
    )


def assess_pairs(
    vehicles: Sequence[VehicleState],
    vehicle_of: Sequence[int] | npt.NDArray[np.int64],
    threat_states: Array,
    threat_covs: Array,
    config: EncounterConfig | None = None,
    *,
    fix_ok: Sequence[bool] | None = None,
    fix_reason: Sequence[str] | None = None,
    link_alarm: bool = False,
    track_fixes: Sequence[int] | None = None,
) -> list[Encounter]:
    """Judge ``B`` (vehicle, threat) pairs at once, one array operation per stage: threat
    ``b`` against ``vehicles[vehicle_of[b]]`` (a backend serving many vehicles judges
    all of them in one call; a pair gets what it gets alone).

    Args:
        vehicles: the vehicles' states.
        vehicle_of: per threat, the index of its vehicle in ``vehicles``, shape (B,).
        threat_states: ``[x_m, y_m, vx_mps, vy_mps]`` per threat, shape (B, 4).
        threat_covs: 4×4 covariance per threat, shape (B, 4, 4).
        config: threat kind, horizon, reaction delay, thresholds.
        fix_ok: per threat, whether its latest fix was trustworthy (default: all).
        fix_reason: per threat, why not (default: empty).
        link_alarm: whether the link's latency watch is alarmed.
        track_fixes: per threat, fixes its track took since it (re)started
            (default: enough for any brake).

    Raises:
        BackendError: states or covariances of the wrong shape or not finite
            (the first bad row is named), per-threat lists of the wrong length, or a
            vehicle index outside ``vehicles``.
    """
    cfg = config or EncounterConfig()
    x = np.asarray(threat_states, np.float64)
    P = np.asarray(threat_covs, np.float64)
    if x.ndim != 2 or x.shape[1:] != (4,) or P.shape != (len(x), 4, 4):
        raise BackendError(
            f"threat states must have shape (B, 4) and covariances (B, 4, 4), "
            f"got {x.shape} and {P.shape}"
        )
    B = len(x)
    owner = np.asarray(vehicle_of, np.int64)
    oks = [True] * B if fix_ok is None else [bool(v) for v in fix_ok]
    whys = [""] * B if fix_reason is None else list(fix_reason)
    fixes = None if track_fixes is None else [int(n) for n in track_fixes]
    if len(oks) != B or len(whys) != B or (fixes is not None and len(fixes) != B):
        raise BackendError(
            f"fix_ok, fix_reason and track_fixes must have one entry per threat ({B})"
        )
    if owner.shape != (B,):
        raise BackendError(f"vehicle_of must have one entry per threat ({B}), got {owner.shape}")
    if B == 0:
        return []
    V = len(vehicles)
    if int(owner.min()) < 0 or int(owner.max()) >= V:
        raise BackendError(f"vehicle_of must index the {V} vehicle(s)")
    from rfsas_hw.backend import _encounter_kernel as k

    # per vehicle: position, unit heading, size, speed, heading, position covariance
    u_hat = np.array([v.direction for v in vehicles])
    speed = np.array([v.speed_mps for v in vehicles])
    size = np.array([v.size for v in vehicles], np.float64)
    heading = np.array([v.heading_deg for v in vehicles], np.float64)
    size_t = cfg.threat_size
    (
        bad,
        t_star,
        cov,
        vehicle_xy,
        threat_xy,
        moving,
        heading_rad,
        contact,
        gap,
        gap_sigma,
        towards,
        towards_sigma,
        path,
    ) = k.encounter_geometry(
        np.ascontiguousarray(x),
        np.ascontiguousarray(P),
        owner,
        np.array([[v.x_m, v.y_m] for v in vehicles]),
        u_hat * speed[:, None],
        u_hat,
        size,
        cfg.horizon_s,
        size_t[0],
        size_t[1],
        MOVING_MPS,
        cfg.thresholds.brake_path_sigmas,
        cfg.thresholds.brake_position_sigmas,
    )
    if bad >= 0:
        raise BackendError(f"threat {bad}: state and covariance must be finite")
    p_coll = collision_probability_batch(
        vehicle_xy,
        heading[owner],
        np.array([v.covariance for v in vehicles])[owner],
        size[owner],
        threat_xy,
        np.where(moving, math_rad_to_compass(heading_rad), 0.0),
        cov,
        size_t,
    )
    # the inputs are valid by construction (vehicle states, config, kernel): no checks
    d_stop = stopping_distance_of(speed, cfg.decel_mps2, cfg.reaction_s)[owner]
    u = speed[owner]
    ahead = contact < np.inf
    v_imp = np.where(
        ahead,
        impact_speed_of(u, np.where(ahead, contact, 0.0), cfg.decel_mps2, cfg.reaction_s),
        0.0,
    )
    p_f = fatality_risk_of(v_imp)
    risk = p_coll * p_f
    held = _brake_held(cfg, fixes, path, gap, gap_sigma, towards, towards_sigma)
    out = []
    for i, (pc, rk, ct, t_i, v_i, pf_i, ds) in enumerate(
        zip(
            p_coll.tolist(),
            risk.tolist(),
            contact.tolist(),
            t_star.tolist(),
            v_imp.tolist(),
            p_f.tolist(),
            d_stop.tolist(),
            strict=True,
        )
    ):
        advisory, reasons = advise(
            pc,
            rk,
            ct,
            ds,
            fix_ok=oks[i],
            fix_reason=whys[i],
            link_alarm=link_alarm,
            brake_held=held[i],
            thresholds=cfg.thresholds,
        )
        out.append(
            Encounter(
                p_collision=pc,
                t_closest_s=t_i,
                distance_to_contact_m=ct,
                stopping_distance_m=ds,
                impact_speed_mps=v_i,
                fatality_risk=pf_i,
                risk=rk,
                advisory=advisory,
                reasons=reasons,
            )
        )
    return out


def _brake_held(
    cfg: EncounterConfig,
    fixes: list[int] | None,
    path: npt.NDArray[np.bool_],
    gap: Array,
    gap_sigma: Array,
    towards: Array,
    towards_sigma: Array,
) -> list[str]:
    """Per threat, why a brake is not supported (empty: it is); see the module docstring.

    ``path`` says per threat whether it is in the vehicle's path or shows evidence
    of entering it; ``gap`` and its one-sigma ``gap_sigma`` (m), ``towards`` and
    ``towards_sigma`` (m/s) are the numbers that decided it.
    """
    th = cfg.thresholds
    held = [""] * len(path)
    if fixes is not None and th.brake_min_fixes > 1:
        for i, n in enumerate(fixes):
            if n < th.brake_min_fixes:
                held[i] = f"track has {n} fix(es) since it started, < {th.brake_min_fixes}"
    if not th.brake_needs_path:
        return held
    for i in np.flatnonzero(~path).tolist():
        where = (
            f"{gap[i]:.1f} m beside the path"
            if gap[i] > 0 or th.brake_position_sigmas == 0
            else f"{-gap[i]:.1f} ± {gap_sigma[i]:.1f} m inside the path "
            f"(needs {th.brake_position_sigmas:g} sigma inside)"
        )
        why = (
            f"{where}, moving towards it at {towards[i]:.2f} ± "
            f"{towards_sigma[i]:.2f} m/s (needs {th.brake_path_sigmas:g} sigma to reach it)"
        )
        held[i] = f"{held[i]}; {why}" if held[i] else why
    return held
