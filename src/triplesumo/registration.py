"""Gymnasium ids of TripleSumo's single-agent view (registered by ``import triplesumo``).

Kept outside :mod:`triplesumo.envs` so that registering imports only gymnasium."""

from __future__ import annotations

import gymnasium as gym

ENV_IDS = ("TripleSumo-v0", "TripleSumo-Paper-v0")


def register_envs() -> None:
    """Register the ids (idempotent)."""
    # vector_entry_point: gym.make_vec(id, num_envs=N) steps N matches together, in-process.
    if "TripleSumo-v0" not in gym.registry:
        gym.register("TripleSumo-v0", entry_point="triplesumo.envs.single:TripleSumoEnv",
                     vector_entry_point="triplesumo.envs.vector:TripleSumoVectorEnv")
    if "TripleSumo-Paper-v0" not in gym.registry:
        # The shipped Ant and Spider drive the others; resolved lazily by the zoo.
        gym.register("TripleSumo-Paper-v0", entry_point="triplesumo.zoo:make_paper_env",
                     vector_entry_point="triplesumo.zoo:make_paper_vector_env")
