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

    @classmethod
    def from_agents(cls, agents: tuple[AgentSpec, ...]) -> Teams:
        labels = list(dict.fromkeys(a.team for a in agents))
        team_of = np.array([labels.index(a.team) for a in agents])
        idx = np.arange(len(agents))
        partners = tuple(idx[(team_of == team_of[i]) & (idx != i)] for i in idx)
        opponents = tuple(idx[team_of != team_of[i]] for i in idx)
        return cls(tuple(labels), team_of, partners, opponents)
