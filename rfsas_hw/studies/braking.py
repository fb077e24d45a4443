"""The paper's braking case: a vehicle approaching the intersection brakes after the warning.

A pedestrian with a phone stands in the vehicle's lane at the intersection.
A roadside unit on the north-west corner and the vehicle's own sensor hear
the phone; the twin's frames go through the real pipeline (DF, hashing) and
the backend's triangulation locates the obstacle with a covariance
(:mod:`rfsas_hw.studies.locate`). The vehicle comes north at ``speed_mps`` from
``start_m`` (its centre, metres south of the intersection centre when
negative), keeps its speed for the reaction delay ``τ_D`` (scan, message,
computation), then brakes at 0.47 g.

Outcome (method.md §7, with the backend's functions):

- ``stopped``: the front bumper stops short of the pedestrian;
- ``impact_speed_mps``: ``√(u² − 2·a_b·x_b)`` with ``x_b`` the braking distance
  left after the delay, 0 when it stops;
- ``p_collision``: the probability that the box the vehicle sweeps until it
  comes to rest overlaps the pedestrian's box, from the located position and
  covariance and the vehicle's own position error (3 m along, 1 m across);
- ``p_fatality``: Rosen's ``P_f`` at the impact speed; ``risk = P_coll · P_f``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.backend import Triangulation
from rfsas_hw.backend.collision import (
    THREAT_SIZES,
    VEHICLE_SIZE,
    collision_probability_batch,
    heading_covariance,
)
from rfsas_hw.backend.risk import BRAKE_DECEL_MPS2, fatality_risk, impact_speed
from rfsas_hw.errors import SimulationError
from rfsas_hw.outpaths import save_figure
from rfsas_hw.studies.locate import locate, run_pipelines
from rfsas_hw.twin.scenario import Detail, Scenario, scenario_from_mapping
from rfsas_hw.twin.world import World

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class BrakingCase:
    """Inputs of the braking case."""

    speed_mps: float = 20.0
    """Initial speed, m/s."""
    start_m: float = -100.0
    """Vehicle centre at t = 0, metres north of the intersection centre (negative: south)."""
    delay_s: float = 1.5
    """Reaction delay τ_D before braking starts, seconds."""
    decel_mps2: float = BRAKE_DECEL_MPS2
    """Braking deceleration, m/s² (0.47 g)."""
    obstacle_xy: tuple[float, float] = (1.75, 0.0)
    """Where the pedestrian stands, metres (in the northbound lane)."""
    lane_x_m: float = 1.75
    """East coordinate of the vehicle's lane centre, metres."""
    observe_s: float = 1.0
    """Bearings from the first ``observe_s`` seconds locate the pedestrian."""
    detail: Detail = "high"
    """Level of detail of the twin."""
    seed: int = 0
    """Scenario seed."""

    def __post_init__(self) -> None:
        if not self.speed_mps > 0:
            raise ValueError("speed must be positive (m/s)")
        if self.delay_s < 0 or self.observe_s <= 0:
            raise ValueError("delay must be >= 0 s and observe_s > 0 s")
        if self.start_m >= self.obstacle_xy[1]:
            raise ValueError("the vehicle must start south of the obstacle")


