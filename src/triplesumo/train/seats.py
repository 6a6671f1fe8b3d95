"""Who sits in which seat of every match: the learners' seats, the fixed policies', and with ``self_play`` the
league members drawn for the seats of the sides that do not learn; :meth:`Seats.act` fills the actions of every
seat a learner does not take.

With ``self_play`` a :class:`~triplesumo.train.league.League` seats the agents that do not learn: at every match
start one member of each such side's pool is drawn (in a free-for-all one per seat); at every match end its
players are rated, due learning sides are admitted (their actors written as policy files under ``RUN/league``).
When both sides learn, each match is live or one learner plays the other side's pool (``League.draw_live``); the
learner whose seats a member takes sits the match out.

:class:`Seats` knows the roster, the fixed policies and the league, never the matches' state: the training loop
draws a match's players when it starts (:meth:`Seats.draw`, :meth:`Seats.plays`) and hands it each finished
match (:meth:`Seats.match_end`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from triplesumo.agents.builtin import BUILTIN, RandomPolicy, ZeroPolicy, act_batch
from triplesumo.agents.frozen import FrozenPolicy
from triplesumo.agents.policy_file import load_fixed_policy
from triplesumo.envs.match import Match
from triplesumo.rules.config import MatchConfig, check_shared_network
from triplesumo.rules.outcome import ERROR_CODE
from triplesumo.train.arrays import Arrays, host
from triplesumo.train.checkpoint import State
from triplesumo.train.config import TrainConfig
from triplesumo.train.league import League
from triplesumo.train.learners import Learner, LearnerSpec
from triplesumo.zoo import policies_from_pairs


class Seats:
    """The seats of ``n_envs`` matches: the fixed policy of every agent that does not learn (:attr:`fixed`, built
    from ``pairs``) and, with ``self_play``, per match, per seat, the league member playing it (None: a learner's or
    a fixed policy's seat) and that member's policy. Without ``self_play`` every seat is None and :attr:`league` is
    None."""

    def __init__(self, cfg: TrainConfig, match_cfg: MatchConfig, probe: Match, specs: Sequence[LearnerSpec],
                 pairs: tuple[str, ...], run_dir: Path, league_seed: Callable[[], int], resume: bool,
                 device: torch.device | None) -> None:
        self.cfg, self.match_cfg, self.probe, self.specs = cfg, match_cfg, probe, list(specs)
        self.xp = Arrays(device)
        self.agents = [a for spec in specs for a in spec.agents]
        try:
            self.fixed: dict[str, Any] = policies_from_pairs(
                pairs, cfg.seed, cfg.obs_mode, obs_dims=probe.observer.sizes,
                action_sizes=dict(zip(probe.agents, probe.action_sizes, strict=True)),
                teams={a.name: a.team for a in match_cfg.agents}, physics=cfg.physics,
                allow_other_ring=cfg.allow_other_ring)
            """Agent -> the fixed policy of every agent that does not learn."""
        except ValueError as err:
            raise ValueError(f"TrainConfig.policies (scenario {cfg.scenario!r}): {err}") from None
        self._fixed = [(probe.agents.index(a), p) for a, p in self.fixed.items()]
        self._fixed_on_device = {i: p.on_device(device) for i, p in self._fixed
                                 if device is not None and isinstance(p, FrozenPolicy)}
        """Roster index -> a trained fixed policy acting on the device (``warp``; others act on the host)."""
        self.league: League | None = None
        """The self-play league (``cfg.self_play``): pools whose members take the seats that do not learn."""
        self.members: list[list[str | None]] = [[None] * probe.n_agents for _ in range(cfg.n_envs)]
        """Per match, per seat: the league member playing it this match (None: a learner's or fixed seat)."""
        self.policies: list[dict[int, Any]] = [{} for _ in range(cfg.n_envs)]
        self._member_policies: dict[tuple[str, str], Any] = {}
        self._groups: tuple[list[tuple[int, Any, torch.Tensor]], list[tuple[int, int, Any]]] | None = None
        """warp: the seats' trained members with the matches each plays, and the random seats (None: stale)."""
        self._device_policies: dict[int, tuple[FrozenPolicy, Any]] = {}
        self.league_seats: frozenset[int] = frozenset()
        """Seats whose player the league draws (the sides that do not learn); a fixed agent of a learning side
        plays its own policy in every match."""
        if cfg.self_play:
            self._setup_league(pairs, run_dir, league_seed, resume)

    def _setup_league(self, pairs: tuple[str, ...], run_dir: Path, league_seed: Callable[[], int],
                      resume: bool) -> None:
        """Sides, roles and seeds of the league (docs/self-play.md); errors name the config field.

        A side is a team of the roster (paper: ``team`` = Ant and Bug, ``spider``); in a free-for-all
        (every team one agent) one side ``ffa`` whose one role takes any seat. The seats of sides that do not
        learn are drawn from their pools, each pool seeded by ``league.zoo`` or else by those seats'
        ``policies`` (passive when not named). A side with learning and fixed agents (the paper's stage 1: Ant
        learns, Bug passive) is a learning side whose roles are its learners': its fixed agents play their
        ``policies`` in every match, and when the side sits a match out only its learners' seats go to a
        member of its pool.
        """
        cfg, probe = self.cfg, self.probe
        roster = list(probe.agents)
        teams = {a.name: a.team for a in self.match_cfg.agents}
        fixed = [a for a in roster if a not in self.agents]
        self.ffa = len(set(teams.values())) == len(roster)
        if self.ffa:
            if len(self.specs) != 1:
                raise ValueError(f"TrainConfig.self_play in a free-for-all (scenario {cfg.scenario!r}) takes one "
                                 f"learner whose snapshots fill the other seats, got {[s.name for s in self.specs]}")
            if len(set(probe.observer.sizes.values())) > 1 or len(set(probe.action_sizes)) > 1:
                raise ValueError(f"TrainConfig.self_play (scenario {cfg.scenario!r}): the seats have different "
                                 "observation or action sizes, so one network cannot take them all")
            check_shared_network(cfg.obs_mode, roster, f"TrainConfig.self_play in a free-for-all (scenario "
                                 f"{cfg.scenario!r}: the learner's snapshots take every seat)")
            sides: dict[str, list[str]] = {"ffa": ["ffa"]}
            self.side_of = dict.fromkeys(roster, "ffa")
            self.role_of = dict.fromkeys(roster, "ffa")
        else:
            sides = {}
            for a in roster:
                sides.setdefault(teams[a], []).append(a)
            self.side_of, self.role_of = dict(teams), {a: a for a in roster}
            for side, members in list(sides.items()):
                learning = [a for a in members if a in self.agents]
                if learning:  # a side's fixed agents (paper: Bug passive beside a learning Ant) keep their
                    sides[side] = learning  # policies in every match; its pool's members hold the learners' roles
        self.learning_sides = list(dict.fromkeys(self.side_of[a] for a in self.agents))
        """Sides whose learners learn; with several, each match is live or one plays the others' pools."""
        self.opponent_sides = list(dict.fromkeys(self.side_of[a] for a in fixed  # (free-for-all: the other seats)
                                                 if self.ffa or self.side_of[a] not in self.learning_sides))
        if not self.opponent_sides and len(self.learning_sides) < 2:
            raise ValueError(f"TrainConfig.self_play: every agent learns ({roster}) in one side; self-play draws "
                             "the seats of the agents that do not learn from pools, so leave a side out of learn")
        self.league_seats = frozenset(i for i, a in enumerate(roster) if self.side_of[a] in self.opponent_sides)
        spec_of = dict(p.split("=", 1) for p in pairs)
        seeded = {e.split("=", 1)[0] for e in cfg.league.zoo}
        extra: list[str] = []
        for side in self.opponent_sides:
            roles = sides[side]
            if not any(r in seeded for r in roles):
                extra += [f"{r}={spec_of.get(a, 'passive')}" for r, a in
                          zip(roles, [a for a in fixed if self.side_of[a] == side], strict=False)]
        self.sides = sides
        """Side -> its roles in the league: every agent of a side that does not learn, the learning agents of
        one that does."""
        lcfg = dataclasses.replace(cfg.league, zoo=(*cfg.league.zoo, *extra))
        try:
            # (resuming: the checkpoint's league state holds the seeded members, so seeding would only rewrite them)
            self.league = League(run_dir, lcfg, sides, seed=league_seed(), seed_zoo=not resume)
        except ValueError as err:
            raise ValueError(f"TrainConfig.league: {err}") from None

    def draw(self, k: int) -> None:
        """Draw match ``k``'s opponents (at its start) from the pools of the sides that do not learn and,
        when several sides learn, of the learning sides that sit this match out (``League.draw_live``)."""
        league = self.league
        if league is None:
            return
        roster = self.probe.agents
        members: list[str | None] = [None] * len(roster)
        live = league.draw_live(self.learning_sides)
        for side in (*self.opponent_sides, *(s for s in self.learning_sides if s not in live)):
            seats = [i for i, a in enumerate(roster) if self.side_of[a] == side and self.role_of[a] in
                     self.sides[side] and not (a in self.agents and side in live)]
            picks = league.sample(side, len(seats) if self.ffa else 1)
            for j, i in enumerate(seats):
                members[i] = picks[j if self.ffa else 0].id
        seed = int(league.rng.integers(2**31 - 1))
        self.members[k] = members
        self.policies[k] = self.policies_of(members, seed)
        self._groups = None

    def plays(self, learner: Learner, k: int) -> bool:
        """Whether ``learner`` plays match ``k`` (a league member may take its seats, see :meth:`draw`)."""
        return all(self.members[k][i] is None for i in learner.index)

    def policies_of(self, members: list[str | None], seed: int) -> dict[int, Any]:
        """Seat index -> the policy of the member seated there (policy files loaded once, then shared)."""
        assert self.league is not None
        probe, out = self.probe, {}
        for i, member_id in enumerate(members):
            if member_id is None:
                continue
            member, role = self.league.member(member_id), self.role_of[probe.agents[i]]
            spec = member.policies[role]
            if spec in BUILTIN:
                size = probe.action_sizes[i]
                out[i] = BUILTIN[spec](seed + i, action_size=size) if spec == "random" else BUILTIN[spec](size)
            else:
                key = (member_id, role)
                if key not in self._member_policies:
                    self._member_policies[key] = load_fixed_policy(self.league.root / spec)[0]
                out[i] = self._member_policies[key]
        return out

    def match_end(self, k: int, outcomes: np.ndarray, places: np.ndarray, epoch: int,
                  write: Callable[[str, Mapping[str, Path]], None]) -> dict[str, float]:
        """Rate match ``k`` (its seats' outcome codes and places; seats still in play when every learner
        is out share the best place), admit the learning sides that are due (``write(side, stems)`` writes a
        snapshot's policy files), and return the league's scalars of ``epoch`` to log."""
        league = self.league
        assert league is not None
        if not (outcomes == ERROR_CODE).any():
            # an agent outside its side's league roles (Bug passive beside a learning Ant) plays for whoever holds
            # its side's seats this match: the member that sat the side out, else the side's learner
            sat_out = {self.side_of[a]: m for a, m in zip(self.probe.agents, self.members[k], strict=True) if m}
            players = [self.members[k][i] or (sat_out.get(self.side_of[a]) if self.role_of[a] not in
                                              self.sides[self.side_of[a]] else None)
                       or League.learner(self.side_of[a]) for i, a in enumerate(self.probe.agents)]
            league.record_seats(players, [float(p) if int(p) > 0 else 1.0 for p in places],
                                [a.team for a in self.match_cfg.agents])
        for side in self.learning_sides:
            if league.admit_due(side, epoch):
                league.admit(side, epoch, write=functools.partial(write, side))
                self._member_policies = {key: p for key, p in self._member_policies.items()
                                         if key[0] in {m.id for pool in league.pools.values() for m in pool.members}}
                kept = {id(p) for p in self._member_policies.values()}
                self._device_policies = {key: v for key, v in self._device_policies.items() if key in kept}
        return league.epoch_end(epoch)

    def act(self, actions: Any, obs: Any) -> None:
        """Every seat a learner does not take, into ``actions`` (``(n_envs, n_agents, width)``, zeros there):
        the fixed policies (a trained one on the device where the run's arrays live there, the others on the
        host from their own generators) and the league members."""
        sizes, n = self.probe.action_sizes, self.cfg.n_envs
        for i, policy in self._fixed:
            if i in self.league_seats or isinstance(policy, ZeroPolicy):  # (a zero policy leaves the zeros)
                continue
            if i in self._fixed_on_device:
                actions[:, i, :sizes[i]] = self._fixed_on_device[i](obs[:, i])
                continue
            fixed = policy.sample(n) if isinstance(policy, RandomPolicy) else act_batch(policy, host(obs[:, i]))
            actions[:, i, :sizes[i]] = self.xp.put(fixed, float32=True)
        if self.league is not None:
            (self.act_on_device if self.xp.on_device else self.act_on_host)(actions, obs)

    def act_on_host(self, actions: np.ndarray, obs: np.ndarray) -> None:
        """The league members' actions of a ``cpu`` run, seat by seat, into ``actions``."""
        sizes = self.probe.action_sizes
        for k, seated in enumerate(self.policies):
            for i, policy in seated.items():
                actions[k, i, :sizes[i]] = act_batch(policy, obs[k, i][None])[0]

    def act_on_device(self, actions: torch.Tensor, obs: torch.Tensor) -> None:
        """The league members' actions of a ``warp`` run: each trained member acts once per seat on the
        observations of all the matches it plays there (``FrozenPolicy.on_device``); passive members
        leave their zeros; random ones draw on the host from their own generators (as on ``cpu``), one
        copy to the device for all of them."""
        if self._groups is None:  # recomputed only when seats change (a match start, a resume)
            groups: dict[tuple[int, int], tuple[Any, list[int]]] = {}
            on_host: list[tuple[int, int, Any]] = []
            for k, seated in enumerate(self.policies):
                for i, policy in seated.items():
                    if isinstance(policy, FrozenPolicy):
                        groups.setdefault((i, id(policy)), (policy, []))[1].append(k)
                    elif not isinstance(policy, ZeroPolicy):
                        on_host.append((k, i, policy))
            self._groups = ([(i, self._device_policy(p), self.xp.put(np.array(ks)))
                             for (i, _), (p, ks) in groups.items()], on_host)
        trained, on_host = self._groups
        sizes = self.probe.action_sizes
        for i, act, rows in trained:
            actions[rows, i, :sizes[i]] = act(obs[rows, i])
        if on_host:  # one copy to the device for all of them (and one of the observations only if one needs it)
            ks, seats = (self.xp.put(np.array(v)) for v in zip(*[(k, i) for k, i, _ in on_host], strict=True))
            seen = None if all(isinstance(p, RandomPolicy) for *_, p in on_host) else host(obs[ks, seats])
            drawn = np.zeros((len(on_host), actions.shape[-1]), dtype=np.float32)
            for r, (_, i, policy) in enumerate(on_host):
                drawn[r, :sizes[i]] = policy.sample(1)[0] if seen is None else policy(seen[r])
            actions[ks, seats] = self.xp.put(drawn)

    def _device_policy(self, policy: FrozenPolicy) -> Any:
        """``policy.on_device`` (made once per member policy; dropped with the member)."""
        key = id(policy)
        if key not in self._device_policies:
            self._device_policies[key] = (policy, policy.on_device(self.xp.device))
        return self._device_policies[key][1]

    def state_dict(self) -> State:
        """What a checkpoint keeps of the seats: the fixed policies' generators and, with a league, the league,
        who sits where and the seated policies' generators."""
        state: dict[str, Any] = {"policy_rngs": {a: p.rng.bit_generator.state for a, p in self.fixed.items()
                                                 if hasattr(p, "rng")}}
        if self.league is not None:
            self.league.save()
            state |= {"league": self.league.state_dict(), "seats": self.members,
                      "seat_rngs": [{str(i): p.rng.bit_generator.state for i, p in seated.items() if hasattr(p, "rng")}
                                    for seated in self.policies]}
        return State(json=state)

    def load_state_dict(self, state: State, epochs_done: int) -> None:
        """The seats of :meth:`state_dict` (the league's log cut back to ``epochs_done``)."""
        saved = state.json
        for agent, rng_state in saved.get("policy_rngs", {}).items():
            self.fixed[agent].rng.bit_generator.state = rng_state
        if self.league is None:
            return
        self.league.load_state_dict(saved["league"])
        self.league.truncate_log(epochs_done)
        self.members = [list(m) for m in saved["seats"]]
        for k, members in enumerate(self.members):
            self.policies[k] = self.policies_of(members, 0)
            for i, rng_state in saved["seat_rngs"][k].items():
                self.policies[k][int(i)].rng.bit_generator.state = rng_state
        self._groups = None
