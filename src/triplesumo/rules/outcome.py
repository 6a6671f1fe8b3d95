"""Judging a match: who left the ring, and what that means for each side.

Two rule sets (``MatchConfig.rules``), written once here over plain sequences.

``first_out`` (the paper)

An agent is *out* when its torso centre (the torso free joint's position, current
after the step) is outside the ring: ``max(|x|, |y|) > half_size``. (The paper says
"centre of mass"; its code, like this one, tests the torso body's position, not the
whole body's centre of mass.)

The match ends on the first step in which any agent is out. Then every team with an
agent out loses and every other team wins. If every team has an agent out in the same
step (e.g. Spider and Bug leave together) nobody wins: the match ends as a draw
(terminated, not truncated). Reaching the step limit with nobody out is a draw by
truncation. With the paper's roster: Spider out -> the team (Ant, Bug) wins; Ant or
Bug out -> Spider wins; Spider and Ant/Bug out together -> draw. Places: winners 1,
losers 2; a draw shares place 1; a physics error decides no place (0)
(:func:`first_out_places`).

``elimination`` (free-for-all, pursuit)
An agent out *leaves*: it is eliminated on that step and plays no more. A team is in play
while any of its agents is. The match ends when at most one team is in play (the last
team standing wins, place 1) or at the step limit. Places count teams: an eliminated
agent's place is 1 + the number of teams other than its own still in play after the step;
several teams leaving in the same step share the best place of the places they span
(``k + 1 .. k + g`` with ``k`` teams left in play) and each gets the mean of those places'
rewards. At the step limit the surviving teams share places ``1 .. s`` (a draw), unless
one of them is the evader's: then it wins (place 1) and the other survivors share
``2 .. s``. Place ``p`` of ``n`` teams is worth ``win + (loss - win) * (p - 1) / (n - 1)``
(:func:`place_value`).

Infos report an agent's outcome as an int code (:data:`OUTCOME_CODES`), the same type at
reset and every step so that tensor-based clients (TorchRL) can stack it;
:data:`OUTCOME_NAMES` turns a code back into its name where a string is the point
(metrics CSVs, printed results).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

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
    """Whose torso centre is outside the ring, per agent; ``torso_xy`` rows start with x, y.

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


def first_out_places(code: Any, xp: Any) -> Any:
    """Place of every agent under ``first_out`` from its outcome code (:data:`OUTCOME_CODES`): 1 for a win
    or a draw (shared), 2 for a loss, 0 while the match goes on and after a physics error (nothing was
    decided: the place of reset's infos, ``Match.reset_infos``).

    ``code`` is an integer array of any shape in the namespace ``xp``: numpy for one match
    (:class:`~triplesumo.envs.match.Match`, when its match ends) or many
    (:mod:`.batched`), torch on the MuJoCo Warp backend's device. The one definition of the place
    on every path.
    """
    won = (code == WIN_CODE) | (code == DRAW_CODE)
    return xp.where(code == LOSS_CODE, 2, xp.where(won, 1, 0))


def place_value(first: float, last: float, low: int, high: int, n_places: int) -> float:
    """Reward of sharing places ``low .. high`` of ``n_places``: the mean of the linear
    interpolation from ``first`` (place 1) to ``last`` (place ``n_places``)."""
    if n_places < 2:
        return first
    middle = (low + high) / 2.0
    return first + (last - first) * (middle - 1.0) / (n_places - 1)


@dataclass(frozen=True)
class Elimination:
    """One step judged under ``elimination``, per agent in roster order."""

    leaving: list[bool]
    """Eliminated on this step (it was in play and its torso centre is out)."""
    alive: list[bool]
    """Still in play after this step."""
    over: bool
    """The match ended on this step (one team or none left, or the step limit)."""
    places: list[int]
    """Place decided on this step (1 = winner), 0 where nothing was decided for the agent."""
    spans: list[tuple[int, int]]
    """``(low, high)``: the places an agent decided on this step shares (``(0, 0)`` if none)."""
    outcomes: list[str | None]
    """``win``, ``loss`` or ``draw`` where a place was decided on this step, else ``None``."""


def judge_elimination(alive: Sequence[bool], out: Sequence[bool], team_of: Sequence[int],
                      at_limit: bool, timeout_team: int | None = None) -> Elimination:
    """Judge one step: ``alive`` before it, ``out`` after it, ``at_limit`` if it is the last allowed."""
    n = len(alive)
    leaving = [bool(alive[i] and out[i]) for i in range(n)]
    still = [bool(alive[i] and not out[i]) for i in range(n)]
    before = {team_of[i] for i in range(n) if alive[i]}
    after = {team_of[i] for i in range(n) if still[i]}
    gone = before - after
    places, spans = [0] * n, [(0, 0)] * n
    outcomes: list[str | None] = [None] * n
    for i in range(n):
        if not leaving[i]:
            continue
        if team_of[i] in after:  # a team-mate plays on: alone in its place
            low = high = 1 + len(after - {team_of[i]})
        else:
            low, high = len(after) + 1, len(after) + len(gone)
        places[i], spans[i] = low, (low, high)
        outcomes[i] = LOSS if low > 1 else (DRAW if high > 1 else WIN)
    over = len(after) <= 1 or at_limit
    if over and after:
        if len(after) == 1 or timeout_team in after:
            winner = next(iter(after)) if len(after) == 1 else timeout_team
            rest = len(after) - 1
            for i in range(n):
                if still[i]:
                    won = team_of[i] == winner
                    spans[i] = (1, 1) if won else (2, 1 + rest)
                    places[i] = spans[i][0]
                    outcomes[i] = WIN if won else LOSS
        else:
            for i in range(n):
                if still[i]:
                    places[i], spans[i], outcomes[i] = 1, (1, len(after)), DRAW
    return Elimination(leaving, still, over, places, spans, outcomes)
