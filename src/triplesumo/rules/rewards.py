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


REPORTED = (*TERMS, "dense_reward", "sparse_reward")
"""Rows of :meth:`RewardRule.table`: every term, then ``dense`` and ``sparse``."""


class RewardRule:
    """The reward of every agent for one roster and :class:`RewardConfig`, computed fast.

    The weights ``C1``..``C3`` and the means over opponents and partners are folded, once,
    into one matrix, so that a step's three velocity terms are one matrix product with
    the sign-times-velocity products (the formulas are in this module's docstring).
    """

    def __init__(self, teams: Teams, cfg: RewardConfig) -> None:
        self.teams, self.cfg = teams, cfg
        n = len(teams.team_of)
        self.n_agents = n
        # products[0, a, b, k] = s(a, b)_k * v_a,k ("a moves toward b");
        # products[1, a, b, k] = s(a, b)_k * v_b,k ("b moves away from a").
        a, b, k = np.meshgrid(np.arange(n), np.arange(n), np.arange(2), indexing="ij")
        self._velocity_index = np.stack([a * 2 + k, b * 2 + k])
        weights = np.zeros((3, n, 2, n, n, 2))
        w_opp, w_par = teams.opponent_weights, teams.partner_weights
        for i in range(n):
            weights[0, i, 1, i] = cfg.opponent_velocity * w_opp[i][:, None]
            weights[1, i, 0, i] = cfg.self_velocity * w_opp[i][:, None]
            weights[2, i, 0] = cfg.partner_velocity * w_par[i][:, :, None]
        self._weights = weights.reshape(3 * n, -1)
        self._still = float(cfg.still)
        self._value = {WIN: float(cfg.win), LOSS: float(cfg.loss), DRAW: float(cfg.draw)}

    def dense(self, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
        """``(3, n_agents)``: the opponent, self and partner velocity terms (``pos``, ``vel``: ``(n, >=2)``)."""
        p = pos[:, :2]
        direction = np.sign(p[None, :, :] - p[:, None, :])  # [a, b] = s(a, b)
        products = direction * np.ravel(vel[:, :2])[self._velocity_index]
        return (self._weights @ products.ravel()).reshape(3, self.n_agents)

    def outcome(self, team_results: list[str] | None, timed_out: bool) -> np.ndarray:
        """Sparse reward per agent: its team's result, a draw on time-out, else zeros."""
        if team_results is None:
            return np.full(self.n_agents, self._value[DRAW] if timed_out else 0.0)
        return np.array([self._value[team_results[t]] for t in self.teams.team_of])

    def table(self, pos: np.ndarray, vel: np.ndarray, team_results: list[str] | None,
              timed_out: bool) -> np.ndarray:
        """``(len(REPORTED), n_agents)``: each term, then dense and sparse.

        ``dense = opponent + self + partner + still`` and ``sparse = outcome`` are summed
        in that order, so ``dense + sparse`` is the sum of the terms in :data:`TERMS` order.
        """
        out = np.empty((len(REPORTED), self.n_agents))
        out[:3] = self.dense(pos, vel)
        out[3] = self._still
        out[4] = self.outcome(team_results, timed_out)
        out[5] = out[0] + out[1] + out[2] + out[3]
        out[6] = out[4]
        return out


def dense_terms(pos: np.ndarray, vel: np.ndarray, teams: Teams, cfg: RewardConfig) -> dict[str, np.ndarray]:
    """Dense terms for every agent by name; ``pos`` and ``vel`` are ``(n_agents, >=2)``.

    A convenience around :class:`RewardRule` (which a match builds once).
    """
    rule = RewardRule(teams, cfg)
    terms = rule.dense(pos, vel)
    return {**dict(zip(DENSE_TERMS[:3], terms, strict=True)), "reward_still": np.full(rule.n_agents, rule._still)}
