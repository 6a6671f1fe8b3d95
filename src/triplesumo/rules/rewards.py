"""The paper's hybrid reward, as named terms, for every agent from its own side's view.

With torso positions ``p`` and world-frame velocities ``v`` (x and y only) after the
step, ``s(a, b) = sign(p_b - p_a)`` per axis (the direction from ``a`` to ``b``), ``O_i``
the opponents and ``P_i`` the partners of agent ``i``::

    opponent_velocity_i = C1 * mean_{o in O_i} sum_{k in x,y} s(i, o)_k * v_{o,k}
    self_velocity_i     = C2 * mean_{o in O_i} sum_{k in x,y} s(i, o)_k * v_{i,k}
    partner_velocity_i  = C3 * mean_{j in P_i} mean_{o in O_i} sum_k s(j, o)_k * v_{j,k}
    still_i             = still punishment (a negative constant, every step)
    outcome_i           = win / loss / draw reward on the step the match ends, else 0

The opponent term is positive when the opponent moves away from the agent along an
axis; the self and partner terms are positive when that agent moves toward the
opponent. Each x or y component has magnitude proportional to the speed along that
axis, as the paper describes. Where the paper has one opponent and one partner (Ant,
Bug), the means are over one element. Spider has two opponents (mean over Ant and Bug)
and no partner (its partner term is 0). ``dense = opponent + self + partner + still``,
``sparse = outcome``, ``reward = dense + sparse``, summed in this order.
"""

from __future__ import annotations

import numpy as np

from triplesumo.rules.config import RewardConfig
from triplesumo.rules.outcome import DRAW, LOSS, WIN
from triplesumo.rules.teams import Teams

DENSE_TERMS = ("reward_opponent_velocity", "reward_self_velocity", "reward_partner_velocity", "reward_still")
SPARSE_TERMS = ("reward_outcome",)
TERMS = DENSE_TERMS + SPARSE_TERMS
"""Names of the reward terms, as reported in ``info[agent]``; the reward is their sum."""


def dense_terms(pos: np.ndarray, vel: np.ndarray, teams: Teams, cfg: RewardConfig) -> dict[str, np.ndarray]:
    """Dense terms for every agent; ``pos`` and ``vel`` are ``(n_agents, >=2)``."""
    p, v = pos[:, :2], vel[:, :2]
    direction = np.sign(p[None, :, :] - p[:, None, :])  # [a, b] = s(a, b)
    toward = (direction * v[:, None, :]).sum(axis=2)  # [a, b]: a moving toward b
    away = (direction * v[None, :, :]).sum(axis=2)  # [a, b]: b moving away from a
    n = len(p)
    opp = (teams.opponent_weights * away).sum(axis=1)
    slf = (teams.opponent_weights * toward).sum(axis=1)
    par = (teams.partner_weights * toward[None, :, :]).sum(axis=(1, 2))
    return {
        "reward_opponent_velocity": cfg.opponent_velocity * opp,
        "reward_self_velocity": cfg.self_velocity * slf,
        "reward_partner_velocity": cfg.partner_velocity * par,
        "reward_still": np.full(n, float(cfg.still)),
    }


def outcome_term(team_results: list[str] | None, teams: Teams, cfg: RewardConfig, n_agents: int,
                 timed_out: bool) -> np.ndarray:
    """Sparse reward per agent: its team's result, a draw on time-out, else zeros."""
    if team_results is None:
        return np.full(n_agents, float(cfg.draw)) if timed_out else np.zeros(n_agents)
    value = {WIN: cfg.win, LOSS: cfg.loss, DRAW: cfg.draw}
    return np.array([float(value[team_results[t]]) for t in teams.team_of])


def total(terms: dict[str, np.ndarray]) -> np.ndarray:
    """The reward: the exact sum of the terms, in :data:`TERMS` order."""
    out = np.zeros_like(terms[TERMS[0]])
    for name in TERMS:
        out = out + terms[name]
    return out
