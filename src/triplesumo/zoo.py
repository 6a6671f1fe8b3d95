"""``triplesumo.zoo``: the shipped policies (see :mod:`triplesumo.agents.zoo`) and the
Gymnasium factory of the paper's setup, which joins them to the env view."""

from __future__ import annotations

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

    obs_mode = kwargs.get("obs_mode", "paper")
    policies = kwargs.pop("policies", None) or {
        "ant": load("ant", expect_obs_mode=obs_mode)[0],
        "spider": load("spider", expect_obs_mode=obs_mode)[0],
    }
    kwargs.setdefault("learner", "bug")
    return TripleSumoEnv(policies=policies, **kwargs)


def make_paper_vector_env(num_envs: int = 1, **kwargs: Any) -> Any:
    """``gym.make_vec("TripleSumo-Paper-v2", num_envs)``: the paper's setup in ``num_envs``
    matches stepped together (:class:`triplesumo.envs.vector.TripleSumoVectorEnv`), the
    zoo's Ant and Spider acting on all matches at once."""
    from triplesumo.envs.vector import TripleSumoVectorEnv

    obs_mode = kwargs.get("obs_mode", "paper")
    policies = kwargs.pop("policies", None) or {
        "ant": load("ant", expect_obs_mode=obs_mode)[0],
        "spider": load("spider", expect_obs_mode=obs_mode)[0],
    }
    kwargs.setdefault("learner", "bug")
    return TripleSumoVectorEnv(num_envs, policies=policies, **kwargs)
