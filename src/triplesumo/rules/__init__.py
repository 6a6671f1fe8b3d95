"""The game: teams, outcome judging, observations, reward terms and their config; each rule written once over arrays."""

from triplesumo.rules.config import MatchConfig, ResetNoise, RewardConfig
from triplesumo.rules.outcome import DRAW, LOSS, WIN
from triplesumo.rules.rewards import DENSE_TERMS, SPARSE_TERMS, TERMS
from triplesumo.rules.teams import Teams

__all__ = ["DENSE_TERMS", "DRAW", "LOSS", "SPARSE_TERMS", "TERMS", "WIN", "MatchConfig", "ResetNoise",
           "RewardConfig", "Teams"]
