"""The field-of-view rules: no confident bearing from an emitter that may lie outside it.

A direction finder is calibrated over a field of view (FoV). Outside it the
measurement folds back: the amplitude ratio of a squinted pair beyond the
FoV edge repeats a value from inside, and behind the antennas both chains
sit on the back-lobe floor, so their ratio looks like boresight. The
estimator then returns an angle inside the FoV with the σ of a good frame,
and the error can be 100° or more. Three rules keep such bearings out:

1. **Edge rule** (per frame, every method). A bearing is refused when its
   interval ``θ̂ ± k·σ`` (``k`` = :data:`EDGE_SIGMAS`) reaches past either
   end of the FoV: the emitter is then about as likely just outside (where
   the curve folds back onto the edge) as inside. ψ beyond the table's ends
   is refused already (``OUTSIDE_FOV``).
2. **Level rule** (needs a reference). Inside the FoV the stronger chain is
   within a few dB of its boresight reading (the table's ``level_db``
   curve); outside it, the stronger chain is far weaker than the same
   emitter at boresight. A frame's *boresight-equivalent level* is its
   stronger reading minus the curve at its bearing,
   ``e = max(RSSI₁, RSSI₂) − level_db(θ̂)``; with a reference ``e_ref`` (the
   emitter's level seen from the front, see below) a frame with
   ``e < e_ref − margin`` is refused: both chains are weak against the
   boresight level, so the emitter is beside or behind the antennas.
   The reference is the brightest ``e`` of the same emitter recently
   (:class:`~rfsas_hw.df.fovguard.FovGuard`, in time) or, for a turntable
   check at one range, the brightest of the run. Near the FoV's edge the
   margin shrinks: an emitter just beyond the edge folds onto a bearing whose
   level is only a few dB above its own (:func:`fold_drop_db`, from the
   table's ψ_D and level curve), so a bearing is refused once its level is
   nearer its fold's than its own (:func:`fold_margin_db`).

3. **Channel rule** (:mod:`rfsas_hw.df.fovchannels`): a bearing that disagrees
   with the same emitter's bearing on another channel moments earlier is
   refused; outside the FoV the folds differ from channel to channel.

4. **Motion rule** (fixed mounts: ``FovGuard.for_mount(moving=False)``):
   an emitter that never shows its front (static behind a fixed sensor) has
   no brighter reference, and behind the antennas its bearing stays put
   however it moves. Its bearings count only once its averaged bearing has
   swept a few degrees beyond what noise gives: a static emitter, in front
   or behind, never counts. Not on a moving mount, where an emitter on a
   collision course keeps a constant bearing.

What the rules cannot see: an emitter beside or behind a fixed sensor that
moves but never passes in front (its folded bearing sweeps too); mount a
two-antenna sensor with its back to a wall, or use an array that resolves
the full circle.
"""

from __future__ import annotations

from typing import Any, overload

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.floating[Any]]

EDGE_SIGMAS = 3.0
"""A bearing whose ``θ̂ ± EDGE_SIGMAS·σ`` leaves the FoV is refused."""

LEVEL_MARGIN_DB = 6.0
"""A frame more than this below the emitter's boresight-equivalent reference is refused, dB.

Twice the spread of a 1 dB-rounded reading in fading plus the few dB the
stronger chain varies inside the FoV that the level curve does not hold.
"""


def near_edge(
    angle_deg: Array, sigma_deg: Array, fov_deg: tuple[float, float], k: float = EDGE_SIGMAS
) -> npt.NDArray[np.bool_]:
    """True where ``angle ± k·σ`` (degrees) reaches past an end of ``fov_deg``.

    NaN angles or σ give False (they are flagged for their own reason; numpy's
    comparisons with NaN are quiet, so no error state is needed).
    """
    angle = np.asarray(angle_deg)
    reach = np.asarray(sigma_deg) * np.float32(k)
    lo, hi = fov_deg
    out: npt.NDArray[np.bool_] = ((angle - reach) < lo) | ((angle + reach) > hi)
    return out


def boresight_equivalent_dbm(
    rssi1_dbm: npt.ArrayLike, rssi2_dbm: npt.ArrayLike, level_at_bearing_db: npt.ArrayLike
) -> Array:
    """The stronger reading less the calibrated level curve at the bearing, dBm.

    For an emitter inside the FoV this is (up to reading noise) what it would
    give at boresight; for one outside it is lower by the pattern's drop.
    """
    # the stronger reading is one of the two exactly, in whatever dtype they come
    out: Array = np.fmax(rssi1_dbm, rssi2_dbm) - np.asarray(level_at_bearing_db, np.float64)
    return out


