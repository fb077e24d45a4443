"""Scoring a district run online: conflicts, collisions, coverage, nuisance, linkability, cost.

:class:`CityScorer` is fed as the run goes and keeps bounded state (per road
user a few numbers; per event type a counter and at most :data:`MAX_EVENTS`
located events for the map), so a run of any length fits.

- ``step(t_s, vehicles, vrus)``, every simulation step, with the true state of
  every car and every VRU (:class:`Actors`, rfsas frame).

  *Conflicts*: a car and a VRU are in conflict when, both keeping their
  velocity, the VRU would come within the car's footprint within
  ``ttc_s`` seconds: the car is a capsule (its centre line, shortened by half
  its width at both ends, widened by half its width), the VRU a disc of half
  its length; the time to collision is found on a grid of ``ttc_step_s``.
  Candidate pairs come from k-d trees of the cars and of the VRUs, within each
  car's reach (both speeds times ``ttc_s`` plus the sizes), so the cost follows
  the pairs that are near, not cars × VRUs. A pair's conflict is one encounter while it
  lasts; it counts again after ``encounter_gap_s`` without conflict.

  *Collisions*: a pair whose boxes overlap, tested with the bridges' oriented
  box geometry (:func:`rfsas_hw.bridges.boxes.overlap`) on the pairs whose
  centres are near enough to touch; one collision per pair.

  *Coverage per crossing*: a VRU *reaches a kerb* when it comes within
  ``kerb_radius_m`` of either end of a crossing (from outside that radius; where
  kerbs of two crossings are that close, the nearest one counts). The
  arrival is *covered* when the backend already had a trustworthy fix of it: a
  fix attributed to that VRU no older than ``fix_age_s`` with one-sigma error
  at most ``trust_sigma_m``; the fix error there is the distance from that fix
  to the VRU's true position at the arrival. Shares are over arrivals of VRUs
  that carry a phone (the others cannot be seen); all arrivals are counted too.

- ``fix(t_s, emitter_id, person, x_m, y_m, sigma_m)``, for every fix the
  backends made, with the truth of whose device it was (None: nobody's, a
  ghost). *Linkability*: per person, the longest stretch of its trip between
  two fixes under one emitter id (the backend sees one pseudonym for that
  long), in seconds, metres walked or ridden, and as a share of the trip.

- ``advisory(t_s, vehicle_id, kind, latency_s)``, for every advisory that
  reached a car. Latency percentiles come from a fixed histogram
  (:data:`LATENCY_BIN_S` bins). A *BRAKE episode* starts with a ``brake`` after
  ``brake_gap_s`` without one for that car; an episode is a *nuisance* when, at
  its first BRAKE, no VRU was in conflict with that car within the looser
  ``nuisance_ttc_s`` (judged on the last step's state, before the car reacted).
  A conflict is *advised* when its car had a BRAKE episode that started no
  later than the conflict's end and at most ``advise_lead_s`` before its
  start, and *defused* when it was advised and the pair did not collide.
  ``latency(latency_s)`` adds the latency of an advisory that became known only
  after it reached its car (its backend's report came after it).

- ``messages(n)``: bearing messages published (for messages per second).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from rfsas_hw.bridges.boxes import overlap
from rfsas_hw.bridges.bridge import Entity
from rfsas_hw.bridges.config import EntityKind
from rfsas_hw.city.demand import VruRecord
from rfsas_hw.city.latency import LatencyParts
from rfsas_hw.city.net import Crossing
from rfsas_hw.errors import ConfigError

FloatArray = npt.NDArray[np.float64]

MAX_EVENTS = 20_000
"""Located events (conflicts, nuisance BRAKEs) kept for the map, per kind."""
LATENCY_BIN_S = 0.0005
"""Width of a latency histogram bin, seconds."""
LATENCY_MAX_S = 5.0
"""Latencies above this land in the last bin, seconds."""
LATENCY_PARTS = ("to_step", "judging", "delivery")
"""The parts of a latency in the summary, in the order of
:class:`~rfsas_hw.city.latency.LatencyParts`."""
ERROR_BIN_M = 0.25
"""Width of a fix-error histogram bin, metres."""
ERROR_MAX_M = 100.0
"""Fix errors above this land in the last bin, metres."""

_COLUMNS = (
    "classes",
    "x_m",
    "y_m",
    "vx_mps",
    "vy_mps",
    "heading_deg",
    "length_m",
    "width_m",
    "route_m",
)

__all__ = ["Actors", "CityScorer", "CitySummary", "CrossingCoverage", "ScoringConfig"]


@dataclass(frozen=True)
class Actors:
    """Road users of one step, one entry per user, rfsas frame (box centres).

    Cars are every vehicle that is not a VRU; a bicycle is a VRU (SUMO runs it as
    a vehicle)."""

    ids: Sequence[str]
    """Simulator ids."""
    classes: Sequence[str]
    """The VRU class of a VRU (``pedestrian``, ``bicycle``, ``moped``, …), by which
    conflicts and collisions are counted; any label for a car (``vehicle``, SUMO's
    vehicle class)."""
    x_m: FloatArray
    """Metres east of the origin."""
    y_m: FloatArray
    """Metres north of the origin."""
    vx_mps: FloatArray
    """Velocity east, m/s."""
    vy_mps: FloatArray
    """Velocity north, m/s."""
    heading_deg: FloatArray
    """Compass heading, degrees clockwise from north."""
    length_m: FloatArray
    """Box length along the heading, metres."""
    width_m: FloatArray
    """Box width, metres."""
    route_m: FloatArray
    """Distance driven since departure, metres (cars; 0 for VRUs)."""

    def __post_init__(self) -> None:
        n = len(self.ids)
        for name in _COLUMNS:
            if len(getattr(self, name)) != n:
                raise ConfigError(f"actors: {name} has {len(getattr(self, name))} entries, not {n}")

    @classmethod
    def empty(cls) -> Actors:
        """No road users."""
        z = np.zeros(0)
        return cls((), (), z, z, z, z, z, z, z, z)

    @classmethod
    def of(
        cls,
        ids: Sequence[str],
        classes: Sequence[str],
        x_m: npt.ArrayLike,
        y_m: npt.ArrayLike,
        speed_mps: npt.ArrayLike,
        heading_deg: npt.ArrayLike,
        length_m: npt.ArrayLike,
        width_m: npt.ArrayLike,
        route_m: npt.ArrayLike = 0.0,
    ) -> Actors:
        """Build from speeds along the headings (the simulator's usual state); scalars
        broadcast."""
        n = len(ids)

        def col(v: npt.ArrayLike) -> FloatArray:
            return np.broadcast_to(np.asarray(v, dtype=np.float64), (n,)).copy()

        head = col(heading_deg)
        speed = col(speed_mps)
        a = np.radians(head)
        return cls(
            ids,
            classes,
            col(x_m),
            col(y_m),
            speed * np.sin(a),
            speed * np.cos(a),
            head,
            col(length_m),
            col(width_m),
            col(route_m),
        )

    def entity(self, i: int) -> Entity:
        """Entry ``i`` as a bridge entity (for the box geometry)."""
        kind: EntityKind = "pedestrian" if self.classes[i] == "pedestrian" else "vehicle"
        return Entity(
            str(self.ids[i]),
            kind,
            float(self.x_m[i]),
            float(self.y_m[i]),
            float(self.heading_deg[i]),
            float(math.hypot(self.vx_mps[i], self.vy_mps[i])),
            float(self.length_m[i]),
            float(self.width_m[i]),
        )


@dataclass(frozen=True)
class ScoringConfig:
    """Thresholds of the scorer (module docstring)."""

    ttc_s: float = 1.5
    """A pair with a time to collision below this is a conflict, seconds."""
    ttc_step_s: float = 0.1
    """Time resolution of the time to collision, seconds."""
    nuisance_ttc_s: float = 4.0
    """A BRAKE with no VRU under this time to collision is a nuisance, seconds."""
    encounter_gap_s: float = 5.0
    """A pair's conflict counts again after this long without one, seconds."""
    brake_gap_s: float = 2.0
    """A BRAKE after this long without one starts a new episode, seconds."""
    advise_lead_s: float = 5.0
    """How long before a conflict its BRAKE may have started, seconds."""
    kerb_radius_m: float = 3.0
    """A VRU this close to a crossing's end has reached the kerb, metres."""
    trust_sigma_m: float = 5.0
    """A fix with a larger one-sigma error is not trustworthy, metres."""
    fix_age_s: float = 1.0
    """A fix older than this at the kerb does not count, seconds."""

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"scoring: {name} must be a number > 0, got {value}")
        if self.ttc_step_s > self.ttc_s:
            raise ConfigError("scoring: ttc_step_s must not exceed ttc_s")


