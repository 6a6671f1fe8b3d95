"""``triplesumo bench train``: training speed against the env alone and against SB3, in one run.

Variants, all on the same collection setup (``n_envs`` matches in a
:class:`~triplesumo.envs.batch.MatchBatch` on ``n_threads`` threads, learner Bug, the
other agents following ``policies``):

``env_only``
    The trainer's collection step with learning switched off (the learner acts at
    random): physics, rules, observations, replay writes. The ceiling for training.
``train_paper``
    The trainer at the paper preset: DDPG with hidden 512/256, batch 64, one gradient
    step every 30 collected transitions (``learn_every=30``, ``gradient_steps=1``),
    after its warm-up. Target: >= 0.7 x ``env_only``.
``train_every_step``
    The same with one gradient step per collected transition (``learn_every=1``), the
    other reading of "update stride"; measured on ``steps // 10`` env steps. It is what
    decided the paper preset: see the projected hours in the table.
``sb3_ddpg``
    Stable-Baselines3's DDPG on the Gymnasium view of the same match (one env), the same
    networks, batch, and schedule (``train_freq=30`` steps, ``gradient_steps=1``),
    after its warm-up. Target: ``train_paper`` >= 1.6 x ``sb3_ddpg``. Skipped when SB3
    is not installed.

Warm-ups (``learning_starts`` transitions) run before timing. The variants take turns
in chunks of about ``chunk`` env steps for ``rounds`` rounds; a rate is the median over
rounds. The time split comes from the trainer's own timers: collecting (physics and
rules), acting, and waiting for the updates that ran in a thread beside the physics;
``learning_busy`` is how much of the wall time that thread computed. The
projected wall time of the paper's 20,000 epochs uses the mean epoch length measured in
``train_paper`` and, as an upper bound, 500 steps per epoch.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.benchmarks import report
from triplesumo.benchmarks.env import _versions
from triplesumo.train.config import TrainConfig
from triplesumo.train.loop import Trainer

TARGET_VS_ENV = 0.7
TARGET_VS_SB3 = 1.6
PAPER_EPOCHS = 20_000


class _TrainerVariant:
    def __init__(self, cfg: TrainConfig, run_dir: Path, warm_up_steps: int) -> None:
        self.trainer = Trainer(cfg, run_dir=run_dir)
        self.warm_up_steps = warm_up_steps

    def warm_up(self) -> None:
        while self.trainer.env_steps < self.warm_up_steps:
            self.trainer.collect_step()

    def run(self, steps: int) -> tuple[int, float]:
        start_steps, t0 = self.trainer.env_steps, time.perf_counter()
        while self.trainer.env_steps - start_steps < steps:
            self.trainer.collect_step()
        return self.trainer.env_steps - start_steps, time.perf_counter() - t0


class _SB3Variant:
    def __init__(self, policies: tuple[str, ...], seed: int, learning_starts: int) -> None:
        from stable_baselines3 import DDPG as SB3DDPG
        from stable_baselines3.common.noise import OrnsteinUhlenbeckActionNoise

        from triplesumo.agents.zoo import policies_from_pairs
        from triplesumo.envs.single import TripleSumoEnv

        env = TripleSumoEnv(learner="bug", policies=policies_from_pairs(policies, seed, "paper"))
        paper = DDPGConfig()
        noise = OrnsteinUhlenbeckActionNoise(np.zeros(8), paper.noise_sigma * np.ones(8), theta=paper.noise_theta)
        self.model = SB3DDPG(
            "MlpPolicy", env, learning_rate=paper.critic_lr, buffer_size=paper.buffer_size,
            learning_starts=learning_starts, batch_size=paper.batch_size, tau=paper.tau, gamma=paper.gamma,
            train_freq=(paper.learn_every, "step"), gradient_steps=paper.gradient_steps, action_noise=noise,
            policy_kwargs={"net_arch": list(paper.hidden), "activation_fn": torch.nn.LeakyReLU},
            seed=seed, device="cpu", verbose=0,
        )
        self.learning_starts = learning_starts

    def warm_up(self) -> None:
        self.model.learn(total_timesteps=self.learning_starts, reset_num_timesteps=False)

    def run(self, steps: int) -> tuple[int, float]:
        t0 = time.perf_counter()
        self.model.learn(total_timesteps=steps, reset_num_timesteps=False)
        return steps, time.perf_counter() - t0


def run_train_benchmark(steps: int = 6000, n_envs: int = 16, n_threads: int = 1, rounds: int = 3,
                        chunk: int = 2000, policies: tuple[str, ...] = ("ant=random", "spider=random"),
                        seed: int = 0, learning_starts: int = 1000, sb3: bool = True) -> dict[str, Any]:
    """Measure env-only, paper-preset training and (optionally) SB3 DDPG; returns a JSON-able dict."""
    torch.set_num_threads(1)
    base = TrainConfig(name="bench", policies=policies, n_envs=n_envs, n_threads=n_threads, seed=seed,
                       progress=False, tensorboard=False, save_replay=False, epochs=10**9)
    tmp = tempfile.TemporaryDirectory(prefix="triplesumo-bench-")
    root = Path(tmp.name)
    variants: dict[str, Any] = {
        "env_only": _TrainerVariant(
            TrainConfig(**{**base.__dict__, "ddpg": DDPGConfig(learning_starts=10**12)}), root / "env",
            learning_starts),
        "train_paper": _TrainerVariant(
            TrainConfig(**{**base.__dict__, "ddpg": DDPGConfig(learning_starts=learning_starts)}), root / "train",
            learning_starts),
    }
    variants["train_every_step"] = _TrainerVariant(
        TrainConfig(**{**base.__dict__, "ddpg": DDPGConfig(learning_starts=learning_starts, learn_every=1)}),
        root / "train1", learning_starts)
    budget = {name: steps for name in variants}
    budget["train_every_step"] = max(steps // 10, 1)
    sb3_status = "measured"
    if sb3:
        try:
            variants["sb3_ddpg"] = _SB3Variant(policies, seed, learning_starts)
            budget["sb3_ddpg"] = steps
        except ImportError:
            sb3_status = "stable-baselines3 not installed"
    else:
        sb3_status = "skipped"
    for v in variants.values():
        v.warm_up()
    trainer = variants["train_paper"].trainer
    timers0 = dict(trainer.timers)
    epochs0 = trainer.epochs_done
    per_round: dict[str, list[float]] = {name: [] for name in variants}
    load_before = os.getloadavg()
    for _ in range(rounds):
        done = dict.fromkeys(variants, 0)
        spent = dict.fromkeys(variants, 0.0)
        while any(done[name] < budget[name] for name in variants):
            for name, variant in variants.items():
                if done[name] < budget[name]:
                    n, seconds = variant.run(min(chunk, budget[name] - done[name]))
                    done[name] += n
                    spent[name] += seconds
        for name in variants:
            per_round[name].append(done[name] / spent[name])
    rates = {name: float(np.median(r)) for name, r in per_round.items()}
    spent = {k: trainer.timers[k] - timers0[k] for k in timers0}
    wall = spent["env"] + spent["act"] + spent["wait"]
    epochs = trainer.epochs_done - epochs0
    finished_steps = trainer.finished_epoch_steps[epochs0:]
    mean_epoch = float(np.mean(finished_steps)) if finished_steps else None
    ratios = {"train_vs_env": rates["train_paper"] / rates["env_only"]}
    if "sb3_ddpg" in rates:
        ratios["train_vs_sb3"] = rates["train_paper"] / rates["sb3_ddpg"]
    result = {
        "setup": {"steps": steps, "rounds": rounds, "chunk": chunk, "n_envs": n_envs, "n_threads": n_threads,
                  "policies": list(policies), "seed": seed, "learning_starts": learning_starts,
                  "paper_schedule": {"learn_every": 30, "gradient_steps": 1, "batch_size": 64, "hidden": [512, 256]},
                  "cpu_count": os.cpu_count(), "usable_cpus": len(os.sched_getaffinity(0)),
                  "load_average_before": list(load_before), "versions": _versions(), "sb3": sb3_status},
        "rates": rates,
        "ratios": ratios,
        "time_split": {"env": spent["env"] / wall, "act": spent["act"] / wall,
                       "wait_for_learning": spent["wait"] / wall},
        "learning_busy": spent["learn"] / wall,
        "updates_per_1000_steps": 1000 / 30,
        "mean_epoch_steps": mean_epoch,
        "epochs_measured": epochs,
        "projected_hours_20000_epochs": {
            "at_measured_epoch_length": (PAPER_EPOCHS * mean_epoch / rates["train_paper"] / 3600
                                         if mean_epoch else None),
            "at_500_steps_per_epoch": PAPER_EPOCHS * 500 / rates["train_paper"] / 3600,
            "every_step_at_measured_epoch_length": (PAPER_EPOCHS * mean_epoch / rates["train_every_step"] / 3600
                                                    if mean_epoch else None),
            "every_step_at_500_steps_per_epoch": PAPER_EPOCHS * 500 / rates["train_every_step"] / 3600,
        },
        "targets": {"train_vs_env": TARGET_VS_ENV, "train_vs_sb3": TARGET_VS_SB3},
    }
    for v in variants.values():
        if isinstance(v, _TrainerVariant):
            v.trainer.log.close()
    tmp.cleanup()
    return result


def format_table(result: dict[str, Any]) -> str:
    s, rates, ratios = result["setup"], result["rates"], result["ratios"]
    lines = [
        f"TripleSumo training benchmark: {s['n_envs']} matches on {s['n_threads']} threads, others {s['policies']}; "
        f"median of {s['rounds']} rounds x {s['steps']} env steps, interleaved in chunks of {s['chunk']}",
        f"paper preset: hidden 512/256, batch 64, 1 gradient step per 30 transitions; "
        f"torch 1 thread; SB3: {s['sb3']}",
        "",
        f"{'variant':34s} {'env steps/s':>11s} {'vs env only':>11s}",
    ]
    labels = {"env_only": "env alone (collection, no learning)", "train_paper": "training, paper preset",
              "sb3_ddpg": "Stable-Baselines3 DDPG, same schedule",
              "train_every_step": "training, 1 update per step"}
    for name, rate in rates.items():
        lines.append(f"{labels[name]:34s} {rate:11.0f} {rate / rates['env_only']:11.2f}")
    split = result["time_split"]
    lines += ["", "time split of training (wall): " + ", ".join(f"{k} {100 * v:.0f}%" for k, v in split.items())
              + f"; the update thread was busy {100 * result['learning_busy']:.0f}% of it (overlapping env)",
              f"train / env alone: {ratios['train_vs_env']:.2f} (target >= {TARGET_VS_ENV}: "
              f"{'met' if ratios['train_vs_env'] >= TARGET_VS_ENV else 'NOT met'})"]
    if "train_vs_sb3" in ratios:
        lines.append(f"train / SB3 DDPG: {ratios['train_vs_sb3']:.2f} (target >= {TARGET_VS_SB3}: "
                     f"{'met' if ratios['train_vs_sb3'] >= TARGET_VS_SB3 else 'NOT met'})")
    p = result["projected_hours_20000_epochs"]
    if p["at_measured_epoch_length"] is not None:
        lines.append(f"projected wall time of 20,000 epochs at the measured {result['mean_epoch_steps']:.0f} "
                     f"steps/epoch ({result['epochs_measured']} epochs): {p['at_measured_epoch_length']:.1f} h; "
                     f"with 1 update per step: {p['every_step_at_measured_epoch_length']:.1f} h")
    lines.append(f"projected wall time of 20,000 epochs at 500 steps/epoch: {p['at_500_steps_per_epoch']:.1f} h; "
                 f"with 1 update per step: {p['every_step_at_500_steps_per_epoch']:.1f} h")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="triplesumo bench train", description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=6000, help="env steps per variant and round (default: 6000)")
    parser.add_argument("--envs", type=int, default=16, help="matches collected at once (default: 16)")
    parser.add_argument("--threads", type=int, default=1, help="MuJoCo threads (default: 1, the trainer's)")
    parser.add_argument("--rounds", type=int, default=3, help="repetitions; the median is reported (default: 3)")
    parser.add_argument("--chunk", type=int, default=2000, help="env steps per turn of a variant (default: 2000)")
    parser.add_argument("--policies", nargs="*", default=["ant=random", "spider=random"],
                        help="AGENT=POLICY of the other agents (default: ant=random spider=random)")
    parser.add_argument("--no-sb3", action="store_true", help="skip the Stable-Baselines3 comparison")
    parser.add_argument("--seed", type=int, default=0, help="seed (default: 0)")
    parser.add_argument("--json", metavar="PATH", default=None, help="also write the results as JSON to PATH")
    parser.add_argument("--quick", action="store_true", help="tiny sizes (a smoke test, not a measurement)")
    args = parser.parse_args(argv)
    learning_starts = 1000
    if args.quick:
        args.steps, args.envs, args.rounds, args.chunk, learning_starts = 64, 2, 1, 32, 32
    result = run_train_benchmark(steps=args.steps, n_envs=args.envs, n_threads=args.threads, rounds=args.rounds,
                                 chunk=args.chunk, policies=tuple(args.policies), seed=args.seed,
                                 learning_starts=learning_starts, sb3=not args.no_sb3)
    report(format_table(result), result, args.json)
    return 0
