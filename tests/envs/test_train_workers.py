"""``sim train --seeds`` on the project's runner: the same models with 0, 1 and 2 workers."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("gymnasium", reason="needs the sim extra: pip install 'rfsas-hw[sim]'")

from rfsas_hw.envs.envconfig import env_config_from_mapping
from rfsas_hw.envs.protocol import seed_model_path, train_seeds

SEEDS = [7, 3]


def _weights(path: Path) -> dict[str, Any]:
    from stable_baselines3 import PPO

    return {k: v.numpy() for k, v in PPO.load(str(path), device="cpu").policy.state_dict().items()}


def _same(a: dict[str, Any], b: dict[str, Any]) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


@pytest.mark.slow
def test_seeds_train_the_same_models_with_0_1_and_2_workers(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3", reason="stable-baselines3 is not installed (make rl)")
    pytest.importorskip("distributed", reason="needs the ncap extra: pip install 'rfsas-hw[ncap]'")
    config = env_config_from_mapping({"scenario": {"kind": "corners"}})
    kw: dict[str, Any] = {"config": config, "n_envs": 2, "n_steps": 32, "batch_size": 32}
    done: list[int] = []
    runs = {}
    for workers in (0, 1, 2):
        model = tmp_path / f"w{workers}" / "m.zip"
        on_seed = (lambda s, r: done.append(s)) if workers == 2 else None
        runs[workers] = train_seeds(SEEDS, 128, model, workers=workers, on_seed=on_seed, **kw)
        assert [r.model_path for r in runs[workers]] == [seed_model_path(model, s) for s in SEEDS]
        assert all(r.steps == 128 for r in runs[workers])
    assert sorted(done) == sorted(SEEDS)
    weights = {w: [_weights(r.model_path) for r in rs] for w, rs in runs.items()}
    for k in range(len(SEEDS)):
        assert _same(weights[0][k], weights[1][k]) and _same(weights[0][k], weights[2][k])
    assert not _same(weights[2][0], weights[2][1])  # the seeds do differ
    logs = runs[2][1].model_path.with_name("m-seed-3-logs")
    assert (logs / "env-1.monitor.csv").is_file()
