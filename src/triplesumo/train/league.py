"""Self-play leagues: pools of policy snapshots that learners play against, with ratings.

A :class:`League` holds one :class:`OpponentPool` per *side*, a group of seats one
learner drives (the paper's 2-vs-1: side ``team`` with roles ``ant`` and ``bug``, side
``spider`` with role ``spider``; free-for-all: one side ``ffa`` with one role whose
network takes any seat). A pool member, a :class:`Snapshot`, is one player: a policy
per role (policy file pairs under ``RUN/league/members/ID/ROLE.{json,safetensors}``, or
a built-in name) with its id, source (``self``: a learner's snapshot; ``zoo``: seeded
from :attr:`LeagueConfig.zoo`), the epoch it joined and the results of the learner that
faces it. Learners are players too (``SIDE:learner``).

The rules, after AlphaStar's league and RLlib's league example:

* **Results.** :meth:`League.record_match` takes the players of a match grouped by team
  with their places (1 = first; equal places a draw). Every player is rated with openskill
  (:class:`~triplesumo.evaluation.ratings.RatingTable`, teams of any size, any number of
  teams); a player in two teams of one match is rated once, at its best place
  (:meth:`League.record_seats` takes one player per seat, as
  :func:`~triplesumo.evaluation.runner.play_matches` reports them). Each learner
  in the match appends 1 (it finished first, alone), its side's draw score (first, tied: a draw;
  :attr:`LeagueConfig.draw_score`, or :attr:`LeagueConfig.side_draw_score` for that side) or 0 to its
  side's win-rate window of
  the last :attr:`LeagueConfig.window` matches, and each member it met counts the
  learner's result against it (win: better place, draw: same place, loss: worse).
* **Admission.** At epochs that are multiples of :attr:`LeagueConfig.snapshot_every`, a
  side whose window is full and whose win rate is strictly greater than its threshold
  (:attr:`LeagueConfig.threshold`, or :attr:`LeagueConfig.side_threshold` for that side) is due
  (:meth:`League.admit_due`); :meth:`League.admit`
  then has the trainer write the learner's policy files, adds the snapshot (rated as the
  learner is at that moment) and empties the window, so the next snapshot must beat the
  grown pool.
* **Sampling.** :meth:`League.sample` draws opponents from a side's pool with the
  league's ``numpy`` Generator, member ``i`` with probability ``w_i / sum(w)``:
  ``uniform``: ``w_i = 1``; ``latest``: only the newest member; ``pfsp`` (prioritised
  fictitious self-play): ``w_i = f(p_i)`` where ``p_i = (wins_i + 1) / (games_i + 2)``
  is the facing learner's win rate against member ``i`` (Laplace prior: an unmet member
  counts 0.5), with AlphaStar's weightings ``hard``: ``f(p) = (1 - p) ** exponent``
  (mostly the opponents it loses to) or ``variance``: ``f(p) = p (1 - p)`` (mostly the
  even matches). With :attr:`LeagueConfig.zoo_share` ``s > 0`` a pool holding both seeded
  (``zoo``) members and snapshots gives its seeds ``s`` of the draws, evenly, and its
  snapshots ``1 - s`` by the rule above, so a fixed opponent (a still team) keeps its
  share of the matches however large the pool grows.
* **Live or pool (several learning sides).** When more than one side learns in the run (the
  paper's 2-vs-1 with ``--learn ant=ddpg bug=ddpg spider=ddpg``), :meth:`League.draw_live` decides at
  every match start who plays: with probability :attr:`LeagueConfig.live_share` the live learners
  meet (AlphaStar's main agents play 35% of their matches against themselves); otherwise one
  learning side, drawn uniformly among those whose opponents' pools all have members, plays
  against members of the other learning sides' pools (those learners sit the match out). While
  no such side exists (both pools still empty in a run from scratch) every match is live. With
  one learning side nothing is drawn.
* **Size limit.** Past :attr:`LeagueConfig.max_size` members the oldest is evicted
  (FIFO), except the first member and the best-rated one (highest ``mu``); with
  :attr:`LeagueConfig.keep_zoo` the seeded members stay and do not count. An evicted
  member's files stay under ``members/`` (listed as ``evicted``), so any checkpoint
  that still names it resumes.

Persistence: :meth:`League.save` writes ``RUN/league/pool.json`` atomically: members
(with the sha256 of every file), evicted members, ratings, win-rate windows, the RNG
state. :meth:`League.load` checks every file against its sha256 and restores the league
exactly (the same next samples, the same ratings); :meth:`League.state_dict` /
:meth:`League.load_state_dict` give the same state for a checkpoint (a trainer resuming from a
checkpoint restores the league from the state in it, which matches its networks, rather
than from ``pool.json``, which is the newest). :meth:`League.epoch_end`
returns the scalars to log and appends them to ``RUN/league/league.csv``, which
:func:`~triplesumo.train.league_plots.plot_league` draws.
"""

