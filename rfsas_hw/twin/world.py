"""The digital twin: every frame an emitter sends while a sensor listens on its channel.

:class:`World` ties a scenario together: tracks for the movers, transmission
times for the emitters, the scan plan of each sensor, and the link physics of
:mod:`rfsas_hw.twin.rfworld`. :meth:`World.receptions` gives, per sensor, the
frames it hears with what each receive chain reports, plus the ground truth
of every frame (true bearing, distance, SNR, blockage).

Levels of detail (method.md §10):

- ``low``: states assigned parametrically; RSSI is the noise-free link budget
  through the beam pattern (no blockage, fading, noise or driver quirks).
- ``medium``: kinematic motion with assigned measurement properties: each
  chain gets Gaussian noise whose size makes the monopulse bearing error
  equal the SNR formula ``σ = β/(k_m·√SNR)``; no blockage, fading or quirks.
- ``high``: the physical model: path loss, blockage, beam gains, optional
  fading, thermal plus measurement-floor noise, quantisation, missing chains
  and the driver's combined signal.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rfsas_hw.angles import math_rad_to_compass, wrap_deg_180
from rfsas_hw.records import ObservationBatch, ObsFlag, mac_to_int
from rfsas_hw.rf.antenna import GaussianBeamPair
from rfsas_hw.rf.aoa import sigma_monopulse_deg
from rfsas_hw.rf.channels import channel_to_freq_mhz
from rfsas_hw.rf.noise import quantise_db, rssi_sigma_db
from rfsas_hw.twin.motion import Track, static_track
from rfsas_hw.twin.rfworld import (
    blockage_db,
    building_array,
    combine_chains,
    fading_from_normals,
    fading_normals,
    link_path_loss_db,
    nearest_first,
)
from rfsas_hw.twin.rng import stream
from rfsas_hw.twin.scan import ScanPlan
from rfsas_hw.twin.scenario import Detail, Scenario, SensorSpec
from rfsas_hw.twin.traffic import EmitterTraffic, Transmissions, traffic_streams

Array = npt.NDArray[np.float64]

CHAIN_PRESENT = 0
"""``Receptions.chain_state``: the chain reported a value."""
CHAIN_SENTINEL = 1
"""The chain reported the driver's sentinel (e.g. -128 dBm)."""
CHAIN_OMITTED = 2
"""The driver left the chain out of the frame."""
CHAIN_NOT_HEARD = 3
"""The card of this chain did not capture the frame (two single-chain cards)."""

Listening = Callable[[Array, npt.NDArray[np.int16]], npt.NDArray[np.bool_]]
"""``(t_s, channel) → mask``: whether a receiver was on each frame's channel at its time."""

TECH_CODES = {"wifi": 0, "ble": 1}
"""``Receptions.tech`` values."""

_FREQS: dict[tuple[int, int], int] = {}
"""Centre frequency (MHz) by (tech code, channel), filled as channels are met."""

_FREQ_TABLE = np.zeros((len(TECH_CODES), 256), np.int32)
"""The same for channels 0–255 as an array (0: not met yet)."""


def no_frames() -> dict[str, npt.NDArray[Any]]:
    """The empty frame table (columns ``t``, ``emitter``, ``channel``, ``kind``, ``seq``)."""
    return {
        "t": np.empty(0),
        "emitter": np.empty(0, np.intp),
        "channel": np.empty(0, np.int16),
        "kind": np.empty(0, np.uint8),
        "seq": np.empty(0, np.int32),
    }


_NO_TABLE: tuple[int, npt.NDArray[np.uint8], npt.NDArray[np.float64], npt.NDArray[np.float64]] = (
    0,
    np.zeros(0, np.uint8),
    np.zeros(0),
    np.zeros(0),
)
"""The emitter table of no emitter (see :meth:`World._emitter_table`)."""

_LAYOUTS_MAX = 64
"""How many :class:`_Layout` a world keeps (sensor sets × frame counts) before starting over."""


