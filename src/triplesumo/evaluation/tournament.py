"""``triplesumo tournament``: seeded matches between named policies in every seat they can take.

The *entries* are named policies (``NAME=SPEC``: ``ant=zoo:ant``, ``passive=passive``,
``mine=runs/x/policy``). A scenario (:func:`triplesumo.scenarios`: ``paper``, ``ffa``,
``pursuit``, ``2v2``, ``bodies``) gives the roster, its default one; a *lineup* puts one
entry in every seat, each entry at most once per match (a policy is one player and cannot
play on both sides). Which seats an entry can take:

* built-in policies (``passive``/``zero``, ``random``) take any seat;
* a policy file takes a seat whose observation size is its ``obs_dim``, in the
  observation mode it was trained with; with ``paper`` observations (one global vector,
  the same for every agent, not relative to the seat) only the seat it was trained in,
  in the roster it was trained in, since nothing in the vector tells it which quadruped
  it drives; with ``egocentric`` ones (the seat's own vector, partners' blocks before
  opponents') any seat with as many partners as the one it was trained in (a team's
  shared network, ``--share team``: either team seat, entered twice under two names to
  fill both).

Schedules: ``round-robin`` plays every lineup once per round for ``rounds`` rounds; in
round ``r`` every match resets with seed ``seed + r``, so all lineups meet the same
starts (a paired comparison). ``sampled`` plays ``matches`` matches; match ``m`` draws
its lineup uniformly from ``SeedSequence([seed, m])`` and resets with ``seed + m``.
Either way match ``m`` depends on ``m`` alone, so more rounds (or matches) extend a
tournament without changing the matches already played.

A self-play run's league joins with ``league=RUN`` (``--league RUN``): up to
``league_snapshots`` of each side's own snapshots (``RUN/league/pool.json``: the members and
the evicted ones, spread evenly over the epochs they joined at, the first and the last kept;
with ``league_until`` only those that joined by that epoch, so a run resumed since picks the same)
become entries named by member id (one per role where a side has several: ``team-0003.ant``),
beside ``policies``. Every entry that is a policy file whose manifest records its training
epochs is also drawn on ``ladder.png``: its rating against those epochs, a line through the
entries of one run (the ``run_id`` their manifests record: a league's snapshots and the run's
own policies, across resumes and wherever the files were copied to; for files written before
ids, a league's folder or one training command) per trained agent, other trained entries (the
zoo's) as labelled points, the built-ins as bands. Rated against one fixed field, not against
a pool that moves with the learner, that is
the honest "ratings rise" of a self-play run.

Places: a team's place is its best member's (1 = first, equal places share). Under the
paper's first-out rules they follow from the outcomes (winners 1, losers 2, a draw shares 1);
under elimination rules (free-for-all, pursuit) ``matches.csv`` also holds every seat's place
(``<seat>_place``: the order agents left the ring in), so a quadruped out second is rated above
one out first, and the cross-play matrix counts, for each pair of opponents, the matches the
row placed better than the column (a draw: the same place).

Writes into ``out``: ``matches.csv`` (one row per match, appended as matches finish),
``tournament.json`` (what the rows depend on, with the sha256 of every policy's files),
``leaderboard.csv``, ``crossplay.csv``, ``results.json`` and ``leaderboard.png``,
``crossplay.png``. In 1-vs-1 rosters the leaderboard also gives plain Elo (K = 32, from
1500). Ratings are openskill's (:mod:`~triplesumo.evaluation.ratings`),
computed from the rows in match order: the same rows give the same table. ``rating_tau=0``
rates the entries as frozen policies (no skill drift between matches, so their intervals keep
narrowing); unset keeps openskill's default drift, as every table published before it. A policy's
rating pools its seats, so where seats are unequal (the paper's Spider seat wins more
often than either team seat, whoever sits in it) ``rate_by="seat"`` rates each policy in
each seat apart (``passive@spider``) and writes the tables as ``*_by_seat.*``; it changes
no match, so ``resume=True`` re-rates a finished tournament without playing. With
``resume=True`` the rows already in ``out`` are kept (a torn last row is cut off) and
the rest are played, exactly the rows of an uninterrupted run.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from triplesumo._lock import held
from triplesumo.agents.builtin import BUILTIN
from triplesumo.agents.policy_file import LEAGUE_FORMAT, load_fixed_policy, seat_problem
from triplesumo.agents.zoo import find_policy_file, make_policy, policy_fingerprint
from triplesumo.envs.match import Match
from triplesumo.envs.seeding import check_seed
from triplesumo.evaluation.evaluate import RowAppender, check_ray, finished_rows
from triplesumo.evaluation.metrics import OUTCOMES
from triplesumo.evaluation.metrics_csv import open_table, write_table
from triplesumo.evaluation.parallel import TaskRunner, play_chunks, portable_spec
from triplesumo.evaluation.ratings import MODELS, PLACE_OF_OUTCOME, Elo, RatingTable, check_tau
from triplesumo.evaluation.runner import SeatedResult, play_matches
from triplesumo.evaluation.stats import wilson_interval
from triplesumo.evaluation.video import check_writable
from triplesumo.model.specs import PhysicsConfig, physics_record
from triplesumo.rules.config import OBS_MODES, MatchConfig
from triplesumo.rules.scenarios import scenario_config, scenarios
from triplesumo.rules.teams import Teams
from triplesumo.zoo import check_ring

SCHEDULES = ("round-robin", "sampled")
RATE_BY = ("policy", "seat")
RECORD_FILE = "tournament.json"
ROWS_FILE = "matches.csv"


@dataclass(frozen=True)
class TournamentConfig:
    """A tournament of seeded matches between named policies, rated with openskill."""

    scenario: str = "paper"
    """Which game (paper, ffa, pursuit, 2v2, bodies: ``triplesumo.scenarios()``): its default roster
    gives the seats."""
    policies: tuple[str, ...] = ("ant=zoo:ant", "bug=zoo:bug", "spider=zoo:spider", "passive=passive",
                                 "random=random")
    """NAME=SPEC entries; SPEC is zero, passive, random, zoo:NAME or a policy-file path."""
    schedule: str = "round-robin"
    """round-robin (every lineup once per round) or sampled (lineups drawn at random)."""
    rounds: int = 10
    """round-robin: rounds (each plays every lineup once, all from the same start seed)."""
    matches: int = 200
    """sampled: number of matches."""
    seed: int = 20_000
    """Seed of the schedule and the matches' reset noise."""
    steps_per_epoch: int = 500
    """Step limit of a match (a draw when reached)."""
    obs_mode: str = "paper"
    """Observation mode of the matches."""
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    """The simulation (``border_rim``: the paper's solid ring rim, the default since env v1;
    ``--no-physics.border-rim`` for env v0's ring); as the policies were trained on."""
    allow_other_ring: bool = False
    """Let a policy file trained on another ring (its manifest's physics: rim, start layout) play on this one;
    without it such a policy is refused, naming both rings."""
    rating_model: str = "PlackettLuce"
    """openskill model: PlackettLuce, BradleyTerryFull, BradleyTerryPart, ThurstoneMostellerFull or
    ThurstoneMostellerPart."""
    rating_tau: float | None = None
    """openskill's tau, the skill drift added to every sigma before each match: unset keeps openskill's
    default (25/300), which floors sigma at about 1.5; 0 suits frozen policies, whose intervals then keep
    narrowing with more matches. Only the rating changes: --resume re-rates a finished tournament."""
    rate_by: str = "policy"
    """Who is rated: "policy" (one rating per policy, whatever its seat) or "seat" (one per policy and
    seat, e.g. passive@spider: fairer where seats are unequal, as in the paper's 2-vs-1)."""
    confidence: float = 0.95
    """Confidence of the rating intervals and of the cross-play win-rate intervals."""
    out: str = "runs/tournament"
    """Folder for the tables and plots."""
    n_envs: int = 16
    """Matches played at once."""
    n_threads: int = 2
    """MuJoCo threads."""
    progress: bool = True
    """Show a progress bar."""
    resume: bool = False
    """Continue the tournament in ``out`` (killed, or to more rounds/matches): finished matches are kept."""
    ray: bool = False
    """Play the matches as Ray tasks (chunks of ray_chunk matches; the same rows as a local run): the
    command line hands run_tournament a Ray runner. Needs pip install "triplesumo[ray]"."""
    ray_address: str = ""
    """With ray: the Ray cluster to use (e.g. auto, ray://HOST:10001); empty: start a local Ray."""
    ray_chunk: int = 50
    """With ray (or any runner handed to run_tournament): matches per task."""
    league: str = ""
    """A self-play run folder: its own league snapshots join the entries (named by member id)."""
    league_snapshots: int = 8
    """With league: at most this many snapshots per side, spread evenly over their epochs."""
    league_until: int = 0
    """With league: only snapshots that joined at or before this epoch (0: all). The same picks however
    far the run has been resumed since, so a published table stays regenerable."""

    def __post_init__(self) -> None:
        check_seed(self.seed, "TournamentConfig.seed")
        for name in ("rounds", "matches", "steps_per_epoch", "n_envs", "n_threads", "ray_chunk", "league_snapshots"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"TournamentConfig.{name} must be an int >= 1, got {value!r}")
        if not isinstance(self.league_until, int) or isinstance(self.league_until, bool) or self.league_until < 0:
            raise ValueError(f"TournamentConfig.league_until must be an int >= 0 (0: every snapshot), "
                             f"got {self.league_until!r}")
        if self.league_until and not self.league:
            raise ValueError("TournamentConfig.league_until needs league (a self-play run folder)")
        check_ray("TournamentConfig", self.ray, self.ray_address)
        if self.scenario not in scenarios():
            raise ValueError(f"TournamentConfig.scenario must be one of {list(scenarios())}, got {self.scenario!r}")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"TournamentConfig.schedule must be one of {SCHEDULES}, got {self.schedule!r}")
        if self.obs_mode not in OBS_MODES:
            raise ValueError(f"TournamentConfig.obs_mode must be one of {OBS_MODES}, got {self.obs_mode!r}")
        if self.rating_model not in MODELS:
            raise ValueError(f"TournamentConfig.rating_model must be one of {sorted(MODELS)}, "
                             f"got {self.rating_model!r}")
        check_tau("TournamentConfig.rating_tau", self.rating_tau)
        if self.rate_by not in RATE_BY:
            raise ValueError(f"TournamentConfig.rate_by must be one of {RATE_BY}, got {self.rate_by!r}")
        if not 0.0 < self.confidence < 1.0:
            raise ValueError(f"TournamentConfig.confidence must be in (0, 1), got {self.confidence!r}")
        entries = parse_entries(self.policies)
        if len(entries) < 2 and not self.league:
            raise ValueError(f"TournamentConfig.policies needs at least 2 entries, got {list(self.policies)}")

    def resolved(self) -> TournamentConfig:
        """This config with ``league`` turned into ``policies`` entries (:func:`league_entries`)."""
        if not self.league:
            return self
        given = parse_entries(self.policies)
        added = league_entries(Path(self.league), self.league_snapshots, self.league_until)
        clash = sorted(set(given) & set(added))
        if clash:
            raise ValueError(f"TournamentConfig.policies: entries {clash} clash with the snapshots of {self.league}")
        pairs = (*self.policies, *(f"{n}={s}" for n, s in added.items()))
        if len(pairs) < 2:
            raise ValueError(f"TournamentConfig: {self.league} adds {len(added)} snapshot(s) to {list(self.policies)}; "
                             "a tournament needs at least 2 entries")
        return dataclasses.replace(self, policies=pairs, league="", league_until=0)

    def match_config(self) -> MatchConfig:
        """The scenario's match."""
        return scenario_config(self.scenario, max_steps=self.steps_per_epoch, obs_mode=self.obs_mode,
                               physics=self.physics)


