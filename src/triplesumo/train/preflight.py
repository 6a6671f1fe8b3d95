"""Checks made before a run folder is made: that the learners' replay buffers, networks and rollouts fit this
machine, that an off-policy schedule does not drown collection in updates, that a shared network's agents have
the same sizes."""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from triplesumo.envs.match import Match
from triplesumo.train.config import TrainConfig
from triplesumo.train.learners import LearnerSpec


def replay_bytes(capacity: int, obs_dim: int, act_dim: int) -> int:
    """Bytes a full replay buffer of ``capacity`` transitions takes (float32 arrays)."""
    return capacity * (2 * obs_dim + act_dim + 2) * 4


def machine_memory() -> int:
    """Physical memory plus swap of this machine, in bytes (0 if unknown)."""
    try:
        info = dict(line.split(":", 1) for line in Path("/proc/meminfo").read_text().splitlines() if ":" in line)
        return sum(int(info[k].split()[0]) * 1024 for k in ("MemTotal", "SwapTotal") if k in info)
    except (OSError, ValueError):
        try:
            return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError, AttributeError):
            return 0


def network_bytes(hidden: Sequence[int], obs_dim: int, act_dim: int, critics: int = 1) -> int:
    """Bytes an actor-critic learner's float32 networks take with their targets, gradients and Adam's two moments
    (about five copies of every parameter; ``critics`` Q networks of the same widths)."""
    def params(widths: list[int]) -> int:
        return sum((a + 1) * b for a, b in zip(widths[:-1], widths[1:], strict=True))

    actor = params([obs_dim, *hidden, 2 * act_dim])
    critic = params([obs_dim + act_dim, *hidden, 1])
    return 5 * 4 * (actor + critics * critic)


def check_memory(cfg: TrainConfig, learners: list[tuple[str, str, int, int]]) -> None:
    """``ValueError`` naming the fields if what the learners hold at once (``(learner, algo, obs_dim, act_dim)``
    each) cannot fit this machine: full replay buffers (``buffer_size``), networks (``hidden``) and PPO's
    rollouts (``n_steps`` x the matches' transitions). Checked before anything is made: a MemoryError there left
    a run folder behind."""
    own = cfg.learner_configs()
    fields: set[str] = set()
    need = 0
    for name, algo, obs, act in learners:
        c = cfg.algo_config(name)

        def field(key: str, value: Any, name: str = name, algo: str = algo) -> None:
            own_key = key in own.get(name, {})
            fields.add(f"TrainConfig.{f'learner_config {name}' if own_key else algo}.{key}={value}")

        field("hidden", list(c.hidden))
        need += network_bytes(c.hidden, obs, act, critics=1 if algo in ("ddpg", "ppo") else 2)
        if algo == "ppo":
            field("n_steps", c.n_steps)
            need += c.n_steps * cfg.n_envs * (obs + 2 * act + 8) * 4  # observations, actions, flags, values
        else:
            field("buffer_size", c.buffer_size)
            need += replay_bytes(c.buffer_size, obs, act)
    have = machine_memory()
    if have and need > have:
        raise ValueError(f"{', '.join(sorted(fields))} need {need / 2**30:.1f} GiB for {len(learners)} learner(s) "
                         f"({learners[0][2]}-value observations), more than this machine's {have / 2**30:.1f} GiB "
                         "of memory and swap; nothing was made")


HEAVY_SCHEDULE = 64
"""Gradient steps per collection step past which :func:`warn_heavy_schedule` warns."""


def warn_heavy_schedule(cfg: TrainConfig, specs: Sequence[LearnerSpec]) -> None:
    """Warn when an off-policy learner's schedule makes more than :data:`HEAVY_SCHEDULE` gradient steps per
    step of all the matches: ``learn_every`` counts transitions, so a CPU schedule (``learn_every 5``) kept
    for thousands of GPU matches makes thousands of updates per step and collects almost nothing (docs/gpu.md,
    "GPU training": ``learn_every N_ENVS``)."""
    for spec in specs:
        if spec.algo == "ppo":
            continue
        c = cfg.algo_config(spec.name)
        transitions = cfg.n_envs * len(spec.agents)
        per_step = transitions / c.learn_every * c.gradient_steps
        if per_step > HEAVY_SCHEDULE:
            warnings.warn(f"learner {spec.name}: {spec.algo}.learn_every={c.learn_every} and gradient_steps="
                          f"{c.gradient_steps} with {transitions:,} transitions per step of the {cfg.n_envs:,} "
                          f"matches make {per_step:,.0f} gradient steps per step, so the run will mostly update "
                          f"and barely collect; for G updates per step of all the matches set learn_every to "
                          f"{transitions} and gradient_steps to G (docs/gpu.md, \"GPU training\")", UserWarning,
                          stacklevel=3)


def learner_dims(match: Match, spec: LearnerSpec) -> tuple[int, int]:
    """The observation and action sizes of ``spec``'s network in ``match``; ``ValueError`` naming ``share=team``
    when its agents' sizes differ."""
    obs = {match.observer.sizes[a] for a in spec.agents}
    act = {match.action_sizes[match.agents.index(a)] for a in spec.agents}
    if len(obs) > 1 or len(act) > 1:
        raise ValueError(f"TrainConfig.share=team: agents {list(spec.agents)} have different observation "
                         f"or action sizes ({sorted(obs)}, {sorted(act)}); they cannot share a network")
    return obs.pop(), act.pop()
