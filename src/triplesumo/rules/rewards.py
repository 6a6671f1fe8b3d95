"""The paper's hybrid reward, as named terms, for every agent from its own side's view.

Written once, over arrays of ``E`` matches in an array namespace ``xp`` (:func:`reward_terms`): numpy for
one match (``E = 1``) and the CPU vector env, torch on the MuJoCo Warp backend's device.

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

from typing import Any

import numpy as np

from triplesumo.rules.codes import DRAW, DRAW_CODE, LOSS, PLAYING, WIN
from triplesumo.rules.config import RewardConfig
from triplesumo.rules.roster import BatchedRules
from triplesumo.rules.teams import Teams

DENSE_TERMS = ("reward_opponent_velocity", "reward_self_velocity", "reward_partner_velocity", "reward_still")
SPARSE_TERMS = ("reward_outcome",)
TERMS = DENSE_TERMS + SPARSE_TERMS
"""Names of the reward terms, as reported in ``info[agent]``; the reward is their sum."""


REPORTED = (*TERMS, "dense_reward", "sparse_reward")
"""Entries of each agent's reward row (:meth:`RewardRule.rows`, ``Match`` infos): each term, then dense and sparse."""


def ordered_sum(values: Any, axis: int) -> Any:
    """Sum over ``axis`` (a small one: the roster) index by index, ``((v_0 + v_1) + v_2) + ...``.

    One association on every path and namespace (``sum`` or ``@`` may pair the terms in another
    order on another backend or batch size), so that one match and many give the same bits. Masked
    sums (zeros where an agent is not an opponent or partner) change nothing: adding an exact zero
    is exact.
    """
    if axis == -1:  # the common cases, indexed directly (this runs on every step of every match)
        total = values[..., 0]
        for j in range(1, values.shape[-1]):
            total = total + values[..., j]
        return total
    index: list[Any] = [slice(None)] * (axis if axis >= 0 else values.ndim + axis)
    total = values[(*index, 0)]
    for j in range(1, values.shape[axis]):
        total = total + values[(*index, j)]
    return total


def reward_terms(pos: Any, vel: Any, code: Any, timed_out: Any, rules: BatchedRules, xp: Any, *,
                 alive: Any = None, sparse: Any = None) -> dict[str, Any]:
    """Every reward term of :data:`TERMS` as ``(E, n)`` arrays, plus ``dense_reward``, ``sparse_reward``
    and ``reward`` (= dense + sparse, summed in that order, as the module docstring says).

    ``pos``, ``vel``: ``(E, n, >=2)`` torso positions and world-frame velocities after the step.
    ``first_out`` rules: ``code`` is :func:`~triplesumo.rules.outcome.judge`'s ``(E, n)`` codes and
    ``timed_out`` ``(E,)`` the step limit reached (a draw). ``elimination`` rules: ``alive`` ``(E, n)``
    bool, who is in play at the step's start (the opponents and partners the terms run over; all
    zeros for an agent not in play), and ``sparse`` ``(E, n)`` the placement rewards
    (:func:`~triplesumo.rules.outcome.place_values`), which replace ``code`` and ``timed_out``.
    """
    c1, c2, c3, still = rules.weights
    n = rules.n_agents
    xy, v = pos[..., :2], vel[..., :2]
    d = xy[:, None] - xy[:, :, None]  # (E, a, o, 2): from a to o
    s = xp.sign(d)  # the direction from a to o, per axis
    if rules.axis_dead_zone > 0:  # 0 inside the band (at 0 the paper's sign, untouched)
        s = xp.where(abs(d) > rules.axis_dead_zone, s, 0.0 * s)
    # per pair (a, o), x plus y (the sum of two, spelt out: cheaper than a reduction on one match):
    # rows 0..n-1 a moving toward o, rows n..2n-1 o moving away from a
    moves = xp.concat([s * v[:, :, None], s * v[:, None]], axis=1)  # (E, 2n, o, 2)
    moves = moves[..., 0] + moves[..., 1]
    if alive is None:
        opp, partners, n_opp, n_par = rules.opponents, rules.partners, rules.n_opponents, rules.n_partners
        opp2, n_opp2 = rules.opponents_twice, rules.n_opponents_twice
    else:  # only agents in play count as opponents and partners
        playing = xp.where(alive, 1.0, 0.0)
        opp = rules.opponents * playing[:, None, :]  # (E, i, o)
        partners = rules.partners * playing[:, None, :]  # (E, i, j)
        n_opp = opp.sum(-1) if rules.opponents_mean else playing * 0.0 + 1.0
        n_opp = xp.where(n_opp > 0, n_opp, 1.0)  # no opponent left: the sums are 0
        n_par = xp.maximum(partners.sum(-1), playing * 0.0 + 1.0)
        opp2, n_opp2 = xp.concat([opp, opp], axis=1), xp.concat([n_opp, n_opp], axis=1)
    # [e, r] = sum over the opponents o of agent r mod n of moves[e, r, o], over their count: row i of the
    # first block is i's self term, row n + i of the second its opponent term (before the weights)
    per_agent = ordered_sum(moves * opp2, -1) / n_opp2
    self_opp = per_agent * rules.term_weights
    self_, opponent = self_opp[:, :n], self_opp[:, n:]
    # a partner j of i has i's opponents (teams partition the roster), so j's own per-opponent mean
    # toward them is the one i's partner term averages
    partner = c3 * (ordered_sum(per_agent[:, None, :n] * partners, -1) / n_par)
    if sparse is None:
        sparse = rules.outcome_table[xp.where(timed_out[:, None] & (code == PLAYING), DRAW_CODE, code)]
    if alive is None:
        still_term = opponent * 0.0 + still
    else:  # an agent no longer in play gets all zeros
        opponent, self_, partner = (xp.where(alive, t, 0.0) for t in (opponent, self_, partner))
        still_term = xp.where(alive, still, 0.0)
    dense = opponent + self_ + partner + still_term
    terms = dict(zip(TERMS, (opponent, self_, partner, still_term, sparse), strict=True))
    return {**terms, "dense_reward": dense, "sparse_reward": sparse, "reward": dense + sparse}


