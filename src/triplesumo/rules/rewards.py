"""The paper's hybrid reward, as named terms, for every agent from its own side's view.

With torso positions ``p`` and world-frame velocities ``v`` (x and y only) after the
step, ``s(a, b) = sign(p_b - p_a)`` per axis (the direction from ``a`` to ``b``; 0 where
``|p_b - p_a| <= RewardConfig.axis_dead_zone`` on that axis, 0 m by default: the paper's sign), ``O_i``
the opponents and ``P_i`` the partners of agent ``i``::

    opponent_velocity_i = C1 * mean_{o in O_i} sum_{k in x,y} s(i, o)_k * v_{o,k}
    self_velocity_i     = C2 * mean_{o in O_i} sum_{k in x,y} s(i, o)_k * v_{i,k}
    partner_velocity_i  = C3 * mean_{j in P_i} mean_{o in O_i} sum_k s(j, o)_k * v_{j,k}
    still_i             = still punishment (a negative constant, every step)
    outcome_i           = win / loss / draw reward on the step the match ends, else 0

(``RewardConfig.opponents="sum"`` sums over ``O_i`` instead of averaging: the same for one opponent.)

The opponent term is positive when the opponent moves away from the agent along an
axis; the self and partner terms are positive when that agent moves toward the
opponent. Each x or y component has magnitude proportional to the speed along that
axis, as the paper describes. Where the paper has one opponent and one partner (Ant,
Bug), the means are over one element. Spider has two opponents (mean over Ant and Bug)
and no partner (its partner term is 0). ``dense = opponent + self + partner + still``,
``sparse = outcome``, ``reward = dense + sparse``, summed in this order.

Under ``elimination`` rules the opponents and partners of a step are those in play at its
start (an agent leaving on this step still counts; one gone before does not); an agent
left without opponents gets 0 for the velocity terms; the outcome term is the placement
reward (:func:`triplesumo.rules.outcome.place_value`); an agent no longer in play gets
all zeros.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from triplesumo.rules.config import RewardConfig
from triplesumo.rules.outcome import DRAW, LOSS, WIN
from triplesumo.rules.teams import Teams

DENSE_TERMS = ("reward_opponent_velocity", "reward_self_velocity", "reward_partner_velocity", "reward_still")
SPARSE_TERMS = ("reward_outcome",)
TERMS = DENSE_TERMS + SPARSE_TERMS
"""Names of the reward terms, as reported in ``info[agent]``; the reward is their sum."""


REPORTED = (*TERMS, "dense_reward", "sparse_reward")
"""Entries of each agent's row of :meth:`RewardRule.rows`: every term, then ``dense`` and ``sparse``."""


