"""The backend service: verified bearings in, fixes and risk assessments out.

Each verified safety message hands the sender's pose and bearings to the
:class:`~rfsas_hw.backend.association.Associator`. Every step (``step_s``):

1. groups of bearings of one emitter from at least two sensors are
   triangulated together (:func:`~rfsas_hw.backend.triangulation.triangulate_batch`),
   each giving a :class:`~rfsas_hw.records.Fix`;
2. trustworthy fixes update the emitter's constant-velocity track;
   flagged fixes are reported, never used as positions (with ``tracking:
   bearings`` a fix only starts a track, and each unit's bearings update it;
   a bearing outside its unit's field of view enters neither:
   :mod:`~rfsas_hw.backend.bearing_tracking`);
3. every live track is judged against the vehicle state (if one is known),
   giving an :class:`~rfsas_hw.records.Assessment` with P(collision), impact
   speed, risk and the advisory;
4. fixes and assessments go to the sinks (a JSONL file, a live table, a map).

The vehicle state comes from a file, a UDP feed (:class:`VehicleFeed`), or a
simulator calling :meth:`BackendService.set_vehicle`. The link's latency alarm
is part of every assessment.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Any, Protocol

import numpy as np

from rfsas_hw.backend.association import AssociationConfig, Associator
from rfsas_hw.backend.bearing_tracking import BearingTracker, BearingUpdateConfig, TrackingMode
from rfsas_hw.backend.encounter import Encounter, EncounterConfig, assess_pairs
from rfsas_hw.backend.risk import Advisory
from rfsas_hw.backend.site import SiteConfig, site_from_mapping
from rfsas_hw.backend.tracking import Track, Tracker, TrackerConfig, predict_tracks
from rfsas_hw.backend.triangulation import (
    FixStatus,
    TriangulationOptions,
    triangulate_batch,
)
from rfsas_hw.backend.vehicle import VehicleFeed, VehicleState
from rfsas_hw.config import from_mapping, read_yaml
from rfsas_hw.errors import BackendError, ConfigError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.privacy.epochs import EpochSchedule
from rfsas_hw.records import Assessment, BearingBatch, Fix, Pose, emitter_hex

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000

__all__ = [
    "BackendConfig",
    "BackendService",
    "BackendStats",
    "BearingSink",
    "JsonlSink",
    "MessageSource",
    "ResultSink",
    "load_backend_config",
]


@dataclass(frozen=True, slots=True)
class BackendConfig:
    """Everything the backend service can be tuned with.

    Args:
        association: time window, epoch length, ageing, sensors per group.
        triangulation: iteration and acceptance limits of the fixes.
        tracker: motion model and track management.
        encounter: threat kind, horizon, reaction delay, advisory thresholds.
        step_s: period of triangulation and assessment in :meth:`BackendService.run`, s.
        site: the site's origin on WGS-84, declared sensors, map and tile URL
            (:mod:`rfsas_hw.backend.site`).
        tracking: what updates a track: ``fixes`` (each trustworthy fix, the
            default) or ``bearings`` (a fix starts the track, then each unit's
            bearing updates it; :mod:`rfsas_hw.backend.bearing_tracking`).
        bearings: how a bearing updates a track (``tracking: bearings`` only).

    Raises:
        BackendError: a non-positive step.
    """

    association: AssociationConfig = field(default_factory=AssociationConfig)
    triangulation: TriangulationOptions = field(default_factory=TriangulationOptions)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    encounter: EncounterConfig = field(default_factory=EncounterConfig)
    step_s: float = 0.1
    site: SiteConfig = field(default_factory=SiteConfig)
    tracking: TrackingMode = "fixes"
    bearings: BearingUpdateConfig = field(default_factory=BearingUpdateConfig)

    def __post_init__(self) -> None:
        if not self.step_s > 0:
            raise BackendError(f"step_s must be > 0, got {self.step_s}")


def load_backend_config(path: str | Path) -> BackendConfig:
    """Read a :class:`BackendConfig` from YAML (top level, or a ``backend:`` section).

    Example::

        association: {window_s: 0.5, epoch_s: 60}
        triangulation: {max_range_fraction: 0.08}
        tracker: {accel_sigma_mps2: 3.0}
        encounter: {threat_kind: cyclist, reaction_s: 0.3,
                    thresholds: {brake_risk: 0.005}}
        step_s: 0.1
        site: {origin: {lat_deg: 52.2053, lon_deg: 0.1218}}

    Raises:
        ConfigError: unreadable file, invalid YAML, an unknown key or a bad value
            (the message names the file and the key).
    """
    data = read_yaml(path)
    if isinstance(data, dict) and "backend" in data:
        data = data["backend"]
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of backend settings")
    site_data = data.get("site")
    data = {k: v for k, v in data.items() if k != "site"}
    site = site_from_mapping(site_data, f"{path}: site", Path(path).parent)
    try:
        return replace(from_mapping(BackendConfig, data, str(path)), site=site)
    except (BackendError, ConfigError) as err:
        # range checks of the settings do not know the file they came from
        if str(err).startswith(str(path)):
            raise
        raise ConfigError(f"{path}: {err}") from err


@dataclass(slots=True)
class BackendStats:
    """What the service did: messages, bearings, fixes by status, assessments by advisory."""

    messages: int = 0
    bearings: int = 0
    steps: int = 0
    fixes: Counter[str] = field(default_factory=Counter)
    """Fixes by status (``ok``, ``ill_conditioned``, …)."""
    assessments: Counter[str] = field(default_factory=Counter)
    """Assessments by advisory."""

    def as_dict(self) -> dict[str, int]:
        """Flat counters."""
        out = {"messages": self.messages, "bearings": self.bearings, "steps": self.steps}
        out.update({f"fixes.{k}": v for k, v in sorted(self.fixes.items())})
        out.update({f"assessments.{k}": v for k, v in sorted(self.assessments.items())})
        return out


class ResultSink(Protocol):
    """Receives what each step produced (a file writer, a live table, a map)."""

    def on_results(self, fixes: Sequence[Fix], assessments: Sequence[Assessment]) -> None:
        """Handle one step's fixes and assessments."""
        ...

    def close(self) -> None:
        """Flush and release resources."""
        ...


