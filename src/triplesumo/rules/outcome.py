"""Judging a match: who left the ring, and what that means for each side.

An agent is *out* when its centre of mass (the torso free joint's position, current
after the step) is outside the ring: ``max(|x|, |y|) > half_size``.

The match ends on the first step in which any agent is out. Then every team with an
agent out loses and every other team wins. If every team has an agent out in the same
step (e.g. Spider and Bug leave together) nobody wins: the match ends as a draw
(terminated, not truncated). Reaching the step limit with nobody out is a draw by
truncation. With the paper's roster: Spider out -> the team (Ant, Bug) wins; Ant or
Bug out -> Spider wins; Spider and Ant/Bug out together -> draw.
"""

from __future__ import annotations

import numpy as np

WIN, LOSS, DRAW = "win", "loss", "draw"


def agents_out(torso_xy: np.ndarray, half_size: float) -> np.ndarray:
    """Boolean ``(n_agents,)``: whose centre of mass is outside the ring."""
    return (np.abs(torso_xy[:, :2]) > half_size).any(axis=1)


def judge(out: np.ndarray, team_of: np.ndarray, n_teams: int) -> list[str] | None:
    """Per-team result (``"win"``/``"loss"``/``"draw"``), or ``None`` while nobody is out."""
    if not out.any():
        return None
    losing = np.zeros(n_teams, dtype=bool)
    losing[team_of[out]] = True
    if losing.all():
        return [DRAW] * n_teams
    return [LOSS if lost else WIN for lost in losing]