@dataclass
class CrossingCoverage:
    """Coverage of one crossing."""

    id: str
    junction: str
    x_m: float
    """Crossing's middle, metres east."""
    y_m: float
    """Crossing's middle, metres north."""
    arrivals: int = 0
    """VRU arrivals at its kerbs."""
    arrivals_with_phone: int = 0
    """Arrivals of VRUs carrying a phone."""
    covered: int = 0
    """Arrivals with a trustworthy fix already made."""
    share: float | None = None
    """covered / arrivals_with_phone (None: no such arrival)."""
    error_p50_m: float | None = None
    """Median fix error at the kerb of the covered arrivals, metres."""
    error_mean_m: float | None = None
    """Mean of the same, metres."""


@dataclass
class CitySummary:
    """The measures of one run (module docstring); :meth:`to_json` for the file."""

    duration_s: float
    steps: int
    vehicles: int
    """Cars seen."""
    vrus_by_class: dict[str, int]
    vehicle_km: float
    ttc_s: float
    conflicts_by_class: dict[str, int]
    conflicts_advised: int
    conflicts_defused: int
    collisions_by_class: dict[str, int]
    brake_episodes: int
    nuisance_brakes: int
    nuisance_per_100_vehicle_km: float | None
    advisories_by_kind: dict[str, int]
    advisories_per_s: float
    messages: int
    messages_per_s: float
    latency_n: int
    latency_p50_ms: float | None
    latency_p99_ms: float | None
    fixes: int
    fixes_ghost: int
    """Fixes attributed to no one's device."""
    coverage_share: float | None
    """Covered arrivals / arrivals with a phone, over all crossings."""
    coverage_error_p50_m: float | None
    crossings_reached: int
    """Crossings with at least one arrival."""
    linkability: dict[str, float | int | None]
    """Persons with fixes, and the median / p90 / max of their longest linked stretch
    (seconds, metres, share of the trip)."""
    crossings: list[CrossingCoverage] = field(default_factory=list)
    latency_parts_ms: dict[str, dict[str, float | None]] = field(default_factory=dict)
    """The p50 and p99 of each part of the latency (:data:`LATENCY_PARTS`), over the same
    advisories as the latency's: ``{"to_step": {"p50": …, "p99": …}, …}``, ms."""

    @property
    def conflicts(self) -> int:
        """All conflicts."""
        return sum(self.conflicts_by_class.values())

    @property
    def collisions(self) -> int:
        """All collisions."""
        return sum(self.collisions_by_class.values())

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready mapping (non-finite numbers as null)."""
        d = asdict(self)
        d["conflicts"] = self.conflicts
        d["collisions"] = self.collisions
        return _finite(d)  # type: ignore[no-any-return]

    def to_json(self) -> str:
        """The summary as one JSON document."""
        return json.dumps(self.as_dict(), indent=2, allow_nan=False)


def _finite(v: Any) -> Any:
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_finite(x) for x in v]
    return v


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else seconds * 1000.0


def _hist_quantile(counts: npt.NDArray[np.int64], bin_width: float, q: float) -> float | None:
    total = int(counts.sum())
    if total == 0:
        return None
    k = int(np.searchsorted(np.cumsum(counts), q * total, side="left"))
    return (k + 0.5) * bin_width


@dataclass
class _Encounter:
    start_s: float
    last_s: float
    vru_class: str
    x_m: float
    y_m: float
    min_ttc_s: float


@dataclass
class _Link:
    first_s: float
    first_m: float
    last_s: float
    last_m: float


class CityScorer:
    """The online scorer of a district run (module docstring).

    Args:
        crossings: the net's crossings (:attr:`~rfsas_hw.city.net.NetInfo.crossings`).
        vrus: the demand's VRU table (who carries a phone); None: all do.
        cfg: thresholds.
    """

    def __init__(
        self,
        crossings: Sequence[Crossing] = (),
        vrus: dict[str, VruRecord] | None = None,
        cfg: ScoringConfig | None = None,
    ) -> None:
        self.cfg = cfg or ScoringConfig()
        self._vru_table = vrus
        self._crossings = [
            CrossingCoverage(
                c.id,
                c.junction,
                (c.kerb_a[0] + c.kerb_b[0]) / 2,
                (c.kerb_a[1] + c.kerb_b[1]) / 2,
            )
            for c in crossings
        ]
        kerbs = [p for c in crossings for p in (c.kerb_a, c.kerb_b)]
        self._kerb_tree = cKDTree(np.asarray(kerbs)) if kerbs else None
        self._cov_err = [np.zeros(int(ERROR_MAX_M / ERROR_BIN_M) + 1, np.int64) for _ in crossings]
        self._cov_err_sum = [0.0 for _ in crossings]
        self._at_kerb: set[tuple[str, int]] = set()
        self._t0: float | None = None
        self._t: float = 0.0
        self._steps = 0
        self._route: dict[str, float] = {}
        # VRUs: persistent index → arrays of last position and distance travelled
        self._vidx: dict[str, int] = {}
        self._vclass: list[str] = []
        self._vlast = np.zeros((0, 2))
        self._vcum = np.zeros(0)
        self._vfirst_t = np.zeros(0)
        self._vlast_t = np.zeros(0)
        self._last_fix: dict[str, tuple[float, float, float, float]] = {}
        self._links: dict[tuple[str, str], _Link] = {}
        self._fixes = 0
        self._ghost = 0
        self._active: dict[tuple[str, str], _Encounter] = {}
        self._conflicts: dict[str, int] = {}
        self._conflict_events: list[tuple[float, float, str, bool, bool]] = []
        self._advised = 0
        self._defused = 0
        self._collided: set[tuple[str, str]] = set()
        self._collisions: dict[str, int] = {}
        self._collision_events: list[tuple[float, float, str]] = []
        self._brake_last: dict[str, float] = {}
        self._brake_starts: dict[str, list[float]] = {}
        self._episodes = 0
        self._nuisance = 0
        self._nuisance_events: list[tuple[float, float, str]] = []
        self._advisories: dict[str, int] = {}
        self._latency = np.zeros(int(LATENCY_MAX_S / LATENCY_BIN_S) + 1, np.int64)
        self._latency_parts = np.zeros((len(LATENCY_PARTS), len(self._latency)), np.int64)
        self._messages = 0
        self._vehicles = Actors.empty()
        self._vrus = Actors.empty()
        self._tree: cKDTree | None = None

    # ---------------------------------------------------------------- per step

    def step(self, t_s: float, vehicles: Actors, vrus: Actors) -> None:
        """Score one step: the true state of every car and every VRU now.

        Raises:
            ConfigError: time went backwards.
        """
        if self._t0 is None:
            self._t0 = t_s
        elif t_s < self._t:
            raise ConfigError(f"scoring: step at {t_s} s after one at {self._t} s")
        self._t = t_s
        self._steps += 1
        self._vehicles, self._vrus = vehicles, vrus
        self._tree = cKDTree(np.column_stack([vrus.x_m, vrus.y_m])) if len(vrus.ids) else None
        self._route.update(zip(vehicles.ids, vehicles.route_m.tolist(), strict=True))
        idx = self._track_vrus(t_s, vrus)
        self._close_encounters(t_s)  # before this step's conflicts: a gap ends an encounter
        if len(vehicles.ids) and self._tree is not None:
            vi, ui, ttc = self._pairs_ttc(np.arange(len(vehicles.ids)), self.cfg.ttc_s)
            self._score_conflicts(t_s, vi, ui, ttc)
            self._score_collisions(vi, ui)
        self._score_kerbs(t_s, vrus, idx)

    def _track_vrus(self, t_s: float, vrus: Actors) -> npt.NDArray[np.intp]:
        get = self._vidx.get
        idx = np.fromiter((get(i, -1) for i in vrus.ids), dtype=np.intp, count=len(vrus.ids))
        new = np.flatnonzero(idx < 0)
        if len(new):
            base = len(self._vclass)
            for k, j in enumerate(new.tolist()):
                self._vidx[vrus.ids[j]] = base + k
                self._vclass.append(str(vrus.classes[j]))
            idx[new] = base + np.arange(len(new))
            xy = np.column_stack([vrus.x_m[new], vrus.y_m[new]])
            self._vlast = np.vstack([self._vlast, xy])
            self._vcum = np.concatenate([self._vcum, np.zeros(len(new))])
            self._vfirst_t = np.concatenate([self._vfirst_t, np.full(len(new), t_s)])
            self._vlast_t = np.concatenate([self._vlast_t, np.full(len(new), t_s)])
        xy = np.column_stack([vrus.x_m, vrus.y_m])
        self._vcum[idx] += np.hypot(*(xy - self._vlast[idx]).T)
        self._vlast[idx] = xy
        self._vlast_t[idx] = t_s
        return idx

    def _pairs_ttc(
        self, vehicles: npt.NDArray[np.intp], horizon_s: float
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], FloatArray]:
        """(car index, VRU index, time to collision s) of every pair that would touch within
        ``horizon_s`` (module docstring); inf-free."""
        veh, vru, tree = self._vehicles, self._vrus, self._tree
        empty = np.zeros(0, np.intp)
        if tree is None or not len(vehicles):
            return empty, empty, np.zeros(0)
        radius = np.maximum(vru.length_m, vru.width_m) / 2
        vru_speed = float(np.max(np.hypot(vru.vx_mps, vru.vy_mps), initial=0.0))
        speed = np.hypot(veh.vx_mps[vehicles], veh.vy_mps[vehicles])
        reach = (
            (speed + vru_speed) * horizon_s
            + veh.length_m[vehicles] / 2
            + float(np.max(radius, initial=0.0))
        )
        cars = cKDTree(np.column_stack([veh.x_m[vehicles], veh.y_m[vehicles]]))
        near = cars.sparse_distance_matrix(tree, float(np.max(reach)), output_type="ndarray")
        keep = near["v"] <= reach[near["i"]]
        if not keep.any():
            return empty, empty, np.zeros(0)
        vi = vehicles[near["i"][keep]]
        ui = near["j"][keep].astype(np.intp)
        t = np.arange(0.0, horizon_s + 1e-9, self.cfg.ttc_step_s)
        a = np.radians(veh.heading_deg[vi])
        ux, uy = np.sin(a), np.cos(a)
        half = np.maximum(veh.length_m[vi] - veh.width_m[vi], 0.0) / 2
        # VRU relative to the car, both moving at constant velocity: (pairs, times)
        rx = (vru.x_m[ui] - veh.x_m[vi])[:, None] + (vru.vx_mps[ui] - veh.vx_mps[vi])[:, None] * t
        ry = (vru.y_m[ui] - veh.y_m[vi])[:, None] + (vru.vy_mps[ui] - veh.vy_mps[vi])[:, None] * t
        along = np.clip(rx * ux[:, None] + ry * uy[:, None], -half[:, None], half[:, None])
        dist = np.hypot(rx - along * ux[:, None], ry - along * uy[:, None])
        touch = dist <= (veh.width_m[vi] / 2 + radius[ui])[:, None]
        hit = touch.any(axis=1)
        first = np.argmax(touch, axis=1)
        return vi[hit], ui[hit], t[first[hit]]

    def _score_conflicts(
        self, t_s: float, vi: npt.NDArray[np.intp], ui: npt.NDArray[np.intp], ttc: FloatArray
    ) -> None:
        veh, vru = self._vehicles, self._vrus
        for v, u, tc in zip(vi.tolist(), ui.tolist(), ttc.tolist(), strict=True):
            key = (str(veh.ids[v]), str(vru.ids[u]))
            enc = self._active.get(key)
            if enc is None:
                cls = str(vru.classes[u])
                self._active[key] = _Encounter(
                    t_s, t_s, cls, float(vru.x_m[u]), float(vru.y_m[u]), tc
                )
                self._conflicts[cls] = self._conflicts.get(cls, 0) + 1
            else:
                enc.last_s = t_s
                if tc < enc.min_ttc_s:
                    enc.min_ttc_s, enc.x_m, enc.y_m = tc, float(vru.x_m[u]), float(vru.y_m[u])

    def _judge(self, key: tuple[str, str], enc: _Encounter) -> tuple[bool, bool]:
        """(advised, defused) of an encounter."""
        starts = self._brake_starts.get(key[0], ())
        advised = any(enc.start_s - self.cfg.advise_lead_s <= s <= enc.last_s for s in starts)
        return advised, advised and key not in self._collided

    def _close_encounters(self, t_s: float) -> None:
        gap = self.cfg.encounter_gap_s
        for key in [k for k, e in self._active.items() if t_s - e.last_s >= gap]:
            enc = self._active.pop(key)
            advised, defused = self._judge(key, enc)
            self._advised += advised
            self._defused += defused
            if len(self._conflict_events) < MAX_EVENTS:
                self._conflict_events.append((enc.x_m, enc.y_m, enc.vru_class, advised, defused))

    def _score_collisions(self, vi: npt.NDArray[np.intp], ui: npt.NDArray[np.intp]) -> None:
        veh, vru = self._vehicles, self._vrus
        for v, u in zip(vi.tolist(), ui.tolist(), strict=True):
            key = (str(veh.ids[v]), str(vru.ids[u]))
            if key in self._collided:
                continue
            reach = math.hypot(veh.length_m[v], veh.width_m[v]) / 2 + max(
                vru.length_m[u], vru.width_m[u]
            )
            if math.hypot(veh.x_m[v] - vru.x_m[u], veh.y_m[v] - vru.y_m[u]) > reach:
                continue
            if overlap(veh.entity(v), vru.entity(u)):
                self._collided.add(key)
                cls = str(vru.classes[u])
                self._collisions[cls] = self._collisions.get(cls, 0) + 1
                if len(self._collision_events) < MAX_EVENTS:
                    self._collision_events.append((float(vru.x_m[u]), float(vru.y_m[u]), cls))

    def _has_phone(self, vru_id: str) -> bool:
        if self._vru_table is None:
            return True
        rec = self._vru_table.get(vru_id)
        return rec is not None and rec.has_phone

    def _score_kerbs(self, t_s: float, vrus: Actors, idx: npt.NDArray[np.intp]) -> None:
        if self._kerb_tree is None or not len(vrus.ids):
            self._at_kerb.clear()
            return
        xy = np.column_stack([vrus.x_m, vrus.y_m])
        dist, kerb = self._kerb_tree.query(xy, k=1, distance_upper_bound=self.cfg.kerb_radius_m)
        now: set[tuple[str, int]] = set()
        for j in np.flatnonzero(np.isfinite(dist)).tolist():
            key = (str(vrus.ids[j]), int(kerb[j]) // 2)
            now.add(key)
            if key not in self._at_kerb:
                self._arrive(t_s, key[0], key[1], float(xy[j, 0]), float(xy[j, 1]))
        self._at_kerb = now

    def _arrive(self, t_s: float, vid: str, crossing: int, x: float, y: float) -> None:
        cov = self._crossings[crossing]
        cov.arrivals += 1
        if not self._has_phone(vid):
            return
        cov.arrivals_with_phone += 1
        fix = self._last_fix.get(vid)
        if fix is None:
            return
        ft, fx, fy, sigma = fix
        if t_s - ft > self.cfg.fix_age_s or sigma > self.cfg.trust_sigma_m:
            return
        cov.covered += 1
        err = math.hypot(fx - x, fy - y)
        self._cov_err[crossing][min(int(err / ERROR_BIN_M), len(self._cov_err[crossing]) - 1)] += 1
        self._cov_err_sum[crossing] += err

    # ---------------------------------------------------------------- fixes, advisories

    def fix(
        self,
        t_s: float,
        emitter_id: str,
        person: str | None,
        x_m: float,
        y_m: float,
        sigma_m: float,
    ) -> None:
        """One fix a backend made: the emitter id it carried, whose device it truly was
        (None: nobody's), its position (metres) and one-sigma error (metres)."""
        self._fixes += 1
        if person is None:
            self._ghost += 1
            return
        self._last_fix[person] = (t_s, x_m, y_m, sigma_m)
        i = self._vidx.get(person)
        walked = float(self._vcum[i]) if i is not None else 0.0
        link = self._links.get((person, emitter_id))
        if link is None:
            self._links[(person, emitter_id)] = _Link(t_s, walked, t_s, walked)
        else:
            link.last_s, link.last_m = t_s, walked

    def advisory(
        self, t_s: float, vehicle_id: str, kind: str, latency: LatencyParts | None
    ) -> None:
        """One advisory that reached a car: its kind (``brake``, ``caution``, ``clear``)
        and its frame → advisory latency (None: not known, or not yet)."""
        self._advisories[kind] = self._advisories.get(kind, 0) + 1
        if latency is not None:
            self.latency(latency)
        if kind != "brake":
            return
        last = self._brake_last.get(vehicle_id)
        self._brake_last[vehicle_id] = t_s
        if last is not None and t_s - last < self.cfg.brake_gap_s:
            return
        self._episodes += 1
        self._brake_starts.setdefault(vehicle_id, []).append(t_s)
        try:
            v = list(self._vehicles.ids).index(vehicle_id)
        except ValueError:
            return  # the car has left: no state to judge the BRAKE on
        _, _, ttc = self._pairs_ttc(np.asarray([v], np.intp), self.cfg.nuisance_ttc_s)
        if len(ttc) == 0:
            self._nuisance += 1
            if len(self._nuisance_events) < MAX_EVENTS:
                veh = self._vehicles
                self._nuisance_events.append((float(veh.x_m[v]), float(veh.y_m[v]), vehicle_id))

    def latency(self, latency: LatencyParts) -> None:
        """One frame → advisory latency and its parts (a total that is not finite or is
        negative, clocks that disagree, is not counted); :meth:`advisory` takes it with
        its advisory, this one for an advisory whose latency became known after it
        reached its car."""
        total = latency.total_s
        if not (math.isfinite(total) and total >= 0):
            return
        last = len(self._latency) - 1
        self._latency[min(int(total / LATENCY_BIN_S), last)] += 1
        for row, part in zip(self._latency_parts, latency, strict=True):
            row[min(max(int(part / LATENCY_BIN_S), 0), last)] += 1

    def messages(self, n: int) -> None:
        """``n`` more bearing messages were published."""
        self._messages += n

    # ---------------------------------------------------------------- results

    @property
    def conflict_events(self) -> list[tuple[float, float, str, bool, bool]]:
        """Conflicts (x m, y m, VRU class, advised, defused), closed ones first, at most
        :data:`MAX_EVENTS`; located where the time to collision was smallest."""
        still = [(e.x_m, e.y_m, e.vru_class, *self._judge(k, e)) for k, e in self._active.items()]
        return (self._conflict_events + still)[:MAX_EVENTS]

    @property
    def nuisance_events(self) -> list[tuple[float, float, str]]:
        """Nuisance BRAKEs (x m, y m, car id), at most :data:`MAX_EVENTS`."""
        return list(self._nuisance_events)

    @property
    def collision_events(self) -> list[tuple[float, float, str]]:
        """Collisions (x m, y m, VRU class), at most :data:`MAX_EVENTS`."""
        return list(self._collision_events)

    def _linkability(self) -> dict[str, float | int | None]:
        best: dict[str, tuple[float, float]] = {}
        for (person, _), link in self._links.items():
            s, m = link.last_s - link.first_s, link.last_m - link.first_m
            old = best.get(person, (0.0, 0.0))
            best[person] = (max(old[0], s), max(old[1], m))
        out: dict[str, float | int | None] = {"persons": len(best)}
        if not best:
            return out
        secs = np.asarray([b[0] for b in best.values()])
        metres = np.asarray([b[1] for b in best.values()])
        trips = []
        for person, (s, _) in best.items():
            i = self._vidx.get(person)
            trip = float(self._vlast_t[i] - self._vfirst_t[i]) if i is not None else 0.0
            trips.append(min(s / trip, 1.0) if trip > 0 else 0.0)
        share = np.asarray(trips)
        for name, arr in (("s", secs), ("m", metres), ("share", share)):
            out[f"p50_{name}"] = float(np.median(arr))
            out[f"p90_{name}"] = float(np.quantile(arr, 0.9))
            out[f"max_{name}"] = float(np.max(arr))
        return out

    def summary(self) -> CitySummary:
        """The measures so far (conflicts still open are judged as they stand; the
        scorer goes on unchanged)."""
        open_judged = [self._judge(k, e) for k, e in self._active.items()]
        advised = self._advised + sum(a for a, _ in open_judged)
        defused = self._defused + sum(d for _, d in open_judged)
        duration = self._t - self._t0 if self._t0 is not None else 0.0
        km = sum(self._route.values()) / 1000.0
        vru_classes: dict[str, int] = {}
        for c in self._vclass:
            vru_classes[c] = vru_classes.get(c, 0) + 1
        crossings = []
        err_total = np.zeros(int(ERROR_MAX_M / ERROR_BIN_M) + 1, np.int64)
        for cov, hist, s in zip(self._crossings, self._cov_err, self._cov_err_sum, strict=True):
            if cov.arrivals == 0:
                continue
            err_total += hist
            crossings.append(
                replace(
                    cov,
                    share=cov.covered / cov.arrivals_with_phone
                    if cov.arrivals_with_phone
                    else None,
                    error_p50_m=_hist_quantile(hist, ERROR_BIN_M, 0.5),
                    error_mean_m=s / cov.covered if cov.covered else None,
                )
            )
        with_phone = sum(c.arrivals_with_phone for c in crossings)
        covered = sum(c.covered for c in crossings)
        rate = (lambda n: n / duration) if duration > 0 else (lambda n: 0.0)
        p50 = _ms(_hist_quantile(self._latency, LATENCY_BIN_S, 0.5))
        p99 = _ms(_hist_quantile(self._latency, LATENCY_BIN_S, 0.99))
        return CitySummary(
            duration_s=duration,
            steps=self._steps,
            vehicles=len(self._route),
            vrus_by_class=vru_classes,
            vehicle_km=km,
            ttc_s=self.cfg.ttc_s,
            conflicts_by_class=dict(self._conflicts),
            conflicts_advised=advised,
            conflicts_defused=defused,
            collisions_by_class=dict(self._collisions),
            brake_episodes=self._episodes,
            nuisance_brakes=self._nuisance,
            nuisance_per_100_vehicle_km=self._nuisance / km * 100.0 if km > 0 else None,
            advisories_by_kind=dict(self._advisories),
            advisories_per_s=rate(sum(self._advisories.values())),
            messages=self._messages,
            messages_per_s=rate(self._messages),
            latency_n=int(self._latency.sum()),
            latency_p50_ms=p50,
            latency_p99_ms=p99,
            fixes=self._fixes,
            fixes_ghost=self._ghost,
            coverage_share=covered / with_phone if with_phone else None,
            coverage_error_p50_m=_hist_quantile(err_total, ERROR_BIN_M, 0.5),
            crossings_reached=len(crossings),
            linkability=self._linkability(),
            crossings=crossings,
            latency_parts_ms={
                name: {
                    f"p{round(q * 100)}": _ms(_hist_quantile(row, LATENCY_BIN_S, q))
                    for q in (0.5, 0.99)
                }
                for name, row in zip(LATENCY_PARTS, self._latency_parts, strict=True)
            },
        )