from __future__ import annotations

import csv
import functools
import json
import math
import shutil
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from triplesumo.agents.builtin import ACTION_SIZE, BUILTIN
from triplesumo.agents.policy_file import (
    LEAGUE_FORMAT,
    PolicyFileError,
    atomic_write_bytes,
    file_sha256,
    load_fixed_policy,
    load_json,
    policy_paths,
)
from triplesumo.agents.zoo import policy_stem
from triplesumo.evaluation.metrics_csv import repair_metrics_csv, unpack_table
from triplesumo.evaluation.ratings import PLACE_OF_OUTCOME, Rating, RatingTable
from triplesumo.train.league_config import LeagueConfig, check_seeds

POOL_FILE = "pool.json"
PRUNED_FILE = "pruned.json"
"""``RUN/league/pruned.json``: the evicted members ``triplesumo compact`` deleted (id, side, epoch, sha256)."""
LOG_FILE = "league.csv"
LOG_COLUMNS = ("epoch", "side", "pool_size", "learner_mu", "learner_sigma", "mean_opponent_mu", "admitted",
               "members")

@dataclass
class Snapshot:
    """A pool member: one player, a policy per role of its side."""

    id: str
    """Unique in the league: SIDE-NNNN."""
    side: str
    """The side whose seats it takes."""
    source: str
    """self (a learner's snapshot) or zoo (seeded from LeagueConfig.zoo)."""
    epoch: int
    """Epoch it joined the pool."""
    policies: dict[str, str]
    """Role -> a built-in policy name, or the stem of its policy files relative to RUN/league."""
    sha256: dict[str, str] = field(default_factory=dict)
    """File (relative to RUN/league) -> sha256 of its bytes."""
    games: int = 0
    """Matches the facing learner played against it."""
    wins: int = 0
    """...of which the learner finished ahead of it."""
    draws: int = 0
    """...of which they finished level."""

    @property
    def p_win(self) -> float:
        """The facing learner's win rate against it, with a Laplace prior: ``(wins + 1) / (games + 2)``."""
        return (self.wins + 1) / (self.games + 2)


