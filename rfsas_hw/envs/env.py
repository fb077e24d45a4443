"""``rfsas/Intersection-v0``: learning to brake for hidden cross traffic (method.md §10).

A car drives north towards the intersection, its front bumper starting
``start_distance_m`` (100 m) south of the centre. A cyclist with a phone rides
east along the cross street, hidden from the car by the south-west building
until shortly before the conflict. The RF-SAS sensors hear the phone earlier,
and after the reaction delay the car's backend receives a *warning*: from then
on it locates the cyclist (at the configured level of detail,
:mod:`rfsas_hw.envs.threat`), tracks them and estimates the risk
``P_collision · P_f(v_impact)`` (Rosen's pedestrian curve stands in for any
vulnerable road user).

Observation (``float32``, shape (7,), every entry in [0, 1]):

0. distance of the front bumper to the intersection centre / ``start_distance_m``
1. speed / ``max_speed_mps``
2. estimated risk
3. ``(log10(max(risk, 1e-4)) + 4) / 4``: the risk on a log scale
4. estimated collision probability
5. 1 once the warning has arrived, else 0
6. the episode clock, ``t / (max_steps · dt_s)``: a car that has stopped sees time
   pass (its other entries stay the same while it waits, and the estimated risk
   of a car holding zero speed is 0 whether or not the crosser has passed), and
   the time left before the episode is truncated is part of the state
7. (only with ``prior.observe``) the RF activity prior ahead:
   ``1 − exp(−density/scale)`` of the expected RF-detected road users per hour
   along the next ``prior.horizon_m`` of the lane (:mod:`rfsas_hw.envs.history`)

With ``observe_drive_on`` two more entries follow (after the prior, if any):
the risk of driving on, i.e. the backend's assessment (the same
:func:`~rfsas_hw.envs.threat.assess_risk` as entries 2–4) for the car where it
is now but moving at the episode's initial speed, as the log-scale risk of
entry 3 and the collision probability. A car that stopped for a warning sees
this stay high while the crosser is still ahead of it and fall to 0 once the
crosser has passed; its own estimated risk (entries 2–4) is 0 in both cases.

Actions (``Discrete(3)``): 0 coast (a = 0), 1 brake (−4.7 m/s²),
2 accelerate (+2 m/s²); the speed is clamped to [0, ``max_speed_mps``] and
never goes negative.

Reward: see :class:`~rfsas_hw.envs.envconfig.RewardConfig` (method.md §10 by
default: +1 for braking while the estimated risk is above the threshold, +1
for accelerating while it is not).

The episode terminates when the front bumper reaches ``end_y_m`` (by default
5 m past the intersection centre, when the car has cleared the cross street's
near lane) or when the car hits the cyclist; it is truncated after
``max_steps`` (a *timeout*: the car never crossed). Stopping does not end the
episode: a car that stops short of the crossing has to drive on (the cyclist
keeps riding, and time passes while it waits), so a stop is never an exit
that counts as safe. ``reset(options={"reaction_distance_m": d})`` fixes the
warning: it arrives when a car holding its initial speed would be ``d``
metres from the centre. Without it, ``reset`` places the warning from the
time to first intercept of the phone plus the reaction delay, and never later
than the moment the buildings stop hiding the cyclist plus the reaction delay.

With ``scenario.kind: corners`` each episode is at a quiet or a busy blind
corner (:class:`~rfsas_hw.envs.envconfig.ScenarioConfig`): busy corners have
a history of crossings and produce more late crossers and fewer empty
episodes. Further ``reset`` options fix the draw: ``corner`` (``quiet`` or
``busy``), ``crosser`` (False: nobody crosses, no warning) and ``heard``
(False: the crosser is there but never heard, no warning).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from rfsas_hw.backend.collision import THREAT_SIZES
from rfsas_hw.backend.risk import fatality_risk
from rfsas_hw.envs.envconfig import CORNERS, EnvConfig, env_config_from_mapping
from rfsas_hw.envs.threat import (
    NO_RISK,
    Assessment,
    Fix,
    SensorPoses,
    ThreatTrack,
    assess_risk,
    make_locator,
)
from rfsas_hw.errors import ConfigError
from rfsas_hw.records import Pose
from rfsas_hw.twin.rfworld import building_array, segment_crossings

Array = npt.NDArray[np.float64]
ObsArray = npt.NDArray[np.float32]

COAST, BRAKE, ACCELERATE = 0, 1, 2
ACTION_NAMES = ("coast", "brake", "accelerate")
"""Names of the actions, by index."""
OBS_SIZE = 7
"""Observation entries without the prior (one more with ``prior.observe``)."""
DRIVE_ON_SIZE = 2
"""Entries added by ``observe_drive_on``."""
_OPTIONS = ("reaction_distance_m", "corner", "crosser", "heard", "hour")
_ABSENT_ARRIVAL_S = 1e6
"""Arrival time of a crosser that is not there: far beyond any episode."""
_RISK_LOG_FLOOR = 1e-4
_SUBSTEPS = 4
"""Collision checks per step (the car moves at most 2 m per 0.1 s step)."""


def observation_size(config: EnvConfig) -> int:
    """Entries of the observation under ``config`` (prior and drive-on entries included)."""
    return OBS_SIZE + int(config.prior.observe) + DRIVE_ON_SIZE * int(config.observe_drive_on)


def _log_risk(risk: float) -> float:
    """A risk on the observation's log scale: 0 at 1e-4 and below, 1 at 1."""
    return (math.log10(max(risk, _RISK_LOG_FLOOR)) + 4.0) / 4.0


