"""Reference rules for the parity tests: plain Python over one match, written from the module docstrings of
:mod:`triplesumo.rules.outcome` and :mod:`triplesumo.rules.rewards`.

These were the per-match implementations until each rule was written once over arrays (the package's
:func:`~triplesumo.rules.outcome.judge`, :func:`~triplesumo.rules.outcome.judge_elimination` and
:func:`~triplesumo.rules.rewards.reward_terms` serve one match, the CPU vector env and MuJoCo Warp alike). They
stay here as an independent oracle, loop by loop, that the array rules must equal.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from triplesumo.rules.config import RewardConfig
from triplesumo.rules.outcome import DRAW, LOSS, WIN
from triplesumo.rules.teams import Teams


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
    terminated: bool
    """The match ended by its rules: every agent out, at most one team left, or a survivor paid a win or a loss
    (the evader surviving to the limit); survivors sharing a draw at the limit are truncated instead."""


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
    paid = any(still[i] and outcomes[i] in (WIN, LOSS) for i in range(n))
    terminated = over and (not any(still) or paid or len(after) <= 1)
    return Elimination(leaving, still, over, places, spans, outcomes, terminated)


class ReferenceRewardRule:
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
