"""What cueing buys: time from the roadside unit's first bearing to the vehicle's own.

The scenario (one per seed): a pedestrian's phone sends data in bursts on one
Wi-Fi channel (drawn per seed from the vehicle's hop plan); a roadside unit
listens on that channel; a car waits 60 m south of the crossing and hops over
a 13-channel (2.4 GHz) or a 38-channel (2.4 + 5 GHz) plan, 100 ms a channel.
The roadside unit's bearings go through the real sensor pipeline (monopulse
DF, keyed hashing); for each it signs a cue (``rfsas_hw.link.cue``), at most
one per emitter every ``cue_every_s``; the vehicle's cue receiver checks it,
and its scan scheduler (``rfsas_hw.sources.schedule``) dwells on the cued
channel. The twin then computes what the car hears on that schedule, and the
car's frames go through its own pipeline. The vehicle's bearing is matched
to the roadside one by the keyed hash alone, as the backend would match them.

Without cueing the car simply walks its plan. The same seed gives the same
phone traffic in both runs; only the car's tuning differs.

Measured: ``first vehicle bearing at or after the roadside unit's first
bearing − that first bearing``, seconds; a trial without a vehicle bearing
before the scenario ends is a miss.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.backend.association import AssociationConfig, Associator
from rfsas_hw.backend.triangulation import triangulate
from rfsas_hw.df import Calibration
from rfsas_hw.link.cue import Cue
from rfsas_hw.link.cue_publisher import CuePublisher
from rfsas_hw.link.cue_receiver import (
    CueReceiver,
    CueReceiverConfig,
    cue_bearing,
    to_channel_cue,
)
from rfsas_hw.link.signing import Signer, TrustedKeys
from rfsas_hw.link.transport import Transport
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.records import BearingBatch, Pose, mac_to_int
from rfsas_hw.sources.schedule import CueScheduler, SchedulerConfig
from rfsas_hw.sources.virtual import VirtualSource
from rfsas_hw.studies.demo import EXAMPLE_SCENARIO, run_demo
from rfsas_hw.studies.locate import default_hasher, sensor_calibration
from rfsas_hw.twin.rng import stream
from rfsas_hw.twin.scenario import Scenario, load_scenario, scenario_from_mapping
from rfsas_hw.twin.turntable import turntable_calibration
from rfsas_hw.twin.world import World

Array = npt.NDArray[np.float64]
NS = 1_000_000_000

PLAN_13 = tuple(range(1, 14))
"""The 2.4 GHz plan: channels 1–13."""
PLAN_38 = PLAN_13 + tuple(range(36, 65, 4)) + tuple(range(100, 145, 4)) + tuple(range(149, 166, 4))
"""A 2.4 + 5 GHz plan: 1–13, 36–64, 100–144 and 149–165 (38 channels, ~4 s at 100 ms)."""
PLANS: dict[str, tuple[int, ...]] = {"13": PLAN_13, "38": PLAN_38}

RSU = "rsu"
CAR = "car-obu"
PHONE = "phone"


@dataclass(frozen=True)
class CueingConfig:
    """The study's settings (defaults are the documented run)."""

    dwell_s: float = 0.1
    """Vehicle plan dwell per channel, seconds."""
    burst_interval_s: float = 0.5
    """Mean time between the phone's data bursts, seconds (± 50 ms jitter)."""
    burst_frames: int = 4
    """Frames per burst (2 ms apart)."""
    duration_s: float = 60.0
    """Scenario length, seconds (the horizon for a miss)."""
    process_s: float = 0.1
    """Bearing capture → cue sent (one pipeline batch), seconds."""
    link_s: float = 0.02
    """Cue sent → cue received at the vehicle, seconds."""
    cue_every_s: float = 0.5
    """Most one cue per emitter this often, seconds."""
    cue_valid_s: float = 2.0
    """Validity window of a cue after its bearing, seconds."""
    scheduler: SchedulerConfig = field(default_factory=SchedulerConfig)
    """The vehicle's cue rules."""
    detail: str = "high"
    """Twin level of detail."""