class RewardRule:
    """The reward terms of every agent for one roster and :class:`RewardConfig`.

    Built once per match: it lists the ordered (agent, opponent) pairs the terms need and,
    per agent, which pairs its means run over. A step then computes each pair's
    sign-times-velocity sums once, in plain Python floats (for a handful of agents that is
    several times faster than numpy's per-call overhead), and averages them as the module
    docstring says.
    """

    def __init__(self, teams: Teams, cfg: RewardConfig) -> None:
        self.teams, self.cfg = teams, cfg
        n = len(teams.team_of)
        self.n_agents = n
        pairs = [(a, int(o)) for a in range(n) for o in teams.opponents[a]]
        self._pairs = pairs
        pair_index = {pair: k for k, pair in enumerate(pairs)}
        self._opponent_pairs = [[pair_index[i, int(o)] for o in teams.opponents[i]] for i in range(n)]
        """``[i]``: the pairs (i, o) over the opponents ``o`` of ``i``."""
        self._partner_pairs = [[[pair_index[int(j), int(o)] for o in teams.opponents[i]] for j in teams.partners[i]]
                               for i in range(n)]
        """``[i][j]``: the pairs (j, o) of partner ``j`` of ``i`` over the opponents ``o`` of ``i``."""
        self._team_of = [int(t) for t in teams.team_of]
        self._c = (float(cfg.opponent_velocity), float(cfg.self_velocity), float(cfg.partner_velocity))
        self._still = float(cfg.still)
        self._dead = float(cfg.axis_dead_zone)
        self._mean = cfg.opponents == "mean"
        self._value = {WIN: float(cfg.win), LOSS: float(cfg.loss), DRAW: float(cfg.draw)}

    def dense(self, pos: Sequence[Sequence[float]], vel: Sequence[Sequence[float]]) -> list[tuple[float, float, float]]:
        """Per agent: the (opponent, self, partner) velocity terms. Rows of ``pos`` and ``vel``
        (lists, e.g. an array's ``tolist()``) start with the x and y components."""
        toward, away = [], []  # per pair (a, o): a moving toward o; o moving away from a
        e = self._dead
        for a, o in self._pairs:
            pa, po, va, vo = pos[a], pos[o], vel[a], vel[o]
            dx, dy = po[0] - pa[0], po[1] - pa[1]
            sx, sy = (dx > e) - (dx < -e), (dy > e) - (dy < -e)
            toward.append(sx * va[0] + sy * va[1])
            away.append(sx * vo[0] + sy * vo[1])
        c1, c2, c3 = self._c
        out = []
        for opponent_pairs, partner_pairs in zip(self._opponent_pairs, self._partner_pairs, strict=True):
            n_opp = len(opponent_pairs) if self._mean else 1
            sum_away = sum_toward = 0.0
            for k in opponent_pairs:
                sum_away += away[k]
                sum_toward += toward[k]
            par = 0.0
            if partner_pairs:
                for pairs in partner_pairs:
                    sum_partner = 0.0
                    for k in pairs:
                        sum_partner += toward[k]
                    par += sum_partner / n_opp
                par = c3 * (par / len(partner_pairs))
            out.append((c1 * (sum_away / n_opp), c2 * (sum_toward / n_opp), par))
        return out

    def dense_in_play(self, pos: Sequence[Sequence[float]], vel: Sequence[Sequence[float]],
                      alive: Sequence[bool]) -> list[tuple[float, float, float]]:
        """:meth:`dense` over the agents in play only; ``(0, 0, 0)`` for an agent not in play."""
        if all(alive):
            return self.dense(pos, vel)
        c1, c2, c3 = self._c
        team_of = self._team_of
        e = self._dead

        def toward(a: int, o: int, mover: int) -> float:
            dx, dy = pos[o][0] - pos[a][0], pos[o][1] - pos[a][1]
            return ((dx > e) - (dx < -e)) * vel[mover][0] + ((dy > e) - (dy < -e)) * vel[mover][1]

        out = []
        for i in range(self.n_agents):
            opponents = [o for o in range(self.n_agents) if alive[o] and team_of[o] != team_of[i]]
            if not alive[i] or not opponents:
                out.append((0.0, 0.0, 0.0))
                continue
            partners = [j for j in range(self.n_agents) if alive[j] and j != i and team_of[j] == team_of[i]]
            n_opp = len(opponents) if self._mean else 1
            opp = c1 * sum(toward(i, o, o) for o in opponents) / n_opp
            slf = c2 * sum(toward(i, o, i) for o in opponents) / n_opp
            par = 0.0
            if partners:
                par = c3 * sum(sum(toward(j, o, j) for o in opponents) / n_opp for j in partners) / len(partners)
            out.append((opp, slf, par))
        return out

    def rows_in_play(self, pos: Sequence[Sequence[float]], vel: Sequence[Sequence[float]], alive: Sequence[bool],
                     sparse: Sequence[float]) -> list[tuple[float, ...]]:
        """:meth:`rows` under ``elimination`` rules: ``alive`` at the step's start and each
        agent's placement reward ``sparse``; all zeros for an agent not in play."""
        rows: list[tuple[float, ...]] = []
        for (opp, slf, par), outcome, playing in zip(self.dense_in_play(pos, vel, alive), sparse, alive, strict=True):
            still = self._still if playing else 0.0
            rows.append((opp, slf, par, still, outcome, opp + slf + par + still, outcome))
        return rows

    def outcome(self, team_results: list[str] | None, timed_out: bool) -> list[float]:
        """Sparse reward per agent: its team's result, a draw on time-out, else zeros."""
        if team_results is None:
            return [self._value[DRAW] if timed_out else 0.0] * self.n_agents
        return [self._value[team_results[t]] for t in self._team_of]

    def rows(self, pos: Sequence[Sequence[float]], vel: Sequence[Sequence[float]], team_results: list[str] | None,
             timed_out: bool) -> list[tuple[float, ...]]:
        """Per agent, the :data:`REPORTED` values: each term, then dense and sparse.

        ``dense = opponent + self + partner + still`` and ``sparse = outcome`` are summed
        in that order, so ``dense + sparse`` is the sum of the terms in :data:`TERMS` order,
        bit for bit.
        """
        still = self._still
        rows: list[tuple[float, ...]] = []
        for (opp, slf, par), sparse in zip(self.dense(pos, vel), self.outcome(team_results, timed_out), strict=True):
            rows.append((opp, slf, par, still, sparse, opp + slf + par + still, sparse))
        return rows


def dense_terms(pos: np.ndarray, vel: np.ndarray, teams: Teams, cfg: RewardConfig) -> dict[str, np.ndarray]:
    """Dense terms for every agent by name, as arrays; ``pos`` and ``vel`` are ``(n_agents, >=2)``.

    A convenience around :class:`RewardRule` (which a match builds once).
    """
    rule = RewardRule(teams, cfg)
    terms = np.array(rule.dense(np.asarray(pos).tolist(), np.asarray(vel).tolist())).reshape(-1, 3).T
    return {**dict(zip(DENSE_TERMS[:3], terms, strict=True)), "reward_still": np.full(rule.n_agents, rule._still)}
