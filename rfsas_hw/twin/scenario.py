"""Scenario files: the versioned, seeded YAML description of one simulated world.

A scenario names an intersection (buildings as axis-aligned rectangles that
block line of sight), movers (pedestrians, cyclists, vehicles following
waypoints), emitters (a MAC, a technology, a transmit power and a traffic
model, carried by a mover or standing still), and sensors (roadside or on a
vehicle, with a two-beam antenna, a receiver type, driver quirks and a scan
plan). Positions are metres east/north of the intersection centre; headings
are compass degrees.

Loading goes through :func:`rfsas_hw.config.from_mapping`, so an unknown key
is an error naming the file and the key path. Cross references (a sensor
mounted on a mover that does not exist, two emitters with one MAC) are checked
here with the same kind of message.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from rfsas_hw.config import from_mapping, read_yaml
from rfsas_hw.errors import ConfigError, DataFormatError
from rfsas_hw.outpaths import safe_name
from rfsas_hw.records import mac_to_int
from rfsas_hw.rf.channels import channel_to_freq_mhz
from rfsas_hw.rf.link_budget import MAX_EIRP_DBM

SCHEMA_VERSION = 1
"""The scenario format this code reads; files carry it as ``version``."""

Detail = Literal["low", "medium", "high"]
MoverKind = Literal["pedestrian", "cyclist", "vehicle", "static"]
Tech = Literal["wifi", "ble"]
ReceiverType = Literal["radiotap-2-chain", "two-single-chain-cards", "serial-board"]
TrafficModel = Literal["beacon", "probe-bursts", "ble-adv", "data-bursts"]
PathLoss = Literal["table", "breakpoint", "coherent"]
Fading = Literal["none", "rayleigh", "rician"]

DEFAULT_SIZE_M: dict[str, tuple[float, float]] = {
    "pedestrian": (0.5, 0.5),
    "cyclist": (1.8, 0.6),
    "vehicle": (4.5, 1.8),
    "static": (0.5, 0.5),
}
"""Default (length, width) of each mover kind, metres."""

DEFAULT_TX_POWER_DBM: dict[str, float] = {"wifi": 27.0, "ble": 7.0}
"""Transmit power per technology when a scenario does not give one (method.md §2)."""

DEFAULT_THRESHOLD_DBM: dict[str, float] = {"wifi": -90.89, "ble": -103.9}
"""Receiver sensitivity per technology (method.md §2); SNR is measured against it."""


@dataclass(frozen=True)
class BuildingSpec:
    """An axis-aligned building footprint that blocks line of sight."""

    x_min_m: float
    """West edge, metres east of the centre."""
    x_max_m: float
    """East edge, metres."""
    y_min_m: float
    """South edge, metres north of the centre."""
    y_max_m: float
    """North edge, metres."""
    name: str = ""
    """Label for maps."""
    loss_db: float = 20.0
    """Extra loss of a path that crosses the footprint, dB."""

    def __post_init__(self) -> None:
        if not (self.x_min_m < self.x_max_m and self.y_min_m < self.y_max_m):
            raise ValueError("building needs x_min_m < x_max_m and y_min_m < y_max_m")
        if self.loss_db < 0:
            raise ValueError("building loss_db must not be negative")


@dataclass(frozen=True)
class IntersectionSpec:
    """The intersection: road widths for maps and the buildings around it."""

    road_half_width_m: float = 7.0
    """Half the width of each road, metres (drawn on maps)."""
    buildings: tuple[BuildingSpec, ...] = ()
    """Building footprints."""


@dataclass(frozen=True)
class WaypointSpec:
    """A point of a mover's route and the speed of the leg that starts there."""

    x_m: float
    """East, metres."""
    y_m: float
    """North, metres."""
    speed_mps: float = 0.0
    """Speed on the leg from this waypoint to the next, m/s (ignored on the last one)."""
    pause_s: float = 0.0
    """Time spent standing at this waypoint before leaving it, seconds."""


@dataclass(frozen=True)
class MoverSpec:
    """Something that moves along waypoints: a pedestrian, a cyclist, a vehicle."""

    id: str
    """Unique id within the scenario."""
    kind: MoverKind
    """What it is (sets the default size)."""
    waypoints: tuple[WaypointSpec, ...]
    """Route; one waypoint for something standing still."""
    start_s: float = 0.0
    """Scenario time at which it leaves the first waypoint, seconds."""
    length_m: float | None = None
    """Length along the heading, metres (default by kind)."""
    width_m: float | None = None
    """Width across the heading, metres (default by kind)."""

    def size_m(self) -> tuple[float, float]:
        """(length, width) in metres, defaults filled in."""
        length, width = DEFAULT_SIZE_M[self.kind]
        return (self.length_m or length, self.width_m or width)