def cueing_scenario(
    seed: int, plan: Sequence[int], config: CueingConfig, phone_channel: int, offset_s: float
) -> Scenario:
    """The study's scenario for one seed (see the module docstring)."""
    data: dict[str, Any] = {
        "version": 1,
        "name": "cueing",
        "seed": seed,
        "start_utc": "2026-01-01T12:00:05Z",
        "duration_s": config.duration_s,
        "detail": config.detail,
        "intersection": {"road_half_width_m": 7.0, "buildings": []},
        "rf": {"path_loss": "table", "margin_db": 15, "fading": "rician", "rician_k_db": 10},
        "movers": [
            {
                "id": "pedestrian",
                "kind": "pedestrian",
                "waypoints": [
                    {"x_m": 10.0, "y_m": -9.0, "speed_mps": 0.25},
                    {"x_m": -5.0, "y_m": -9.0},
                ],
            },
            {"id": "car", "kind": "vehicle", "waypoints": [{"x_m": 1.75, "y_m": -60.0}]},
        ],
        "emitters": [
            {
                "id": PHONE,
                "mac": "3c:22:fb:4e:91:07",
                "tech": "wifi",
                "tx_power_dbm": 20,
                "carried_by": "pedestrian",
                "traffic": [
                    {
                        "model": "data-bursts",
                        "channels": [phone_channel],
                        "interval_s": config.burst_interval_s,
                        "burst_frames": config.burst_frames,
                        "gap_ms": 2.0,
                    }
                ],
            }
        ],
        "sensors": [
            {
                "id": RSU,
                "kind": "roadside",
                "pose": {"x_m": -9.0, "y_m": 9.0, "heading_deg": 150.0},
                "antenna": {"squint_deg": 15, "beamwidth_deg": 30},
                "scan": {"channels": [phone_channel], "dwell_ms": 100},
            },
            {
                "id": CAR,
                "kind": "on-board",
                "mounted_on": "car",
                "antenna": {"squint_deg": 15, "beamwidth_deg": 30},
                "scan": {
                    "channels": list(plan),
                    "dwell_ms": config.dwell_s * 1e3,
                    "offset_ms": offset_s * 1e3,
                },
            },
        ],
    }
    return scenario_from_mapping(data, f"cueing study seed {seed}")


def calibrations(plan: Sequence[int], config: CueingConfig) -> dict[str, Calibration]:
    """Turntable calibrations of both sensors over every channel of ``plan`` (done once:
    a sensor is calibrated on the bench, not per encounter)."""
    sc = cueing_scenario(0, plan, config, plan[0], 0.0)
    return {sid: turntable_calibration(_with_scan(sc, sid, plan), sid) for sid in (RSU, CAR)}


def _with_scan(sc: Scenario, sensor_id: str, plan: Sequence[int]) -> Scenario:
    sensors = tuple(
        dataclasses.replace(s, scan=dataclasses.replace(s.scan, channels=tuple(plan)))
        if s.id == sensor_id
        else s
        for s in sc.spec.sensors
    )
    return dataclasses.replace(sc, spec=dataclasses.replace(sc.spec, sensors=sensors))


def sensor_bearings(
    world: World, sensor_id: str, calibration: Calibration, hasher: MacHasher
) -> BearingBatch:
    """Every bearing the sensor's pipeline makes over the scenario."""
    src = VirtualSource(world.scenario, sensor_id, world=world, batch_s=0.1)
    parts: list[BearingBatch] = []
    with src:
        pipe = SensorPipeline(calibration, hasher, sensor_id, src.pose_at(world.t0_ns))
        for batch in src:
            pipe.pose = src.pose_at(int(np.median(batch.t_ns)))
            parts.append(pipe.process(batch))
    return BearingBatch.concat(sensor_id, parts)


@dataclass
class Trial:
    """One seed's result on one plan."""

    seed: int
    phone_channel: int
    rsu_first_s: float
    """Roadside unit's first bearing of the phone, scenario seconds (NaN: never)."""
    uncued_s: float
    """Vehicle's first bearing at or after it, minus it, seconds (inf: a miss)."""
    cued_s: float
    """The same with cueing, seconds (inf: a miss)."""
    cues: dict[str, float]
    """Cue receiver and scheduler counters of the cued run."""
    fused_error_m: float = math.nan
    """Cued run: error of the fix from the vehicle's first bearing and the roadside
    bearing of the latest cue, associated by keyed hash, metres (NaN: no fix)."""


