"""The end-to-end demo: scenario → captures → two sensor pipelines → signed UDP → backend.

Nothing is shortcut. The twin writes one radiotap capture per sensor; each
capture is replayed through the pcap source, the sensor pipeline (monopulse
DF with the sensor's calibration table, keyed MAC hashing) and a publisher
that signs safety messages and sends them over real UDP on the loopback
interface; the backend's receiver verifies them, and the backend service
associates, triangulates, tracks and judges the risk to the vehicle. Time is
the scenario's: every stage runs on a shared simulated UTC clock, stepped as
fast as the machine allows.

The ground truth is used only to score the result: fix error against the
reported covariance, and when the brake advisory came compared with the
distance the vehicle needs to stop.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from cryptography.hazmat.primitives.asymmetric import ec

from rfsas_hw.backend.encounter import EncounterConfig
from rfsas_hw.backend.risk import BRAKE_DECEL_MPS2, stopping_distance
from rfsas_hw.backend.service import BackendConfig, BackendService, JsonlSink, ResultSink
from rfsas_hw.backend.triangulation import TriangulationOptions
from rfsas_hw.backend.vehicle import VehicleState
from rfsas_hw.df.fovguard import FovGuard
from rfsas_hw.errors import SimulationError
from rfsas_hw.geo import SiteOrigin
from rfsas_hw.link import Publisher, Receiver, Signer, TrustedKeys, open_transport
from rfsas_hw.outpaths import save_figure
from rfsas_hw.pipeline import SensorPipeline
from rfsas_hw.privacy.hashing import FixedNonce, MacHasher
from rfsas_hw.records import Assessment, Fix, ObservationBatch, Pose
from rfsas_hw.sources.pcap import PcapSource
from rfsas_hw.studies.locate import emitter_hash, sensor_calibration
from rfsas_hw.twin.capture_writer import write_captures
from rfsas_hw.twin.rng import stream
from rfsas_hw.twin.scenario import Scenario, load_scenario
from rfsas_hw.twin.world import Listening, World

Array = npt.NDArray[np.float64]
NS = 1_000_000_000

EXAMPLE_SCENARIO = Path(__file__).resolve().parents[2] / "examples" / "crossing.yaml"
"""The bundled scenario (in a source checkout)."""
DEMO_ORIGIN = SiteOrigin(52.20530, 0.12180, 12.0)
"""Where the demo's crossing is placed on the globe for outputs that need it (CPMs)."""


class SimClock:
    """A settable UTC clock shared by every stage of the demo, nanoseconds."""

    def __init__(self, t_ns: int) -> None:
        self.t_ns = int(t_ns)

    def __call__(self) -> int:
        return self.t_ns


@dataclass
class DemoRow:
    """One backend step's result for the threat, with the truth to score it."""

    t_s: float
    """Scenario time, seconds."""
    truth_xy: Array
    """True position of the threat, metres."""
    fix: Fix | None
    """The backend's latest fix of the threat at this step (None before the first)."""
    fix_new: bool
    """The fix was computed at this step."""
    assessment: Assessment | None
    """The backend's assessment of the threat at this step."""
    vehicle_xy: Array
    """Vehicle position, metres."""
    vehicle_speed_mps: float
    """Vehicle speed, m/s."""

    @property
    def error_m(self) -> float:
        """Distance from the fix to the truth at the fix's time, metres."""
        if self.fix is None:
            return math.nan
        return float(np.hypot(self.fix.x_m - self.truth_xy[0], self.fix.y_m - self.truth_xy[1]))

    @property
    def mahalanobis(self) -> float:
        """Error in units of the fix's reported covariance (≤ 3: within 3σ)."""
        if self.fix is None:
            return math.nan
        cov = np.array(
            [[self.fix.cov_xx_m2, self.fix.cov_xy_m2], [self.fix.cov_xy_m2, self.fix.cov_yy_m2]]
        )
        d = np.array([self.fix.x_m - self.truth_xy[0], self.fix.y_m - self.truth_xy[1]])
        try:
            return float(np.sqrt(d @ np.linalg.solve(cov, d)))
        except np.linalg.LinAlgError:
            return math.inf

    @property
    def sigma_major_m(self) -> float:
        """One-sigma semi-major axis of the fix's error ellipse, metres."""
        if self.fix is None:
            return math.nan
        cov = np.array(
            [[self.fix.cov_xx_m2, self.fix.cov_xy_m2], [self.fix.cov_xy_m2, self.fix.cov_yy_m2]]
        )
        return float(np.sqrt(max(np.linalg.eigvalsh(cov).max(), 0.0)))


