"""Gymnasium ids of TripleSumo's single-agent view (registered by ``import triplesumo``).

Kept outside :mod:`triplesumo.envs` so that registering imports only gymnasium."""

from __future__ import annotations

import gymnasium as gym

ENV_IDS = ("TripleSumo-v0", "TripleSumo-Paper-v0", "TripleSumo-FFA-v0", "TripleSumo-Pursuit-v0", "TripleSumo-2v2-v0",
           "TripleSumo-Bodies-v0")
SCENARIO_IDS = {"TripleSumo-FFA-v0": "ffa", "TripleSumo-Pursuit-v0": "pursuit", "TripleSumo-2v2-v0": "2v2",
                "TripleSumo-Bodies-v0": "bodies"}
"""The single-learner view of each scenario besides the paper's, the others passive unless given
(kept in step with ``triplesumo.rules.scenarios.SCENARIOS``, checked by the tests)."""


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
    for env_id, scenario in SCENARIO_IDS.items():
        if env_id not in gym.registry:
            gym.register(env_id, entry_point="triplesumo.envs.single:TripleSumoEnv", kwargs={"scenario": scenario},
                         vector_entry_point="triplesumo.envs.vector:TripleSumoVectorEnv")
