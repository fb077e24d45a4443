"""Recordings read back by decoders that did not write them match the JSONL of the same run.

The CDR is produced by ``rosbags``' serialiser; the MCAP file is read by
``mcap`` with ``mcap-ros2-support``'s decoder and, as a container, also by
``rosbags``' reader; the rosbag2 directory by ``sqlite3`` with the schemas the
bag carries and ``mcap-ros2-support``'s decoder. Types, counts, every value,
frames (REP-103: ENU ``map``, a frame per sensor, TF) and stamps are checked.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("rosbags", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")
pytest.importorskip("mcap_ros2", reason="needs the ros2 extra: pip install 'rfsas-hw[ros2]'")

from rosrun import (
    SENSORS,
    Decoded,
    jsonl_records,
    read_mcap,
    read_rosbag2_sqlite,
    run_backend,
)

from rfsas_hw.cli.main import main
from rfsas_hw.ros2 import topics
from rfsas_hw.ros2.bag import McapFileWriter, Rosbag2Writer
from rfsas_hw.ros2.sink import vehicle_at

ADVISORY = {0: "none", 1: "clear", 2: "caution", 3: "brake"}


def ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def heading_of(q: Any) -> float:
    """Compass heading of a yaw quaternion (ENU yaw → degrees clockwise from north)."""
    assert q.x == 0.0 and q.y == 0.0
    yaw = 2.0 * math.atan2(q.z, q.w)
    return (90.0 - math.degrees(yaw)) % 360.0


def same(a: Any, b: Any, rel: float = 0.0) -> bool:
    """Equal, with JSON null meaning NaN, and a relative tolerance for float32 fields."""
    if b is None:
        return isinstance(a, float) and math.isnan(a)
    if isinstance(b, float) and isinstance(a, float):
        if math.isnan(b):
            return math.isnan(a)
        return a == b if rel == 0 else math.isclose(a, b, rel_tol=rel)
    return bool(a == b)


def by_topic(msgs: list[Decoded], name: str) -> list[Decoded]:
    return [m for m in msgs if m.topic == name]


def check_against_jsonl(msgs: list[Decoded], jsonl: Path, *, live: bool) -> None:
    recs = jsonl_records(jsonl)
    # types: every topic carries the type the topic table names
    for m in msgs:
        assert m.typename == topics.BY_NAME[m.topic].typename, m.topic

    # stamps: the log time of each message is its header stamp
    for m in msgs:
        if m.topic == topics.TF.name:
            assert {ns(t.header.stamp) for t in m.message.transforms} == {m.log_time_ns}
        elif m.topic != topics.MARKERS.name:
            assert ns(m.message.header.stamp) == m.log_time_ns, m.topic

    # bearings: one element per JSONL bearing, in order, every value
    # (the order of messages may differ: a reader sorts by log time, a file keeps arrival)
    got = sorted(
        (b for m in by_topic(msgs, topics.BEARINGS.name) for b in m.message.bearings),
        key=lambda b: (ns(b.header.stamp), b.sensor_id, b.emitter_id, b.azimuth_deg),
    )
    want = sorted(
        recs["bearing"], key=lambda w: (w["t_ns"], w["sensor_id"], w["emitter"], w["azimuth_deg"])
    )
    assert len(got) == len(want) > 100
    for b, w in zip(got, want, strict=True):
        assert b.header.frame_id == f"rfsas/sensor/{w['sensor_id']}"
        assert ns(b.header.stamp) == w["t_ns"]
        assert (b.sensor_id, b.emitter_id, b.channel) == (
            w["sensor_id"],
            w["emitter"],
            w["channel"],
        )
        assert same(b.azimuth_deg, w["azimuth_deg"]) and same(b.sigma_deg, w["sigma_deg"])
        assert same(b.snr_db, w["snr_db"], rel=1e-6)  # float32 on the wire
        assert (b.sensor_pose.position.x, b.sensor_pose.position.y) == (w["x_m"], w["y_m"])
        assert heading_of(b.sensor_pose.orientation) == pytest.approx(w["heading_deg"], abs=1e-9)
        # REP-103 yaw of the same direction: counter-clockwise from east
        assert math.cos(b.yaw_rad) == pytest.approx(math.sin(math.radians(b.azimuth_deg)))
        assert math.sin(b.yaw_rad) == pytest.approx(math.cos(math.radians(b.azimuth_deg)))

    # fixes: every field of every JSONL fix
    fixes = sorted(
        (f for m in by_topic(msgs, topics.FIXES.name) for f in m.message.fixes),
        key=lambda f: (ns(f.header.stamp), f.emitter_id),
    )
    want = sorted(recs["fix"], key=lambda w: (w["t_ns"], w["emitter"]))
    assert len(fixes) == len(want) > 10
    for f, w in zip(fixes, want, strict=True):
        assert f.header.frame_id == "map" and ns(f.header.stamp) == w["t_ns"]
        assert (f.emitter_id, f.ok, f.status, f.reason) == (
            w["emitter"],
            w["ok"],
            w["status"],
            w["reason"],
        )
        assert list(f.sensor_ids) == w["sensors"]
        assert same(f.position.x, w["x_m"]) and same(f.position.y, w["y_m"])
        cov = list(f.covariance)
        assert cov[1] == cov[2]
        keys = ("cov_xx_m2", "cov_xy_m2", "cov_yy_m2")
        for got_v, key in zip((cov[0], cov[1], cov[3]), keys, strict=True):
            assert same(got_v, w[key]), key
        assert same(f.gdop, w["gdop"]) and same(f.condition, w["condition"])

    # assessments and their tracks
    assessments = sorted(
        (a for m in by_topic(msgs, topics.ASSESSMENTS.name) for a in m.message.assessments),
        key=lambda a: (ns(a.track.header.stamp), a.track.emitter_id),
    )
    want_a = sorted(recs["assessment"], key=lambda w: (w["t_ns"], w["emitter"]))
    assert len(assessments) == len(want_a) > 10
    for a, w in zip(assessments, want_a, strict=True):
        tr = a.track
        assert ns(tr.header.stamp) == w["t_ns"] and tr.header.frame_id == "map"
        assert tr.emitter_id == w["emitter"] and list(tr.sensor_ids) == w["sensors"]
        pairs = [
            (tr.position.x, "x_m"),
            (tr.position.y, "y_m"),
            (tr.velocity.x, "vx_mps"),
            (tr.velocity.y, "vy_mps"),
            (tr.position_covariance[0], "cov_xx_m2"),
            (tr.position_covariance[1], "cov_xy_m2"),
            (tr.position_covariance[3], "cov_yy_m2"),
            (tr.age_s, "age_s"),
            (a.p_collision, "p_collision"),
            (a.t_closest_s, "t_closest_s"),
            (a.distance_to_contact_m, "distance_to_contact_m"),
            (a.impact_speed_mps, "impact_speed_mps"),
            (a.fatality_risk, "fatality_risk"),
            (a.risk, "risk"),
        ]
        for value, key in pairs:
            assert same(value, w[key]), key
        assert ADVISORY[a.advisory] == w["advisory"]
        assert (a.fix_ok, a.fix_reason, a.link_alarm) == (
            w["fix_ok"],
            w["fix_reason"],
            w["link_alarm"],
        )
        assert list(a.reasons) == w["reasons"]

    # standard types: one RadarTrack per located assessment, one pose per trustworthy fix
    tracks = sorted(
        (
            (m.log_time_ns, bytes(t.uuid.uuid[:8]).hex(), t)
            for m in by_topic(msgs, topics.TRACKS.name)
            for t in m.message.tracks
        ),
        key=lambda item: item[:2],
    )
    assert len(tracks) == len(want_a)
    for (_, _, t), w in zip(tracks, want_a, strict=True):
        assert bytes(t.uuid.uuid[:8]).hex() == w["emitter"]
        assert (t.position.x, t.position.y) == (w["x_m"], w["y_m"])
        assert t.position_covariance[0] == pytest.approx(w["cov_xx_m2"], rel=1e-6)
    poses = sorted(
        by_topic(msgs, topics.FIX_POSE.name),
        key=lambda p: (p.log_time_ns, p.message.pose.pose.position.x),
    )
    ok_fixes = sorted((w for w in recs["fix"] if w["ok"]), key=lambda w: (w["t_ns"], w["x_m"]))
    assert len(poses) == len(ok_fixes) > 0
    for p, w in zip(poses, ok_fixes, strict=True):
        assert (p.message.pose.pose.position.x, p.message.pose.pose.position.y) == (
            w["x_m"],
            w["y_m"],
        )
        cov = list(p.message.pose.covariance)
        assert (cov[0], cov[1], cov[6], cov[7]) == (
            w["cov_xx_m2"],
            w["cov_xy_m2"],
            w["cov_xy_m2"],
            w["cov_yy_m2"],
        )

    # frames: every transform hangs off map; sensors at their pose, yaw = 90° − heading
    children: dict[str, list[Any]] = {}
    for m in by_topic(msgs, topics.TF.name):
        for t in m.message.transforms:
            assert t.header.frame_id == "map"
            children.setdefault(t.child_frame_id, []).append(t)
    want_frames = {f"rfsas/sensor/{s}" for s in SENSORS}
    assert want_frames <= set(children)
    for sensor_id, pose in SENSORS.items():
        for t in children[f"rfsas/sensor/{sensor_id}"]:
            assert (t.transform.translation.x, t.transform.translation.y) == (pose.x_m, pose.y_m)
            assert heading_of(t.transform.rotation) == pytest.approx(pose.heading_deg, abs=1e-9)
    if live:
        assert "rfsas/ego" in children
        assert len(by_topic(msgs, topics.EGO.name)) == len(children["rfsas/ego"]) > 0
        assert by_topic(msgs, topics.LINK.name) and by_topic(msgs, topics.DIAGNOSTICS.name)
    markers = [mk for m in by_topic(msgs, topics.MARKERS.name) for mk in m.message.markers]
    namespaces = {mk.ns for mk in markers}
    assert {"fix_ellipses", "tracks", "advisories", "sensors"} <= namespaces
    assert {f"bearings/{s}" for s in SENSORS} <= namespaces
    assert all(mk.header.frame_id == "map" for mk in markers)
    # a sensor's marker keeps its id whichever path drew it (no flicker between sensors)
    sensor_marks: dict[int, set[tuple[float, float]]] = {}
    for mk in markers:
        if mk.ns == "sensors":
            sensor_marks.setdefault(mk.id, set()).add((mk.pose.position.x, mk.pose.position.y))
    assert sorted(sensor_marks.values(), key=str) == sorted(
        ({(p.x_m, p.y_m)} for p in SENSORS.values()), key=str
    )


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    tmp = tmp_path_factory.mktemp("ros2run")
    run = run_backend(tmp, [McapFileWriter(tmp / "run.mcap"), Rosbag2Writer(tmp / "bag")])
    return tmp, run


def test_mcap_read_by_mcap_ros2_matches_the_jsonl(recorded: tuple[Path, Any]) -> None:
    tmp, run = recorded
    msgs = read_mcap(tmp / "run.mcap")
    assert len(msgs) == sum(run.sink.counts.values())
    check_against_jsonl(msgs, tmp / "run.jsonl", live=True)
    # the ego is where the backend judged it: the vehicle state moved to each step's time
    ego = by_topic(msgs, topics.EGO.name)[-1]
    want = vehicle_at(run.vehicle, ego.log_time_ns)
    assert ego.message.pose.pose.position.y == pytest.approx(want.y_m)
    assert ego.message.child_frame_id == "rfsas/ego"


def test_mcap_container_read_by_rosbags(recorded: tuple[Path, Any]) -> None:
    """The same file through rosbags' reader: same topics, types, times and bytes."""
    from rosbags.highlevel import AnyReader

    tmp, _ = recorded
    ours = read_mcap(tmp / "run.mcap")
    with AnyReader([tmp / "run.mcap"]) as reader:
        theirs = [(c.topic, c.msgtype, t, bytes(data)) for c, t, data in reader.messages()]
    assert sorted(theirs) == sorted((m.topic, m.typename, m.log_time_ns, m.data) for m in ours)


