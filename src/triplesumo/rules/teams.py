"""Who plays with whom: partners and opponents of each agent, derived from team labels."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from triplesumo.model.specs import AgentSpec


@dataclass(frozen=True)
class Teams:
    """Team structure of a roster, as index arrays into the roster order."""

    names: tuple[str, ...]
    """Team labels in order of first appearance."""
    team_of: np.ndarray
    """``team_of[i]`` is the team index of agent ``i``."""
    partners: tuple[np.ndarray, ...]
    """``partners[i]``: indices of agent ``i``'s team-mates (not ``i`` itself)."""
    opponents: tuple[np.ndarray, ...]
    """``opponents[i]``: indices of every agent in another team."""
    opponent_weights: np.ndarray
    """``(n, n)``: ``1/|O_i|`` where ``j`` is an opponent of ``i``, else 0 (a mean over opponents)."""
    partner_weights: np.ndarray
    """``(n, n, n)``: ``[i, j, o] = 1/(|P_i| |O_i|)`` for partner ``j`` and opponent ``o`` of ``i``."""

    @classmethod
    def from_agents(cls, agents: tuple[AgentSpec, ...]) -> Teams:
        labels = list(dict.fromkeys(a.team for a in agents))
        team_of = np.array([labels.index(a.team) for a in agents])
        idx = np.arange(len(agents))
        partners = tuple(idx[(team_of == team_of[i]) & (idx != i)] for i in idx)
        opponents = tuple(idx[team_of != team_of[i]] for i in idx)
        n = len(agents)
        w_opp = np.zeros((n, n))
        w_par = np.zeros((n, n, n))
        for i in range(n):
            w_opp[i, opponents[i]] = 1.0 / len(opponents[i])
            if len(partners[i]):
                w_par[i][np.ix_(partners[i], opponents[i])] = 1.0 / (len(partners[i]) * len(opponents[i]))
        return cls(tuple(labels), team_of, partners, opponents, w_opp, w_par)
