"""The physics of one link, vectorised over frames.

Everything a frame goes through between the emitter's antenna and the
numbers a driver reports: path loss (the published table model or a
physical two-ray model), extra loss where the straight path crosses a
building, the gain of each beam of the receiving antenna, small-scale fading
(optional Rayleigh or Rician, correlated between the two co-located chains),
measurement noise, quantisation to the card's step, missing chains, and the
driver's combined signal.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
import numpy.typing as npt

from rfsas_hw.rf.propagation import TABLE_OFFSET_DB, path_loss_db
from rfsas_hw.twin.scenario import BuildingSpec, RfSpec

Array = npt.NDArray[np.float64]


def building_array(buildings: Sequence[BuildingSpec]) -> Array:
    """Rectangles as an ``(m, 5)`` array: x_min, x_max, y_min, y_max, loss_db."""
    if not buildings:
        return np.empty((0, 5))
    return np.array([[b.x_min_m, b.x_max_m, b.y_min_m, b.y_max_m, b.loss_db] for b in buildings])


def _segments(p0: Array, p1: Array, rects: Array) -> tuple[Array, Array, Array]:
    """The arguments of the compiled loops, as float64 C arrays."""
    return (
        np.ascontiguousarray(p0, dtype=np.float64).reshape(-1, 2),
        np.ascontiguousarray(p1, dtype=np.float64).reshape(-1, 2),
        np.ascontiguousarray(rects, dtype=np.float64),
    )


def segment_crossings(p0: Array, p1: Array, rects: Array) -> npt.NDArray[np.bool_]:
    """Which segments cross which rectangles, shape ``(n, m)``.

    ``p0`` and ``p1`` are ``(n, 2)`` end points, ``rects`` an ``(m, ≥4)``
    array of x_min, x_max, y_min, y_max. A segment crosses a rectangle when
    any part of it lies strictly inside (slab clipping, Liang–Barsky); a
    segment that only grazes an edge does not count, nor does one with a NaN
    end. Only the pairs whose boxes overlap are clipped (a segment cannot
    enter a rectangle its box does not overlap), so a district's buildings
    cost what the few near each segment cost. A compiled loop
    (:mod:`rfsas_hw.twin._blockage_kernel`).
    """
    from rfsas_hw.twin import _blockage_kernel as k

    if len(p0) == 0 or len(rects) == 0:
        return np.zeros((len(p0), len(rects)), dtype=bool)
    out: npt.NDArray[np.bool_] = k.crossings(*_segments(p0, p1, rects))
    return out


def blockage_db(
    p0: Array,
    p1: Array,
    rects: Array,
    candidates: Sequence[tuple[int, npt.NDArray[np.intp] | None]] | None = None,
) -> tuple[Array, npt.NDArray[np.bool_]]:
    """Extra loss of each path from the buildings it crosses (:func:`segment_crossings`;
    ``rects`` column 4 is each building's loss), dB, and whether any was crossed.

    Args:
        p0, p1: the paths' end points, ``(n, 2)``, metres.
        rects: the buildings, ``(m, 5)``.
        candidates: the caller's knowledge of which buildings a path can cross at all:
            consecutive groups of rows as ``(rows in the group, the building indices
            its paths may cross, increasing; None: any)``, the counts adding up to
            ``n``. A building left out of a group's list is not looked at for its
            paths (it must be one they cannot cross); None: every path against every
            building.

    Raises:
        ValueError: the groups' rows do not add up to ``n``.
    """
    from rfsas_hw.twin import _blockage_kernel as k

    n, m = len(p0), len(rects)
    if n == 0 or m == 0:
        return np.zeros(n), np.zeros(n, dtype=bool)
    every = np.arange(m, dtype=np.intp)
    groups = [(n, every)] if candidates is None else candidates
    counts = [c for c, _ in groups]
    if sum(counts) != n:
        raise ValueError(f"the groups of paths hold {sum(counts)} rows, not {n}")
    lists = [every if idx is None else idx for _, idx in groups]
    starts = np.zeros(len(groups) + 1, np.intp)
    np.cumsum(counts, out=starts[1:])
    cand_ptr = np.zeros(len(groups) + 1, np.intp)
    np.cumsum([len(c) for c in lists], out=cand_ptr[1:])
    cand_idx = np.ascontiguousarray(np.concatenate(lists), dtype=np.intp)
    loss: Array
    hit: npt.NDArray[np.bool_]
    loss, hit = k.blockage(*_segments(p0, p1, rects), starts, cand_ptr, cand_idx)
    return loss, hit


def nearest_first(point: tuple[float, float], rects: Array) -> tuple[Array, npt.NDArray[np.intp]]:
    """The rectangles ordered by their distance from ``point`` (metres; 0 inside one):
    the sorted distances and the rectangles' indices in that order. A segment that
    starts at ``point`` and is ``L`` long can cross only those within ``L``."""
    x, y = point
    dx = np.maximum(np.maximum(rects[:, 0] - x, x - rects[:, 1]), 0.0)
    dy = np.maximum(np.maximum(rects[:, 2] - y, y - rects[:, 3]), 0.0)
    dist = np.hypot(dx, dy)
    order = np.argsort(dist, kind="stable")
    return np.asarray(dist[order], np.float64), order.astype(np.intp)


def link_path_loss_db(distance_m: Array, freq_mhz: npt.ArrayLike, rf: RfSpec) -> Array:
    """Path loss per frame with the scenario's model, dB."""
    d = np.maximum(np.asarray(distance_m, dtype=np.float64), rf.min_distance_m)
    offset = TABLE_OFFSET_DB if rf.offset_db is None else rf.offset_db
    if rf.path_loss == "table":
        return path_loss_db(d, "table", offset_db=offset)
    freqs = np.asarray(freq_mhz)
    if len(d) and freqs.min() == freqs.max():  # the usual case: one frequency, no grouping
        return path_loss_db(
            d, rf.path_loss, freq_mhz=float(freqs[0]), ht_m=rf.tx_height_m, hr_m=rf.rx_height_m
        )
    out = np.empty_like(d)
    for f in np.unique(freqs):
        sel = freqs == f
        out[sel] = path_loss_db(
            d[sel], rf.path_loss, freq_mhz=float(f), ht_m=rf.tx_height_m, hr_m=rf.rx_height_m
        )
    return out


def fading_db(
    n: int,
    model: Literal["none", "rayleigh", "rician"],
    k_db: float,
    correlation: float,
    rng: np.random.Generator,
    rng_own: np.random.Generator | None = None,
) -> Array:
    """Power gain of small-scale fading on two chains, dB, shape ``(n, 2)``, mean power 1.

    The complex gain of each chain is a common part plus an independent part,
    ``h_i = √ρ·c + √(1−ρ)·u_i``, so ``ρ`` is the correlation between chains.
    Rician adds a fixed direct component with power ratio ``K`` to the
    scattered part. With ``rng_own`` the independent parts come from that
    stream (each stream then advances by a fixed amount per frame, so frames
    can be drawn in pieces).
    """
    if model == "none" or n == 0:
        return np.zeros((n, 2))
    common, own = fading_normals(n, rng, rng_own)
    return fading_from_normals(common, own, model, k_db, correlation)


def fading_normals(
    n: int, rng: np.random.Generator, rng_own: np.random.Generator | None = None
) -> tuple[Array, Array]:
    """The standard normals :func:`fading_db` draws for ``n`` frames: (n, 1, 2) and (n, 2, 2)."""
    common = rng.standard_normal((n, 1, 2))
    own = (rng if rng_own is None else rng_own).standard_normal((n, 2, 2))
    return common, own


def fading_from_normals(
    common: Array,
    own: Array,
    model: Literal["none", "rayleigh", "rician"],
    k_db: float,
    correlation: float,
) -> Array:
    """:func:`fading_db` from its normals (:func:`fading_normals`; rows of several draws
    may be stacked), dB, shape ``(n, 2)``."""
    n = len(common)
    if model == "none" or n == 0:
        return np.zeros((n, 2))
    c = (common[..., 0] + 1j * common[..., 1]) / math.sqrt(2.0)
    u = (own[..., 0] + 1j * own[..., 1]) / math.sqrt(2.0)
    scatter = math.sqrt(correlation) * c + math.sqrt(1.0 - correlation) * u
    if model == "rician":
        k = 10.0 ** (k_db / 10.0)
        h = math.sqrt(k / (k + 1.0)) + math.sqrt(1.0 / (k + 1.0)) * scatter
    else:
        h = scatter
    return np.asarray(10.0 * np.log10(np.maximum(np.abs(h) ** 2, 1e-12)), dtype=np.float64)


def combine_chains(chain_dbm: Array, how: Literal["max", "power-sum"]) -> Array:
    """The driver's combined signal from per-chain readings (NaN = chain absent), dBm.

    Rows without any chain give NaN.
    """
    present = ~np.isnan(chain_dbm)
    any_present = present.any(axis=1)
    if how == "max":
        filled = np.where(present, chain_dbm, -np.inf)
        out = np.max(filled, axis=1)
    else:
        mw = np.where(present, np.power(10.0, np.nan_to_num(chain_dbm) / 10.0), 0.0)
        with np.errstate(divide="ignore"):
            out = 10.0 * np.log10(mw.sum(axis=1))
    return np.where(any_present, out, np.nan)
