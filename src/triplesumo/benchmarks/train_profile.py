"""``triplesumo bench train --profile``: one env step of the trainer, cut into its parts, for every learner.

The trainer is built as ``triplesumo bench train`` builds it (``n_envs`` matches on one MuJoCo thread, Bug
learning, the other agents random; DDPG at the paper preset, TD3, SAC and PPO on the algorithm schedule) and
stepped as in training, with its parts' methods wrapped on the instances (nothing in the trainer changes):

``env``
    the matches' step (``VectorMatches.step``): physics, rules, observations, the reset of finished matches;
``act``
    the learner's training action (``Learner.act``): its normaliser, the policy's forward pass, exploration;
``seats``
    the actions of the agents that do not learn (``Seats.act``);
``store``
    the learner's transitions into its replay buffer or rollout (``Learner.store``);
``bookkeeping``
    everything else the collecting thread does in ``Trainer.step``: the actions' array, the schedule, the
    epochs' sums and rows (its thread CPU less the parts above);
``update``
    the gradient steps: off-policy ones in the update thread (``Learner.run_updates``), PPO's inline
    (``Learner.learn``); per gradient step (PPO: per minibatch step) and amortised per env step.

All in thread CPU microseconds (``time.thread_time``: what the thread itself ran, so the machine's other load
barely moves it) per env step (one match's step: a trainer step of ``n_envs`` matches is ``n_envs`` env steps).
Each learner runs twice: with the updates in their thread beside the physics (``overlap``, the trainer's
default) and inline (``inline``). What the two threads cost each other shows as the difference: a part that
takes more CPU beside the other thread (caches, memory bandwidth) and, in wall time, a thread that is ready but
not running (``wall / cpu`` above 1: waiting for the GIL or, on a loaded machine, for a core). The torch
threads (intra-op and inter-op) each thread runs with are read in that thread.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from triplesumo.benchmarks import learner_configs, report, versions
from triplesumo.train.config import TrainConfig
from triplesumo.train.loop import Trainer

PARTS = ("env", "act", "seats", "store", "bookkeeping", "update")
"""The parts of an env step, in the table's order (their sum is the CPU of an env step, both threads)."""
LEARNERS = ("env", "ddpg", "td3", "sac", "ppo", "td3_bf16", "sac_bf16")
"""The learners profiled: ``env`` the collection alone (``bench train``'s ``env_only``: DDPG that never leaves
its random warm-up), DDPG at the paper preset, the others on ``bench train``'s algorithm schedule (``*_bf16``:
with bfloat16 updates)."""
MODES = ("overlap", "inline")


class _Parts:
    """Thread CPU and wall seconds of named parts, by wrapping methods on instances (the update thread's
    part is recorded from that thread)."""

    def __init__(self) -> None:
        self.cpu: dict[str, float] = defaultdict(float)
        self.wall: dict[str, float] = defaultdict(float)
        self.threads: dict[str, dict[str, int]] = {}
        self.blocked: dict[str, int] = defaultdict(int)

    def wrap(self, obj: Any, name: str, part: str, thread: str | None = None) -> None:
        fn: Callable[..., Any] = getattr(obj, name)

        def wrapper(*args: Any, **kwargs: Any) -> Any:
            if thread is not None and thread not in self.threads:
                self.threads[thread] = {"intra_op": torch.get_num_threads(),
                                        "inter_op": torch.get_num_interop_threads()}
            c, w, b = time.thread_time(), time.perf_counter(), _blocked()
            try:
                return fn(*args, **kwargs)
            finally:
                self.cpu[part] += time.thread_time() - c
                self.wall[part] += time.perf_counter() - w
                self.blocked[part] += _blocked() - b

        setattr(obj, name, wrapper)


def _blocked() -> int:
    """Times the calling thread has blocked so far (voluntary context switches: waiting for the GIL, a lock or
    an event; the machine's other load preempts instead, which is not counted)."""
    return resource.getrusage(resource.RUSAGE_THREAD).ru_nvcsw


class _Window:
    """The collecting thread's CPU seconds (:attr:`cpu`) from the moment a step's updates are handed to their
    thread (``Updates.begin`` returns) to the moment it waits for them (``Updates.finish``): what it does beside
    them."""

    def __enter__(self) -> _Window:
        from triplesumo.train.learners import Updates

        self.cpu, self._start = 0.0, 0.0
        self._saved = (Updates.begin, Updates.finish)
        begin, finish = self._saved

        def timed_begin(updates: Any, *args: Any, **kwargs: Any) -> Any:
            out = begin(updates, *args, **kwargs)
            self._start = time.thread_time()
            return out

        def timed_finish(updates: Any, *args: Any, **kwargs: Any) -> Any:
            self.cpu += time.thread_time() - self._start
            return finish(updates, *args, **kwargs)

        setattr(Updates, "begin", timed_begin)  # noqa: B010
        setattr(Updates, "finish", timed_finish)  # noqa: B010
        return self

    def __exit__(self, *exc: object) -> None:
        from triplesumo.train.learners import Updates

        setattr(Updates, "begin", self._saved[0])  # noqa: B010
        setattr(Updates, "finish", self._saved[1])  # noqa: B010