@dataclass(frozen=True)
class PoseSpec:
    """A fixed pose: position and compass heading of the boresight."""

    x_m: float
    """East, metres."""
    y_m: float
    """North, metres."""
    heading_deg: float
    """Compass azimuth of the array boresight, degrees."""


@dataclass(frozen=True)
class AntennaSpec:
    """The squinted two-beam antenna of a sensor (method.md §4)."""

    squint_deg: float = 30.0
    """Offset of each beam from boresight, degrees."""
    beamwidth_deg: float = 60.0
    """3 dB beamwidth of each beam, degrees."""
    gain_dbi: float = 3.0
    """Peak gain of each beam, dBi."""
    front_to_back_db: float = 25.0
    """How far below the peak the pattern floors, dB."""
    chain_offsets_db: tuple[float, float] = (0.0, 0.0)
    """Fixed gain imbalance of chain 0 and chain 1, dB (what K_D calibrates away)."""


@dataclass(frozen=True)
class ScanSpec:
    """A sensor's scan plan: which channels it visits and for how long."""

    channels: tuple[int, ...] = (6,)
    """Channels visited in turn (one channel: no hopping)."""
    dwell_ms: float = 100.0
    """Time on each channel, milliseconds, including the switch time."""
    switch_ms: float = 0.0
    """Dead time at the start of each dwell while the radio retunes, milliseconds."""
    offset_ms: float = 0.0
    """Phase of the plan: time of the first dwell's start, milliseconds."""

    def __post_init__(self) -> None:
        if not self.channels:
            raise ValueError("a scan plan needs at least one channel")
        if self.dwell_ms <= 0 or not 0 <= self.switch_ms < self.dwell_ms:
            raise ValueError("scan plan needs dwell_ms > 0 and 0 <= switch_ms < dwell_ms")


