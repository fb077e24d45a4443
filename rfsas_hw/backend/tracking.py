"""A constant-velocity Kalman filter per emitter over successive fixes.

State ``[x_m, y_m, vx_mps, vy_mps]`` (east/north). Between fixes the state
moves at constant velocity with white-noise acceleration of one-sigma
``accel_sigma_mps2`` (the discretised Wiener model); a fix is a position
measurement whose noise is the fix's own covariance. A fix that falls outside
the gate (Mahalanobis distance above ``gate_chi2``) restarts the track rather
than dragging it across the map; tracks without a fix for ``drop_after_s`` are
dropped. With ``stop_go`` set, a track runs the constant-velocity model beside a
standing one (:mod:`rfsas_hw.backend.stop_go`) and every reader sees their
combination; the one prediction (:func:`predict_tracks`, :meth:`Track.predict`)
serves both kinds of track.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from rfsas_hw.backend.stop_go import Modes, StopGoConfig, combine, predict_modes, reweigh
from rfsas_hw.errors import BackendError

Array = npt.NDArray[np.float64]
NS_PER_S = 1_000_000_000

__all__ = ["Track", "Tracker", "TrackerConfig", "TrackerStats", "predict_tracks"]


@dataclass(frozen=True, slots=True)
class TrackerConfig:
    """Motion model and track management.

    Args:
        accel_sigma_mps2: one-sigma white-noise acceleration, m/s² (1 suits
            pedestrians and cyclists; use 3 for cars).
        initial_speed_sigma_mps: one-sigma speed of a new track per axis, m/s.
        gate_chi2: Mahalanobis² above which a fix restarts the track (default:
            the 99.99 % point of χ² with 2 degrees of freedom).
        drop_after_s: seconds without a fix after which a track is dropped.
        epoch_overlap_s: seconds into a nonce epoch after which the tracks and fixes
            last fixed in an earlier epoch are dropped (None: only ``drop_after_s``):
            their ids, keyed with an earlier epoch's nonce, get no more bearings (the
            same emitters come back under new ids), so kept for ``drop_after_s`` they
            would stand beside their successors as second targets. At least the
            receivers' age limit (late bearings of the old epoch still arrive that
            long).
        stop_go: a standing model beside the constant-velocity one, and how often
            a target switches between them (None: constant velocity alone).

    Raises:
        BackendError: a non-positive value.
    """

    accel_sigma_mps2: float = 1.0
    initial_speed_sigma_mps: float = 2.0
    gate_chi2: float = 18.42
    drop_after_s: float = 10.0
    stop_go: StopGoConfig | None = None
    epoch_overlap_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("accel_sigma_mps2", "initial_speed_sigma_mps", "gate_chi2", "drop_after_s"):
            if not getattr(self, name) > 0:
                raise BackendError(f"tracker {name} must be > 0, got {getattr(self, name)}")
        if self.epoch_overlap_s is not None and not self.epoch_overlap_s > 0:
            raise BackendError(f"tracker epoch_overlap_s must be > 0, got {self.epoch_overlap_s}")


@dataclass(slots=True)
class Track:
    """The filtered state of one emitter."""

    emitter: int
    """Emitter id (64-bit keyed hash)."""
    state: Array
    """``[x_m, y_m, vx_mps, vy_mps]`` at ``t_ns``."""
    cov: Array
    """4×4 state covariance at ``t_ns`` (m², m²/s, m²/s²)."""
    t_ns: int
    """Time of the last fix applied, UTC ns."""
    updates: int = 1
    """Fixes applied since the track (re)started."""
    sensors: tuple[str, ...] = ()
    """Sensors whose bearings made the last fix."""
    modes: Modes | None = None
    """The moving and standing models' estimates (``stop_go``; None: constant velocity
    alone); ``state`` and ``cov`` are then their combination."""

    def predict(self, t_ns: int, accel_sigma_mps2: float) -> tuple[Array, Array]:
        """State and covariance extrapolated to ``t_ns`` (not stored): :func:`predict_tracks`
        of this track alone."""
        x, P = _predict_each([self], [t_ns], accel_sigma_mps2)
        return x[0], P[0]

    @property
    def position(self) -> Array:
        """``(x_m, y_m)`` at ``t_ns``."""
        return self.state[:2].copy()

    @property
    def position_cov(self) -> Array:
        """2×2 position covariance at ``t_ns``, m²."""
        return self.cov[:2, :2].copy()

    @property
    def velocity(self) -> Array:
        """``(vx_mps, vy_mps)``."""
        return self.state[2:].copy()


def predict_tracks(
    tracks: Sequence[Track], t_ns: int, accel_sigma_mps2: float
) -> tuple[Array, Array]:
    """Many tracks extrapolated to ``t_ns`` at once: states (B, 4) and covariances (B, 4, 4).

    State ``F·x`` and covariance ``F·P·Fᵀ + Q`` with ``F`` the constant-velocity
    transition over ``dt`` (s, never negative) and ``Q`` the discretised
    white-noise acceleration of one-sigma ``accel_sigma_mps2`` (m/s²).
    """
    if not tracks:
        return np.empty((0, 4)), np.empty((0, 4, 4))
    return _predict_each(tracks, [t_ns] * len(tracks), accel_sigma_mps2)


def _stack(tracks: Sequence[Track], t_ns: Sequence[int]) -> tuple[Array, Array, Array]:
    """The tracks' states (B, 4), covariances (B, 4, 4) and the time to ``t_ns`` (B,), s ≥ 0."""
    if len(tracks) == 1:  # (one track: no list comprehensions)
        t = tracks[0]
        dt = np.array([max(t_ns[0] - t.t_ns, 0) / NS_PER_S])
        return t.state[None], t.cov[None], dt
    states = np.array([t.state for t in tracks], np.float64)
    covs = np.array([t.cov for t in tracks], np.float64)
    then = np.array([t.t_ns for t in tracks], np.int64)
    return states, covs, np.maximum(np.asarray(t_ns, np.int64) - then, 0) / NS_PER_S


