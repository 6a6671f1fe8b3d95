"""``triplesumo.zoo``: the shipped policies (see :mod:`triplesumo.agents.zoo`) and the
Gymnasium factory of the paper's setup, which joins them to the env view."""

from __future__ import annotations

import warnings
from typing import Any

from triplesumo.agents.zoo import ZOO_DIR, available, load, make_policy, policies_from_pairs, publish

__all__ = ["ZOO_DIR", "available", "load", "make_paper_env", "make_paper_vector_env", "make_policy",
           "policies_from_pairs", "publish"]


def make_paper_env(**kwargs: Any) -> Any:
    """``TripleSumo-Paper-v2``: Bug learns; Ant and Spider are the shipped zoo policies.

    Keyword arguments are those of :class:`triplesumo.envs.single.TripleSumoEnv`;
    ``policies`` replaces the zoo's Ant and Spider.
    """
    from triplesumo.envs.single import TripleSumoEnv

    policies = kwargs.pop("policies", None) or _zoo_pair(kwargs.get("obs_mode", "paper"))
    kwargs.setdefault("learner", "bug")
    return TripleSumoEnv(policies=policies, **kwargs)


def make_paper_vector_env(num_envs: int = 1, **kwargs: Any) -> Any:
    """``gym.make_vec("TripleSumo-Paper-v2", num_envs)``: the paper's setup in ``num_envs``
    matches stepped together (:class:`triplesumo.envs.vector.TripleSumoVectorEnv`), the
    zoo's Ant and Spider acting on all matches at once."""
    from triplesumo.envs.vector import TripleSumoVectorEnv

    policies = kwargs.pop("policies", None) or _zoo_pair(kwargs.get("obs_mode", "paper"))
    kwargs.setdefault("learner", "bug")
    return TripleSumoVectorEnv(num_envs, policies=policies, **kwargs)


def _zoo_pair(obs_mode: str) -> dict[str, Any]:
    """The zoo's Ant and Spider; a ``UserWarning`` names each one trained on an older env version (whose ring
    and start differ from the one it now plays on)."""
    from triplesumo import ENV_VERSION

    pair = {}
    for name in ("ant", "spider"):
        policy, manifest = load(name, expect_obs_mode=obs_mode)
        version = manifest.get("env_version", "v0")
        if version != ENV_VERSION:
            warnings.warn(f"zoo:{name} was trained on env {version}, not {ENV_VERSION} (another start layout or "
                          f"rim); TripleSumo-Paper-{ENV_VERSION} plays it as it is until `triplesumo reproduce "
                          f"--publish` rebuilds the zoo on {ENV_VERSION}", UserWarning, stacklevel=3)
        pair[name] = policy
    return pair
