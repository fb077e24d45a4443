"""The RF activity prior: built from a replayed backend run, its counts, decay,
persistence, hour-of-day rates, the density along a path, and no emitter id stored."""

from __future__ import annotations

import json
import math
import socket
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from backendhelp import bearing_towards

from rfsas_hw.angles import math_rad_to_compass
from rfsas_hw.backend.prior import ActivityPrior, PriorConfig, PriorSink
from rfsas_hw.backend.service import BackendConfig, BackendService, JsonlSink
from rfsas_hw.errors import ConfigError, DataFormatError
from rfsas_hw.records import BearingBatch, Pose

SENSORS = {"rsu-a": Pose(-30.0, 10.0, 90.0), "rsu-b": Pose(25.0, -20.0, 0.0)}
EMITTERS = (0x0123_4567_89AB_CDEF, 0x0FED_CBA9_8765_4321, 0x1111_2222_3333_4444)
T0 = 1_767_268_800_000_000_000  # 2026-01-01T12:00:00Z
NS = 1_000_000_000
SPACING_S = 120
"""Seconds between the crossers: longer than ``max_gap_s``, so the gaps are not observed."""
STEPS = 50


def walker(k: int, t_s: float) -> np.ndarray:
    """Crosser ``k`` walks east along y = 2.5 m from x = −12 m at 4 m/s."""
    return np.array([-12.0 + 4.0 * t_s, 2.5])