@dataclass(frozen=True)
class DriverSpec:
    """What the receiver's driver does with the per-chain readings."""

    combined: Literal["max", "power-sum"] = "max"
    """How the driver forms the combined signal (iwlwifi/mt76: max)."""
    missing_chain: Literal["sentinel", "omit"] = "sentinel"
    """A chain that heard nothing: reported as ``missing_chain_dbm`` or left out."""
    missing_chain_dbm: int = -128
    """Sentinel value of a missing chain (iwlwifi: S8_MIN = -128)."""
    chain_drop_prob: float = 0.0
    """Probability that one chain reports nothing for a frame."""
    step_db: float = 1.0
    """Reporting step of the RSSI, dB (0: unquantised, only for the virtual source)."""
    measurement_floor_db: float = 1.0
    """Per-chain RSSI spread at high SNR (AGC, estimator), dB."""
    tsft_drift_ppm: float = 0.0
    """Largest drift of a card's TSF clock against UTC, ppm (each card draws its own)."""
    delivery_jitter_us: float = 150.0
    """Largest delay between the frame on air and its capture timestamp, microseconds."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.chain_drop_prob < 1.0:
            raise ValueError("chain_drop_prob must be in [0, 1)")
        if not -128 <= self.missing_chain_dbm <= 127:
            raise ValueError("missing_chain_dbm must fit a signed byte")


@dataclass(frozen=True)
class SensorSpec:
    """A direction-finding sensor: roadside (fixed pose) or on board a mover."""

    id: str
    """Sensor id (goes into bearings and messages)."""
    kind: Literal["roadside", "on-board"]
    """Roadside units have a fixed ``pose``; on-board units follow ``mounted_on``."""
    receiver: ReceiverType = "radiotap-2-chain"
    """Hardware: one 2-chain card, two single-chain cards, or the serial DF board."""
    pose: PoseSpec | None = None
    """Fixed pose of a roadside unit."""
    mounted_on: str | None = None
    """Mover id an on-board unit rides on."""
    heading_offset_deg: float = 0.0
    """On-board: boresight relative to the vehicle heading, degrees clockwise."""
    antenna: AntennaSpec = field(default_factory=AntennaSpec)
    """The two-beam antenna."""
    calibration: str | None = None
    """Calibration table file, relative to the scenario file."""
    driver: DriverSpec = field(default_factory=DriverSpec)
    """Driver quirks."""
    scan: ScanSpec = field(default_factory=ScanSpec)
    """Scan plan."""
    threshold_dbm: dict[str, float] = field(default_factory=dict)
    """Sensitivity per technology (``wifi``, ``ble``), dBm; defaults from method.md §2."""
    card_macs: tuple[str, ...] = ()
    """Hardware addresses of the capture cards (only used in capture metadata)."""

    def threshold_for(self, tech: str) -> float:
        """Sensitivity for ``tech`` in dBm."""
        return float(self.threshold_dbm.get(tech, DEFAULT_THRESHOLD_DBM[tech]))

    def hears(self, tech: str) -> bool:
        """Whether this receiver type can hear ``tech`` frames at all."""
        return tech == "wifi" or self.receiver == "serial-board"

    @property
    def n_cards(self) -> int:
        """How many capture files the receiver produces."""
        return 2 if self.receiver == "two-single-chain-cards" else 1


@dataclass(frozen=True)
class TrafficSpec:
    """When an emitter transmits and on which channels.

    Models: ``beacon`` (an AP every ``interval_s``, default 102.4 ms, on one
    channel), ``probe-bursts`` (a phone sweeping ``channels`` every
    ``interval_s``, ``frames_per_channel`` probe requests ``gap_ms`` apart,
    ``channel_dwell_ms`` per channel), ``ble-adv`` (advertising events every
    ``interval_s`` plus a random 0–``jitter_ms`` delay, one packet on each of
    channels 37/38/39), ``data-bursts`` (``burst_frames`` data frames
    ``gap_ms`` apart every ``interval_s`` on one channel).
    """

    model: TrafficModel
    """Traffic model (see above)."""
    interval_s: float | None = None
    """Period of beacons, bursts or advertising events, seconds (default per model)."""
    jitter_ms: float | None = None
    """Random extra delay of each event, milliseconds (default per model)."""
    channels: tuple[int, ...] = ()
    """Channels used (default per model)."""
    frames_per_channel: int = 2
    """Probe requests sent on each channel of a sweep."""
    gap_ms: float = 1.0
    """Spacing of frames within a burst, milliseconds."""
    channel_dwell_ms: float = 15.0
    """Probe sweep: time spent on each channel, milliseconds."""
    burst_frames: int = 8
    """Data bursts: frames per burst."""
    peer_mac: str = "02:00:5e:10:00:01"
    """Data bursts: the access point the data goes to."""
    ssid: str = "rfsas-demo"
    """Beacons: the network name."""
    phase_s: float | None = None
    """Time of the first event, seconds (None: drawn from the scenario seed)."""

    def __post_init__(self) -> None:
        if self.interval_s is not None and self.interval_s <= 0:
            raise ValueError("traffic interval_s must be positive")
        if self.frames_per_channel < 1 or self.burst_frames < 1:
            raise ValueError("frames_per_channel and burst_frames must be at least 1")
        if self.gap_ms < 0 or self.channel_dwell_ms <= 0:
            raise ValueError("gap_ms must be >= 0 and channel_dwell_ms > 0")

    def effective_interval_s(self) -> float:
        """``interval_s`` with the model's default filled in, seconds."""
        defaults = {"beacon": 0.1024, "probe-bursts": 2.0, "ble-adv": 0.1, "data-bursts": 0.5}
        return float(self.interval_s if self.interval_s is not None else defaults[self.model])

    def effective_jitter_ms(self) -> float:
        """``jitter_ms`` with the model's default filled in, milliseconds."""
        defaults = {"beacon": 0.5, "probe-bursts": 200.0, "ble-adv": 10.0, "data-bursts": 50.0}
        return float(self.jitter_ms if self.jitter_ms is not None else defaults[self.model])

    def effective_channels(self) -> tuple[int, ...]:
        """``channels`` with the model's default filled in."""
        if self.channels:
            return self.channels
        if self.model == "ble-adv":
            return (37, 38, 39)
        if self.model == "probe-bursts":
            return tuple(range(1, 14))
        return (6,)