def run_trial(
    seed: int,
    plan: Sequence[int],
    config: CueingConfig,
    cals: dict[str, Calibration],
    signer: Signer,
    trust: TrustedKeys,
) -> Trial:
    """Both runs (without and with cueing) of one seed."""
    rng = stream(seed, "cueing-study")
    phone_channel = int(rng.choice(np.asarray(plan)))
    period = config.dwell_s * len(plan)
    offset_s = float(rng.uniform(0.0, period))
    sc = cueing_scenario(seed, plan, config, phone_channel, offset_s)
    hasher = default_hasher()
    plain = World(sc)
    rsu = sensor_bearings(plain, RSU, cals[RSU], hasher)
    phone_mac = mac_to_int(sc.spec.emitters[0].mac)
    t0 = plain.t0_ns
    mine = rsu.emitter == np.uint64(hasher.hash_one(phone_mac, t0))
    if not mine.any():
        return Trial(seed, phone_channel, math.nan, math.inf, math.inf, {})
    rsu_first_ns = int(rsu.t_ns[mine].min())
    uncued = _first_after(sensor_bearings(plain, CAR, cals[CAR], hasher), rsu, rsu_first_ns)

    scheduler = CueScheduler(plan, config.dwell_s, config.scheduler, start_s=offset_s - period)
    rx = CueReceiver(trust, CueReceiverConfig())
    accepted: list[tuple[int, Cue]] = []
    for cue, arrive_ns in _cues(rsu, sc, signer, config, hasher):
        now_s = (arrive_ns - t0) / NS
        got = rx.feed(cue, arrive_ns)
        if got is not None:
            accepted.append((arrive_ns, got))
            scheduler.offer(to_channel_cue(got, arrive_ns, now_s), now_s)
    timeline = scheduler.timeline(config.duration_s)
    cued_world = World(sc, listening={CAR: timeline.listens})
    car = sensor_bearings(cued_world, CAR, cals[CAR], hasher)
    t_car_ns = _first_after_ns(car, rsu, rsu_first_ns)
    cued = math.inf if t_car_ns is None else (t_car_ns - rsu_first_ns) / NS
    counters: dict[str, float] = {**scheduler.stats.as_dict()}
    counters.update({f"rx.{k}": v for k, v in rx.stats.as_dict().items()})
    trial = Trial(seed, phone_channel, (rsu_first_ns - t0) / NS, uncued, cued, counters)
    if t_car_ns is not None:
        trial.fused_error_m = _fused_error(cued_world, car, accepted, t_car_ns)
    return trial


def _fused_error(world: World, car: BearingBatch, cues: list[tuple[int, Cue]], t_ns: int) -> float:
    """Fix from the car's bearing at ``t_ns`` and the latest cue received by then, associated
    by keyed hash as the backend does; its distance to the phone's true position, metres."""
    before = [c for arrive, c in cues if arrive <= t_ns]
    if not before:
        return math.nan
    cue = before[-1]
    assoc = Associator(AssociationConfig(window_s=2.0))
    batch, pose = cue_bearing(cue)
    assoc.add(batch, pose)
    row = np.flatnonzero(car.t_ns == t_ns)[:1]
    t_s = (t_ns - world.t0_ns) / NS
    xy, heading = world.sensor_pose(CAR, [t_s])
    assoc.add(car.select(row), Pose(float(xy[0, 0]), float(xy[0, 1]), float(heading[0])))
    groups = assoc.groups(t_ns)
    if len(groups) != 1 or set(groups.sensors[0]) != {RSU, CAR}:
        return math.nan
    fix = triangulate(groups.stations_xy[0], groups.azimuth_deg[0], groups.sigma_deg[0])
    truth = world.emitter_position(0, [t_s])[0]
    return float(np.hypot(fix.position[0] - truth[0], fix.position[1] - truth[1]))


def _first_after(car: BearingBatch, rsu: BearingBatch, rsu_first_ns: int) -> float:
    """Seconds from the RSU's first bearing to the car's first bearing of an emitter the
    RSU also has (matched by keyed hash only), at or after it; inf if none."""
    t_ns = _first_after_ns(car, rsu, rsu_first_ns)
    return math.inf if t_ns is None else (t_ns - rsu_first_ns) / NS


def _first_after_ns(car: BearingBatch, rsu: BearingBatch, rsu_first_ns: int) -> int | None:
    ok = (car.t_ns >= rsu_first_ns) & np.isin(car.emitter, rsu.emitter)
    return int(car.t_ns[ok].min()) if ok.any() else None


class _Captured(Transport):
    """Keeps what a cue publisher sends, with the time it was sent (the twin's link)."""

    def __init__(self, clock: Callable[[], int]) -> None:
        self.clock = clock
        self.sent: list[tuple[bytes, int]] = []

    def send(self, datagram: bytes) -> None:
        self.sent.append((datagram, self.clock()))

    def recv(self, timeout: float | None = None) -> bytes | None:
        return None

    def close(self) -> None:
        pass


