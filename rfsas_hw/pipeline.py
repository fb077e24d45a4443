"""The sensor pipeline: observations → DF → hashed bearings.

This is the one place where an observation (with its raw MAC) becomes
something that may leave the sensor: a :class:`~rfsas_hw.records.BearingBatch`
whose emitter column holds keyed hashes only.

A frame whose epoch nonce has not arrived yet (the authority is late or
unreachable) is not lost and does not stop the sensor: it waits, with its
bearing already computed, in a bounded hold queue, and is hashed and released
as soon as the nonce arrives. Frames whose epoch is over (the nonce can no
longer come) are dropped and counted; so are the oldest held frames when the
queue is full. While frames wait or are dropped, the pipeline's nonce alarm
is raised; it clears when frames flow again.
"""

from __future__ import annotations

import itertools
import logging
import time
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import relative_to_compass
from rfsas_hw.df.arraycsi import array_df_result
from rfsas_hw.df.calibration import Calibration
from rfsas_hw.df.estimate import DfFlag, DfResult, estimate
from rfsas_hw.df.fovguard import FovGuard, boresight_levels
from rfsas_hw.df.hybrid import phase_df_result
from rfsas_hw.privacy.hashing import MacHasher, NonceExpiredError, NonceUnavailableError
from rfsas_hw.records import BearingBatch, ObservationBatch, Pose

log = logging.getLogger(__name__)

Array = npt.NDArray[np.floating[Any]]

DEFAULT_HOLD_MAX = 200_000
"""Frames a pipeline holds at most while it waits for a nonce (about 10 MB)."""
DF_MEMO_ROWS = 8
"""Batches of at most this many frames look their DF results up reading pair by pair.

A batch of 1–8 known pairs costs about 7–10 µs against 50–65 µs for
:func:`estimate` (``bench/bench_small_batches.py``)."""
DF_MEMO_MAX = 1 << 14
"""Reading pairs a pipeline remembers at most (then it forgets the older half)."""
DF_MEMO_REACH = 4
"""On a miss, the memo also learns the pairs up to this many reading steps around
each new pair (a moving emitter's next readings are near its last ones)."""


@dataclass
class PipelineStats:
    """What the pipeline did with the observations it was given."""

    observations: int = 0
    """Observations received."""
    bearings: int = 0
    """Valid bearings produced."""
    rejected: Counter[str] = field(default_factory=Counter)
    """Observations without a bearing, by reason (a frame may count under several)."""
    emitters: set[int] = field(default_factory=set)
    """Distinct emitter ids seen (hashed)."""
    held: int = 0
    """Frames waiting for their epoch's nonce now."""
    held_max: int = 0
    """Most frames that waited at once."""
    released: int = 0
    """Frames that waited for a nonce and were then hashed and sent on."""
    nonce_alarms: int = 0
    """Times the nonce alarm was raised (frames had to wait or were dropped)."""

    def as_dict(self) -> dict[str, object]:
        """A JSON-friendly copy."""
        return {
            "observations": self.observations,
            "bearings": self.bearings,
            "rejected": dict(self.rejected),
            "emitters": len(self.emitters),
            "held": self.held,
            "held_max": self.held_max,
            "released": self.released,
            "nonce_alarms": self.nonce_alarms,
        }


