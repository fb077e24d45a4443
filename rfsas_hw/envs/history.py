"""The RF activity prior the environment's car knows: from a file, or a simulated history.

A corner's history is simulated as the backend would have recorded it:
crossers on the cross street arriving as a Poisson process
(``history_rate_per_h``), each located once a second with the ``low``
detail's position error while it crosses, counted by
:class:`~rfsas_hw.backend.prior.ActivityPrior` exactly as a live run's fixes
are. The observation entry is then a function of the car's position only
(a profile along the lane), computed once per configuration and corner.
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from rfsas_hw.backend.prior import ActivityPrior, PriorConfig
from rfsas_hw.envs.envconfig import CORNERS, CornerKind, EnvConfig

__all__ = ["PriorProfile", "corner_history", "prior_profile"]

HISTORY_START_NS = 1_767_225_600_000_000_000
"""2026-01-01T00:00:00Z: when every simulated history starts."""
NS_PER_S = 1_000_000_000
_FIX_INTERVAL_S = 1.0
_OBSERVE_INTERVAL_S = 10.0
_STREET_HALF_LENGTH_M = 60.0
_PROFILE_STEP_M = 0.5

Array = npt.NDArray[np.float64]


def corner_history(config: EnvConfig, corner: CornerKind) -> ActivityPrior:
    """The prior of a corner built from its simulated history (see the module docstring)."""
    sc = config.scenario
    o = config.obstacle
    rate = sc.history_rate_per_h[CORNERS.index(corner)]
    rng = np.random.default_rng([sc.history_seed, CORNERS.index(corner)])
    span_s = sc.history_h * 3600.0
    n = int(rng.poisson(rate * sc.history_h))
    starts = np.sort(rng.uniform(0.0, span_s, n))
    speeds = rng.uniform(*o.speed_mps, n)
    sign = 1.0 if o.direction == "east" else -1.0
    events: list[tuple[float, float, float, str]] = []
    for k in range(n):
        duration = 2 * _STREET_HALF_LENGTH_M / speeds[k]
        t = starts[k] + np.arange(0.0, duration, _FIX_INTERVAL_S)
        x = sign * (-_STREET_HALF_LENGTH_M + speeds[k] * (t - starts[k]))
        noise = config.sensing.low_sigma_m * rng.standard_normal((len(t), 2))
        for tk, xk, (ex, ey) in zip(t, x, noise, strict=True):
            events.append((float(tk), float(xk + ex), o.crossing_y_m + float(ey), f"h{k}"))
    events.sort()
    prior = ActivityPrior(PriorConfig(tile_m=config.prior.tile_m))
    ticks = np.arange(0.0, span_s + _OBSERVE_INTERVAL_S, _OBSERVE_INTERVAL_S)
    i = 0
    for tick in ticks:
        while i < len(events) and events[i][0] <= tick:
            t, x, y, who = events[i]
            prior.add_fix(HISTORY_START_NS + round(t * NS_PER_S), x, y, who)
            i += 1
        prior.observe(HISTORY_START_NS + round(tick * NS_PER_S))
    prior.close()
    return prior


class PriorProfile:
    """The observation entry along the lane for one corner: a function of the car's front
    and, once the prior's history is long enough (:attr:`ActivityPrior.hourly`), of the
    hour of day.

    Args:
        prior: the activity prior of the site.
        config: the environment (lane, start, end and the prior settings).
    """

    def __init__(self, prior: ActivityPrior, config: EnvConfig) -> None:
        p = config.prior
        v = config.vehicle
        self.front_y = np.arange(
            -v.start_distance_m - 5.0, config.end_y_m + 5.0 + _PROFILE_STEP_M, _PROFILE_STEP_M
        )
        self.hourly = prior.hourly
        """Whether the profile depends on the hour of day (one row per hour)."""
        hours: list[int | None] = [None, *range(24)] if self.hourly else [None]
        density = np.array(
            [
                [
                    prior.density_ahead(
                        [[v.lane_x_m, y], [v.lane_x_m, y + p.horizon_m]], p.corridor_m, hour=h
                    )
                    for y in self.front_y
                ]
                for h in hours
            ]
        )
        self.density_per_h: Array = density
        """Road users per hour ahead: (hours, positions); row 0 pooled over the hours,
        rows 1–24 the hours of day 0–23 when :attr:`hourly`."""
        self.value: Array = 1.0 - np.exp(-density / p.scale_per_h)

    def __call__(self, front_y_m: float, hour: int | None = None) -> float:
        """Observation entry (in [0, 1]) with the front bumper at ``front_y_m`` at the UTC
        ``hour`` of day (ignored, and may be None, unless :attr:`hourly`)."""
        row = self.value[1 + hour % 24] if self.hourly and hour is not None else self.value[0]
        return float(np.interp(front_y_m, self.front_y, row))


@functools.lru_cache(maxsize=8)
def prior_profile(config: EnvConfig, corner: CornerKind) -> PriorProfile:
    """The profile of ``corner`` (cached per configuration).

    Raises:
        DataFormatError: ``prior.path`` cannot be read as an activity prior.
    """
    if config.prior.path is not None:
        return PriorProfile(ActivityPrior.load(config.prior.path), config)
    return PriorProfile(corner_history(config, corner), config)