@dataclass
class DemoResult:
    """Everything the demo produced and measured."""

    scenario: Scenario
    """The scenario that ran."""
    out_dir: Path
    """Where the files are."""
    rows: list[DemoRow]
    """One row per backend step."""
    files: dict[str, Path]
    """Output files by role (captures, truth, backend JSONL, demo JSONL, map)."""
    counters: dict[str, Any]
    """Frames, bearings, messages sent/verified/rejected, fixes by status."""
    latency_ms: Array
    """Wall time from a step's frames entering the pipelines to the backend's assessment, ms."""
    first_brake_s: float | None
    """Scenario time of the first brake advisory for the threat."""
    brake_gap_m: float | None
    """Vehicle front to threat when that advisory came, metres."""
    stop_needed_m: float
    """Distance the vehicle needs to stop from its speed then at 0.47 g, metres."""
    brake_needed_by_s: float | None
    """Last step at which a BRAKE (after the reaction delay) still stops the car short."""
    wall_s: float
    """Wall time of the whole demo, seconds."""
    truth_tracks: dict[str, Array] = field(default_factory=dict)
    """Mover tracks sampled for the map: id → (n, 2)."""

    @property
    def ok_rows(self) -> list[DemoRow]:
        """Rows where a trustworthy fix was computed at that step."""
        return [r for r in self.rows if r.fix is not None and r.fix_new and r.fix.ok]

    @property
    def within_3sigma(self) -> float:
        """Fraction of trustworthy fixes whose error is within 3σ of their covariance."""
        rows = self.ok_rows
        return float(np.mean([r.mahalanobis <= 3.0 for r in rows])) if rows else math.nan

    @property
    def final(self) -> DemoRow | None:
        """The last trustworthy fix."""
        rows = self.ok_rows
        return rows[-1] if rows else None

    @property
    def decisive(self) -> DemoRow | None:
        """The trustworthy fix the first brake advisory was based on (the latest before it)."""
        if self.first_brake_s is None:
            return None
        rows = [r for r in self.ok_rows if r.t_s <= self.first_brake_s + 1e-9]
        return rows[-1] if rows else None


def _pose(world: World, sensor_id: str, t_ns: int) -> Pose:
    xy, heading = world.sensor_pose(sensor_id, [(t_ns - world.t0_ns) / NS])
    return Pose(float(xy[0, 0]), float(xy[0, 1]), float(heading[0]))


def _read_capture(path: Path) -> tuple[ObservationBatch, dict[str, Any]]:
    src = PcapSource(str(path))
    with src:
        batches = list(src)
        stats = src.stats.as_dict()
    return (ObservationBatch.concat(batches) if batches else ObservationBatch.empty()), stats


