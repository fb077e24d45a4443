"""A change test on a standing track: has the target left its standing position?

A track whose standing model (:mod:`rfsas_hw.backend.stop_go`) holds most of the
probability believes a start only once the bearings have outweighed that
model's likelihood, and its constant-velocity model then still has to learn the
speed through its acceleration noise. This test looks at the last bearings
directly (Willsky and Jones' generalised likelihood ratio for a jump, here a
ramp):

- every bearing applied to (or gated by) the track is kept with the standing
  model's prediction at its time: its residual ``y_i = wrap(z_i − h_i)`` (rad),
  the gradient ``H_i`` of the predicted reading on the position (rad/m), the
  reading's own variance ``R_i`` (rad²; the bearing update's, censoring at the
  units' edge included), the predicted position ``p_i`` (m) and its covariance
  ``P_i`` (m²), and the standing model's predicted probability ``μ_i``; readings
  older than ``window_s`` before the newest are dropped;
- for each onset ``k`` in the window at which the track believed the target might
  stand (``μ_k ≥ armed_standing_prob``) and with at least ``min_readings``
  readings at or after it, from two sensors or more (one sensor's lines of
  bearing do not fix the range), the readings ``i ≥ k`` are explained by two
  hypotheses around the standing model's position ``p_k`` before reading ``k``
  (``τ_i = t_i − t_k`` in s, linearised:
  ``y_i − H_i·(p_k − p_i) = H_i·(d + τ_i·v) + e_i``, ``e_i ~ N(0, R_i)``):
  **standing**, ``v = 0``; **started at t_k**, ``v`` free. In both the position
  offset ``d`` has the prior ``N(0, P_k)`` (the readings before ``k`` are in it and
  not in the test), and ``v`` the prior ``N(0, speed_sigma_mps²·I)`` (weak: it only
  keeps a direction that the readings do not see, along every line of bearing at
  once, unknown instead of undefined);
- the statistic of onset ``k`` is twice the log of the ratio of the two
  hypotheses' maximised likelihoods (their priors included),
  ``g·J⁻¹·g − g_d·J_d⁻¹·g_d`` (``J``, ``g`` the information and score of
  ``(d, v)``; ``J_d``, ``g_d`` those of ``d`` alone). For
  a target that stands still it is χ² with 2 degrees of freedom at each ``k``
  (``P(> h) = exp(−h/2)``; 1 degree where all lines of bearing are parallel);
  the test fires when the largest over the onsets whose fit knows the velocity to
  ``max_speed_sigma_mps`` or better (the square root of the largest eigenvalue of
  its covariance) reaches ``threshold`` (:class:`StartTestConfig`). A fit that
  knows less would restart the track with a velocity worse than the one it has;
  it is also what a fit linearised too far (a target passing a sensor) gives.

When it fires the window's fit at the best onset gives the target's position at
the newest reading, ``p_k + d̂ + τ_n·v̂``, and velocity ``v̂``, with the fit's
covariance (``J⁻¹`` through the same linear map): the caller restarts the
moving model from it (:mod:`rfsas_hw.backend.bearing_tracking`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from rfsas_hw.backend.tracking import NS_PER_S
from rfsas_hw.errors import BackendError

Array = npt.NDArray[np.float64]

__all__ = ["StartFit", "StartTestConfig", "StartWindow"]


@dataclass(frozen=True, slots=True)
class StartTestConfig:
    """The change test on a standing track (module docstring).

    Args:
        threshold: twice the log-likelihood ratio of "started" over "standing" at
            which the test fires (χ² with 2 degrees of freedom per onset for a
            target standing still: 30 is exceeded with probability
            ``exp(−15)`` ≈ 3·10⁻⁷ per onset and test).
        window_s: the readings within this many seconds of the newest are tested, s.
        min_readings: readings at or after an onset needed to test it.
        armed_standing_prob: an onset is tested only where the standing model's
            predicted probability at its reading was at least this (a track that
            already believed its target moving is not tested from there).
        speed_sigma_mps: one-sigma prior of a start's velocity per axis, m/s.
        max_speed_sigma_mps: an onset fires the test only if its fit's velocity
            one-sigma, along its worst direction, is at most this, m/s.
        moving_prob: the moving model's probability after the test fired.

    Raises:
        BackendError: a value out of range (a threshold, window or speed ≤ 0, fewer
            than 3 readings, probabilities outside (0, 1]).
    """

    threshold: float = 30.0
    window_s: float = 1.0
    min_readings: int = 4
    armed_standing_prob: float = 0.5
    speed_sigma_mps: float = 5.0
    max_speed_sigma_mps: float = 1.5
    moving_prob: float = 0.99

    def __post_init__(self) -> None:
        for name in ("threshold", "window_s", "speed_sigma_mps", "max_speed_sigma_mps"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise BackendError(f"start_test {name} must be > 0 and finite, got {value}")
        if self.min_readings < 3:
            raise BackendError(f"start_test min_readings must be ≥ 3, got {self.min_readings}")
        for name in ("armed_standing_prob", "moving_prob"):
            value = getattr(self, name)
            if not 0 < value <= 1:
                raise BackendError(f"start_test {name} must be in (0, 1], got {value}")


@dataclass(frozen=True, slots=True)
class StartFit:
    """The test's verdict where it fired."""

    statistic: float
    """Twice the log-likelihood ratio at the best onset (χ² scale)."""
    onset_t_ns: int
    """Time of the best onset, UTC ns."""
    state: Array
    """``[x_m, y_m, vx_mps, vy_mps]`` at the newest reading of the window."""
    cov: Array
    """Its 4×4 covariance (m², m²/s, m²/s²), the fit's."""


