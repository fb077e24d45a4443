"""The streaming twin gives exactly the offline world's observations, window by window."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from rfsas_hw.errors import SimulationError
from rfsas_hw.twin.motion import Track
from rfsas_hw.twin.scenario import (
    EmitterSpec,
    MoverSpec,
    Scenario,
    TrafficSpec,
    WaypointSpec,
    load_scenario,
)
from rfsas_hw.twin.stream import LiveTrack, StreamTwin, extend_tracks
from rfsas_hw.twin.world import Receptions, World

CROSSING = Path(__file__).resolve().parents[2] / "examples" / "crossing.yaml"


def _feed(twin: StreamTwin, world: World, t1: float, fed: dict[str, int]) -> None:
    """Give every live track the offline knots up to two beyond ``t1`` (simulator steps)."""
    for mid, live in twin.live.items():
        if mid not in world.tracks:
            continue
        track = world.tracks[mid]
        k = fed.get(mid, 0)
        beyond = 0
        while k < len(track.t_s) and beyond < 2:
            live.extend(float(track.t_s[k]), float(track.x_m[k]), float(track.y_m[k]))
            if track.t_s[k] >= t1:
                beyond += 1
            k += 1
        fed[mid] = k


FLOAT_RTOL = 1e-12
"""Float columns of two passes over different windows: numpy may round a value
differently in the last bit with another array length or CPU dispatch."""


def _assert_column(got: np.ndarray, want: np.ndarray, name: str) -> None:
    """Integer and flag columns exactly; float columns to :data:`FLOAT_RTOL` (NaN where NaN)."""
    if np.issubdtype(np.asarray(want).dtype, np.floating):
        np.testing.assert_allclose(got, want, rtol=FLOAT_RTOL, atol=0.0, err_msg=name)
    else:
        np.testing.assert_array_equal(got, want, err_msg=name)


def _concat(parts: list[Receptions]) -> dict[str, np.ndarray]:
    names = [n for n in Receptions.__dataclass_fields__ if n not in ("sensor_id", "n_cards")]
    return {n: np.concatenate([getattr(p, n) for p in parts]) for n in names}


@pytest.mark.parametrize("step_s", [0.1, 0.37])
def test_streamed_windows_equal_the_offline_run(step_s: float) -> None:
    # the crossing has fading, chain drops, two traffic models on the phone, an AP,
    # a moving on-board sensor and buildings: every random stream is exercised
    sc = load_scenario(CROSSING)
    world = World(sc)
    twin = StreamTwin(sc)
    fed: dict[str, int] = {}
    parts: dict[str, list[Receptions]] = {s.id: [] for s in sc.spec.sensors}
    t0 = 0.0
    while t0 < world.duration_s:
        t1 = min(t0 + step_s, world.duration_s)
        _feed(twin, world, t1, fed)
        for sid, rec in twin.step(t1).items():
            parts[sid].append(rec)
        t0 = t1
    for s in sc.spec.sensors:
        offline = world.receptions(s.id)
        streamed = _concat(parts[s.id])
        assert len(offline) > 100
        for name, got in streamed.items():
            _assert_column(got, getattr(offline, name), name)
        # and what the driver hands to the pipeline
        obs_off = offline.observations()
        obs_str = Receptions(s.id, offline.n_cards, **streamed).observations()
        _assert_column(obs_str.rssi_dbm, obs_off.rssi_dbm, "rssi_dbm")
        np.testing.assert_array_equal(obs_str.t_ns, obs_off.t_ns)
        np.testing.assert_array_equal(obs_str.mac, obs_off.mac)


def _crowded(n: int) -> Scenario:
    """The crossing with ``n`` more walkers with phones (and a standing AP): many tracks at once."""
    sc = load_scenario(CROSSING)
    rng = np.random.default_rng(4)
    movers = list(sc.spec.movers)
    emitters = list(sc.spec.emitters)
    for k in range(n):
        a, b = rng.uniform(-25, 25, (2, 2))
        movers.append(
            MoverSpec(
                id=f"w{k}",
                kind="pedestrian",
                start_s=float(rng.uniform(0, 1)),
                waypoints=(
                    WaypointSpec(float(a[0]), float(a[1]), float(rng.uniform(0.8, 2)), 0.3),
                    WaypointSpec(float(b[0]), float(b[1])),
                ),
            )
        )
        emitters.append(
            EmitterSpec(
                id=f"phone{k}",
                mac=f"02:00:00:00:01:{k:02x}",
                tech="wifi",
                tx_power_dbm=20.0,
                carried_by=f"w{k}",
                traffic=(TrafficSpec(model="data-bursts", channels=(6,), interval_s=0.1),),
            )
        )
    spec = __import__("dataclasses").replace(
        sc.spec, movers=tuple(movers), emitters=tuple(emitters)
    )
    return Scenario(spec=spec, source=sc.source, base_dir=sc.base_dir)


@pytest.mark.parametrize("lookahead_s", [0.35, 4.0])
def test_many_carriers_streamed_equal_the_offline_run(lookahead_s: float) -> None:
    # many carriers at once: positions of many tracks in one window; traffic generated
    # less or more than a window ahead (the district's twin workers: 4 s)
    sc = _crowded(12)
    world = World(sc)
    twin = StreamTwin(sc, lookahead_s=lookahead_s)
    fed: dict[str, int] = {}
    parts: dict[str, list[Receptions]] = {s.id: [] for s in sc.spec.sensors}
    t0 = 0.0
    while t0 < world.duration_s:
        t1 = min(t0 + 0.1, world.duration_s)
        _feed(twin, world, t1, fed)
        for sid, rec in twin.step(t1).items():
            parts[sid].append(rec)
        t0 = t1
    for s in sc.spec.sensors:
        offline = world.receptions(s.id)
        streamed = _concat(parts[s.id])
        assert len(np.unique(offline.emitter)) > 8
        for name, got in streamed.items():
            _assert_column(got, getattr(offline, name), name)


def test_live_track_positions_are_the_offline_tracks() -> None:
    rng = np.random.default_rng(5)
    live = LiveTrack()
    ts = np.cumsum(rng.uniform(0.0, 0.2, 40))
    ts[7] = ts[6]  # a repeated knot time
    for k, t in enumerate(ts):
        live.extend(float(t), float(rng.normal(0, 20)), float(rng.normal(0, 20)))
        q = np.concatenate([rng.uniform(-0.5, t + 0.5, 50), ts[: k + 1]])
        t_k, x_k, y_k = (a.copy() for a in live.knots())
        _assert_column(live.position(q), Track(t_k, x_k, y_k).position(q), "position")
    _assert_column(live.position(1.0), Track(t_k, x_k, y_k).position(1.0), "position")


def test_a_live_track_moves_in_straight_lines_between_its_knots() -> None:
    """Hand-made knots, one of them at a repeated time (a jump): before the first knot
    the first position, between knots the straight line at constant speed, at a
    repeated time the later knot, after the last knot the last position."""
    live = LiveTrack()
    for t, x, y in ((0.0, 0.0, 0.0), (2.0, 10.0, -4.0), (2.0, 20.0, 6.0), (5.0, 20.0, 12.0)):
        live.extend(t, x, y)
    q = np.array([-1.0, 0.0, 0.5, 1.0, 2.0, 3.5, 5.0, 9.0])
    want = [
        [0.0, 0.0],
        [0.0, 0.0],
        [2.5, -1.0],
        [5.0, -2.0],
        [20.0, 6.0],
        [20.0, 9.0],
        [20.0, 12.0],
        [20.0, 12.0],
    ]
    np.testing.assert_allclose(live.position(q), want, rtol=0.0, atol=1e-12)
    assert np.isnan(live.position(np.array([np.nan]))).all()
    one = LiveTrack()
    one.extend(1.0, 3.0, 4.0)
    np.testing.assert_array_equal(one.position([0.0, 1.0, 2.0]), [[3.0, 4.0]] * 3)


def test_other_seed_differs() -> None:
    sc = load_scenario(CROSSING)
    a = World(sc).receptions(sc.spec.sensors[0].id)
    other = World(
        type(sc)(
            spec=__import__("dataclasses").replace(sc.spec, seed=sc.spec.seed + 1),
            source=sc.source,
            base_dir=sc.base_dir,
        )
    ).receptions(sc.spec.sensors[0].id)
    assert len(a) != len(other) or not np.array_equal(a.chain_dbm, other.chain_dbm)


def test_windows_must_follow_each_other() -> None:
    sc = load_scenario(CROSSING)
    twin = StreamTwin(sc)
    world = World(sc)
    _feed(twin, world, 0.5, {})
    sid = sc.spec.sensors[0].id
    twin.receptions_between(sid, 0.0, 0.2)
    with pytest.raises(SimulationError, match="previous one ended"):
        twin.receptions_between(sid, 0.3, 0.5)
    with pytest.raises(SimulationError, match="empty"):
        twin.receptions_between(sid, 0.2, 0.2)
    with pytest.raises(SimulationError, match="receptions_between"):
        twin.receptions(sid)


def test_emitters_come_and_go() -> None:
    sc = load_scenario(CROSSING)
    twin = StreamTwin(sc)
    world = World(sc)
    fed: dict[str, int] = {}
    _feed(twin, world, 1.0, fed)
    walker = twin.add_mover("walker")
    for k in range(11):
        walker.extend(k * 0.1, -3.0 + 0.14 * k, -9.0)
    phone = EmitterSpec(
        id="walker-phone",
        mac="02:11:22:33:44:55",
        tech="wifi",
        traffic=(TrafficSpec(model="data-bursts", channels=(6,), interval_s=0.05),),
        carried_by="walker",
    )
    index = twin.add_emitter(phone, start_s=0.0)
    heard = twin.step(1.0)
    assert any((rec.emitter == index).sum() > 5 for rec in heard.values())
    twin.retire_emitter(index, 1.0)
    _feed(twin, world, 2.0, fed)
    later = twin.step(2.0)
    assert all((rec.emitter == index).sum() == 0 for rec in later.values())
    with pytest.raises(SimulationError, match="already exists"):
        twin.add_emitter(phone)
    with pytest.raises(SimulationError, match="no mover"):
        twin.add_emitter(
            EmitterSpec(
                id="x", mac="02:00:00:00:00:09", tech="wifi", traffic=phone.traffic, carried_by="z"
            )
        )


def test_live_track_headings_and_order() -> None:
    tr = LiveTrack()
    tr.extend(0.0, 0.0, 0.0, 350.0)
    tr.extend(1.0, 1.0, 0.0, 10.0)
    # the short way round, through north
    assert tr.heading_deg([0.5])[0] == pytest.approx(0.0)
    np.testing.assert_allclose(tr.position([0.5, 2.0]), [[0.5, 0.0], [1.0, 0.0]])
    with pytest.raises(SimulationError, match="time order"):
        tr.extend(0.5, 0.0, 0.0)
    for k in range(2, 40):
        tr.extend(float(k), float(k), 0.0, 10.0)
    tr.forget_before(30.5)
    assert tr.first_s == 30.0 and tr.last_s == 39.0
    np.testing.assert_allclose(tr.position([35.25]), [[35.25, 0.0]])
    no_heading = LiveTrack()
    no_heading.extend(0.0, 0.0, 0.0)
    no_heading.extend(1.0, 0.0, 1.0)
    assert no_heading.heading_deg([0.5])[0] == pytest.approx(0.0)
    with pytest.raises(SimulationError, match="no knot"):
        LiveTrack().position([0.0])


def test_prepared_windows_are_the_ones_computed_alone() -> None:
    sc = load_scenario(CROSSING)
    world = World(sc)
    alone, together = StreamTwin(sc), StreamTwin(sc)
    fed_a: dict[str, int] = {}
    fed_b: dict[str, int] = {}
    sids = [s.id for s in sc.spec.sensors]
    for k in range(1, 30):
        t0, t1 = (k - 1) * 0.2, k * 0.2
        _feed(alone, world, t1, fed_a)
        _feed(together, world, t1, fed_b)
        together.prepare(t1)
        for sid in reversed(sids):
            a = alone.receptions_between(sid, t0, t1)
            b = together.receptions_between(sid, t0, t1)
            for name in Receptions.__dataclass_fields__:
                if name not in ("sensor_id", "n_cards"):
                    _assert_column(getattr(b, name), getattr(a, name), name)
    end = together.cursor_s[sids[0]]
    together.prepare(end + 0.4)
    with pytest.raises(SimulationError, match="prepared"):
        together.receptions_between(sids[0], end, end + 0.2)
    together.receptions_between(sids[0], end, end + 0.4)
    assert together.cursor_s[sids[0]] == end + 0.4


def test_a_retired_emitter_sends_nothing_after_the_windows_asked_for() -> None:
    sc = load_scenario(CROSSING)
    twin = StreamTwin(sc)  # generates a second ahead
    world = World(sc)
    _feed(twin, world, 2.0, {})
    walker = twin.add_mover("walker")
    walker.extend(0.0, 0.0, -9.0)
    phone = EmitterSpec(
        id="walker-phone",
        mac="02:11:22:33:44:55",
        tech="wifi",
        traffic=(TrafficSpec(model="data-bursts", channels=(6,), interval_s=0.02),),
        carried_by="walker",
    )
    index = twin.add_emitter(phone, start_s=0.0)
    first = twin.step(0.5)
    assert any((rec.emitter == index).any() for rec in first.values())
    # it left at 0.8 s, reported at the next step: its position after 0.5 s is unknown
    twin.retire_emitter(index, 0.8)
    later = twin.step(1.0)
    assert not any((rec.emitter == index).any() for rec in later.values())


def _more_units() -> Scenario:
    """The crossing with three more roadside units: two on channel 6 (they hear the same
    frames as rsu-nw), one on channel 1 and one hopping (frames of their own)."""
    import dataclasses

    from rfsas_hw.twin.scenario import PoseSpec, ScanSpec

    sc = load_scenario(CROSSING)
    base = sc.sensor("rsu-nw")
    extra = (
        dataclasses.replace(base, id="rsu-se", pose=PoseSpec(9.0, -9.0, 320.0)),
        dataclasses.replace(base, id="rsu-ne", pose=PoseSpec(9, 9, 220)),  # integer pose
        dataclasses.replace(base, id="rsu-ch1", scan=ScanSpec(channels=(1,))),
        dataclasses.replace(base, id="rsu-hop", scan=ScanSpec(channels=(1, 6), dwell_ms=50.0)),
    )
    spec = dataclasses.replace(sc.spec, sensors=(*sc.spec.sensors, *extra))
    return Scenario(spec=spec, source=sc.source, base_dir=sc.base_dir)


def _alone_and_together(
    sc: Scenario, world: World, alone: StreamTwin, together: StreamTwin, windows: int, dt: float
) -> Iterator[tuple[str, Receptions, Receptions]]:
    """Step both twins window by window (``together`` prepares all units at once) and
    give each unit's receptions from each: (sensor id, alone, together)."""
    fed_a: dict[str, int] = {}
    fed_b: dict[str, int] = {}
    for k in range(1, windows + 1):
        t0, t1 = (k - 1) * dt, k * dt
        _feed(alone, world, t1, fed_a)
        _feed(together, world, t1, fed_b)
        together.prepare(t1)
        for s in sc.spec.sensors:
            yield (
                s.id,
                alone.receptions_between(s.id, t0, t1),
                together.receptions_between(s.id, t0, t1),
            )