class _Layout:
    """Per-sensor constants of one :meth:`World._receive_many` call, repeated over its rows.

    Sensor ``k`` owns ``counts[k]`` rows. The arrays are what the call would
    build (same dtypes and values) and are read-only: callers compute from
    them or copy them.
    """

    def __init__(
        self, sensors: Sequence[SensorSpec], counts: list[int], rxs: Sequence[ReceiverStreams]
    ) -> None:
        self.sensors = list(sensors)  # keeps the ids in the cache key alive
        self.rxs = list(rxs)
        self.xy = np.repeat(
            np.array(
                [(s.pose.x_m, s.pose.y_m) if s.pose is not None else (0.0, 0.0) for s in sensors],
                np.float64,
            ),
            counts,
            axis=0,
        )
        self.heading = np.repeat(
            np.array(
                [s.pose.heading_deg % 360.0 if s.pose is not None else 0.0 for s in sensors],
                np.float64,
            ),
            counts,
        )
        self.offsets = np.repeat(
            np.array([s.antenna.chain_offsets_db for s in sensors], np.float64), counts, axis=0
        )
        self.clock0 = np.repeat([rx.tsft0_us[0] for rx in rxs], counts)[:, None]
        self.rate = np.repeat([rx.drift[0] for rx in rxs], counts)[:, None]
        for a in (self.xy, self.heading, self.offsets, self.clock0, self.rate):
            a.flags.writeable = False


def _quantise_each(
    values: npt.NDArray[np.float64], sensors: Sequence[SensorSpec], parts: Sequence[slice]
) -> npt.NDArray[np.float64]:
    """``values`` quantised to each sensor's driver step, sensor ``k`` owning rows
    ``parts[k]``; in one call when every sensor has the same step."""
    steps = {s.driver.step_db for s in sensors}
    if len(steps) == 1:
        return quantise_db(values, steps.pop())
    for s, p in zip(sensors, parts, strict=True):
        values[p] = quantise_db(values[p], s.driver.step_db)
    return values


def _frequency(code: int, channel: int) -> int:
    """Centre frequency (MHz) of ``channel`` of the technology with ``code``.

    Raises:
        ConfigError: not a channel of that technology.
    """
    freq = _FREQS.get((code, channel))
    if freq is None:
        freq = channel_to_freq_mhz(channel, list(TECH_CODES)[code])
        _FREQS[(code, channel)] = freq
        if 0 <= channel < _FREQ_TABLE.shape[1]:
            _FREQ_TABLE[code, channel] = freq
    return freq