@dataclass(slots=True)
class StartWindow:
    """One track's last readings under the standing model, and the test on them."""

    config: StartTestConfig
    _t_ns: list[int] = field(default_factory=list)
    _rows: list[tuple[float, ...]] = field(default_factory=list)
    """Per reading: residual (rad), gradient on x and y (rad/m), variance (rad²), p_i
    (m), μ_i."""
    _covs: list[Array] = field(default_factory=list)
    """Per reading: ``P_i``, 2×2 (m²)."""
    _sensors: list[str] = field(default_factory=list)
    """Per reading: the sensor that took it."""

    def __len__(self) -> int:
        return len(self._t_ns)

    def clear(self) -> None:
        """Forget every reading (after a start, or when the track is restarted)."""
        self._t_ns.clear()
        self._rows.clear()
        self._covs.clear()
        self._sensors.clear()

    def add(
        self,
        t_ns: int,
        residual_rad: float,
        gradient_rad_per_m: Array,
        variance_rad2: float,
        position_m: Array,
        position_cov_m2: Array,
        standing_prob: float,
        sensor: str,
    ) -> None:
        """Keep one reading of ``sensor`` (at or after the newest kept, UTC ns) with
        the standing model's prediction at its time (residual, gradient, the
        reading's variance, position, its covariance, and the model's probability);
        readings older than ``window_s`` before it are dropped.

        Raises:
            BackendError: a reading older than the newest kept, or a non-finite
                residual, gradient, variance ≤ 0 or position.
        """
        if self._t_ns and t_ns < self._t_ns[-1]:
            raise BackendError(f"start test reading at {t_ns} ns before the newest kept")
        g = np.asarray(gradient_rad_per_m, np.float64)[:2]
        p = np.asarray(position_m, np.float64)[:2]
        row = (
            float(residual_rad),
            float(g[0]),
            float(g[1]),
            float(variance_rad2),
            *p.tolist(),
            float(standing_prob),
        )
        if not (all(math.isfinite(v) for v in row) and variance_rad2 > 0):
            raise BackendError(f"start test reading {row} is not finite with a variance > 0")
        self._t_ns.append(int(t_ns))
        self._sensors.append(sensor)
        self._rows.append(row)
        self._covs.append(np.asarray(position_cov_m2, np.float64)[:2, :2].copy())
        horizon = t_ns - round(self.config.window_s * NS_PER_S)
        drop = 0
        while self._t_ns[drop] < horizon:
            drop += 1
        if drop:
            del self._t_ns[:drop], self._rows[:drop], self._covs[:drop], self._sensors[:drop]

    def test(self) -> StartFit | None:
        """The test over the kept readings: the fit at the best onset when the
        statistic reaches the threshold, else None."""
        m = self.config.min_readings
        n = len(self._t_ns)
        if n < m:
            return None
        rows = np.array(self._rows)
        y, H, R, p = rows[:, 0], rows[:, 1:3], rows[:, 3], rows[:, 4:6]
        t_s = (np.array(self._t_ns, np.int64) - self._t_ns[0]) / NS_PER_S
        # k with at least m readings at or after it, from two sensors or more (one
        # sensor's lines of bearing do not fix the range), where the track believed
        # the target might stand
        seen: set[str] = set()
        crossed = np.zeros(n, bool)
        for i in range(n - 1, -1, -1):
            seen.add(self._sensors[i])
            crossed[i] = len(seen) >= 2
        armed = (rows[:, 6] >= self.config.armed_standing_prob) & crossed
        onsets = np.flatnonzero(armed[: n - m + 1])
        K = len(onsets)
        if K == 0:
            return None
        after = np.arange(n)[None, :] >= onsets[:, None]  # (K, n)
        tau = np.where(after, t_s[None, :] - t_s[onsets][:, None], 0.0)
        # residual against p_k, linearised at each reading's own prediction
        r = y[None, :] - np.einsum("ia,kia->ki", H, p[onsets][:, None, :] - p[None, :, :])
        w = np.where(after, 1.0 / R[None, :], 0.0)
        a = np.concatenate(
            [np.broadcast_to(H, (K, n, 2)), tau[:, :, None] * H[None, :, :]], axis=2
        )  # (K, n, 4): d(reading)/d(d, v)
        J = np.einsum("ki,kia,kib->kab", w, a, a)
        g = np.einsum("ki,kia,ki->ka", w, a, r)
        prior = np.array([np.linalg.inv(self._covs[k]) for k in onsets])
        J[:, :2, :2] += prior
        J[:, 2, 2] += self.config.speed_sigma_mps**-2
        J[:, 3, 3] += self.config.speed_sigma_mps**-2
        cov_fit = np.linalg.inv(J)
        sol = np.einsum("kab,kb->ka", cov_fit, g)
        sol_d = np.linalg.solve(J[:, :2, :2], g[:, :2, None])[:, :, 0]
        stat = np.einsum("ka,ka->k", g, sol) - np.einsum("ka,ka->k", g[:, :2], sol_d)
        worst_var = np.linalg.eigvalsh(cov_fit[:, 2:, 2:])[:, -1]
        stat = np.where(worst_var <= self.config.max_speed_sigma_mps**2, stat, -np.inf)
        best = int(np.argmax(stat))
        if not stat[best] >= self.config.threshold:
            return None
        k = int(onsets[best])
        span = float(t_s[-1] - t_s[k])
        A = np.eye(4)
        A[0, 2] = A[1, 3] = span
        state = A @ sol[best]
        state[:2] += p[k]
        cov = A @ cov_fit[best] @ A.T
        return StartFit(float(stat[best]), self._t_ns[k], state, 0.5 * (cov + cov.T))