def run_backend(path: Path, prior: ActivityPrior | PriorSink) -> None:
    """Three crossers, one after the other, heard by two sensors, 10 Hz, through the service
    with a JSONL sink and the prior as a second sink."""
    sink = JsonlSink(path)
    service = BackendService(BackendConfig(), sinks=[sink, prior], clock=lambda: T0)
    rng = np.random.default_rng(3)
    for k, emitter in enumerate(EMITTERS):
        for step in range(STEPS):
            t_ns = T0 + k * SPACING_S * NS + step * NS // 10
            target = walker(k, step / 10)
            for sid, pose in SENSORS.items():
                d = target - np.array([pose.x_m, pose.y_m])
                az = float(math_rad_to_compass(np.arctan2(d[1], d[0]))) + rng.normal(0, 0.3)
                service.on_bearings(
                    BearingBatch(
                        sid,
                        np.array([t_ns], np.int64),
                        np.array([az % 360.0]),
                        np.array([0.5]),
                        np.array([20.0]),
                        np.array([6], np.int16),
                        np.array([emitter], np.uint64),
                    ),
                    pose,
                )
            service.step(now_ns=t_ns + NS // 20)
    service.close()


@pytest.fixture(scope="module")
def replay(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, ActivityPrior]:
    path = tmp_path_factory.mktemp("prior") / "run.jsonl"
    live = ActivityPrior()
    run_backend(path, live)
    return path, live


def test_prior_from_a_replayed_run_counts_each_crosser_once_per_tile(
    replay: tuple[Path, ActivityPrior],
) -> None:
    path, live = replay
    prior, skipped = ActivityPrior.from_run(path)
    assert skipped == 0
    # the walkers cross x = −10…+6 m inside the tiles (−2, 0) … (1, 0): three visits each
    for ix in (-2, -1, 0, 1):
        assert prior.visits((ix, 0)).sum() == pytest.approx(3.0, rel=1e-3)
        assert prior.visits((ix, 0))[12] == pytest.approx(3.0, rel=1e-3)  # 12:00 UTC
    assert set(prior.tiles()) <= {(ix, iy) for ix in range(-3, 2) for iy in (0,)}
    # the 115 s gaps between crossers are not observed time: 3 × 4.9 s are
    assert prior.observed_s().sum() == pytest.approx(3 * 4.9, abs=0.35)
    rate = prior.rate_per_h(-7.0, 2.0)
    assert rate == pytest.approx(3 / (prior.observed_s().sum() / 3600), rel=1e-3)
    # the prior fed live as a result sink of the same run agrees with the replay
    for tile in prior.tiles():
        assert live.visits(tile).sum() == pytest.approx(prior.visits(tile).sum(), rel=1e-6)


def test_a_line_that_is_not_json_costs_only_itself(
    replay: tuple[Path, ActivityPrior], tmp_path: Path
) -> None:
    path, _ = replay
    lines = path.read_text().splitlines()
    damaged = tmp_path / "damaged.jsonl"
    damaged.write_text("\n".join([lines[0], "{not json", '{"record": "fix"}', *lines[1:]]) + "\n")
    prior, skipped = ActivityPrior.from_run(damaged)
    assert skipped == 2
    assert prior.visits((0, 0)).sum() == pytest.approx(3.0, rel=1e-3)
    with pytest.raises(DataFormatError, match=r"missing\.jsonl"):
        ActivityPrior.from_run(tmp_path / "missing.jsonl")


def test_counts_decay_with_the_half_life() -> None:
    prior = ActivityPrior(PriorConfig(half_life_h=1.0))
    assert prior.add_fix(T0, 1.0, 1.0, "a")
    assert not prior.add_fix(T0 + NS, 1.2, 1.1, "a")  # same road user, same tile
    assert prior.add_fix(T0 + NS, 1.2, 1.1, "b")
    prior.add_fix(T0 + 3600 * NS, 40.0, 40.0, "c")  # one half-life later, elsewhere
    assert prior.visits((0, 0)).sum() == pytest.approx(1.0, rel=1e-3)
    assert prior.visits((8, 8)).sum() == pytest.approx(1.0)
    # two half-lives on, asked at a later time: a quarter of the original two visits
    assert prior.visits((0, 0), t_ns=T0 + 2 * 3600 * NS).sum() == pytest.approx(0.5, rel=1e-3)
    # a road user who comes back after revisit_s is a new visit
    assert prior.add_fix(T0 + 3700 * NS, 1.0, 1.0, "a")


def test_persistence_round_trip_and_counting_continues(
    replay: tuple[Path, ActivityPrior], tmp_path: Path
) -> None:
    path, _ = replay
    prior, _ = ActivityPrior.from_run(path)
    saved = prior.save(tmp_path / "site" / "prior.json")
    loaded = ActivityPrior.load(saved)
    assert loaded.tiles() == prior.tiles()
    for tile in prior.tiles():
        np.testing.assert_allclose(loaded.visits(tile), prior.visits(tile), rtol=1e-9)
    np.testing.assert_allclose(loaded.observed_s(), prior.observed_s(), rtol=1e-9)
    assert loaded.rate_per_h(-7.0, 2.0) == pytest.approx(prior.rate_per_h(-7.0, 2.0))
    # the next run adds to the loaded history
    assert prior.last_ns is not None
    loaded.add_fix(prior.last_ns + NS, -7.0, 2.0, "new")
    assert loaded.visits((-2, 0)).sum() == pytest.approx(4.0, rel=1e-3)
    assert len(saved.read_text().splitlines()) < 20  # small: one line per tile


def test_the_prior_file_holds_no_emitter_id(
    replay: tuple[Path, ActivityPrior], tmp_path: Path
) -> None:
    path, live = replay
    prior, _ = ActivityPrior.from_run(path)
    text = prior.save(tmp_path / "prior.json").read_text()
    live_text = live.save(tmp_path / "live.json").read_text()
    run_text = path.read_text()
    for emitter in EMITTERS:
        # the run log names each emitter by a keyed hash; the prior names none
        assert f"{emitter:016x}" in run_text
        for t in (text, live_text):
            assert f"{emitter:016x}" not in t.lower()
            assert f"{emitter:x}" not in t.lower()
    data = json.loads(text)
    assert set(data) == {
        "format",
        "version",
        "config",
        "first_ns",
        "last_ns",
        "observed_s",
        "tiles",
    }
    for ix, iy, counts in data["tiles"]:
        assert isinstance(ix, int) and isinstance(iy, int) and len(counts) == 24
    # and the in-memory table of recent emitters is gone once the run is over
    assert live._recent == {}


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ("{", "not JSON"),
        ('{"format": "other"}', "not an activity prior"),
        ('{"format": "rfsas-activity-prior", "version": 9}', "unsupported version"),
        (
            '{"format": "rfsas-activity-prior", "version": 1, "config": {}, "first_ns": 1, '
            '"last_ns": 2, "observed_s": [1], "tiles": []}',
            "observed_s",
        ),
    ],
)
def test_a_bad_prior_file_is_one_clear_error(tmp_path: Path, content: str, match: str) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    with pytest.raises(DataFormatError, match=match):
        ActivityPrior.load(bad)


def test_hour_of_day_rates_once_the_history_is_long_enough() -> None:
    prior = ActivityPrior(PriorConfig(hourly_after_days=7.0, max_gap_s=3600.0))
    day = 86400 * NS
    n = 0
    for d in range(8):
        for minute in range(0, 24 * 60, 30):
            t = T0 - 12 * 3600 * NS + d * day + minute * 60 * NS  # from midnight
            prior.observe(t)
            if 8 * 60 <= minute < 9 * 60:  # a crossing every half hour from 08:00 to 09:00
                prior.add_fix(t, 1.0, 1.0, f"x{n}")
                n += 1
    assert prior.hourly
    assert prior.rate_per_h(1.0, 1.0, hour=8) == pytest.approx(2.0, rel=0.1)
    assert prior.rate_per_h(1.0, 1.0, hour=15) == 0.0
    pooled = prior.rate_per_h(1.0, 1.0)
    assert pooled == pytest.approx(2.0 / 24, rel=0.15)
    short = ActivityPrior()
    short.add_fix(T0, 1.0, 1.0, "a")
    short.observe(T0 + 10 * NS)
    assert not short.hourly
    assert short.rate_per_h(1.0, 1.0, hour=3) == pytest.approx(360.0, rel=1e-4)