@dataclass
class Receptions:
    """The frames one sensor hears, with its readings and the truth, one row per frame.

    Rows are sorted by time on air. For ``radiotap-2-chain`` and
    ``serial-board`` receivers there is one card; for
    ``two-single-chain-cards`` card ``c`` carries chain ``c``.
    """

    sensor_id: str
    """The sensor."""
    n_cards: int
    """Capture cards of the receiver (1 or 2)."""
    t_s: Array
    """Time the frame started on air, scenario seconds."""
    t_ns: npt.NDArray[np.int64]
    """Same, UTC nanoseconds."""
    emitter: npt.NDArray[np.intp]
    """Index of the emitter in the scenario."""
    mac: npt.NDArray[np.uint64]
    """Transmitter MAC (raw; simulator-internal and capture files only)."""
    channel: npt.NDArray[np.int16]
    """Channel of the frame."""
    freq_mhz: npt.NDArray[np.int32]
    """Centre frequency, MHz."""
    kind: npt.NDArray[np.uint8]
    """:class:`FrameKind`."""
    seq: npt.NDArray[np.int32]
    """Sequence number or -1."""
    tech: npt.NDArray[np.uint8]
    """:data:`TECH_CODES` value."""
    chain_dbm: Array
    """Reading per chain, dBm, shape (n, 2); NaN unless ``chain_state`` is present."""
    chain_state: npt.NDArray[np.uint8]
    """``CHAIN_*`` per chain, shape (n, 2)."""
    combined_dbm: Array
    """Driver's combined signal of a 2-chain card, dBm (NaN if no chain)."""
    heard: npt.NDArray[np.bool_]
    """Whether each card captured the frame, shape (n, n_cards)."""
    capture_ns: npt.NDArray[np.int64]
    """Capture timestamp on each card, UTC ns, shape (n, n_cards)."""
    tsft_us: npt.NDArray[np.uint64]
    """Each card's TSF timer when the frame arrived, microseconds, shape (n, n_cards)."""
    true_relative_deg: Array
    """True angle of the emitter from boresight, degrees clockwise."""
    true_azimuth_deg: Array
    """True compass azimuth from the sensor to the emitter, degrees."""
    distance_m: Array
    """True distance, metres."""
    snr_db: Array
    """True per-chain power above the sensitivity threshold, dB, shape (n, 2)."""
    blocked: npt.NDArray[np.bool_]
    """The straight path crosses a building."""
    sensor_xy: Array
    """Sensor position at the frame, metres, shape (n, 2)."""
    sensor_heading_deg: Array
    """Sensor boresight at the frame, compass degrees."""
    emitter_xy: Array
    """Emitter position at the frame, metres, shape (n, 2)."""

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def select(self, index: npt.NDArray[Any] | slice) -> Receptions:
        """Rows picked by a mask, an index array or a slice."""
        kw = {
            name: getattr(self, name)[index]
            for name in self.__dataclass_fields__
            if name not in ("sensor_id", "n_cards")
        }
        return Receptions(sensor_id=self.sensor_id, n_cards=self.n_cards, **kw)

    def observations(self, card: int | None = None) -> ObservationBatch:
        """What the sensor's driver would hand to the pipeline, as an observation batch.

        With ``card=None`` both chains side by side (frames paired perfectly
        for two single-chain cards), otherwise the frames of one card with
        that card's chain only. Sentinel chains become NaN with
        ``SENTINEL_CHAIN``; omitted or unheard ones NaN with ``MISSING_CHAIN``.
        """
        if card is None:
            # the usual case, every card heard every frame: no copies (one reduction)
            rows = slice(None) if self.heard.all() else self.heard.any(axis=1)
            if not isinstance(rows, slice) and rows.all():
                rows = slice(None)
            rssi = self.chain_dbm[rows]
            state = self.chain_state[rows]
            capture = self.capture_ns[rows]
            t_ns = capture[:, 0] if self.n_cards == 1 else capture.min(axis=1)
        else:
            rows = self.heard[:, card]
            rssi = self.chain_dbm[rows][:, [card]]
            state = self.chain_state[rows][:, [card]]
            t_ns = self.capture_ns[rows, card]
        if not state.any():  # every chain present (CHAIN_PRESENT is 0): no flag to set
            flags = np.zeros(len(state), np.uint16)
        else:
            flags = np.where(
                (state == CHAIN_SENTINEL).any(axis=1),
                np.uint16(ObsFlag.SENTINEL_CHAIN),
                np.uint16(0),
            )
            missing = state >= CHAIN_OMITTED  # omitted or not heard
            flags |= np.where(missing.any(axis=1), np.uint16(ObsFlag.MISSING_CHAIN), np.uint16(0))
        if card is None and self.n_cards > 1:
            flags |= np.uint16(ObsFlag.PAIRED)
        return ObservationBatch(
            t_ns=t_ns,
            mac=self.mac[rows],
            freq_mhz=self.freq_mhz[rows],
            channel=self.channel[rows],
            rssi_dbm=rssi.astype(np.float32),
            seq=self.seq[rows],
            kind=self.kind[rows],
            flags=flags,
        )


class ReceiverStreams:
    """A sensor's random streams, one per purpose, and its cards' clocks.

    Each purpose (fading, noise, chain drops, capture delay) draws from its
    own stream in frame order, so the frames of a scenario can be computed in
    one piece or window by window with the same result.

    Args:
        seed: the scenario seed.
        sensor: the sensor.
        detail: the level of detail (part of the stream names).
    """

    def __init__(self, seed: int, sensor: SensorSpec, detail: Detail) -> None:
        names = ("rf", sensor.id, detail)
        self.fade_common = stream(seed, *names, "fade-common")
        self.fade_own = stream(seed, *names, "fade-own")
        self.noise = stream(seed, *names, "noise")
        self.drop = stream(seed, *names, "drop")
        self.drop_chain = stream(seed, *names, "drop-chain")
        self.jitter = stream(seed, *names, "capture-delay")
        clock_rng = stream(seed, "tsft", sensor.id)
        self.tsft0_us = clock_rng.integers(10**6, 10**10, sensor.n_cards)
        """Each card's TSF timer at scenario time 0, microseconds."""
        # every card's crystal is off by its own amount, up to ±tsft_drift_ppm
        self.drift = 1.0 + sensor.driver.tsft_drift_ppm * 1e-6 * clock_rng.uniform(
            -1.0, 1.0, sensor.n_cards
        )
        """Rate of each card's TSF clock against true time."""


