"""Judging a match: who left the ring, and what that means for each side.

Two rule sets (``MatchConfig.rules``), each written once here over arrays of ``E`` matches in an array
namespace ``xp`` (numpy for one match, ``E = 1``, and for the CPU vector env; torch on the MuJoCo Warp
backend's device). The constant matrices of a roster they read are :class:`~triplesumo.rules.roster.BatchedRules`.

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

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from triplesumo.rules.roster import BatchedRules

from triplesumo.rules.codes import DRAW as DRAW
from triplesumo.rules.codes import DRAW_CODE as DRAW_CODE
from triplesumo.rules.codes import ERROR as ERROR
from triplesumo.rules.codes import ERROR_CODE as ERROR_CODE
from triplesumo.rules.codes import LOSS as LOSS
from triplesumo.rules.codes import LOSS_CODE as LOSS_CODE
from triplesumo.rules.codes import OUTCOME_CODES as OUTCOME_CODES
from triplesumo.rules.codes import OUTCOME_NAMES as OUTCOME_NAMES
from triplesumo.rules.codes import PLAYING as PLAYING
from triplesumo.rules.codes import WIN as WIN
from triplesumo.rules.codes import WIN_CODE as WIN_CODE


def outcome_name(code: int) -> str:
    """The name of an outcome code (``"win"``, ...); ``ValueError`` for an unknown code."""
    if not 0 <= int(code) < len(OUTCOME_NAMES):
        raise ValueError(f"unknown outcome code {code!r}; codes are {OUTCOME_CODES}")
    return OUTCOME_NAMES[int(code)]



def agents_out(pos: Any, half_size: float, xp: Any) -> Any:
    """``(..., n)`` bool: whose torso centre (``pos[..., :2]``) is outside the ring, ``max(|x|, |y|) > half_size``.

    ``pos`` is ``(E, n, >=2)`` for ``E`` matches (``E = 1`` for one :class:`~triplesumo.envs.match.Match`), in the
    namespace ``xp``: numpy on the CPU, torch on the MuJoCo Warp backend's device.
    """
    return xp.maximum(xp.abs(pos[..., 0]), xp.abs(pos[..., 1])) > half_size


def judge(out: Any, rules: BatchedRules, xp: Any) -> Any:
    """``(E, n)`` outcome code (:data:`OUTCOME_CODES`) of every agent under ``first_out`` rules, from
    :func:`agents_out`'s flags: 0 while nobody is out; else every team with an agent out loses, the
    others win, and if every team has an agent out the match is a draw for all."""
    onehot = rules.team_onehot
    losing = (xp.where(out, 1.0, 0.0) @ onehot) > 0  # (E, T): the team has an agent out
    agent_lost = (xp.where(losing, 1.0, 0.0) @ onehot.T) > 0  # (E, n)
    code = xp.where(agent_lost, LOSS_CODE, WIN_CODE)
    code = xp.where(losing.all(-1)[:, None], DRAW_CODE, code)
    return xp.where(out.any(-1)[:, None], code, PLAYING)


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


def place_value(first: float, last: float, low: Any, high: Any, n_places: int) -> Any:
    """Reward of sharing places ``low .. high`` of ``n_places``: the mean of the linear
    interpolation from ``first`` (place 1) to ``last`` (place ``n_places``). ``low`` and ``high``
    are numbers or arrays of any namespace (elementwise)."""
    if n_places < 2:
        return first
    middle = (low + high) / 2.0
    return first + (last - first) * (middle - 1.0) / (n_places - 1)


@dataclass(frozen=True)
class Elimination:
    """One step of ``E`` matches judged under ``elimination``, per agent in roster order (arrays ``(E, n)``
    unless said otherwise, in the namespace the judge ran in)."""

    leaving: Any
    """Eliminated on this step (it was in play and its torso centre is out)."""
    alive: Any
    """Still in play after this step."""
    over: Any
    """``(E,)``: the match ended on this step (one team or none left, or the step limit)."""
    low: Any
    """The best place an agent decided on this step shares (1 = winner); 0 where nothing was decided."""
    high: Any
    """The worst place it shares (``low`` when it is alone in its place; 0 where nothing was decided)."""
    code: Any
    """Outcome code (:data:`OUTCOME_CODES`) decided on this step: win, loss or draw, else 0 (playing)."""
    terminated: Any
    """``(E,)``: the match ended on this step by its rules: at most one team left in play, or a survivor paid a
    decided win or loss (the evader surviving to the step limit). Only survivors sharing a draw at the step limit
    end truncated (:attr:`truncated`)."""

    @property
    def places(self) -> Any:
        """Place decided on this step, 0 where nothing was decided (``low``)."""
        return self.low

    @property
    def truncated(self) -> Any:
        """``(E,)``: the match ended on this step at the step limit with survivors sharing a draw."""
        return self.over & ~self.terminated


def judge_elimination(alive: Any, out: Any, at_limit: Any, rules: BatchedRules, xp: Any) -> Elimination:
    """Judge one step of ``E`` matches under ``elimination`` rules (see the module docstring): ``alive``
    ``(E, n)`` before the step, ``out`` ``(E, n)`` after it (:func:`agents_out`), ``at_limit`` ``(E,)`` it is
    the last step allowed. ``rules.evader_team`` (``-1``: none) is the team that wins at the step limit."""
    member = rules.team_onehot > 0  # (n, T)

    def count(flags: Any) -> Any:
        return xp.where(flags, 1, 0).sum(-1)

    def teams_with(agents: Any) -> Any:  # (E, n) -> (E, T): the team has such an agent
        return (agents[..., None] & member).any(-2)

    leaving = alive & out
    still = alive & ~out
    before, after = teams_with(alive), teams_with(still)  # teams in play before and after the step
    n_after, n_gone = count(after)[:, None], count(before & ~after)[:, None]  # (E, 1)
    team_on = (after[:, None, :] & member).any(-1)  # (E, n): the agent's team is still in play
    over = (n_after[:, 0] <= 1) | at_limit
    ended = over[:, None] & (n_after >= 1)  # survivors are placed
    evader = rules.evader_team
    evader_on = after[:, evader:evader + 1] if evader >= 0 else n_after < 0  # (E, 1)
    decided = ended & ((n_after == 1) | evader_on)  # one winner among the survivors
    is_evader = member[:, evader] if evader >= 0 else ~member[:, 0] & member[:, 0]  # (n,)
    won = still & decided & ((n_after == 1) | is_evader)
    lost = still & decided & ~won
    drawn = still & ended & ~decided
    # A leaving agent whose team plays on is alone in its place, behind the teams left; teams that leave
    # together share the places they span.
    low = xp.where(leaving, xp.where(team_on, n_after, n_after + 1), 0)
    high = xp.where(leaving, xp.where(team_on, n_after, n_after + n_gone), 0)
    low = xp.where(won | drawn, 1, xp.where(lost, 2, low))
    high = xp.where(won, 1, xp.where(lost | drawn, n_after, high))
    code = xp.where(low == 0, PLAYING, xp.where(low > 1, LOSS_CODE, xp.where(high > 1, DRAW_CODE, WIN_CODE)))
    # terminal: one team or none left, or a survivor paid a win or loss (decided implies the match is over)
    terminated = ((n_after <= 1) | decided)[:, 0]
    return Elimination(leaving, still, over, low, high, code, terminated)


def place_values(low: Any, high: Any, rules: BatchedRules, xp: Any) -> Any:
    """:func:`place_value` of every agent's places ``low .. high`` (:class:`Elimination`), with the win and
    loss rewards of ``rules`` over its teams; 0 where nothing was decided (``low == 0``)."""
    first, last = rules.outcome_values[0], rules.outcome_values[1]
    return xp.where(low > 0, place_value(first, last, low, high, rules.team_onehot.shape[1]), 0.0)
