"""Learning to brake: the full PPO run and the learned policy next to the rule.

    python bench/bench_rl.py [--steps 40000] [--episodes 100] [--out out/rl] [--docs]

Trains PPO (MlpPolicy, seed 0, batch_size 64, ent_coef 0.0, learning_rate
3e-4, n_epochs 10, n_steps 64) on ``rfsas/Intersection-v0`` at the default
(low) level of detail with the default reward (+1 for braking above the risk
threshold, +1 for accelerating below it), one torch thread. The goal is a
training run of at most 3 minutes on one CPU core; training stops at 175 s
whatever the step count, and the table says how many steps were done.

Then the learned policy, the rule a user would write instead (brake while the
estimated risk is above the threshold, else hold speed) and a car that ignores
warnings (hold speed) drive the same episodes (same seeds) at reaction
distances 40–100 m. Printed per distance: probability of collision, mean
fatality risk of the collisions, risk per episode, and the relative risk
reduction ``1 − R_learned/R_rule`` (pooled over distances by summed risk).

With ``--docs`` it also writes ``docs/images/rl_eval.png`` (the three measures
against distance) and ``docs/images/rl_frame.png`` (one rendered frame).

Needs the ``rl`` extra (``make rl``); without stable-baselines3 it says so and
exits cleanly. Timings are from this one run on a machine that may be shared.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from rfsas_hw.envs.envconfig import EnvConfig, env_config_from_mapping
from rfsas_hw.envs.rl import (
    HoldPolicy,
    LearnedPolicy,
    RulePolicy,
    evaluate,
    plot,
    risk_reduction,
    train,
    write_csv,
)

GOAL_TRAIN_S = 180.0
BUDGET_S = 175.0
DISTANCES = [40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0]
REPO = Path(__file__).resolve().parent.parent


def fmt(x: float, digits: int = 3) -> str:
    return "  —  " if math.isnan(x) else f"{x:.{digits}f}"


def write_frame(model: LearnedPolicy, path: Path) -> None:
    """One frame of the learned policy's episode at medium detail (lines of bearing visible)."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    from PIL import Image

    from rfsas_hw.envs.env import IntersectionEnv

    config = env_config_from_mapping({"sensing": {"detail": "medium"}})
    env = IntersectionEnv(config, render_mode="rgb_array")
    obs, _ = env.reset(seed=2, options={"reaction_distance_m": 70.0})
    frame = env.render()
    while True:
        obs, _, term, trunc, info = env.step(model.act(obs))
        if (env.warned and info["distance_m"] < 30.0) or term or trunc:
            frame = env.render()
            break
    env.close()
    assert frame is not None
    Image.fromarray(frame).save(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=40_000, help="PPO steps (default 40000)")
    ap.add_argument("--episodes", type=int, default=100, help="episodes per policy and distance")
    ap.add_argument("--out", type=Path, default=REPO / "out" / "rl", help="model, logs, CSV")
    ap.add_argument(
        "--docs", action="store_true", help="write docs/images/rl_eval.png and rl_frame.png"
    )
    args = ap.parse_args()
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        print("stable-baselines3 is not installed: run `make rl` first; skipping")
        return 0

    config = EnvConfig()
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    result = train(
        args.steps,
        args.out / "model.zip",
        config=config,
        log_dir=args.out / "logs",
        max_seconds=BUDGET_S,
    )
    ok = "ok" if result.seconds <= GOAL_TRAIN_S else "OVER"
    print(
        f"training: {result.steps} of {args.steps} steps, {result.episodes} episodes in "
        f"{result.seconds:.1f} s ({result.steps / result.seconds:.0f} steps/s, "
        f"goal ≤ {GOAL_TRAIN_S:.0f} s: {ok}); model {result.model_path}"
    )
    learned = LearnedPolicy.load(result.model_path)
    t1 = time.perf_counter()
    rows = evaluate(
        [learned, RulePolicy(config.risk_threshold), HoldPolicy()],
        DISTANCES,
        args.episodes,
        config=config,
    )
    t_eval = time.perf_counter() - t1
    write_csv([r for r in rows if r.policy != "hold"], args.out / "eval.csv")
    per, pooled = risk_reduction(rows)
    by = {(r.distance_m, r.policy): r for r in rows}

    print(
        f"\n{args.episodes} episodes per policy and distance (same seeds for all), "
        f"threshold {config.risk_threshold:g}, evaluation {t_eval:.0f} s"
    )
    head = (
        f"{'dist m':>6} | {'learned P(coll)':>15} {'P_f':>6} {'risk':>14} | "
        f"{'rule P(coll)':>12} {'P_f':>6} {'risk':>14} | {'RRR':>6} | {'hold risk':>9}"
    )
    print(head)
    print("-" * len(head))
    for d in DISTANCES:
        a, b, h = by[(d, "learned")], by[(d, "rule")], by[(d, "hold")]
        rrr = per.get(d, math.nan)
        print(
            f"{d:6.0f} | {a.p_collision:15.2f} {fmt(a.p_fatality):>6} "
            f"{a.risk:7.4f} ± {a.risk_stderr:.4f} | {b.p_collision:12.2f} {fmt(b.p_fatality):>6} "
            f"{b.risk:7.4f} ± {b.risk_stderr:.4f} | "
            f"{'  —' if math.isnan(rrr) else f'{rrr:+6.0%}'} | {h.risk:9.4f}"
        )
    mean_t = {
        p: np.mean([r.mean_time_s for r in rows if r.policy == p]) for p in ("learned", "rule")
    }
    print(
        f"\nrisk reduction over all distances (summed risks): {pooled:+.0%}; "
        f"mean episode time learned {mean_t['learned']:.2f} s, rule {mean_t['rule']:.2f} s"
    )
    print(f"wrote {args.out / 'eval.csv'}; total {time.perf_counter() - t0:.0f} s")
    if args.docs:
        img = REPO / "docs" / "images"
        img.mkdir(parents=True, exist_ok=True)
        plot([r for r in rows if r.policy != "hold"], img / "rl_eval.png")
        write_frame(learned, img / "rl_frame.png")
        print(f"wrote {img / 'rl_eval.png'} and {img / 'rl_frame.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