class World:
    """A scenario brought to life: tracks, traffic, scan plans and link physics.

    Args:
        scenario: the loaded scenario.
        detail: override the scenario's level of detail.
        listening: per sensor id, which channel the receiver is on, replacing its
            scan plan (a cue-driven schedule): ``listening[id](t_s, channel)`` is
            True where the receiver was on ``channel`` at scenario time ``t_s``.
    """

    def __init__(
        self,
        scenario: Scenario,
        detail: Detail | None = None,
        listening: Mapping[str, Listening] | None = None,
    ) -> None:
        self.scenario = scenario
        self.listening: dict[str, Listening] = dict(listening or {})
        spec = scenario.spec
        self.detail: Detail = detail or spec.detail
        self.duration_s = spec.duration_s
        self.t0_ns = scenario.t0_ns
        self.tracks: dict[str, Track] = {m.id: Track.from_spec(m) for m in spec.movers}
        self.rects = building_array(spec.intersection.buildings)
        self.emitter_macs = np.array([mac_to_int(e.mac) for e in spec.emitters], np.uint64)
        self.tx: list[Transmissions] = [
            EmitterTraffic(e.traffic, traffic_streams(spec.seed, e.id, len(e.traffic))).advance(
                spec.duration_s
            )
            for e in spec.emitters
        ]
        self.antennas: dict[str, GaussianBeamPair] = {
            s.id: GaussianBeamPair(
                squint_deg=s.antenna.squint_deg,
                beamwidth_deg=s.antenna.beamwidth_deg,
                peak_gain_dbi=s.antenna.gain_dbi,
                front_to_back_db=s.antenna.front_to_back_db,
            )
            for s in spec.sensors
        }
        self._cache: dict[str, Receptions] = {}
        self._tables: dict[str, tuple[int, npt.NDArray[np.uint8], Array, Array]] = {}
        """Per sensor id: how many emitters its table covers, and the table."""
        self._layouts: dict[tuple[object, ...], _Layout] = {}
        self._near_rects: dict[str, tuple[Array, npt.NDArray[np.intp]]] = {}
        """Per standing sensor id: the buildings nearest first (:func:`nearest_first`)."""

    # -- geometry -----------------------------------------------------------------

    def emitter_track(self, index: int) -> Track:
        """Track of emitter ``index`` (its carrier's, or a standing one)."""
        e = self.scenario.spec.emitters[index]
        if e.carried_by is not None:
            return self.tracks[e.carried_by]
        assert e.position is not None
        return static_track(*e.position)

    def emitter_position(self, index: int, t_s: npt.ArrayLike) -> Array:
        """Position of emitter ``index`` at times ``t_s``, shape (n, 2), metres."""
        return self.emitter_track(index).position(t_s)

    def sensor_pose(self, sensor: SensorSpec | str, t_s: npt.ArrayLike) -> tuple[Array, Array]:
        """Position (n, 2) in metres and boresight compass heading (n,) of a sensor at ``t_s``."""
        s = self.scenario.sensor(sensor) if isinstance(sensor, str) else sensor
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        if s.pose is not None:
            xy = np.empty((len(t), 2))
            xy[:] = (s.pose.x_m, s.pose.y_m)
            return xy, np.full(len(t), s.pose.heading_deg % 360.0)
        assert s.mounted_on is not None
        track = self.tracks[s.mounted_on]
        heading = np.mod(track.heading_deg(t) + s.heading_offset_deg, 360.0)
        return track.position(t), heading

    # -- frames -------------------------------------------------------------------

    def _candidates(self, s: SensorSpec) -> dict[str, Any]:
        """Every transmitted frame the sensor could hear by tech and channel."""
        plan = ScanPlan.from_spec(s.scan)
        listens = self.listening.get(s.id)
        parts: dict[str, list[Any]] = {k: [] for k in ("t", "emitter", "channel", "kind", "seq")}
        for i, (e, tx) in enumerate(zip(self.scenario.spec.emitters, self.tx, strict=True)):
            if not s.hears(e.tech) or len(tx) == 0:
                continue
            if listens is not None:
                listening = np.asarray(listens(tx.t_s, tx.channel), bool)
            else:
                listening = plan.channel_at(tx.t_s) == tx.channel
            parts["t"].append(tx.t_s[listening])
            parts["emitter"].append(np.full(int(listening.sum()), i, np.intp))
            parts["channel"].append(tx.channel[listening])
            parts["kind"].append(tx.kind[listening])
            parts["seq"].append(tx.seq[listening])
        if not parts["t"]:
            return no_frames()
        out = {k: np.concatenate(v) for k, v in parts.items()}
        order = np.lexsort((out["emitter"], out["t"]))
        return {k: v[order] for k, v in out.items()}

    def receptions(self, sensor_id: str) -> Receptions:
        """Every frame sensor ``sensor_id`` hears during the scenario (computed once, cached).

        Raises:
            ConfigError: no such sensor.
        """
        if sensor_id not in self._cache:
            self._cache[sensor_id] = self._compute(self.scenario.sensor(sensor_id))
        return self._cache[sensor_id]

    def _compute(self, s: SensorSpec) -> Receptions:
        rx = ReceiverStreams(self.scenario.seed, s, self.detail)
        return self._receive(s, self._candidates(s), rx)

    def _frame_positions(self, c: dict[str, Any]) -> Array:
        """Where each candidate frame's emitter was when it sent it, shape (n, 2), metres."""
        t = c["t"]
        e_idx = c["emitter"]
        exy = np.empty((len(t), 2))
        for i in np.unique(e_idx):
            sel = e_idx == i
            exy[sel] = self.emitter_position(int(i), t[sel])
        return exy

    def _emitter_table(self, s: SensorSpec) -> tuple[npt.NDArray[np.uint8], Array, Array]:
        """Per emitter: tech code, radiated power (dBm) and sensor ``s``'s threshold (dBm).

        Kept between calls and grown by the emitters added since: emitters are
        only ever appended, never changed.
        """
        emitters = self.scenario.spec.emitters
        if not emitters:
            return np.zeros(1, np.uint8), np.zeros(1), np.zeros(1)
        known, codes, power, threshold = self._tables.get(s.id, _NO_TABLE)
        if known < len(emitters):
            new = emitters[known:]
            codes = np.concatenate([codes, np.array([TECH_CODES[e.tech] for e in new], np.uint8)])
            power = np.concatenate(
                [power, np.array([e.power_dbm() + e.antenna_gain_dbi for e in new], np.float64)]
            )
            threshold = np.concatenate(
                [threshold, np.array([s.threshold_for(e.tech) for e in new], np.float64)]
            )
            self._tables[s.id] = (len(emitters), codes, power, threshold)
        return codes, power, threshold

    def _frequencies(
        self, tech: npt.NDArray[np.uint8], channel: npt.NDArray[np.int16]
    ) -> npt.NDArray[np.int32]:
        """Centre frequency of each frame, MHz, from its tech code and channel."""
        if not len(tech):
            return np.zeros(0, np.int32)
        if channel.min() >= 0 and channel.max() < _FREQ_TABLE.shape[1]:
            freq = _FREQ_TABLE[tech, channel]
            if freq.all():  # every channel met before
                return freq
        key = tech.astype(np.int64) * 65536 + channel.astype(np.int64) + 32768
        uniq, inverse = np.unique(key, return_inverse=True)
        table = np.array(
            [_frequency(k // 65536, k % 65536 - 32768) for k in uniq.tolist()], np.int32
        )
        return np.asarray(table[inverse.reshape(-1)], np.int32)

    def _sensor_poses(
        self,
        sensors: list[SensorSpec],
        cands: list[dict[str, Any]],
        parts: list[slice],
        layout: _Layout | None,
    ) -> tuple[Array, Array]:
        """:meth:`sensor_pose` of every sensor at its candidates' times, stacked.

        Standing sensors' rows are a copy of ``layout``'s (the values
        :meth:`sensor_pose` gives, repeated), so only sensors on a vehicle cost
        a lookup. ``layout`` may be None for one sensor only.
        """
        if len(sensors) == 1 or layout is None:
            return self.sensor_pose(sensors[0], cands[0]["t"])
        xy, heading = layout.xy.copy(), layout.heading.copy()
        for s, c, p in zip(sensors, cands, parts, strict=True):
            if s.pose is None:
                xy[p], heading[p] = self.sensor_pose(s, c["t"])
        return xy, heading

    def _blockage(
        self,
        sensors: list[SensorSpec],
        parts: list[slice],
        sxy: Array,
        exy: Array,
        dist: Array,
    ) -> tuple[Array, npt.NDArray[np.bool_]]:
        """:func:`blockage_db` of the paths ``sxy → exy`` (``dist`` long, metres), sensor
        ``k`` owning rows ``parts[k]``: a standing sensor's paths are clipped only against
        the buildings within its longest path of the call (a path from the sensor cannot
        reach farther; the buildings nearest each sensor are sorted once)."""
        groups: list[tuple[int, npt.NDArray[np.intp] | None]] = []
        for s, p in zip(sensors, parts, strict=True):
            count = p.stop - p.start
            if s.pose is None or count == 0:
                groups.append((count, None))
                continue
            near = self._near_rects.get(s.id)
            if near is None:
                near = self._near_rects[s.id] = nearest_first((s.pose.x_m, s.pose.y_m), self.rects)
            # a metre more than the longest path: no rounding can leave a building out
            within = int(np.searchsorted(near[0], float(dist[p].max()) + 1.0, side="right"))
            groups.append((count, np.sort(near[1][:within])))
        return blockage_db(sxy, exy, self.rects, groups)

    def _layout(
        self, items: Sequence[tuple[SensorSpec, dict[str, Any], ReceiverStreams]], counts: list[int]
    ) -> _Layout:
        """The per-sensor constants of :meth:`_receive_many` for these sensors and frame
        counts, built once per such combination (consecutive windows usually repeat it)."""
        key = (tuple(id(s) for s, _, _ in items), tuple(id(rx) for _, _, rx in items), *counts)
        layout = self._layouts.get(key)
        if layout is None:
            if len(self._layouts) >= _LAYOUTS_MAX:
                self._layouts.clear()
            layout = self._layouts[key] = _Layout(
                [s for s, _, _ in items], counts, [rx for _, _, rx in items]
            )
        return layout

    def _receive(self, s: SensorSpec, c: dict[str, Any], rx: ReceiverStreams) -> Receptions:
        """What sensor ``s`` makes of the candidate frames ``c`` (time-sorted).

        Every random draw comes from ``rx``'s per-purpose streams in frame
        order, so consecutive windows give exactly what one long window gives.
        """
        return self._receive_many([(s, c, rx)])[0]

    def _receive_many(
        self, items: Sequence[tuple[SensorSpec, dict[str, Any], ReceiverStreams]]
    ) -> list[Receptions]:
        """:meth:`_receive` for several sensors at once, one :class:`Receptions` each.

        The frames of all sensors go through the geometry and the link budget
        as one array (one numpy call per stage instead of one per sensor);
        each sensor's random streams are drawn for its own frames, in frame
        order, so every sensor gets exactly what :meth:`_receive` gives it alone.
        """
        spec = self.scenario.spec
        rf = spec.rf
        sensors = [s for s, _, _ in items]
        cands = [c for _, c, _ in items]
        counts = [len(c["t"]) for c in cands]
        bounds = [0, *itertools.accumulate(counts)]
        parts = [slice(bounds[k], bounds[k + 1]) for k in range(len(items))]

        def cat(name: str) -> npt.NDArray[Any]:
            return np.concatenate([c[name] for c in cands]) if len(cands) > 1 else cands[0][name]

        def each(arrays: list[npt.NDArray[Any]]) -> npt.NDArray[Any]:
            return np.concatenate(arrays) if len(arrays) > 1 else arrays[0]

        t = cat("t")
        n = len(t)
        e_idx = cat("emitter")
        channel = cat("channel")
        codes, power_e, _ = self._emitter_table(sensors[0])
        tech = codes[e_idx]
        freq = self._frequencies(tech, channel)
        threshold = each(
            [self._emitter_table(s)[2][c["emitter"]] for s, c in zip(sensors, cands, strict=True)]
        )
        positions: dict[int, Array] = {}  # sensors with the same candidates share them
        for c in cands:
            if id(c) not in positions:
                positions[id(c)] = self._frame_positions(c)
        exy = each([positions[id(c)] for c in cands])
        layout = self._layout(items, counts) if len(items) > 1 else None
        sxy, heading = self._sensor_poses(sensors, cands, parts, layout)
        delta = exy - sxy
        dist = np.hypot(delta[:, 0], delta[:, 1])
        azimuth = math_rad_to_compass(np.arctan2(delta[:, 1], delta[:, 0]))
        relative = wrap_deg_180(azimuth - heading)
        antennas = [self.antennas[s.id] for s in sensors]
        if all(a == antennas[0] for a in antennas):  # units of one build
            gains = antennas[0].gains_db(relative)
        else:
            gains = each([a.gains_db(relative[p]) for a, p in zip(antennas, parts, strict=True)])
        pt = power_e[e_idx]
        pl = link_path_loss_db(dist, freq, rf)
        physical = self.detail == "high"
        if physical:
            block, blocked = self._blockage(sensors, parts, sxy, exy, dist)
            if rf.fading == "none":
                fade = np.zeros((n, 2))
            else:
                # each sensor's own draws, the arithmetic on all of them at once
                normals = [
                    fading_normals(k, rx.fade_common, rx.fade_own)
                    for k, (_, _, rx) in zip(counts, items, strict=True)
                ]
                fade = fading_from_normals(
                    each([z[0] for z in normals]),
                    each([z[1] for z in normals]),
                    rf.fading,
                    rf.rician_k_db,
                    rf.fading_correlation,
                )
        else:
            block, blocked = np.zeros(n), np.zeros(n, dtype=bool)
            fade = np.zeros((n, 2))
        power = (pt - pl - rf.margin_db - block)[:, None] + gains + fade
        if physical:
            if layout is not None:
                power = power + layout.offsets
            else:
                offsets = np.array([s.antenna.chain_offsets_db for s in sensors], np.float64)
                power = power + np.repeat(offsets, counts, axis=0)
        snr = power - threshold[:, None]
        sigma = np.empty((n, 2))
        floors = {s.driver.measurement_floor_db for s in sensors}
        if self.detail == "high" and len(floors) == 1:
            sigma = rssi_sigma_db(snr, next(iter(floors)))
        else:
            for s, p in zip(sensors, parts, strict=True):
                if self.detail == "high":
                    sigma[p] = rssi_sigma_db(snr[p], s.driver.measurement_floor_db)
                elif self.detail == "medium":
                    # noise that makes the monopulse bearing error equal σ_amp(SNR)
                    best = snr[p].max(axis=1) if p.stop > p.start else np.empty(0)
                    sig_deg = sigma_monopulse_deg(best, beamwidth_deg=s.antenna.beamwidth_deg)
                    slope = self.antennas[s.id].difference_slope_db_per_deg()
                    sig_db = np.asarray(sig_deg) * slope / math.sqrt(2)
                    sigma[p] = np.repeat(np.atleast_1d(sig_db)[:, None], 2, axis=1)
                else:
                    sigma[p] = 0.0
        noise = each(
            [rx.noise.standard_normal((k, 2)) for k, (_, _, rx) in zip(counts, items, strict=True)]
        )
        reading = power + sigma * noise
        if physical:
            reading = _quantise_each(reading, sensors, parts)
        reading = np.clip(reading, -127.0, 127.0)
        state = np.zeros((n, 2), np.uint8)
        heard_any = np.empty(n, bool)
        heard_by: list[npt.NDArray[np.bool_]] = []
        # one capture card per sensor (the usual case): its columns for all sensors at once
        one_card = all(s.n_cards == 1 for s in sensors)
        if one_card:
            heard_all = (power.max(axis=1) >= threshold)[:, None] if n else np.zeros((0, 1), bool)
            heard_any = heard_all[:, 0]
        for (s, _, rx), k, p in zip(items, counts, parts, strict=True):
            st = state[p]
            drv = s.driver
            if physical and drv.chain_drop_prob > 0 and s.receiver != "two-single-chain-cards":
                drop = rx.drop.random(k) < drv.chain_drop_prob
                which = (rx.drop_chain.random(k) < 0.5).astype(np.intp)
                lost = CHAIN_SENTINEL if drv.missing_chain == "sentinel" else CHAIN_OMITTED
                st[drop, which[drop]] = lost
            if one_card:
                continue
            if s.n_cards == 2:
                heard = power[p] >= threshold[p, None]
                st[~heard] = CHAIN_NOT_HEARD
            elif k:
                heard = (power[p].max(axis=1) >= threshold[p])[:, None]
            else:
                heard = np.zeros((0, 1), bool)
            heard_any[p] = heard.any(axis=1)
            heard_by.append(heard)
        chain = np.where(state == CHAIN_PRESENT, reading, np.nan)
        combined = np.empty(n)
        for how in {s.driver.combined for s in sensors}:
            rows = [p for s, p in zip(sensors, parts, strict=True) if s.driver.combined == how]
            if len(rows) == len(parts):
                combined = combine_chains(chain, how)
            else:
                for p in rows:
                    combined[p] = combine_chains(chain[p], how)
        if physical:
            combined = _quantise_each(combined, sensors, parts)
        t_ns = self.t0_ns + np.round(t * 1e9).astype(np.int64)
        mac = self.emitter_macs[e_idx] if n else np.empty(0, np.uint64)
        kept = np.flatnonzero(heard_any)
        shared = {
            "t_s": t,
            "t_ns": t_ns,
            "emitter": e_idx,
            "mac": mac,
            "channel": channel,
            "freq_mhz": freq,
            "kind": cat("kind"),
            "seq": cat("seq"),
            "tech": tech,
            "chain_dbm": chain,
            "chain_state": state,
            "combined_dbm": combined,
            "true_relative_deg": relative,
            "true_azimuth_deg": azimuth,
            "distance_m": dist,
            "snr_db": snr,
            "blocked": blocked,
            "sensor_xy": sxy,
            "sensor_heading_deg": heading,
            "emitter_xy": exy,
        }
        if len(kept) < n:
            shared = {name: v[kept] for name, v in shared.items()}
        kept_bounds = bounds if len(kept) == n else np.searchsorted(kept, bounds).tolist()
        jitter_us_all = [s.driver.delivery_jitter_us if physical else 0.0 for s in sensors]
        if one_card:
            # drawn for every candidate frame, heard or not, as the streams require
            delay_us = each(
                [
                    rx.jitter.uniform(0.0, jitter, (k, 1))
                    for (_, _, rx), k, jitter in zip(items, counts, jitter_us_all, strict=True)
                ]
            )
            if layout is not None:
                clock0, rate = layout.clock0, layout.rate
            else:
                clock0 = np.repeat([rx.tsft0_us[0] for _, _, rx in items], counts)[:, None]
                rate = np.repeat([rx.drift[0] for _, _, rx in items], counts)[:, None]
            cards = {
                "heard": heard_all,
                "capture_ns": t_ns[:, None] + np.round(delay_us * 1e3).astype(np.int64),
                "tsft_us": (clock0 + np.floor(t[:, None] * 1e6 * rate)).astype(np.uint64),
            }
            if len(kept) < n:
                cards = {name: v[kept] for name, v in cards.items()}
            return [
                Receptions(
                    sensor_id=s.id,
                    n_cards=1,
                    **{name: v[lo:hi] for name, v in cards.items()},
                    **{name: v[lo:hi] for name, v in shared.items()},
                )
                for s, lo, hi in zip(sensors, kept_bounds[:-1], kept_bounds[1:], strict=True)
            ]
        out = []
        for k, ((s, c, rx), heard) in enumerate(zip(items, heard_by, strict=True)):
            n_cards = s.n_cards
            lo, hi = kept_bounds[k], kept_bounds[k + 1]
            view = {name: v[lo:hi] for name, v in shared.items()}
            # drawn for every candidate frame, heard or not, as the streams require
            delay_us = rx.jitter.uniform(0.0, jitter_us_all[k], (counts[k], n_cards))
            tk = c["t"]
            keep = heard_any[parts[k]]
            capture = t_ns[parts[k], None] + np.round(delay_us * 1e3).astype(np.int64)
            tsft = (rx.tsft0_us[None, :] + np.floor(tk[:, None] * 1e6 * rx.drift[None, :])).astype(
                np.uint64
            )
            if not keep.all():
                heard, capture, tsft = heard[keep], capture[keep], tsft[keep]
            out.append(
                Receptions(
                    sensor_id=s.id,
                    n_cards=n_cards,
                    heard=heard,
                    capture_ns=capture,
                    tsft_us=tsft,
                    **view,
                )
            )
        return out