def test_density_ahead_sums_the_tiles_along_the_path() -> None:
    prior = ActivityPrior(PriorConfig(tile_m=5.0, max_gap_s=7200.0))
    prior.add_fix(T0, 1.75, -3.5, "a")  # on the car's lane, at the crossing
    prior.add_fix(T0, 30.0, -3.5, "b")  # far off the lane
    prior.observe(T0 + 3600 * NS)
    lane = np.array([[1.75, -100.0], [1.75, 5.0]])
    assert prior.density_ahead(lane) == pytest.approx(1.0, rel=1e-2)
    assert prior.density_ahead(np.array([[1.75, -100.0], [1.75, -40.0]])) == 0.0
    assert prior.density_ahead(np.array([[-20.0, -3.5], [40.0, -3.5]])) == pytest.approx(
        2.0, rel=1e-2
    )
    assert math.isclose(prior.density_ahead([[1.75, -3.0]]), 1.0, rel_tol=1e-2)
    with pytest.raises(ConfigError, match="path"):
        prior.density_ahead(np.zeros(3))
    with pytest.raises(ConfigError, match="tile_m"):
        PriorConfig(tile_m=0)


def test_a_prior_sink_keeps_the_file_across_backend_runs(tmp_path: Path) -> None:
    path = tmp_path / "site-prior.json"
    for run in range(2):
        run_backend(tmp_path / f"run{run}.jsonl", PriorSink(path))  # saved when it ends
        assert ActivityPrior.load(path).visits((0, 0)).sum() == pytest.approx(
            3.0 * (run + 1), rel=1e-3
        )
    path.write_text("{}")
    with pytest.raises(DataFormatError, match="site-prior"):
        PriorSink(path)


def _send_signed(url: str, stores: dict[str, Any], emitter: int) -> None:
    """Signed bearings of one emitter at (−6, 22) m from two sensors, 10 Hz for 2 s."""
    from rfsas_hw.link import Publisher

    time.sleep(0.3)
    poses = {"rsu-n": Pose(-35.0, 10.0, 90.0), "rsu-s": Pose(25.0, -5.0, 0.0)}
    pubs = {sid: Publisher.to_url(url, stores[sid].signer(), p) for sid, p in poses.items()}
    try:
        for _ in range(20):
            now = time.time_ns()
            for sid, pose in poses.items():
                pubs[sid].on_bearings(bearing_towards(sid, pose, (-6.0, 22.0), emitter, now))
            time.sleep(0.1)
    finally:
        for pub in pubs.values():
            pub.close()


def test_rfsas_backend_prior_keeps_a_file_across_runs(tmp_path: Path) -> None:
    from click.testing import CliRunner

    from rfsas_hw.cli.backend import backend
    from rfsas_hw.link.keys import KeyStore

    keys = KeyStore.create(tmp_path / "backend", "backend", "obu-1")
    stores = {sid: KeyStore.create(tmp_path / sid, "sensor", sid) for sid in ("rsu-n", "rsu-s")}
    for store in stores.values():
        keys.trust.enroll(store.card)
    prior_path = tmp_path / "site-prior.json"
    emitter = 0xC0FF_EE00_0000_0042
    totals = []
    for _ in range(2):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            url = f"udp://127.0.0.1:{s.getsockname()[1]}"
        sender = threading.Thread(target=_send_signed, args=(url, stores, emitter))
        sender.start()
        result = CliRunner().invoke(
            backend,
            ["--listen", url, "--keys", str(tmp_path / "backend"), "--prior", str(prior_path),
             "--duration", "2.5", "--no-table"],
        )  # fmt: skip
        sender.join()
        assert result.exit_code == 0, result.output
        prior = ActivityPrior.load(prior_path)
        tile = prior.tile_of(-6.0, 22.0)
        totals.append(float(prior.visits(tile).sum()))
    # one visit of the emitter's tile per run, kept and added to across the runs
    assert totals[0] == pytest.approx(1.0, rel=1e-3)
    assert totals[1] == pytest.approx(2.0, rel=1e-3)
    text = prior_path.read_text()
    assert f"{emitter:016x}" not in text and str(emitter) not in text
    prior_path.write_text("not json")
    bad = CliRunner().invoke(
        backend,
        ["--listen", "udp://127.0.0.1:9", "--keys", str(tmp_path / "backend"),
         "--prior", str(prior_path), "--duration", "0.1", "--no-table"],
    )  # fmt: skip
    assert isinstance(bad.exception, DataFormatError) and "site-prior" in str(bad.exception)