def run_demo(
    scenario: str | Path | Scenario | None = None,
    out_dir: str | Path = "out/demo",
    *,
    listening: Mapping[str, Listening] | None = None,
    step_s: float = 0.1,
    threat: str | None = None,
    reaction_s: float = 0.5,
    max_range_fraction: float | None = None,
    pose_slice_s: float = 0.02,
    plot: bool = True,
    progress: Callable[[str], None] | None = None,
    cpm_url: str | None = None,
    cpm_station_id: int = 1,
    cpm_origin: SiteOrigin = DEMO_ORIGIN,
) -> DemoResult:
    """Run the end-to-end demo and write its outputs under ``out_dir``.

    Args:
        scenario: scenario file (default: the bundled ``examples/crossing.yaml``).
        out_dir: output directory (captures, truth, backend JSONL, demo JSONL, map PNG).
        listening: per sensor, the channel schedule replacing its scan plan (a cued
            sensor; see :class:`~rfsas_hw.twin.world.World`).
        step_s: backend step, seconds of scenario time.
        threat: emitter id to score (default: the first emitter carried by a pedestrian).
        reaction_s: reaction delay the backend's advisory allows for, seconds.
        max_range_fraction: the backend's limit on a fix's one-sigma major axis as a
            fraction of the shortest sensor range (None: the backend's default).
        pose_slice_s: a moving sensor sends a message per slice this long, each
            with its pose at that time (a message carries one pose), seconds.
        plot: draw the map PNG (needs matplotlib).
        progress: called with a short line as each stage starts.
        cpm_url: also send the backend's tracks as ETSI CPMs here (``udp://HOST:PORT``
            with an optional ``?btp=1``, or ``mqtt://HOST/TOPIC``; see
            :mod:`rfsas_hw.v2x.sink`), as roadside station ``cpm_station_id`` at the
            site origin ``cpm_origin``.

    Raises:
        ConfigError: bad scenario.
        SimulationError: the scenario has no ego vehicle or no threat, or a file
            cannot be written.
        LinkError: the loopback sockets cannot be opened.
    """
    wall0 = time.perf_counter()
    say = progress or (lambda _msg: None)
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario or EXAMPLE_SCENARIO)
    spec = sc.spec
    if spec.ego is None:
        raise SimulationError(f"{sc.source}: the demo needs an ego vehicle (key 'ego')")
    if threat is None:
        carried = [e for e in spec.emitters if e.carried_by is not None]
        peds = [e for e in carried if sc.mover(e.carried_by or "").kind == "pedestrian"]
        if not peds:
            raise SimulationError(f"{sc.source}: no emitter carried by a pedestrian to score")
        threat = peds[0].id
    threat_index = [e.id for e in spec.emitters].index(threat)
    out = Path(out_dir)
    world = World(sc, listening=listening)

    say("twin: writing captures")
    caps = write_captures(world, out / "captures")
    files: dict[str, Path] = {f"capture {k}": v[0] for k, v in caps.files.items()}
    assert caps.truth is not None
    files["truth"] = caps.truth

    say("link: keys, backend receiver on loopback UDP")
    clock = SimClock(world.t0_ns)
    trust = TrustedKeys()
    signers: dict[str, Signer] = {}
    for s in spec.sensors:
        # fresh keys every run: nothing secret is written anywhere
        signers[s.id] = Signer(s.id, ec.generate_private_key(ec.SECP256R1()))
        trust.enroll(s.id, signers[s.id].public_key)
    receiver = Receiver.listen("udp://127.0.0.1:0", trust, clock=clock)
    host, port = receiver.transport.address  # type: ignore[union-attr]
    url = f"udp://{host}:{port}"
    jsonl_path = out / "backend.jsonl"
    sinks: list[ResultSink] = [JsonlSink(jsonl_path)]
    cpm_sink = None
    if cpm_url is not None:
        from rfsas_hw.v2x.perception import CpmConfig
        from rfsas_hw.v2x.sink import CpmSink

        try:
            cpm_sink = CpmSink.to_url(
                cpm_url, CpmConfig(station_id=cpm_station_id, origin=cpm_origin), clock=clock
            )
        except Exception:
            sinks[0].close()
            receiver.close()
            raise
        sinks.append(cpm_sink)
    backend = BackendService(
        BackendConfig(
            step_s=step_s,
            encounter=EncounterConfig(reaction_s=reaction_s),
            triangulation=(
                TriangulationOptions()
                if max_range_fraction is None
                else TriangulationOptions(max_range_fraction=max_range_fraction)
            ),
        ),
        sinks=sinks,
        clock=clock,
        link_alarm=lambda: bool(receiver.latency.alarm),
    )
    backend.link_stats = lambda: dict(receiver.stats.as_dict())
    files["backend jsonl"] = jsonl_path

    say("sensors: replaying captures through DF, hashing and signing")
    key = stream(spec.seed, "demo-nonce").bytes(32)
    hasher = MacHasher(FixedNonce(key))
    observations: dict[str, ObservationBatch] = {}
    pipelines: dict[str, SensorPipeline] = {}
    publishers: dict[str, Publisher] = {}
    source_stats: dict[str, Any] = {}
    current_pose: dict[str, Pose] = {}
    for s in spec.sensors:
        if s.id not in caps.files:
            continue
        obs, stats = _read_capture(caps.files[s.id][0])
        observations[s.id] = obs
        source_stats[s.id] = stats
        current_pose[s.id] = _pose(world, s.id, world.t0_ns)
        # the field-of-view guard of the mount: the motion rule on a roadside unit only
        guard = FovGuard.for_mount(moving=s.mounted_on is not None)
        pipelines[s.id] = SensorPipeline(
            sensor_calibration(world, s.id), hasher, s.id, current_pose[s.id], fov_guard=guard
        )
        publishers[s.id] = Publisher(
            signers[s.id],
            open_transport(url, "send"),
            (lambda sid=s.id: current_pose[sid]),  # type: ignore[misc]
            clock=clock,
            epoch_s=hasher.epoch_s,
        )
    if len(pipelines) < 2:
        raise SimulationError(f"{sc.source}: the demo needs two capture sensors")

    ego = world.tracks[spec.ego]
    ego_spec = sc.mover(spec.ego)
    length, width = ego_spec.size_m()
    threat_track = world.emitter_track(threat_index)
    rows: list[DemoRow] = []
    headings: list[float] = []
    latency: list[float] = []
    cursors = dict.fromkeys(observations, 0)
    n_steps = math.ceil(world.duration_s / step_s)
    for k in range(1, n_steps + 1):
        t_end_ns = world.t0_ns + round(k * step_s * NS)
        t_s = (t_end_ns - world.t0_ns) / NS
        w0 = time.perf_counter()
        for sid, obs in observations.items():
            stop = int(np.searchsorted(obs.t_ns, t_end_ns, side="left"))
            part = obs.select(slice(cursors[sid], stop))
            cursors[sid] = stop
            if not len(part):
                continue
            clock.t_ns = t_end_ns
            moving = sc.sensor(sid).kind == "on-board"
            slices = (
                np.floor((part.t_ns - part.t_ns[0]) / (pose_slice_s * NS)).astype(np.int64)
                if moving
                else np.zeros(len(part), np.int64)
            )
            for piece in np.unique(slices):
                chunk = part.select(slices == piece)
                current_pose[sid] = _pose(world, sid, int(np.median(chunk.t_ns)))
                pipelines[sid].pose = current_pose[sid]
                publishers[sid].on_bearings(pipelines[sid].process(chunk))
        clock.t_ns = t_end_ns
        total_sent = sum(p.stats.messages for p in publishers.values())
        deadline = time.monotonic() + 1.0
        # loopback delivers at once; wait until every datagram sent so far has been checked
        while receiver.stats.datagrams < total_sent and time.monotonic() < deadline:
            for msg in receiver.receive(timeout=0.05):
                backend.on_verified(msg)
        pos = ego.position([t_s])[0]
        heading = float(ego.heading_deg([t_s])[0])
        speed = float(ego.speed_mps([t_s])[0])
        backend.set_vehicle(
            VehicleState(
                x_m=float(pos[0]),
                y_m=float(pos[1]),
                heading_deg=heading,
                speed_mps=speed,
                length_m=length,
                width_m=width,
                t_ns=t_end_ns,
            )
        )
        headings.append(heading)
        backend.step(now_ns=t_end_ns)
        latency.append((time.perf_counter() - w0) * 1e3)
        target = emitter_hash(world, threat, hasher, t_end_ns)
        fix = backend.fixes.get(target)
        fix_t = ((fix.t_ns - world.t0_ns) / NS) if fix is not None else t_s
        rows.append(
            DemoRow(
                t_s=t_s,
                truth_xy=threat_track.position([fix_t])[0],
                fix=fix,
                fix_new=bool(fix is not None and rows and rows[-1].fix is not fix)
                or bool(fix is not None and not rows),
                assessment=backend.assessments.get(target),
                vehicle_xy=pos,
                vehicle_speed_mps=speed,
            )
        )
    for p in publishers.values():
        p.close()
    backend.close()
    receiver.close()

    first_brake = next(
        (r for r in rows if r.assessment is not None and r.assessment.advisory == "brake"), None
    )
    # the car's front-bumper gap to the pedestrian at every step, along its heading
    gaps = np.array(
        [
            float(
                (threat_track.position([r.t_s])[0] - r.vehicle_xy)
                @ np.array([math.sin(math.radians(h)), math.cos(math.radians(h))])
            )
            - length / 2
            for r, h in zip(rows, headings, strict=True)
        ]
    )
    needed = np.asarray(
        stopping_distance(
            np.array([r.vehicle_speed_mps for r in rows]), BRAKE_DECEL_MPS2, reaction_s
        )
    )
    in_time = np.flatnonzero(gaps >= needed)
    brake_by = rows[int(in_time[-1])].t_s if len(in_time) else None
    brake_gap = None
    stop_needed = math.nan
    if first_brake is not None:
        k = rows.index(first_brake)
        brake_gap = float(gaps[k])
        stop_needed = float(needed[k])
    counters = {
        "frames": {sid: len(o) for sid, o in observations.items()},
        "source": source_stats,
        "bearings": {sid: p.stats.bearings for sid, p in pipelines.items()},
        "messages_sent": {sid: p.stats.messages for sid, p in publishers.items()},
        "receiver": receiver.stats.as_dict(),
        "backend": backend.stats.as_dict(),
    }
    if cpm_sink is not None:
        counters["cpm"] = cpm_sink.counters()
    t_map = np.linspace(0.0, world.duration_s, 200)
    tracks = {m.id: world.tracks[m.id].position(t_map) for m in spec.movers}
    result = DemoResult(
        scenario=sc,
        out_dir=out,
        rows=rows,
        files=files,
        counters=counters,
        latency_ms=np.asarray(latency),
        first_brake_s=first_brake.t_s if first_brake is not None else None,
        brake_needed_by_s=brake_by,
        brake_gap_m=brake_gap,
        stop_needed_m=stop_needed,
        wall_s=0.0,
        truth_tracks=tracks,
    )
    files["demo jsonl"] = write_demo_jsonl(result, out / "demo.jsonl")
    if plot:
        say("map: drawing tracks and covariance ellipses")
        files["map"] = plot_demo(result, world, out / "demo_map.png")
    result.wall_s = time.perf_counter() - wall0
    return result


