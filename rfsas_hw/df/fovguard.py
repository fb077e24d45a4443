"""The level rule of :mod:`rfsas_hw.df.fovrule` applied to bearings, once or over time.

:func:`boresight_levels` gives each bearing's boresight-equivalent level,
:func:`refuse_weak` refuses the bearings too weak against a reference, and
:class:`FovGuard` keeps that reference per emitter in time: the brightest
boresight-equivalent level of the emitter, decaying by ``decay_db_per_s``
so that an emitter walking away is not refused for its path loss; on a
fixed mount it also requires each emitter to prove by its bearing's
sweep that it has been in front (``prove_motion_deg``; :meth:`FovGuard.for_mount`
turns that on for a fixed mount and off for a moving one). It is keyed by
whatever identifies an emitter inside the sensor process (the raw MAC); its
state never leaves the process.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.df.calibration import Calibration, CalibrationTable
from rfsas_hw.df.estimate import DfFlag, DfResult
from rfsas_hw.df.fovchannels import ChannelConsistency
from rfsas_hw.df.fovrule import (
    LEVEL_MARGIN_DB,
    boresight_equivalent_dbm,
    fold_drop_db,
    fold_margin_db,
    weak_against,
)

Array = npt.NDArray[np.floating[Any]]

DECAY_DB_PER_S = 0.5
"""How fast an emitter's reference level forgets a bright frame, dB per second.

A walker at 1.4 m/s 20 m away loses about 0.6 dB/s of path loss; a sensor
spinning once in 10 s forgets 5 dB a turn, well short of the 20 dB and more
that a back lobe is down.
"""

SMOOTH_S = 0.3
"""Time constant of the level average an emitter is judged by, seconds: long enough
to ride out a fading dip of a frame or two, short against a turn of the sensor."""

MAX_EMITTERS = 65_536
"""Emitters a guard remembers at most (the least recently heard are forgotten)."""

PROVE_MOTION_DEG = 3.0
"""For a fixed mount: how far an emitter's smoothed bearing must have moved before its
bearings count, degrees (at least; :data:`PROVE_SPREADS` times the spread noise alone
gives that average, when that is more). The default of :meth:`FovGuard.for_mount` for
a fixed mount.