def test_rosbag2_read_by_sqlite_and_mcap_ros2_matches_the_jsonl(recorded: tuple[Path, Any]) -> None:
    tmp, run = recorded
    msgs = read_rosbag2_sqlite(tmp / "bag")
    assert len(msgs) == sum(run.sink.counts.values())
    check_against_jsonl(msgs, tmp / "run.jsonl", live=True)
    meta = (tmp / "bag" / "metadata.yaml").read_text()
    assert "storage_identifier: sqlite3" in meta and "/rfsas/bearings" in meta


@pytest.mark.parametrize("fmt", ["mcap", "rosbag2"])
def test_export_of_the_jsonl_matches_it_and_the_live_recording(
    recorded: tuple[Path, Any], tmp_path: Path, fmt: str, capsys: pytest.CaptureFixture[str]
) -> None:
    tmp, _ = recorded
    out = tmp_path / ("x.mcap" if fmt == "mcap" else "x_bag")
    main(["export", str(tmp / "run.jsonl"), "--to", fmt, "--out", str(out)])
    assert f"wrote {out}" in capsys.readouterr().out
    msgs = read_mcap(out) if fmt == "mcap" else read_rosbag2_sqlite(out)
    check_against_jsonl(msgs, tmp / "run.jsonl", live=False)
    # fixes and assessments are byte for byte what the live run recorded
    live = read_mcap(tmp / "run.mcap")
    for topic in (topics.FIXES.name, topics.ASSESSMENTS.name):
        field = "fixes" if topic == topics.FIXES.name else "assessments"
        assert [m.data for m in by_topic(msgs, topic)] == [
            m.data for m in by_topic(live, topic) if getattr(m.message, field)
        ]