@dataclass(frozen=True)
class EmitterSpec:
    """A transmitter: a phone, an access point, a BLE tag."""

    id: str
    """Unique id within the scenario (ground truth names emitters by it)."""
    mac: str
    """Transmitter address, ``aa:bb:cc:dd:ee:ff``."""
    tech: Tech
    """``wifi`` or ``ble``."""
    traffic: tuple[TrafficSpec, ...]
    """When it transmits: one or more traffic models (e.g. probe bursts and data)."""
    tx_power_dbm: float | None = None
    """Transmit power, dBm (default 27 for Wi-Fi, 7 for BLE)."""
    antenna_gain_dbi: float = 3.0
    """Transmit antenna gain, dBi."""
    carried_by: str | None = None
    """Mover id that carries it."""
    position: tuple[float, float] | None = None
    """Fixed (east, north) position in metres, when not carried."""

    def power_dbm(self) -> float:
        """Transmit power with the technology default filled in, dBm."""
        if self.tx_power_dbm is not None:
            return float(self.tx_power_dbm)
        return DEFAULT_TX_POWER_DBM[self.tech]


@dataclass(frozen=True)
class RfSpec:
    """Propagation and measurement settings shared by every link."""

    path_loss: PathLoss = "table"
    """``table`` (published two-ray asymptote), ``breakpoint`` or ``coherent`` two-ray."""
    offset_db: float | None = None
    """Constant of the table model, dB (None: 10·log10 24, the published value)."""
    margin_db: float = 15.0
    """Fade / implementation margin, dB."""
    tx_height_m: float = 1.0
    """Emitter antenna height, metres."""
    rx_height_m: float = 1.0
    """Sensor antenna height, metres."""
    fading: Fading = "none"
    """Small-scale fading per frame."""
    rician_k_db: float = 6.0
    """Rician K factor (direct to scattered power), dB."""
    fading_correlation: float = 0.9
    """Correlation of the complex fading gain between the two co-located chains."""
    min_distance_m: float = 1.0
    """Distances are clamped to at least this, metres."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.fading_correlation <= 1.0:
            raise ValueError("fading_correlation must be in [0, 1]")
        if self.min_distance_m <= 0:
            raise ValueError("min_distance_m must be positive")


@dataclass(frozen=True)
class ScenarioSpec:
    """The whole scenario file."""

    version: int
    """Format version; must equal :data:`SCHEMA_VERSION`."""
    name: str
    """Short name."""
    seed: int
    """Seed of every random draw; the same seed gives the same output."""
    duration_s: float
    """Simulated time, seconds."""
    sensors: tuple[SensorSpec, ...]
    """The direction-finding sensors."""
    emitters: tuple[EmitterSpec, ...]
    """The transmitters."""
    movers: tuple[MoverSpec, ...] = ()
    """Everything that moves (or stands) and can carry emitters or sensors."""
    intersection: IntersectionSpec = field(default_factory=IntersectionSpec)
    """Roads and buildings."""
    rf: RfSpec = field(default_factory=RfSpec)
    """Propagation and measurement settings."""
    detail: Detail = "high"
    """Level of detail (method.md §10): low, medium or high."""
    start_utc: str = "2026-01-01T12:00:00Z"
    """UTC time of scenario time 0 (ISO 8601)."""
    description: str = ""
    """Free text."""
    ego: str | None = None
    """Mover id of the vehicle the backend assesses risk for (braking, demo)."""

    def __post_init__(self) -> None:
        if self.duration_s <= 0:
            raise ValueError("duration_s must be positive")


@dataclass(frozen=True)
class Scenario:
    """A loaded, checked scenario and the directory its relative paths start from."""

    spec: ScenarioSpec
    """The parsed file."""
    source: str
    """Where it came from (a path or ``<mapping>``), for messages."""
    base_dir: Path
    """Directory that relative paths (calibration files) are resolved against."""

    @property
    def seed(self) -> int:
        """The scenario seed."""
        return self.spec.seed

    @property
    def t0_ns(self) -> int:
        """Scenario time 0 as UTC nanoseconds."""
        return parse_utc_ns(self.spec.start_utc)

    def sensor(self, sensor_id: str) -> SensorSpec:
        """The sensor with id ``sensor_id``.

        Raises:
            ConfigError: no such sensor.
        """
        for s in self.spec.sensors:
            if s.id == sensor_id:
                return s
        known = ", ".join(s.id for s in self.spec.sensors)
        raise ConfigError(f"{self.source}: no sensor {sensor_id!r} (sensors: {known})")

    def mover(self, mover_id: str) -> MoverSpec:
        """The mover with id ``mover_id``.

        Raises:
            ConfigError: no such mover.
        """
        for m in self.spec.movers:
            if m.id == mover_id:
                return m
        raise ConfigError(f"{self.source}: no mover {mover_id!r}")

    def calibration_path(self, sensor_id: str) -> Path | None:
        """Absolute path of a sensor's calibration file, or None if it has none."""
        cal = self.sensor(sensor_id).calibration
        if cal is None:
            return None
        p = Path(cal)
        return p if p.is_absolute() else self.base_dir / p


