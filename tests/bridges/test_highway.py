"""highway-env adapter: crossers from behind the building, the rfsas frame, and the shield
against the unprotected baseline over eight seeds."""

from __future__ import annotations

import pytest

pytest.importorskip(
    "highway_env", reason="needs the highway extra: pip install 'rfsas-hw[highway]'"
)

from rfsas_hw.bridges.highway import (
    CrossingConfig,
    HighwayAdapter,
    idle_action,
    make_scene,
)
from rfsas_hw.envs.closed_loop import compare, summarise
from rfsas_hw.envs.rfsas_wrapper import RfsasWrapper
from rfsas_hw.errors import ConfigError

QUIET = {"policy_frequency": 5, "initial_vehicle_count": 1, "spawn_probability": 0.0}
SEEDS = range(8)
MAX_STEPS = 30
"""6 s at 5 Hz: the crossers meet the ego after about 3.5 s."""


def test_ego_and_crossers_are_in_the_rfsas_frame_and_hidden_at_first() -> None:
    env = make_scene("intersection-v0", QUIET)
    adapter = HighwayAdapter(CrossingConfig(count=2, cyclist_share=0.0))
    try:
        env.reset(seed=2)
        adapter.reset(env, 2)
        snap = adapter.read(env)
        # intersection-v0's ego comes from the south, driving north (highway-env y down)
        assert snap.ego.y_m < -20.0 and abs(snap.ego.heading_deg % 360.0) < 1.0
        walkers = [e for e in snap.entities if e.id.startswith("crosser")]
        assert [w.kind for w in walkers] == ["pedestrian", "pedestrian"]
        # walking west, across the ego's lane, from behind the building on its right
        assert all(abs(w.heading_deg - 270.0) < 1.0 for w in walkers)
        (building,) = adapter.buildings()
        assert all(w.x_m > building.x_min_m and w.y_m > building.y_max_m for w in walkers)
        assert not adapter.visible("crosser-0")
        assert all(w.obstacle not in env.unwrapped.road.objects for w in adapter.crossers)
        assert len(adapter.units()) == 2
        seen = False
        for _ in range(25):
            env.step(idle_action(env))
            adapter.after_step(env)
            seen = seen or adapter.visible("crosser-0")
            if env.unwrapped.vehicle.crashed:
                break
        assert seen
    finally:
        env.close()


def test_unknown_scene_is_named() -> None:
    with pytest.raises(ConfigError, match="'nowhere-v0' is not a registered"):
        make_scene("nowhere-v0")


@pytest.mark.slow
def test_shield_cuts_collisions_against_the_baseline() -> None:
    def make(shield: bool) -> RfsasWrapper:
        return RfsasWrapper(make_scene("intersection-v0", QUIET), HighwayAdapter(), shield=shield)

    out = compare(
        {"baseline": lambda: make(False), "shield": lambda: make(True)},
        lambda obs, env: idle_action(env),
        SEEDS,
        MAX_STEPS,
    )
    base, shield = summarise("baseline", out["baseline"]), summarise("shield", out["shield"])
    # the crossers are timed to meet an ego that holds its speed: nearly every seed hits
    assert base.collisions >= 6
    # the shield stops the ego on RF-SAS's BRAKE; a cyclist whose BRAKE comes too late
    # (a fraction of a second before contact) is still hit
    assert shield.collisions <= 2 and shield.collisions <= base.collisions - 4
    assert all(o.shielded_steps > 0 for o in out["shield"])
    assert all(o.first_brake_s is not None for o in out["baseline"])


def test_any_scene_with_a_road_network_gets_its_crossing() -> None:
    # highway-v0: a long straight road at 25 m/s; the crossing is 60 m ahead
    def make(shield: bool) -> RfsasWrapper:
        scene = make_scene("highway-v0", {"policy_frequency": 5, "vehicles_count": 3})
        return RfsasWrapper(scene, HighwayAdapter(), shield=shield)

    out = compare(
        {"baseline": lambda: make(False), "shield": lambda: make(True)},
        lambda obs, env: idle_action(env),
        range(2),
        20,
    )
    assert [o.collided for o in out["baseline"]] == [True, True]
    # highway-v0's slowest rung is 20 m/s: the shield's stop goes below it
    assert [o.collided for o in out["shield"]] == [False, False]
