"""``triplesumo bench train``: training speed against the env alone and against SB3, in one run.

Variants, all on the same collection setup (``n_envs`` matches in a
:class:`~triplesumo.envs.batch.VectorMatches` on ``n_threads`` threads, learner Bug, the
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

``train_td3``, ``train_sac``, ``train_ppo``
    The trainer with Bug learning by TD3, SAC or PPO at their default networks and batch
    sizes, on one shared *algorithm schedule*: one gradient step per ``n_envs`` collected
    transitions for the off-policy ones (``learn_every = n_envs``), and for PPO rollouts of
    2,048 transitions (``n_steps = 2048 / n_envs``), 10 epochs of 32 minibatches.
``train_td3_bf16``, ``train_sac_bf16``
    TD3 and SAC on that schedule with their updates' matrix products in bfloat16
    (``update_dtype="bfloat16"``); their ratios against SB3 are against its float32 TD3 and SAC.
``train_3_learners``
    Ant (SAC), Bug (TD3) and Spider (PPO) learning at once on that schedule.
``sb3_td3``, ``sb3_sac``, ``sb3_ppo``
    Stable-Baselines3's same algorithm on one Gymnasium env, same networks, batch and
    schedule (``train_freq = n_envs`` steps; PPO ``n_steps = 2048``, batch 64, 10 epochs,
    the value update clipped as ours). The algorithm rows run ``algo_steps`` env steps per
    round; ``updates/s`` counts gradient steps (PPO: minibatch steps).

Every variant is also timed in CPU seconds of the whole process (its update thread
included): ``cpu_rates`` are env steps per CPU-second and ``cpu_ratios`` ours against SB3's
same algorithm on that basis. On a machine shared with other work the wall rates follow
the load; the CPU rates barely do, but they give no credit for running the updates beside
the physics (which pays off only when a core is free). ``update_profile_ms``
(:func:`update_profile`) is the thread CPU of one gradient step of each algorithm, ours
and SB3's, split into forward passes and the rest, backward, and Adam: where the time of
an update goes.

``--profile`` cuts one env step of the trainer into its parts instead, per learner, in thread CPU
(:mod:`~triplesumo.benchmarks.train_profile`).

``--backend warp --device DEV`` measures the trainer on MuJoCo Warp instead
(:func:`run_warp_train_benchmark`): ``env_only``, ``train_ddpg`` and ``train_ppo`` on a
massively parallel schedule (``n_envs`` matches, DDPG ``gradient_steps`` updates of
``batch_size`` per collection step, PPO rollouts of ``ppo_steps`` steps of every match),
observations, actions, replay and rollouts on the device. Warp's ``cpu`` device runs it
(a check that it works, no speed); GPU figures need a GPU.

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
import functools
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.ppo import PPOConfig
from triplesumo.algos.sac import SACConfig
from triplesumo.algos.td3 import TD3Config
from triplesumo.benchmarks import PPO_ROLLOUT, learner_configs, report, versions
from triplesumo.train.config import TrainConfig
from triplesumo.train.loop import Trainer

TARGET_VS_ENV = 0.7
TARGET_VS_SB3 = 1.6
PAPER_EPOCHS = 20_000
TARGET_ALGO_VS_ENV = 0.8
"""The ratio to the env alone the off-policy learners on the algorithm schedule are held to: the updates beside
collection should cost at most a fifth of the env's speed."""
BF16_ROWS = ("td3_bf16", "sac_bf16")
"""The algorithm rows with bfloat16 updates (keys of :func:`~triplesumo.benchmarks.learner_configs`)."""
ALGO_ROWS = ("td3", "sac", "ppo", *BF16_ROWS)
"""Every algorithm row, in the table's order."""


def _sb3_twin(algo: str) -> str:
    """The SB3 variant an algorithm row is compared with: its own algorithm's (SB3 has no bfloat16 updates)."""
    return f"sb3_{algo.removesuffix('_bf16')}"


def _label(algo: str) -> str:
    """An algorithm row's name in the table's verdict lines: ``SAC``, ``SAC (bfloat16 updates)``."""
    return algo.upper().replace("_BF16", " (bfloat16 updates)")


