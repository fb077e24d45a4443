"""PPO on highway-env ``intersection-v0`` with and without the RF-SAS observation.

    python bench/bench_highway_ppo.py          # 4 runs of 1 024 steps; see the docs for its time
    RFSAS_PPO_STEPS=20000 RFSAS_PPO_SEEDS=5 python bench/bench_highway_ppo.py

The scene is the adapter's: one crosser (pedestrian or cyclist with a phone)
from behind a building beside the ego's approach, timed to meet an ego that
holds its speed; little other traffic (1 vehicle, no spawns) so the time goes
to learning; decisions at 5 Hz; highway-env's own reward (−5 for a crash, a
speed bonus, +1 on arrival). No shield: the policy alone decides.

- **with RF-SAS**: PPO (``MlpPolicy``) on the wrapper's flat observation:
  highway-env's ``Kinematics`` rows (vehicles; a crosser only once the ego can
  see it past the building) followed by the RF-SAS rows (tracked emitters in
  the ego's frame, covariance, P_coll, risk, advisory);
- **without**: the same env and wrapper, the RF-SAS rows cut off, so the
  dynamics, the crossers and the seeds are identical.

Each condition is trained with the same seeds and the same number of steps,
then evaluated for ``RFSAS_PPO_EVAL`` episodes on held-out seeds
(deterministic actions). Columns: collision rate and mean episode return,
mean ± standard error over the training seeds, and wall time.

What this does and does not show: with the default budget (1 024 steps per
run, about 40 episodes, two seeds) PPO has hardly started to learn; the
table shows that the pipeline trains end to end on the wrapped observation
with the same budget and seeds, not that the RF-SAS rows are learned. A
claim about learning needs a budget one or two orders larger (the second
command) and more seeds.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

from rfsas_hw.bridges.highway import HighwayAdapter, make_scene
from rfsas_hw.envs.rfsas_obs import FEATURES
from rfsas_hw.envs.rfsas_wrapper import RfsasWrapper

STEPS = int(os.environ.get("RFSAS_PPO_STEPS", "1024"))
SEEDS = range(int(os.environ.get("RFSAS_PPO_SEEDS", "2")))
EVAL_EPISODES = int(os.environ.get("RFSAS_PPO_EVAL", "5"))
SCENE = {"policy_frequency": 5, "initial_vehicle_count": 1, "spawn_probability": 0.0}
MAX_EMITTERS = 4
PPO_KWARGS = {"n_steps": 256, "batch_size": 64, "n_epochs": 5, "learning_rate": 3e-4, "gamma": 0.95}


class DropRfsas(gym.ObservationWrapper[Any, Any, Any]):
    """The flat wrapped observation without its RF-SAS rows."""

    def __init__(self, env: RfsasWrapper) -> None:
        super().__init__(env)
        self.cut = MAX_EMITTERS * len(FEATURES)
        box = env.observation_space
        assert isinstance(box, gym.spaces.Box)
        self.observation_space = gym.spaces.Box(
            box.low[: -self.cut], box.high[: -self.cut], dtype=np.float32
        )

    def observation(self, observation: Any) -> Any:
        return observation[: -self.cut]


def make(with_rfsas: bool) -> gym.Env[Any, Any]:
    env = RfsasWrapper(
        make_scene("intersection-v0", SCENE), HighwayAdapter(), flatten=True, max_emitters=4
    )
    return env if with_rfsas else DropRfsas(env)


def run(with_rfsas: bool, seed: int) -> tuple[float, float]:
    from stable_baselines3 import PPO

    env = make(with_rfsas)
    model = PPO("MlpPolicy", env, seed=seed, verbose=0, device="cpu", **PPO_KWARGS)
    env.reset(seed=seed)
    model.learn(total_timesteps=STEPS)
    hits, returns = 0, []
    for k in range(EVAL_EPISODES):
        obs, _ = env.reset(seed=10_000 + k)
        total, done = 0.0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, term, trunc, info = env.step(action)
            total += float(reward)
            done = term or trunc
        hits += int(bool(info["rfsas"]["collision"]))
        returns.append(total)
    env.close()
    return hits / EVAL_EPISODES, float(np.mean(returns))


def mean_se(values: list[float]) -> str:
    m = float(np.mean(values))
    se = float(np.std(values, ddof=1) / math.sqrt(len(values))) if len(values) > 1 else 0.0
    return f"{m:.2f} ± {se:.2f}"


def main() -> None:
    warnings.filterwarnings("ignore", category=UserWarning, module="stable_baselines3")
    print(
        f"PPO, {STEPS} steps per run, training seeds {list(SEEDS)}, "
        f"{EVAL_EPISODES} evaluation episodes each"
    )
    print(f"{'observation':<24}{'collision rate':>18}{'return':>16}{'wall s':>9}")
    for with_rfsas in (False, True):
        t0 = time.perf_counter()
        rates, rets = [], []
        for seed in SEEDS:
            rate, ret = run(with_rfsas, seed)
            rates.append(rate)
            rets.append(ret)
        name = "Kinematics + RF-SAS" if with_rfsas else "Kinematics only"
        print(f"{name:<24}{mean_se(rates):>18}{mean_se(rets):>16}{time.perf_counter() - t0:>9.0f}")


if __name__ == "__main__":
    main()