class _DfMemo:
    """DF results of single RSSI pairs, kept by (RSSI 1, RSSI 2, channel, one channel).

    A driver reports RSSI in whole or half dB, so a sensor sees the same few
    thousand pairs again and again, and :func:`estimate` works element by
    element, so a pair's result is reused instead of running a few dozen
    numpy calls on a handful of frames. What a pair gets can still depend on
    its batch in one way: with one channel in the batch, ``db`` mode gives σ in
    float64, with several the columns are float32 — so whether the batch had
    one channel is part of the key, and each row keeps its columns' dtypes.
    A pair's boresight-equivalent level (:func:`boresight_levels`, what the
    field-of-view guard judges) is a function of the pair and its bearing
    alone, so it is kept with the result. Pairs with a NaN are never kept.
    A batch on one channel that misses also has the pairs around its new ones
    (:data:`DF_MEMO_REACH` steps of the calibration's reading step) computed in
    the same :func:`estimate` call: a moving emitter's next readings are near
    its last ones, and one call on a hundred pairs costs little more than one
    on three.
    Pipelines of one calibration (the units of one build) share a memo:
    :func:`_df_memo`. A result computed in another batch may differ from this
    batch's own in the last bit (numpy's SIMD and scalar loops); it is the same
    estimate.
    """

    def __init__(self, calibration: Calibration, min_snr_db: float | None) -> None:
        self.calibration = calibration
        self.min_snr_db = min_snr_db
        self.channel_free = len(calibration.tables) == 1 and calibration.tables[0].channel is None
        """One table for every channel: the channel never matters."""
        self.rows: dict[
            tuple[float, float, int, bool], tuple[float, float, float, int, Any, float]
        ] = {}
        """Per key: angle, σ, SNR, flags, the columns' dtypes and the boresight level."""
        self._dtypes: dict[tuple[Any, ...], tuple[Any, ...]] = {}
        """One tuple object per combination of column dtypes (compared by identity)."""
        step = calibration.step_db
        reach = np.arange(-DF_MEMO_REACH, DF_MEMO_REACH + 1) * step
        self._offsets = (
            np.stack(np.meshgrid(reach, reach, indexing="ij"), axis=-1).reshape(-1, 2)
            if step > 0.0 and DF_MEMO_REACH > 0
            else None
        )
        """Steps from a pair to its neighbours, dB, shape (m, 2) (None: no neighbours)."""

    def estimate(self, batch: ObservationBatch) -> DfResult:
        """:func:`estimate` of the batch's first two chains."""
        return self.estimate_with_levels(batch)[0]

    def estimate_with_levels(self, batch: ObservationBatch) -> tuple[DfResult, Array]:
        """:meth:`estimate` and the frames' boresight-equivalent levels, dBm
        (:func:`boresight_levels` of that result; NaN without a bearing)."""
        return self.readings(batch.rssi_dbm, batch.channel)

    def readings(
        self, rssi: npt.NDArray[np.float32], channel: npt.NDArray[np.int16]
    ) -> tuple[DfResult, Array]:
        """:meth:`estimate_with_levels` of the readings ``rssi`` (n, ≥ 2; the first two
        chains count) on ``channel`` (n,)."""
        batch_channel = channel
        channels = channel.tolist()
        one = self.channel_free or min(channels) == max(channels)
        keys = [(r[0], r[1], c, one) for r, c in zip(rssi.tolist(), channels, strict=True)]
        rows = self.rows
        got = [rows.get(k) for k in keys]
        if any(g is None for g in got) or any(g[4] is not got[0][4] for g in got):  # type: ignore[index]
            n = len(keys)
            r1, r2, channel = rssi[:, 0], rssi[:, 1], batch_channel
            if one:  # the neighbours' results go into the same call
                near = self._neighbours([k for k, g in zip(keys, got, strict=True) if g is None])
                if len(near):
                    r1 = np.concatenate([r1, near[:, 0]])
                    r2 = np.concatenate([r2, near[:, 1]])
                    channel = np.full(len(r1), channels[0], batch_channel.dtype)
                    keys = keys + [(a, b, channels[0], one) for a, b in near.tolist()]
            cal = self.calibration
            result = estimate(cal, r1, r2, channel, min_snr_db=self.min_snr_db)
            levels = boresight_levels(cal, result, r1, r2, channel)
            if len(rows) + len(keys) > DF_MEMO_MAX:
                for k in list(itertools.islice(rows, len(rows) // 2 + len(keys))):
                    del rows[k]
            dtypes = (
                result.angle_deg.dtype,
                result.sigma_deg.dtype,
                result.snr_db.dtype,
                result.flags.dtype,
            )
            dtypes = self._dtypes.setdefault(dtypes, dtypes)
            for k, a, s, q, f, e in zip(
                keys,
                result.angle_deg.tolist(),
                result.sigma_deg.tolist(),
                result.snr_db.tolist(),
                result.flags.tolist(),
                levels.tolist(),
                strict=True,
            ):
                if k[0] == k[0] and k[1] == k[1]:  # NaN never matches a key
                    rows[k] = (a, s, q, f, dtypes, e)
            if len(keys) == n:
                return result, levels
            head = DfResult(
                result.angle_deg[:n].copy(),
                result.sigma_deg[:n].copy(),
                result.snr_db[:n].copy(),
                result.flags[:n].copy(),
            )
            return head, levels[:n].copy()
        dtypes = got[0][4]  # type: ignore[index]
        result = DfResult(
            np.array([g[0] for g in got], dtypes[0]),  # type: ignore[index]
            np.array([g[1] for g in got], dtypes[1]),  # type: ignore[index]
            np.array([g[2] for g in got], dtypes[2]),  # type: ignore[index]
            np.array([g[3] for g in got], dtypes[3]),  # type: ignore[index]
        )
        return result, np.array([g[5] for g in got], np.float64)  # type: ignore[index]

    def _neighbours(self, missing: list[tuple[float, float, int, bool]]) -> Array:
        """Reading pairs on the calibration's step grid within :data:`DF_MEMO_REACH`
        steps of the ``missing`` pairs, neither among them nor known yet, shape (m, 2),
        float32 (the readings' own dtype: their keys are the keys such readings get)."""
        pairs = [(k[0], k[1]) for k in missing if k[0] == k[0] and k[1] == k[1]]
        if not pairs or self._offsets is None:
            return np.empty((0, 2), np.float32)
        centre = np.array(pairs, np.float64)
        grid = (centre[:, None, :] + self._offsets).reshape(-1, 2).astype(np.float32)
        c, one = missing[0][2], missing[0][3]
        rows, own = self.rows, set(pairs)
        fresh = [
            p
            for p in dict.fromkeys(map(tuple, grid.tolist()))
            if p not in own and (p[0], p[1], c, one) not in rows
        ]
        return np.array(fresh, np.float32).reshape(-1, 2)


_MEMOS: dict[tuple[int, float | None], _DfMemo] = {}
_MEMOS_MAX = 32


def _df_memo(calibration: Calibration, min_snr_db: float | None) -> _DfMemo:
    """The memo shared by pipelines with this calibration object and SNR floor."""
    key = (id(calibration), min_snr_db)
    memo = _MEMOS.get(key)
    if memo is None or memo.calibration is not calibration:
        if len(_MEMOS) >= _MEMOS_MAX:
            _MEMOS.clear()
        memo = _MEMOS[key] = _DfMemo(calibration, min_snr_db)
    return memo


_FLAG_NAMES = tuple(
    (int(f), f.name.lower()) for f in DfFlag if f is not DfFlag.NONE and f.name is not None
)
"""Each :class:`DfFlag` bit with the name its frames are counted under."""


@dataclass(slots=True)
class _Waiting:
    """Frames of one epoch with their bearings computed, waiting for the nonce."""

    epoch: int
    frames: ObservationBatch
    relative_deg: np.ndarray
    sigma_deg: np.ndarray
    snr_db: np.ndarray


class SensorPipeline:
    """Turn observation batches into bearing batches for one sensor.

    Several sensors of one process (the units of a twin worker) go through their
    pipelines together with :func:`process_units`, which is what :meth:`process`
    does for one.

    Args:
        calibration: the antenna pair's calibration (one table per channel or one for all).
        hasher: MAC → emitter id (the privacy stage).
        sensor_id: id written into every bearing.
        pose: where the sensor is and which way its boresight points (compass).
        min_snr_db: frames whose stronger antenna is below this are rejected (None: keep all).
        hold_max: most frames held while their epoch's nonce is missing; beyond it
            the oldest are dropped (counted as ``hold_overflow``).
        fov_guard: the level rule in time (:class:`~rfsas_hw.df.fovguard.FovGuard`), keyed
            by the raw MAC inside this process; None: one with the default settings.
        guard_key: added to every MAC to key ``fov_guard``'s state: pipelines sharing
            one guard (so that :func:`process_units` judges all their frames in one
            pass) keep their emitters apart with different keys; a multiple of
            2⁴⁸ below 2⁶⁴ (MACs have 48 bits).

    Raises:
        ValueError: ``guard_key`` is not a multiple of 2⁴⁸ in [0, 2⁶⁴).
    """

    def __init__(
        self,
        calibration: Calibration,
        hasher: MacHasher,
        sensor_id: str,
        pose: Pose,
        *,
        min_snr_db: float | None = None,
        hold_max: int = DEFAULT_HOLD_MAX,
        fov_guard: FovGuard | None = None,
        guard_key: int = 0,
    ) -> None:
        if not 0 <= guard_key < 1 << 64 or guard_key % (1 << 48):
            raise ValueError(f"guard_key {guard_key} is not a multiple of 2**48 in [0, 2**64)")
        self.calibration = calibration
        self.fov_guard = FovGuard() if fov_guard is None else fov_guard
        self.guard_key = np.uint64(guard_key)
        self.hasher = hasher
        self.sensor_id = sensor_id
        self.pose = pose
        self.min_snr_db = min_snr_db
        self.hold_max = max(0, int(hold_max))
        self.stats = PipelineStats()
        self._waiting: deque[_Waiting] = deque()
        self.alarm = False
        """True while frames wait for, or were lost for want of, a nonce."""
        self.end_wait_s = 0.0
        """How long :meth:`finish` waits for missing nonces when the input ends, seconds."""
        self.alarm_reason = ""
        self._memo: _DfMemo | None = None

    def _estimate(
        self, rssi: npt.NDArray[np.float32], channel: npt.NDArray[np.int16]
    ) -> tuple[DfResult, Array | None]:
        """DF of the readings' first two chains (a few frames through the memo), and the
        frames' boresight-equivalent levels when the memo has them (else None)."""
        if len(rssi) > DF_MEMO_ROWS:
            result = estimate(
                self.calibration, rssi[:, 0], rssi[:, 1], channel, min_snr_db=self.min_snr_db
            )
            return result, None
        memo = self._memo
        if (
            memo is None
            or memo.calibration is not self.calibration
            or memo.min_snr_db != self.min_snr_db
        ):
            memo = self._memo = _df_memo(self.calibration, self.min_snr_db)
        return memo.readings(rssi, channel)

    def _guard(
        self,
        batch: ObservationBatch,
        result: DfResult,
        levels_dbm: Array | None = None,
        folds: bool = True,
    ) -> DfResult:
        """The level rule in time (:class:`FovGuard`) on the amplitude or phase bearings;
        ``levels_dbm``: the bearings' boresight-equivalent levels if known; ``folds``:
        False for phase bearings (the amplitude pair's folds are not theirs)."""
        rssi = batch.rssi_dbm
        return self.fov_guard.apply(
            self.calibration,
            result,
            rssi[:, 0],
            rssi[:, 1],
            batch.channel,
            batch.mac + self.guard_key,
            batch.t_ns,
            levels_dbm,
            folds=folds,
        )

    def process(self, batch: ObservationBatch) -> BearingBatch:
        """Valid bearings of ``batch``, in order, after any held frames whose nonce has
        arrived; invalid frames are counted by reason. Never raises for a missing
        nonce: those frames are held (or dropped and counted, see the class).
        """
        return process_units([(self, batch)])[0]

    def _bearings(
        self, batch: ObservationBatch, result: DfResult, released: BearingBatch | None
    ) -> BearingBatch:
        """The last stage of :meth:`process`: count the invalid frames, hash (or hold)
        the valid ones by epoch, after ``released``."""
        n = len(batch)
        n_bad = int(np.count_nonzero(result.flags))
        if n_bad:
            # each distinct combination of flags once (there are few), each flag it has
            combos, counts = np.unique(result.flags[result.flags != 0], return_counts=True)
            for combo, count in zip(combos.tolist(), counts.tolist(), strict=True):
                for bit, name in _FLAG_NAMES:
                    if combo & bit:
                        self.stats.rejected[name] += count
            if n_bad == n:
                return released if released is not None else BearingBatch.empty(self.sensor_id)
            valid = result.flags == 0
            good = batch.select(valid)
            angle = result.angle_deg[valid].astype(np.float64)
            sigma, snr = result.sigma_deg[valid], result.snr_db[valid]
        else:  # the usual case: every frame valid, nothing to pick
            good = batch
            angle = result.angle_deg.astype(np.float64)
            sigma, snr = result.sigma_deg, result.snr_db
        parts = [released] if released is not None and len(released) else []
        epoch_ns = self.hasher.epoch_ns
        times = good.t_ns.tolist()
        first, last = min(times) // epoch_ns, max(times) // epoch_ns
        epochs = None if first == last else good.t_ns // epoch_ns
        distinct = [first] if epochs is None else np.unique(epochs).tolist()
        for epoch in distinct:
            if epochs is None:  # the usual case: no copies
                waiting = _Waiting(int(epoch), good, angle, sigma, snr)
            else:
                sel = epochs == epoch
                waiting = _Waiting(int(epoch), good.select(sel), angle[sel], sigma[sel], snr[sel])
            if any(w.epoch == waiting.epoch for w in self._waiting):
                self._hold(waiting)  # behind the frames of its epoch already waiting
                continue
            out = self._hash(waiting)
            if out is not None and len(out):
                parts.append(out)
        return BearingBatch.concat(self.sensor_id, parts)

    def release(self) -> BearingBatch:
        """Bearings of held frames whose nonce has now arrived (empty if none); drops
        and counts held frames whose epoch is over. Call it now and then when no
        frames come, so held frames do not wait for the next one."""
        parts: list[BearingBatch] = []
        while self._waiting:
            head = self._waiting[0]
            out = self._hash(head, holding=True)
            if out is None:
                break  # still missing: later epochs wait behind it, in order
            self._waiting.popleft()
            self.stats.held -= len(head.frames)
            self.stats.released += len(out)
            if len(out):
                parts.append(out)
        return BearingBatch.concat(self.sensor_id, parts)

    def finish(self, wait_s: float = 0.0) -> BearingBatch:
        """At the end of a run: what can still be released, waiting up to ``wait_s``
        seconds for missing nonces (a short recording may end before the authority's
        first envelope arrives); the rest is dropped and counted as ``nonce_unavailable``."""
        parts = [self.release()]
        deadline = time.monotonic() + wait_s
        while self._waiting and time.monotonic() < deadline:
            time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))
            parts.append(self.release())
        out = BearingBatch.concat(self.sensor_id, [p for p in parts if len(p)])
        for waiting in self._waiting:
            self.stats.rejected["nonce_unavailable"] += len(waiting.frames)
        self._waiting.clear()
        self.stats.held = 0
        return out

    def _hash(self, waiting: _Waiting, *, holding: bool = False) -> BearingBatch | None:
        """Bearings of ``waiting`` (empty if its epoch is over), or None when it has to
        (keep) wait(ing)."""
        frames = waiting.frames
        try:
            emitters = self.hasher.hash_batch(frames.mac, frames.t_ns)
        except NonceExpiredError as err:
            self.stats.rejected["nonce_expired"] += len(frames)
            self._raise_alarm(f"{len(frames)} frames dropped: {err}")
            return BearingBatch.empty(self.sensor_id)
        except NonceUnavailableError as err:
            if not holding:
                self._hold(waiting)
                self._raise_alarm(f"holding frames: {err}")
            return None
        self.stats.emitters.update(emitters.tolist())
        if self.alarm and ((holding and len(self._waiting) == 1) or not self._waiting):
            self.alarm = False
            log.warning(
                "nonce alarm cleared: bearings flow again (%d held frames released so far)",
                self.stats.released + (len(frames) if holding else 0),
            )
        out = BearingBatch(
            sensor_id=self.sensor_id,
            t_ns=frames.t_ns,
            azimuth_deg=relative_to_compass(waiting.relative_deg, self.pose.heading_deg),
            sigma_deg=waiting.sigma_deg,
            snr_db=waiting.snr_db,
            channel=frames.channel,
            emitter=emitters,
            relative_deg=waiting.relative_deg,
        )
        self.stats.bearings += len(out)
        return out

    def _hold(self, waiting: _Waiting) -> None:
        self._waiting.append(waiting)
        self.stats.held += len(waiting.frames)
        while self.stats.held > self.hold_max and self._waiting:
            oldest = self._waiting[0]
            excess = self.stats.held - self.hold_max
            if excess >= len(oldest.frames):
                self._waiting.popleft()
                dropped = len(oldest.frames)
            else:
                keep = slice(excess, None)
                self._waiting[0] = _Waiting(
                    oldest.epoch,
                    oldest.frames.select(keep),
                    oldest.relative_deg[keep],
                    oldest.sigma_deg[keep],
                    oldest.snr_db[keep],
                )
                dropped = excess
            self.stats.held -= dropped
            self.stats.rejected["hold_overflow"] += dropped
        self.stats.held_max = max(self.stats.held_max, self.stats.held)

    def _raise_alarm(self, reason: str) -> None:
        self.alarm_reason = reason
        if not self.alarm:
            self.alarm = True
            self.stats.nonce_alarms += 1
            log.warning("nonce alarm: %s", reason)