class BearingSink(Protocol):
    """A sink that also wants every sensor's bearings as they arrive (a map, a log)."""

    def on_bearings(self, bearings: BearingBatch, pose: Pose) -> None:
        """Take the bearings sensor ``bearings.sensor_id`` measured from ``pose``."""
        ...


class VerifiedLike(Protocol):
    """What the service needs of a verified safety message."""

    @property
    def bearings(self) -> BearingBatch:
        """The message's bearings; ``sensor_id`` is the sender."""
        ...

    @property
    def message(self) -> Any:
        """The decoded message; ``.pose`` is the sender's :class:`Pose`."""
        ...


class MessageSource(Protocol):
    """Where verified messages come from (a :class:`rfsas_hw.link.Receiver`)."""

    def receive(self, timeout: float | None = None) -> Sequence[VerifiedLike]:
        """Verified messages that arrived within ``timeout`` seconds."""
        ...

    @property
    def latency(self) -> Any:
        """The latency watch; ``.alarm`` is True when a sender is late or silent."""
        ...

    @property
    def stats(self) -> Any:
        """Counters; ``.as_dict()`` gives them flat (verified, rejected by reason)."""
        ...


class JsonlSink:
    """Writes every fix and assessment as one JSON object per line.

    Each line has ``"record": "fix"`` or ``"assessment"`` followed by the
    record's fields (non-finite numbers as null); :meth:`write_stats` adds a
    ``"record": "stats"`` line. With an ``origin`` the first line is
    ``{"record": "site", "origin": {"lat_deg", "lon_deg", "height_m"}}``; with
    ``bearings`` every bearing is a ``"record": "bearing"`` line with the
    sensor's pose (``x_m``, ``y_m``, ``heading_deg``) — what the exports
    (:mod:`rfsas_hw.exports`) draw bearing lines from.

    Raises:
        BackendError: the file cannot be opened.
    """

    def __init__(
        self, path: str | Path, *, origin: SiteOrigin | None = None, bearings: bool = False
    ) -> None:
        self.path = Path(path)
        try:
            self._file: IO[str] | None = self.path.open("w", encoding="utf-8")
        except OSError as err:
            raise BackendError(f"{self.path}: cannot write: {err.strerror or err}") from err
        self.lines = 0
        self.bearings = bearings
        if origin is not None:
            o = {"lat_deg": origin.lat_deg, "lon_deg": origin.lon_deg, "height_m": origin.height_m}
            self._write("site", {"origin": o})

    def on_bearings(self, bearings: BearingBatch, pose: Pose) -> None:
        """Append one line per bearing (only with ``bearings=True``)."""
        if not self.bearings:
            return
        for i in range(len(bearings)):
            self._write(
                "bearing",
                {
                    "t_ns": int(bearings.t_ns[i]),
                    "sensor_id": bearings.sensor_id,
                    "emitter": emitter_hex(int(bearings.emitter[i])),
                    "azimuth_deg": _finite(bearings.azimuth_deg[i]),
                    "sigma_deg": _finite(bearings.sigma_deg[i]),
                    "snr_db": _finite(bearings.snr_db[i]),
                    "channel": int(bearings.channel[i]),
                    "x_m": _finite(pose.x_m),
                    "y_m": _finite(pose.y_m),
                    "heading_deg": _finite(pose.heading_deg),
                },
            )

    def _write(self, kind: str, data: dict[str, Any]) -> None:
        if self._file is None:
            raise BackendError(f"{self.path}: writer is closed")
        self._file.write(json.dumps({"record": kind, **data}, allow_nan=False) + "\n")
        self.lines += 1

    def on_results(self, fixes: Sequence[Fix], assessments: Sequence[Assessment]) -> None:
        """Append one step's records and flush."""
        for fix in fixes:
            self._write("fix", fix.as_dict())
        for assessment in assessments:
            self._write("assessment", assessment.as_dict())
        if self._file is not None:
            self._file.flush()

    def write_stats(self, stats: dict[str, int]) -> None:
        """Append a line of counters."""
        self._write("stats", dict(stats))

    def close(self) -> None:
        """Close the file; idempotent."""
        if self._file is not None:
            self._file.close()
            self._file = None