def test_export_of_a_bearings_file_needs_poses_for_rays(tmp_path: Path) -> None:
    """A bearings file of ``rfsas replay`` has no pose: bearings are recorded either way,
    transforms and rays only for sensors given with --pose."""
    lines = [
        '{"t_ns": 1763800000000000000, "sensor_id": "s1", "azimuth_deg": 10.0, "sigma_deg": 2.0,'
        ' "snr_db": 20.0, "channel": 6, "emitter": "00000000000000aa", "relative_deg": null}',
        "this line is broken",
        '{"t_ns": 1763800000050000000, "sensor_id": "s2", "azimuth_deg": 350.0, "sigma_deg": 2.0,'
        ' "snr_db": 21.5, "channel": 11, "emitter": "00000000000000aa", "relative_deg": 3.0}',
    ]
    src = tmp_path / "bearings.jsonl"
    src.write_text("\n".join(lines) + "\n")
    from rfsas_hw.records import Pose
    from rfsas_hw.ros2.export import export_runs

    res = export_runs([src], tmp_path / "b.mcap", "mcap", poses={"s1": Pose(1.0, 2.0, 90.0)})
    assert res.bearings == 2 and res.skipped["not JSON"] == 1 and res.no_pose == {"s2"}
    assert "line 2" in res.errors[0]
    msgs = read_mcap(tmp_path / "b.mcap")
    arrays = by_topic(msgs, topics.BEARINGS.name)
    assert [len(m.message.bearings) for m in arrays] == [1, 1]
    b2 = arrays[1].message.bearings[0]
    assert math.isnan(b2.sensor_pose.position.x) and b2.relative_deg == 3.0 and b2.channel == 11
    tfs = [t.child_frame_id for m in by_topic(msgs, topics.TF.name) for t in m.message.transforms]
    assert tfs == ["rfsas/sensor/s1"]


