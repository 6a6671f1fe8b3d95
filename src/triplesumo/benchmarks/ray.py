"""``triplesumo bench ray``: how the project's own work scales over Ray, in one run.

Measured on a local Ray of ``num_cpus`` CPUs (one ``ray.init`` for the whole run; its
start is not timed), env steps per second of wall time:

``sweep_1`` / ``sweep_2``
    A sweep (:func:`~triplesumo.integrations.ray_tasks.run_trials_on_ray`) of 1 trial, then
    of 2 trials (seeds), each a ``triplesumo train`` run of ``epochs`` epochs of at most
    ``steps`` steps: Bug learning with DDPG (paper networks) against the zoo's Ant and
    Spider. Env steps are the trials' own (their ``metrics.csv``); the wall time includes
    Ray's scheduling and each trial's set-up (a warm-up trial first imports torch in the
    workers).
``evaluate_local`` / ``evaluate_ray``
    ``eval_epochs`` test epochs of the zoo's Bug against the zoo's Ant and Spider, played
    locally as ``triplesumo evaluate`` does (16 matches at once on 2 MuJoCo threads), then
    as Ray tasks of ``eval_epochs / 4`` epochs (``evaluate --ray``). The rows are checked
    equal.

``rllib_ppo`` / ``trainer_ppo`` (with ``--rllib``)
    Bug learning PPO against the zoo's Ant and Spider for the same budget of ``ppo_steps``
    env steps on the same schedule: updates on batches of 2,000 transitions (fewer for a tiny
    budget), 4 minibatches, 10 epochs each. RLlib's PPO (:func:`~triplesumo.integrations.rllib.make_config`,
    sampling in the driver, its default networks) against ``triplesumo train --learn
    bug=ppo`` (16 matches x 125 steps per rollout, the project's PPO networks); wall time of
    sampling and learning together, build and warm-up untimed.

From the measured rates, per-core figures (``sweep_2`` and ``evaluate_ray`` over
``num_cpus``) and a **projection** to ``cores`` cores (default 64): the per-core rate
times the cores. It is arithmetic, not a measurement: it assumes every core runs as fast
as one here and that scheduling, the network and shared storage cost nothing.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from triplesumo.benchmarks import report, versions

OTHERS = {"ant": "zoo:ant", "spider": "zoo:spider"}


def _trial_steps(run_dir: str) -> int:
    with (Path(run_dir) / "metrics.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    return int(rows[-1]["env_steps"]) if rows else 0


def _ppo_batch(budget: int) -> int:
    """Transitions per PPO update in both rows: 2,000 (a multiple of the 16 matches), fewer for tiny budgets."""
    return max(16, min(2000, budget) // 16 * 16)


def _rllib_ppo(budget: int, seed: int) -> dict[str, Any]:
    """RLlib PPO on the paper match (Bug learns, zoo Ant and Spider frozen) for ``budget`` env steps."""
    from triplesumo.integrations.rllib import make_config

    algo = (make_config("paper", policies_to_train=["bug"], frozen=OTHERS)
            .env_runners(num_env_runners=0)
            .training(train_batch_size_per_learner=_ppo_batch(budget), minibatch_size=_ppo_batch(budget) // 4,
                      num_epochs=10)
            .debugging(seed=seed)
            .build_algo())
    try:
        done, wall = 0, 0.0
        while done < budget:
            start = time.perf_counter()
            result = algo.train()
            wall += time.perf_counter() - start
            done = int(result["env_runners"]["num_env_steps_sampled_lifetime"])
    finally:
        algo.stop()
    return {"env_steps": done, "seconds": wall, "env_steps_per_s": done / wall}


def _trainer_ppo(budget: int, seed: int, out: str) -> dict[str, Any]:
    """``triplesumo train --learn bug=ppo`` against the zoo's Ant and Spider for ``budget`` env steps."""
    from triplesumo.algos.ppo import PPOConfig
    from triplesumo.train.config import TrainConfig
    from triplesumo.train.loop import Trainer

    cfg = TrainConfig(name="ppo", out=out, learn=("bug=ppo",), policies=tuple(f"{a}={s}" for a, s in OTHERS.items()),
                      n_envs=16, seed=seed, progress=False, tensorboard=False, checkpoint_every=10**6,
                      ppo=PPOConfig(n_steps=_ppo_batch(budget) // 16, n_minibatches=4, n_epochs=10))
    trainer = Trainer(cfg)
    try:
        start = time.perf_counter()
        while trainer.collector.env_steps < budget:
            trainer.step()
        wall = time.perf_counter() - start
    finally:
        trainer.log.close()
        trainer.collector.env.close()
    steps = trainer.collector.env_steps
    return {"env_steps": steps, "seconds": wall, "env_steps_per_s": steps / wall}


def run_ray_benchmark(epochs: int = 24, steps: int = 300, eval_epochs: int = 32, num_cpus: int = 2,
                      cores: int = 64, seed: int = 0, ppo_steps: int = 0) -> dict[str, Any]:
    """Measure the variants of the module docstring; returns rates, per-core figures and the projection."""
    import ray

    from triplesumo.evaluation.evaluate import play_test_epochs
    from triplesumo.integrations import ray_tasks
    from triplesumo.rules.config import MatchConfig
    from triplesumo.train.config import TrainConfig

    result: dict[str, Any] = {"config": {"epochs": epochs, "steps": steps, "eval_epochs": eval_epochs,
                                         "num_cpus": num_cpus, "cores": cores, "seed": seed},
                              "machine": {"cpus": os.cpu_count(), "load_avg": os.getloadavg()[0]},
                              "versions": {**versions(), "ray": ray.__version__}, "variants": {}}
    with tempfile.TemporaryDirectory() as tmp, ray_tasks.session("", num_cpus):
        base = TrainConfig(out=tmp, epochs=epochs, steps_per_epoch=steps, n_envs=8, progress=False,
                           tensorboard=False, checkpoint_every=max(epochs, 1), save_replay=False, seed=seed)
        warm = [dataclasses.replace(base, name=f"warm{k}", epochs=2, steps_per_epoch=20) for k in range(num_cpus)]
        ray_tasks.run_trials_on_ray(warm)
        for n in (1, 2):
            configs = [dataclasses.replace(base, name=f"sweep{n}-seed{k}", seed=seed + k) for k in range(n)]
            start = time.perf_counter()
            done = ray_tasks.run_trials_on_ray(configs)
            wall = time.perf_counter() - start
            bad = [d["error"] for d in done if "error" in d]
            if bad:
                raise RuntimeError(f"a benchmark trial failed: {bad[0]}")
            env_steps = sum(_trial_steps(d["run_dir"]) for d in done)
            result["variants"][f"sweep_{n}"] = {"trials": n, "env_steps": env_steps, "seconds": wall,
                                                "env_steps_per_s": env_steps / wall}
        match_cfg = MatchConfig(max_steps=500)
        ray_tasks.play_test_epochs_on_ray("zoo:bug", OTHERS, "bug", 2, seed, match_cfg, chunk=1)  # warm workers
        from triplesumo.agents.zoo import make_policy

        start = time.perf_counter()
        local = play_test_epochs(make_policy("zoo:bug"), {a: make_policy(s) for a, s in OTHERS.items()}, "bug",
                                 eval_epochs, seed, match_cfg, n_envs=16, n_threads=2)
        wall_local = time.perf_counter() - start
        start = time.perf_counter()
        remote = ray_tasks.play_test_epochs_on_ray("zoo:bug", OTHERS, "bug", eval_epochs, seed, match_cfg,
                                                   chunk=max(1, eval_epochs // 4), n_envs=8)
        wall_ray = time.perf_counter() - start
        if remote != local:
            raise RuntimeError("evaluate on Ray gave other rows than the local run")
        if ppo_steps:
            result["variants"]["rllib_ppo"] = _rllib_ppo(ppo_steps, seed)
            result["variants"]["trainer_ppo"] = _trainer_ppo(ppo_steps, seed, tmp)
        env_steps = sum(int(r["steps"]) for r in local)
        for name, wall in (("evaluate_local", wall_local), ("evaluate_ray", wall_ray)):
            result["variants"][name] = {"epochs": eval_epochs, "env_steps": env_steps, "seconds": wall,
                                        "env_steps_per_s": env_steps / wall}
    v = result["variants"]
    result["scaling"] = {"sweep_2_vs_1": v["sweep_2"]["env_steps_per_s"] / v["sweep_1"]["env_steps_per_s"],
                         "evaluate_ray_vs_local": (v["evaluate_ray"]["env_steps_per_s"]
                                                   / v["evaluate_local"]["env_steps_per_s"])}
    if ppo_steps:
        result["scaling"]["trainer_ppo_vs_rllib_ppo"] = (v["trainer_ppo"]["env_steps_per_s"]
                                                         / v["rllib_ppo"]["env_steps_per_s"])
    per_core = {"sweep": v["sweep_2"]["env_steps_per_s"] / num_cpus,
                "evaluate": v["evaluate_ray"]["env_steps_per_s"] / num_cpus}
    result["per_core"] = per_core
    result["projection"] = {"cores": cores, "note": "projection, not a measurement: per-core rate x cores",
                            "sweep_env_steps_per_s": per_core["sweep"] * cores,
                            "evaluate_env_steps_per_s": per_core["evaluate"] * cores}
    return result


def format_table(result: dict[str, Any]) -> str:
    """The readable table ``main`` prints."""
    c, v = result["config"], result["variants"]
    m = result["machine"]
    lines = [f"Ray on {c['num_cpus']} CPUs (machine: {m['cpus']} CPUs, load {m['load_avg']:.1f}); "
             f"train {c['epochs']} epochs x <= {c['steps']} steps per trial; evaluate {c['eval_epochs']} epochs",
             f"{'variant':16s} {'env steps':>10s} {'seconds':>8s} {'env steps/s':>12s}"]
    for name, row in v.items():
        lines.append(f"{name:16s} {row['env_steps']:10d} {row['seconds']:8.1f} {row['env_steps_per_s']:12.0f}")
    s, p = result["scaling"], result["projection"]
    lines += ["", f"sweep 2 trials / 1 trial: {s['sweep_2_vs_1']:.2f}x; evaluate --ray / local: "
                  f"{s['evaluate_ray_vs_local']:.2f}x"
              + (f"; our PPO trainer / RLlib PPO: {s['trainer_ppo_vs_rllib_ppo']:.2f}x"
                 if "trainer_ppo_vs_rllib_ppo" in s else ""),
              f"per core: sweep {result['per_core']['sweep']:.0f}, evaluate {result['per_core']['evaluate']:.0f} "
              "env steps/s",
              f"PROJECTION to {p['cores']} cores (per-core rate x cores, not measured): sweep "
              f"{p['sweep_env_steps_per_s']:,.0f}, evaluate {p['evaluate_env_steps_per_s']:,.0f} env steps/s"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="triplesumo bench ray", description=__doc__.split("\n\n")[0])
    parser.add_argument("--epochs", type=int, default=24, help="training epochs per trial (default: 24)")
    parser.add_argument("--steps", type=int, default=300, help="step limit of a training match (default: 300)")
    parser.add_argument("--eval-epochs", type=int, default=32, help="test epochs (default: 32)")
    parser.add_argument("--num-cpus", type=int, default=2, help="CPUs of the local Ray (default: 2)")
    parser.add_argument("--cores", type=int, default=64, help="cores of the projection (default: 64)")
    parser.add_argument("--seed", type=int, default=0, help="seed (default: 0)")
    parser.add_argument("--rllib", type=int, default=0, metavar="ENV_STEPS",
                        help="also RLlib PPO vs our PPO trainer on this many env steps each (0: skip)")
    parser.add_argument("--json", metavar="PATH", default=None, help="also write the results as JSON to PATH")
    parser.add_argument("--quick", action="store_true", help="tiny sizes (a smoke test, not a measurement)")
    args = parser.parse_args(argv)
    if args.quick:
        args.epochs, args.steps, args.eval_epochs = 2, 30, 4
    result = run_ray_benchmark(args.epochs, args.steps, args.eval_epochs, args.num_cpus, args.cores, args.seed,
                               args.rllib)
    report(format_table(result), result, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