def league_entries(run: Path, k: int, until: int = 0) -> dict[str, str]:
    """Entry name -> policy-file stem of up to ``k`` own snapshots per side of the self-play run ``run``
    (or its ``league/`` folder), oldest first, only those that joined at or before epoch ``until`` when
    it is not 0; errors name the file."""
    root = run if (run / "pool.json").exists() else run / "league"
    path = root / "pool.json"
    if not path.exists():
        raise FileNotFoundError(f"TournamentConfig.league: no self-play league in {run} ({path} not found; "
                                "a run trained with --self-play has one)")
    try:
        pool = json.loads(path.read_text(encoding="utf-8"))
        if pool.get("format") != LEAGUE_FORMAT:
            raise ValueError(f"format {pool.get('format')!r}, expected {LEAGUE_FORMAT!r}")
        entries: dict[str, str] = {}
        for members in ((*p["members"], *p["evicted"]) for p in pool["pools"].values()):
            own = sorted((m for m in members if m["source"] == "self" and (not until or int(m["epoch"]) <= until)),
                         key=lambda m: (int(m["epoch"]), m["id"]))
            picks = sorted({round(x) for x in np.linspace(0, len(own) - 1, min(k, len(own)))}) if own else []
            for m in (own[i] for i in picks):
                roles = sorted(m["policies"])
                for role in roles:
                    name = m["id"] if len(roles) == 1 else f"{m['id']}.{role}"
                    entries[name] = str(root / m["policies"][role])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"TournamentConfig.league: {path} is unreadable or corrupt ({exc})") from None
    if not entries:
        raise ValueError(f"TournamentConfig.league: {path} holds no snapshot of the run's own yet"
                         + (f" that joined at or before epoch {until}" if until else ""))
    return entries


