"""Train TripleSumo agents with RLlib PPO (new API stack) on a local Ray.

Two runs (see docs/ray-rllib.md):

- the paper's setup (default): Bug learns; Ant and Spider are the shipped zoo policies,
  frozen (acting inside the env with the zoo's numpy policies: RLlib holds Bug only)::

      python examples/rllib_bug_ppo.py --iterations 50

- self-play: one module for the team (Ant and Bug share it) against a Spider module,
  both learning::

      python examples/rllib_bug_ppo.py --self-play --iterations 50

Each iteration prints env steps, env steps/s (sampling and learning together), the
outcome rates of each side over the last 100 episodes and the modules' mean episode
returns; the last line is the run's mean env steps/s. ``--sample-only N`` instead times
RLlib sampling N env steps in the driver (no learning), the ceiling for training.
``--json`` prints one JSON object per iteration instead; ``--out DIR`` saves an RLlib
checkpoint at the end (``Algorithm.from_checkpoint(DIR)``).
Needs the ``ray`` extra: ``pip install "triplesumo[ray]"``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--self-play", action="store_true", help="team module vs spider module, both learning")
    p.add_argument("--iterations", type=int, default=20, help="training iterations (default 20)")
    p.add_argument("--batch", type=int, default=4000, help="env steps per iteration (train_batch_size_per_learner)")
    p.add_argument("--minibatch", type=int, default=500, help="PPO minibatch size")
    p.add_argument("--epochs", type=int, default=10, help="PPO epochs over each batch")
    p.add_argument("--lr", type=float, default=3e-4, help="learning rate")
    p.add_argument("--env-runners", type=int, default=0, help="remote env runners (0: sample in the driver)")
    p.add_argument("--max-steps", type=int, default=500, help="match step limit (the paper's 500)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--num-cpus", type=int, default=None, help="CPUs given to the local Ray (default: all)")
    p.add_argument("--out", type=Path, default=None, help="save an RLlib checkpoint here at the end")
    p.add_argument("--json", action="store_true", help="one JSON object per iteration")
    p.add_argument("--sample-only", type=int, default=0, metavar="N",
                   help="only time sampling N env steps in the driver (needs --env-runners 0)")
    args = p.parse_args(argv)
    for name in ("iterations", "batch", "minibatch", "epochs", "max_steps"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1")
    if args.env_runners < 0:
        p.error("--env-runners must be >= 0")
    if args.sample_only < 0 or (args.sample_only and args.env_runners):
        p.error("--sample-only must be >= 0 and needs --env-runners 0")
    return args


def build(args: argparse.Namespace) -> Any:
    from triplesumo.integrations.rllib import make_config

    if args.self_play:
        config = make_config("paper", share="team", policies_to_train=["team", "spider"], max_steps=args.max_steps,
                             obs_mode="egocentric")  # one network for two seats needs seat-own observations
    else:
        config = make_config("paper", policies_to_train=["bug"], frozen={"ant": "zoo:ant", "spider": "zoo:spider"},
                             max_steps=args.max_steps)
    return (config
            .env_runners(num_env_runners=args.env_runners)
            .training(train_batch_size_per_learner=args.batch, minibatch_size=args.minibatch,
                      num_epochs=args.epochs, lr=args.lr)
            .debugging(seed=args.seed)
            .build_algo())


def summarise(it: int, result: dict[str, Any], wall: float) -> dict[str, Any]:
    runners = result.get("env_runners", {})
    steps = int(runners.get("num_env_steps_sampled", 0))
    outcomes = runners.get("outcomes", {})
    return {
        "iteration": it,
        "env_steps_total": int(runners.get("num_env_steps_sampled_lifetime", 0)),
        "env_steps_per_s": steps / wall if wall > 0 else None,
        "episodes": int(runners.get("num_episodes", 0)),
        "team_win": outcomes.get("bug", {}).get("win"),
        "spider_win": outcomes.get("spider", {}).get("win"),
        "draw": outcomes.get("bug", {}).get("draw"),
        "returns": {m: float(v) for m, v in runners.get("module_episode_returns_mean", {}).items()},
    }


def sample_only(algo: Any, args: argparse.Namespace) -> None:
    """Time the driver's env runner sampling ``args.sample_only`` env steps (acting, no learning)."""
    runner = algo.env_runner
    runner.sample(num_timesteps=min(200, args.sample_only), explore=True)  # warm-up
    start = time.perf_counter()
    episodes = runner.sample(num_timesteps=args.sample_only, explore=True)
    wall = time.perf_counter() - start
    steps = sum(e.env_steps() for e in episodes)
    row = {"sample_only_env_steps": steps, "seconds": wall, "env_steps_per_s": steps / wall}
    print(json.dumps(row) if args.json else f"sampling only: {steps} env steps in {wall:.1f} s = "
          f"{steps / wall:.0f} env steps/s")


def _fmt(x: float | None, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    import ray

    ray.init(num_cpus=args.num_cpus, include_dashboard=False, log_to_driver=False)
    algo = None
    try:
        algo = build(args)
        if args.sample_only:
            sample_only(algo, args)
            return
        if not args.json:
            print(f"{'iter':>4} {'env steps':>10} {'steps/s':>8} {'eps':>4} "
                  f"{'team win':>8} {'spider win':>10} {'draw':>5}  mean returns")
        total_wall = 0.0
        for it in range(1, args.iterations + 1):
            start = time.perf_counter()
            result = algo.train()
            wall = time.perf_counter() - start
            total_wall += wall
            row = summarise(it, result, wall)
            if args.json:
                print(json.dumps(row), flush=True)
            else:
                returns = " ".join(f"{m}={v:.0f}" for m, v in sorted(row["returns"].items()))
                print(f"{it:>4} {row['env_steps_total']:>10} {_fmt(row['env_steps_per_s'], '8.0f')} "
                      f"{row['episodes']:>4} "
                      f"{_fmt(row['team_win'], '8.2f')} {_fmt(row['spider_win'], '10.2f')} "
                      f"{_fmt(row['draw'], '5.2f')}  {returns}", flush=True)
        if not args.json:
            print(f"mean: {row['env_steps_total'] / total_wall:.0f} env steps/s over {total_wall:.0f} s")
        if args.out is not None:
            path = algo.save_to_path(str(args.out.resolve()))
            print(f"checkpoint: {path}")
    finally:
        if algo is not None:
            algo.stop()
        ray.shutdown()


if __name__ == "__main__":
    main()