@dataclass
class BrakingResult:
    """Outcome of :func:`run_braking` plus its time series."""

    case: BrakingCase
    """The inputs."""
    stopped: bool
    """True when the vehicle stops before reaching the pedestrian."""
    impact_speed_mps: float
    """Speed at contact, m/s (0 when it stops)."""
    p_collision: float
    """Probability that the swept path overlaps the located pedestrian."""
    p_fatality: float
    """Rosen's fatality probability at the impact speed."""
    risk: float
    """``p_collision · p_fatality``."""
    gap_at_rest_m: float
    """Front bumper to pedestrian when stopped, metres (negative: the distance it would
    have needed beyond the contact point)."""
    fix: Triangulation
    """The located pedestrian (position, covariance, status)."""
    obstacle_xy: Array
    """True pedestrian position, metres."""
    t_s: Array
    """Time axis, seconds."""
    front_gap_m: Array
    """Front bumper to pedestrian over time, metres."""
    speed_mps: Array
    """Speed over time, m/s."""
    p_collision_t: Array
    """Overlap probability of the box swept up to each time with the located pedestrian."""

    def summary(self) -> dict[str, Any]:
        """The JSON-friendly outcome (``stopped``, ``impact_speed_mps``, ``p_collision``,
        ``p_fatality``, ``risk`` and context)."""
        cov = self.fix.covariance
        return {
            "stopped": self.stopped,
            "impact_speed_mps": round(self.impact_speed_mps, 6),
            "p_collision": round(self.p_collision, 6),
            "p_fatality": round(self.p_fatality, 6),
            "risk": round(self.risk, 6),
            "speed_mps": self.case.speed_mps,
            "start_m": self.case.start_m,
            "delay_s": self.case.delay_s,
            "gap_at_rest_m": round(self.gap_at_rest_m, 3),
            "fix_xy_m": [round(float(v), 3) for v in self.fix.position],
            "fix_sigma_m": [
                round(float(np.sqrt(max(cov[0, 0], 0))), 3),
                round(float(np.sqrt(max(cov[1, 1], 0))), 3),
            ],
            "fix_status": self.fix.status.name.lower(),
            "obstacle_xy_m": [float(v) for v in self.obstacle_xy],
        }


def braking_scenario(case: BrakingCase) -> Scenario:
    """The twin of the braking case: pedestrian with phone, roadside unit, vehicle sensor."""
    ox, oy = case.obstacle_xy
    duration = max(case.observe_s, 0.1) + 0.05
    data: dict[str, Any] = {
        "version": 1,
        "name": "braking-case",
        "seed": case.seed,
        "duration_s": duration,
        "detail": case.detail,
        "ego": "vehicle",
        "intersection": {
            "buildings": [
                {
                    "name": "south-east",
                    "x_min_m": 10,
                    "x_max_m": 60,
                    "y_min_m": -60,
                    "y_max_m": -10,
                },
                {
                    "name": "north-west",
                    "x_min_m": -60,
                    "x_max_m": -10,
                    "y_min_m": 10,
                    "y_max_m": 60,
                },
            ]
        },
        "rf": {"fading": "rician", "rician_k_db": 10, "fading_correlation": 0.95},
        "movers": [
            {"id": "pedestrian", "kind": "pedestrian", "waypoints": [{"x_m": ox, "y_m": oy}]},
            {
                "id": "vehicle",
                "kind": "vehicle",
                "waypoints": [
                    {"x_m": case.lane_x_m, "y_m": case.start_m, "speed_mps": case.speed_mps},
                    {"x_m": case.lane_x_m, "y_m": case.start_m + case.speed_mps * duration},
                ],
            },
        ],
        "emitters": [
            {
                "id": "phone",
                "mac": "3c:22:fb:4e:91:07",
                "tech": "wifi",
                "tx_power_dbm": 20,
                "carried_by": "pedestrian",
                "traffic": [
                    {"model": "data-bursts", "channels": [6], "interval_s": 0.05, "burst_frames": 3}
                ],
            }
        ],
        "sensors": [
            {
                "id": "rsu",
                "kind": "roadside",
                "pose": {"x_m": -9.0, "y_m": 9.0, "heading_deg": 130.0},
                "antenna": {"squint_deg": 30, "beamwidth_deg": 60, "chain_offsets_db": [0.8, -0.4]},
            },
            {
                "id": "obu",
                "kind": "on-board",
                "mounted_on": "vehicle",
                "antenna": {"squint_deg": 30, "beamwidth_deg": 60, "chain_offsets_db": [-0.5, 0.3]},
            },
        ],
    }
    return scenario_from_mapping(data, "<braking case>")


def locate_obstacle(case: BrakingCase) -> tuple[Triangulation, Array]:
    """The pedestrian's fix from the twin and the real pipeline, and its true position.

    Raises:
        SimulationError: fewer than two sensors heard the phone.
    """
    world = World(braking_scenario(case))
    bearings = run_pipelines(world)
    fix = locate(world, "phone", bearings, t_start_s=0.0, t_end_s=case.observe_s)
    return fix, np.asarray(case.obstacle_xy, np.float64)