class _TrainerVariant:
    def __init__(self, cfg: TrainConfig, run_dir: Path, warm_up_steps: int) -> None:
        self.trainer = Trainer(cfg, run_dir=run_dir)
        self.warm_up_steps = warm_up_steps

    def gradient_steps(self) -> int:
        """Gradient steps so far, PPO's minibatch steps included."""
        total = 0
        for learner in self.trainer.learners:
            c = learner.config
            total += learner.algo.num_updates * (c.n_epochs * c.n_minibatches if learner.spec.algo == "ppo" else 1)
        return total

    def warm_up(self) -> None:
        while self.trainer.collector.env_steps < self.warm_up_steps:
            self.trainer.step()

    def run(self, steps: int) -> tuple[int, float]:
        start_steps, t0 = self.trainer.collector.env_steps, time.perf_counter()
        while self.trainer.collector.env_steps - start_steps < steps:
            self.trainer.step()
        return self.trainer.collector.env_steps - start_steps, time.perf_counter() - t0


class _SB3Variant:
    def __init__(self, algo: str, policies: tuple[str, ...], seed: int, learning_starts: int,
                 learn_every: int = 30) -> None:
        import stable_baselines3 as sb3
        from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

        from triplesumo.agents.zoo import policies_from_pairs
        from triplesumo.envs.single import TripleSumoEnv

        env = TripleSumoEnv(learner="bug", policies=policies_from_pairs(policies, seed, "paper"))
        common: dict[str, Any] = {"seed": seed, "device": "cpu", "verbose": 0}
        act = torch.nn.LeakyReLU
        self.algo = algo
        if algo == "ppo":
            c = PPOConfig()
            self.model: Any = sb3.PPO(
                "MlpPolicy", env, learning_rate=c.lr, n_steps=PPO_ROLLOUT, batch_size=PPO_ROLLOUT // c.n_minibatches,
                n_epochs=c.n_epochs, gamma=c.gamma, gae_lambda=c.gae_lambda, clip_range=c.clip_coef,
                ent_coef=c.ent_coef, vf_coef=c.vf_coef, max_grad_norm=c.max_grad_norm,
                clip_range_vf=c.clip_coef if c.clip_value else None,  # ours clips the value update too
                policy_kwargs={"net_arch": {"pi": list(c.hidden), "vf": list(c.hidden)}, "activation_fn": act},
                **common)
            self.learning_starts = 0
            return
        if algo == "ddpg":
            paper = DDPGConfig()
            noise = OrnsteinUhlenbeckActionNoise(np.zeros(8), paper.noise_sigma * np.ones(8), theta=paper.noise_theta)
            self.model = sb3.DDPG(
                "MlpPolicy", env, learning_rate=paper.critic_lr, buffer_size=paper.buffer_size,
                learning_starts=learning_starts, batch_size=paper.batch_size, tau=paper.tau, gamma=paper.gamma,
                train_freq=(paper.learn_every, "step"), gradient_steps=paper.gradient_steps, action_noise=noise,
                policy_kwargs={"net_arch": list(paper.hidden), "activation_fn": act}, **common)
        elif algo == "td3":
            t = TD3Config()
            self.model = sb3.TD3(
                "MlpPolicy", env, learning_rate=t.actor_lr, buffer_size=t.buffer_size, learning_starts=learning_starts,
                batch_size=t.batch_size, tau=t.tau, gamma=t.gamma, train_freq=(learn_every, "step"),
                gradient_steps=1, action_noise=NormalActionNoise(np.zeros(8), t.noise_sigma * np.ones(8)),
                policy_delay=t.policy_delay, target_policy_noise=t.policy_noise, target_noise_clip=t.noise_clip,
                policy_kwargs={"net_arch": list(t.hidden), "activation_fn": act}, **common)
        else:
            c2 = SACConfig()
            self.model = sb3.SAC(
                "MlpPolicy", env, learning_rate=c2.actor_lr, buffer_size=c2.buffer_size,
                learning_starts=learning_starts, batch_size=c2.batch_size, tau=c2.tau, gamma=c2.gamma,
                train_freq=(learn_every, "step"), gradient_steps=1, ent_coef=f"auto_{c2.alpha}",
                policy_kwargs={"net_arch": list(c2.hidden), "activation_fn": act}, **common)
        self.learning_starts = learning_starts

    def gradient_steps(self) -> int:
        n = int(self.model._n_updates)
        return n * (PPO_ROLLOUT // self.model.batch_size) if self.algo == "ppo" else n

    def warm_up(self) -> None:
        if self.learning_starts:
            self.model.learn(total_timesteps=self.learning_starts, reset_num_timesteps=False)

    def run(self, steps: int) -> tuple[int, float]:
        t0, before = time.perf_counter(), self.model.num_timesteps
        self.model.learn(total_timesteps=steps, reset_num_timesteps=False)
        return self.model.num_timesteps - before, time.perf_counter() - t0


PROFILE_STEPS = 64
"""Off-policy gradient steps timed per side by :func:`update_profile` (PPO: two updates of 320 minibatches)."""


class _PhaseTimer:
    """Thread CPU seconds spent in ``Tensor.backward`` and in ``torch.optim.Adam.step`` while
    entered: both libraries descend through these two, so the rest of a gradient step is its
    forward passes, replay sampling and bookkeeping."""

    def __enter__(self) -> _PhaseTimer:
        self.backward = self.optimizer = 0.0
        self._saved = (torch.Tensor.backward, torch.optim.Adam.step)

        def timed(fn: Callable[..., Any], field: str) -> Callable[..., Any]:
            def wrapper(*args: Any, **kwargs: Any) -> Any:
                t = time.thread_time()
                try:
                    return fn(*args, **kwargs)
                finally:
                    setattr(self, field, getattr(self, field) + time.thread_time() - t)
            return wrapper

        setattr(torch.Tensor, "backward", timed(self._saved[0], "backward"))  # noqa: B010
        setattr(torch.optim.Adam, "step", timed(self._saved[1], "optimizer"))  # noqa: B010
        return self

    def __exit__(self, *exc: object) -> None:
        setattr(torch.Tensor, "backward", self._saved[0])  # noqa: B010
        setattr(torch.optim.Adam, "step", self._saved[1])  # noqa: B010


def _phases(run: Callable[[], tuple[int, float]]) -> dict[str, float]:
    """Milliseconds of thread CPU per gradient step of ``run`` (which returns its gradient steps and
    the thread CPU seconds of its timed part), split into forward-and-rest, backward and Adam."""
    run()  # warm
    with _PhaseTimer() as timer:
        steps, total = run()
    ms = 1e3 / steps
    return {"forward_and_rest": (total - timer.backward - timer.optimizer) * ms, "backward": timer.backward * ms,
            "optimizer": timer.optimizer * ms, "total": total * ms}


def _timed(fn: Callable[[], Any], steps: int) -> Callable[[], tuple[int, float]]:
    def run() -> tuple[int, float]:
        t = time.thread_time()
        fn()
        return steps, time.thread_time() - t
    return run


def _ppo_update(algo: Any, n_rows: int, seed: int) -> Callable[[], tuple[int, float]]:
    """A fresh PPO like ``algo`` (same networks and config) whose every call fills a synthetic rollout
    of ``n_rows`` rows (the cost of an update does not depend on the data) and times the update."""
    from triplesumo.algos.ppo import PPO

    fresh = PPO(algo.obs_dim, algo.act_dim, algo.config, seed)
    rng = np.random.default_rng(seed)
    zeros, no = np.zeros(n_rows), np.zeros(n_rows, dtype=bool)

    def run() -> tuple[int, float]:
        obs = np.zeros((n_rows, fresh.obs_dim), np.float32)
        while not fresh.rollout_full:
            obs = rng.standard_normal((n_rows, fresh.obs_dim)).astype(np.float32)
            fresh.observe(obs)
            fresh.explore(obs, rng)
            fresh.record(zeros, no, no)
        t = time.thread_time()
        fresh.update(obs)
        return fresh.config.n_epochs * fresh.config.n_minibatches, time.thread_time() - t
    return run


def update_profile(variants: dict[str, Any], seed: int) -> dict[str, dict[str, dict[str, float]]]:
    """Thread CPU milliseconds of one gradient step of each algorithm, ours against SB3's, at the
    bench's networks and batch sizes, split by phase (:class:`_PhaseTimer`; PPO: one minibatch
    step). Ours: the trainer's learner (replay sample, update, finite checks); SB3: ``model.train``
    on its own replay or rollout; CPU time, so the machine's load barely moves it."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for algo, ours_name in (("ddpg", "train_paper"), *((a, f"train_{a}") for a in ALGO_ROWS)):
        if ours_name not in variants:
            continue
        learner = variants[ours_name].trainer.learners[0]
        row: dict[str, dict[str, float]] = {}
        if algo == "ppo":
            row["ours"] = _phases(_ppo_update(learner.algo, learner.n_rows, seed))
            if "sb3_ppo" in variants:
                model = variants["sb3_ppo"].model
                row["sb3"] = _phases(_timed(model.train, model.n_epochs * (PPO_ROLLOUT // model.batch_size)))
        else:
            row["ours"] = _phases(_timed(functools.partial(learner.run_updates, PROFILE_STEPS), PROFILE_STEPS))
            if f"sb3_{algo}" in variants:  # (not for the bfloat16 rows: SB3's are in their float32 rows)
                model = variants[f"sb3_{algo}"].model
                sb3_train = functools.partial(model.train, gradient_steps=PROFILE_STEPS, batch_size=model.batch_size)
                row["sb3"] = _phases(_timed(sb3_train, PROFILE_STEPS))
        out[algo] = row
    return out


def run_train_benchmark(steps: int = 6000, n_envs: int = 16, n_threads: int = 1, rounds: int = 3,
                        chunk: int = 2000, policies: tuple[str, ...] = ("ant=random", "spider=random"),
                        seed: int = 0, learning_starts: int = 1000, sb3: bool = True,
                        algo_steps: int | None = 2048, update_steps: bool = True,
                        steps_per_epoch: int = 500) -> dict[str, Any]:
    """Measure env-only, paper-preset training and (optionally) SB3 DDPG, then (unless
    ``algo_steps`` is None) TD3, SAC, PPO and three learners at once against SB3's same
    algorithms, then (``update_steps``) the cost of one gradient step of each, split by phase
    (:func:`update_profile`); returns a JSON-able dict."""
    torch.set_num_threads(1)
    base = TrainConfig(name="bench", policies=policies, n_envs=n_envs, n_threads=n_threads, seed=seed,
                       progress=False, tensorboard=False, save_replay=False, epochs=10**9,
                       steps_per_epoch=steps_per_epoch)
    tmp = tempfile.TemporaryDirectory(prefix="triplesumo-bench-")
    root = Path(tmp.name)
    configs = learner_configs(n_envs, learning_starts)
    variants: dict[str, Any] = {
        "env_only": _TrainerVariant(TrainConfig(**{**base.__dict__, **configs["env"]}), root / "env", learning_starts),
        "train_paper": _TrainerVariant(TrainConfig(**{**base.__dict__, **configs["ddpg"]}), root / "train",
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
            variants["sb3_ddpg"] = _SB3Variant("ddpg", policies, seed, learning_starts)
            budget["sb3_ddpg"] = steps
        except ImportError:
            sb3_status = "stable-baselines3 not installed"
    else:
        sb3_status = "skipped"
    if algo_steps is not None:
        algo_base = {**base.__dict__, **{algo: configs[algo][algo] for algo in ("td3", "sac", "ppo")}}
        for algo in ("td3", "sac", "ppo"):
            variants[f"train_{algo}"] = _TrainerVariant(TrainConfig(**{**algo_base, "learn": (f"bug={algo}",)}),
                                                        root / algo, 0 if algo == "ppo" else learning_starts)
            budget[f"train_{algo}"] = algo_steps
        for name in BF16_ROWS:
            variants[f"train_{name}"] = _TrainerVariant(TrainConfig(**{**base.__dict__, **configs[name]}),
                                                        root / name, learning_starts)
            budget[f"train_{name}"] = algo_steps
        others = tuple(p for p in policies if p.split("=")[0] not in ("ant", "bug", "spider"))
        variants["train_3_learners"] = _TrainerVariant(
            TrainConfig(**{**algo_base, "learn": ("ant=sac", "bug=td3", "spider=ppo"), "policies": others}),
            root / "three", learning_starts)
        budget["train_3_learners"] = algo_steps
        if sb3 and sb3_status == "measured":
            for algo in ("td3", "sac", "ppo"):
                variants[f"sb3_{algo}"] = _SB3Variant(algo, policies, seed, learning_starts, learn_every=n_envs)
                budget[f"sb3_{algo}"] = algo_steps
    for v in variants.values():
        v.warm_up()
    trainer = variants["train_paper"].trainer
    timers0 = dict(trainer.timers)
    epochs0 = trainer.collector.epochs_done
    per_round: dict[str, list[float]] = {name: [] for name in variants}
    update_rounds: dict[str, list[float]] = {name: [] for name in variants}
    load_before = os.getloadavg()
    cpu_rounds: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(rounds):
        done = dict.fromkeys(variants, 0)
        spent = dict.fromkeys(variants, 0.0)
        cpu = dict.fromkeys(variants, 0.0)
        grads = {name: v.gradient_steps() for name, v in variants.items()}
        while any(done[name] < budget[name] for name in variants):
            for name, variant in variants.items():
                if done[name] < budget[name]:
                    cpu0 = time.process_time()  # every thread of the process: the update thread's too
                    n, seconds = variant.run(min(chunk, budget[name] - done[name]))
                    cpu[name] += time.process_time() - cpu0
                    done[name] += n
                    spent[name] += seconds
        for name, variant in variants.items():
            per_round[name].append(done[name] / spent[name])
            update_rounds[name].append((variant.gradient_steps() - grads[name]) / spent[name])
            cpu_rounds[name].append(done[name] / max(cpu[name], 1e-9))
    rates = {name: float(np.median(r)) for name, r in per_round.items()}
    update_rates = {name: float(np.median(r)) for name, r in update_rounds.items()}
    cpu_rates = {name: float(np.median(r)) for name, r in cpu_rounds.items()}
    profile = update_profile(variants, seed) if update_steps else {}
    spent = {k: trainer.timers[k] - timers0[k] for k in timers0}
    wall = spent["env"] + spent["act"] + spent["wait"]
    epochs = trainer.collector.epochs_done - epochs0
    finished_steps = trainer.collector.finished_epoch_steps[epochs0:]
    mean_epoch = float(np.mean(finished_steps)) if finished_steps else None
    ratios = {"train_vs_env": rates["train_paper"] / rates["env_only"]}
    if "sb3_ddpg" in rates:
        ratios["train_vs_sb3"] = rates["train_paper"] / rates["sb3_ddpg"]
    for algo in ALGO_ROWS:
        if f"train_{algo}" in rates and _sb3_twin(algo) in rates:
            ratios[f"{algo}_vs_sb3"] = rates[f"train_{algo}"] / rates[_sb3_twin(algo)]
        if f"train_{algo}" in rates:
            ratios[f"{algo}_vs_env"] = rates[f"train_{algo}"] / rates["env_only"]
    if "train_3_learners" in rates:
        ratios["3_learners_vs_env"] = rates["train_3_learners"] / rates["env_only"]
    cpu_ratios = {f"{ours.removeprefix('train_').replace('paper', 'ddpg')}_vs_sb3": cpu_rates[ours] / cpu_rates[theirs]
                  for ours, theirs in (("train_paper", "sb3_ddpg"), *((f"train_{a}", _sb3_twin(a)) for a in ALGO_ROWS))
                  if ours in cpu_rates and theirs in cpu_rates}
    result = {
        "setup": {"steps": steps, "rounds": rounds, "chunk": chunk, "n_envs": n_envs, "n_threads": n_threads,
                  "policies": list(policies), "seed": seed, "learning_starts": learning_starts,
                  "paper_schedule": {"learn_every": 30, "gradient_steps": 1, "batch_size": 64, "hidden": [512, 256]},
                  "cpu_count": os.cpu_count(), "usable_cpus": len(os.sched_getaffinity(0)),
                  "load_average_before": list(load_before), "versions": versions(), "sb3": sb3_status,
                  "algo_steps": algo_steps,
                  "algo_schedule": {"offpolicy_learn_every": n_envs, "gradient_steps": 1,
                                    "ppo_rollout": PPO_ROLLOUT, "ppo_epochs": 10, "ppo_minibatches": 32,
                                    "three_learners": ["ant=sac", "bug=td3", "spider=ppo"]}},
        "rates": rates,
        "updates_per_s": update_rates,
        "ratios": ratios,
        "cpu_rates": cpu_rates,
        "cpu_ratios": cpu_ratios,
        "update_profile_ms": profile,
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


def run_warp_train_benchmark(steps: int = 2048, n_envs: int = 1024, device: str | None = None, rounds: int = 3,
                             chunk: int = 1024, policies: tuple[str, ...] = ("ant=zoo:ant", "spider=zoo:spider"),
                             seed: int = 0,
                             learning_starts: int = 10_000, gradient_steps: int = 4, batch_size: int = 4096,
                             ppo_steps: int = 16) -> dict[str, Any]:
    """Env steps/s of the trainer on ``backend="warp"`` (``device``): collection alone, DDPG with
    ``gradient_steps`` updates of ``batch_size`` per collection step of ``n_envs`` matches, and PPO
    with rollouts of ``ppo_steps`` steps x ``n_envs`` matches; JSON-able dict (interleaved rounds,
    medians). Trained fixed policies (the zoo's) act on the device, ``random`` ones on the host."""
    base = TrainConfig(name="bench", policies=policies, n_envs=n_envs, seed=seed, backend="warp", device=device,
                       progress=False, tensorboard=False, save_replay=False, epochs=10**9)
    ddpg = DDPGConfig(learning_starts=learning_starts, learn_every=n_envs, gradient_steps=gradient_steps,
                      batch_size=batch_size, buffer_size=max(1_000_000, 4 * learning_starts))
    tmp = tempfile.TemporaryDirectory(prefix="triplesumo-bench-")
    root = Path(tmp.name)
    variants = {
        "env_only": _TrainerVariant(TrainConfig(**{**base.__dict__, "ddpg": DDPGConfig(learning_starts=10**12)}),
                                    root / "env", 0),
        "train_ddpg": _TrainerVariant(TrainConfig(**{**base.__dict__, "ddpg": ddpg}), root / "ddpg", learning_starts),
        "train_ppo": _TrainerVariant(TrainConfig(**{**base.__dict__, "learn": ("bug=ppo",),
                                                    "ppo": PPOConfig(n_steps=ppo_steps, n_minibatches=4)}),
                                     root / "ppo", 0),
    }
    for v in variants.values():
        v.warm_up()
    per_round: dict[str, list[float]] = {name: [] for name in variants}
    update_rounds: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(rounds):
        done, spent = dict.fromkeys(variants, 0), dict.fromkeys(variants, 0.0)
        grads = {name: v.gradient_steps() for name, v in variants.items()}
        while any(done[name] < steps for name in variants):
            for name, variant in variants.items():
                if done[name] < steps:
                    n, seconds = variant.run(min(chunk, steps - done[name]))
                    done[name], spent[name] = done[name] + n, spent[name] + seconds
        for name, variant in variants.items():
            per_round[name].append(done[name] / spent[name])
            update_rounds[name].append((variant.gradient_steps() - grads[name]) / spent[name])
    trainer = variants["env_only"].trainer
    result = {
        "setup": {"backend": "warp", "device": str(trainer.collector.xp.device), "steps": steps, "rounds": rounds,
                  "chunk": chunk, "n_envs": n_envs, "policies": list(policies), "seed": seed,
                  "learning_starts": learning_starts,
                  "ddpg_schedule": {"learn_every": n_envs, "gradient_steps": gradient_steps, "batch_size": batch_size},
                  "ppo_schedule": {"n_steps": ppo_steps, "rollout": ppo_steps * n_envs, "n_minibatches": 4,
                                   "n_epochs": PPOConfig().n_epochs},
                  "cpu_count": os.cpu_count(), "versions": versions()},
        "rates": {name: float(np.median(r)) for name, r in per_round.items()},
        "updates_per_s": {name: float(np.median(r)) for name, r in update_rounds.items()},
    }
    for v in variants.values():
        v.trainer.log.close()
        v.trainer.collector.env.close()
    tmp.cleanup()
    return result


def format_warp_table(result: dict[str, Any]) -> str:
    s, rates, updates = result["setup"], result["rates"], result["updates_per_s"]
    d, p = s["ddpg_schedule"], s["ppo_schedule"]
    lines = [f"TripleSumo training benchmark, backend warp on {s['device']}: {s['n_envs']} matches, others "
             f"{s['policies']}; median of {s['rounds']} rounds x {s['steps']} env steps",
             f"DDPG: {d['gradient_steps']} updates of batch {d['batch_size']} per collection step; PPO: rollouts of "
             f"{p['rollout']} steps, {p['n_epochs']} epochs of {p['n_minibatches']} minibatches",
             "", f"{'variant':38s} {'env steps/s':>11s} {'vs env only':>11s} {'updates/s':>9s}"]
    labels = {"env_only": "env alone (collection, no learning)", "train_ddpg": "training DDPG, on the device",
              "train_ppo": "training PPO, on the device"}
    for name, rate in rates.items():
        lines.append(f"{labels[name]:38s} {rate:11.0f} {rate / rates['env_only']:11.2f} {updates[name]:9.1f}")
    if s["device"] == "cpu":
        lines += ["", "Warp's CPU device: a check that the GPU path runs, not a speed figure"]
    return "\n".join(lines)


def format_table(result: dict[str, Any]) -> str:
    s, rates, ratios = result["setup"], result["rates"], result["ratios"]
    lines = [
        f"TripleSumo training benchmark: {s['n_envs']} matches on {s['n_threads']} threads, others {s['policies']}; "
        f"median of {s['rounds']} rounds x {s['steps']} env steps, interleaved in chunks of {s['chunk']}",
        f"paper preset: hidden 512/256, batch 64, 1 gradient step per 30 transitions; "
        f"torch 1 thread; SB3: {s['sb3']}",
        "",
        f"{'variant':38s} {'env steps/s':>11s} {'vs env only':>11s} {'updates/s':>9s}",
    ]
    labels = {"env_only": "env alone (collection, no learning)", "train_paper": "training, paper preset",
              "sb3_ddpg": "Stable-Baselines3 DDPG, same schedule",
              "train_every_step": "training, 1 update per step",
              "train_td3": "training TD3, algorithm schedule", "train_sac": "training SAC, algorithm schedule",
              "train_ppo": "training PPO, algorithm schedule",
              "train_3_learners": "training 3 learners (SAC, TD3, PPO)",
              "sb3_td3": "Stable-Baselines3 TD3, same schedule", "sb3_sac": "Stable-Baselines3 SAC, same schedule",
              "sb3_ppo": "Stable-Baselines3 PPO, same schedule",
              "train_td3_bf16": "training TD3, bfloat16 updates", "train_sac_bf16": "training SAC, bfloat16 updates"}
    updates = result.get("updates_per_s", {})
    for name, rate in rates.items():
        lines.append(f"{labels[name]:38s} {rate:11.0f} {rate / rates['env_only']:11.2f} "
                     f"{updates.get(name, float('nan')):9.1f}")
    split = result["time_split"]
    lines += ["", "time split of training (wall): " + ", ".join(f"{k} {100 * v:.0f}%" for k, v in split.items())
              + f"; the update thread was busy {100 * result['learning_busy']:.0f}% of it (overlapping env)",
              f"train / env alone: {ratios['train_vs_env']:.2f} (target >= {TARGET_VS_ENV}: "
              f"{'met' if ratios['train_vs_env'] >= TARGET_VS_ENV else 'NOT met'})"]
    if "train_vs_sb3" in ratios:
        lines.append(f"train / SB3 DDPG: {ratios['train_vs_sb3']:.2f} (target >= {TARGET_VS_SB3}: "
                     f"{'met' if ratios['train_vs_sb3'] >= TARGET_VS_SB3 else 'NOT met'})")
    for algo in ALGO_ROWS:
        if f"{algo}_vs_sb3" in ratios:
            theirs = _sb3_twin(algo).removeprefix("sb3_").upper()
            lines.append(f"train {_label(algo)} / SB3 {theirs}: {ratios[f'{algo}_vs_sb3']:.2f} "
                         f"(target >= 2: {'met' if ratios[f'{algo}_vs_sb3'] >= 2 else 'NOT met'})")
    for algo in ALGO_ROWS:
        if algo != "ppo" and f"{algo}_vs_env" in ratios:
            ratio = ratios[f"{algo}_vs_env"]
            lines.append(f"train {_label(algo)} / env alone: {ratio:.2f} (target >= {TARGET_ALGO_VS_ENV}: "
                         f"{'met' if ratio >= TARGET_ALGO_VS_ENV else 'NOT met'})")
    cpu_rates, cpu_ratios = result.get("cpu_rates", {}), result.get("cpu_ratios", {})
    if cpu_ratios:
        lines.append("per CPU-second of the process (all its threads; barely moved by other load on the machine): "
                     + ", ".join(f"{k.split('_')[0].upper()} {v:.2f}x SB3" for k, v in cpu_ratios.items())
                     + f"; env alone {cpu_rates['env_only']:.0f} steps/CPU-s")
    profile = result.get("update_profile_ms", {})
    if profile:
        lines += ["", "one gradient step (PPO: one minibatch step), thread CPU ms: forward and rest / backward / "
                  "Adam = total"]
        for algo, row in profile.items():
            cells = [f"{side} {t['forward_and_rest']:.2f} / {t['backward']:.2f} / {t['optimizer']:.2f} = "
                     f"{t['total']:.2f}" for side, t in row.items()]
            lines.append(f"  {algo.upper():5s} " + ";  ".join(cells)
                         + (f";  SB3/ours {row['sb3']['total'] / row['ours']['total']:.2f}" if "sb3" in row else ""))
    p = result["projected_hours_20000_epochs"]
    if p["at_measured_epoch_length"] is not None:
        lines.append(f"projected wall time of 20,000 epochs at the measured {result['mean_epoch_steps']:.0f} "
                     f"steps/epoch ({result['epochs_measured']} epochs): {p['at_measured_epoch_length']:.1f} h; "
                     f"with 1 update per step: {p['every_step_at_measured_epoch_length']:.1f} h")
    lines.append(f"projected wall time of 20,000 epochs at 500 steps/epoch: {p['at_500_steps_per_epoch']:.1f} h; "
                 f"with 1 update per step: {p['every_step_at_500_steps_per_epoch']:.1f} h")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    if "--profile" in (sys.argv[1:] if argv is None else argv):  # one env step cut into its parts
        from triplesumo.benchmarks.train_profile import main as profile

        return profile(argv)
    parser = argparse.ArgumentParser(prog="triplesumo bench train", description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=None,
                        help="env steps per variant and round (default: 6000; warp: 2048)")
    parser.add_argument("--envs", type=int, default=None, help="matches collected at once (default: 16; warp: 1024)")
    parser.add_argument("--threads", type=int, default=1, help="MuJoCo threads (default: 1, the trainer's)")
    parser.add_argument("--rounds", type=int, default=3, help="repetitions; the median is reported (default: 3)")
    parser.add_argument("--chunk", type=int, default=2000, help="env steps per turn of a variant (default: 2000)")
    parser.add_argument("--policies", nargs="*", default=None,
                        help="AGENT=POLICY of the other agents (default: ant=random spider=random; warp: zoo)")
    parser.add_argument("--backend", choices=["cpu", "warp"], default="cpu",
                        help="cpu (default) or warp: the trainer on MuJoCo Warp (env only, DDPG, PPO rows)")
    parser.add_argument("--device", default=None, help="warp's device: cuda or cpu (default: cuda if Warp sees one)")
    parser.add_argument("--gradient-steps", type=int, default=4, help="warp: DDPG updates per collection step")
    parser.add_argument("--batch-size", type=int, default=4096, help="warp: DDPG batch size (default: 4096)")
    parser.add_argument("--no-sb3", action="store_true", help="skip the Stable-Baselines3 comparison")
    parser.add_argument("--algo-steps", type=int, default=2048,
                        help="env steps per round of the TD3/SAC/PPO/3-learner rows and their SB3 rows (default: 2048)")
    parser.add_argument("--no-algos", action="store_true", help="skip the TD3, SAC, PPO and 3-learner rows")
    parser.add_argument("--no-update-profile", action="store_true",
                        help="skip the per-phase cost of one gradient step, ours against SB3's")
    parser.add_argument("--seed", type=int, default=0, help="seed (default: 0)")
    parser.add_argument("--json", metavar="PATH", default=None, help="also write the results as JSON to PATH")
    parser.add_argument("--quick", action="store_true", help="tiny sizes (a smoke test, not a measurement)")
    parser.add_argument("--profile", action="store_true",
                        help="instead: one env step of the trainer cut into its parts, per learner "
                             "(triplesumo.benchmarks.train_profile; its own options)")
    args = parser.parse_args(argv)
    learning_starts = 1000
    if args.backend == "warp":
        steps, envs, chunk, learning_starts = args.steps or 2048, args.envs or 1024, args.steps or 2048, 10_000
        if args.quick:
            envs, args.rounds, steps, chunk, learning_starts = 4, 1, 16, 8, 8
            args.batch_size, args.gradient_steps = 16, 2
        result = run_warp_train_benchmark(steps=steps, n_envs=envs, device=args.device, rounds=args.rounds,
                                          chunk=chunk,
                                          policies=tuple(args.policies or ("ant=zoo:ant", "spider=zoo:spider")),
                                          seed=args.seed, learning_starts=learning_starts,
                                          gradient_steps=args.gradient_steps, batch_size=args.batch_size,
                                          ppo_steps=4 if args.quick else 16)
        report(format_warp_table(result), result, args.json)
        return 0
    if args.device not in (None, "cpu"):
        parser.error(f"--device {args.device} needs --backend warp")
    args.policies = args.policies or ["ant=random", "spider=random"]
    args.steps, args.envs = args.steps or 6000, args.envs or 16
    steps_per_epoch = 500
    if args.quick:  # (matches of 24 steps: some end within the 64 measured, however far from the edges they start)
        args.steps, args.envs, args.rounds, args.chunk, learning_starts = 64, 2, 1, 32, 32
        args.algo_steps, steps_per_epoch = 64, 24
    result = run_train_benchmark(steps=args.steps, n_envs=args.envs, n_threads=args.threads, rounds=args.rounds,
                                 chunk=args.chunk, policies=tuple(args.policies), seed=args.seed,
                                 learning_starts=learning_starts, sb3=not args.no_sb3,
                                 algo_steps=None if args.no_algos else args.algo_steps,
                                 update_steps=not args.no_update_profile, steps_per_epoch=steps_per_epoch)
    report(format_table(result), result, args.json)
    return 0