def parse_entries(pairs: tuple[str, ...]) -> dict[str, str]:
    """``("ant=zoo:ant", ...)`` -> ``{"ant": "zoo:ant", ...}``; errors name the bad entry."""
    entries: dict[str, str] = {}
    for pair in pairs:
        name, sep, spec = pair.partition("=")
        if not sep or not name or not spec or "=" in spec:
            raise ValueError(f"TournamentConfig.policies: expected NAME=SPEC, got {pair!r}")
        if not all(c.isalnum() or c in "-_." for c in name):
            raise ValueError(f"TournamentConfig.policies: NAME may hold letters, digits, - _ . only, got {name!r}")
        if name in entries:
            raise ValueError(f"TournamentConfig.policies: entry {name!r} given twice")
        entries[name] = spec
    return entries


def _manifest(spec: str, physics: PhysicsConfig | None = None, allow_other_ring: bool = False) -> dict[str, Any] | None:
    """A policy file's manifest (``None`` for built-ins); errors name the spec, and with ``physics`` (the
    matches' simulation) a policy trained on another ring, unless ``allow_other_ring``."""
    if spec in BUILTIN:
        return None
    manifest = load_fixed_policy(find_policy_file(spec))[1]  # the weights too (numpy): a broken file is refused early
    if physics is not None:
        check_ring(spec, physics, allow_other_ring)
    return manifest