def _split(result: DfResult, bounds: list[int]) -> list[DfResult]:
    """``result`` cut at ``bounds`` (row offsets, first 0, last its length); views."""
    return [
        DfResult(
            result.angle_deg[lo:hi],
            result.sigma_deg[lo:hi],
            result.snr_db[lo:hi],
            result.flags[lo:hi],
        )
        for lo, hi in itertools.pairwise(bounds)
    ]


def _joined(parts: list[npt.NDArray[Any]]) -> npt.NDArray[Any]:
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def process_units(
    items: Sequence[tuple[SensorPipeline, ObservationBatch]],
) -> list[BearingBatch]:
    """:meth:`SensorPipeline.process` of each ``(pipeline, batch)``, the sensors together:
    one DF call for the batches of pipelines with the same calibration (object) and
    SNR floor, one pass of the level rule for those that also share a field-of-view
    guard (each pipeline's emitters kept apart by its ``guard_key``), so that many
    units of one process pay the fixed cost of those stages once, not once per unit.
    Each pipeline's bearings, counters, held frames and nonce alarm are its own, as if
    it had processed its batch alone; the bearings are the same estimates (a DF
    result can differ in the last bit with the rows it is computed with, see
    :class:`_DfMemo`). Never raises for a missing nonce.

    Returns:
        The bearings of each item, in the items' order.

    Raises:
        ValueError: a pipeline is given more than one batch (its frames must go
            through it in order, one batch after the other).
    """
    if len({id(pipe) for pipe, _ in items}) != len(items):
        raise ValueError("process_units takes one batch per pipeline")
    out: list[BearingBatch | None] = [None] * len(items)
    released: list[BearingBatch | None] = []
    groups: dict[tuple[int, float | None], list[int]] = {}
    for k, (pipe, batch) in enumerate(items):
        n = len(batch)
        pipe.stats.observations += n
        released.append(pipe.release() if pipe._waiting else None)
        if n == 0 or batch.n_antennas < 2:
            if n:
                pipe.stats.rejected["missing_chain"] += n
            rel = released[k]
            out[k] = rel if rel is not None else BearingBatch.empty(pipe.sensor_id)
            continue
        groups.setdefault((id(pipe.calibration), pipe.min_snr_db), []).append(k)
    results: dict[int, DfResult] = {}
    guarded: dict[tuple[int, int], list[tuple[int, DfResult, Array]]] = {}
    for ks in groups.values():
        first = items[ks[0]][0]
        cal = first.calibration
        rssi = _joined([items[k][1].rssi_dbm[:, :2] for k in ks])
        channel = _joined([items[k][1].channel for k in ks])
        result, levels = first._estimate(rssi, channel)
        bounds = [0, *itertools.accumulate(len(items[k][1]) for k in ks)]
        for k, part, (lo, hi) in zip(
            ks, _split(result, bounds), itertools.pairwise(bounds), strict=True
        ):
            pipe, batch = items[k]
            if cal.phase is not None and batch.csi is not None:
                # a CSI receiver with a phase calibration: interferometer bearings (their
                # levels are the phase bearings', computed by the guard)
                results[k] = pipe._guard(batch, phase_df_result(cal, batch, part), folds=False)
            elif cal.array is not None and batch.csi is not None:
                # an array with a CSI receiver: every antenna in one fit, over its own field
                # of view (the amplitude pair's level curve says nothing about it)
                results[k] = array_df_result(cal, batch, part)
            else:
                if levels is None:  # the frames' boresight levels, once for the group
                    levels = boresight_levels(cal, result, rssi[:, 0], rssi[:, 1], channel)
                guard = (id(pipe.fov_guard), id(cal))
                guarded.setdefault(guard, []).append((k, part, levels[lo:hi]))
    for members in guarded.values():
        # the level rule in time over every member's frames in one pass: each member's
        # frames stay in their order, its emitters apart from the others' by its key
        ks = [k for k, _, _ in members]
        first = items[ks[0]][0]
        batches = [items[k][1] for k in ks]
        keys = _joined([b.mac + items[k][0].guard_key for k, b in zip(ks, batches, strict=True)])
        joined = DfResult(
            _joined([m[1].angle_deg for m in members]),
            _joined([m[1].sigma_deg for m in members]),
            _joined([m[1].snr_db for m in members]),
            _joined([m[1].flags for m in members]),
        )
        judged = first.fov_guard.apply(
            first.calibration,
            joined,
            _joined([b.rssi_dbm[:, 0] for b in batches]),
            _joined([b.rssi_dbm[:, 1] for b in batches]),
            _joined([b.channel for b in batches]),
            keys,
            _joined([b.t_ns for b in batches]),
            _joined([m[2] for m in members]),
        )
        bounds = [0, *itertools.accumulate(len(b) for b in batches)]
        results.update(zip(ks, _split(judged, bounds), strict=True))
    for k, result in results.items():
        pipe, batch = items[k]
        out[k] = pipe._bearings(batch, result, released[k])
    return [
        o if o is not None else BearingBatch.empty(items[k][0].sensor_id) for k, o in enumerate(out)
    ]