def write_demo_jsonl(result: DemoResult, path: Path) -> Path:
    """One JSON line per backend step: truth, fix (if any), assessment (if any).

    Raises:
        SimulationError: the file cannot be written.
    """
    try:
        with path.open("w", encoding="utf-8") as f:
            for r in result.rows:
                line: dict[str, Any] = {
                    "t_s": round(r.t_s, 3),
                    "truth_xy_m": [round(float(v), 3) for v in r.truth_xy],
                    "vehicle_xy_m": [round(float(v), 3) for v in r.vehicle_xy],
                    "vehicle_speed_mps": round(r.vehicle_speed_mps, 3),
                }
                if r.fix is not None:
                    line["fix"] = r.fix.as_dict()
                    line["fix_new"] = r.fix_new
                    line["error_m"] = round(r.error_m, 3)
                    line["mahalanobis"] = round(r.mahalanobis, 3)
                if r.assessment is not None:
                    line["assessment"] = r.assessment.as_dict()
                f.write(json.dumps(line, sort_keys=True, allow_nan=False, default=_nan) + "\n")
    except OSError as err:
        raise SimulationError(f"{path}: cannot write: {err.strerror or err}") from err
    return path


def _nan(value: object) -> object:
    return None


def _ellipse(cov: Array, n_sigma: float, n: int = 60) -> Array:
    vals, vecs = np.linalg.eigh(cov)
    a = np.linspace(0, 2 * math.pi, n)
    circle = np.stack([np.cos(a), np.sin(a)])
    pts: Array = (vecs @ (np.sqrt(np.maximum(vals, 0))[:, None] * circle)).T * n_sigma
    return pts