def gradient_steps(trainer: Trainer) -> int:
    """Gradient steps so far (PPO: minibatch steps)."""
    total = 0
    for learner in trainer.learners:
        c = learner.config
        total += learner.algo.num_updates * (c.n_epochs * c.n_minibatches if learner.spec.algo == "ppo" else 1)
    return total


def profile_trainer(cfg: TrainConfig, run_dir: Path, steps: int, warm_up: int) -> dict[str, Any]:
    """Step a trainer of ``cfg`` for ``warm_up`` env steps, then ``steps`` more with its parts timed; the parts in
    CPU microseconds per env step, the wall time and what the threads ran with."""
    trainer = Trainer(cfg, run_dir=run_dir)
    c = trainer.collector
    while c.env_steps < warm_up:
        trainer.step()
    parts = _Parts()
    parts.wrap(c.env, "step", "env")
    parts.wrap(trainer.seats, "act", "seats")
    for learner in trainer.learners:
        parts.wrap(learner, "prepare", "act")  # (the normaliser; an off-policy learner's actor copy)
        parts.wrap(learner, "act", "act")
        parts.wrap(learner, "store", "store")
        if hasattr(learner, "run_updates"):  # off-policy: in the update thread (or inline)
            parts.wrap(learner, "draw", "update")  # (its replay samples)
            parts.wrap(learner, "run_updates", "update", thread="update" if cfg.overlap_learning else "collect")
        else:  # PPO: inline, when its rollout is full
            parts.wrap(learner, "learn", "update_inline")
    parts.threads["collect"] = {"intra_op": torch.get_num_threads(), "inter_op": torch.get_num_interop_threads()}
    start_steps, grads0 = c.env_steps, gradient_steps(trainer)
    main_cpu = main_wall = critical = 0.0
    main_blocked = _blocked()
    with _Window() as window:
        while c.env_steps - start_steps < steps:
            t, w, u = time.thread_time(), time.perf_counter(), parts.cpu["update"]
            window.cpu = 0.0
            trainer.step()
            step_cpu = time.thread_time() - t
            main_cpu += step_cpu
            main_wall += time.perf_counter() - w
            beside = parts.cpu["update"] - u if cfg.overlap_learning else 0.0
            critical += step_cpu - window.cpu + max(window.cpu, beside)
    n, grads = c.env_steps - start_steps, gradient_steps(trainer) - grads0
    main_blocked = _blocked() - main_blocked
    trainer_steps = n / cfg.n_envs
    trainer.log.close()
    cpu, wall = parts.cpu, parts.wall
    update = cpu["update"] + cpu["update_inline"]
    inline = cpu["update_inline"] + (cpu["update"] if not cfg.overlap_learning else 0.0)
    measured = cpu["env"] + cpu["act"] + cpu["seats"] + cpu["store"] + inline
    us = 1e6 / n
    row = {"env": cpu["env"] * us, "act": cpu["act"] * us, "seats": cpu["seats"] * us, "store": cpu["store"] * us,
           "bookkeeping": max(main_cpu - measured, 0.0) * us, "update": update * us}
    update_wall = wall["update"] + wall["update_inline"]
    return {"cpu_us_per_env_step": row,
            "cpu_us_per_env_step_total": sum(row.values()),
            "wall_us_per_env_step": main_wall * us,
            "critical_path_us_per_env_step": critical * us,
            "update_ms_per_gradient_step": 1e3 * update / grads if grads else None,
            "gradient_steps_per_env_step": grads / n,
            "wall_over_cpu": {"env": wall["env"] / max(cpu["env"], 1e-12),
                              "update": update_wall / update if update else None,
                              "collecting_thread": main_wall / max(main_cpu, 1e-12)},
            "blocked_per_step": {"collecting_thread": main_blocked / trainer_steps,
                                 "update_thread": parts.blocked["update"] / trainer_steps
                                 if cfg.overlap_learning else 0.0},
            "torch_threads": dict(parts.threads), "env_steps": n, "gradient_steps": grads}


