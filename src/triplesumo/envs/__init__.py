"""Views of one match: the framework-free core, PettingZoo and Gymnasium."""

from triplesumo.envs.batch import MatchBatch
from triplesumo.envs.match import Match, StepResult
from triplesumo.envs.parallel import TripleSumoParallelEnv, parallel_env
from triplesumo.envs.single import Policy, TripleSumoEnv
from triplesumo.registration import ENV_IDS, register_envs

__all__ = ["ENV_IDS", "Match", "MatchBatch", "Policy", "StepResult", "TripleSumoEnv",
           "TripleSumoParallelEnv", "parallel_env", "register_envs"]
