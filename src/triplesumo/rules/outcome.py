"""Judging a match: who left the ring, and what that means for each side.

An agent is *out* when its centre of mass (the torso free joint's position, current
after the step) is outside the ring: ``max(|x|, |y|) > half_size``.

The match ends on the first step in which any agent is out. Then every team with an
agent out loses and every other team wins. If every team has an agent out in the same
step (e.g. Spider and Bug leave together) nobody wins: the match ends as a draw
(terminated, not truncated). Reaching the step limit with nobody out is a draw by
truncation. With the paper's roster: Spider out -> the team (Ant, Bug) wins; Ant or
Bug out -> Spider wins; Spider and Ant/Bug out together -> draw.

Infos report an agent's outcome as an int code (:data:`OUTCOME_CODES`), the same type at
reset and every step so that tensor-based clients (TorchRL) can stack it;
:data:`OUTCOME_NAMES` turns a code back into its name where a string is the point
(metrics CSVs, printed results).
"""

from __future__ import annotations

from collections.abc import Sequence

WIN, LOSS, DRAW = "win", "loss", "draw"
ERROR = "error"
"""A physics error truncated the match (see ``MatchConfig.on_physics_error``)."""

OUTCOME_CODES: dict[str, int] = {"playing": 0, WIN: 1, LOSS: 2, DRAW: 3, ERROR: 4}
"""Int code of each outcome in infos: 0 while the match goes on, 1 win, 2 loss, 3 draw,
4 physics error."""
PLAYING, WIN_CODE, LOSS_CODE, DRAW_CODE, ERROR_CODE = OUTCOME_CODES.values()
OUTCOME_NAMES: tuple[str, ...] = tuple(OUTCOME_CODES)
"""``OUTCOME_NAMES[code]`` is the outcome's name (``"playing"`` for 0)."""


def outcome_name(code: int) -> str:
    """The name of an outcome code (``"win"``, ...); ``ValueError`` for an unknown code."""
    if not 0 <= int(code) < len(OUTCOME_NAMES):
        raise ValueError(f"unknown outcome code {code!r}; codes are {OUTCOME_CODES}")
    return OUTCOME_NAMES[int(code)]


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
