"""A game's roster and reward weights as small constant arrays: what every rule over arrays reads.

:class:`BatchedRules` is built once per :class:`~triplesumo.rules.config.MatchConfig` on the host (numpy), and
copied into another namespace (torch on a device) by :meth:`BatchedRules.to`. The rules themselves are
functions of :mod:`.outcome`, :mod:`.rewards` and :mod:`.observations`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from triplesumo.rules.codes import DRAW_CODE, ERROR_CODE, LOSS_CODE, PLAYING, WIN_CODE
from triplesumo.rules.config import MatchConfig, RewardConfig
from triplesumo.rules.teams import Teams


@dataclass(frozen=True)
class BatchedRules:
    """The game of one :class:`MatchConfig`, as small constant matrices over the roster.

    Built once on the host (numpy, float64); :meth:`to` copies the matrices into another
    namespace (e.g. torch on a device) for the rule functions.
    """

    n_agents: int
    half_size: float
    max_steps: int
    force_clip: float
    team_onehot: Any
    """``(n_agents, n_teams)`` 1.0 where agent ``i`` plays for team ``t``."""
    opponents: Any
    """``(n_agents, n_agents)`` 1.0 where ``j`` is an opponent of ``i`` (row ``i``)."""
    partners: Any
    """``(n_agents, n_agents)`` 1.0 where ``j`` is a partner of ``i`` (row ``i``)."""
    n_opponents: Any
    """``(n_agents,)`` how many opponents each agent has (at least one in a valid roster): the divisor of the
    per-opponent sums, 1 with ``RewardConfig.opponents="sum"``."""
    n_partners: Any
    """``(n_agents,)`` how many partners, or 1 where there are none (the partner term is 0 then)."""
    others: Any
    """``(n_agents, n_agents - 1)`` integer: each agent's partners, then opponents, roster order
    (the order of the ``egocentric`` observation's blocks)."""
    weights: tuple[float, float, float, float]
    """C1, C2, C3 and the still punishment."""
    outcome_values: tuple[float, float, float]
    """Sparse reward of a win, a loss and a draw."""
    outcome_table: Any
    """``(5,)`` the sparse reward of each outcome code (0 for a match that goes on, and for an error)."""
    axis_dead_zone: float = 0.0
    """``RewardConfig.axis_dead_zone``: a per-axis direction within it counts as 0."""
    opponents_mean: bool = True
    """``RewardConfig.opponents == "mean"``: per-opponent sums are averaged (else summed)."""
    evader_team: int = -1
    """Team of ``MatchConfig.evader`` (it wins at the step limit under elimination rules); -1: none."""
    opponents_twice: Any = None
    """``(2 n, n)``: :attr:`opponents` stacked twice (the self rows, then the opponent rows, of
    :func:`~triplesumo.rules.rewards.reward_terms`' per-agent sums)."""
    n_opponents_twice: Any = None
    """``(2 n,)``: :attr:`n_opponents` twice."""
    term_weights: Any = None
    """``(2 n,)``: C2 for the self entries, then C1 for the opponent entries."""

    @classmethod
    def build(cls, config: MatchConfig, half_size: float) -> BatchedRules:
        teams = Teams.from_agents(config.agents)
        evader = config.agent_names.index(config.evader) if config.evader is not None else None
        return cls.from_roster(teams, config.reward, half_size, config.max_steps, config.contact_force_clip,
                               -1 if evader is None else int(teams.team_of[evader]))

    @classmethod
    def from_roster(cls, teams: Teams, r: RewardConfig, half_size: float, max_steps: int, force_clip: float,
                    evader_team: int = -1) -> BatchedRules:
        """:meth:`build` from a roster's :class:`Teams` and a :class:`RewardConfig`."""
        n = len(teams.team_of)
        onehot = np.zeros((n, len(teams.names)))
        onehot[np.arange(n), teams.team_of] = 1.0
        opponents, partners = np.zeros((n, n)), np.zeros((n, n))
        for i in range(n):
            opponents[i, teams.opponents[i]] = 1.0
            partners[i, teams.partners[i]] = 1.0
        others = np.stack([np.concatenate([teams.partners[i], teams.opponents[i]]) for i in range(n)]).astype(np.int64)
        table = np.zeros(max(PLAYING, WIN_CODE, LOSS_CODE, DRAW_CODE, ERROR_CODE) + 1)
        table[[WIN_CODE, LOSS_CODE, DRAW_CODE]] = r.win, r.loss, r.draw
        mean = r.opponents == "mean"
        return cls(n, float(half_size), int(max_steps), float(force_clip), onehot, opponents,
                   partners, opponents.sum(1) if mean else np.ones(n),
                   np.maximum(partners.sum(1), 1.0), others,
                   (float(r.opponent_velocity), float(r.self_velocity), float(r.partner_velocity), float(r.still)),
                   (float(r.win), float(r.loss), float(r.draw)), table, float(r.axis_dead_zone), mean,
                   int(evader_team), np.concatenate([opponents] * 2),
                   np.concatenate([opponents.sum(1) if mean else np.ones(n)] * 2),
                   np.array([float(r.self_velocity)] * n + [float(r.opponent_velocity)] * n))

    def to(self, convert: Any) -> BatchedRules:
        """The same rules with every matrix passed through ``convert`` (e.g. ``lambda a: torch.as_tensor(a, ...)``)."""
        return BatchedRules(self.n_agents, self.half_size, self.max_steps, self.force_clip,
                            convert(self.team_onehot), convert(self.opponents), convert(self.partners),
                            convert(self.n_opponents), convert(self.n_partners), convert(self.others),
                            self.weights, self.outcome_values, convert(self.outcome_table), self.axis_dead_zone,
                            self.opponents_mean, self.evader_team, convert(self.opponents_twice),
                            convert(self.n_opponents_twice), convert(self.term_weights))