def parse_utc_ns(text: str) -> int:
    """UTC nanoseconds of an ISO 8601 time (``Z`` or an offset required).

    Raises:
        ConfigError: not a time, or a naive time without a zone.
    """
    try:
        when = dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError as err:
        raise ConfigError(f"start_utc: not an ISO 8601 time: {text!r}") from err
    if when.tzinfo is None:
        raise ConfigError(f"start_utc: {text!r} has no time zone; add Z for UTC")
    try:
        delta = when - dt.datetime(1970, 1, 1, tzinfo=dt.UTC)
    except OverflowError as err:
        raise ConfigError(f"start_utc: {text!r} is out of range") from err
    return (delta.days * 86_400 + delta.seconds) * 1_000_000_000 + delta.microseconds * 1000


MAX_DURATION_S = 86_400.0
"""Longest scenario, seconds (a day)."""
MIN_INTERVAL_S = 0.001
"""Shortest traffic interval, seconds: no real emitter repeats faster than 1 ms."""
MAX_FRAMES = 5_000_000
"""Most frames a scenario may transmit: the twin holds them in memory (about 100 bytes
each before captures are written), so a file cannot ask for gigabytes."""
START_UTC_RANGE = ("1970-01-01T00:00:00Z", "2200-01-01T00:00:00Z")
"""start_utc must lie in this range: capture times are int64 nanoseconds since 1970."""


def frames_per_event(tr: TrafficSpec) -> int:
    """Frames one event of a traffic model sends (a beacon, a probe sweep, a burst)."""
    if tr.model == "probe-bursts":
        return len(tr.effective_channels()) * tr.frames_per_channel
    if tr.model == "ble-adv":
        return len(tr.effective_channels())
    if tr.model == "data-bursts":
        return tr.burst_frames
    return 1


def expected_frames(spec: ScenarioSpec) -> int:
    """Frames the scenario's emitters transmit over its duration (an upper estimate)."""
    total = 0.0
    for e in spec.emitters:
        for tr in e.traffic:
            events = spec.duration_s / tr.effective_interval_s() + 1
            total += events * frames_per_event(tr)
    return int(min(total, 2**62))


def _check_size(spec: ScenarioSpec, where: str) -> None:
    """Bound every size the file can ask for, and say which key asked."""
    if not spec.duration_s <= MAX_DURATION_S:
        raise ConfigError(
            f"{where}.duration_s: {spec.duration_s:g} s is longer than {MAX_DURATION_S:g} s"
        )
    for i, e in enumerate(spec.emitters):
        for j, tr in enumerate(e.traffic):
            if tr.effective_interval_s() < MIN_INTERVAL_S:
                raise ConfigError(
                    f"{where}.emitters[{i}].traffic[{j}].interval_s: "
                    f"{tr.effective_interval_s():g} s is below {MIN_INTERVAL_S:g} s"
                )
    frames = expected_frames(spec)
    if frames > MAX_FRAMES:
        raise ConfigError(
            f"{where}: the emitters would send about {frames:,} frames in {spec.duration_s:g} s, "
            f"more than {MAX_FRAMES:,} (memory): shorten duration_s or lengthen interval_s"
        )


