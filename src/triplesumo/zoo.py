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


def older_pair() -> dict[str, str]:
    """The shipped Ant and Spider trained on another env version than this one (whose ring and start differ from
    the ones they now play on), as ``{"zoo:ant": "v1", ...}``; empty once the zoo is this version's."""
    from triplesumo.agents import zoo as shipped  # (its ZOO_DIR read now: tests point it at their own zoo)
    from triplesumo.agents.policy_file import load_json
    from triplesumo.version import ENV_VERSION

    versions = {f"zoo:{n}": str(load_json(shipped.ZOO_DIR / f"{n}.json").get("env_version", "v0"))
                for n in ("ant", "spider")}
    return {name: v for name, v in versions.items() if v != ENV_VERSION}


def _zoo_pair(obs_mode: str) -> dict[str, Any]:
    """The zoo's Ant and Spider; a ``UserWarning`` names each one trained on an older env version
    (:func:`older_pair`)."""
    from triplesumo.version import ENV_VERSION

    for name, version in older_pair().items():
        warnings.warn(f"{name} was trained on env {version}, not {ENV_VERSION} (another start layout or rim); "
                      f"TripleSumo-Paper-{ENV_VERSION} plays it as it is until `triplesumo reproduce --publish` "
                      f"rebuilds the zoo on {ENV_VERSION}", UserWarning, stacklevel=3)
    return {name: load(name, expect_obs_mode=obs_mode)[0] for name in ("ant", "spider")}
