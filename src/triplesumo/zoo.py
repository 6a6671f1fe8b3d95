"""``triplesumo.zoo``: the shipped policies (see :mod:`triplesumo.agents.zoo`) and the
Gymnasium factory of the paper's setup, which joins them to the env view.

Here policies meet the match they play: a policy file records the ring it was trained on (its manifest's
``physics``, :func:`policy_ring`), and :func:`make_policy`, :func:`policies_from_pairs` and :func:`load`, given the
match's simulation, refuse one trained on another ring (rim, start layout), naming both rings and the file,
unless ``allow_other_ring``; :func:`publish` refuses a manifest whose ring is invalid. (The loaders of
:mod:`triplesumo.agents.zoo` know nothing of the physics.)
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

from triplesumo.agents import zoo as _files
from triplesumo.agents.builtin import ACTION_SIZE, BUILTIN
from triplesumo.agents.policy_file import bare_stem, load_json, policy_paths
from triplesumo.agents.zoo import ZOO_DIR, available

if TYPE_CHECKING:
    from triplesumo.model.specs import PhysicsConfig

__all__ = ["ZOO_DIR", "available", "check_ring", "load", "make_paper_env", "make_paper_vector_env", "make_policy",
           "policies_from_pairs", "policy_ring", "publish"]


def policy_ring(spec: str) -> PhysicsConfig:
    """The simulation the policy file ``spec`` (``zoo:NAME`` or a path) was trained on, by its manifest
    (:func:`~triplesumo.model.specs.recorded_physics`: its ``physics``; without one, its env version's default,
    env v0's for a manifest naming none); :class:`~triplesumo.model.specs.RingError` naming the manifest and the
    field for an invalid record."""
    from triplesumo.model.specs import recorded_physics

    meta = policy_paths(_files.find_policy_file(spec))[0]
    return recorded_physics(load_json(meta), str(meta))


def check_ring(spec: str, physics: PhysicsConfig, allow_other_ring: bool = False) -> None:
    """:class:`~triplesumo.model.specs.RingError` naming the policy file and both rings unless the policy ``spec``
    was trained on the ring of ``physics`` (the match's simulation), or ``allow_other_ring``; built-in policies play
    on any ring. A manifest whose ring is invalid is refused either way."""
    if spec in BUILTIN:
        return
    from triplesumo.model.specs import RingError, ring_problem

    trained = policy_ring(spec)
    problem = None if allow_other_ring else ring_problem(trained, physics)
    if problem is not None:
        raise RingError(f"{policy_paths(_files.find_policy_file(spec))[0]}: {problem}")


def make_policy(spec: str, seed: int | None = None, expect_obs_mode: str | None = None,
                action_size: int = ACTION_SIZE, expect_obs_dim: int | None = None,
                expect_physics: PhysicsConfig | None = None, allow_other_ring: bool = False,
                frozen: bool | None = None) -> Any:
    """:func:`triplesumo.agents.zoo.make_policy` (a policy callable from its name: built-in, ``zoo:NAME`` or a
    policy-file path; ``frozen`` picks the numpy or the torch actor, by default the torch one where torch is
    installed), for a match on ``expect_physics``: a policy file trained on another ring is refused
    (:func:`check_ring`) unless ``allow_other_ring``. Without ``expect_physics`` the ring is not checked."""
    policy = _files.make_policy(spec, seed=seed, expect_obs_mode=expect_obs_mode, action_size=action_size,
                                expect_obs_dim=expect_obs_dim, frozen=frozen)
    if expect_physics is not None:
        check_ring(spec, expect_physics, allow_other_ring)
    return policy


def policies_from_pairs(pairs: tuple[str, ...], seed: int, obs_mode: str,
                        action_sizes: dict[str, int] | None = None, obs_dims: dict[str, int] | None = None,
                        teams: dict[str, str] | None = None, physics: PhysicsConfig | None = None,
                        allow_other_ring: bool = False) -> dict[str, Any]:
    """:func:`triplesumo.agents.zoo.policies_from_pairs` (``("ant=zoo:ant", "spider=random")`` -> ``{"ant": policy,
    "spider": policy}``, checked against the roster), for a match on ``physics``: a policy file trained on another
    ring is refused (:func:`check_ring`) unless ``allow_other_ring``."""
    out = _files.policies_from_pairs(pairs, seed, obs_mode, action_sizes=action_sizes, obs_dims=obs_dims, teams=teams)
    if physics is not None:
        for pair in pairs:
            check_ring(pair.split("=")[1], physics, allow_other_ring)
    return out


def load(name: str, expect_obs_mode: str | None = None, expect_physics: PhysicsConfig | None = None,
         allow_other_ring: bool = False) -> tuple[Any, dict[str, Any]]:
    """:func:`triplesumo.agents.zoo.load` (a shipped policy as numpy, and its manifest), for a match on
    ``expect_physics``: one trained on another ring is refused (:func:`check_ring`) unless ``allow_other_ring``."""
    loaded = _files.load(name, expect_obs_mode=expect_obs_mode)
    if expect_physics is not None:
        check_ring(f"zoo:{name}", expect_physics, allow_other_ring)
    return loaded


def publish(policy_stem: Path, name: str, evaluation: dict[str, Any] | None = None,
            zoo_dir: Path | None = None, extra: dict[str, Any] | None = None) -> Path:
    """:func:`triplesumo.agents.zoo.publish` (copy a trained policy file pair into the zoo as ``name``), refusing a
    manifest whose ring is invalid (its ``physics`` with ``extra``'s entries, e.g. an unknown layout:
    :class:`~triplesumo.model.specs.RingError` naming the file and the field) before anything is written."""
    from triplesumo.model.specs import recorded_physics

    meta = policy_paths(bare_stem(policy_stem))[0]
    recorded_physics({**load_json(meta), **(extra or {})}, f"{meta}" + (" (with the extra entries)" if extra else ""))
    return _files.publish(Path(policy_stem), name, evaluation, zoo_dir=zoo_dir, extra=extra)


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
