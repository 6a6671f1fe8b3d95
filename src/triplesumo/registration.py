"""Gymnasium ids of TripleSumo's single-agent view (registered by ``import triplesumo``).

Kept outside :mod:`triplesumo.envs` so that registering imports only gymnasium."""

from __future__ import annotations

import gymnasium as gym

from triplesumo.version import ENV_VERSION

BASE_ID = f"TripleSumo-{ENV_VERSION}"
"""The paper's match, the others passive unless given."""
PAPER_ID = f"TripleSumo-Paper-{ENV_VERSION}"
"""The paper's match, Ant and Spider from the shipped zoo."""
SCENARIO_IDS = {f"TripleSumo-{label}-{ENV_VERSION}": scenario
                for label, scenario in (("FFA", "ffa"), ("Pursuit", "pursuit"), ("2v2", "2v2"), ("Bodies", "bodies"))}
"""The single-learner view of each scenario besides the paper's, the others passive unless given
(kept in step with ``triplesumo.rules.scenarios.SCENARIOS``, checked by the tests)."""
ELIMINATION_SCENARIOS = ("ffa", "pursuit")
"""Scenarios under elimination rules (checked against ``triplesumo.rules.scenarios`` by the tests). Their ids have no
native vector env: in one, a learner out ends its own episode while the match goes on, which a slot of the native
vector view (all agents' steps in lock step) cannot express; ``gym.make_vec`` of them is Gymnasium's
``SyncVectorEnv`` of single matches, each learner's episode ending when it is out."""
ENV_IDS = (BASE_ID, PAPER_ID, *SCENARIO_IDS)
"""Only the current version is registered: ``gym.make`` of an older one raises Gymnasium's
``DeprecatedEnv``, naming the current id."""


def register_envs() -> None:
    """Register the ids (idempotent)."""
    # vector_entry_point: gym.make_vec(id, num_envs=N) steps N matches together, in-process.
    if BASE_ID not in gym.registry:
        gym.register(BASE_ID, entry_point="triplesumo.envs.single:TripleSumoEnv",
                     vector_entry_point="triplesumo.envs.vector:TripleSumoVectorEnv")
    if PAPER_ID not in gym.registry:
        # The shipped Ant and Spider drive the others; resolved lazily by the zoo.
        gym.register(PAPER_ID, entry_point="triplesumo.zoo:make_paper_env",
                     vector_entry_point="triplesumo.zoo:make_paper_vector_env")
    for env_id, scenario in SCENARIO_IDS.items():
        if env_id not in gym.registry:
            native = None if scenario in ELIMINATION_SCENARIOS else "triplesumo.envs.vector:TripleSumoVectorEnv"
            gym.register(env_id, entry_point="triplesumo.envs.single:TripleSumoEnv", kwargs={"scenario": scenario},
                         vector_entry_point=native)