def run_braking(case: BrakingCase, *, dt_s: float = 0.01) -> BrakingResult:
    """Locate the pedestrian, brake after the delay, and judge the outcome.

    Raises:
        SimulationError: the pedestrian could not be located.
    """
    fix, truth = locate_obstacle(case)
    if not np.all(np.isfinite(fix.position)):
        raise SimulationError(f"the pedestrian could not be located: {fix.reason}")
    u, a, tau = case.speed_mps, case.decel_mps2, case.delay_s
    length = VEHICLE_SIZE[0]
    ped = THREAT_SIZES["pedestrian"]
    # distance from the front bumper to the pedestrian's near edge at t = 0
    gap0 = (truth[1] - ped[0] / 2) - (case.start_m + length / 2)
    v_impact = float(impact_speed(u, gap0, a, reaction_s=tau))
    stop_dist = u * tau + u * u / (2 * a)
    stopped = stop_dist <= gap0
    t_end = tau + u / a + 0.5
    t = np.arange(0.0, t_end + dt_s / 2, dt_s)
    tb = np.clip(t - tau, 0.0, u / a)
    travelled = u * np.minimum(t, tau) + u * tb - 0.5 * a * tb**2
    speed = np.where(t < tau, u, np.maximum(u - a * (t - tau), 0.0))
    front_gap = gap0 - travelled
    # the box the vehicle sweeps from t = 0 to each time: a pedestrian standing
    # anywhere in it is hit; the located position and both position errors decide
    rear0 = case.start_m - length / 2
    swept_len = length + travelled
    n = len(t)
    p_t = collision_probability_batch(
        np.column_stack([np.full(n, case.lane_x_m), rear0 + swept_len / 2]),
        np.zeros(n),
        np.broadcast_to(heading_covariance(0.0), (n, 2, 2)),
        np.column_stack([swept_len, np.full(n, VEHICLE_SIZE[1])]),
        np.broadcast_to(fix.position, (n, 2)),
        np.zeros(n),
        np.broadcast_to(np.asarray(fix.covariance, np.float64), (n, 2, 2)),
        ped,
    )
    p_coll = float(p_t[-1])
    p_f = float(fatality_risk(v_impact))
    return BrakingResult(
        case=case,
        stopped=bool(stopped),
        impact_speed_mps=v_impact,
        p_collision=p_coll,
        p_fatality=p_f,
        risk=p_coll * p_f,
        gap_at_rest_m=float(gap0 - stop_dist),
        fix=fix,
        obstacle_xy=truth,
        t_s=t,
        front_gap_m=front_gap,
        speed_mps=speed,
        p_collision_t=np.asarray(p_t, np.float64),
    )


def plot_braking(result: BrakingResult, path: str) -> None:
    """Gap to the pedestrian, speed and overlap probability over time, as a PNG.

    Raises:
        SimulationError: matplotlib is missing or the file cannot be written.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as err:
        raise SimulationError("plotting needs matplotlib: pip install 'rfsas-hw[plot]'") from err
    c = result.case
    fig, axes = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True)
    t = result.t_s
    for ax in axes:
        ax.axvspan(0, min(c.delay_s, t[-1]), color="0.9", label="reaction delay")
        ax.grid(alpha=0.3)
    axes[0].plot(t, result.front_gap_m, color="tab:blue")
    axes[0].axhline(0, color="tab:red", lw=1)
    axes[0].set_ylabel("gap to pedestrian (m)")
    axes[1].plot(t, result.speed_mps, color="tab:green")
    axes[1].set_ylabel("speed (m/s)")
    axes[2].plot(t, result.p_collision_t, color="tab:orange")
    axes[2].set_ylabel("P(path hits pedestrian)")
    axes[2].set_xlabel("time since the warning-worthy moment (s)")
    axes[0].legend(loc="upper right")
    outcome = (
        f"stops {result.gap_at_rest_m:.1f} m short"
        if result.stopped
        else f"impact at {result.impact_speed_mps * 3.6:.0f} km/h"
    )
    fig.suptitle(
        f"{c.speed_mps:g} m/s from {c.start_m:g} m, delay {c.delay_s:g} s: {outcome}\n"
        f"P_coll {result.p_collision:.3f}, P_f {result.p_fatality:.3f}, risk {result.risk:.4f}"
    )
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
