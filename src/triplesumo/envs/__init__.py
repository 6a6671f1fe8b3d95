"""Views of one match: the framework-free core, PettingZoo and Gymnasium."""

from triplesumo.envs.batch import MatchBatch
from triplesumo.envs.match import ACTION_SIZE, Match, StepResult
from triplesumo.envs.parallel import TripleSumoParallelEnv, parallel_env
from triplesumo.envs.single import Policy, TripleSumoEnv
from triplesumo.registration import ENV_IDS, register_envs

__all__ = ["ACTION_SIZE", "ENV_IDS", "Match", "MatchBatch", "Policy", "StepResult", "TripleSumoEnv",
           "TripleSumoParallelEnv", "parallel_env", "register_envs"]
