"""Closed loop in the driving simulators: collisions without RF-SAS and with its shield.

    python bench/bench_sim_shield.py                      # highway-env (main venv)
    .venv-metadrive/bin/python bench/bench_sim_shield.py  # MetaDrive (its own venv)

highway-env ``intersection-v0`` with its own traffic (10 vehicles at the
start, new ones spawned with probability 0.6, decisions at 5 Hz): the
adapter adds one crosser per episode (a pedestrian or a cyclist with a
phone, from behind a building beside the ego's approach, timed to meet an
ego that holds its speed). The ego's policy holds its speed (``IDLE``); the
shield stops it on a BRAKE advisory of the RF-SAS bridge. MetaDrive: a
straight road, no traffic, the ego at 10 m/s (a cruise controller), the same
crossing plan 35 m ahead; the shield brakes fully. Same seeds for both
conditions (common random numbers). What a user would do instead: nothing —
the simulators' own agents do not see a person hidden behind a building.

Columns: episodes, collisions, collision rate ± its standard error over seeds,
mean impact speed of the collisions, seconds of wall time.
"""

from __future__ import annotations

import importlib.util
import os
import time
from collections.abc import Callable

from rfsas_hw.envs.closed_loop import Policy, compare, summarise
from rfsas_hw.envs.rfsas_wrapper import RfsasWrapper

HIGHWAY_SEEDS = range(int(os.environ.get("RFSAS_BENCH_SEEDS", "12")))
METADRIVE_SEEDS = range(int(os.environ.get("RFSAS_BENCH_SEEDS", "10")))
HIGHWAY_TRAFFIC = {"policy_frequency": 5}
"""intersection-v0 with its own traffic; decisions at 5 Hz."""


def table(
    title: str,
    make: Callable[[bool], RfsasWrapper],
    policy: Policy,
    seeds: range,
    max_steps: int,
) -> None:
    t0 = time.perf_counter()
    out = compare(
        {"no RF-SAS": lambda: make(False), "RF-SAS shield": lambda: make(True)},
        policy,
        seeds,
        max_steps,
    )
    wall = time.perf_counter() - t0
    print(f"\n{title} ({len(seeds)} seeds, {wall:.0f} s wall for both conditions)")
    print(f"{'condition':<16}{'episodes':>9}{'hits':>6}{'rate ± s.e.':>16}{'impact m/s':>12}")
    for name, outcomes in out.items():
        s = summarise(name, outcomes)
        print(
            f"{name:<16}{s.episodes:>9}{s.collisions:>6}"
            f"{f'{s.rate:.2f} ± {s.stderr:.2f}':>16}{s.mean_impact_mps:>12.1f}"
        )


def main() -> None:
    if importlib.util.find_spec("highway_env") is not None:
        from rfsas_hw.bridges.highway import HighwayAdapter, idle_action, make_scene

        table(
            "highway-env intersection-v0, own traffic",
            lambda shield: RfsasWrapper(
                make_scene("intersection-v0", HIGHWAY_TRAFFIC), HighwayAdapter(), shield=shield
            ),
            lambda obs, env: idle_action(env),
            HIGHWAY_SEEDS,
            40,
        )
    else:
        print("highway-env: not installed here (pip install 'rfsas-hw[highway]')")
    if importlib.util.find_spec("metadrive") is not None:
        from rfsas_hw.bridges.metadrive import MetaDriveAdapter, cruise_action, make_scene

        table(
            "MetaDrive straight road (physics only)",
            lambda shield: RfsasWrapper(make_scene(), MetaDriveAdapter(), shield=shield),
            lambda obs, env: cruise_action(env),
            METADRIVE_SEEDS,
            60,
        )
    else:
        print("MetaDrive: not in this environment (it has its own: make metadrive)")


if __name__ == "__main__":
    main()
