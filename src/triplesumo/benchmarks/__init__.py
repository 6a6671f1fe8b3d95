"""Speed measurements (never timed tests): ``triplesumo bench env`` (:mod:`.env`),
``triplesumo bench train`` (:mod:`.train`), ``bench ray`` (:mod:`.ray`), ``bench rllib``
(:mod:`.rllib`) and ``bench skill`` (:mod:`.skill`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

PPO_ROLLOUT = 2048
"""Transitions per PPO rollout on ``bench train``'s algorithm schedule (SB3's n_steps with one env); its
``--profile`` uses it too."""


def learner_configs(n_envs: int, learning_starts: int, ppo_rollout: int | None = None) -> dict[str, dict[str, Any]]:
    """``TrainConfig`` fields of each learner as ``bench train`` measures it (DDPG: the paper preset; PPO's
    rollout ``ppo_rollout`` transitions, by default ``bench train``'s; ``td3_bf16`` and ``sac_bf16``: TD3 and SAC
    with ``update_dtype="bfloat16"``). Every off-policy learner has one-step targets here, as SB3's, which ``bench
    train`` sets beside them on the same schedule (SAC's default is 5-step returns)."""
    from triplesumo.algos.ddpg import DDPGConfig  # (here: the env benches import this package without torch)
    from triplesumo.algos.ppo import PPOConfig
    from triplesumo.algos.sac import SACConfig
    from triplesumo.algos.td3 import TD3Config

    rollout = ppo_rollout or PPO_ROLLOUT
    return {"env": {"ddpg": DDPGConfig(learning_starts=10**12)},
            "ddpg": {"ddpg": DDPGConfig(learning_starts=learning_starts)},
            "td3": {"learn": ("bug=td3",), "td3": TD3Config(learn_every=n_envs, learning_starts=learning_starts)},
            "sac": {"learn": ("bug=sac",), "sac": SACConfig(learn_every=n_envs, learning_starts=learning_starts,
                                                            n_step=1)},
            "td3_bf16": {"learn": ("bug=td3",), "td3": TD3Config(learn_every=n_envs, learning_starts=learning_starts,
                                                                 update_dtype="bfloat16")},
            "sac_bf16": {"learn": ("bug=sac",), "sac": SACConfig(learn_every=n_envs, learning_starts=learning_starts,
                                                                 n_step=1, update_dtype="bfloat16")},
            "ppo": {"learn": ("bug=ppo",), "ppo": PPOConfig(n_steps=max(rollout // n_envs, 1))}}


def report(table: str, result: dict[str, Any], json_path: str | None) -> None:
    """Print a benchmark's table and, when asked, write its results as JSON."""
    print(table)
    if json_path:
        path = Path(json_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {path}")


def versions(*extra: str) -> dict[str, str]:
    """Versions of what a benchmark's figures depend on (``extra``: further installed packages)."""
    import platform
    from importlib import metadata

    import mujoco
    import numpy as np

    found = {"python": platform.python_version(), "mujoco": mujoco.__version__, "numpy": np.__version__}
    for package in ("triplesumo", "gymnasium", "pettingzoo", *extra):
        try:
            found[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            found[package] = "not installed"
    return found