@overload
def weak_against(level_dbm: float, reference_dbm: float, margin_db: float = ...) -> bool: ...
@overload
def weak_against(
    level_dbm: Array, reference_dbm: Array, margin_db: float | Array = ...
) -> npt.NDArray[np.bool_]: ...
def weak_against(
    level_dbm: float | Array,
    reference_dbm: float | Array,
    margin_db: float | Array = LEVEL_MARGIN_DB,
) -> bool | npt.NDArray[np.bool_]:
    """True where a boresight-equivalent level is more than ``margin_db`` below its reference.

    Floats (one frame) or arrays (many) alike; an array may carry one margin per
    frame (:func:`fold_margin_db`). NaN levels, references or margins give False
    (quietly: numpy does not warn on comparisons with NaN).
    """
    out: bool | npt.NDArray[np.bool_] = level_dbm < reference_dbm - margin_db
    return out


def fold_drop_db(
    grid_deg: Array, psi: Array, level_db: Array, fov_deg: tuple[float, float]
) -> Array:
    """How much weaker the brightest fold of each grid angle is, dB; +inf with no fold.

    A *fold* of an angle θ inside the FoV is an angle outside it, on the
    calibrated grid, where ψ_D takes the same value: an emitter there gives
    the same ratio and hence the bearing θ. It differs from one at θ only in
    level: the stronger chain reads ``level_db(θ) − level_db(fold)`` less.
    That drop, for the brightest fold (the hardest to tell apart), is returned
    per grid point (NaN outside the FoV, +inf where no grid angle outside the
    FoV folds onto it). Folds are found on the grid's segments outside the FoV
    (the edge points included), the level interpolated linearly along them.
    """
    grid = np.asarray(grid_deg, np.float64)
    p = np.asarray(psi, np.float64)
    level = np.asarray(level_db, np.float64)
    lo, hi = fov_deg
    inside = (grid >= lo - 1e-9) & (grid <= hi + 1e-9)
    out: Array = np.full(len(grid), np.nan)
    outer = ~((grid > lo + 1e-9) & (grid < hi - 1e-9))  # outside, the edges included
    seg = np.flatnonzero(outer[:-1] & outer[1:])  # segments [j, j + 1] outside the FoV
    target = p[inside]
    if not len(seg):
        out[inside] = np.inf
        return out
    a, b = p[seg][None, :], p[seg + 1][None, :]
    t = target[:, None]
    span = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(span != 0.0, (t - a) / span, np.where(t == a, 0.0, np.nan))
    hit = (frac >= 0.0) & (frac <= 1.0)
    fold_level = level[seg][None, :] + frac * (level[seg + 1] - level[seg])[None, :]
    brightest = np.max(np.where(hit, fold_level, -np.inf), axis=1)
    out[inside] = level[inside] - brightest  # +inf where nothing folds (−inf brightest)
    return out


def fold_margin_db(
    drop_db: npt.ArrayLike, aged_db: npt.ArrayLike = 0.0, margin_db: float = LEVEL_MARGIN_DB
) -> Array:
    """The level rule's margin, dB, for bearings whose brightest fold is ``drop_db`` weaker.

    Two hypotheses explain a bearing: the emitter is where it says, at its
    reference level, or at the fold, ``drop_db`` weaker. Reading noise blurs both
    alike, so a frame nearer the fold's level than its own (more than half the
    drop below the emitter's peak) is refused. The peak is the reference before
    it decayed: ``aged_db`` is how far it has decayed since the emitter was last
    that bright. The decay allows for a change of range since then, and that
    change blurs both hypotheses alike too, so the margin below the *decayed*
    reference is ``drop/2 − aged``: an emitter not seen at its brightest for long
    loses the power to tell a fold near the edge, and there its bearings are
    refused. At most ``margin_db`` (behind the antennas, where the drop is large,
    the fixed margin rules; +inf drop: no fold). A margin ≤ 0 refuses every frame
    below the reference. NaN stays NaN.
    """
    half = 0.5 * np.asarray(drop_db, np.float64) - np.asarray(aged_db, np.float64)
    out: Array = np.minimum(half, margin_db)
    return out
