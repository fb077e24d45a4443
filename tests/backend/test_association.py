"""Association by hashed emitter id within a time window."""

from __future__ import annotations

import numpy as np
import pytest

from rfsas_hw.backend.association import AssociationConfig, Associator, StationBearing
from rfsas_hw.errors import ConfigError
from rfsas_hw.records import BearingBatch, Pose

S = 1_000_000_000


def batch(sensor: str, t_s: list[float], az: list[float], emitters: list[int]) -> BearingBatch:
    n = len(t_s)
    return BearingBatch(
        sensor_id=sensor,
        t_ns=np.array([int(t * S) for t in t_s], np.int64),
        azimuth_deg=np.array(az),
        sigma_deg=np.full(n, 2.0),
        snr_db=np.full(n, 20.0),
        channel=np.full(n, 6, np.int16),
        emitter=np.array(emitters, np.uint64),
    )


def test_newest_bearing_per_sensor_and_emitter_within_the_window() -> None:
    assoc = Associator(AssociationConfig(window_s=1.0, epoch_s=60.0))
    a, b, c = Pose(0, 0, 0), Pose(10, 0, 0), Pose(5, -20, 0)
    assoc.add(batch("a", [100.0, 100.5, 100.2], [10.0, 11.0, 99.0], [7, 7, 8]), a)
    assoc.add(batch("b", [100.6], [350.0], [7]), b)
    assoc.add(batch("c", [98.0], [0.0], [7]), c)  # too old for the window around 100.6
    groups = assoc.groups(int(100.7 * S))
    assert len(groups) == 1  # emitter 8 has one sensor only
    assert int(groups.emitter[0]) == 7 and groups.sensors[0] == ("a", "b")
    np.testing.assert_allclose(groups.azimuth_deg[0], [11.0, 350.0])  # newest of sensor a
    np.testing.assert_allclose(groups.stations_xy[0], [[0, 0], [10, 0]])
    assert groups.t_ns[0] == int(100.6 * S)
    # nothing new: no groups; only_new=False hands out the current state again
    assert len(assoc.groups(int(100.7 * S))) == 0
    assert len(assoc.groups(int(100.7 * S), only_new=False)) == 1
    # an older bearing arriving late does not replace a newer one
    assoc.add(batch("a", [100.1], [45.0], [7]), a)
    assert assoc.groups(int(100.7 * S), only_new=False).azimuth_deg[0, 0] == 11.0


def test_stale_bearings_age_out_and_ids_from_different_emitters_never_mix() -> None:
    assoc = Associator(AssociationConfig(window_s=0.5, epoch_s=60.0, max_age_s=2.0))
    assoc.add(batch("a", [10.0], [10.0], [1]), Pose(0, 0, 0))
    assoc.add(batch("b", [10.2], [350.0], [2]), Pose(10, 0, 0))
    assert len(assoc.groups(int(10.3 * S))) == 0
    assoc.add(batch("b", [10.3], [350.0], [1]), Pose(10, 0, 0))
    assert len(assoc.groups(int(10.4 * S))) == 1
    assoc.prune(int(12.25 * S))
    assert len(assoc) == 1 and assoc.stats.aged_out == 2  # 'a'/1 and 'b'/2 at 10.0 and 10.2
    assoc.prune(int(13 * S))
    assert len(assoc) == 0


def test_many_emitters_are_padded_into_one_batch() -> None:
    rng = np.random.default_rng(40)
    assoc = Associator()
    emitters = list(range(100, 150))
    for k, sensor in enumerate(["a", "b", "c"]):
        keep = emitters if sensor != "c" else emitters[::2]
        assoc.add(
            batch(sensor, [5.0] * len(keep), list(rng.uniform(0, 360, len(keep))), keep),
            Pose(10.0 * k, 0, 0),
        )
    groups = assoc.groups(5 * S)
    assert len(groups) == 50 and groups.azimuth_deg.shape == (50, 3)
    assert np.isnan(groups.azimuth_deg[1, 2]) and not np.isnan(groups.azimuth_deg[0, 2])


def test_window_must_be_shorter_than_the_epoch() -> None:
    with pytest.raises(ConfigError, match="shorter than the nonce epoch"):
        AssociationConfig(window_s=60.0, epoch_s=60.0)
    with pytest.raises(ConfigError, match="max_age_s"):
        AssociationConfig(window_s=1.0, max_age_s=0.5)
    with pytest.raises(ConfigError, match="min_sensors"):
        AssociationConfig(min_sensors=1)


def test_a_batch_keeps_each_emitters_newest_bearing_the_later_row_on_a_tie() -> None:
    assoc = Associator(AssociationConfig(window_s=1.0, epoch_s=60.0))
    assoc.add(
        batch("a", [100.2, 100.5, 100.5, 100.1, 100.3], [1.0, 2.0, 3.0, 4.0, 5.0], [9, 7, 7, 3, 7]),
        Pose(0, 0, 0),
    )
    assert assoc.stats.superseded == 2  # two of emitter 7's three bearings
    assoc.add(batch("b", [100.4, 100.4, 100.4], [6.0, 7.0, 8.0], [3, 7, 9]), Pose(10, 0, 0))
    groups = assoc.groups(int(100.6 * S))
    assert groups.emitter.tolist() == [3, 7, 9]
    assert all(s == ("a", "b") for s in groups.sensors)
    np.testing.assert_allclose(groups.azimuth_deg, [[4.0, 6.0], [3.0, 7.0], [1.0, 8.0]])


def test_a_refused_bearing_is_left_out_of_the_group_and_kept() -> None:
    assoc = Associator(AssociationConfig(window_s=1.0, epoch_s=60.0))
    assoc.add(batch("a", [100.0], [10.0], [7]), Pose(0, 0, 0))
    assoc.add(batch("b", [100.2], [350.0], [7]), Pose(10, 0, 0))
    assoc.add(batch("c", [100.4], [5.0], [7]), Pose(5, -20, 0))
    asked: list[tuple[int, str]] = []

    def not_c(emitter: int, bearing: StationBearing) -> bool:
        asked.append((emitter, bearing.sensor))
        return bearing.sensor != "c"

    groups = assoc.groups(int(100.5 * S), admit=not_c)
    assert sorted(asked) == [(7, "a"), (7, "b"), (7, "c")]
    assert groups.sensors == (("a", "b"),)
    assert groups.t_ns[0] == int(100.2 * S)  # the newest bearing that joined
    # refusing all but one leaves no group; the bearings are still there
    assert (
        len(assoc.groups(int(100.5 * S), only_new=False, admit=lambda e, b: b.sensor == "a")) == 0
    )
    assert [b.sensor for b in assoc.newest(7)] == ["a", "b", "c"]
    assert assoc.groups(int(100.5 * S), only_new=False).sensors == (("a", "b", "c"),)
