"""The streaming twin: the same world as :class:`~rfsas_hw.twin.world.World`, one window at a time.

A simulator that runs closed loop cannot hand the twin a whole scenario in
advance: it knows where everything is only up to the current step. The
streaming twin therefore keeps

- :class:`LiveTrack` objects that grow a knot per simulator step (position,
  and the heading when the simulator reports one);
- one traffic generator per emitter (:class:`~rfsas_hw.twin.traffic.EmitterTraffic`)
  that keeps its random stream between windows;
- per-sensor random streams (:class:`~rfsas_hw.twin.world.ReceiverStreams`)
  and a cursor, so :meth:`StreamTwin.receptions_between` computes the frames a
  sensor hears in ``[t0, t1)`` with exactly the physics of the offline world
  (scan plan, traffic models, path loss, blockage, beams, fading, noise,
  quantisation, driver quirks).

Consecutive windows give the same frames, readings and timestamps as one
offline run of the same scenario with the same seed, as long as the tracks
carry the same knots.

Emitters and movers can come and go while the twin runs
(:meth:`StreamTwin.add_mover`, :meth:`StreamTwin.add_emitter`,
:meth:`StreamTwin.retire_emitter`), which is what a simulator's entities do.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import wrap_deg_180
from rfsas_hw.errors import ConfigError, SimulationError
from rfsas_hw.records import mac_to_int
from rfsas_hw.twin.motion import Track
from rfsas_hw.twin.scan import ScanPlan
from rfsas_hw.twin.scenario import Detail, EmitterSpec, Scenario, SensorSpec
from rfsas_hw.twin.traffic import EmitterTraffic, Transmissions, traffic_streams
from rfsas_hw.twin.world import Listening, ReceiverStreams, Receptions, World, no_frames

Array = npt.NDArray[np.float64]

__all__ = ["LiveTrack", "StreamTwin", "extend_tracks"]


_COLUMNS = ("t", "emitter", "channel", "kind", "seq")
_HEARS_NONE = np.zeros(0, bool)


def _merge_frames(
    frames: dict[str, npt.NDArray[Any]], new: list[tuple[int, Transmissions]]
) -> dict[str, npt.NDArray[Any]]:
    """``frames`` plus each emitter's new frames, in time order (ties: emitter order).

    Frames of one emitter at the same time keep the order its generator gave them.
    """
    parts = [(i, tx) for i, tx in new if len(tx)]
    if not parts:
        return frames
    t = np.concatenate([frames["t"], *(tx.t_s for _, tx in parts)])
    emitter = np.concatenate(
        [frames["emitter"], *(np.full(len(tx), i, np.intp) for i, tx in parts)]
    )
    order = np.lexsort((emitter, t))
    return {
        "t": t[order],
        "emitter": emitter[order],
        "channel": np.concatenate([frames["channel"], *(tx.channel for _, tx in parts)])[order],
        "kind": np.concatenate([frames["kind"], *(tx.kind for _, tx in parts)])[order],
        "seq": np.concatenate([frames["seq"], *(tx.seq for _, tx in parts)])[order],
    }


def _interp_tracks(
    knots: list[tuple[Array, Array, Array]], track: npt.NDArray[np.intp], t: Array
) -> Array:
    """Positions at times ``t`` on tracks ``knots[track]`` (knot times, east, north), (n, 2).

    ``np.interp`` on each track, as the offline world interpolates one track;
    the rows are grouped by track with one sort, so a track costs two calls.
    """
    if len(knots) == 1:  # one track (the usual case of a small scene): nothing to group
        ts, xs, ys = knots[0]
        one = np.empty((len(t), 2))
        one[:, 0] = np.interp(t, ts, xs)
        one[:, 1] = np.interp(t, ts, ys)
        return one
    order = np.argsort(track, kind="stable")
    bounds = np.searchsorted(track[order], np.arange(len(knots) + 1)).tolist()
    t_sorted = t[order]
    xy = np.empty((len(t), 2))
    for u, (ts, xs, ys) in enumerate(knots):
        lo, hi = bounds[u], bounds[u + 1]
        if lo < hi:
            xy[lo:hi, 0] = np.interp(t_sorted[lo:hi], ts, xs)
            xy[lo:hi, 1] = np.interp(t_sorted[lo:hi], ts, ys)
    out = np.empty_like(xy)
    out[order] = xy
    return out


class LiveTrack:
    """A piecewise-linear track that grows a knot at a time.

    Between knots the mover moves in a straight line at constant speed; after
    the last knot it stands where that knot put it (as an offline
    :class:`~rfsas_hw.twin.motion.Track` does after its last waypoint). When
    every knot in use carries a heading, headings are interpolated between
    knots (the short way round); otherwise the heading follows the direction
    of motion, as offline.
    """

    def __init__(self) -> None:
        self._t = np.empty(16)
        self._x = np.empty(16)
        self._y = np.empty(16)
        self._h = np.empty(16)
        """Unwrapped heading at each knot, degrees (NaN: not reported)."""
        self._n = 0
        self._cache: Track | None = None
        self._last_t = -math.inf
        """Time of the newest knot, seconds (a float: the checks of every step read it)."""
        self._last_h = math.nan
        """Unwrapped heading of the newest knot, degrees (NaN: none, or not reported)."""

    def __len__(self) -> int:
        return self._n

    @property
    def first_s(self) -> float:
        """Time of the oldest knot kept, seconds (inf without knots)."""
        return float(self._t[0]) if self._n else math.inf

    @property
    def last_s(self) -> float:
        """Time of the newest knot, seconds (-inf without knots)."""
        return self._last_t

    def extend(self, t_s: float, x_m: float, y_m: float, heading_deg: float | None = None) -> None:
        """Add the knot ``(t_s, x_m, y_m)`` (and the heading, compass degrees, if known).

        Raises:
            SimulationError: ``t_s`` is before the newest knot, or a value is not finite.
        """
        h = None if heading_deg is None else np.array([heading_deg], np.float64)
        extend_tracks([self], t_s, np.array([x_m], np.float64), np.array([y_m], np.float64), h)

    def _push(self, t_s: float, x_m: float, y_m: float, h: float) -> None:
        """Append a checked knot (``h``: unwrapped heading, NaN if not reported)."""
        i = self._n
        if i == len(self._t):
            for name in ("_t", "_x", "_y", "_h"):
                old = getattr(self, name)
                grown = np.empty(2 * len(old))
                grown[: len(old)] = old
                setattr(self, name, grown)
        self._t[i], self._x[i], self._y[i], self._h[i] = t_s, x_m, y_m, h
        self._n = i + 1
        self._last_t, self._last_h = t_s, h
        self._cache = None

    def forget_before(self, t_s: float) -> None:
        """Drop knots no longer needed for times at or after ``t_s`` (keeps one before it)."""
        if self._n < 2:
            return
        keep_from = int(np.searchsorted(self._t[: self._n], t_s, side="right")) - 1
        if keep_from <= 0:
            return
        m = self._n - keep_from
        for name in ("_t", "_x", "_y", "_h"):
            arr = getattr(self, name)
            arr[:m] = arr[keep_from : self._n]
        self._n = m
        self._cache = None

    def knots(self) -> tuple[Array, Array, Array]:
        """The knots so far: times (s), east and north (m); views, not to be written to.

        Raises:
            SimulationError: no knot yet.
        """
        if self._n == 0:
            raise SimulationError("a live track has no knot yet")
        n = self._n
        return self._t[:n], self._x[:n], self._y[:n]

    def track(self) -> Track:
        """The knots so far as an offline :class:`Track`.

        Raises:
            SimulationError: no knot yet.
        """
        if self._n == 0:
            raise SimulationError("a live track has no knot yet")
        if self._cache is None:
            n = self._n
            self._cache = Track(self._t[:n].copy(), self._x[:n].copy(), self._y[:n].copy())
        return self._cache

    def position(self, t_s: npt.ArrayLike) -> Array:
        """Positions at times ``t_s``, shape ``(n, 2)`` (east, north), metres."""
        n = self._n
        if n < 2:
            return self.track().position(t_s)
        # what Track.position computes, on the knots themselves (no copy of them)
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        ts = self._t[:n]
        out = np.empty((len(t), 2))
        out[:, 0] = np.interp(t, ts, self._x[:n])
        out[:, 1] = np.interp(t, ts, self._y[:n])
        return out

    def velocity(self, t_s: npt.ArrayLike) -> Array:
        """Velocities at times ``t_s``, shape ``(n, 2)``, m/s."""
        return self.track().velocity(t_s)

    def speed_mps(self, t_s: npt.ArrayLike) -> Array:
        """Speeds at times ``t_s``, m/s."""
        return self.track().speed_mps(t_s)

    def heading_deg(self, t_s: npt.ArrayLike) -> Array:
        """Compass headings at times ``t_s``, degrees."""
        n = self._n
        h = self._h[:n]
        if n and not np.isnan(h).any():
            t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
            return np.asarray(np.mod(np.interp(t, self._t[:n], h), 360.0), np.float64)
        return self.track().heading_deg(t_s)


def extend_tracks(
    tracks: Sequence[LiveTrack],
    t_s: float,
    x_m: Array,
    y_m: Array,
    heading_deg: Array | None = None,
) -> None:
    """Add one knot at ``t_s`` to each of ``tracks``: ``(x_m[i], y_m[i])`` and, if known,
    the compass heading ``heading_deg[i]`` (degrees), as :meth:`LiveTrack.extend` does for
    one; the checks and the headings' unwrapping (the short way round from each track's
    last heading) run over all tracks at once.

    Raises:
        SimulationError: ``t_s`` is before a track's newest knot, or a value is not
            finite (no track is extended then).
    """
    x = np.asarray(x_m, np.float64)
    y = np.asarray(y_m, np.float64)
    if not math.isfinite(t_s) or not (np.isfinite(x).all() and np.isfinite(y).all()):
        bad = 0 if not math.isfinite(t_s) else int(np.flatnonzero(~np.isfinite(x + y))[0])
        raise SimulationError(f"track knot at t={t_s}: position ({x[bad]}, {y[bad]}) not finite")
    if tracks and t_s < max([tr._last_t for tr in tracks]):
        late = next(tr for tr in tracks if t_s < tr._last_t)
        raise SimulationError(
            f"track knot at t={t_s:.6f} s is before the newest one "
            f"({late._last_t:.6f} s); knots must come in time order"
        )
    if heading_deg is None:
        h = np.full(len(tracks), math.nan)
    else:
        heading = np.asarray(heading_deg, np.float64)
        if not np.isfinite(heading).all():
            bad = int(np.flatnonzero(~np.isfinite(heading))[0])
            raise SimulationError(f"track knot at t={t_s}: heading {heading[bad]} not finite")
        prev = np.array([tr._last_h for tr in tracks], np.float64)
        h = np.where(np.isnan(prev), np.mod(heading, 360.0), prev + wrap_deg_180(heading - prev))
    for tr, xi, yi, hi in zip(tracks, x.tolist(), y.tolist(), h.tolist(), strict=True):
        tr._push(t_s, xi, yi, hi)


class StreamTwin(World):
    """The digital twin driven window by window (see the module docstring).

    Args:
        scenario: sensors, buildings, RF settings, seed and start time; its
            movers start with empty live tracks and its emitters transmit from
            time 0. Its ``duration_s`` plays no part.
        detail: override the scenario's level of detail.
        listening: per sensor, a channel schedule replacing its scan plan
            (as for :class:`World`).
        start_s: scenario time the first window starts at, seconds.
        lookahead_s: traffic is generated this far beyond the window asked
            for, in one go (the frames do not depend on it: each generator
            gives the same frames however its time is cut up), seconds.
        reach_m: per standing sensor id, the farthest an emitter can be from it
            for its frames to be computed at all, metres: a frame from farther
            away is not heard and costs no physics (many units in one twin
            each compute only the emitters near them).

    Raises:
        ConfigError: a reach for a sensor the scenario does not have, on a
            vehicle, or not positive.
    """

    def __init__(
        self,
        scenario: Scenario,
        detail: Detail | None = None,
        listening: Mapping[str, Listening] | None = None,
        *,
        start_s: float = 0.0,
        lookahead_s: float = 1.0,
        reach_m: Mapping[str, float] | None = None,
    ) -> None:
        short = dataclasses.replace(scenario.spec, duration_s=1e-9)
        super().__init__(
            Scenario(spec=short, source=scenario.source, base_dir=scenario.base_dir),
            detail,
            listening,
        )
        self.emitters: list[EmitterSpec] = list(scenario.spec.emitters)
        """The transmitters so far; ``Receptions.emitter`` indexes this list."""
        self._emitter_ids = {e.id for e in self.emitters}
        self.live: dict[str, LiveTrack] = {m.id: LiveTrack() for m in scenario.spec.movers}
        """Track of every mover, by id."""
        seed = scenario.seed
        self._traffic: list[EmitterTraffic | None] = [
            EmitterTraffic(e.traffic, traffic_streams(seed, e.id, len(e.traffic)), start_s)
            for e in scenario.spec.emitters
        ]
        self._frames = no_frames()
        """Generated frames of every emitter not yet heard by every sensor, in time order."""
        self._fresh: list[int] = list(range(len(self.emitters)))
        """Emitters whose traffic has not been generated up to the horizon yet."""
        self.lookahead_s = float(lookahead_s)
        """How far beyond a window traffic is generated in one go, seconds."""
        self._horizon_s = float(start_s)
        self._rx = {s.id: ReceiverStreams(seed, s, self.detail) for s in scenario.spec.sensors}
        self.cursor_s: dict[str, float] = {s.id: float(start_s) for s in scenario.spec.sensors}
        """End of the last window computed for each sensor, seconds."""
        self.generated_s = float(start_s)
        """Frames before this time have been generated for every live emitter, seconds."""
        self._window_key: tuple[float, float, int] | None = None
        self._n_frames_added = 0
        self._window: dict[str, npt.NDArray[Any]] = {}
        self._window_xy: Array | None = None
        self._plans: dict[str, ScanPlan] = {}
        self._ready: dict[str, tuple[float, float, Receptions]] = {}
        """Windows computed ahead by :meth:`prepare`, by sensor id."""
        self._hear_cache: dict[str, npt.NDArray[np.bool_]] = {}
        self._trimmed_s = -math.inf
        """Where the frames and knots were last trimmed, seconds."""
        self.reach_m: dict[str, float] = {}
        """Per standing sensor id, how far away an emitter can be heard at most, metres."""
        for sid, reach in (reach_m or {}).items():
            s = scenario.sensor(sid)
            if s.pose is None or not reach > 0.0:
                raise ConfigError(
                    f"sensor {sid!r}: a reach ({reach} m) needs a standing sensor and a "
                    "positive distance"
                )
            self.reach_m[sid] = float(reach)

    # -- entities -------------------------------------------------------------------

    def add_mover(self, mover_id: str) -> LiveTrack:
        """A new, empty live track for ``mover_id``.

        Raises:
            SimulationError: the id is taken.
        """
        if mover_id in self.live:
            raise SimulationError(f"mover {mover_id!r} already exists")
        self.live[mover_id] = track = LiveTrack()
        return track

    def add_emitter(self, emitter: EmitterSpec, start_s: float | None = None) -> int:
        """Start an emitter at ``start_s`` (default: the generated time); its index.

        Its traffic draws from streams named by its id under the scenario seed.

        Raises:
            SimulationError: duplicate id or MAC, or an unknown carrier.
        """
        if emitter.id in self._emitter_ids:
            raise SimulationError(f"emitter {emitter.id!r} already exists")
        mac = mac_to_int(emitter.mac)
        if np.any(self.emitter_macs == np.uint64(mac)):
            raise SimulationError(f"emitter {emitter.id!r}: its MAC is already in use")
        if emitter.carried_by is not None and emitter.carried_by not in self.live:
            raise SimulationError(f"emitter {emitter.id!r}: no mover {emitter.carried_by!r}")
        start = self.generated_s if start_s is None else float(start_s)
        if start < self.generated_s:
            raise SimulationError(
                f"emitter {emitter.id!r} cannot start at {start:.3f} s: frames up to "
                f"{self.generated_s:.3f} s were already generated"
            )
        self.emitters.append(emitter)
        self._emitter_ids.add(emitter.id)
        self._set_emitters()
        self.emitter_macs = np.append(self.emitter_macs, np.uint64(mac))
        streams = traffic_streams(self.scenario.seed, emitter.id, len(emitter.traffic))
        self._traffic.append(EmitterTraffic(emitter.traffic, streams, start))
        self._fresh.append(len(self.emitters) - 1)
        return len(self.emitters) - 1

    def retire_emitter(self, index: int, t_s: float) -> None:
        """Emitter ``index`` sends nothing from ``t_s`` on (it left the simulation).

        Nor does it send anything after :attr:`generated_s` (the end of the
        windows asked for so far): a simulator reports an entity gone at the
        first step it is missing, and after its last knot its position is
        not known.
        """
        self._traffic[index] = None
        f = self._frames
        keep = (f["emitter"] != index) | (f["t"] < min(t_s, self.generated_s))
        if not keep.all():
            self._frames = {k: v[keep] for k, v in f.items()}
            self._n_frames_added += 1

    def _set_emitters(self) -> None:
        """Keep the scenario's emitter list (read by the offline code) in step."""
        spec = dataclasses.replace(self.scenario.spec, emitters=tuple(self.emitters))
        self.scenario = Scenario(
            spec=spec, source=self.scenario.source, base_dir=self.scenario.base_dir
        )

    # -- geometry -------------------------------------------------------------------

    def _carrier(self, index: int) -> LiveTrack | None:
        e = self.emitters[index]
        return self.live[e.carried_by] if e.carried_by is not None else None

    def emitter_position(self, index: int, t_s: npt.ArrayLike) -> Array:
        """Position of emitter ``index`` at times ``t_s``, shape (n, 2), metres.

        Raises:
            SimulationError: its carrier has no knot yet.
        """
        track = self._carrier(index)
        if track is None:
            return super().emitter_position(index, t_s)
        return track.position(t_s)

    def _candidates(self, s: SensorSpec) -> dict[str, Any]:
        """The window's frames sensor ``s`` could hear by tech and channel
        (:meth:`_candidates_many` of one sensor)."""
        return self._candidates_many([s])[0]

    def _candidates_many(self, sensors: Sequence[SensorSpec]) -> list[dict[str, Any]]:
        """The window's frames each of ``sensors`` could hear by tech and channel.

        The same selection, in the same order, as the offline world's, over
        all emitters at once (the window's frames are gathered once for every
        sensor); for several sensors the tests of all of them are one array of
        sensors × frames, and each column of the window is gathered once for
        all of them (each sensor's frames are a slice of it).
        """
        w = self._window
        if not self._window_key or not len(w["t"]):
            if w:
                return [{k: v[:0] for k, v in w.items()} for _ in sensors]
            return [super()._candidates(s) for s in sensors]
        emitter = w["emitter"]
        hears = np.stack([self._hears(s) for s in sensors])[:, emitter]
        by_channel: dict[int, npt.NDArray[np.bool_]] = {}
        reach = np.full(len(sensors), np.nan)
        sx, sy = np.zeros(len(sensors)), np.zeros(len(sensors))
        for k, s in enumerate(sensors):
            listens = self.listening.get(s.id)
            on: npt.NDArray[np.bool_]
            if listens is not None:
                on = np.asarray(listens(w["t"], w["channel"]), bool)
            else:
                plan = self._plan(s)
                if plan.hopping:
                    on = np.asarray(plan.channel_at(w["t"]) == w["channel"], bool)
                else:  # one channel, listened to all the time (frame times are finite)
                    ch = int(plan.channels[0])
                    if ch not in by_channel:
                        by_channel[ch] = np.asarray(w["channel"] == ch, bool)
                    on = by_channel[ch]
            hears[k] &= on
            r = self.reach_m.get(s.id)
            if r is not None and s.pose is not None:
                reach[k], sx[k], sy[k] = r, s.pose.x_m, s.pose.y_m
        far = np.flatnonzero(np.isfinite(reach))
        if len(far):
            xy = self._window_positions()
            dist = np.hypot(xy[None, :, 0] - sx[far, None], xy[None, :, 1] - sy[far, None])
            hears[far] &= dist <= reach[far, None]
        # row-major: sensor by sensor, each sensor's frames in the window's order (the
        # offline order: time, then emitter)
        which, rows = np.nonzero(hears)
        gathered = {k: v[rows] for k, v in w.items()}
        gathered["row"] = rows
        bounds = np.searchsorted(which, np.arange(len(sensors) + 1)).tolist()
        return [{k: v[lo:hi] for k, v in gathered.items()} for lo, hi in itertools.pairwise(bounds)]

    def _plan(self, s: SensorSpec) -> ScanPlan:
        """Sensor ``s``'s scan plan (built once)."""
        plan = self._plans.get(s.id)
        if plan is None:
            plan = self._plans[s.id] = ScanPlan.from_spec(s.scan)
        return plan

    def _candidates_key(self, s: SensorSpec) -> tuple[bytes, int] | None:
        """What :meth:`_candidates` of ``s`` depends on, when it is the technologies heard
        and one fixed channel (sensors with equal keys get the same frames); else None."""
        if s.id in self.listening or s.id in self.reach_m:
            return None
        plan = self._plan(s)
        if plan.hopping:
            return None
        return self._hears(s).tobytes(), int(plan.channels[0])

    def _hears(self, s: SensorSpec) -> npt.NDArray[np.bool_]:
        """Whether sensor ``s`` hears each emitter's technology (grown as emitters come)."""
        hears = self._hear_cache.get(s.id, _HEARS_NONE)
        if len(hears) < len(self.emitters):
            new = self.emitters[len(hears) :]
            hears = np.concatenate([hears, np.array([s.hears(e.tech) for e in new], bool)])
            self._hear_cache[s.id] = hears
        return hears

    def _frame_positions(self, c: dict[str, Any]) -> Array:
        """Positions of the candidate frames, from the window's positions.

        Every sensor of a window asks for a subset of the same frames, so the
        positions are computed once per window (one track lookup per emitter).
        """
        rows = c.get("row")
        if rows is None:
            return super()._frame_positions(c)
        return np.asarray(self._window_positions()[rows], np.float64)

    def _window_positions(self) -> Array:
        """Where every frame of the window was sent from, shape (n, 2), metres (once per window)."""
        if self._window_xy is None:
            w = self._window
            self._window_xy = self._positions(w["emitter"], w["t"])
        return self._window_xy

    def _positions(self, emitter: npt.NDArray[np.intp], t_s: Array) -> Array:
        """Where each frame's emitter was at its time, shape (n, 2), metres.

        :meth:`emitter_position` for many emitters: ``np.interp`` on each
        carrier's knots, as the offline world does (so the streamed frames keep
        the offline world's positions).

        Raises:
            SimulationError: a carrier has no knot yet.
        """
        if not len(t_s):
            return np.empty((0, 2))
        uniq_ids: list[int]
        if emitter.min() == emitter.max():  # one emitter: no sort
            uniq_ids, inverse = [int(emitter[0])], np.zeros(len(emitter), np.intp)
        else:
            uniq, inverse = np.unique(emitter, return_inverse=True)
            uniq_ids = uniq.tolist()
        knots: list[tuple[Array, Array, Array]] = []
        for i in uniq_ids:
            track = self._carrier(i)
            if track is None:
                pos = self.emitters[i].position
                assert pos is not None
                knots.append((np.zeros(1), np.array([pos[0]], float), np.array([pos[1]], float)))
            else:
                knots.append(track.knots())
        return _interp_tracks(knots, inverse.reshape(-1), np.asarray(t_s, np.float64))

    def sensor_pose(self, sensor: SensorSpec | str, t_s: npt.ArrayLike) -> tuple[Array, Array]:
        """Position (n, 2) in metres and boresight compass heading (n,) of a sensor at ``t_s``.

        Raises:
            SimulationError: the sensor's vehicle has no knot yet.
        """
        s = self.scenario.sensor(sensor) if isinstance(sensor, str) else sensor
        if s.mounted_on is None:
            return super().sensor_pose(s, t_s)
        track = self.live[s.mounted_on]
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        heading = np.mod(track.heading_deg(t) + s.heading_offset_deg, 360.0)
        return track.position(t), heading

    # -- frames ---------------------------------------------------------------------

    def _generate(self, t_end_s: float) -> None:
        """Generate every live emitter's frames up to ``t_end_s`` (and on to the horizon)."""
        if t_end_s > self.generated_s:
            if t_end_s > self._horizon_s:
                self._horizon_s = t_end_s + self.lookahead_s
                todo = range(len(self._traffic))
            else:
                todo = self._fresh  # type: ignore[assignment]
            new = []
            for i in todo:
                traffic = self._traffic[i]
                if traffic is not None:
                    new.append((i, traffic.advance(self._horizon_s)))
            self._fresh = []
            merged = _merge_frames(self._frames, new)
            if merged is not self._frames:
                self._frames = merged
                self._n_frames_added += 1
            self.generated_s = t_end_s
            self._trim()

    def _trim(self) -> None:
        """Drop frames and knots every sensor is done with.

        Only once the sensors have moved on by ``lookahead_s`` since the last
        trim (at most that much more is kept): trimming every window cost a
        copy of every frame column and of every track's knots per step, and
        what is kept beyond the windows changes no frame.
        """
        done = min(self.cursor_s.values(), default=self.generated_s)
        if done < self._trimmed_s + self.lookahead_s:
            return
        self._trimmed_s = done
        f = self._frames
        if len(f["t"]) and f["t"][0] < done:
            cut = int(np.searchsorted(f["t"], done, side="left"))
            self._frames = {k: v[cut:] for k, v in f.items()}
            self._n_frames_added += 1
        for track in self.live.values():
            track.forget_before(done)

    def receptions_between(self, sensor_id: str, t0_s: float, t1_s: float) -> Receptions:
        """The frames sensor ``sensor_id`` hears that start in ``[t0_s, t1_s)``.

        Windows of one sensor must follow each other without gap or overlap
        (``t0_s`` is where the previous window ended), because the sensor's
        random streams advance frame by frame. Every live carrier must have a
        knot at or after ``t1_s`` (or have stopped: after its newest knot a
        mover stands still).

        Raises:
            ConfigError: no such sensor.
            SimulationError: a window that does not start at the sensor's
                cursor or does not move forward, or not the one :meth:`prepare`
                computed for the sensor.
        """
        s = self.scenario.sensor(sensor_id)
        self._check_window(s.id, t0_s, t1_s)
        ready = self._ready.pop(s.id, None)
        if ready is not None:
            if ready[:2] != (t0_s, t1_s):
                self._ready[s.id] = ready
                raise SimulationError(
                    f"sensor {s.id!r}: frames of [{ready[0]:.6f}, {ready[1]:.6f}) s were "
                    f"prepared; ask for that window, not [{t0_s:.6f}, {t1_s:.6f})"
                )
            rec = ready[2]
        else:
            self._set_window(t0_s, t1_s)
            rec = self._receive(s, self._candidates(s), self._rx[s.id])
        self.cursor_s[s.id] = t1_s
        return rec

    def _check_window(self, sensor_id: str, t0_s: float, t1_s: float) -> None:
        cursor = self.cursor_s[sensor_id]
        if t0_s != cursor:
            raise SimulationError(
                f"sensor {sensor_id!r}: window starts at {t0_s:.6f} s, but the previous one "
                f"ended at {cursor:.6f} s; windows must follow each other"
            )
        if not t1_s > t0_s:
            raise SimulationError(f"sensor {sensor_id!r}: window [{t0_s}, {t1_s}) is empty")

    def _set_window(self, t0_s: float, t1_s: float) -> None:
        """Make ``[t0_s, t1_s)`` the current window (frames generated up to ``t1_s``)."""
        self._generate(t1_s)
        key = (t0_s, t1_s, self._n_frames_added)
        if self._window_key != key:
            f = self._frames
            lo = int(np.searchsorted(f["t"], t0_s, side="left"))
            hi = int(np.searchsorted(f["t"], t1_s, side="left"))
            self._window_key = key
            self._window = {k: v[lo:hi] for k, v in f.items()}
            self._window_xy = None

    def prepare(self, t1_s: float) -> None:
        """Compute every sensor's frames from its cursor to ``t1_s`` in one pass.

        :meth:`receptions_between` then hands each sensor its window without
        computing it again; the frames are exactly those it would compute
        alone. A sensor prepared for ``[cursor, t1_s)`` must be asked for that
        window next (its random streams have moved on). Sensors already
        prepared, or whose cursor is at or after ``t1_s``, are left alone.
        Knots added after this call do not change the prepared frames.
        """
        due: dict[float, list[SensorSpec]] = {}
        for sid, cursor in self.cursor_s.items():
            if cursor < t1_s and sid not in self._ready:
                due.setdefault(cursor, []).append(self.scenario.sensor(sid))
        for t0_s, sensors in due.items():
            self._set_window(t0_s, t1_s)
            shared: dict[tuple[bytes, int], dict[str, Any]] = {}
            cands: dict[str, dict[str, Any]] = {}
            own = []  # sensors whose candidates are their own: all of them in one call
            for s in sensors:
                key = self._candidates_key(s)
                if key is None:
                    own.append(s)
                    continue
                c = shared.get(key)
                if c is None:
                    c = shared[key] = self._candidates(s)
                cands[s.id] = c
            if own:
                cands.update(zip([s.id for s in own], self._candidates_many(own), strict=True))
            items = [(s, cands[s.id], self._rx[s.id]) for s in sensors]
            for s, rec in zip(sensors, self._receive_many(items), strict=True):
                self._ready[s.id] = (t0_s, t1_s, rec)

    def step(self, t1_s: float) -> dict[str, Receptions]:
        """Every sensor's frames from its cursor to ``t1_s``, by sensor id (in one pass).

        Raises:
            SimulationError: ``t1_s`` is not after some sensor's cursor.
        """
        for sid, cursor in self.cursor_s.items():
            self._check_window(sid, cursor, t1_s)
        self.prepare(t1_s)
        return {
            sid: self.receptions_between(sid, cursor, t1_s)
            for sid, cursor in list(self.cursor_s.items())
        }

    def receptions(self, sensor_id: str) -> Receptions:
        """Not available on a streaming twin: use :meth:`receptions_between`.

        Raises:
            SimulationError: always.
        """
        raise SimulationError(
            "a streaming twin computes frames window by window: use receptions_between()"
        )