def eligible_seats(spec: str, manifest: dict[str, Any] | None, match: Match) -> list[str]:
    """The seats of ``match`` that policy ``spec`` (with its ``manifest``) can take (module docstring)."""
    if manifest is None:
        return list(match.agents)
    if manifest["obs_mode"] != match.config.obs_mode:
        return []
    motors = dict(zip(match.agents, match.action_sizes, strict=True))
    seats = [a for a in match.agents
             if match.observer.sizes[a] == int(manifest["obs_dim"]) and motors[a] == int(manifest["act_dim"])]
    roster = {a.name: a.team for a in match.config.agents}
    trained_with = _trained_partners(manifest)
    return [a for a in seats if seat_problem(manifest, a, roster, trained_with) is None]


def _trained_partners(manifest: dict[str, Any]) -> int | None:
    """How many partners the seat a policy was trained in had: its manifest's ``partners``, or for
    files written before that key, its scenario's default roster (``None`` where neither can say)."""
    if isinstance(manifest.get("partners"), int):
        return int(manifest["partners"])
    try:
        roster = scenario_config(str(manifest.get("scenario", "paper"))).agents
    except ValueError:
        return None
    seat = (manifest.get("plays") or [manifest.get("agent")])[0]
    names = [a.name for a in roster]
    if list(manifest.get("agents") or names) != names or seat not in names:
        return None
    return len(Teams.from_agents(roster).partners[names.index(seat)])


def _run_of(spec: str, manifest: dict[str, Any]) -> str | None:
    """Which training run a policy file comes from: the ``run_id`` its manifest records (wherever the file
    was copied to), else for files written before that key a league snapshot's league folder
    (``RUN/league/members/ID/ROLE``; a resumed run's snapshots record another command), that of a
    self-play run's own policy (``RUN/policy``), else its training command."""
    if isinstance(manifest.get("run_id"), str):
        return str(manifest["run_id"])
    path = Path(spec)
    if "league_member" in manifest and len(path.parents) > 2:
        return str(path.parents[2])
    if (path.parent / "league" / "pool.json").exists():  # a self-play run's own policy (RUN/policy)
        return str(path.parent / "league")
    return manifest.get("command")


def lineups(seats_of: dict[str, list[str]], agents: tuple[str, ...]) -> list[tuple[str, ...]]:
    """Every assignment of one entry per seat (roster order), each entry at most once, in a fixed order."""
    options = [[name for name, seats in seats_of.items() if agent in seats] for agent in agents]
    return [combo for combo in itertools.product(*options) if len(set(combo)) == len(combo)]


def columns_of(agents: tuple[str, ...], places: bool = False) -> tuple[str, ...]:
    """The columns of ``matches.csv`` for a roster (``places``: with each seat's place, under elimination rules)."""
    return ("match", "seed", *agents, *(f"{a}_outcome" for a in agents), *(f"{a}_place" for a in agents if places),
            "steps")


