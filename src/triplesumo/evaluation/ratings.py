"""Ratings of policies from match results, with their uncertainty.

:class:`RatingTable` rates any roster on `openskill <https://openskill.me>`_'s Bayesian
models: teams of any size, any number of teams, free-for-all places. Each policy holds a
Gaussian belief about its skill, mean ``mu`` and standard deviation ``sigma`` (defaults
25 and 25/3); after a match, :meth:`RatingTable.record` passes the teams and their
places (1 = first; equal places are a draw) to the model's ``rate``, which moves every
player's ``mu`` and shrinks its ``sigma``. A rating is reported with an interval
``mu +- z * sigma`` (95 %: z = 1.96) and openskill's conservative ``ordinal``
(``mu - 3 sigma``). Updates are applied in the order matches are recorded, so the
same results in the same order give the same table.

Before every match openskill adds ``tau**2`` to each player's ``sigma**2``: the skill may
have drifted since it was last seen. Its default, ``25/300``, suits players who change (a
league's learners), and it keeps ``sigma`` from falling below a floor set by how much one
match tells (about 1.5 after a few hundred matches a policy in the paper's tournaments).
Frozen policies do not drift: ``tau=0`` lets their intervals keep narrowing as matches are
added, about as ``1/sqrt(matches)``.

:class:`Elo` is the plain Elo rating of two-player games, for users who expect it in
1-vs-1 matches; it has no uncertainty and no notion of teams.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from openskill.models import (
    BradleyTerryFull,
    BradleyTerryPart,
    PlackettLuce,
    ThurstoneMostellerFull,
    ThurstoneMostellerPart,
)

from triplesumo.evaluation.stats import normal_quantile

MODELS: dict[str, Any] = {
    "PlackettLuce": PlackettLuce,
    "BradleyTerryFull": BradleyTerryFull,
    "BradleyTerryPart": BradleyTerryPart,
    "ThurstoneMostellerFull": ThurstoneMostellerFull,
    "ThurstoneMostellerPart": ThurstoneMostellerPart,
}
"""The openskill models a :class:`RatingTable` can use, by name."""

PLACE_OF_OUTCOME = {"win": 1, "draw": 1, "loss": 2}
"""A team's place from its match outcome: winners first, losers second; in a draw every team
shares first place."""


@dataclass(frozen=True)
class Rating:
    """A policy's skill belief: a Gaussian with mean ``mu`` and standard deviation ``sigma``."""

    mu: float
    """Mean skill."""
    sigma: float
    """Standard deviation of the skill (its uncertainty)."""

    @property
    def ordinal(self) -> float:
        """openskill's conservative rating, ``mu - 3 sigma``."""
        return self.mu - 3.0 * self.sigma

    def interval(self, confidence: float = 0.95) -> tuple[float, float]:
        """``(mu - z sigma, mu + z sigma)`` for a two-sided normal ``confidence``."""
        z = normal_quantile(confidence)
        return (self.mu - z * self.sigma, self.mu + z * self.sigma)


def check_tau(what: str, tau: float | None) -> None:
    """Refuse a ``tau`` that is not ``None`` or a finite number ``>= 0``, naming ``what``."""
    if tau is None:
        return
    if isinstance(tau, bool) or not isinstance(tau, int | float) or not math.isfinite(tau) or tau < 0:
        raise ValueError(f"{what} must be a finite number >= 0 (or None: openskill's default), got {tau!r}")


