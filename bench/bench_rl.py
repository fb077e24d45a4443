"""Learning to slow down where phones have been heard: the learned-vs-rule protocol.

    python bench/bench_rl.py [--steps 150000] [--seeds 0,1,2,3,4] [--episodes 60]
                             [--ablation 30] [--jobs 2] [--out out/rl] [--docs]

Run time: see docs/simulation.md §10 (the command, its wall time and the
machine's load for the run whose numbers are there).

The ``corners`` scenario of ``rfsas/Intersection-v0`` (quiet and busy blind
corners; busy ones have a history of crossings and produce more late
crossers; a quarter of the crossers are never heard) at the default (low)
level of detail. Three arms, each trained with every seed on 8 vectorised
environments with the same PPO settings (n_steps 128 per environment, batch
256, ent_coef 0.01, lr 3e-4, 10 epochs) and the same number of steps:

- ``rp+prior``: reward ``risk-progress`` (risk_weight 20, 0.1 per second, 1
  for a timeout), RF activity prior in the observation;
- ``rp-noprior``: the same without the prior;
- ``method+prior``: the method's reward (+1 braking above the risk threshold,
  +1 accelerating below) with the prior.

Then every model, the rule (brake while the estimated risk is above the
threshold, else hold) and a car that ignores warnings drive the same
episodes (episode k has seed 10000 + k) at reaction distances 30–100 m from
the centre (70–0 m from the start line, the method's convention). Per
distance: mean risk, standard error over the seeds and over the episodes, a
paired t-test over the episodes (seed-averaged learned risk against the
rule's), seeds at or below the rule, episode time, timeouts, mean return.
Pooled ratio rule/learned over the distances where the rule cannot stop in
time. Per seed: the risk at every distance and the speed 20 m before the
centre without a warning.

Ablation: the same models on episodes without a warning (nobody crosses:
duration; a crosser who is never heard: risk), and the mean speed along the
approach at a busy and a quiet corner with and without a warning (60 m).

``--jobs`` trainings run in parallel processes (each one torch thread).
With ``--docs`` it writes ``docs/images/rl_eval.png`` and
``docs/images/rl_speed.png``. Needs the ``rl`` extra; without
stable-baselines3 it says so and exits cleanly. Timings are from one run
on a machine that may be shared.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from rfsas_hw.envs.envconfig import EnvConfig, env_config_from_mapping
from rfsas_hw.envs.protocol import (
    PairedRow,
    cannot_stop,
    compare,
    outcomes,
    plot_speed_profiles,
    pooled_ratio,
    seed_model_path,
    speed_profiles,
)
from rfsas_hw.envs.rl import HoldPolicy, LearnedPolicy, Policy, RulePolicy, train

REPO = Path(__file__).resolve().parent.parent
DISTANCES = [30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0]
N_ENVS = 8
TUNED = {"n_steps": 128, "batch_size": 256, "ent_coef": 0.01}
ARMS: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    "rp+prior": (
        {"reward": {"kind": "risk-progress"}, "prior": {"observe": True}},
        TUNED,
    ),
    "rp-noprior": (
        {"reward": {"kind": "risk-progress"}, "prior": {"observe": False}},
        TUNED,
    ),
    "method+prior": ({"reward": {"kind": "method"}, "prior": {"observe": True}}, TUNED),
}


ARMS_EVAL = {"rule": "rp-noprior"}
SPEED_EPISODES = 20


def arm_config(arm: str) -> EnvConfig:
    data, _ = ARMS[arm]
    return env_config_from_mapping({"scenario": {"kind": "corners"}, **data})


def train_one(job: tuple[str, int, int, str]) -> tuple[str, int, int, float]:
    arm, seed, steps, out = job
    _, ppo = ARMS[arm]
    path = seed_model_path(Path(out) / f"{arm}.zip", seed)
    r = train(
        steps,
        path,
        config=arm_config(arm),
        seed=seed,
        log_dir=path.with_name(path.stem + "-logs"),
        n_envs=N_ENVS,
        **ppo,
    )
    return arm, seed, r.steps, r.seconds


def eval_one(job: tuple[str, int, int, int, str]) -> dict[str, Any]:
    """Every evaluation of one model (or the rule): paired distances, ablation, speed."""
    arm, seed, episodes, n_abl, out = job
    config = arm_config(ARMS_EVAL.get(arm, arm))
    policy: Policy = (
        RulePolicy(config.risk_threshold)
        if arm == "rule"
        else LearnedPolicy.load(seed_model_path(Path(out) / f"{arm}.zip", seed))
    )
    res: dict[str, Any] = {
        "main": outcomes(policy, DISTANCES, episodes, config=config),
        "empty": {},
        "unheard": {},
        "speed": {},
    }
    for corner in ("busy", "quiet"):
        for kind, opts in (("empty", {"crosser": False}), ("unheard", {"heard": False})):
            res[kind][corner] = outcomes(
                policy, [None], n_abl, config=config, options={"corner": corner, **opts}
            )
        for label, opts2 in (
            ("no warning", {"crosser": False}),
            ("warning at 60 m", {"reaction_distance_m": 60.0}),
        ):
            res["speed"][f"{corner}, {label}"] = speed_profiles(
                policy,
                min(SPEED_EPISODES, n_abl),
                config=config,
                options={"corner": corner, **opts2},
            )
    return res


def per_seed(out: Path, seeds: list[int], arms: list[str], episodes: int) -> None:
    """Per seed, from the models of a finished run: risk at 30 and 40 m, and the speed
    20 m before the centre at a busy and a quiet corner without a warning (10 episodes)."""
    print("arm, seed | risk 30 m | risk 40 m | v(20 m) busy / quiet, no warning (m/s)")
    for arm in [a for a in arms if a.startswith("rp")]:
        cfg = arm_config(arm)
        for s in seeds:
            m = LearnedPolicy.load(seed_model_path(out / f"{arm}.zip", s))
            o = outcomes(m, [30.0, 40.0], episodes, config=cfg)
            v20 = []
            for corner in ("busy", "quiet"):
                g, v = speed_profiles(
                    m, 10, config=cfg, options={"corner": corner, "crosser": False}
                )
                v20.append(float(np.interp(20.0, g[::-1], v[::-1])))
            print(
                f"{arm} {s} | {o.risk[0].mean():.4f} | {o.risk[1].mean():.4f} | "
                f"{v20[0]:.1f} / {v20[1]:.1f}"
            )


def rule_return(arm: str, row: PairedRow) -> str:
    """The rule's mean return, under the arm's reward (the rule ran the risk-progress one)."""
    same = arm_config(arm).reward.kind == arm_config(ARMS_EVAL["rule"]).reward.kind
    return f"{row.baseline_return:.3f}" if same else "—"


def fmt(x: float, digits: int = 4) -> str:
    return "—" if math.isnan(x) else f"{x:.{digits}f}"


def print_table(arm: str, rows: list[PairedRow], start_m: float, stop: list[float]) -> float:
    print(f"\n{arm}: learned ({rows[0].seeds} seeds) vs rule, {rows[0].episodes} paired episodes")
    head = (
        f"{'d ctr':>5} {'d start':>7} | {'learned risk':>12} {'±SE seeds':>9} {'±SE eps':>8} "
        f"{'P(coll)':>7} | {'rule risk':>9} {'±SE':>7} {'P(coll)':>7} | {'p':>7} "
        f"{'seeds≤':>6} | {'t lrn':>5} {'t rule':>6} {'tmo':>4} | {'ret lrn':>7} {'ret rule':>8}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        print(
            f"{r.distance_m:5.0f} {start_m - r.distance_m:7.0f} | {r.risk:12.4f} "
            f"{fmt(r.risk_se_seeds):>9} {fmt(r.risk_se_episodes):>8} {r.p_collision:7.3f} | "
            f"{r.baseline_risk:9.4f} {fmt(r.baseline_se):>7} {r.baseline_p_collision:7.3f} | "
            f"{r.p_value:7.3g} {r.seeds_at_or_below:>4}/{r.seeds} | "
            f"{r.time_s:5.2f} {r.baseline_time_s:6.2f} {r.timeouts:4.0%} | "
            f"{r.mean_return:7.3f} {rule_return(arm, r):>8}"
        )
    ratio = pooled_ratio(rows, stop)
    at_or_below = all(r.risk <= r.baseline_risk for r in rows)
    print(
        f"pooled rule/learned where the rule cannot stop ({', '.join(f'{d:g}' for d in stop)} m): "
        f"{ratio:.2f}×; learned ≤ rule at every distance: {at_or_below}"
    )
    return ratio


def plot_eval(results: dict[str, list[PairedRow]], path: Path) -> None:
    from rfsas_hw.optional import pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
    first = next(iter(results.values()))
    d = [r.distance_m for r in first]
    ax.errorbar(d, [r.baseline_risk for r in first], [r.baseline_se for r in first],
                fmt="k--o", label="rule")  # fmt: skip
    for arm, rows in results.items():
        ax.errorbar(d, [r.risk for r in rows], [r.risk_se_seeds for r in rows], fmt="-o", label=arm)
    ax.set_yscale("symlog", linthresh=1e-4)
    ax.set_xlabel("reaction distance from the centre (m)")
    ax.set_ylabel("risk per episode")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(str(path), dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=150_000, help="PPO steps per seed and arm")
    ap.add_argument("--seeds", default="0,1,2,3,4", help="training seeds")
    ap.add_argument("--episodes", type=int, default=60, help="episodes per policy and distance")
    ap.add_argument("--ablation", type=int, default=30, help="episodes per corner, ablation")
    ap.add_argument("--jobs", type=int, default=2, help="processes for training and evaluation")
    ap.add_argument("--arms", default=",".join(ARMS), help="arms to run")
    ap.add_argument("--out", type=Path, default=REPO / "out" / "rl", help="models, logs, JSON")
    ap.add_argument(
        "--docs", action="store_true", help="write docs/images/rl_eval.png, rl_speed.png"
    )
    ap.add_argument(
        "--per-seed", action="store_true", help="only the per-seed table, from the models in --out"
    )
    args = ap.parse_args()
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        print("stable-baselines3 is not installed: run `make rl` first; skipping")
        return 0
    seeds = [int(s) for s in args.seeds.split(",")]
    arms = args.arms.split(",")
    if args.per_seed:
        per_seed(args.out, seeds, arms, args.episodes)
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    jobs = [(a, s, args.steps, str(args.out)) for a in arms for s in seeds]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        done = list(pool.map(train_one, jobs))
    t_train = time.perf_counter() - t0
    for arm, seed, steps, secs in done:
        print(f"trained {arm} seed {seed}: {steps} steps in {secs:.0f} s")
    print(f"training: {len(jobs)} runs, {t_train:.0f} s wall with {args.jobs} processes")

    t1 = time.perf_counter()
    base_config = arm_config(arms[0])
    start_m = base_config.vehicle.start_distance_m
    stop = [d for d in DISTANCES if cannot_stop(base_config, d)]
    # the rule ignores the prior entry: its episodes are the same in every arm
    eval_jobs = [("rule", 0, args.episodes, args.ablation, str(args.out))]
    eval_jobs += [(a, s, args.episodes, args.ablation, str(args.out)) for a in arms for s in seeds]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        evals = dict(
            zip([(j[0], j[1]) for j in eval_jobs], pool.map(eval_one, eval_jobs), strict=True)
        )
    t_eval = time.perf_counter() - t1
    base = evals[("rule", 0)]["main"]
    hold = outcomes(HoldPolicy(), DISTANCES[:1], args.episodes, config=base_config)
    results = {arm: compare([evals[(arm, s)]["main"] for s in seeds], base) for arm in arms}
    summary: dict[str, Any] = {
        "steps": args.steps,
        "seeds": seeds,
        "episodes": args.episodes,
        "ablation_episodes": args.ablation,
        "jobs": args.jobs,
        "train_s": t_train,
        "eval_s": t_eval,
        "hold_risk": float(hold.risk.mean()),
        "hold_p_collision": float(hold.collision.mean()),
        "arms": {},
    }
    print(
        f"\nevaluation and ablation {t_eval:.0f} s wall; a car ignoring warnings: risk "
        f"{hold.risk.mean():.4f} (P(coll) {hold.collision.mean():.3f}) at every distance"
    )
    for arm in arms:
        ratio = print_table(arm, results[arm], start_m, stop)
        summary["arms"][arm] = {
            "rows": [asdict(r) for r in results[arm]],
            "pooled_ratio_cannot_stop": ratio,
            "at_or_below_everywhere": all(r.risk <= r.baseline_risk for r in results[arm]),
        }

    print(f"\nwithout a warning ({args.ablation} episodes per corner; mean over the seeds)")
    print(
        f"{'arm':>13} {'corner':>6} | {'empty: t (s)':>12} {'tmo':>4} | "
        f"{'unheard: risk':>13} {'P(coll)':>7}"
    )
    ablation: dict[str, Any] = {}
    for name in ["rule", *arms]:
        keys = [("rule", 0)] if name == "rule" else [(name, s) for s in seeds]
        for corner in ("busy", "quiet"):
            t_empty = float(np.mean([evals[k]["empty"][corner].time_s.mean() for k in keys]))
            tmo = float(np.mean([evals[k]["empty"][corner].timeouts.mean() for k in keys]))
            r_un = float(np.mean([evals[k]["unheard"][corner].risk.mean() for k in keys]))
            c_un = float(np.mean([evals[k]["unheard"][corner].collision.mean() for k in keys]))
            ablation[f"{name}/{corner}"] = {
                "empty_time_s": t_empty,
                "empty_timeouts": tmo,
                "unheard_risk": r_un,
                "unheard_p_collision": c_un,
            }
            print(f"{name:>13} {corner:>6} | {t_empty:12.2f} {tmo:4.0%} | {r_un:13.4f} {c_un:7.3f}")
    summary["ablation"] = ablation

    curves: dict[str, tuple[Any, Any]] = {}
    for name in ["rule", *[a for a in arms if a.startswith("rp")]]:
        keys = [("rule", 0)] if name == "rule" else [(name, s) for s in seeds]
        for label in evals[keys[0]]["speed"]:
            grid = evals[keys[0]]["speed"][label][0]
            mean = np.mean([evals[k]["speed"][label][1] for k in keys], axis=0)
            curves[f"{name}, {label}"] = (grid, mean)
    summary["speed_at"] = {
        name: {f"{d:g}": float(np.interp(d, g[::-1], v[::-1])) for d in (80, 60, 40, 20, 5)}
        for name, (g, v) in curves.items()
    }
    print("\nmean speed (m/s) at distance to the centre")
    for name, at in summary["speed_at"].items():
        print(f"  {name:40s} " + " ".join(f"{d}m {v:5.2f}" for d, v in at.items()))
    print("\nper seed: risk at each distance; speed 20 m before the centre without a warning")
    per: dict[str, Any] = {}
    for arm in arms:
        for s in seeds:
            ev = evals[(arm, s)]
            v20 = {
                corner: float(
                    np.interp(20.0, *(x[::-1] for x in ev["speed"][f"{corner}, no warning"]))
                )
                for corner in ("busy", "quiet")
            }
            risks = [float(x) for x in ev["main"].risk.mean(axis=1)]
            per[f"{arm}/{s}"] = {"risk": risks, "v20_no_warning": v20}
            print(
                f"  {arm:>13} seed {s}: risk "
                + " ".join(f"{x:.4f}" for x in risks)
                + f" | v(20 m) busy {v20['busy']:.1f} quiet {v20['quiet']:.1f} m/s"
            )
    summary["per_seed"] = per
    summary["total_s"] = time.perf_counter() - t0
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    print(f"\nwrote {args.out / 'summary.json'}; total {summary['total_s']:.0f} s")
    if args.docs:
        img = REPO / "docs" / "images"
        img.mkdir(parents=True, exist_ok=True)
        plot_eval(results, img / "rl_eval.png")
        plot_speed_profiles(curves, img / "rl_speed.png")
        print(f"wrote {img / 'rl_eval.png'} and {img / 'rl_speed.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