class OpponentPool:
    """The snapshots of one side, its learner's win-rate window, and the sampling rule."""

    def __init__(self, side: str, roles: tuple[str, ...], config: LeagueConfig) -> None:
        self.side, self.roles, self.config = side, roles, config
        self.draw_score = config.draw_score_of(side)
        """What a draw adds to this side's window."""
        self.threshold = config.threshold_of(side)
        """The win rate this side's window must pass for admission."""
        self.members: list[Snapshot] = []
        self.evicted: list[Snapshot] = []
        self.window: deque[float] = deque(maxlen=config.window)
        self.created = 0
        self.admitted_since_log = 0

    def __len__(self) -> int:
        return len(self.members)

    @property
    def win_rate(self) -> float:
        """The learner's win rate over its window (nan while empty)."""
        return float(np.mean(self.window)) if self.window else math.nan

    def weights(self) -> np.ndarray:
        """Each member's probability of being drawn, by :attr:`LeagueConfig.sampling` and
        :attr:`LeagueConfig.zoo_share` (module docstring)."""
        n = len(self.members)
        if n == 0:
            raise ValueError(f"pool {self.side!r} is empty: seed it (LeagueConfig.zoo) or admit a snapshot first")
        seeded = np.array([m.source == "zoo" for m in self.members])
        share = self.config.zoo_share
        if share > 0 and seeded.any() and not seeded.all():
            w = np.zeros(n)
            w[seeded] = share / seeded.sum()
            w[~seeded] = (1.0 - share) * self._rule([m for m, z in zip(self.members, seeded, strict=True) if not z])
            return w
        return self._rule(self.members)

    def _rule(self, members: Sequence[Snapshot]) -> np.ndarray:
        """:attr:`LeagueConfig.sampling`'s probabilities over ``members`` (in pool order)."""
        n = len(members)
        if self.config.sampling == "uniform":
            w = np.ones(n)
        elif self.config.sampling == "latest":
            w = np.zeros(n)
            w[-1] = 1.0
        else:
            p = np.array([m.p_win for m in members])
            w = (1.0 - p) ** self.config.pfsp_exponent if self.config.pfsp_weighting == "hard" else p * (1.0 - p)
        return w / w.sum()

    def new_id(self) -> str:
        self.created += 1
        return f"{self.side}-{self.created:04d}"

    def evict(self, ratings: RatingTable) -> list[Snapshot]:
        """Drop the oldest members past ``max_size``, never the first nor the best-rated (highest mu); with
        ``keep_zoo`` the seeded members are neither evicted nor counted."""
        gone: list[Snapshot] = []
        kept = [m for m in self.members if m.source == "zoo"] if self.config.keep_zoo else []
        while len(self.members) - len(kept) > self.config.max_size:
            best = max(self.members, key=lambda m: ratings[m.id].mu)  # ties: the earliest
            keep = {self.members[0].id, best.id, *(m.id for m in kept)}
            victim = next(m for m in self.members if m.id not in keep)
            self.members.remove(victim)
            self.evicted.append(victim)
            gone.append(victim)
        return gone


