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

from collections.abc import Sequence

WIN, LOSS, DRAW = "win", "loss", "draw"

OUTCOME_CODES: dict[str | None, int] = {None: 0, WIN: 1, LOSS: 2, DRAW: 3, "error": 4}
"""Integer code of each outcome in batched infos: ``None`` (the match goes on), win, loss, draw,
and ``"error"`` (physics error, the match truncated)."""


def agents_out(torso_xy: Sequence[Sequence[float]], half_size: float) -> list[bool]:
    """Whose centre of mass is outside the ring, per agent; ``torso_xy`` rows start with x, y.

    Plain Python on the rows (a list, or an array's ``tolist()``): for a handful of agents
    this is several times faster than numpy's per-call overhead.
    """
    return [abs(row[0]) > half_size or abs(row[1]) > half_size for row in torso_xy]


def judge(out: Sequence[bool], team_of: Sequence[int], n_teams: int) -> list[str] | None:
    """Per-team result (``"win"``/``"loss"``/``"draw"``), or ``None`` while nobody is out."""
    if not any(out):
        return None
    losing = [False] * n_teams
    for is_out, team in zip(out, team_of, strict=True):
        if is_out:
            losing[team] = True
    if all(losing):
        return [DRAW] * n_teams
    return [LOSS if lost else WIN for lost in losing]