def _predict_each(
    tracks: Sequence[Track], t_ns: Sequence[int], accel_sigma_mps2: float
) -> tuple[Array, Array]:
    """Each track predicted to its own time: states (B, 4), covariances (B, 4, 4); a
    track with a standing model gives its models' predicted combination."""
    from rfsas_hw.backend import _tracking_kernel as k

    states, covs, dt = _stack(tracks, t_ns)
    x, P = k.predict(
        np.ascontiguousarray(states, np.float64),
        np.ascontiguousarray(covs, np.float64),
        dt,
        float(accel_sigma_mps2) ** 2,
    )
    for b, track in enumerate(tracks):
        if track.modes is not None:
            xs, Ps, c = predict_modes(track.modes, float(dt[b]), accel_sigma_mps2)
            x[b], P[b] = combine(xs, Ps, c)
    return x, P


@dataclass(slots=True)
class TrackerStats:
    """Counts of what the tracker did with the fixes it was given."""

    started: int = 0
    updated: int = 0
    restarted: int = 0
    """Fixes outside the gate that restarted their track."""
    out_of_order: int = 0
    """Fixes older than their track, ignored."""
    dropped: int = 0


@dataclass(slots=True)
class Tracker:
    """One :class:`Track` per emitter, updated with fixes (position + covariance)."""

    config: TrackerConfig = field(default_factory=TrackerConfig)
    tracks: dict[int, Track] = field(default_factory=dict)
    stats: TrackerStats = field(default_factory=TrackerStats)

    def _start(
        self, emitter: int, t_ns: int, z: Array, R: Array, sensors: tuple[str, ...]
    ) -> Track:
        cov = np.zeros((4, 4))
        cov[:2, :2] = R
        cov[2, 2] = cov[3, 3] = self.config.initial_speed_sigma_mps**2
        state = np.array([z[0], z[1], 0.0, 0.0])
        track = Track(emitter, state, cov, t_ns, 1, sensors)
        if self.config.stop_go is not None:
            modes = track.modes = Modes.start(state, cov, self.config.stop_go)
            track.state, track.cov = combine(modes.states, modes.covs, modes.probs)
        self.tracks[emitter] = track
        return track

    def update(
        self, emitter: int, t_ns: int, position: Array, cov: Array, sensors: tuple[str, ...] = ()
    ) -> Track:
        """Apply one fix of ``emitter`` taken at ``t_ns``; return its track.

        Raises:
            BackendError: a non-finite position or covariance.
        """
        z = np.asarray(position, np.float64)
        R = np.asarray(cov, np.float64)
        if z.shape != (2,) or R.shape != (2, 2):
            raise BackendError(f"fix of emitter {emitter:016x} is not a finite position/covariance")
        self.update_many([emitter], [t_ns], z[None], R[None], [sensors])
        return self.tracks[emitter]

    def update_many(
        self,
        emitters: Sequence[int],
        t_ns: Sequence[int],
        positions: Array,
        covs: Array,
        sensors: Sequence[tuple[str, ...]],
    ) -> None:
        """Apply one fix of each of several emitters (position m, covariance m², time UTC ns),
        the filter steps stacked; an emitter given twice is updated one fix after the other.

        A new emitter starts a track; a fix older than its track is ignored; a fix
        outside the gate (or with a singular innovation covariance) restarts the
        track; else the Kalman update in Joseph form.

        Raises:
            BackendError: a non-finite position or covariance (nothing is updated).
        """
        z = np.asarray(positions, np.float64).reshape(-1, 2)
        R = np.asarray(covs, np.float64).reshape(-1, 2, 2)
        if len(set(emitters)) < len(emitters):
            for i, e in enumerate(emitters):
                self.update_many([e], [t_ns[i]], z[i : i + 1], R[i : i + 1], [sensors[i]])
            return
        if not (np.isfinite(z).all() and np.isfinite(R).all()):
            finite = np.isfinite(z).all(axis=1) & np.isfinite(R).all(axis=(1, 2))
            bad = emitters[int(np.flatnonzero(~finite)[0])]
            raise BackendError(f"fix of emitter {bad:016x} is not a finite position/covariance")
        rows: list[int] = []
        tracks: list[Track] = []
        for i, e in enumerate(emitters):
            track = self.tracks.get(e)
            if track is None:
                self.stats.started += 1
                self._start(e, int(t_ns[i]), z[i], R[i], sensors[i])
            elif t_ns[i] < track.t_ns:
                self.stats.out_of_order += 1
            elif track.modes is not None:
                self._update_modes(track, int(t_ns[i]), z[i], R[i], sensors[i])
            else:
                rows.append(i)
                tracks.append(track)
        if not rows:
            return
        from rfsas_hw.backend import _tracking_kernel as kernels

        t_new = [int(t_ns[i]) for i in rows]
        states, covs, dt = _stack(tracks, t_new)
        state, cov, d2 = kernels.update(
            np.ascontiguousarray(states, np.float64),
            np.ascontiguousarray(covs, np.float64),
            dt,
            float(self.config.accel_sigma_mps2) ** 2,
            np.ascontiguousarray(z[rows]),
            np.ascontiguousarray(R[rows]),
        )
        for k, (i, track) in enumerate(zip(rows, tracks, strict=True)):
            if d2[k] > self.config.gate_chi2:
                self.stats.restarted += 1
                self._start(emitters[i], t_new[k], z[i], R[i], sensors[i])
                continue
            track.cov = cov[k]
            track.state = state[k]
            track.t_ns = t_new[k]
            track.updates += 1
            track.sensors = sensors[i]
            self.stats.updated += 1

    def _update_modes(
        self, track: Track, t_ns: int, z: Array, R: Array, sensors: tuple[str, ...]
    ) -> None:
        """One fix applied to a track with a standing model: the gate on the models'
        predicted combination, then each model's Kalman update (the kernel's, over no
        time) weighted by the fix's likelihood under it."""
        from rfsas_hw.backend import _tracking_kernel as kernels

        assert track.modes is not None
        dt = max(t_ns - track.t_ns, 0) / NS_PER_S
        q = float(self.config.accel_sigma_mps2) ** 2
        xs, Ps, c = predict_modes(track.modes, dt, q**0.5)
        x, P = combine(xs, Ps, c)
        zero = np.zeros(1)
        _, _, d2 = kernels.update(x[None], P[None], zero, q, z[None], R[None])
        if not d2[0] <= self.config.gate_chi2:
            self.stats.restarted += 1
            self._start(track.emitter, t_ns, z, R, sensors)
            return
        new_x, new_P, d2_j = kernels.update(
            xs, Ps, np.zeros(2), q, np.array([z, z]), np.array([R, R])
        )
        dets = np.array([np.linalg.det(Ps[j, :2, :2] + R) for j in range(2)])
        log_det = np.log(np.where(dets > 0, dets, 1.0))
        log_l = np.where(dets > 0, -0.5 * d2_j - 0.5 * log_det, -np.inf)
        probs = reweigh(c, log_l)
        track.modes = Modes(new_x, new_P, probs, track.modes.config)
        track.state, track.cov = combine(new_x, new_P, probs)
        track.t_ns = t_ns
        track.updates += 1
        track.sensors = sensors
        self.stats.updated += 1

    def prune(self, now_ns: int, limit_ns: int | None = None) -> list[int]:
        """Drop tracks without a fix for ``drop_after_s`` (or whose last fix is older than
        ``limit_ns``, UTC ns, when that is later); return their emitter ids."""
        limit = now_ns - int(self.config.drop_after_s * NS_PER_S)
        if limit_ns is not None:
            limit = max(limit, limit_ns)
        gone = [e for e, t in self.tracks.items() if t.t_ns < limit]
        for emitter in gone:
            del self.tracks[emitter]
        self.stats.dropped += len(gone)
        return gone

    def __iter__(self) -> Iterator[Track]:
        return iter(list(self.tracks.values()))

    def __len__(self) -> int:
        return len(self.tracks)