def _finite(value: Any) -> float | None:
    """A float for JSON: None where it is not finite."""
    v = float(value)
    return v if math.isfinite(v) else None


class BackendService:
    """Associates, triangulates, tracks and judges risk (see the module docstring).

    Args:
        config: the service's settings.
        vehicle: the vehicle state to judge risk against (None: risk not computed).
        sinks: where each step's fixes and assessments go.
        link_alarm: returns True while the link's latency watch is alarmed.
        clock: UTC time in ns.
    """

    def __init__(
        self,
        config: BackendConfig | None = None,
        *,
        vehicle: VehicleState | None = None,
        sinks: Iterable[ResultSink] = (),
        link_alarm: Callable[[], bool] | None = None,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        self.config = config or BackendConfig()
        self.vehicle = vehicle
        self.sinks = list(sinks)
        self.link_alarm = link_alarm
        self.clock = clock
        self.associator = Associator(self.config.association)
        self.tracker = Tracker(self.config.tracker)
        self.bearing_tracker = (
            BearingTracker(self.tracker, self.config.bearings)
            if self.config.tracking == "bearings"
            else None
        )
        self.stats = BackendStats()
        self.stations: dict[str, Pose] = {}
        """Latest pose of every sensor heard, by sensor id."""
        self.fixes: dict[int, Fix] = {}
        """Latest fix of every emitter, by emitter id."""
        self.stepped: dict[int, Fix] = {}
        """The fixes the last :meth:`step` made that it still holds (in :attr:`fixes`),
        by emitter id."""
        self.assessments: dict[int, Assessment] = {}
        """Latest assessment of every live emitter, by emitter id."""
        self.link_stats: Callable[[], dict[str, int]] | None = None
        """Counters of the link (verified, rejected by reason), merged into :meth:`all_stats`."""
        self.sink_errors: dict[str, str] = {}
        """The first error of every sink that raised, by sink name."""

    def _sink_failed(self, sink: object, err: Exception, what: str) -> None:
        name = str(getattr(sink, "path", None) or type(sink).__name__)
        if name not in self.sink_errors:
            # one line: the run's end reports it, and a full disk must not bury the
            # operator's console in tracebacks
            self.sink_errors[name] = f"{what}: {getattr(err, 'strerror', None) or err}"
            log.warning("result sink %s %s: %s", name, what, err)
            log.debug("result sink %s failure", name, exc_info=True)

    def problems(self) -> list[str]:
        """One line per sink whose output failed (a write error, or a sender whose
        ``problem()`` says nothing got through), for the run's end."""
        found = [f"{name}: {text}" for name, text in self.sink_errors.items()]
        for sink in self.sinks:
            error = getattr(sink, "error", None)
            if isinstance(error, str):
                found.append(error)
            problem = getattr(sink, "problem", None)
            text = problem() if callable(problem) else None
            if isinstance(text, str):
                found.append(f"{type(sink).__name__}: {text}")
        return found

    def set_vehicle(self, vehicle: VehicleState | None) -> None:
        """Use ``vehicle`` as the vehicle state from now on (None: stop judging risk)."""
        self.vehicle = vehicle

    def on_bearings(self, bearings: BearingBatch, pose: Pose) -> None:
        """Take the bearings sensor ``bearings.sensor_id`` measured from ``pose``."""
        self.stations[bearings.sensor_id] = pose
        self.stats.bearings += len(bearings)
        self.associator.add(bearings, pose)
        if self.bearing_tracker is not None:
            self.bearing_tracker.take(bearings, pose)
        for sink in self.sinks:
            take = getattr(sink, "on_bearings", None)
            if take is None:
                continue
            try:
                take(bearings, pose)
            except Exception as err:
                self._sink_failed(sink, err, "failed on bearings")

    def on_verified(self, message: VerifiedLike) -> None:
        """Take a verified safety message (``rfsas_hw.link.VerifiedMessage``)."""
        self.stats.messages += 1
        self.on_bearings(message.bearings, message.message.pose)

    def step(self, now_ns: int | None = None, *, assess: bool = True) -> list[Assessment]:
        """Triangulate new groups, update tracks, judge every live emitter; feed the sinks.

        Args:
            now_ns: UTC ns of the step (default: the clock).
            assess: judge every live emitter against the service's vehicle into
                :attr:`assessments` (True, the default). False: only fixes and tracks;
                :attr:`assessments` is emptied and the sinks get no assessments — for
                a caller that judges other vehicles itself (:meth:`assess_many`) and
                takes the emitters' positions from :meth:`predicted`.

        Returns:
            This step's assessments, highest risk first (none with ``assess=False``).
        """
        now = self.clock() if now_ns is None else int(now_ns)
        self.stats.steps += 1
        made = self._triangulate(now)
        fixes = [f for _, f in made]
        keep = max(now - int(self.config.tracker.drop_after_s * NS_PER_S), self._epoch_floor(now))
        self.tracker.prune(now, keep)
        for emitter in [e for e, f in self.fixes.items() if f.t_ns < keep]:
            del self.fixes[emitter]
        held_now = self.fixes
        self.stepped = {e: f for e, f in made if held_now.get(e) is f}
        held = list(self.fixes.items())
        assessments = (
            self._assess(now, [self._vehicle_at(now)], held, [range(len(held))])[0]
            if assess
            else []
        )
        self.assessments = {int(a.emitter, 16): a for a in assessments}
        for sink in self.sinks:
            try:
                sink.on_results(fixes, assessments)
            except Exception as err:
                self._sink_failed(sink, err, "failed")
        return assessments

    def _epoch_floor(self, now: int) -> int:
        """The earliest last-fix time (UTC ns) a track or fix may have at ``now`` for its
        epoch: with ``tracker.epoch_overlap_s``, once that long into a nonce epoch
        (``association.epoch_s``, on the UTC grid), its start; before then, the
        previous epoch's start (0 without it)."""
        overlap = self.config.tracker.epoch_overlap_s
        if overlap is None:
            return 0
        schedule = EpochSchedule(self.config.association.epoch_s, 0.0)
        epoch = schedule.epoch_of(now)
        if now - schedule.start_ns(epoch) < overlap * NS_PER_S:
            epoch -= 1
        return schedule.start_ns(epoch)

    def _triangulate(self, now: int) -> list[tuple[int, Fix]]:
        """Fix every group of bearings ready at ``now``: per fix, its emitter id and the
        fix (held in :attr:`fixes`; the trustworthy ones update the tracks)."""
        # tracks fed by bearings: a bearing from outside its unit's field of view stays
        # out of the fixes as it stays out of the tracks
        admit = None if self.bearing_tracker is None else self.bearing_tracker.admit
        groups = self.associator.groups(now, admit=admit)
        if len(groups) == 0:
            if self.bearing_tracker is not None:
                self.bearing_tracker.step(
                    self.associator, [], [], np.empty((0, 2)), np.empty((0, 2, 2)), []
                )
            return []
        opts = self.config.triangulation
        batch = triangulate_batch(groups.stations_xy, groups.azimuth_deg, groups.sigma_deg, opts)
        emitters = groups.emitter.tolist()
        times = groups.t_ns.tolist()
        gdop, condition = batch.gdop.tolist(), batch.condition.tolist()
        # every column as Python numbers once (the values float() gives row by row)
        positions, covs = batch.position.tolist(), batch.covariance.tolist()
        statuses, reasons = batch.statuses(), batch.reasons()
        out = []
        for i, emitter in enumerate(emitters):
            cov = covs[i]
            fix = Fix(
                t_ns=times[i],
                emitter=emitter_hex(emitter),
                x_m=positions[i][0],
                y_m=positions[i][1],
                cov_xx_m2=cov[0][0],
                cov_xy_m2=cov[0][1],
                cov_yy_m2=cov[1][1],
                ok=statuses[i] is FixStatus.OK,
                status=statuses[i].name.lower(),
                reason=reasons[i],
                sensors=groups.sensors[i],
                gdop=gdop[i],
                condition=condition[i],
            )
            self.stats.fixes[fix.status] += 1
            self.fixes[emitter] = fix
            out.append(fix)
        good = [i for i, fix in enumerate(out) if fix.ok]
        if self.bearing_tracker is not None:
            self.bearing_tracker.step(
                self.associator,
                [emitters[i] for i in good],
                [times[i] for i in good],
                batch.position[good],
                batch.covariance[good],
                [out[i].sensors for i in good],
            )
        elif good:
            self.tracker.update_many(
                [emitters[i] for i in good],
                [times[i] for i in good],
                batch.position[good],
                batch.covariance[good],
                [out[i].sensors for i in good],
            )
        return list(zip(emitters, out, strict=True))

    def _vehicle_at(self, now: int) -> VehicleState | None:
        return None if self.vehicle is None else self.vehicle.at(now)

    def assess_for(
        self, vehicle: VehicleState, emitters: Iterable[int], now_ns: int | None = None
    ) -> list[Assessment]:
        """Judge the live ``emitters`` (ids as integers) against another ``vehicle`` than
        the service's own, at ``now_ns`` (UTC ns; default: the clock): :meth:`assess_many`
        of one vehicle.

        Returns:
            The assessments of those emitters, highest risk first (unknown ids are skipped).
        """
        return self.assess_many([(vehicle, emitters)], now_ns)[0]

    def assess_many(
        self,
        requests: Sequence[tuple[VehicleState, Iterable[int]]],
        now_ns: int | None = None,
    ) -> list[list[Assessment]]:
        """Judge, for each ``(vehicle, emitters)`` of ``requests``, the live ``emitters``
        (ids as integers) against that vehicle (not the service's own), at ``now_ns``
        (UTC ns; default: the clock). Nothing is kept and no sink is fed: a backend
        serving many vehicles calls it once per step with the emitters near each
        vehicle; the tracks are predicted once and every (vehicle, emitter) pair is
        judged in one batch, each pair as it would be alone.

        Returns:
            Per request, the assessments of its emitters, highest risk first (unknown
            ids are skipped).
        """
        now = self.clock() if now_ns is None else int(now_ns)
        wanted = [set(emitters) for _, emitters in requests]
        union = set().union(*wanted)
        fixes = [(e, f) for e, f in self.fixes.items() if e in union]
        row_of = {e: i for i, (e, _) in enumerate(fixes)}
        rows = [sorted(row_of[e] for e in keep if e in row_of) for keep in wanted]
        return self._assess(now, [v for v, _ in requests], fixes, rows)

    def _assess(
        self,
        now: int,
        vehicles: Sequence[VehicleState | None],
        fixes: list[tuple[int, Fix]],
        rows: Sequence[Sequence[int]],
    ) -> list[list[Assessment]]:
        """Per vehicle (None: no vehicle state), the assessments of its ``rows`` of
        ``fixes``, highest risk first. The tracks of ``fixes`` are predicted once;
        the encounters of every vehicle with its tracked rows are one batch."""
        alarm = bool(self.link_alarm()) if self.link_alarm is not None else False
        tracks, states, covs = self._predict(now, fixes)
        # every (vehicle, tracked row) pair, judged in one batch
        owner: list[int] = []
        pair_rows: list[int] = []
        judged = [v for v in vehicles if v is not None]
        index = 0
        for vehicle, chosen in zip(vehicles, rows, strict=True):
            if vehicle is None:
                continue
            for i in chosen:
                if tracks[i] is not None:
                    owner.append(index)
                    pair_rows.append(i)
            index += 1
        encounters = iter(
            self._encounters(judged, owner, states, covs, fixes, pair_rows, alarm, tracks)
        )
        # plain floats once for all rows (the same values float() gives one by one)
        state_rows = states.tolist()
        cov_rows = covs[:, :2, :2].reshape(-1, 4).tolist()
        # an untracked emitter's assessment does not depend on the vehicle (only on
        # whether there is one): built once per row and shared (it is immutable)
        unlocated: dict[tuple[int, bool], Assessment] = {}
        counts = self.stats.assessments
        out = []
        for vehicle, chosen in zip(vehicles, rows, strict=True):
            unjudged = "none" if vehicle is None else self.unlocated_advice(alarm)
            mine = []
            for i in chosen:
                fix = fixes[i][1]
                track = tracks[i]
                if track is None:
                    shared = unlocated.get((i, vehicle is None))
                    if shared is None:
                        shared = unlocated[i, vehicle is None] = self._assessment(
                            now,
                            fix,
                            None,
                            state_rows[i],
                            cov_rows[i],
                            None,
                            alarm,
                            vehicle,
                            unjudged,
                        )
                    counts[shared.advisory] += 1
                    mine.append(shared)
                    continue
                enc = next(encounters) if vehicle is not None else None
                mine.append(
                    self._assessment(
                        now, fix, track, state_rows[i], cov_rows[i], enc, alarm, vehicle, unjudged
                    )
                )
                counts[mine[-1].advisory] += 1
            mine.sort(key=lambda a: -a.risk if math.isfinite(a.risk) else 1.0)
            out.append(mine)
        return out

    def unlocated_advice(self, alarm: bool | None = None) -> str:
        """The advice every vehicle gets about an emitter heard but not tracked (its
        latest fix not trustworthy), the same for every vehicle: ``caution`` with
        ``caution_on_bad_fix``, or with ``caution_on_link_alarm`` during a link latency
        alarm (``alarm``; None: asked of :attr:`link_alarm` now), else ``clear``."""
        if alarm is None:
            alarm = bool(self.link_alarm()) if self.link_alarm is not None else False
        th = self.config.encounter.thresholds
        if th.caution_on_bad_fix or (alarm and th.caution_on_link_alarm):
            return Advisory.CAUTION.value
        return Advisory.CLEAR.value

    def _predict(
        self, now: int, fixes: list[tuple[int, Fix]]
    ) -> tuple[list[Track | None], np.ndarray, np.ndarray]:
        """Per row of ``fixes``: its emitter's track (None: not tracked), its predicted
        state ``[x, y, vx, vy]`` at ``now`` (rows (N, 4); not tracked: the fix's
        position and NaN velocity) and that state's 4×4 covariance (NaN when not
        tracked)."""
        nan = math.nan
        accel = self.config.tracker.accel_sigma_mps2
        tracks = [self.tracker.tracks.get(emitter) for emitter, _ in fixes]
        live = [(i, t) for i, t in enumerate(tracks) if t is not None]
        if len(live) == len(fixes):  # every emitter tracked (the usual case): no NaN rows
            states, covs = predict_tracks([t for _, t in live], now, accel)
            return tracks, states, covs
        tracked = [i for i, _ in live]
        states = np.full((len(fixes), 4), nan)
        covs = np.full((len(fixes), 4, 4), nan)
        if live:
            states[tracked], covs[tracked] = predict_tracks([t for _, t in live], now, accel)
        for i, (_, fix) in enumerate(fixes):
            if tracks[i] is None:  # not tracked: the fix's position, nothing else
                states[i, 0], states[i, 1] = fix.x_m, fix.y_m
        return tracks, states, covs

    def predicted(
        self, now_ns: int, emitters: Iterable[int] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every live emitter (one with a fix held, as :attr:`fixes`; of ``emitters``
        only, when given) at ``now_ns`` (UTC ns): their ids (uint64, in the order of
        :attr:`fixes`, or of ``emitters`` skipping those not held) and ``[x_m, y_m,
        vx_mps, vy_mps]`` per emitter (rfsas frame; its track predicted to ``now_ns``,
        or where it is not tracked its fix's position, NaN when not located, and NaN
        velocity): the positions and velocities :meth:`step` would give its
        assessments."""
        if emitters is None:
            held = list(self.fixes.items())
        else:
            fixes = self.fixes
            held = [(e, fixes[e]) for e in emitters if e in fixes]
        ids = np.fromiter((e for e, _ in held), np.uint64, len(held))
        if not held:
            return ids, np.empty((0, 4))
        return ids, self._predict(int(now_ns), held)[1]

    def _assessment(
        self,
        now: int,
        fix: Fix,
        track: Track | None,
        state: list[float],
        cov: list[float],
        enc: Encounter | None,
        alarm: bool,
        vehicle: VehicleState | None,
        unjudged: str,
    ) -> Assessment:
        """One emitter's assessment from its fix, track, predicted state and encounter
        (not counted in :attr:`stats`: the caller counts each pair it gives out)."""
        nan = math.nan
        reasons: tuple[str, ...]
        if track is not None:
            age_s = (now - track.t_ns) / NS_PER_S
            sensors = track.sensors
        else:
            age_s = (now - fix.t_ns) / NS_PER_S
            sensors = fix.sensors
        if enc is not None:
            p_coll, t_closest, contact = (
                enc.p_collision,
                enc.t_closest_s,
                enc.distance_to_contact_m,
            )
            impact, fatal, risk = enc.impact_speed_mps, enc.fatality_risk, enc.risk
            advisory, reasons = enc.advisory.value, enc.reasons
        else:
            p_coll = t_closest = contact = impact = fatal = risk = nan
            advisory = unjudged
            if vehicle is None:
                reasons = ("no vehicle state",)
            else:
                unlocated = ("emitter not located: " + fix.reason,)
                reasons = unlocated + (("link latency alarm",) if alarm else ())
        return Assessment(
            t_ns=now,
            emitter=fix.emitter,
            x_m=state[0],
            y_m=state[1],
            cov_xx_m2=cov[0],
            cov_xy_m2=cov[1],
            cov_yy_m2=cov[3],
            vx_mps=state[2],
            vy_mps=state[3],
            age_s=age_s,
            sensors=sensors,
            fix_ok=fix.ok,
            fix_reason=fix.reason,
            link_alarm=alarm,
            p_collision=p_coll,
            t_closest_s=t_closest,
            distance_to_contact_m=contact,
            impact_speed_mps=impact,
            fatality_risk=fatal,
            risk=risk,
            advisory=advisory,
            reasons=reasons,
        )

    def _encounters(
        self,
        vehicles: Sequence[VehicleState],
        owner: list[int],
        states: np.ndarray,
        covs: np.ndarray,
        fixes: list[tuple[int, Fix]],
        rows: list[int],
        alarm: bool,
        tracks: Sequence[Track | None],
    ) -> list[Encounter]:
        """The encounter of each pair: the tracked emitter of ``rows[b]`` (its track took
        ``updates`` fixes since it started) with ``vehicles[owner[b]]``."""
        if not rows:
            return []
        cfg = self.config.encounter
        every = rows == list(range(len(states)))  # rows are then 0, 1, …: no copy
        return assess_pairs(
            vehicles,
            owner,
            states if every else states[rows],
            covs if every else covs[rows],
            cfg,
            fix_ok=[fixes[i][1].ok for i in rows],
            fix_reason=[fixes[i][1].reason for i in rows],
            link_alarm=alarm,
            track_fixes=[tracks[i].updates for i in rows],  # type: ignore[union-attr]
        )

    def run(
        self,
        source: MessageSource,
        *,
        duration_s: float | None = None,
        vehicle_feed: VehicleFeed | None = None,
        on_step: Callable[[list[Assessment]], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
    ) -> None:
        """Receive, associate and judge until ``duration_s`` passes or ``should_stop()``.

        Args:
            source: verified messages (a ``rfsas_hw.link.Receiver`` listening on UDP).
            duration_s: how long to run, seconds (None: until stopped).
            vehicle_feed: a UDP feed of vehicle states, polled every step.
            on_step: called with each step's assessments (e.g. to redraw a table).
            should_stop: polled between receives; True ends the loop.
        """
        if self.link_alarm is None:
            self.link_alarm = lambda: bool(source.latency.alarm)
        if self.link_stats is None:
            self.link_stats = lambda: dict(source.stats.as_dict())
        start = time.monotonic()
        step_s = self.config.step_s
        next_step = start + step_s
        while True:
            now_mono = time.monotonic()
            if duration_s is not None and now_mono - start >= duration_s:
                break
            if should_stop is not None and should_stop():
                break
            for message in source.receive(timeout=max(next_step - now_mono, 0.0)):
                self.on_verified(message)
            if time.monotonic() >= next_step:
                next_step += step_s * max(1, math.ceil((time.monotonic() - next_step) / step_s))
                if vehicle_feed is not None:
                    self.set_vehicle(vehicle_feed.poll(0.0) or self.vehicle)
                assessments = self.step()
                if on_step is not None:
                    on_step(assessments)

    def all_stats(self) -> dict[str, int]:
        """The service's counters and the link's (prefixed ``link.``), flat."""
        out = self.stats.as_dict()
        if self.bearing_tracker is not None:
            out.update(
                {f"tracking.{k}": v for k, v in self.bearing_tracker.stats.as_dict().items()}
            )
        if self.link_stats is not None:
            out.update({f"link.{k}": v for k, v in self.link_stats().items()})
        return out

    def close(self) -> None:
        """Close every sink (a JSONL sink gets a final stats line first)."""
        for sink in self.sinks:
            try:
                if isinstance(sink, JsonlSink):
                    sink.write_stats(self.all_stats())
                sink.close()
            except Exception as err:
                self._sink_failed(sink, err, "could not be closed")