def plot_demo(result: DemoResult, world: World, path: Path) -> Path:
    """The map: buildings, sensors, true tracks, fixes with 1σ and 3σ ellipses.

    Raises:
        SimulationError: matplotlib is missing or the file cannot be written.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.patches import Rectangle
    except ImportError as err:
        raise SimulationError("the map needs matplotlib: pip install 'rfsas-hw[plot]'") from err
    spec = world.scenario.spec
    fig, (ax, zoom) = plt.subplots(1, 2, figsize=(12, 8.5), gridspec_kw={"width_ratios": [1, 1.4]})
    colours = ["tab:blue", "tab:green", "tab:purple", "tab:brown"]
    half = spec.intersection.road_half_width_m
    ok_rows = [r for r in result.rows if r.fix is not None and r.fix_new]
    for axis in (ax, zoom):
        axis.axvspan(-half, half, color="0.93", zorder=0)
        axis.axhspan(-half, half, color="0.93", zorder=0)
        for b in spec.intersection.buildings:
            axis.add_patch(
                Rectangle(
                    (b.x_min_m, b.y_min_m),
                    b.x_max_m - b.x_min_m,
                    b.y_max_m - b.y_min_m,
                    color="0.6",
                    zorder=1,
                )
            )
        for k, (mid, xy) in enumerate(result.truth_tracks.items()):
            axis.plot(
                xy[:, 0],
                xy[:, 1],
                "--",
                lw=1.2,
                color=colours[k % len(colours)],
                label=f"{mid} (truth)",
                zorder=2,
            )
        for s in spec.sensors:
            if s.pose is None:
                continue
            a = math.radians(s.pose.heading_deg)
            axis.plot(s.pose.x_m, s.pose.y_m, "k^", ms=9, zorder=5)
            axis.annotate(
                s.id,
                (s.pose.x_m, s.pose.y_m),
                xytext=(4, 4),
                textcoords="offset points",
                fontsize=8,
            )
            axis.arrow(
                s.pose.x_m,
                s.pose.y_m,
                5 * math.sin(a),
                5 * math.cos(a),
                width=0.15,
                color="k",
                zorder=5,
            )
        for r in ok_rows:
            assert r.fix is not None
            cov = np.array([[r.fix.cov_xx_m2, r.fix.cov_xy_m2], [r.fix.cov_xy_m2, r.fix.cov_yy_m2]])
            if not np.all(np.isfinite(cov)) or r.sigma_major_m > 15:
                continue
            colour = "tab:red" if r.fix.ok else "tab:orange"
            centre = np.array([r.fix.x_m, r.fix.y_m])
            e1 = centre + _ellipse(cov, 1.0)
            axis.plot(e1[:, 0], e1[:, 1], color=colour, lw=0.8, alpha=0.8, zorder=3)
            axis.plot(*centre, "o", color=colour, ms=3, zorder=4)
        d = result.decisive
        if d is not None and d.fix is not None:
            cov = np.array([[d.fix.cov_xx_m2, d.fix.cov_xy_m2], [d.fix.cov_xy_m2, d.fix.cov_yy_m2]])
            e3 = np.array([d.fix.x_m, d.fix.y_m]) + _ellipse(cov, 3.0)
            axis.plot(
                e3[:, 0],
                e3[:, 1],
                color="k",
                lw=1.4,
                ls=":",
                label=f"fix behind first BRAKE, 3σ ({d.t_s:.1f} s)",
                zorder=6,
            )
            axis.plot(*d.truth_xy, "x", color="k", ms=8, zorder=6)
        if result.first_brake_s is not None:
            row = next(r for r in result.rows if r.t_s == result.first_brake_s)
            axis.plot(
                *row.vehicle_xy,
                "s",
                color="tab:purple",
                ms=9,
                label=f"car at first BRAKE ({row.t_s:.1f} s)",
                zorder=6,
            )
        axis.set_aspect("equal")
        axis.set_xlabel("east (m)")
    ax.plot([], [], "o-", color="tab:red", ms=3, lw=0.8, label="fix + 1σ ellipse")
    ax.plot([], [], "o-", color="tab:orange", ms=3, lw=0.8, label="flagged fix + 1σ")
    ys = np.concatenate([xy[:, 1] for xy in result.truth_tracks.values()])
    ax.set_xlim(-30, 30)
    ax.set_ylim(max(ys.min() - 5, -120), 25)
    ax.set_ylabel("north (m)")
    ax.set_title("overview")
    ax.legend(loc="lower left", fontsize=7)
    zoom.set_xlim(-12, 16)
    zoom.set_ylim(-20, 12)
    zoom.set_title("the crossing (1σ ellipses; × = truth)")
    fig.suptitle(f"{spec.name}: pedestrian located by a roadside unit and the car, over signed UDP")
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
    return path