def _cues(
    rsu: BearingBatch,
    sc: Scenario,
    signer: Signer,
    config: CueingConfig,
    hasher: MacHasher,
    sender: str = RSU,
) -> list[tuple[bytes, int]]:
    """Signed cues the roadside unit's cue publisher sends for its bearings, each bearing
    handed over ``process_s`` after its capture, with arrival times ``link_s`` later (UTC ns)."""
    pose = sc.sensor(sender).pose
    assert pose is not None
    now = [0]
    link = _Captured(lambda: now[0])
    pub = CuePublisher(
        signer,
        link,
        Pose(pose.x_m, pose.y_m, pose.heading_deg),
        every_s=config.cue_every_s,
        valid_s=config.cue_valid_s,
        epoch_s=hasher.epoch_s,
        clock=lambda: now[0],
    )
    for k in np.argsort(rsu.t_ns, kind="stable").tolist():
        now[0] = int(rsu.t_ns[k]) + int(config.process_s * NS)
        pub.on_bearings(rsu.select(np.array([k])))
    link_ns = int(config.link_s * NS)
    return [(datagram, t_ns + link_ns) for datagram, t_ns in link.sent]


@dataclass(frozen=True)
class Summary:
    """Statistics of one plan's trials, with and without cueing."""

    plan: str
    channels: int
    trials: int
    uncued_median_s: float
    uncued_p90_s: float
    uncued_misses: int
    cued_median_s: float
    cued_p90_s: float
    cued_misses: int
    no_rsu_bearing: int
    """Seeds where the roadside unit never had a bearing (left out of the statistics)."""
    fused: int = 0
    """Cued trials whose first vehicle bearing was fused with the cue's bearing into a fix."""
    fused_median_error_m: float = math.nan
    """Median error of those fixes, metres."""

    @property
    def speedup(self) -> float:
        """Ratio of the medians (uncued / cued)."""
        return self.uncued_median_s / self.cued_median_s if self.cued_median_s > 0 else math.inf


def summarise(plan: str, n_channels: int, trials: Sequence[Trial]) -> Summary:
    """Median, 90th percentile (empirical, misses count as infinite) and misses of each mode."""
    valid = [t for t in trials if not math.isnan(t.rsu_first_s)]
    u = np.array([t.uncued_s for t in valid])
    c = np.array([t.cued_s for t in valid])
    err = np.array([t.fused_error_m for t in valid])

    def q(x: Array, p: float) -> float:
        # no interpolation: a miss (inf) stays a miss instead of turning into NaN
        return float(np.quantile(x, p, method="inverted_cdf")) if len(x) else math.nan

    return Summary(
        plan=plan,
        channels=n_channels,
        trials=len(valid),
        uncued_median_s=q(u, 0.5),
        uncued_p90_s=q(u, 0.9),
        uncued_misses=int(np.isinf(u).sum()),
        cued_median_s=q(c, 0.5),
        cued_p90_s=q(c, 0.9),
        cued_misses=int(np.isinf(c).sum()),
        no_rsu_bearing=len(trials) - len(valid),
        fused=int(np.isfinite(err).sum()),
        fused_median_error_m=float(np.median(err[np.isfinite(err)]))
        if np.isfinite(err).any()
        else math.nan,
    )