class Tournament:
    """The schedule of a :class:`TournamentConfig`: entries, their seats, the lineups and the matches."""

    def __init__(self, cfg: TournamentConfig, match_cfg: MatchConfig | None = None) -> None:
        cfg = cfg.resolved()
        self.cfg = cfg
        self.match_cfg = match_cfg or cfg.match_config()
        self.entries = parse_entries(cfg.policies)
        match = Match(self.match_cfg)
        self.agents = match.agents
        self.teams = Teams.from_agents(self.match_cfg.agents)
        self.manifests = {name: _manifest(spec, self.match_cfg.physics, cfg.allow_other_ring)
                          for name, spec in self.entries.items()}
        """Each entry's policy manifest (``None`` for a built-in)."""
        self.seats_of = {name: eligible_seats(spec, self.manifests[name], match) for name, spec in self.entries.items()}
        idle = [f"{n}={self.entries[n]}" for n, s in self.seats_of.items() if not s]
        if idle:
            raise ValueError(f"policies {idle} fit no seat of the {cfg.scenario!r} scenario (seats "
                             f"{list(self.agents)}, obs_mode {self.match_cfg.obs_mode!r}, observation sizes "
                             f"{[match.observer.sizes[a] for a in self.agents]})")
        self.lineups = lineups(self.seats_of, self.agents)
        if not self.lineups:
            raise ValueError(f"no lineup fills every seat {list(self.agents)} with different policies; "
                             f"seats each policy can take: {self.seats_of}")
        self.n_matches = cfg.rounds * len(self.lineups) if cfg.schedule == "round-robin" else cfg.matches
        self.places = self.match_cfg.rules == "elimination"
        """Whether the rows hold each seat's place (elimination rules: the order agents left in)."""
        self.columns = columns_of(self.agents, self.places)

    def lineup_of(self, m: int) -> tuple[str, ...]:
        """Entry names in each seat of match ``m``."""
        if self.cfg.schedule == "round-robin":
            return self.lineups[m % len(self.lineups)]
        draw = np.random.default_rng(np.random.SeedSequence([self.cfg.seed, m])).integers(len(self.lineups))
        return self.lineups[int(draw)]

    def seed_of(self, m: int) -> int:
        """Reset seed of match ``m``."""
        return self.cfg.seed + (m // len(self.lineups) if self.cfg.schedule == "round-robin" else m)

    def row(self, result: SeatedResult) -> dict[str, Any]:
        m = result.index
        return {"match": m + 1, "seed": self.seed_of(m), **dict(zip(self.agents, self.lineup_of(m), strict=True)),
                **{f"{a}_outcome": o for a, o in zip(self.agents, result.outcomes, strict=True)},
                **({f"{a}_place": p for a, p in zip(self.agents, result.places, strict=True)} if self.places else {}),
                "steps": result.steps}

    def play(self, policies: dict[str, Any], first: int, end: int, n_envs: int, n_threads: int,
             on_row: Callable[[dict[str, Any]], None] | None = None, progress: str | None = None
             ) -> list[dict[str, Any]]:
        """The rows of matches ``first .. end - 1`` (``policies``: entry name -> policy), in match order;
        ``on_row`` gets each as soon as it and every earlier one have finished."""
        results = play_matches(lambda m: [policies[n] for n in self.lineup_of(m)], self.seed_of, end, self.match_cfg,
                               n_envs, n_threads, first=first,
                               on_result=None if on_row is None else lambda r: on_row(self.row(r)),
                               progress=progress)
        return [self.row(r) for r in results]

    def valid_row(self, values: dict[str, str], number: int) -> bool:
        m = number - 1
        return (values["match"] == str(number) and values["seed"] == str(self.seed_of(m))
                and tuple(values[a] for a in self.agents) == self.lineup_of(m)
                and all(values[f"{a}_outcome"] in OUTCOMES for a in self.agents) and values["steps"].isdigit()
                and all(values[f"{a}_place"].isdigit() for a in self.agents if self.places))

    def seat_places(self, row: dict[str, str]) -> list[int]:
        """Each seat's place in a row of ``matches.csv`` (see the module docstring)."""
        if self.places:
            return [int(row[f"{a}_place"]) for a in self.agents]
        return [PLACE_OF_OUTCOME[row[f"{a}_outcome"]] for a in self.agents]

    def record(self) -> dict[str, Any]:
        """What the rows depend on (see the module docstring)."""
        c = self.cfg
        return {"rows_depend_on": {"schedule": c.schedule, "seed": c.seed, "match": asdict(self.match_cfg)},
                "entries": {n: {"policy": s, "sha256": policy_fingerprint(s), "seats": self.seats_of[n]}
                            for n, s in self.entries.items()}}


def run_tournament(cfg: TournamentConfig, match_cfg: MatchConfig | None = None,
                   runner: TaskRunner | None = None) -> dict[str, Any]:
    """Play (or resume) the tournament, write its tables and plots; returns the results.

    With a ``runner`` (:mod:`triplesumo.evaluation.parallel`) the matches are played by it as
    tasks of ``cfg.ray_chunk`` matches (the same rows); ``cfg.ray`` asks for one (the command
    line hands down a :class:`~triplesumo.integrations.ray_tasks.RayRunner`).

    ``match_cfg`` replaces the scenario's match (a roster of any teams), for tests and
    scenarios not yet named.
    """
    if cfg.ray and runner is None:
        raise ValueError("TournamentConfig.ray: run_tournament plays on the runner it is handed; pass one, e.g. "
                         "triplesumo.integrations.ray_tasks.RayRunner() inside ray_tasks.session() (as --ray does)")
    out = check_writable(Path(cfg.out), folder=True)
    with held(out, "tournament"):  # one writer: a second tournament into it meanwhile is refused
        return _run_tournament(cfg.resolved(), match_cfg, runner, out)


def _run_tournament(cfg: TournamentConfig, match_cfg: MatchConfig | None, runner: TaskRunner | None,
                    out: Path) -> dict[str, Any]:
    t = Tournament(cfg, match_cfg)
    policies = {n: make_policy(s, seed=cfg.seed, expect_obs_mode=t.match_cfg.obs_mode) for n, s in t.entries.items()}
    record = json.loads(json.dumps(t.record()))
    rows_path = out / ROWS_FILE
    done = 0
    if cfg.resume:
        empty_record = (out / RECORD_FILE).exists() and (out / RECORD_FILE).stat().st_size == 0
        if not empty_record:  # (empty: killed before anything was written, a fresh start if no row was either)
            _check_resumable(out / RECORD_FILE, record)
        done = finished_rows(rows_path, t.n_matches, t.columns, t.valid_row,
                             ("table of tournament matches", "matches", "matches of this schedule"))
        if empty_record and done:
            raise ValueError(f"cannot resume {out}: {RECORD_FILE} is empty, so nothing says what its {done} matches "
                             f"in {ROWS_FILE} depend on; choose another --out")
    from triplesumo.agents.policy_file import atomic_write_bytes

    atomic_write_bytes(out / RECORD_FILE, (json.dumps(record, indent=2) + "\n").encode())
    if done < t.n_matches:
        progress = "tournament" if cfg.progress else None
        with RowAppender(rows_path, fresh=done == 0, columns=t.columns) as append:
            if runner is not None:
                play_tournament_on(runner, cfg, match_cfg, done, t.n_matches, cfg.ray_chunk, on_row=append,
                                   progress=progress)
            else:
                t.play(policies, done, t.n_matches, cfg.n_envs, cfg.n_threads, on_row=append, progress=progress)
    rows = read_rows(rows_path)
    results = tabulate(rows, t, cfg)
    results["config"] = asdict(cfg)
    _write_outputs(out, results, cfg)
    return results


def play_schedule(cfg: TournamentConfig, match_cfg: MatchConfig | None, first: int, end: int,
                  n_envs: int | None = None) -> list[dict[str, Any]]:
    """The ``matches.csv`` rows of matches ``first .. end - 1`` of ``cfg``'s tournament, played here on
    one MuJoCo thread (a chunk of a tournament played by a runner, e.g. as a Ray task)."""
    t = Tournament(cfg, match_cfg)
    policies = {n: make_policy(s, seed=cfg.seed, expect_obs_mode=t.match_cfg.obs_mode) for n, s in t.entries.items()}
    return t.play(policies, first, end, min(n_envs or cfg.n_envs, end - first), 1)


def play_tournament_on(runner: TaskRunner, cfg: TournamentConfig, match_cfg: MatchConfig | None = None,
                       first: int = 0, n: int | None = None, chunk: int = 50,
                       on_row: Callable[[dict[str, Any]], None] | None = None,
                       progress: str | None = None) -> list[dict[str, Any]]:
    """Rows of matches ``first .. n - 1`` of the tournament of ``cfg`` (``n``: its whole schedule), played by
    ``runner`` as tasks of ``chunk`` matches (:func:`play_schedule`): the rows of ``matches.csv`` a local run
    writes."""
    if n is None:
        n = Tournament(cfg, match_cfg).n_matches
    portable = dataclasses.replace(cfg, policies=tuple(f"{k}={portable_spec(v)}"
                                                       for k, v in parse_entries(cfg.policies).items()))
    return play_chunks(runner, play_schedule, (portable, match_cfg), n, first, chunk, on_row, progress)


def read_rows(path: Path) -> list[dict[str, str]]:
    import csv

    with open_table(path) as fh:
        return list(csv.DictReader(fh))


def _check_resumable(path: Path, record: dict[str, Any]) -> None:
    folder = path.parent
    if not path.exists():
        raise FileNotFoundError(f"nothing to resume in {folder}: {path.name} not found (run without resume to "
                                "start a tournament there)")
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
        old_fields, old_entries = old["rows_depend_on"], old["entries"]
        match = old_fields.get("match")
        if isinstance(match, dict) and isinstance(match.get("physics"), dict):  # recorded before a physics field
            old_fields = {**old_fields, "match": {**match, "physics": physics_record(match["physics"])}}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"cannot resume {folder}: {path} is unreadable or corrupt ({exc})") from None
    for name, value in record["rows_depend_on"].items():
        if old_fields.get(name) != value:
            raise ValueError(f"cannot resume {folder}: {name} was {old_fields.get(name)!r}, now {value!r}")
    if old_entries != record["entries"]:
        changed = sorted(n for n in {*old_entries, *record["entries"]}
                         if old_entries.get(n) != record["entries"].get(n))
        raise ValueError(f"cannot resume {folder}: entries {changed} changed (another policy, its files, or the "
                         "set of entries)")


