"""TripleSumo: cooperation in a physical, contact-rich, adversarial three-agent game.

A reimplementation of Wang, Das & Millard, *Learning cooperative behaviours in
adversarial multi-agent systems* (TAROS 2022), on MuJoCo, PettingZoo and Gymnasium.

``import triplesumo`` registers the Gymnasium ids (``TripleSumo-v2``,
``TripleSumo-Paper-v2``, ...) and nothing heavier: the env classes, PettingZoo and torch are
imported when first used (``triplesumo.parallel_env``, ``triplesumo.Match``, ...).
"""

from __future__ import annotations

import importlib
from typing import Any

from triplesumo._gl import ensure_headless_gl
from triplesumo.version import ENV_VERSION, __version__

ensure_headless_gl()

_LAZY = {
    "Match": "triplesumo.envs.match",
    "MatchBatch": "triplesumo.envs.batch",
    "TripleSumoEnv": "triplesumo.envs.single",
    "TripleSumoParallelEnv": "triplesumo.envs.parallel",
    "parallel_env": "triplesumo.envs.parallel",
    "vector_env": "triplesumo.envs.backends",
    "VectorMatches": "triplesumo.envs.batch",
    "MatchConfig": "triplesumo.rules.config",
    "ResetNoise": "triplesumo.rules.config",
    "RewardConfig": "triplesumo.rules.config",
    "scenarios": "triplesumo.rules.scenarios",
    "scenario_config": "triplesumo.rules.scenarios",
}

__all__ = ["ENV_VERSION", "__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    if name == "zoo":
        return importlib.import_module("triplesumo.zoo")
    raise AttributeError(f"module 'triplesumo' has no attribute {name!r}")


def _register() -> None:
    from triplesumo.registration import register_envs

    register_envs()


_register()