def test_export_refuses_what_it_must_not_write(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One line and exit code 2: a missing input, the input as output, an existing bag."""
    src = tmp_path / "run.jsonl"
    src.write_text("")
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "keep.txt").write_text("precious")
    cases = [
        (
            ["export", str(tmp_path / "missing.jsonl"), "--to", "mcap", "--out", "x.mcap"],
            "cannot read",
        ),
        (["export", str(src), "--to", "mcap", "--out", str(src)], "is also an input"),
        (["export", str(src), "--to", "rosbag2", "--out", str(bag)], "must be new"),
    ]
    for argv, message in cases:
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
    assert (bag / "keep.txt").read_text() == "precious"


def test_rosbag2_with_mcap_storage(recorded: tuple[Path, Any], tmp_path: Path) -> None:
    """``--storage mcap``: a rosbag2 directory whose storage file mcap-ros2-support reads."""
    tmp, _ = recorded
    out = tmp_path / "bag_mcap"
    main(
        [
            "export",
            str(tmp / "run.jsonl"),
            "--to",
            "rosbag2",
            "--out",
            str(out),
            "--storage",
            "mcap",
        ]
    )
    (inner,) = out.glob("*.mcap")
    assert "storage_identifier: mcap" in (out / "metadata.yaml").read_text()
    check_against_jsonl(read_mcap(inner), tmp / "run.jsonl", live=False)