def tabulate(rows: list[dict[str, str]], t: Tournament, cfg: TournamentConfig) -> dict[str, Any]:
    """Ratings, per-seat win/loss/draw counts and the cross-play matrix from the match rows.

    The players are the policies, or with ``rate_by="seat"`` each policy in each seat it took
    (``NAME@SEAT``).
    """
    def player(name: str, seat: str) -> str:
        return name if cfg.rate_by == "policy" else f"{name}@{seat}"

    names = [player(n, seat) for n in t.entries for seat in
             ([t.agents[0]] if cfg.rate_by == "policy" else [a for a in t.agents if a in t.seats_of[n]])]
    table = RatingTable(cfg.rating_model, names, tau=cfg.rating_tau)
    counts = {n: {a: dict.fromkeys(OUTCOMES, 0) for a in t.agents} for n in names}
    policy_of = {player(n, seat): n for n in t.entries for seat in t.agents}
    wins = np.zeros((len(names), len(names)), dtype=np.int64)
    draws = np.zeros_like(wins)
    games = np.zeros_like(wins)
    idx = {n: i for i, n in enumerate(names)}
    team_members = [[int(i) for i in np.flatnonzero(t.teams.team_of == k)] for k in range(len(t.teams.names))]
    duel = len(team_members) == 2 and all(len(m) == 1 for m in team_members)
    elo = Elo() if duel else None  # plain Elo beside openskill where users expect it: 1-vs-1
    for row in rows:
        seated = [player(row[a], a) for a in t.agents]
        outcome = [row[f"{a}_outcome"] for a in t.agents]
        for name, agent, o in zip(seated, t.agents, outcome, strict=True):
            counts[name][agent][o] += 1
        if "error" in outcome:
            continue  # a physics error decides nothing: counted, not rated
        teams = [[seated[i] for i in members] for members in team_members]
        seat_place = t.seat_places(row)
        place = [min(seat_place[i] for i in members) for members in team_members]  # a team: its best member's
        table.record(teams, place)
        if elo is not None:
            elo.record(seated[0], seated[1], 1.0 if place[0] < place[1] else 0.5 if place[0] == place[1] else 0.0)
        team_place = [place[k] for k in t.teams.team_of]
        for i, j in itertools.permutations(range(len(seated)), 2):
            if t.teams.team_of[i] != t.teams.team_of[j]:
                row_i, col_j = idx[seated[i]], idx[seated[j]]
                games[row_i, col_j] += 1
                wins[row_i, col_j] += team_place[i] < team_place[j]
                draws[row_i, col_j] += team_place[i] == team_place[j]
    board = []
    for name in table.ranking():
        r = table[name]
        lo, hi = r.interval(cfg.confidence)
        total = {o: sum(counts[name][a][o] for a in t.agents) for o in OUTCOMES}
        elo_rating = None if elo is None else elo.ratings.get(name, elo.initial)
        manifest = t.manifests[policy_of[name]] or {}
        board.append({"policy": name, "spec": t.entries[policy_of[name]], "mu": r.mu, "sigma": r.sigma, "lo": lo,
                      "hi": hi, "ordinal": r.ordinal, "elo": elo_rating, "matches": sum(total.values()),
                      **{f"n_{o}": total[o] for o in OUTCOMES}, "seats": counts[name],
                      "trained": manifest.get("agent"), "epochs": manifest.get("epochs"),
                      "env_steps": manifest.get("env_steps"), "run": _run_of(t.entries[policy_of[name]], manifest)})
    cross = []
    for a, b in itertools.permutations(names, 2):
        n, w = int(games[idx[a], idx[b]]), int(wins[idx[a], idx[b]])
        lo, hi = wilson_interval(w, n, cfg.confidence)
        cross.append({"row": a, "column": b, "n": n, "wins": w, "draws": int(draws[idx[a], idx[b]]),
                      "win_rate": w / n if n else None, "lo": None if math.isnan(lo) else lo,
                      "hi": None if math.isnan(hi) else hi})
    return {"scenario": cfg.scenario, "seats": list(t.agents), "n_matches": len(rows), "rate_by": cfg.rate_by,
            "rating_model": cfg.rating_model, "rating_tau": float(table.model.tau), "confidence": cfg.confidence,
            "leaderboard": board,
            "crossplay": cross}