Behind a fixed two-antenna sensor both chains sit on the back-lobe floor: the
ratio, and the bearing, stay put (near boresight) however the emitter moves
there, and an emitter that never moves has no brighter front level to be
judged by. An emitter whose bearing has swept this far has crossed the main
lobes, so it has shown its front. A static emitter never does: in front or
behind, a two-antenna pair cannot tell, so its bearings are refused. The
price: a passing emitter's bearings count only once it has swept this far
(in the bundled crossing, half of the phone's bearings at ``rsu-nw``), and an
emitter walking straight at or away from the sensor never counts.

Not for a moving mount: an emitter on a collision course with it keeps a
constant bearing while it closes in, the one emitter that must not be refused
(in the bundled crossing the phone's bearing from the car stays within a few
degrees until the car is upon it; the rule refuses all of the car's bearings).
"""

MOTION_SMOOTH_S = 1.0
"""Time constant of the bearing average whose sweep proves motion, seconds: the
noise of single bearings (a few σ) must not look like a sweep."""

PROVE_WINDOW_S = 60.0
"""An emitter heard for longer than this without proving motion must sweep
:data:`LATE_SWEEPS` times farther: the more chances noise gets, the likelier it once
looks like a sweep (a static emitter stays refused, one that starts to walk, a
parked car driving off, proves itself within a few tens of degrees)."""

LATE_SWEEPS = 5.0
"""How many times ``prove_motion_deg`` a sweep must be after :data:`PROVE_WINDOW_S`."""

SETTLE_S = 1.0
"""How long after an emitter is first heard its bearing average settles before a
sweep counts, seconds (the first bearing the average starts from is one noisy frame)."""

PROVE_SPREADS = 8.0
"""The sweep that proves motion is at least this many times the spread of the bearing
average that noise alone gives.

An exponential average with weight ``w`` per frame of bearings that scatter by
``s`` about it wanders with a spread of ``s·√(w / (2 − w))`` (``w ≈ dt/τ``: a third
of ``s`` at 5 frames/s, two thirds at one frame a second); over an hour its range
stays within about eight such spreads. ``s`` is the emitter's reported σ,
averaged (as σ², over ten time constants) with the weight per frame; both
averages are divided by their total weight so that they hold from the first
frames on. An emitter whose frames come sparse and scattered (beside the
antennas, at the field of view's edge) can still wander past this over many
minutes; :data:`PROVE_WINDOW_S` bounds those chances.
"""


NO_FOLD_DB = 1000.0
"""The drop :func:`fold_drops` gives a bearing with no fold on its table's grid, dB."""


def boresight_levels(
    cal: Calibration,
    result: DfResult,
    rssi1_dbm: npt.ArrayLike,
    rssi2_dbm: npt.ArrayLike,
    channel: npt.ArrayLike | None = None,
) -> Array:
    """Boresight-equivalent level of each bearing, dBm; NaN where there is no bearing.

    The level curve is the table's for the frame's channel (0 dB for tables
    without one; see :meth:`CalibrationTable.level_at`). A batch on one
    channel, the usual case, costs one lookup and no gathers.
    """
    angle = result.angle_deg
    n = len(angle)
    ch = None if channel is None else np.asarray(channel)
    if ch is None or n < 2 or ch.min() == ch.max():  # the usual case: one table for the batch
        table = cal.table_for(None if ch is None or not n else int(ch[0]))
        # a NaN angle (no bearing) gives a NaN level, hence a NaN result
        level = table.level_at(angle) if table is not None else _no_level(angle)
    else:
        level = _no_level(angle)
        for c in np.unique(ch).tolist():
            table = cal.table_for(int(c))
            if table is not None:
                mask = ch == c
                level[mask] = table.level_at(angle[mask])
    return boresight_equivalent_dbm(rssi1_dbm, rssi2_dbm, level)


def fold_drops(cal: Calibration, result: DfResult, channel: npt.ArrayLike | None = None) -> Array:
    """How much weaker each amplitude bearing's brightest fold is, dB
    (:func:`~rfsas_hw.df.fovrule.fold_drop_db` of the frame's table at the bearing,
    built once per table); :data:`NO_FOLD_DB` or +inf where the bearing has no fold on
    the grid or the table no level curve, NaN where there is no bearing.
    """
    angle = np.asarray(result.angle_deg, np.float64)
    n = len(angle)
    ch = None if channel is None else np.asarray(channel)
    if ch is None or n < 2 or ch.min() == ch.max():  # the usual case: one table for the batch
        table = cal.table_for(None if ch is None or not n else int(ch[0]))
        if table is not None and table.level_db is not None:
            one: Array = np.interp(angle, table.grid_deg, _table_drops(table))  # NaN stays NaN
            return one
        groups: list[tuple[int | None, npt.NDArray[np.bool_]]] = []
    else:
        groups = [(int(c), ch == c) for c in np.unique(ch).tolist()]
    out: Array = np.where(np.isnan(angle), np.nan, np.inf)
    for c, mask in groups:
        table = cal.table_for(c)
        if table is not None and table.level_db is not None:
            out[mask] = np.interp(angle[mask], table.grid_deg, _table_drops(table))
    return out


def _table_drops(table: CalibrationTable) -> Array:
    """:func:`~rfsas_hw.df.fovrule.fold_drop_db` of a table with a level curve, on its
    grid, built once and cached on the table; outside the FoV (NaN: no bearing is given
    there) and where nothing folds (+inf: nothing to tell apart) :data:`NO_FOLD_DB`, a
    finite stand-in far beyond any margin that keeps the interpolation finite."""
    drop = table.cache.get("fold_drop_db")
    if drop is None:
        assert table.level_db is not None
        raw = fold_drop_db(table.grid_deg, table.psi, table.level_db, table.fov_deg)
        drop = np.where(np.isfinite(raw), raw, NO_FOLD_DB)
        table.cache["fold_drop_db"] = drop
    out: Array = drop
    return out


def _no_level(angle_deg: Array) -> Array:
    """0 dB where there is a bearing, NaN where there is none (no table for the frame)."""
    out: Array = np.where(np.isnan(angle_deg), np.nan, 0.0)
    return out


def refuse_weak(
    result: DfResult,
    levels_dbm: Array,
    reference_dbm: Array,
    margin_db: float | Array = LEVEL_MARGIN_DB,
) -> DfResult:
    """``result`` with the bearings weak against their reference flagged ``MAY_BE_OUTSIDE``
    (``margin_db``: one margin, or one per bearing as
    :func:`~rfsas_hw.df.fovrule.fold_margin_db` gives)."""
    return refuse(result, weak_against(levels_dbm, reference_dbm, margin_db))


def refuse(result: DfResult, mask: npt.NDArray[np.bool_]) -> DfResult:
    """``result`` with the valid bearings under ``mask`` flagged ``MAY_BE_OUTSIDE``."""
    mask = mask & result.valid
    if not mask.any():
        return result
    flags = result.flags | (mask.view(np.uint8) * np.uint8(DfFlag.MAY_BE_OUTSIDE))
    angle, sigma = result.angle_deg.copy(), result.sigma_deg.copy()
    angle[mask] = np.nan
    sigma[mask] = np.nan
    return dataclasses.replace(result, angle_deg=angle, sigma_deg=sigma, flags=flags)


class FovGuard:
    """Refuses bearings of an emitter that is weak against its own recent front level.

    Args:
        margin_db: how far below the reference a bearing is refused, dB (at most: near
            the FoV's edge amplitude bearings get less, see :meth:`apply`).
        decay_db_per_s: how fast the reference forgets, dB per second.
        max_emitters: emitters remembered at most.
        warmup_s: bearings of an emitter heard for less than this are refused, seconds.
            On a sensor that turns (a robot spinning in place) one turn lets every
            emitter show its front before its bearings count; 0 (the default) on a
            fixed mount, where waiting teaches nothing.
        smooth_s: time constant of the level average an emitter is judged by, seconds.
        channels: the across-channel check (None: one with the default settings).
        prove_motion_deg: bearings of an emitter count once its bearing, averaged over
            :data:`MOTION_SMOOTH_S`, has swept this far and :data:`PROVE_SPREADS` times
            the spread noise gives that average, and it has been heard for three such
            times (degrees; 0: at once). An emitter that stands still before a fixed
            sensor then never counts (:data:`PROVE_MOTION_DEG` is the value for a fixed
            mount, see :meth:`for_mount`); a turning sensor proves every emitter in its
            first turn.

    Raises:
        ValueError: a non-positive margin, or a negative rate, time or sweep.
    """

    @classmethod
    def for_mount(
        cls, moving: bool, prove_motion_deg: float | None = None, **settings: Any
    ) -> FovGuard:
        """The guard for a sensor's mount: with the motion rule (``prove_motion_deg``,
        by default :data:`PROVE_MOTION_DEG`) on a fixed mount, without it (0) on a
        moving one, where an emitter on a collision course keeps a constant bearing.

        ``prove_motion_deg`` given (degrees) overrides the mount's default, 0 turning
        the rule off; ``settings``: the other arguments of the class.

        Raises:
            ValueError: as the class.
        """
        if prove_motion_deg is None:
            prove_motion_deg = 0.0 if moving else PROVE_MOTION_DEG
        return cls(prove_motion_deg=prove_motion_deg, **settings)

    def __init__(
        self,
        margin_db: float = LEVEL_MARGIN_DB,
        decay_db_per_s: float = DECAY_DB_PER_S,
        max_emitters: int = MAX_EMITTERS,
        warmup_s: float = 0.0,
        smooth_s: float = SMOOTH_S,
        channels: ChannelConsistency | None = None,
        prove_motion_deg: float = 0.0,
    ) -> None:
        if not (
            margin_db > 0
            and decay_db_per_s >= 0
            and max_emitters >= 1
            and warmup_s >= 0
            and smooth_s >= 0
            and prove_motion_deg >= 0
        ):
            raise ValueError(
                "margin_db > 0, decay_db_per_s ≥ 0, max_emitters ≥ 1, warmup_s ≥ 0, "
                "smooth_s ≥ 0 and prove_motion_deg ≥ 0 needed"
            )
        self.prove_motion_deg = float(prove_motion_deg)
        self.warmup_ns = int(warmup_s * 1e9)
        self.margin_db = float(margin_db)
        self.decay_db_per_s = float(decay_db_per_s)
        self.max_emitters = int(max_emitters)
        self.smooth_ns = smooth_s * 1e9
        self.channels = ChannelConsistency() if channels is None else channels
        self._ref: dict[
            int, tuple[float, float, int, int, float, float, float, float, float, float, float]
        ] = {}
        """Per emitter: smoothed and reference level (dBm), when it was last updated and
        when first heard (ns), its averaged bearing, the least and most that average
        has been (degrees, unwrapped), its average σ² (degrees²; -1 once proven), the
        average weight per frame, and the total weight of those two averages (they
        are divided by it)."""
        self.refused = 0
        """Bearings refused so far."""

    def __len__(self) -> int:
        return len(self._ref)

    def track(
        self,
        keys: npt.ArrayLike,
        t_ns: npt.ArrayLike,
        levels_dbm: Array,
        angle_deg: npt.ArrayLike | None = None,
        sigma_deg: npt.ArrayLike | None = None,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Follow each emitter through the frames in order: its smoothed level and the
        reference that level is judged against, per frame (dBm).

        The smoothed level is an exponential average of the boresight-equivalent
        levels with time constant ``smooth_s`` (a single fading dip is not a turn
        away from the antennas); the reference is the brightest smoothed level,
        decaying. NaN for a frame without a level; the reference is +inf while
        the emitter is in its warm-up, and while its bearings (``angle_deg`` with
        their ``sigma_deg``, the frames' bearings and σ; None: not judged) have not
        swept ``prove_motion_deg`` (see the class).
        """
        zeros = [0.0] * len(np.asarray(keys))
        smooth, refs, _ = self._walk(
            np.asarray(keys).tolist(),
            np.asarray(t_ns).tolist(),
            np.asarray(levels_dbm).tolist(),
            zeros if angle_deg is None else np.asarray(angle_deg, np.float64).tolist(),
            zeros if sigma_deg is None else np.asarray(sigma_deg, np.float64).tolist(),
            judge_motion=angle_deg is not None,
        )
        return np.array(smooth, np.float64), np.array(refs, np.float64)

    def _walk(
        self,
        keys: list[int],
        t_ns: list[int],
        levels_dbm: list[float],
        angles_deg: list[float],
        sigmas_deg: list[float] | None = None,
        judge_motion: bool = True,
    ) -> tuple[list[float], list[float], list[float]]:
        """:meth:`track` on the columns as lists; also, per frame, how far the reference
        has decayed since the emitter was last that bright (dB; NaN without a level)."""
        refs = self._ref
        decay = self.decay_db_per_s * 1e-9
        tau = self.smooth_ns
        tau_b = MOTION_SMOOTH_S * 1e9
        warmup = self.warmup_ns
        sweep = self.prove_motion_deg if judge_motion else 0.0
        nan, inf = math.nan, math.inf
        smooth: list[float] = []
        out: list[float] = []
        aged: list[float] = []
        sigmas = [0.0] * len(angles_deg) if sigmas_deg is None else sigmas_deg
        for key, t, level, angle, sigma in zip(
            keys, t_ns, levels_dbm, angles_deg, sigmas, strict=True
        ):
            if level != level:  # NaN: no bearing, nothing learned
                smooth.append(nan)
                out.append(nan)
                aged.append(nan)
                continue
            got = refs.pop(key, None)  # re-inserted below: the dict stays in hearing order
            if got is None:
                s = ref = peak = level
                first = t
                b = lo = hi = angle
                var = 0.0 if sweep > 0 else -1.0
                wbar = norm = 0.0
            else:
                old_s, old_ref, t_old, first, b, lo, hi, var, wbar, norm, peak = got
                dt = t - t_old if t > t_old else 0
                keep = math.exp(-dt / tau) if tau > 0 else 0.0
                s = keep * old_s + (1.0 - keep) * level
                ref = old_ref - decay * dt
                if s > ref:
                    ref = peak = s
                if var >= 0.0:  # not proven yet: follow the bearing's average and sweep
                    w = 1.0 - math.exp(-dt / tau_b)
                    step = (angle - b + 180.0) % 360.0 - 180.0  # the short way round
                    # the scatter and the weight per frame over ten time constants: steadier
                    # than the average itself (frames may come in bursts and gaps)
                    slow = 1.0 - math.exp(-dt / (10.0 * tau_b))
                    var += slow * (sigma * sigma - var)
                    wbar += slow * (w - wbar)
                    norm += slow * (1.0 - norm)  # the averages' total weight, to unbias them
                    b += w * step
                    if t - first < SETTLE_S * 1e9:
                        # the average and the scatter settle first: the sweep counts after
                        lo = hi = b
                    else:
                        lo, hi = min(lo, b), max(hi, b)
                    wn = wbar / norm if norm > 0.0 else 1.0
                    noise = PROVE_SPREADS * math.sqrt(var / max(norm, 1e-12) * wn / (2.0 - wn))
                    late = t - first > PROVE_WINDOW_S * 1e9
                    if hi - lo >= max(LATE_SWEEPS * sweep if late else sweep, noise):
                        var = -1.0
            refs[key] = (s, ref, t, first, b, lo, hi, var, wbar, norm, peak)
            smooth.append(s)
            out.append(ref if t - first >= warmup and var < 0.0 else inf)
            aged.append(peak - ref)
        while len(refs) > self.max_emitters:
            del refs[next(iter(refs))]
        return smooth, out, aged

    def apply(
        self,
        cal: Calibration,
        result: DfResult,
        rssi1_dbm: npt.ArrayLike,
        rssi2_dbm: npt.ArrayLike,
        channel: npt.ArrayLike | None,
        keys: npt.ArrayLike,
        t_ns: npt.ArrayLike,
        levels_dbm: Array | None = None,
        *,
        folds: bool = True,
    ) -> DfResult:
        """``result`` with the bearings weak against their emitter's reference refused,
        and those that disagree with the emitter's bearing on another channel moments
        earlier (:mod:`rfsas_hw.df.fovchannels`).

        ``keys`` identifies the emitter of each frame, ``t_ns`` its time (ns).
        ``levels_dbm`` are the frames' :func:`boresight_levels` when the caller has
        them already (they depend on the reading pair and its bearing only); None:
        computed here. ``folds``: the bearings are the amplitude pair's, whose folds
        beyond the FoV's edge shrink the level rule's margin (:func:`fold_drops`,
        :func:`~rfsas_hw.df.fovrule.fold_margin_db`); False for bearings of another
        method (the phase interferometer), judged with the fixed ``margin_db``.
        """
        if levels_dbm is None:
            levels_dbm = boresight_levels(cal, result, rssi1_dbm, rssi2_dbm, channel)
        key_rows, t_rows = np.asarray(keys).tolist(), np.asarray(t_ns).tolist()
        smooth, refs, aged = self._walk(
            key_rows,
            t_rows,
            np.asarray(levels_dbm).tolist(),
            result.angle_deg.tolist(),
            result.sigma_deg.tolist(),
        )
        if folds:
            drops = fold_drops(cal, result, channel)
            margins = fold_margin_db(drops, aged, self.margin_db).tolist()
        else:
            margins = [self.margin_db] * len(smooth)
        refused = [weak_against(s, r, m) for s, r, m in zip(smooth, refs, margins, strict=True)]
        if channel is not None:
            angle = result.angle_deg.tolist()
            if True in refused:  # the weak ones are refused first: neither judged nor remembered
                angle = [math.nan if w else a for a, w in zip(angle, refused, strict=True)]
            mixed = self.channels.walk(
                key_rows, t_rows, np.asarray(channel).tolist(), angle, result.sigma_deg.tolist()
            )
            if True in mixed:
                refused = [w or m for w, m in zip(refused, mixed, strict=True)]
        if True not in refused:  # the usual case: nothing refused
            return result
        out = refuse(result, np.array(refused, dtype=bool))
        self.refused += int(np.count_nonzero(out.flags != result.flags))
        return out
