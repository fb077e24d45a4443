"""Tracks fed by each unit's bearing instead of by fixes.

A fix-fed track (:class:`~rfsas_hw.backend.tracking.Tracker`) sees an emitter
only through the fixes that pass triangulation's acceptance test, and that test
keeps or refuses a fix depending on the sign of its error where the error
ellipse is long (a fix that errs towards the nearest unit shortens its range
and is refused): the accepted fixes are biased, and a track over them sees
motion that is not there. Here a track starts from the first trustworthy fix
(its position sigma widened by ``start_sigma_scale``: that fix is itself one
the test selected) and from then on every new bearing is a measurement of the
track on its own, whatever the fix of the moment:

- ``h(x) = atan2(x − x_s, y − y_s)``, the compass azimuth from the sensor at
  ``(x_s, y_s)`` to the track's position;
- measurement variance ``σ_θ² + σ_s²/r²`` (rad²): the bearing's own one-sigma
  error (its site floor included) and the sensor's position error
  ``station_sigma_m`` across the line of sight at range ``r``;
- the update is the extended Kalman filter on this scalar (``iterations`` > 1:
  the iterated one, Gauss-Newton on the wrapped residual from the prediction),
  the covariance in Joseph form; the prediction is the fix-fed tracker's own
  (:meth:`~rfsas_hw.backend.tracking.Track.predict`); a track with a standing
  model beside its constant velocity (``tracker.stop_go``,
  :mod:`rfsas_hw.backend.stop_go`) is gated on the models' combined prediction,
  then each model takes the bearing and is weighed by its likelihood;
- a bearing measured, or of a track predicted, more than
  ``max_off_boresight_deg`` from its sensor's boresight (outside the field of
  view its calibration and sigma hold for; a two-antenna unit folds a direction
  from its side or back into its front, where only the track's prediction
  shows it) is not applied and counted; the same rule keeps such a bearing out
  of the fixes (:meth:`BearingTracker.admit`, the associator's ``admit``), which
  start and restart the tracks and whose status the assessment reports;
- with the units' field of view given (``fov_deg``), a reading is one the unit's
  edge rule let through: a unit reports a direction only while its reading ``m``
  (off boresight) and ``edge_sigmas`` of its σ stay inside the field of view
  (:func:`~rfsas_hw.df.fovrule.near_edge`), so for a target near that edge only
  the readings that err towards boresight arrive. The update then takes the
  reading as drawn from the prediction's normal truncated to
  ``[lo + k·σ, hi − k·σ]``: the predicted reading is that truncated normal's mean
  and its variance ``g·R``, the gradient ``g·H`` (``g`` = the truncated over the
  untruncated variance, 1 deep inside, → 0 past the edge); a track near the edge
  is then not pulled towards boresight by the readings that got through;
- a bearing whose innovation exceeds ``gate_sigmas`` of its predicted sigma is
  not applied and counted; a track whose last ``lost_after`` bearings were all
  outside the gate is dropped, and the next trustworthy fix starts a new one.

By default only the newest bearing of each sensor per step is used (the
associator keeps no other): the same measurements the fixes are made of, so that
a sensor's correlated errors (multipath at a slowly changing geometry) are not
counted many times over. With ``readings: all`` every bearing a sensor reported
since the last step is applied, oldest first, each at its own capture time
(:meth:`BearingTracker.take` keeps one step's bearings): for units whose readings
of one burst have independent errors (measured for the Euro NCAP matrix's,
docs/ncap-log.md, section J) the track then sees a start sooner.

With ``start_test`` set, a track with a standing model (``tracker.stop_go``)
also runs a change test on its last bearings while it believes the target
stands (:mod:`rfsas_hw.backend.start_test`): when the readings show that the
target has left its standing position, the moving model restarts from the
test's fit over the window (position and velocity with the fit's covariance)
and takes the probability ``moving_prob``; the standing model restarts at the
same position.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy.special import log_ndtr

from rfsas_hw.angles import wrap_deg_180
from rfsas_hw.backend.association import Associator, StationBearing
from rfsas_hw.backend.start_test import StartTestConfig, StartWindow
from rfsas_hw.backend.stop_go import MOVING, STANDING, Modes, combine, predict_modes, reweigh
from rfsas_hw.backend.tracking import NS_PER_S, Tracker
from rfsas_hw.df.fovrule import EDGE_SIGMAS
from rfsas_hw.errors import BackendError
from rfsas_hw.records import BearingBatch, Pose

Array = npt.NDArray[np.float64]

TrackingMode = Literal["fixes", "bearings"]
"""What updates a track: ``fixes`` (triangulated positions) or ``bearings`` (each unit's)."""

Readings = Literal["newest", "all"]
"""Which of a sensor's bearings in a step update a track: its ``newest`` or ``all``."""

__all__ = [
    "BearingTracker",
    "BearingTrackerStats",
    "BearingUpdate",
    "BearingUpdateConfig",
    "Readings",
    "TrackingMode",
    "bearing_update",
    "censored_reading",
]


@dataclass(frozen=True, slots=True)
class BearingUpdateConfig:
    """How a bearing updates a track.

    Args:
        gate_sigmas: a bearing whose innovation exceeds this many of its predicted
            one-sigma is not applied.
        station_sigma_m: one-sigma error of a sensor's reported position, metres
            (a moving unit's pose error); enters as ``σ_s/r`` across the line of sight.
        iterations: Gauss-Newton iterations of the update (1: the extended Kalman
            filter; more re-linearise at the updated position, the iterated filter,
            for a position sigma not small against the range; on the Euro NCAP
            matrix's true negatives 3 braked more often than 1, docs/ncap.md).
        lost_after: bearings in a row outside the gate after which the track is dropped.
        max_off_boresight_deg: bearings measured, or of a track predicted, further
            than this from their sensor's boresight are not used, degrees (180:
            every bearing).
        start_sigma_scale: factor on the one-sigma position of the fix that starts
            a track. That fix is the first to pass triangulation's acceptance
            test, which keeps long fixes by the sign of their error: its error is
            larger than its covariance says, and a start that claims too much
            leaks the bearings' correction into a false velocity (docs/ncap.md).
        fov_deg: the units' calibrated field of view, degrees off boresight
            (lower, upper; clockwise positive), within which their edge rule keeps
            a reading and ``edge_sigmas`` of its σ; None: readings are taken as
            uncensored (module docstring).
        edge_sigmas: the units' edge rule, sigmas (the DF's own,
            :data:`~rfsas_hw.df.fovrule.EDGE_SIGMAS`).
        readings: ``newest``: each sensor's newest bearing per step updates a track;
            ``all``: every bearing it reported since the last step, each at its own
            time (a burst's frames as independent measurements: only for units whose
            errors within a burst are uncorrelated).
        start_test: a change test on the tracks that believe their target stands,
            which restarts the velocity when it fires (module docstring,
            :mod:`rfsas_hw.backend.start_test`; None: no test). Only tracks with a
            standing model (``tracker.stop_go``) run it.

    Raises:
        BackendError: a non-positive gate, iteration count or loss count, a
            negative station sigma, a field of view that does not hold boresight,
            a negative ``edge_sigmas``, or an unknown ``readings``.
    """

    gate_sigmas: float = 3.0
    station_sigma_m: float = 0.0
    iterations: int = 1
    lost_after: int = 10
    max_off_boresight_deg: float = 180.0
    start_sigma_scale: float = 1.0
    fov_deg: tuple[float, float] | None = None
    edge_sigmas: float = EDGE_SIGMAS
    readings: Readings = "newest"
    start_test: StartTestConfig | None = None

    def __post_init__(self) -> None:
        if not self.gate_sigmas > 0:
            raise BackendError(f"bearings gate_sigmas must be > 0, got {self.gate_sigmas}")
        if not self.station_sigma_m >= 0:
            raise BackendError(f"bearings station_sigma_m must be ≥ 0, got {self.station_sigma_m}")
        if self.iterations < 1:
            raise BackendError(f"bearings iterations must be ≥ 1, got {self.iterations}")
        if self.lost_after < 1:
            raise BackendError(f"bearings lost_after must be ≥ 1, got {self.lost_after}")
        if not self.start_sigma_scale >= 1:
            raise BackendError(
                f"bearings start_sigma_scale must be ≥ 1, got {self.start_sigma_scale}"
            )
        if not 0 < self.max_off_boresight_deg <= 180:
            raise BackendError(
                f"bearings max_off_boresight_deg must be in (0, 180], "
                f"got {self.max_off_boresight_deg}"
            )
        if self.fov_deg is not None and not -180 <= self.fov_deg[0] < 0 < self.fov_deg[1] <= 180:
            raise BackendError(
                f"bearings fov_deg must be (lower < 0 < upper) within ±180°, got {self.fov_deg}"
            )
        if not self.edge_sigmas >= 0:
            raise BackendError(f"bearings edge_sigmas must be ≥ 0, got {self.edge_sigmas}")
        if self.readings not in ("newest", "all"):
            raise BackendError(f"bearings readings must be newest or all, got {self.readings!r}")


@dataclass(frozen=True, slots=True)
class BearingUpdate:
    """The outcome of one bearing applied to a predicted state."""

    state: Array
    """``[x_m, y_m, vx_mps, vy_mps]`` after the update (the prediction when gated)."""
    cov: Array
    """4×4 covariance after the update (the prediction's when gated)."""
    innovation_sigmas: float
    """Wrapped innovation at the prediction over its predicted one-sigma (signed)."""
    applied: bool
    """False when the bearing was outside the gate (or the target sat on the sensor)."""
    innovation_sd_rad: float = math.nan
    """The innovation's predicted one-sigma, radians (NaN: the target sat on the sensor)."""
    gradient: Array | None = None
    """The predicted reading's gradient on the state at the prediction, rad per unit
    (None: the target sat on the sensor)."""
    reading_var_rad2: float = math.nan
    """The reading's own variance at the prediction, rad² (censoring included)."""

    @property
    def log_likelihood(self) -> float:
        """Log of the Gaussian density of the innovation at the prediction, log(1/rad)
        (−inf when undefined): how well the predicted state explains the bearing."""
        if not (math.isfinite(self.innovation_sigmas) and self.innovation_sd_rad > 0):
            return -math.inf
        r = self.innovation_sigmas
        return -0.5 * r * r - math.log(self.innovation_sd_rad) - 0.5 * math.log(2 * math.pi)


def _azimuth_and_gradient(state: Array, sx: float, sy: float) -> tuple[float, Array, float]:
    """Compass azimuth (rad) from the sensor to the state's position, its gradient
    ``H`` (1/m on the positions, 0 on the velocities) and the range² (m²)."""
    dx, dy = float(state[0]) - sx, float(state[1]) - sy
    r2 = dx * dx + dy * dy
    H = np.array([dy / r2, -dx / r2, 0.0, 0.0]) if r2 > 0 else np.zeros(4)
    return math.atan2(dx, dy), H, r2


def _wrap(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


def censored_reading(u: float, var: float, lo: float, hi: float) -> tuple[float, float]:
    """Mean shift and variance factor of a reading ``~ N(u, var)`` that is only seen
    within ``[lo, hi]`` (the same unit throughout, e.g. radians off boresight).

    Returns:
        ``(E[m | lo ≤ m ≤ hi] − u, Var[m | lo ≤ m ≤ hi] / var)``; the factor is also
        ``d E[m | …] / d u``. Computed in log space, so a mean far outside the window
        gives the edge's value and a factor near 0, not a division by zero.

    Raises:
        BackendError: a variance ≤ 0 or a window with ``lo ≥ hi``.
    """
    if not (var > 0 and lo < hi):
        raise BackendError(f"censored reading needs var > 0 and lo < hi, got {var}, {lo}, {hi}")
    s = math.sqrt(var)
    a, b = (lo - u) / s, (hi - u) / s
    flip = a + b > 0  # the mean below the window's middle: work on the mirrored window
    if flip:
        a, b = -b, -a
    # log Z = log(Φ(b) − Φ(a)) with Φ(a) ≤ Φ(b)
    log_b, log_a = float(log_ndtr(b)), float(log_ndtr(a))
    log_z = log_b + math.log1p(-math.exp(min(log_a - log_b, 0.0)))
    if not math.isfinite(log_z):  # the window is too narrow to hold any probability
        log_z = log_b - 700.0
    log_phi = -0.5 * math.log(2 * math.pi)
    ra = math.exp(log_phi - 0.5 * a * a - log_z)
    rb = math.exp(log_phi - 0.5 * b * b - log_z)
    shift = s * (ra - rb)
    factor = 1.0 + a * ra - b * rb - (ra - rb) ** 2
    factor = min(max(factor, 1e-9), 1.0)
    return (-shift if flip else shift), factor


def bearing_update(
    state: Array,
    cov: Array,
    station_xy: tuple[float, float],
    azimuth_deg: float,
    sigma_deg: float,
    config: BearingUpdateConfig,
    boresight_deg: float | None = None,
) -> BearingUpdate:
    """Apply one bearing to a predicted track state (see the module docstring).

    Args:
        state: predicted ``[x_m, y_m, vx_mps, vy_mps]``.
        cov: its 4×4 covariance.
        station_xy: the sensor's position, metres east/north.
        azimuth_deg: the measured compass azimuth, degrees.
        sigma_deg: its one-sigma error, degrees.
        config: gate, station sigma, iterations and the units' field of view.
        boresight_deg: compass azimuth of the sensor's boresight, degrees; with
            ``config.fov_deg`` the reading is taken as censored by the unit's edge
            rule (None: uncensored).

    Raises:
        BackendError: a non-finite bearing or sigma, or a sigma ≤ 0.
    """
    if not (math.isfinite(azimuth_deg) and math.isfinite(sigma_deg) and sigma_deg > 0):
        raise BackendError(
            f"bearing {azimuth_deg}° ± {sigma_deg}° is not a finite azimuth with a positive sigma"
        )
    x0 = np.asarray(state, np.float64)
    P = np.asarray(cov, np.float64)
    sx, sy = float(station_xy[0]), float(station_xy[1])
    z = math.radians(azimuth_deg)
    var_theta = math.radians(sigma_deg) ** 2
    var_station = config.station_sigma_m**2
    window = None
    if config.fov_deg is not None and boresight_deg is not None:
        reach = config.edge_sigmas * sigma_deg
        lo, hi = config.fov_deg[0] + reach, config.fov_deg[1] - reach
        if lo < hi:
            window = (math.radians(boresight_deg), math.radians(lo), math.radians(hi))

    def model(xs: Array) -> tuple[float, Array, float, float] | None:
        """The predicted reading at ``xs``, its gradient and noise variance (censored
        when the field of view is known), and the range²; None on the sensor."""
        h, H, r2 = _azimuth_and_gradient(xs, sx, sy)
        if not r2 > 0:
            return None
        R = var_theta + var_station / r2
        if window is not None:
            shift, g = censored_reading(_wrap(h - window[0]), R, window[1], window[2])
            h, H, R = h + shift, g * H, g * R
        return h, H, R, r2

    first = model(x0)
    if first is None:
        return BearingUpdate(x0, P, math.nan, False)
    h0, H0, R0, _ = first
    PH0 = P @ H0
    S0 = float(H0 @ PH0) + R0
    nu0 = _wrap(z - h0)
    ratio = nu0 / math.sqrt(S0)
    if abs(ratio) > config.gate_sigmas:
        return BearingUpdate(x0, P, ratio, False, math.sqrt(S0), H0, R0)
    x, H, PH, S, R, K = x0, H0, PH0, S0, R0, PH0 / S0
    for i in range(config.iterations):
        if i:
            again = model(x)
            if again is None:
                break
            h, H, R, _ = again
            PH = P @ H
            S = float(H @ PH) + R
            nu = _wrap(z - h) - float(H @ (x0 - x))
        else:
            nu = nu0
        K = PH / S
        x = x0 + K * nu
    A = np.eye(4) - np.outer(K, H)
    P_new = A @ P @ A.T + R * np.outer(K, K)
    return BearingUpdate(x, 0.5 * (P_new + P_new.T), ratio, True, math.sqrt(S0), H0, R0)


@dataclass(slots=True)
class BearingTrackerStats:
    """Counts of what the bearings did to the tracks."""

    started: int = 0
    """Tracks started from a trustworthy fix."""
    applied: int = 0
    """Bearings applied."""
    gated: int = 0
    """Bearings outside the innovation gate, not applied."""
    out_of_order: int = 0
    """Bearings older than their track, not applied."""
    off_boresight: int = 0
    """Bearings beyond ``max_off_boresight_deg`` from their sensor's boresight, not applied."""
    fix_off_boresight: int = 0
    """The same, left out of a fix's group (once per group it would have joined)."""
    invalid: int = 0
    """Bearings with a non-finite azimuth or a sigma that is not positive, not applied."""
    lost: int = 0
    """Tracks dropped after ``lost_after`` gated bearings in a row."""
    starts: int = 0
    """Standing tracks whose velocity the start test restarted."""

    def as_dict(self) -> dict[str, int]:
        """The counters, flat."""
        return {
            "started": self.started,
            "applied": self.applied,
            "gated": self.gated,
            "out_of_order": self.out_of_order,
            "off_boresight": self.off_boresight,
            "fix_off_boresight": self.fix_off_boresight,
            "invalid": self.invalid,
            "lost": self.lost,
            "starts": self.starts,
        }


@dataclass(slots=True)
class BearingTracker:
    """Starts tracks from fixes and updates them with bearings (module docstring).

    The tracks live in ``tracker`` (its configuration gives the motion model, its
    :meth:`~rfsas_hw.backend.tracking.Tracker.prune` drops stale tracks); a track's
    ``updates`` counts the steps in which it took at least one bearing, so that the
    brake rule's "fixes since the track started" means the same in both modes.
    """

    tracker: Tracker
    config: BearingUpdateConfig = field(default_factory=BearingUpdateConfig)
    stats: BearingTrackerStats = field(default_factory=BearingTrackerStats)
    _used: dict[int, dict[str, int]] = field(default_factory=dict)
    """Per emitter, the time of the newest bearing of each sensor already used, ns."""
    _missed: dict[int, int] = field(default_factory=dict)
    """Per emitter, gated bearings in a row."""
    _pending: dict[int, list[StationBearing]] = field(default_factory=dict)
    """Per emitter, the bearings taken since the last step (``readings: all`` only)."""
    _windows: dict[int, StartWindow] = field(default_factory=dict)
    """Per emitter, the start test's readings (``start_test`` only)."""

    def take(self, batch: BearingBatch, pose: Pose) -> None:
        """Keep the bearings one sensor measured from ``pose`` until the next :meth:`step`
        (with ``readings: all``; otherwise the associator's newest are used and this
        does nothing)."""
        if self.config.readings != "all" or len(batch) == 0:
            return
        sensor = batch.sensor_id
        rows = zip(
            batch.emitter.tolist(),
            batch.t_ns.tolist(),
            batch.azimuth_deg.tolist(),
            batch.sigma_deg.tolist(),
            strict=True,
        )
        for emitter, t_ns, azimuth, sigma in rows:
            self._pending.setdefault(emitter, []).append(
                StationBearing(sensor, t_ns, azimuth, sigma, pose.x_m, pose.y_m, pose.heading_deg)
            )

    def step(
        self,
        associator: Associator,
        emitters: Sequence[int],
        t_ns: Sequence[int],
        positions: Array,
        covs: Array,
        sensors: Sequence[tuple[str, ...]],
    ) -> None:
        """One service step: the new bearings of every tracked emitter, then tracks
        started from this step's trustworthy fixes (``emitters``, their times in UTC
        ns, positions in m, covariances in m², sensors) of emitters without one; a
        fix of an emitter already tracked is not used.

        Raises:
            BackendError: a non-finite fix (nothing is started).
        """
        for emitter in [e for e in self._used if e not in self.tracker.tracks]:
            del self._used[emitter]
            self._missed.pop(emitter, None)
            self._windows.pop(emitter, None)
        pending, self._pending = self._pending, {}
        for emitter in list(self.tracker.tracks):
            if self.config.readings == "all":
                taken = pending.get(emitter, [])
                taken.sort(key=lambda b: (b.t_ns, b.sensor))
                self._apply(emitter, taken)
            else:
                self._apply(emitter, associator.newest(emitter))
        new = [i for i, e in enumerate(emitters) if e not in self.tracker.tracks]
        if not new:
            return
        self.tracker.update_many(
            [emitters[i] for i in new],
            [t_ns[i] for i in new],
            np.asarray(positions, np.float64)[new],
            np.asarray(covs, np.float64)[new] * self.config.start_sigma_scale**2,
            [sensors[i] for i in new],
        )
        for i in new:
            e = emitters[i]
            self.stats.started += 1
            self._used[e] = {b.sensor: b.t_ns for b in associator.newest(e)}
            self._missed[e] = 0

    def admit(self, emitter: int, bearing: StationBearing) -> bool:
        """Whether ``bearing`` of ``emitter`` may enter a fix: the field-of-view rule of
        the track updates, judged on the measured direction and, when the emitter has a
        track, on the track's direction predicted to the bearing's time. A refused
        bearing is counted (``fix_off_boresight``)."""
        track = self.tracker.tracks.get(emitter)
        at = None
        if track is not None:
            at = track.predict(bearing.t_ns, self.tracker.config.accel_sigma_mps2)[0]
        if self._outside_view(bearing, at):
            self.stats.fix_off_boresight += 1
            return False
        return True

    def _outside_view(self, bearing: StationBearing, at: Array | None) -> bool:
        """Whether ``bearing``'s measured direction, or the direction from its sensor to
        ``at`` (a track's predicted position, m; None: no track), lies further than
        ``max_off_boresight_deg`` from the sensor's boresight. A unit that folds a
        direction from its side or back reports it in front, where only the track
        shows it."""
        limit = self.config.max_off_boresight_deg
        off = abs(wrap_deg_180(bearing.azimuth_deg - bearing.heading_deg))
        if at is not None:
            toward = math.degrees(math.atan2(at[0] - bearing.x_m, at[1] - bearing.y_m))
            off = max(off, abs(wrap_deg_180(toward - bearing.heading_deg)))
        return off > limit

    def _apply(self, emitter: int, bearings: Sequence[StationBearing]) -> None:
        track = self.tracker.tracks[emitter]
        used = self._used.setdefault(emitter, {})
        fresh = [b for b in bearings if b.t_ns > used.get(b.sensor, -1)]
        if not fresh:
            return
        accel = self.tracker.config.accel_sigma_mps2
        # the models of a stop-and-go track are updated past the gate (it is judged once,
        # on their combination)
        free = self.config if track.modes is None else replace(self.config, gate_sigmas=math.inf)
        applied: list[str] = []
        for b in fresh:  # oldest first
            used[b.sensor] = b.t_ns
            if b.t_ns < track.t_ns:
                self.stats.out_of_order += 1
                continue
            if not (
                math.isfinite(b.azimuth_deg) and math.isfinite(b.sigma_deg) and b.sigma_deg > 0
            ):
                self.stats.invalid += 1  # one bad bearing must not stop the service
                continue
            modes = track.modes
            if modes is None:
                x, P = track.predict(b.t_ns, accel)
            else:  # the models' predictions, kept for their own updates
                xs, Ps, c = predict_modes(modes, (b.t_ns - track.t_ns) / NS_PER_S, accel)
                x, P = combine(xs, Ps, c)
            if self._outside_view(b, x):
                self.stats.off_boresight += 1
                continue
            out = bearing_update(
                x, P, (b.x_m, b.y_m), b.azimuth_deg, b.sigma_deg, self.config, b.heading_deg
            )
            if not out.applied:
                self.stats.gated += 1
                missed = self._missed.get(emitter, 0) + 1
                self._missed[emitter] = missed
                if missed >= self.config.lost_after:
                    del self.tracker.tracks[emitter]
                    del self._used[emitter]
                    del self._missed[emitter]
                    self._windows.pop(emitter, None)
                    self.stats.lost += 1
                    return
                if modes is None or not self._watch(emitter, b, xs, Ps, None, c, free):
                    continue
                self._missed[emitter] = 0
                applied.append(b.sensor)
                continue
            self._missed[emitter] = 0
            self.stats.applied += 1
            track.state, track.cov, track.t_ns = out.state, out.cov, b.t_ns
            if modes is not None:  # gated on the combination; each model updated alone
                each = [
                    bearing_update(
                        xs[j],
                        Ps[j],
                        (b.x_m, b.y_m),
                        b.azimuth_deg,
                        b.sigma_deg,
                        free,
                        b.heading_deg,
                    )
                    for j in range(len(xs))
                ]
                probs = reweigh(c, np.array([o.log_likelihood for o in each]))
                track.modes = Modes(
                    np.array([o.state for o in each]),
                    np.array([o.cov for o in each]),
                    probs,
                    modes.config,
                )
                track.state, track.cov = combine(track.modes.states, track.modes.covs, probs)
                self._watch(emitter, b, xs, Ps, each[STANDING], c, free)
            applied.append(b.sensor)
        if applied:
            track.updates += 1
            track.sensors = tuple(sorted(set(applied)))

    def _watch(
        self,
        emitter: int,
        b: StationBearing,
        xs: Array,
        Ps: Array,
        standing: BearingUpdate | None,
        predicted_probs: Array,
        ungated: BearingUpdateConfig,
    ) -> bool:
        """The start test on bearing ``b`` of a track with a standing model, given the
        models' predictions at its time (``xs``, ``Ps``), the standing model's update by
        it (None: the bearing was gated; it is then computed here with ``ungated``, the
        update's settings without the gate) and the models' predicted probabilities.
        When the test fires the track restarts moving at ``b``'s time; returns whether
        it did."""
        cfg = self.config.start_test
        track = self.tracker.tracks[emitter]
        if cfg is None or track.modes is None:
            return False
        if standing is None:
            standing = bearing_update(
                xs[STANDING],
                Ps[STANDING],
                (b.x_m, b.y_m),
                b.azimuth_deg,
                b.sigma_deg,
                ungated,
                b.heading_deg,
            )
        if standing.gradient is None:  # the target sat on the sensor
            return False
        window = self._windows.setdefault(emitter, StartWindow(cfg))
        window.add(
            b.t_ns,
            standing.innovation_sigmas * standing.innovation_sd_rad,
            standing.gradient,
            standing.reading_var_rad2,
            xs[STANDING],
            Ps[STANDING],
            float(predicted_probs[STANDING]),
            b.sensor,
        )
        fit = window.test()
        if fit is None:
            return False
        window.clear()
        modes = track.modes
        sigma2 = modes.config.standing_sigma_mps**2
        still = np.zeros(4)
        still[:2] = fit.state[:2]
        still_cov = np.zeros((4, 4))
        still_cov[:2, :2] = fit.cov[:2, :2]
        still_cov[2, 2] = still_cov[3, 3] = sigma2
        states = np.empty((2, 4))
        covs = np.empty((2, 4, 4))
        states[MOVING], covs[MOVING] = fit.state, fit.cov
        states[STANDING], covs[STANDING] = still, still_cov
        probs = np.array([cfg.moving_prob, 1.0 - cfg.moving_prob])
        track.modes = Modes(states, covs, probs, modes.config)
        track.state, track.cov = combine(states, covs, probs)
        track.t_ns = b.t_ns
        self.stats.starts += 1
        return True