def run_step_profile(steps: int = 4096, n_envs: int = 16, learners: tuple[str, ...] = LEARNERS,
                     modes: tuple[str, ...] = MODES, learning_starts: int = 1000, seed: int = 0,
                     policies: tuple[str, ...] = ("ant=random", "spider=random"),
                     steps_per_epoch: int = 500, ppo_rollout: int | None = None) -> dict[str, Any]:
    """Profile one env step of the trainer for every learner in ``learners`` and mode in ``modes``
    (:func:`profile_trainer`); a JSON-able dict."""
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    base = TrainConfig(name="profile", policies=policies, n_envs=n_envs, n_threads=1, seed=seed, progress=False,
                       tensorboard=False, save_replay=False, epochs=10**9, steps_per_epoch=steps_per_epoch)
    configs = learner_configs(n_envs, learning_starts, ppo_rollout)
    out: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="triplesumo-profile-") as tmp:
        for name in learners:
            out[name] = {}
            for mode in modes[:1] if name == "env" else modes:  # (nothing to overlap)
                cfg = TrainConfig(**{**base.__dict__, **configs[name], "overlap_learning": mode == "overlap"})
                out[name][mode] = profile_trainer(cfg, Path(tmp) / f"{name}-{mode}", steps,
                                                  0 if name in ("ppo", "env") else learning_starts)
    return {"setup": {"steps": steps, "n_envs": n_envs, "n_threads": 1, "policies": list(policies), "seed": seed,
                      "learning_starts": learning_starts, "switch_interval_s": sys.getswitchinterval(),
                      "cpu_count": os.cpu_count(), "load_average_before": list(load_before),
                      "load_average_after": list(os.getloadavg()), "versions": versions()},
            "learners": out}


def format_profile_table(result: dict[str, Any]) -> str:
    s = result["setup"]
    lines = [f"One env step of the trainer, in thread CPU microseconds: {s['n_envs']} matches on 1 MuJoCo thread, "
             f"others {s['policies']}, {s['steps']} env steps per row; load average "
             f"{s['load_average_before'][0]:.1f} before, {s['load_average_after'][0]:.1f} after",
             "", f"{'learner':13s} " + " ".join(f"{p:>8s}" for p in PARTS)
             + f" {'total':>8s} {'critical':>8s} {'vs env':>6s} {'wall':>8s} {'ms/grad':>8s} {'env w/c':>8s} "
             f"{'upd w/c':>8s} {'blocked':>9s} {'torch thr':>10s}"]
    env = result["learners"].get("env", {})
    alone = next(iter(env.values()))["critical_path_us_per_env_step"] if env else float("nan")
    for name, modes in result["learners"].items():
        for mode, r in modes.items():
            cells = " ".join(f"{r['cpu_us_per_env_step'][p]:8.0f}" for p in PARTS)
            ms = r["update_ms_per_gradient_step"]
            wc = r["wall_over_cpu"]
            threads = ",".join(f"{t[0]}{v['intra_op']}/{v['inter_op']}" for t, v in r["torch_threads"].items())
            crit, blocked = r["critical_path_us_per_env_step"], r["blocked_per_step"]
            nan = float("nan")
            lines.append(f"{name + ' ' + mode:13s} {cells} {r['cpu_us_per_env_step_total']:8.0f} {crit:8.0f} "
                         f"{alone / crit:6.2f} {r['wall_us_per_env_step']:8.0f} {nan if ms is None else ms:8.2f} "
                         f"{wc['env']:8.2f} {wc['update'] or nan:8.2f} "
                         f"{blocked['collecting_thread']:4.1f}/{blocked['update_thread']:<4.1f} {threads:>10s}")
    lines += ["", "total: CPU of an env step, both threads; critical: the CPU on the step's critical path (the "
              "collecting thread's, where the update thread's is longer beside it: the wall time of an idle machine "
              "with a core per thread, no contention); vs env: env alone's critical over this one's; "
              "wall: of the collecting thread per env step (this machine, its load); "
              "ms/grad: CPU of one gradient step (PPO: minibatch); w/c: wall over CPU of the part (above 1: ready "
              "but not running, the GIL or a busy core); blocked: times per trainer step the collecting / update "
              "thread blocked (the GIL, or one waiting for the other; preemption by other load is not counted); "
              "torch thr: intra/inter-op threads of the collecting (c) and update (u) threads"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="triplesumo bench train --profile", description=__doc__.split("\n\n")[0])
    parser.add_argument("--profile", action="store_true", help="(how bench train hands over to this profile)")
    parser.add_argument("--steps", type=int, default=4096, help="env steps timed per learner and mode (4096)")
    parser.add_argument("--envs", type=int, default=16, help="matches collected at once (default: 16)")
    parser.add_argument("--learners", nargs="*", default=list(LEARNERS), choices=LEARNERS)
    parser.add_argument("--modes", nargs="*", default=list(MODES), choices=MODES)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", metavar="PATH", default=None, help="also write the results as JSON to PATH")
    parser.add_argument("--quick", action="store_true", help="tiny sizes (a smoke test, not a measurement)")
    args = parser.parse_args(argv)
    steps, envs, learning_starts, per_epoch, rollout = args.steps, args.envs, 1000, 500, None
    if args.quick:  # (a replay of 300 holds a batch of 256; a PPO rollout of 64 transitions: one update)
        steps, envs, learning_starts, per_epoch, rollout = 64, 2, 300, 24, 64
    result = run_step_profile(steps, envs, tuple(args.learners), tuple(args.modes), learning_starts, args.seed,
                              steps_per_epoch=per_epoch, ppo_rollout=rollout)
    report(format_profile_table(result), result, args.json)
    return 0