def _check(spec: ScenarioSpec, where: str) -> None:
    if spec.version != SCHEMA_VERSION:
        raise ConfigError(
            f"{where}.version: scenario format {spec.version} is not supported "
            f"(this version reads {SCHEMA_VERSION})"
        )
    start = parse_utc_ns(spec.start_utc)
    lo, hi = (parse_utc_ns(t) for t in START_UTC_RANGE)
    if not lo <= start < hi:
        raise ConfigError(
            f"{where}.start_utc: {spec.start_utc!r} is outside {START_UTC_RANGE[0]} … "
            f"{START_UTC_RANGE[1]}"
        )
    _check_size(spec, where)
    movers = {m.id: m for m in spec.movers}
    if len(movers) != len(spec.movers):
        raise ConfigError(f"{where}.movers: duplicate mover id")
    for i, m in enumerate(spec.movers):
        at = f"{where}.movers[{i}]"
        if not m.waypoints:
            raise ConfigError(f"{at}.waypoints: at least one waypoint is needed")
        for j, wp in enumerate(m.waypoints[:-1]):
            if wp.speed_mps <= 0:
                raise ConfigError(f"{at}.waypoints[{j}].speed_mps: must be positive on a leg")
        if any(wp.pause_s < 0 for wp in m.waypoints):
            raise ConfigError(f"{at}.waypoints: pause_s must not be negative")
    if spec.ego is not None and spec.ego not in movers:
        raise ConfigError(f"{where}.ego: no mover {spec.ego!r}")
    ids = [s.id for s in spec.sensors]
    if len(set(ids)) != len(ids):
        raise ConfigError(f"{where}.sensors: duplicate sensor id")
    for i, s in enumerate(spec.sensors):
        at = f"{where}.sensors[{i}]"
        safe_name(s.id, f"{at}.id")  # names capture files
        if s.kind == "roadside" and (s.pose is None or s.mounted_on is not None):
            raise ConfigError(f"{at}: a roadside sensor needs pose and no mounted_on")
        if s.kind == "on-board":
            if s.mounted_on is None or s.pose is not None:
                raise ConfigError(f"{at}: an on-board sensor needs mounted_on and no pose")
            if s.mounted_on not in movers:
                raise ConfigError(f"{at}.mounted_on: no mover {s.mounted_on!r}")
        for tech in s.threshold_dbm:
            if tech not in DEFAULT_THRESHOLD_DBM:
                raise ConfigError(f"{at}.threshold_dbm: unknown technology {tech!r}")
        for k, mac in enumerate(s.card_macs):
            _mac(mac, f"{at}.card_macs[{k}]")
    ids = [e.id for e in spec.emitters]
    if len(set(ids)) != len(ids):
        raise ConfigError(f"{where}.emitters: duplicate emitter id")
    seen: dict[int, str] = {}
    for i, e in enumerate(spec.emitters):
        at = f"{where}.emitters[{i}]"
        mac_int = _mac(e.mac, f"{at}.mac")
        if mac_int in seen:
            raise ConfigError(f"{at}.mac: {e.mac} is also emitter {seen[mac_int]!r}")
        seen[mac_int] = e.id
        if (e.carried_by is None) == (e.position is None):
            raise ConfigError(f"{at}: give exactly one of carried_by and position")
        if e.carried_by is not None and e.carried_by not in movers:
            raise ConfigError(f"{at}.carried_by: no mover {e.carried_by!r}")
        if e.power_dbm() + e.antenna_gain_dbi > MAX_EIRP_DBM + 1e-9:
            raise ConfigError(f"{at}: EIRP above the +{MAX_EIRP_DBM:.0f} dBm limit")
        if not e.traffic:
            raise ConfigError(f"{at}.traffic: at least one traffic model is needed")
        for j, tr in enumerate(e.traffic):
            tat = f"{at}.traffic[{j}]"
            if (tr.model == "ble-adv") != (e.tech == "ble"):
                raise ConfigError(f"{tat}.model: {tr.model} does not fit tech {e.tech}")
            if tr.model == "data-bursts":
                _mac(tr.peer_mac, f"{tat}.peer_mac")
            for ch in tr.effective_channels():
                try:
                    channel_to_freq_mhz(ch, e.tech)
                except ConfigError as err:
                    raise ConfigError(f"{tat}.channels: {err}") from err


def _mac(text: str, where: str) -> int:
    try:
        return mac_to_int(text)
    except DataFormatError as err:
        raise ConfigError(f"{where}: {err}") from err


def scenario_from_mapping(
    data: Mapping[str, Any], where: str = "<mapping>", base_dir: Path | None = None
) -> Scenario:
    """Check and build a scenario from parsed YAML.

    Raises:
        ConfigError: unknown key, wrong type, bad value or broken reference,
            with ``where`` and the key path.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping at the top level")
    spec = from_mapping(ScenarioSpec, data, where)
    _check(spec, where)
    return Scenario(spec=spec, source=where, base_dir=base_dir or Path.cwd())


def load_scenario(path: str | Path) -> Scenario:
    """Read and check a scenario file.

    Raises:
        ConfigError: unreadable file, invalid YAML, unknown key, bad value or
            broken reference (named with the file and key path).
    """
    p = Path(path)
    data = read_yaml(p)
    return scenario_from_mapping(data or {}, str(p), p.resolve().parent)