def _same_columns(a: Receptions, b: Receptions) -> Iterator[tuple[str, np.ndarray]]:
    """Assert every array column of ``b`` equals ``a``'s, type included; give (name, b's)."""
    for name in Receptions.__dataclass_fields__:
        if name not in ("sensor_id", "n_cards"):
            got, want = getattr(b, name), getattr(a, name)
            assert got.dtype == want.dtype, name
            _assert_column(got, want, name)
            yield name, got


def test_units_that_hear_the_same_frames_share_them_and_get_what_they_get_alone(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sc = _more_units()
    world = World(sc)
    alone, together = StreamTwin(sc), StreamTwin(sc)
    calls: list[str] = []
    original = StreamTwin._candidates_many

    def counted(self: StreamTwin, sensors):  # type: ignore[no-untyped-def]
        if self is together:
            calls.extend(s.id for s in sensors)
        return original(self, sensors)

    monkeypatch.setattr(StreamTwin, "_candidates_many", counted)
    heard = {s.id: 0 for s in sc.spec.sensors}
    for sid, a, b in _alone_and_together(sc, world, alone, together, 39, 0.2):
        heard[sid] += len(a)
        for _ in _same_columns(a, b):
            pass
    assert all(v > 0 for v in heard.values()), heard
    # per window: one selection for the three channel-6 units and the on-board unit
    # (same technologies, same channel), one for channel 1, one for the hopping unit
    assert set(calls) == {"rsu-nw", "rsu-ch1", "rsu-hop"}
    assert len(calls) == 3 * 39


@pytest.mark.parametrize("lookahead_s", [0.0, 0.35, 1.0])
def test_frames_and_knots_are_trimmed_at_most_a_lookahead_behind(lookahead_s: float) -> None:
    sc = load_scenario(CROSSING)
    world = World(sc)
    twin = StreamTwin(sc, lookahead_s=lookahead_s)
    fed: dict[str, int] = {}
    t1 = 0.0
    while t1 < 8.0:
        t1 = round(t1 + 0.1, 9)
        _feed(twin, world, t1, fed)
        twin.step(t1)
        done = min(twin.cursor_s.values())
        frames_t = twin._frames["t"]
        if len(frames_t):
            assert frames_t[0] >= done - lookahead_s - 0.1 - 1e-9
        for live in twin.live.values():
            if len(live) > 1:
                # one knot before the trim time is kept
                assert live.knots()[0][1] >= done - lookahead_s - 0.1 - 1e-9


def test_per_sensor_constants_are_built_once_per_layout_and_never_shared() -> None:
    """The sensor poses, chain offsets and clocks that ``_receive_many`` repeats over
    its rows come from a cache per (sensors, frame counts): every window still equals
    the sensor computed alone (chain offsets that differ per unit included), and no
    frame column shares memory with the cache."""
    import dataclasses

    sc = _more_units()
    sensors = tuple(
        dataclasses.replace(
            s, antenna=dataclasses.replace(s.antenna, chain_offsets_db=(0.5, -1.25))
        )
        if s.id == "rsu-se"
        else s
        for s in sc.spec.sensors
    )
    sc = Scenario(
        spec=dataclasses.replace(sc.spec, sensors=sensors), source=sc.source, base_dir=sc.base_dir
    )
    world = World(sc)
    alone, together = StreamTwin(sc), StreamTwin(sc)
    windows = 40
    for _, a, b in _alone_and_together(sc, world, alone, together, windows, 0.1):
        for name, got in _same_columns(a, b):
            for layout in together._layouts.values():
                for cached in (layout.xy, layout.heading, layout.clock0, layout.rate):
                    assert not np.shares_memory(got, cached), name
        assert b.sensor_xy.flags.writeable and b.sensor_heading_deg.flags.writeable
    assert 0 < len(together._layouts) < windows
    for layout in together._layouts.values():
        assert not layout.xy.flags.writeable and not layout.offsets.flags.writeable


def test_a_unit_with_a_reach_computes_only_the_frames_from_within_it() -> None:
    # at the low level of detail a frame's readings draw nothing at random, so the
    # frames a reach leaves are exactly those of the twin without it, row for row
    sc = _crowded(12)
    world = World(sc, detail="low")
    reach = 12.0
    plain = StreamTwin(sc, detail="low")
    near = StreamTwin(sc, detail="low", reach_m={"rsu-nw": reach})
    fed_a: dict[str, int] = {}
    fed_b: dict[str, int] = {}
    kept = dropped = 0
    t0 = 0.0
    while t0 < world.duration_s:
        t1 = min(t0 + 0.1, world.duration_s)
        _feed(plain, world, t1, fed_a)
        _feed(near, world, t1, fed_b)
        all_of, near_of = plain.step(t1), near.step(t1)
        for sid, got in near_of.items():
            want = all_of[sid]
            if sid == "rsu-nw":
                inside = want.distance_m <= reach
                kept, dropped = kept + int(inside.sum()), dropped + int((~inside).sum())
                want = want.select(inside)
            for name in Receptions.__dataclass_fields__:
                if name not in ("sensor_id", "n_cards"):
                    _assert_column(getattr(got, name), getattr(want, name), name)
        t0 = t1
    assert kept > 50 and dropped > 50


def test_units_with_reaches_selected_together_get_what_each_selects_alone() -> None:
    # the standing units of every channel plan, each with its own reach: selected in
    # one array of units x frames (prepare), each gets exactly the frames and
    # readings it gets when its window is computed alone
    sc = _more_units()
    world = World(sc)
    reach = {"rsu-nw": 15.0, "rsu-se": 22.0, "rsu-ne": 25.0, "rsu-ch1": 30.0, "rsu-hop": 12.0}
    alone, together = StreamTwin(sc, reach_m=reach), StreamTwin(sc, reach_m=reach)
    heard = dict.fromkeys(reach, 0)
    far = 0
    for sid, a, b in _alone_and_together(sc, world, alone, together, 30, 0.2):
        for name, got in _same_columns(a, b):
            if name == "distance_m" and sid in reach:
                heard[sid] += len(got)
                far += int((got > reach[sid]).sum())
    assert all(v > 0 for v in heard.values()), heard
    assert far == 0


def test_a_reach_needs_a_standing_sensor_and_a_positive_distance() -> None:
    from rfsas_hw.errors import ConfigError

    sc = load_scenario(CROSSING)
    with pytest.raises(ConfigError, match="no sensor"):
        StreamTwin(sc, reach_m={"nobody": 10.0})
    with pytest.raises(ConfigError, match="positive"):
        StreamTwin(sc, reach_m={"rsu-nw": 0.0})
    mounted = next(s.id for s in sc.spec.sensors if s.pose is None)
    with pytest.raises(ConfigError, match="standing"):
        StreamTwin(sc, reach_m={mounted: 10.0})


def test_extend_tracks_is_extend_of_each_track() -> None:
    rng = np.random.default_rng(4)
    one = [LiveTrack() for _ in range(5)]
    many = [LiveTrack() for _ in range(5)]
    for k in range(6):
        x, y = rng.uniform(-50, 50, 5), rng.uniform(-50, 50, 5)
        h = rng.uniform(-720.0, 720.0, 5)  # across north and beyond one turn
        for tr, xi, yi, hi in zip(one, x, y, h, strict=True):
            tr.extend(0.1 * k, float(xi), float(yi), float(hi))
        extend_tracks(many, 0.1 * k, x, y, h)
    t = np.linspace(0.0, 0.6, 13)
    for a, b in zip(one, many, strict=True):
        np.testing.assert_allclose(b.position(t), a.position(t))
        np.testing.assert_allclose(b.heading_deg(t), a.heading_deg(t), atol=1e-9)
    fresh, old = LiveTrack(), many[0]
    extend_tracks([fresh, old], 0.6, np.array([1.0, 2.0]), np.array([3.0, 4.0]))
    assert len(fresh) == 1 and old.last_s == 0.6
    with pytest.raises(SimulationError, match="time order"):
        extend_tracks([fresh, old], 0.5, np.zeros(2), np.zeros(2))
    with pytest.raises(SimulationError, match="not finite"):
        extend_tracks([fresh], 0.7, np.array([np.nan]), np.zeros(1))
    with pytest.raises(SimulationError, match="heading"):
        extend_tracks([fresh], 0.7, np.zeros(1), np.zeros(1), np.array([np.inf]))
    assert len(fresh) == 1  # nothing added by a refused step
