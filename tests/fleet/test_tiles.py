"""Tile plans: disjoint regions, one group per backend, stable assignment."""

from __future__ import annotations

from pathlib import Path

import pytest

from rfsas_hw.errors import ConfigError
from rfsas_hw.fleet.tiles import TilePlan, assign_tiles, load_tile_plan, with_tiles


def plan(groups: dict[str, object]) -> TilePlan:
    return TilePlan.from_mapping({"groups": groups}, "plan.yaml")


def test_a_plan_gives_each_backend_its_subscriptions(tmp_path: Path) -> None:
    path = tmp_path / "plan.yaml"
    path.write_text(
        "groups:\n"
        "  north: {tiles: ['1202', '1203'], members: [be-a, be-b]}\n"
        "  south: {tiles: ['1212'], members: [be-c]}\n"
    )
    p = load_tile_plan(path)
    assert p.group_of("be-b").name == "north"
    assert p.group_of("be-a").filters() == [
        "rfsas/v1/bearing/+/1/2/0/2/#",
        "rfsas/v1/bearing/+/1/2/0/3/#",
    ]
    assert p.listen_options("be-c") == {"tiles": "1212"}
    assert p.owner("1202" + "0" * 12) is p.groups["north"]
    assert p.owner("0" * 16) is None
    with pytest.raises(ConfigError, match="in no group"):
        p.group_of("be-z")


@pytest.mark.parametrize(
    ("groups", "why"),
    [
        ({"a": {"tiles": ["12"], "members": ["x"]}, "b": {"tiles": ["123"], "members": ["y"]}},
         "overlaps"),
        ({"a": {"tiles": ["12"], "members": ["x"]}, "b": {"tiles": ["13"], "members": ["x"]}},
         "groups 'a' and 'b'"),
        ({"a": {"tiles": [], "members": ["x"]}}, "needs tiles"),
        ({"a": {"tiles": ["14"], "members": ["x"]}}, "quadkey"),
        ({"a": {"tiles": ["1" * 17], "members": ["x"]}}, "zoom 16"),
        ({"a": {"tiles": ["1"], "members": ["x"], "spare": 1}}, "exactly the keys"),
    ],
)  # fmt: skip
def test_bad_plans_are_refused_with_the_reason(groups: dict[str, object], why: str) -> None:
    with pytest.raises(ConfigError, match=why):
        plan(groups)


def test_assignment_is_stable_when_a_group_is_added() -> None:
    tiles = [f"{a}{b}{c}" for a in "0123" for b in "0123" for c in "0123"]
    two = assign_tiles(tiles, ["g1", "g2"])
    three = assign_tiles(tiles, ["g1", "g2", "g3"])
    assert sorted(two["g1"] + two["g2"]) == sorted(tiles)
    assert 20 < len(two["g1"]) < 44  # roughly even
    # tiles only move to the new group, never between the old ones
    for g in ("g1", "g2"):
        assert set(three[g]) <= set(two[g])
    plan({g: {"tiles": ts, "members": [f"be-{g}"]} for g, ts in three.items()})


def test_broker_urls_take_the_tiles_of_the_backends_group() -> None:
    p = plan({"north": {"tiles": ["1202", "1203"], "members": ["be-a"]}})
    assert with_tiles("mqtts://b?ca=x", p, "be-a") == "mqtts://b?ca=x&tiles=1202,1203"
    assert with_tiles("mqtt://b", p, "be-a") == "mqtt://b?tiles=1202,1203"
    assert with_tiles("udp://0.0.0.0:47000", p, "be-a") == "udp://0.0.0.0:47000"
    with pytest.raises(ConfigError, match="not both"):
        with_tiles("mqtt://b?tiles=1", p, "be-a")