class RatingTable:
    """openskill ratings of named players, updated match by match.

    Args:
        model: One of :data:`MODELS` (default ``"PlackettLuce"``, openskill's default).
        players: Names to start with (others are added when they first play).
        tau: Skill drift added before every match (``None``: openskill's default, ``25/300``;
            ``0`` for frozen policies, see the module docstring).
    """

    def __init__(self, model: str = "PlackettLuce", players: Sequence[str] = (), tau: float | None = None) -> None:
        if model not in MODELS:
            raise ValueError(f"rating model must be one of {sorted(MODELS)}, got {model!r}")
        check_tau("rating tau", tau)
        self.model_name = model
        self.tau = tau
        self.model = MODELS[model]() if tau is None else MODELS[model](tau=float(tau))
        self._ratings: dict[str, Any] = {}
        self.matches: dict[str, int] = {}
        for name in players:
            self._player(name)

    def _player(self, name: str) -> Any:
        if name not in self._ratings:
            self._ratings[name] = self.model.rating(name=name)
            self.matches[name] = 0
        return self._ratings[name]

    def record(self, teams: Sequence[Sequence[str]], places: Sequence[float]) -> None:
        """Rate one match: ``teams[t]`` (player names) finished in place ``places[t]`` (1 is first).

        Equal places are a draw between those teams. A player may appear only once per match.
        """
        if len(teams) < 2 or len(places) != len(teams):
            raise ValueError(f"a match needs >= 2 teams and one place per team, got {len(teams)} teams "
                             f"and {len(places)} places")
        names = [n for team in teams for n in team]
        if any(len(team) == 0 for team in teams):
            raise ValueError(f"every team needs at least one player, got {[list(t) for t in teams]}")
        if len(set(names)) != len(names):
            raise ValueError(f"a player may appear only once in a match, got teams {[list(t) for t in teams]}")
        if not all(isinstance(p, int | float) and math.isfinite(p) for p in places):
            raise ValueError(f"places must be finite numbers, got {list(places)}")
        rated = self.model.rate([[self._player(n) for n in team] for team in teams], ranks=list(places))
        for team, new in zip(teams, rated, strict=True):
            for name, rating in zip(team, new, strict=True):
                self._ratings[name] = rating
                self.matches[name] += 1

    def record_outcomes(self, teams: Sequence[Sequence[str]], outcomes: Sequence[str]) -> None:
        """Rate one match from each team's outcome (``win``, ``loss`` or ``draw``, see
        :data:`PLACE_OF_OUTCOME`)."""
        unknown = [o for o in outcomes if o not in PLACE_OF_OUTCOME]
        if unknown:
            raise ValueError(f"outcomes must be among {sorted(PLACE_OF_OUTCOME)}, got {unknown}")
        self.record(teams, [PLACE_OF_OUTCOME[o] for o in outcomes])

    def __getitem__(self, name: str) -> Rating:
        if name not in self._ratings:
            raise KeyError(f"no rating for {name!r}; rated: {sorted(self._ratings)}")
        r = self._ratings[name]
        return Rating(float(r.mu), float(r.sigma))

    def __contains__(self, name: object) -> bool:
        return name in self._ratings

    @property
    def players(self) -> list[str]:
        """Rated names, in order of first appearance."""
        return list(self._ratings)

    def ranking(self) -> list[str]:
        """Names by decreasing ``mu`` (ties by name)."""
        return sorted(self._ratings, key=lambda n: (-self[n].mu, n))

    def set(self, name: str, rating: Rating, matches: int = 0) -> None:
        """Give ``name`` the belief ``rating`` (a new player starts from another's, e.g. a snapshot
        of a learner from the learner's) and a match count."""
        if not (math.isfinite(rating.mu) and math.isfinite(rating.sigma) and rating.sigma > 0):
            raise ValueError(f"a rating needs a finite mu and a finite sigma > 0, got {rating}")
        self._ratings[name] = self.model.rating(mu=rating.mu, sigma=rating.sigma, name=name)
        self.matches[name] = int(matches)

    def state_dict(self) -> dict[str, Any]:
        """The table as JSON-able data (model, tau where one was given, and per player mu, sigma,
        matches, in order)."""
        state: dict[str, Any] = {"model": self.model_name}
        if self.tau is not None:
            state["tau"] = float(self.tau)
        state["players"] = [[n, float(r.mu), float(r.sigma), self.matches[n]] for n, r in self._ratings.items()]
        return state

    @classmethod
    def from_state_dict(cls, state: dict[str, Any]) -> RatingTable:
        """The table :meth:`state_dict` described, exactly (floats round-trip through JSON)."""
        tau = state.get("tau")
        table = cls(str(state["model"]), tau=None if tau is None else float(tau))
        for name, mu, sigma, matches in state["players"]:
            table.set(str(name), Rating(float(mu), float(sigma)), int(matches))
        return table

    def win_probability(self, teams: Sequence[Sequence[str]]) -> list[float]:
        """openskill's predicted probability that each team wins a match between them."""
        return [float(p) for p in self.model.predict_win([[self._player(n) for n in team] for team in teams])]


class Elo:
    """Plain Elo ratings for 1-vs-1 games (no uncertainty; use :class:`RatingTable` otherwise).

    Expected score of A against B: ``1 / (1 + 10 ** ((R_B - R_A) / 400))``; after a game
    with score ``s`` for A (1 win, 0.5 draw, 0 loss), ``R_A += k (s - E_A)`` and
    ``R_B -= k (s - E_A)``.
    """

    def __init__(self, k: float = 32.0, initial: float = 1500.0) -> None:
        if not (math.isfinite(k) and k > 0):
            raise ValueError(f"Elo k must be finite and > 0, got {k!r}")
        self.k, self.initial = float(k), float(initial)
        self.ratings: dict[str, float] = {}

    def expected(self, a: str, b: str) -> float:
        """Expected score of ``a`` against ``b``."""
        ra, rb = self.ratings.get(a, self.initial), self.ratings.get(b, self.initial)
        return 1.0 / (1.0 + 10.0 ** ((rb - ra) / 400.0))

    def record(self, a: str, b: str, score_a: float) -> None:
        """One game: ``score_a`` is 1 if ``a`` won, 0.5 for a draw, 0 if ``b`` won."""
        if a == b:
            raise ValueError(f"an Elo game needs two different players, got {a!r} twice")
        if score_a not in (0, 0.5, 1):
            raise ValueError(f"score_a must be 1 (win), 0.5 (draw) or 0 (loss), got {score_a!r}")
        delta = self.k * (score_a - self.expected(a, b))
        self.ratings[a] = self.ratings.get(a, self.initial) + delta
        self.ratings[b] = self.ratings.get(b, self.initial) - delta