def _write_outputs(out: Path, results: dict[str, Any], cfg: TournamentConfig) -> None:
    import csv
    import io

    from triplesumo.agents.policy_file import atomic_write_bytes
    from triplesumo.evaluation.tournament_plots import plot_crossplay, plot_ladder, plot_leaderboard

    seats = results["seats"]
    tag = "" if cfg.rate_by == "policy" else "_by_seat"
    buf = io.StringIO()
    seat_cols = [f"{a}_{o}" for a in seats for o in OUTCOMES]
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["rank", "policy", "spec", "mu", "sigma", "lo", "hi", "ordinal", "elo", "matches",
                *(f"n_{o}" for o in OUTCOMES), *seat_cols])
    for rank, e in enumerate(results["leaderboard"], 1):
        w.writerow([rank, e["policy"], e["spec"], *(f"{e[k]:.4f}" for k in ("mu", "sigma", "lo", "hi", "ordinal")),
                    "" if e["elo"] is None else f"{e['elo']:.1f}", e["matches"], *(e[f"n_{o}"] for o in OUTCOMES),
                    *(e["seats"][a][o] for a in seats for o in OUTCOMES)])
    write_table(out / f"leaderboard{tag}.csv", buf.getvalue().encode())
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["row", "column", "n", "wins", "draws", "win_rate", "lo", "hi"])
    for c in results["crossplay"]:
        w.writerow([c["row"], c["column"], c["n"], c["wins"], c["draws"],
                    *("" if c[k] is None else f"{c[k]:.4f}" for k in ("win_rate", "lo", "hi"))])
    write_table(out / f"crossplay{tag}.csv", buf.getvalue().encode())
    atomic_write_bytes(out / f"results{tag}.json", (json.dumps(results, indent=2) + "\n").encode())
    title = f"{cfg.scenario}: {results['n_matches']} matches"
    plot_leaderboard(results, out / f"leaderboard{tag}.png", title=title)
    plot_crossplay(results, out / f"crossplay{tag}.png", title=title)
    if sum(e["epochs"] is not None for e in results["leaderboard"]) >= 2:
        plot_ladder(results, out / f"ladder{tag}.png", title=title)
    else:  # no trained entries with epochs (now): no ladder left over from another tournament here
        (out / f"ladder{tag}.png").unlink(missing_ok=True)


def format_leaderboard(results: dict[str, Any]) -> str:
    """A readable leaderboard with per-seat win/loss/draw."""
    seats = results["seats"]
    pct = round(100 * results["confidence"])
    head = f"{'#':>2s} {'policy':16s} {'mu':>7s} {'sigma':>6s} {f'{pct}% interval':>17s} {'matches':>7s} " + " ".join(
        f"{a + ' W/L/D':>14s}" for a in seats)
    lines = [head]
    for rank, e in enumerate(results["leaderboard"], 1):
        per_seat = " ".join(f"{'{}/{}/{}'.format(*(e['seats'][a][o] for o in ('win', 'loss', 'draw'))):>14s}"
                            for a in seats)
        lines.append(f"{rank:2d} {e['policy'][:16]:16s} {e['mu']:7.2f} {e['sigma']:6.2f} "
                     f"[{e['lo']:6.2f}, {e['hi']:6.2f}] {e['matches']:7d} {per_seat}")
    return "\n".join(lines)