class RewardRule:
    """One match's view of :func:`reward_terms` for a roster and :class:`RewardConfig`: rows of plain
    floats from plain sequences (hand-made scenarios, tests). :class:`~triplesumo.envs.match.Match`
    calls :func:`reward_terms` itself."""

    def __init__(self, teams: Teams, cfg: RewardConfig) -> None:
        self.teams, self.cfg = teams, cfg
        self.n_agents = len(teams.team_of)
        self._team_of = [int(t) for t in teams.team_of]
        self._rules = BatchedRules.from_roster(teams, cfg, half_size=np.inf, max_steps=0, force_clip=np.inf)
        self._value = {WIN: float(cfg.win), LOSS: float(cfg.loss), DRAW: float(cfg.draw)}

    def outcome(self, team_results: list[str] | None, timed_out: bool) -> list[float]:
        """Sparse reward per agent: its team's result, a draw on time-out, else zeros."""
        if team_results is None:
            return [self._value[DRAW] if timed_out else 0.0] * self.n_agents
        return [self._value[team_results[t]] for t in self._team_of]

    def rows(self, pos: Any, vel: Any, team_results: list[str] | None, timed_out: bool) -> list[tuple[float, ...]]:
        """Per agent, the :data:`REPORTED` values: each term, then dense and sparse; ``team_results`` per team
        (``"win"``, ``"loss"``, ``"draw"``) or ``None`` while the match goes on."""
        sparse = np.array([self.outcome(team_results, timed_out)])
        terms = self._terms(pos, vel, sparse)
        return [tuple(row) for row in np.stack([terms[k][0] for k in REPORTED], axis=1).tolist()]

    def _terms(self, pos: Any, vel: Any, sparse: np.ndarray) -> dict[str, Any]:
        zeros = np.zeros((1, self.n_agents), np.int64)
        terms = reward_terms(np.asarray(pos, float)[None], np.asarray(vel, float)[None], zeros,
                             np.zeros(1, bool), self._rules, np)
        dense = terms["dense_reward"]
        return {**terms, "reward_outcome": sparse, "sparse_reward": sparse, "reward": dense + sparse}

    def dense(self, pos: Any, vel: Any) -> list[tuple[float, float, float]]:
        """Per agent: the (opponent, self, partner) velocity terms."""
        terms = self._terms(pos, vel, np.zeros((1, self.n_agents)))
        return [tuple(row) for row in np.stack([terms[k][0] for k in DENSE_TERMS[:3]], axis=1).tolist()]


def dense_terms(pos: np.ndarray, vel: np.ndarray, teams: Teams, cfg: RewardConfig) -> dict[str, np.ndarray]:
    """Dense terms for every agent by name, as arrays; ``pos`` and ``vel`` are ``(n_agents, >=2)``.

    A convenience around :func:`reward_terms` for one match.
    """
    terms = RewardRule(teams, cfg)._terms(pos, vel, np.zeros((1, len(teams.team_of))))
    return {name: terms[name][0] for name in DENSE_TERMS}