class League:
    """Opponent pools of every side of a run, their ratings and the sampling RNG (module docstring).

    Args:
        run_dir: The run folder; the league lives in ``run_dir/league``.
        config: The league's rules.
        sides: Side name -> its roles (``{"team": ("ant", "bug"), "spider": ("spider",)}``).
        seed: Seeds the sampling Generator.
        epoch: The epoch the zoo members join at.
        seed_zoo: Seed the pools with ``config.zoo`` (False when a saved state is loaded next, as a resumed
            run does: its members are in that state, and seeding again would write over their files).
    """

    def __init__(self, run_dir: Path, config: LeagueConfig, sides: Mapping[str, Sequence[str]],
                 seed: int = 0, epoch: int = 0, seed_zoo: bool = True) -> None:
        if not sides:
            raise ValueError("a league needs at least one side")
        for side, roles in sides.items():
            if not side or "-" in side or ":" in side or not roles or len(set(roles)) != len(roles):
                raise ValueError(f"side {side!r}: a name without '-' or ':' and distinct roles, got {list(roles)}")
        for name, named in config.sides_named().items():
            unknown = [s for s in named if s not in sides]
            if unknown:
                raise ValueError(f"LeagueConfig.{name} names sides this run has not: {unknown}; "
                                 f"sides are {sorted(sides)}")
        self.root = Path(run_dir) / "league"
        self.config = config
        self.pools = {side: OpponentPool(side, tuple(roles), config) for side, roles in sides.items()}
        self.ratings = RatingTable(config.rating_model, [self.learner(s) for s in sides])
        self.rng = np.random.default_rng(seed)
        self.epoch = epoch
        self.seed(config.zoo if seed_zoo else (), epoch)

    def seed(self, entries: Sequence[str], epoch: int) -> list[Snapshot]:
        """Add the ROLE=POLICY ``entries`` (:attr:`LeagueConfig.zoo`'s form) to the pools as ``zoo`` members
        joining at ``epoch``, at the initial rating; a pool past its size limit then evicts as admission does.
        A new league seeds its config's zoo; a fork that appends zoo entries seeds only those, at the fork's
        epoch. Returns the members added."""
        all_roles = {r for pool in self.pools.values() for r in pool.roles}
        unknown = [e for e in entries if e.partition("=")[0] not in all_roles]
        if unknown:
            raise ValueError(f"LeagueConfig.zoo names roles no side has: {unknown}; roles are {sorted(all_roles)}")
        check_seeds(entries)
        seeds: dict[str, list[str]] = {}
        for entry in entries:
            role, _, spec = entry.partition("=")
            seeds.setdefault(role, []).append(spec)
        added: list[Snapshot] = []
        for side, pool in self.pools.items():
            named = [r for r in pool.roles if r in seeds]
            if not named:
                continue
            if len(named) < len(pool.roles):
                raise ValueError(f"LeagueConfig.zoo names roles {named} of side {side!r} but not "
                                 f"{[r for r in pool.roles if r not in seeds]}: a member needs a policy per role")
            counts = {r: len(seeds[r]) for r in pool.roles}
            if len(set(counts.values())) > 1:
                raise ValueError(f"LeagueConfig.zoo names the roles of side {side!r} unequally often {counts}: the "
                                 f"i-th entries of its roles make its i-th member")
            for i in range(counts[pool.roles[0]]):
                specs = {r: seeds[r][i] for r in pool.roles}
                added.append(self._add(side, "zoo", epoch, functools.partial(_copy_specs, specs), specs))
            pool.evict(self.ratings)
        return added

    @staticmethod
    def learner(side: str) -> str:
        """The rating name of a side's learner."""
        return f"{side}:learner"

    def member(self, member_id: str) -> Snapshot:
        """A current or evicted member by id."""
        for pool in self.pools.values():
            for m in (*pool.members, *pool.evicted):
                if m.id == member_id:
                    return m
        raise KeyError(f"no league member {member_id!r}")

    # -- sampling ---------------------------------------------------------------------------
    def sample(self, side: str, k: int = 1) -> list[Snapshot]:
        """``k`` opponents from ``side``'s pool by the sampling rule; distinct while the pool has ``k``."""
        pool = self._pool(side)
        w = pool.weights()
        picks = self.rng.choice(len(w), size=k, replace=bool(k > np.count_nonzero(w)), p=w)
        return [pool.members[int(i)] for i in picks]

    def draw_live(self, sides: Sequence[str]) -> list[str]:
        """The learning ``sides`` whose learners play the next match (module docstring, "Live or pool");
        the seats of the others go to members of their pools. One side: itself, no draw."""
        if len(sides) < 2:
            return list(sides)
        live = self.rng.random() < self.config.live_share
        ready = [s for s in sides if all(len(self._pool(o)) for o in sides if o != s)]
        if live or not ready:
            return list(sides)
        return [ready[int(self.rng.integers(len(ready)))]]

    def policies(self, member: Snapshot, seed: int | None = None,
                 action_sizes: Mapping[str, int] | None = None) -> dict[str, Any]:
        """Role -> a callable policy of ``member`` (files as numpy :class:`FrozenPolicy`)."""
        out: dict[str, Any] = {}
        for role, spec in member.policies.items():
            if spec in BUILTIN:
                size = (action_sizes or {}).get(role, ACTION_SIZE)
                out[role] = BUILTIN[spec](seed, action_size=size) if spec == "random" else BUILTIN[spec](size)
            else:
                out[role] = load_fixed_policy(self.root / spec)[0]
        return out

    # -- results ----------------------------------------------------------------------------
    def record_match(self, teams: Sequence[Sequence[str]], places: Sequence[float]) -> None:
        """Rate one match and update windows and member results (module docstring).

        ``teams[t]`` are the players (``SIDE:learner`` names and member ids) of the team that
        finished in place ``places[t]``.
        """
        if len(teams) != len(places):
            raise ValueError(f"one place per team, got {len(teams)} teams and {len(places)} places")
        for team in teams:
            for name in team:
                if not self._is_learner(name):
                    self.member(name)  # raises for an unknown id
        # a player in several teams of one match (a member drawn for two free-for-all seats) is rated once,
        # at its best place (openskill rates a player once per match); its other seats still count as met
        rated_at: dict[str, int] = {}
        for t in sorted(range(len(teams)), key=lambda u: places[u]):
            for name in teams[t]:
                rated_at.setdefault(name, t)
        rated_teams, rated_places = [], []
        for t, (team, place) in enumerate(zip(teams, places, strict=True)):
            kept = [n for n in team if rated_at[n] == t]
            if kept:
                rated_teams.append(kept)
                rated_places.append(place)
        if len(rated_teams) >= 2:
            self.ratings.record(rated_teams, rated_places)
        best = min(places)
        for t, (team, place) in enumerate(zip(teams, places, strict=True)):
            for name in team:
                if not self._is_learner(name):
                    continue
                pool = self.pools[name.split(":")[0]]
                first, alone = place == best, list(places).count(best) == 1
                pool.window.append(1 if first and alone else pool.draw_score if first else 0)
                for u, (other, other_place) in enumerate(zip(teams, places, strict=True)):
                    for opp in other if u != t else ():  # teammates are not opponents
                        if not self._is_learner(opp):
                            m = self.member(opp)
                            m.games += 1
                            m.wins += int(place < other_place)
                            m.draws += int(place == other_place)

    def record_seats(self, players: Sequence[str], places: Sequence[float], teams: Sequence[str]) -> None:
        """:meth:`record_match` from one player per seat (roster order), each seat's place and each seat's team
        label: the seats of one player in one team (a snapshot of a team drives all its seats) are one entry;
        seats are seats otherwise, each at its own place, even where two opponent seats share a member (a
        free-for-all pool of one draws it for both), so the learner's place is its own."""
        if not len(players) == len(places) == len(teams):
            raise ValueError(f"one place and one team per seat, got {len(players)} players, {len(places)} places and "
                             f"{len(teams)} teams")
        entries: dict[tuple[str, str], float] = {}
        for name, place, team in zip(players, places, teams, strict=True):
            entries.setdefault((name, team), place)
        self.record_match([[name] for name, _ in entries], list(entries.values()))

    def record_seat_outcomes(self, players: Sequence[str], outcomes: Sequence[str], teams: Sequence[str]) -> None:
        """:meth:`record_seats` from each seat's ``win``/``loss``/``draw`` (a :class:`SeatedResult`'s outcomes)."""
        bad = [o for o in outcomes if o not in PLACE_OF_OUTCOME]
        if bad:
            raise ValueError(f"outcomes must be among {sorted(PLACE_OF_OUTCOME)}, got {bad}")
        self.record_seats(players, [PLACE_OF_OUTCOME[o] for o in outcomes], teams)

    def record_outcomes(self, teams: Sequence[Sequence[str]], outcomes: Sequence[str]) -> None:
        """:meth:`record_match` from each team's ``win``/``loss``/``draw``."""
        bad = [o for o in outcomes if o not in PLACE_OF_OUTCOME]
        if bad:
            raise ValueError(f"outcomes must be among {sorted(PLACE_OF_OUTCOME)}, got {bad}")
        self.record_match(teams, [PLACE_OF_OUTCOME[o] for o in outcomes])

    # -- admission --------------------------------------------------------------------------
    def admit_due(self, side: str, epoch: int) -> bool:
        """Whether ``side``'s learner joins its pool now: at a multiple of ``snapshot_every``, with a
        full window whose win rate is greater than the side's threshold (:meth:`LeagueConfig.threshold_of`)."""
        pool = self._pool(side)
        return (epoch % self.config.snapshot_every == 0 and len(pool.window) == self.config.window
                and pool.win_rate > pool.threshold)

    def admit(self, side: str, epoch: int, write: Callable[[Mapping[str, Path]], None] | None = None,
              builtin: Mapping[str, str] | None = None) -> Snapshot:
        """Add the learner of ``side`` as a snapshot: ``write(stems)`` writes one policy file pair per role
        at ``stems[role]`` (e.g. with :func:`~triplesumo.agents.policy_file.save_policy`), or
        ``builtin`` names a built-in policy per role. The snapshot starts from the learner's rating;
        the window empties; past the size limit the oldest member goes. Saves ``pool.json``."""
        pool = self._pool(side)
        if (write is None) == (builtin is None):
            raise ValueError("admit needs exactly one of write (policy files) or builtin (policy names)")
        if builtin is not None:
            missing = [r for r in pool.roles if builtin.get(r) not in BUILTIN]
            if missing:
                raise ValueError(f"admit: builtin must name a built-in policy ({sorted(BUILTIN)}) for roles {missing}")
        snap = self._add(side, "self", epoch, write, dict(builtin) if builtin is not None else None)
        self.ratings.set(snap.id, self.ratings[self.learner(side)])
        pool.window.clear()
        pool.evict(self.ratings)
        self.save()
        return snap

    def _add(self, side: str, source: str, epoch: int, write: Callable[[Mapping[str, Path]], None] | None,
             specs: dict[str, str] | None) -> Snapshot:
        pool = self.pools[side]
        member_id = pool.new_id()
        folder = self.root / "members" / member_id
        files = {r: folder / r for r in pool.roles if specs is None or specs[r] not in BUILTIN}
        if files:
            folder.mkdir(parents=True, exist_ok=True)
            assert write is not None
            write(files)
        policies, sums = {}, {}
        for role in pool.roles:
            if role not in files:
                policies[role] = (specs or {})[role]
                continue
            policies[role] = files[role].relative_to(self.root).as_posix()
            for suffix in (".json", ".safetensors"):
                path = files[role].with_suffix(suffix)
                if not path.is_file():
                    raise PolicyFileError(f"{path}: snapshot {member_id} lacks its {role!r} policy file")
                sums[path.relative_to(self.root).as_posix()] = file_sha256(path)
        snap = Snapshot(member_id, side, source, epoch, policies, sums)
        pool.members.append(snap)
        pool.admitted_since_log += 1
        if snap.id not in self.ratings:
            self.ratings.set(snap.id, Rating(self.ratings.model.mu, self.ratings.model.sigma))
        return snap

    # -- logging ----------------------------------------------------------------------------
    def epoch_end(self, epoch: int) -> dict[str, float]:
        """Scalars to log for ``epoch`` (``league/SIDE/...``: pool size, learner mu and sigma, mean
        opponent mu, snapshots admitted since the last call), also appended to ``league.csv``. A side's
        learner that has played no match yet (a side that does not learn in this run) logs nan."""
        self.epoch = epoch
        out: dict[str, float] = {}
        rows = []
        for side, pool in self.pools.items():
            name = self.learner(side)
            me = self.ratings[name] if self.ratings.matches.get(name) else Rating(math.nan, math.nan)
            opp = float(np.mean([self.ratings[m.id].mu for m in pool.members])) if pool.members else math.nan
            values = {"pool_size": float(len(pool)), "learner_mu": me.mu, "learner_sigma": me.sigma,
                      "mean_opponent_mu": opp, "admitted": float(pool.admitted_since_log)}
            out |= {f"league/{side}/{k}": v for k, v in values.items()}
            rows.append([epoch, side, len(pool), repr(me.mu), repr(me.sigma), repr(opp), pool.admitted_since_log,
                         " ".join(m.id for m in pool.members)])
            pool.admitted_since_log = 0
        self.root.mkdir(parents=True, exist_ok=True)
        log = self.root / LOG_FILE
        new = not log.exists()
        with open(log, "a", newline="") as fh:
            writer = csv.writer(fh)
            if new:
                writer.writerow(LOG_COLUMNS)
            writer.writerows(rows)
        return out

    # -- persistence ------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """The whole league as JSON-able data (the member files stay in ``RUN/league``)."""
        return {
            "format": LEAGUE_FORMAT,
            "config": asdict(self.config),
            "epoch": self.epoch,
            "sides": {s: list(p.roles) for s, p in self.pools.items()},
            "pools": {s: {"members": [asdict(m) for m in p.members], "evicted": [asdict(m) for m in p.evicted],
                          "window": list(p.window), "created": p.created, "admitted_since_log": p.admitted_since_log}
                      for s, p in self.pools.items()},
            "ratings": self.ratings.state_dict(),
            "rng": self.rng.bit_generator.state,
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`state_dict` exactly, after checking every member file against its sha256."""
        if state.get("format") != LEAGUE_FORMAT:
            raise PolicyFileError(f"league state: format {state.get('format')!r}, expected {LEAGUE_FORMAT!r}")
        if {s: list(r) for s, r in state["sides"].items()} != {s: list(p.roles) for s, p in self.pools.items()}:
            raise ValueError(f"league state has sides {state['sides']}, this league "
                             f"{ {s: list(p.roles) for s, p in self.pools.items()} }")
        pools = {}
        for side, data in state["pools"].items():
            pool = OpponentPool(side, self.pools[side].roles, self.config)
            pool.members = [Snapshot(**m) for m in data["members"]]
            pool.evicted = [Snapshot(**m) for m in data["evicted"]]
            pool.window.extend(x if isinstance(x, float) else int(x) for x in data["window"])
            pool.created, pool.admitted_since_log = int(data["created"]), int(data["admitted_since_log"])
            for m in (*pool.members, *pool.evicted):
                for rel, digest in m.sha256.items():
                    path = self.root / rel
                    if not path.is_file():
                        raise PolicyFileError(f"{path}: league member {m.id} lacks this file")
                    if file_sha256(path) != digest:
                        raise PolicyFileError(f"{path}: sha256 differs from the league's record (damaged or replaced)")
            pools[side] = pool
        self.pools = pools
        self.ratings = RatingTable.from_state_dict(state["ratings"])
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = state["rng"]
        self.epoch = int(state["epoch"])

    def save(self) -> Path:
        """Write ``RUN/league/pool.json`` atomically; returns its path."""
        return write_pool(self.root, self.state_dict())

    @classmethod
    def load(cls, run_dir: Path, config: LeagueConfig | None = None) -> League:
        """The league saved in ``run_dir/league`` (files checked); ``league.csv`` rows past its epoch
        are cut, so a resumed run logs every epoch once."""
        root = Path(run_dir) / "league"
        state = load_json(root / POOL_FILE)
        if state.get("format") != LEAGUE_FORMAT:
            raise PolicyFileError(f"{root / POOL_FILE}: format {state.get('format')!r}, expected {LEAGUE_FORMAT!r}")
        cfg = config or LeagueConfig(**state["config"])
        league = cls.__new__(cls)
        league.root, league.config = root, cfg
        league.pools = {s: OpponentPool(s, tuple(r), cfg) for s, r in state["sides"].items()}
        league.load_state_dict(state)
        league.truncate_log(league.epoch)
        return league

    def truncate_log(self, epoch: int) -> None:
        """Drop ``league.csv`` rows of epochs after ``epoch`` (written before a resume point) and a torn last line
        (a kill while writing it, which the next row would be glued onto): the repair routine of the metrics CSVs
        (:func:`~triplesumo.evaluation.metrics_csv.repair_metrics_csv`), which names the file and line of a damaged
        row."""
        log = self.root / LOG_FILE
        unpack_table(log)  # a packed league log (triplesumo pack) goes back to its plain file, appended to next
        if not log.exists():
            return
        complete = log.read_text(encoding="utf-8", errors="replace").split("\n")[1:-1]
        through = sum(1 for row in csv.reader(complete) if row and row[0].isdigit() and int(row[0]) <= epoch)

        def problem(row: list[str], number: int) -> str | None:
            if len(row) != len(LOG_COLUMNS) or not row[0].isdigit():
                return f"{len(row)} fields, expected {len(LOG_COLUMNS)} starting with the epoch"
            return None

        repair_metrics_csv(log, through, tuple(LOG_COLUMNS), problem, "league log")

    # -- helpers ----------------------------------------------------------------------------
    def _pool(self, side: str) -> OpponentPool:
        if side not in self.pools:
            raise KeyError(f"no side {side!r}; sides are {sorted(self.pools)}")
        return self.pools[side]

    def _is_learner(self, name: str) -> bool:
        side, sep, rest = name.partition(":")
        return bool(sep) and rest == "learner" and side in self.pools


def write_pool(root: Path, state: Mapping[str, Any]) -> Path:
    """Write a league's :meth:`League.state_dict` as ``root/pool.json`` atomically (``root``: ``RUN/league``,
    created if need be); returns its path. Forks and compaction write the states they edit with it too."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(root / POOL_FILE, (json.dumps(state, indent=1) + "\n").encode())
    return root / POOL_FILE


def _copy_specs(specs: Mapping[str, str], stems: Mapping[str, Path]) -> None:
    """Copy the policy files named by ``specs`` (zoo:NAME or a path) to ``stems``."""
    for role, stem in stems.items():
        spec = specs[role]
        for src, dst in zip(policy_paths(policy_stem(spec)), policy_paths(stem), strict=True):
            shutil.copyfile(src, dst)