@dataclass(frozen=True, slots=True)
class Episode:
    """What ``reset`` drew for one episode."""

    initial_speed_mps: float
    """Speed of the car at reset, m/s."""
    obstacle_speed_mps: float
    """Speed of the obstacle along its path, m/s."""
    obstacle_arrival_s: float
    """Time its centre reaches the car's lane centre, seconds after reset."""
    warning_s: float
    """Time the warning reaches the car, seconds after reset."""
    reaction_distance_m: float
    """Distance from the centre at which a car holding its initial speed gets the warning."""
    los_s: float
    """Time the buildings stop hiding the obstacle from a car holding its initial speed."""
    corner: str = "busy"
    """``quiet`` or ``busy`` (``single`` scenarios are at a busy corner)."""
    crosser: bool = True
    """Whether anybody crosses."""
    heard: bool = True
    """Whether the crosser's phone is heard (a warning comes)."""
    late: bool = True
    """Whether the crosser was drawn as late (``corners``; ``single``: always True)."""
    hour: int | None = None
    """UTC hour of day of the episode, for an hour-of-day prior (None: not used)."""


class IntersectionEnv(gym.Env[ObsArray, np.int64]):
    """The car, the hidden cyclist and the RF-SAS warning (see the module docstring).

    Args:
        config: an :class:`EnvConfig`, a mapping of its fields, or None for the defaults.
        render_mode: ``None``, ``"human"`` (pygame window) or ``"rgb_array"``.

    Raises:
        ConfigError: an invalid configuration or render mode.
    """

    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array"], "render_fps": 10}  # noqa: RUF012

    def __init__(
        self,
        config: EnvConfig | Mapping[str, Any] | None = None,
        render_mode: str | None = None,
    ) -> None:
        super().__init__()
        if config is None:
            config = EnvConfig()
        elif not isinstance(config, EnvConfig):
            config = env_config_from_mapping(config)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ConfigError(
                f"render_mode {render_mode!r} is not one of human, rgb_array (or None)"
            )
        self.config = config
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": max(1, round(1.0 / config.dt_s))}
        self.action_space = spaces.Discrete(3)
        size = observation_size(config)
        self.observation_space = spaces.Box(0.0, 1.0, shape=(size,), dtype=np.float32)
        self._profiles: dict[str, Any] = {}
        if config.prior.observe:
            from rfsas_hw.envs.history import prior_profile

            corners = CORNERS if config.scenario.kind == "corners" else ("busy",)
            self._profiles = {c: prior_profile(config, c) for c in corners}
        self._locator = make_locator(config)
        self._rects = building_array(config.buildings)
        self._renderer: Any = None
        self._reset_state()

    # -- state -----------------------------------------------------------------------

    def _reset_state(self) -> None:
        v = self.config.vehicle
        self.t_s = 0.0
        self.steps = 0
        self.front_y_m = -v.start_distance_m
        self.speed_mps = v.initial_speed_mps[1]
        self.episode: Episode | None = None
        self.track = ThreatTrack(self._locator, self.config.sensing)
        self.assessment: Assessment = NO_RISK
        self.drive_on: Assessment = NO_RISK
        self.last_fix: Fix | None = None
        self.warned = False
        self.collided = False
        self.impact_speed_mps = 0.0
        self.last_action: int | None = None
        self._last_frame_s = -math.inf

    @property
    def distance_m(self) -> float:
        """Distance of the front bumper to the intersection centre, metres (≥ 0)."""
        return max(-self.front_y_m, 0.0)

    def vehicle_xy(self) -> tuple[float, float]:
        """Centre of the car, metres."""
        return self.config.vehicle.lane_x_m, self.front_y_m - self.config.vehicle.length_m / 2

    def obstacle_xy(self, t_s: float | None = None) -> Array:
        """True position of the obstacle at ``t_s`` (default: now), metres."""
        if self.episode is None:
            raise RuntimeError("call reset() first")
        t = self.t_s if t_s is None else t_s
        return np.array([self._obstacle_x(t), self.config.obstacle.crossing_y_m])

    def _obstacle_x(self, t_s: Any) -> Any:
        """East coordinate of the obstacle at ``t_s`` (float or array), metres."""
        assert self.episode is not None
        e = self.episode
        return self._path_x(t_s, e.obstacle_speed_mps, e.obstacle_arrival_s)

    def _path_x(self, t_s: Any, speed_mps: float, arrival_s: float) -> Any:
        """East coordinate at ``t_s`` of an obstacle reaching the car's lane at ``arrival_s``."""
        sign = 1.0 if self.config.obstacle.direction == "east" else -1.0
        return self.config.vehicle.lane_x_m + sign * speed_mps * (t_s - arrival_s)

    def sensor_poses(self) -> SensorPoses:
        """Poses of the roadside units and the on-board unit now."""
        s = self.config.sensing
        x, _ = self.vehicle_xy()
        return SensorPoses(
            roadside=tuple(Pose(*p) for p in s.roadside),
            obu=Pose(x, self.front_y_m, s.obu_heading_offset_deg % 360.0),
        )

    # -- reset -------------------------------------------------------------------------

    def _los_s(self, u0: float, speed_mps: float, arrival_s: float) -> float:
        """First time the front of a car holding ``u0`` sees the obstacle past the buildings."""
        c = self.config
        t = np.arange(0.0, c.vehicle.start_distance_m / u0 + c.dt_s, c.dt_s / 4)
        eyes = np.stack(
            [np.full(len(t), c.vehicle.lane_x_m), u0 * t - c.vehicle.start_distance_m], 1
        )
        target = np.stack(
            [self._path_x(t, speed_mps, arrival_s), np.full(len(t), c.obstacle.crossing_y_m)],
            axis=1,
        )
        blocked = segment_crossings(eyes, target, self._rects).any(axis=1)
        clear = np.flatnonzero(~blocked)
        return float(t[clear[0]]) if len(clear) else float(t[-1])

    def _draw_corner(
        self, options: Mapping[str, Any], arrival: float
    ) -> tuple[str, bool, bool, float, bool]:
        """Corner, crosser present, late, the arrival time and whether the crosser's phone
        is heard (``corners`` scenario)."""
        sc = self.config.scenario
        if sc.kind == "single":
            return "busy", True, True, arrival, True
        rng = self.np_random
        # always the same draws, so that an option changes nothing else in the episode
        busy = bool(rng.uniform() < sc.busy_fraction)
        u_empty, u_late = float(rng.uniform()), float(rng.uniform())
        u_arrival = float(rng.uniform())
        heard = float(rng.uniform()) < sc.heard_fraction
        corner = str(options.get("corner", "busy" if busy else "quiet"))
        if corner not in CORNERS:
            raise ConfigError(f"reset options: corner must be quiet or busy, got {corner!r}")
        i = CORNERS.index(corner)
        present = u_empty >= sc.empty_fraction[i]
        late = u_late < sc.late_fraction[i]
        lo, hi = sc.late_arrival_s if late else sc.early_arrival_s
        return corner, present, late, lo + (hi - lo) * u_arrival, heard

    def _draw_episode(self, options: Mapping[str, Any]) -> Episode:
        c = self.config
        rng = self.np_random
        o = c.obstacle
        unknown = set(options) - set(_OPTIONS)
        if unknown:
            raise ConfigError(
                f"reset options: unknown key {sorted(unknown)[0]!r} (known: {', '.join(_OPTIONS)})"
            )
        u0 = float(rng.uniform(*c.vehicle.initial_speed_mps))
        speed = float(rng.uniform(*o.speed_mps))
        arrival = float(rng.uniform(*o.lane_arrival_s))
        intercept = float(rng.uniform(*c.sensing.intercept_s))
        d0 = c.vehicle.start_distance_m
        corner, present, late, arrival, heard = self._draw_corner(options, arrival)
        present = bool(options.get("crosser", present))
        # a warning at a given distance is a heard phone, unless told otherwise
        heard = heard or "reaction_distance_m" in options
        heard = bool(options.get("heard", heard)) and present
        if not present:
            arrival = _ABSENT_ARRIVAL_S
        los = self._los_s(u0, speed, arrival)
        delay = c.sensing.reaction_delay_s
        if "reaction_distance_m" in options:
            try:
                d_r = float(options["reaction_distance_m"])
            except (TypeError, ValueError) as err:
                raise ConfigError(
                    f"reset options: reaction_distance_m must be a number, "
                    f"got {options['reaction_distance_m']!r}"
                ) from err
            if not 0 <= d_r:
                raise ConfigError(f"reset options: reaction_distance_m must be ≥ 0, got {d_r}")
            warning = max(d0 - d_r, 0.0) / u0
        else:
            warning = min(intercept, los) + delay
        reaction = min(max(d0 - u0 * warning, 0.0), d0)
        if not heard:
            warning, reaction = math.inf, math.nan
        hour = self._draw_hour(options)
        return Episode(
            u0, speed, arrival, warning, reaction, los, corner, present, heard, late, hour
        )

    def _draw_hour(self, options: Mapping[str, Any]) -> int | None:
        """The episode's hour of day when the prior depends on it (drawn last, uniformly,
        so that the other draws do not change), else None."""
        if not any(p.hourly for p in self._profiles.values()):
            return None
        if "hour" in options:
            h = options["hour"]
            if isinstance(h, bool) or not isinstance(h, int | np.integer) or not 0 <= h < 24:
                raise ConfigError(f"reset options: hour must be an integer 0–23, got {h!r}")
            return int(h)
        if self.config.prior.hour is not None:
            return self.config.prior.hour
        return int(self.np_random.integers(0, 24))

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsArray, dict[str, Any]]:
        """Start an episode; ``options={"reaction_distance_m": d}`` fixes the warning.

        Other options: ``corner`` (``quiet``/``busy``, ``corners`` scenario only),
        ``crosser`` (False: nobody crosses), ``heard`` (False: no warning), ``hour``
        (UTC hour of day 0–23 for a prior whose history is long enough to be per
        hour; ignored otherwise).

        Raises:
            ConfigError: unknown option, a negative distance, an unknown corner or an
                hour outside 0–23.
        """
        super().reset(seed=seed)
        self._reset_state()
        self.episode = self._draw_episode(options or {})
        self.speed_mps = self.episode.initial_speed_mps
        self._sense()
        if self.render_mode == "human":
            self.render()
        return self._observation(), self._info()

    # -- step --------------------------------------------------------------------------

    def _sense(self) -> None:
        """Warning, measurements and the backend's assessment at the current time."""
        assert self.episode is not None
        if not self.warned and self.t_s + 1e-9 >= self.episode.warning_s:
            self.warned = True
        if not self.warned:
            self.assessment = self.drive_on = NO_RISK
            return
        s = self.config.sensing
        if self.t_s - self._last_frame_s >= s.frame_interval_s - 1e-9:
            self._last_frame_s = self.t_s
            fix = self.track.observe(
                self.t_s, self.obstacle_xy(), self.sensor_poses(), self.np_random
            )
            if fix is not None:
                self.last_fix = fix
        self.assessment = assess_risk(
            self.config, self.t_s, self.front_y_m, self.speed_mps, self.track
        )
        if self.config.observe_drive_on:
            nominal = self.episode.initial_speed_mps
            self.drive_on = (
                self.assessment
                if self.speed_mps == nominal
                else assess_risk(self.config, self.t_s, self.front_y_m, nominal, self.track)
            )

    def _overlap(self, front_y: float, obstacle_x: float) -> bool:
        v = self.config.vehicle
        length, width = THREAT_SIZES[self.config.obstacle.kind]
        # the obstacle travels east or west: its length lies along x
        dx = abs(obstacle_x - v.lane_x_m)
        dy = abs(self.config.obstacle.crossing_y_m - (front_y - v.length_m / 2))
        return dx < (v.width_m + length) / 2 and dy < (v.length_m + width) / 2

    def _move(self, accel: float) -> tuple[float, bool]:
        """Advance the car and the obstacle by one step; distance covered and collision."""
        c = self.config
        dt = c.dt_s / _SUBSTEPS
        covered = 0.0
        for _ in range(_SUBSTEPS):
            u0 = self.speed_mps
            u1 = min(max(u0 + accel * dt, 0.0), c.vehicle.max_speed_mps)
            if accel != 0 and u1 != u0 + accel * dt:
                # clamped within the sub-step: constant acceleration until the limit, then hold
                t_hit = (u1 - u0) / accel
                s = u0 * t_hit + 0.5 * accel * t_hit**2 + u1 * (dt - t_hit)
            else:
                s = 0.5 * (u0 + u1) * dt
            self.front_y_m += s
            covered += s
            self.speed_mps = u1
            self.t_s += dt
            if self._overlap(self.front_y_m, self._obstacle_x(self.t_s)):
                self.collided = True
                self.impact_speed_mps = u1
                break
        return covered, self.collided

    def step(self, action: Any) -> tuple[ObsArray, SupportsFloat, bool, bool, dict[str, Any]]:
        """Apply one action for ``dt_s`` seconds.

        Raises:
            RuntimeError: ``step`` before ``reset`` or after the episode ended.
        """
        if self.episode is None:
            raise RuntimeError("call reset() before step()")
        a = int(action)
        if not self.action_space.contains(a):
            raise ValueError(f"action must be 0 (coast), 1 (brake) or 2 (accelerate), got {action}")
        c = self.config
        seen_risk = self.assessment.risk
        accel = (0.0, -c.vehicle.brake_mps2, c.vehicle.accel_mps2)[a]
        covered, collided = self._move(accel)
        self.steps += 1
        self.last_action = a
        reached = self.front_y_m >= c.end_y_m
        terminated = collided or reached
        truncated = not terminated and self.steps >= c.max_steps
        if not terminated:
            self._sense()
        reward = self._reward(a, seen_risk, covered, timeout=truncated)
        if self.render_mode == "human":
            self.render()
        return self._observation(), reward, terminated, truncated, self._info()

    def _reward(self, action: int, risk: float, covered_m: float, *, timeout: bool) -> float:
        r = self.config.reward
        if r.kind == "method":
            above = risk > self.config.risk_threshold
            return float((action == BRAKE and above) or (action == ACCELERATE and not above))
        progress = r.progress_weight * covered_m / self.config.vehicle.start_distance_m
        realised = self.realised_risk
        cost = r.time_weight * self.config.dt_s + (r.timeout_weight if timeout else 0.0)
        return float(progress - r.risk_weight * realised - cost)

    @property
    def realised_risk(self) -> float:
        """Fatality risk of the collision that happened (0 without one)."""
        if not self.collided:
            return 0.0
        return float(fatality_risk(self.impact_speed_mps))

    # -- observation -----------------------------------------------------------------------

    def _observation(self) -> ObsArray:
        c = self.config
        risk = self.assessment.risk
        obs = np.array(
            [
                self.distance_m / c.vehicle.start_distance_m,
                self.speed_mps / c.vehicle.max_speed_mps,
                risk,
                _log_risk(risk),
                self.assessment.p_collision,
                float(self.warned),
                self.steps / c.max_steps,
            ],
            dtype=np.float32,
        )
        if self._profiles:
            obs = np.append(obs, np.float32(self.prior_ahead))
        if c.observe_drive_on:
            extra = [_log_risk(self.drive_on.risk), self.drive_on.p_collision]
            obs = np.append(obs, np.asarray(extra, np.float32))
        return np.clip(obs, 0.0, 1.0)

    @property
    def prior_ahead(self) -> float:
        """The prior entry of the observation now (0 without ``prior.observe``): the
        episode's corner, at the episode's hour of day when the prior is hourly."""
        if not self._profiles or self.episode is None:
            return 0.0
        prior = self._profiles.get(self.episode.corner, self._profiles.get("busy"))
        return prior(self.front_y_m, self.episode.hour) if prior else 0.0

    def _info(self) -> dict[str, Any]:
        assert self.episode is not None
        return {
            "t_s": self.t_s,
            "distance_m": self.distance_m,
            "speed_mps": self.speed_mps,
            "warned": self.warned,
            "risk": self.assessment.risk,
            "p_collision": self.assessment.p_collision,
            "collision": self.collided,
            "crossed": self.front_y_m >= self.config.end_y_m,
            "impact_speed_mps": self.impact_speed_mps,
            "realised_risk": self.realised_risk,
            # None without a warning (NaN would not compare equal to itself)
            "reaction_distance_m": self.episode.reaction_distance_m if self.episode.heard else None,
            "warning_s": self.episode.warning_s,
            "corner": self.episode.corner,
            "crosser": self.episode.crosser,
            "heard": self.episode.heard,
            "hour": self.episode.hour,
        }

    # -- rendering -----------------------------------------------------------------------

    def render(self) -> npt.NDArray[np.uint8] | None:
        """Draw the current state: a pygame window (``human``) or an RGB array (``rgb_array``).

        Raises:
            MissingDependencyError: pygame is not installed.
        """
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode=...")
            return None
        if self._renderer is None:
            from rfsas_hw.envs.render import Renderer

            self._renderer = Renderer(self.config, self.render_mode, self.metadata["render_fps"])
        frame: npt.NDArray[np.uint8] | None = self._renderer.draw(self)
        return frame

    def close(self) -> None:
        """Close the window, if any."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