def run_study(
    seeds: Sequence[int],
    plans: Sequence[str] = ("13", "38"),
    config: CueingConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[list[Summary], dict[str, list[Trial]]]:
    """Every seed on every named plan (``13``, ``38``); returns the summaries and the trials.

    Raises:
        KeyError: an unknown plan name.
    """
    config = config or CueingConfig()
    say = progress or (lambda _msg: None)
    # a fresh key each run: nothing secret is written anywhere
    signer = Signer(RSU, ec.generate_private_key(ec.SECP256R1()))
    trust = TrustedKeys({RSU: signer.public_key})
    summaries = []
    all_trials: dict[str, list[Trial]] = {}
    for name in plans:
        plan = PLANS[name]
        say(f"plan {name}: calibrating both sensors over {len(plan)} channels")
        cals = calibrations(plan, config)
        trials = []
        for k, seed in enumerate(seeds):
            trials.append(run_trial(seed, plan, config, cals, signer, trust))
            if (k + 1) % 20 == 0:
                say(f"plan {name}: {k + 1}/{len(seeds)} seeds")
        all_trials[name] = trials
        summaries.append(summarise(name, len(plan), trials))
    return summaries, all_trials


DEMO_VEHICLE_SENSOR = "car-obu"
DEMO_RSU = "rsu-nw"


@dataclass(frozen=True)
class BrakeComparison:
    """First BRAKE of the end-to-end demo for three vehicle receivers."""

    fixed_s: float | None
    """The vehicle's sensor parked on the phone's channel (the shipped scenario), seconds."""
    hopping_s: float | None
    """The vehicle's sensor hopping the plan, no cues, seconds (None: no BRAKE)."""
    cued_s: float | None
    """Hopping, cued by the roadside unit's bearings, seconds (None: no BRAKE)."""
    needed_by_s: float | None
    """Last step at which a BRAKE still stops the car short (the demo's yardstick)."""
    cues: dict[str, float]
    """Scheduler counters of the cued run."""


def brake_comparison(
    out_dir: str | Path,
    plan: Sequence[int] = PLAN_13,
    config: CueingConfig | None = None,
    progress: Callable[[str], None] | None = None,
    *,
    probes: bool = True,
) -> BrakeComparison:
    """Run the bundled demo three times: vehicle sensor fixed on channel 6 (as shipped),
    hopping ``plan`` without cues, and hopping with the roadside unit's cues.
    ``probes=False`` silences the phone's probe sweeps (on 1, 6 and 11 every second),
    leaving its data bursts on channel 6: a hopping vehicle then rarely has a bearing
    of its own.

    Raises:
        SimulationError, ConfigError, LinkError: as :func:`~rfsas_hw.studies.demo.run_demo`.
    """
    config = config or CueingConfig()
    say = progress or (lambda _msg: None)
    out = Path(out_dir)
    shipped = load_scenario(EXAMPLE_SCENARIO)
    if not probes:
        shipped = _without_probes(shipped)
    hopping = _with_scan(shipped, DEMO_VEHICLE_SENSOR, plan)
    say("demo: vehicle sensor fixed on channel 6")
    fixed = run_demo(shipped, out / "fixed", plot=False)
    say(f"demo: vehicle sensor hopping {len(plan)} channels, no cues")
    hop = run_demo(hopping, out / "hopping", plot=False)

    say("demo: roadside bearings → signed cues → the vehicle's scan scheduler")
    world = World(hopping)
    hasher = MacHasher(FixedNonce(stream(hopping.seed, "demo-nonce").bytes(32)))
    rsu = sensor_bearings(world, DEMO_RSU, sensor_calibration(world, DEMO_RSU), hasher)
    signer = Signer(DEMO_RSU, ec.generate_private_key(ec.SECP256R1()))
    rx = CueReceiver(TrustedKeys({DEMO_RSU: signer.public_key}), CueReceiverConfig())
    scan = hopping.sensor(DEMO_VEHICLE_SENSOR).scan
    period = scan.dwell_ms / 1e3 * len(scan.channels)
    scheduler = CueScheduler(
        scan.channels, scan.dwell_ms / 1e3, config.scheduler, start_s=scan.offset_ms / 1e3 - period
    )
    for datagram, arrive_ns in _cues(rsu, hopping, signer, config, hasher, sender=DEMO_RSU):
        now_s = (arrive_ns - world.t0_ns) / NS
        got = rx.feed(datagram, arrive_ns)
        if got is not None:
            scheduler.offer(to_channel_cue(got, arrive_ns, now_s), now_s)
    timeline = scheduler.timeline(world.duration_s)
    say("demo: vehicle sensor hopping, cued")
    cued = run_demo(
        hopping, out / "cued", plot=False, listening={DEMO_VEHICLE_SENSOR: timeline.listens}
    )
    return BrakeComparison(
        fixed_s=fixed.first_brake_s,
        hopping_s=hop.first_brake_s,
        cued_s=cued.first_brake_s,
        needed_by_s=fixed.brake_needed_by_s,
        cues={**scheduler.stats.as_dict(), **{f"rx.{k}": v for k, v in rx.stats.as_dict().items()}},
    )


def _without_probes(sc: Scenario) -> Scenario:
    emitters = tuple(
        dataclasses.replace(e, traffic=tuple(t for t in e.traffic if t.model != "probe-bursts"))
        for e in sc.spec.emitters
    )
    return dataclasses.replace(sc, spec=dataclasses.replace(sc.spec, emitters=emitters))
