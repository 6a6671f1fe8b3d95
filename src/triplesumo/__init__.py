"""TripleSumo: cooperation in a physical, contact-rich, adversarial three-agent game.

A reimplementation of Wang, Das & Millard, *Learning cooperative behaviours in
adversarial multi-agent systems* (TAROS 2022), on MuJoCo, PettingZoo and Gymnasium.
"""

from triplesumo._gl import ensure_headless_gl

ensure_headless_gl()

from triplesumo.envs import Match, TripleSumoEnv, TripleSumoParallelEnv, parallel_env, register_envs  # noqa: E402
from triplesumo.rules import MatchConfig, ResetNoise, RewardConfig  # noqa: E402

__version__ = "0.1.0"
ENV_VERSION = "v0"

register_envs()

__all__ = ["ENV_VERSION", "Match", "MatchConfig", "ResetNoise", "RewardConfig", "TripleSumoEnv",
           "TripleSumoParallelEnv", "__version__", "parallel_env"]
