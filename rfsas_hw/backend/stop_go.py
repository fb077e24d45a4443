"""Stop and go: a target that walks or stands, as an interacting multiple model.

A person walks, stops at the kerb, waits, walks on. One constant-velocity
model believes a stop only once the measurements have undone the velocity it
learnt, which takes seconds when the bearings are a few degrees wide; a model
whose velocity decays believes a walk slowly. Here two models of the same
state ``[x_m, y_m, vx_mps, vy_mps]`` run side by side (Blom and Bar-Shalom's
interacting multiple model, IMM):

- **moving** (index 0): the tracker's constant velocity with white-noise
  acceleration (:mod:`rfsas_hw.backend._tracking_kernel`, the same prediction);
- **standing** (index 1): the velocity is 0 with one-sigma ``σ_s``
  (``standing_sigma_mps``) per axis, and the position wanders as a random walk
  of variance ``σ_s²·dt`` per axis (m², dt in s): a person who shifts their
  weight, not one who walks.

A two-state Markov chain in continuous time switches between them: a moving
target stops at rate ``a`` (``stop_per_s``), a standing one starts at rate
``b`` (``go_per_s``). Over ``dt`` with ``s = a + b`` and ``e = exp(−s·dt)``::

    P(moving → standing) = a·(1 − e)/s      P(standing → moving) = b·(1 − e)/s

Each measurement: the models' estimates are mixed by the probability that the
target switched since the last one (interaction), each mixed estimate is
predicted by its model, updated by the measurement, and weighted by the
measurement's likelihood under that model; every reader of the track sees
the moment-matched combination (mean ``Σ μ_j·x_j``, covariance
``Σ μ_j·(P_j + (x_j − x̄)(x_j − x̄)ᵀ)``), so the spread between the models
enters the velocity's sigma and with it the brake's path test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rfsas_hw.errors import BackendError

Array = npt.NDArray[np.float64]

__all__ = ["MOVING", "STANDING", "Modes", "StopGoConfig", "combine", "predict_modes", "reweigh"]

MOVING = 0
"""Index of the constant-velocity model."""
STANDING = 1
"""Index of the standing model."""


@dataclass(frozen=True, slots=True)
class StopGoConfig:
    """The standing model and how often a target switches.

    The defaults are the Euro NCAP matrix's (docs/ncap.md, "A walker who stops"): a
    higher stop rate lets the standing model pull the velocity of a rider who has
    just started back towards 0, and a start is then believed later.

    Args:
        stop_per_s: rate at which a moving target stops, 1/s.
        go_per_s: rate at which a standing target starts to move, 1/s.
        standing_sigma_mps: one-sigma velocity of a standing target per axis, m/s
            (also the random walk of its position, m/√s).

    Raises:
        BackendError: a value that is not positive and finite.
    """

    stop_per_s: float = 0.2
    go_per_s: float = 0.5
    standing_sigma_mps: float = 0.5

    def __post_init__(self) -> None:
        for name in ("stop_per_s", "go_per_s", "standing_sigma_mps"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise BackendError(f"stop_go {name} must be > 0 and finite, got {value}")

    def transition(self, dt_s: float) -> Array:
        """``T[i, j]``: probability of model ``j`` after ``dt_s`` seconds given ``i`` now."""
        a, b = self.stop_per_s, self.go_per_s
        s = a + b
        e = math.exp(-s * max(dt_s, 0.0))
        stop, go = a * (1 - e) / s, b * (1 - e) / s
        return np.array([[1 - stop, stop], [go, 1 - go]])

    @property
    def standing_share(self) -> float:
        """The chain's long-run probability of standing, ``a/(a + b)``: a new track's."""
        return self.stop_per_s / (self.stop_per_s + self.go_per_s)


@dataclass(slots=True)
class Modes:
    """The two models' estimates of one track at the track's time."""

    states: Array
    """(2, 4): moving, standing."""
    covs: Array
    """(2, 4, 4)."""
    probs: Array
    """(2,): the probability of each model, summing to 1."""
    config: StopGoConfig

    @classmethod
    def start(cls, state: Array, cov: Array, config: StopGoConfig) -> Modes:
        """Both models from one start (zero velocity): the standing one with its own
        velocity sigma, the probabilities the chain's long-run ones."""
        standing = cov.copy()
        standing[2:, :] = 0.0
        standing[:, 2:] = 0.0
        standing[2, 2] = standing[3, 3] = config.standing_sigma_mps**2
        p = config.standing_share
        return cls(
            np.array([state, state], np.float64),
            np.array([cov, standing], np.float64),
            np.array([1 - p, p]),
            config,
        )


def combine(states: Array, covs: Array, probs: Array) -> tuple[Array, Array]:
    """The moment-matched mean (4,) and covariance (4, 4) of the models' estimates."""
    x = probs @ states
    P = np.zeros((4, 4))
    for j in range(len(probs)):
        d = states[j] - x
        P += probs[j] * (covs[j] + np.outer(d, d))
    return x, 0.5 * (P + P.T)


def predict_modes(modes: Modes, dt_s: float, accel_sigma_mps2: float) -> tuple[Array, Array, Array]:
    """Interaction and prediction over ``dt_s`` (s, ≥ 0): each model's predicted state
    (2, 4), covariance (2, 4, 4) and the predicted model probabilities (2,)."""
    from rfsas_hw.backend import _tracking_kernel as k

    dt = max(dt_s, 0.0)
    T = modes.config.transition(dt)
    predicted = modes.probs @ T  # c_j
    safe = np.where(predicted > 0, predicted, 1.0)
    weights = modes.probs[:, None] * T / safe[None, :]  # w[i, j] = P(was i | is j)
    mixed_x = np.empty((2, 4))
    mixed_P = np.empty((2, 4, 4))
    for j in range(2):
        mixed_x[j], mixed_P[j] = combine(modes.states, modes.covs, weights[:, j])
    x = np.empty((2, 4))
    P = np.empty((2, 4, 4))
    xm, Pm = k.predict(
        mixed_x[MOVING][None], mixed_P[MOVING][None], np.array([dt]), float(accel_sigma_mps2) ** 2
    )
    x[MOVING], P[MOVING] = xm[0], Pm[0]
    sigma2 = modes.config.standing_sigma_mps**2
    x[STANDING] = mixed_x[STANDING]
    x[STANDING, 2:] = 0.0
    Ps = mixed_P[STANDING].copy()
    Ps[2:, :] = 0.0
    Ps[:, 2:] = 0.0
    Ps[0, 0] += sigma2 * dt
    Ps[1, 1] += sigma2 * dt
    Ps[2, 2] = Ps[3, 3] = sigma2
    P[STANDING] = Ps
    return x, P, predicted


def reweigh(predicted: Array, log_likelihoods: Array) -> Array:
    """The model probabilities after a measurement: ``c_j·L_j`` normalised (from the
    log-likelihoods, so that a far-off model does not underflow to 0/0)."""
    ll = np.asarray(log_likelihoods, np.float64)
    if not np.isfinite(ll).any():
        return np.asarray(predicted, np.float64).copy()
    ll = np.where(np.isfinite(ll), ll, -np.inf)
    w = predicted * np.exp(ll - ll.max())
    total = float(w.sum())
    if not total > 0:
        return np.asarray(predicted, np.float64).copy()
    out: Array = w / total
    return out
