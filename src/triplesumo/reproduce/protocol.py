"""The protocol: its stages in order, each with what it runs and when it is complete, and the contest rule's
verdict."""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import json
import shlex
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.agents.zoo import policy_fingerprint
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.ppo import PPOConfig
from triplesumo.algos.sac import SACConfig
from triplesumo.algos.td3 import TD3Config
from triplesumo.evaluation.compare import CompareConfig, compare, format_compare
from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate
from triplesumo.evaluation.metrics_csv import open_table, read_table_bytes, table_exists
from triplesumo.evaluation.parallel import ProcessRunner, TaskRunner
from triplesumo.model.specs import PhysicsConfig
from triplesumo.reproduce.config import CONTEST_BAND, PUSH_MIN, ContestError, ReproduceConfig, Stage, ablation, bug_runs
from triplesumo.reproduce.pretrain import PAIR_FILE, SCREENS_FILE, Side, counts_of, play_pair_rule, read_record
from triplesumo.train.config import TrainConfig, parallel_schedule
from triplesumo.train.run_folder import command_for
from triplesumo.train.sweep import SweepConfig, Trial, finished, run_facts, run_trial, run_trials, trials


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not table_exists(path):
        return []
    with open_table(path) as fh:
        return list(csv.DictReader(fh))


def _fingerprint(policy: str) -> str | None:
    """:func:`policy_fingerprint`, None when the policy's files are gone."""
    try:
        return policy_fingerprint(policy)
    except FileNotFoundError:
        return None


def _rows_in(path: Path) -> int:
    """Complete rows of a metrics CSV (lines ending in a newline, less the header)."""
    if not table_exists(path):
        return 0
    return max(read_table_bytes(path).count(b"\n") - 1, 0)


CONTEST_CHECKS = ("ant-pushes", "spider-pushes", "match")
"""Stage 2's checks, in the order they are played: the Ant against a passive Spider, the Spider against a passive
Ant and Bug, and the match with Bug passive (from the Spider's seat)."""
NOT_PLAYED = "not played: the contest failed on an earlier check"
ENGAGEMENT_FILE = "engagement.json"
"""The pair with Bug passive watched match by match (``contest/engagement.json``, rows in ``engagement.csv``)."""
ENGAGEMENT_MATCHES = 200
"""Starts of the engagement report: the first of the contest's held-out starts."""


@functools.lru_cache(maxsize=8)
def _band_range(matches: int) -> tuple[int, int]:
    """The least and the most team wins minus team losses over ``matches`` starts whose MWR (computed as
    :func:`contest_verdict` does) lies in :data:`CONTEST_BAND`; (1, 0) when none does."""
    lo, hi = CONTEST_BAND
    inside = [k for k in range(-matches, matches + 1) if lo <= k / matches <= hi]
    return (inside[0], inside[-1]) if inside else (1, 0)


def contest_can_pass(check: str, counts: dict[str, int], matches: int) -> bool:
    """Whether a contest check (:data:`CONTEST_CHECKS`) that gave ``counts`` (n, n_win, n_loss, n_draw, from the
    learner's seat) on its first ``counts["n"]`` starts can still pass on all ``matches``, whatever the other starts
    give; with every start played, whether it passed (the rule of :func:`contest_verdict`)."""
    left = matches - counts["n"]
    if left < 0:
        raise ValueError(f"contest check {check}: {counts['n']} starts played, more than the {matches} it plays")
    if check == "match":  # the reachable team wins minus team losses (the Spider's losses are the team's wins)
        team = counts["n_loss"] - counts["n_win"]
        least, most = _band_range(matches)
        return max(team - left, least) <= min(team + left, most)
    return (counts["n_win"] + left) / matches >= PUSH_MIN


def contest_block(check: str, counts: dict[str, int], matches: int, least: int = 1) -> int:
    """Where a contest check's next block of starts ends: after the fewest more starts that could decide it (every
    one going against it: no win for a push check; all Spider wins, or all team wins, for the match), at least
    ``least`` more (a block smaller than the matches played at once wastes them), and all ``matches`` when fewer than
    ``least`` would be left."""
    n, left = counts["n"], matches - counts["n"]
    worst = ("n_win", "n_loss") if check == "match" else ("n_draw",)  # the outcomes that go against the check
    for k in range(1, left + 1):
        if not all(contest_can_pass(check, {**counts, "n": n + k, outcome: counts[outcome] + k}, matches)
                   for outcome in worst):
            end = min(n + max(k, least), matches)
            return matches if matches - end < least else end  # (no tail block smaller than least)
    return matches


def play_contest(play: Callable[[str, int], dict[str, int]], matches: int, least: int = 1,
                 stop: bool = True) -> dict[str, dict[str, int]]:
    """The contest checks one after another, each in blocks (:func:`contest_block`): ``play(check, end)`` plays that
    check's starts up to ``end`` and returns the counts of all it has played. With ``stop``, as soon as a check can no
    longer pass (:func:`contest_can_pass`) the contest has failed and no further start or check is played; a check that
    can still pass plays all ``matches`` starts. Returns the counts of the checks played, in order; without ``stop``
    every check is played whole, in one block."""
    counts: dict[str, dict[str, int]] = {}
    for check in CONTEST_CHECKS:
        so_far = {"n": 0, "n_win": 0, "n_loss": 0, "n_draw": 0}
        while so_far["n"] < matches:
            end = contest_block(check, so_far, matches, least) if stop else matches
            so_far = counts[check] = play(check, end)
            if so_far["n"] < end:
                raise ValueError(f"contest check {check}: asked to play up to start {end}, it played {so_far['n']}")
            if stop and not contest_can_pass(check, so_far, matches):
                return counts
    return counts


def _failed_line(check: str, c: dict[str, int], matches: int) -> str:
    """Why a check failed: on all its starts, or (stopped early) on its first ``c["n"]`` of ``matches``, after which
    it could no longer pass."""
    lo, hi = CONTEST_BAND
    left = matches - c["n"]
    if check == "match":
        team = c["n_loss"] - c["n_win"]
        if not left:
            return f"with Bug passive the team's MWR is {team / c['n']:+.3f} (the band is [{lo:+.2f}, {hi:+.2f}])"
        return (f"with Bug passive the team's MWR is {team / c['n']:+.3f} on the first {c['n']:,} of {matches:,} "
                f"starts and can only end in [{(team - left) / matches:+.3f}, {(team + left) / matches:+.3f}], "
                f"outside the band [{lo:+.2f}, {hi:+.2f}]")
    who = ("the Ant pushes a passive Spider out" if check == "ant-pushes"
           else "the Spider pushes a passive Ant or Bug out (its win)")
    if not left:
        return f"{who} in {c['n_win'] / c['n']:.1%} of the starts (at least {PUSH_MIN:.0%})"
    return (f"{who} in {c['n_win']:,} of the first {c['n']:,} of {matches:,} starts, so in at most "
            f"{(c['n_win'] + left) / matches:.1%} of them (at least {PUSH_MIN:.0%})")


def _values(counts: dict[str, dict[str, int]]) -> dict[str, float | None]:
    """Each check's value over the starts it played (None: not played)."""
    m = counts.get("match")
    push = {k.replace("-", "_"): counts[k]["n_win"] / counts[k]["n"] if k in counts else None
            for k in ("ant-pushes", "spider-pushes")}
    if m is None:
        return {**push, "team_mwr": None, "team_wins": None, "team_losses": None, "draws": None}
    return {**push, "team_mwr": (m["n_loss"] - m["n_win"]) / m["n"],  # the Spider's losses are the team's wins
            "team_wins": m["n_loss"] / m["n"], "team_losses": m["n_win"] / m["n"], "draws": m["n_draw"] / m["n"]}


def contest_verdict(counts: dict[str, dict[str, int]], ant: str, spider: str,
                    matches: int | None = None) -> dict[str, Any]:
    """The contest rule on stage 2's counts (``{"ant-pushes" | "spider-pushes" | "match": {n, n_win, n_loss,
    n_draw}}``, each from the learner's seat) on ``matches`` starts each (default: the match's): every check with its
    value and bound, ``failed`` (one line per failed check) and the verdict ``contest``.

    A contest stopped early (:func:`play_contest`) has the counts of the checks it played: each before the last on
    all ``matches`` starts (and passed), the last one a check that could no longer pass. Its record adds ``stopped``
    (that check and the starts it played) and ``not_played`` (the checks after it, whose values are None);
    ``ValueError`` on counts that no stopped contest gives."""
    if matches is None:
        if "match" not in counts:
            raise ValueError("contest_verdict: a contest stopped before its match check needs matches= (the starts "
                             "each check was to play)")
        matches = counts["match"]["n"]
    played = [check for check in CONTEST_CHECKS if check in counts]
    if list(counts) != played or played != list(CONTEST_CHECKS[:len(played)]):
        raise ValueError(f"contest counts: expected the checks {list(CONTEST_CHECKS)} in this order (the first ones "
                         f"of a contest stopped early), got {list(counts)}")
    facts = {"ant": ant, "spider": spider, "matches": matches, "counts": counts, "push_min": PUSH_MIN,
             "band": list(CONTEST_BAND), **_values(counts)}
    if len(played) == len(CONTEST_CHECKS) and all(c["n"] == matches for c in counts.values()):
        failed = [_failed_line(check, counts[check], matches) for check in CONTEST_CHECKS
                  if not contest_can_pass(check, counts[check], matches)]
        return {**facts, "failed": failed, "contest": not failed}
    last = played[-1] if played else ""
    if not played or any(counts[c]["n"] != matches or not contest_can_pass(c, counts[c], matches)
                         for c in played[:-1]) or contest_can_pass(last, counts[last], matches):
        raise ValueError(f"contest counts on {matches} starts: a contest stops at its first check that can no longer "
                         f"pass, after playing each earlier one on all its starts; got {counts}")
    return {**facts, "failed": [_failed_line(last, counts[last], matches)], "contest": False,
            "stopped": {"check": last, "after": counts[last]["n"]}, "not_played": list(CONTEST_CHECKS[len(played):])}


def format_contest(facts: dict[str, Any]) -> str:
    """The contest checks as lines of text (a check a contest stopped early did not play: :data:`NOT_PLAYED`)."""
    lo, hi = facts["band"]
    skipped = facts.get("not_played", [])
    stopped = facts.get("stopped")

    def starts(check: str) -> str:  # how many starts a check played, when the contest stopped on it early
        n = facts["counts"][check]["n"]
        return f" of the first {n:,}" if stopped and stopped["check"] == check and n < facts["matches"] else ""

    lines = [
        "  Ant pushes a passive Spider out: " + (NOT_PLAYED if "ant-pushes" in skipped else
                                                 f"{facts['ant_pushes']:.1%}{starts('ant-pushes')} (at least "
                                                 f"{facts['push_min']:.0%})"),
        "  Spider pushes a passive Ant or Bug out: " + (NOT_PLAYED if "spider-pushes" in skipped else
                                                        f"{facts['spider_pushes']:.1%}{starts('spider-pushes')} "
                                                        f"(at least {facts['push_min']:.0%})"),
        "  Bug passive: " + (NOT_PLAYED if "match" in skipped else
                             f"team wins {facts['team_wins']:.1%}, loses {facts['team_losses']:.1%}, draws "
                             f"{facts['draws']:.1%}{starts('match')}; team MWR {facts['team_mwr']:+.3f} (band "
                             f"[{lo:+.2f}, {hi:+.2f}])")]
    if stopped:
        return "\n".join([*lines, f"  verdict: NOT a contest, decided by {stopped['check']} after "
                                   f"{stopped['after']:,} of its {facts['matches']:,} starts: {facts['failed'][0]}"])
    return "\n".join([*lines, f"  verdict: {'a contest' if facts['contest'] else 'NOT a contest'} "
                              f"({facts['matches']:,} starts each)"])


class Protocol:
    """The stages of one reproduction folder, built from its config."""

    def __init__(self, cfg: ReproduceConfig) -> None:
        self.cfg = cfg
        self.out = Path(cfg.out).resolve()
        self._ray_kept: contextlib.ExitStack | None = None
        """Inside :meth:`one_ray`: holds the Ray the first stage on Ray connected to."""
        tiny = cfg.tiny
        self.steps = 20 if tiny else 500
        self.n_envs = 2 if tiny else cfg.n_envs
        # tiny: two rounds of the 2 matches for each Bug, so a Bug budget of 40 env steps stops one at half of it
        self.epochs = {"ant": 2, "spider": 2, "bug": 4, "contest": 4, "eval": 4} if tiny else {
            "ant": cfg.ant_epochs, "spider": cfg.spider_epochs, "bug": cfg.bug_epochs, "contest": cfg.contest_epochs,
            "eval": cfg.eval_epochs}
        self.screen_every = 1 if tiny else cfg.screen_every
        self.screen_epochs = 4 if tiny else cfg.screen_epochs
        self.physics = PhysicsConfig(border_rim=cfg.border_rim)
        # backend warp: matches on the device, the parallel schedule (tiny: 2 matches, 2 updates of 8)
        self.warp: dict[str, int] = ({"n_envs": 2, "updates": 2, "batch": 8, "warmup": 1, "eval_workers": 1} if tiny
                                     else {"n_envs": cfg.warp_envs, "updates": cfg.warp_updates,
                                           "batch": cfg.warp_batch, "warmup": cfg.warp_warmup,
                                           "eval_workers": cfg.warp_eval_workers})
        self.stages = [
            *(self._pretrain_stage(role, against)
              for role, against in (() if cfg.pair else (("ant", "a still Spider, Bug still"),
                                                         ("spider", "a still Ant and Bug")))),
            *(() if cfg.pair else (
                Stage("pair", "the pair rule: the sides' picks meet with Bug passive on the screen's starts",
                      (self.out / "pair" / PAIR_FILE,), lambda: bool(self.pair_record().get("pick")),
                      self._pair_stage),)),
            Stage("contest", "is the pair a contest? (each side pushes; the team loses without Bug, not hopelessly)",
                  (self.out / "contest" / "contest.json",), self._contest_complete, self._contest),
            Stage("engagement", "who leaves the ring with Bug passive, match by match (reported beside the Bugs, "
                  "not a gate)", (self.out / "contest" / ENGAGEMENT_FILE,), self._engagement_complete,
                  self._engagement),
            Stage("bug", "Bug per algorithm x seed in the pair's match (Ant and Spider frozen)", (self.out / "bug",),
                  lambda: all(finished(t) for t in self.bug_trials()), self._bug_stage),
            *([Stage("ablations", "paper-preset DDPG Bug with one change each, per seed", (self.out / "ablations",),
                     lambda: all(finished(t) for t in self.ablation_trials()),
                     lambda: self._train_trials(self.ablation_trials()))] if cfg.ablations else []),
            Stage("evaluation", "every Bug and the baselines on the same test matches",
                  (self.out / "evaluation" / "per_seed.csv",), self._evaluation_complete, self._evaluation),
            Stage("compare", "IQM [CI] by trial (algorithm, ablation)", (self.out / "compare" / "compare.json",),
                  self._compare_complete, self._compare),
        ]

    # ------------------------------------------------------------ stage 1
    @property
    def ant_policy(self) -> str:
        """The Ant of the pair: ``--pair``'s, else stage 1's pick (``ant/screens/policy-EPOCH``)."""
        return self._pair_policy("ant")

    @property
    def spider_policy(self) -> str:
        return self._pair_policy("spider")

    def _pair_policy(self, role: str) -> str:
        if self.cfg.pair:
            return self.cfg.pair[0 if role == "ant" else 1]
        pick = self.pair_record().get("pick")
        return str(self.out / pick[role]["policy"]) if pick else str(self.out / role / "policy")

    def pair_record(self) -> dict[str, Any]:
        return read_record(self.out / "pair" / PAIR_FILE, {})

    def _pretrain_stage(self, role: str, against: str) -> Stage:
        """Stage ``ant`` or ``spider``: that side trains and is screened until a screen passes
        (:class:`~triplesumo.reproduce.pretrain.Side`); with ``sides_at_once`` the first of the two runs both."""
        def run() -> list[str]:
            roles = [role]
            if self.cfg.sides_at_once and role == "ant" and not self.side("spider").pick():
                roles.append("spider")
            self.train_sides(roles)
            return [self.side_commands(role)]

        return Stage(role, f"the {role.capitalize()} learns to push: against {against}, screened every "
                           f"{self.screen_every:,} epochs", (self.out / role / SCREENS_FILE,),
                     lambda: self.side(role).pick() is not None, run, lambda: [self.side_commands(role)])

    def _base(self, **kw: Any) -> TrainConfig:
        """A train config at the protocol's budgets; tiny networks and buffers when tiny."""
        extra: dict[str, Any] = {}
        if self.cfg.tiny:
            small: dict[str, Any] = {"hidden": (16, 16), "buffer_size": 2000, "learning_starts": 10, "batch_size": 8}
            extra = {"ddpg": DDPGConfig(learn_every=4, **small), "td3": TD3Config(learn_every=4, **small),
                     "sac": SACConfig(learn_every=4, **small),
                     "ppo": PPOConfig(hidden=(16, 16), n_steps=8, n_minibatches=2, n_epochs=2),
                     "checkpoint_every": 1}
        return TrainConfig(out=str(self.out), steps_per_epoch=self.steps, n_envs=self.n_envs,
                           progress=self.cfg.progress, tensorboard=not self.cfg.tiny, physics=self.physics,
                           allow_other_ring=self.cfg.allow_other_ring,
                           save_replay=self.cfg.save_replay, **extra, **kw)

    def on_backend(self, t: TrainConfig) -> TrainConfig:
        """A training config of the protocol on its backend: unchanged on cpu; on warp, ``warp_envs`` matches on the
        device, every off-policy learner on the parallel schedule, a checkpoint at the end of each leg or run only
        (thousands of matches end every few steps: one every few hundred epochs would save the device's replay
        buffer every few seconds), and the evaluations in the background on ``warp_eval_workers`` processes (the
        device trains on while the host plays the test matches)."""
        if self.cfg.backend == "cpu":
            return t
        w = self.warp
        t = dataclasses.replace(t, backend="warp", device=self.cfg.device, n_envs=w["n_envs"], checkpoint_every=10**9)
        if t.eval_every:
            t = dataclasses.replace(t, eval_background=True, eval_workers=w["eval_workers"])
        for algo in ("ddpg", "td3", "sac"):
            t = parallel_schedule(t, algo, w["updates"], w["batch"], w["warmup"])
        return t

    def pretrain(self, role: str) -> TrainConfig:
        """Stage ``ant`` or ``spider``: that side alone learns (DDPG) to push still opponents (every other agent
        passive: a body that neither leaves the ring by itself nor pushes back), on the pre-training reward, up to its
        epoch budget (a screen stops it earlier)."""
        others = tuple(f"{a}=passive" for a in ("ant", "bug", "spider") if a != role)
        base = self._base(name=role, learn=(f"{role}=ddpg",), policies=others, epochs=self.epochs[role],
                          seed=self.cfg.pretrain_seed, reward=self.cfg.pretrain)
        # one gradient step per 5 transitions, as the v1 pair learned (docs/REPRODUCTION.md)
        return self.on_backend(base if self.cfg.tiny else dataclasses.replace(base, ddpg=DDPGConfig(learn_every=5),
                                                                              checkpoint_every=250))

    def side(self, role: str) -> Side:
        """A side's training in legs with its screens (:class:`~triplesumo.reproduce.pretrain.Side`)."""
        cfg = self.pretrain(role)
        others = cfg.policies  # every other agent passive, as in its training

        def train_to(epochs: int) -> int:
            leg = dataclasses.replace(cfg, epochs=epochs)
            run_trial(leg)  # resumes the run from its last checkpoint when there is one
            return int(run_facts(Path(cfg.out) / cfg.name, 1)["env_steps"])

        def screen(policy: str, out: Path) -> dict[str, int]:
            ecfg = self._check_config(out, role, policy, others, self.screen_epochs, self.cfg.screen_seed)
            self._evaluate(ecfg, here=True)  # in the side's process, beside the other side: no Ray, no processes
            return counts_of(out / "summary.json")

        return Side(role, self.out / role, self.screen_every, self.epochs[role],
                    f"{self.screen_epochs}, seed {self.cfg.screen_seed} + i", train_to, screen,
                    push_min=0.0 if self.cfg.tiny else PUSH_MIN)  # tiny: the rule recorded, not enforced

    def train_sides(self, roles: list[str]) -> None:
        """Train and screen the sides until each passes: side by side in processes of their own when there are
        two."""
        if len(roles) > 1:
            quiet = dataclasses.replace(self.cfg, progress=False)  # two progress bars would garble each other
            runner = ProcessRunner(workers=len(roles))
            for k, get in runner(train_side, [(quiet, role) for role in roles]):
                get()  # a side's error (PairError, a crash) surfaces here, after the other side finished
                print(f"  stage {roles[k]}: done")
        else:
            self.side(roles[0]).until_pass(0)

    def side_commands(self, role: str) -> str:
        """How a side's legs and screens are made by hand."""
        cfg = self.pretrain(role)
        run = Path(cfg.out) / cfg.name
        legs = [s["epoch"] for s in self.side(role).screens()]
        first = dataclasses.replace(cfg, epochs=legs[0] if legs else self.screen_every)
        return "; ".join([command_for(first), *(f"triplesumo train --resume {shlex.quote(str(run))} --epochs {e}"
                                                for e in legs[1:]),
                          f"(after each leg: copy {run}/policy.* to {run}/screens/policy-EPOCH.* and screen it with "
                          f"triplesumo evaluate --learner {role} --epochs {self.screen_epochs} "
                          f"--seed {self.cfg.screen_seed}, the other agents passive)"])

    def _pair_stage(self) -> list[str]:
        sides = {role: self.side(role) for role in ("ant", "spider")}

        def play(ant: dict[str, Any], spider: dict[str, Any]) -> dict[str, int]:
            out = self.out / "pair" / f"ant-{ant['epoch']}_spider-{spider['epoch']}"
            ant_policy, spider_policy = (str(sides[r].run_dir / s["policy"]) for r, s in (("ant", ant),
                                                                                       ("spider", spider)))
            self._evaluate(self._check_config(out, "spider", spider_policy, (f"ant={ant_policy}", "bug=passive"),
                                              self.screen_epochs, self.cfg.screen_seed))
            return counts_of(out / "summary.json")

        band = (-1.0, 1.0) if self.cfg.tiny else CONTEST_BAND  # tiny: the rule recorded, not enforced
        record = play_pair_rule(sides, self.out / "pair" / PAIR_FILE, play, band)
        pick = record["pick"]
        return [f"the pair rule on {len(record['pairs'])} pair(s) played: Ant {pick['ant']['epoch']:,}, Spider "
                f"{pick['spider']['epoch']:,} (pair/{PAIR_FILE})", *(self.side_commands(r) for r in ("ant", "spider"))]

    def sweeps(self) -> list[SweepConfig]:
        """One sweep per algorithm over its seeds (:func:`bug_runs`); trial names as in one grid over both."""
        runs = bug_runs(self.cfg.algos, self.cfg.seeds, self.cfg.ddpg_runs)
        return [SweepConfig(grid=(f"learn=bug={a}", "seed=" + ",".join(str(s) for b, s in runs if b == a)),
                            out=str(self.out / "bug")) for a in self.cfg.algos]

    def bug_base(self) -> TrainConfig:
        base = self._base(name="bug", learn=("bug=ddpg",), policies=(f"ant={self.ant_policy}",
                                                                     f"spider={self.spider_policy}"),
                          epochs=self.epochs["bug"], max_env_steps=self.cfg.bug_env_steps,
                          **({} if self.cfg.tiny else {"checkpoint_every": 500}))
        if self.cfg.bug_eval_every:  # tiny: an evaluation of 2 matches every 20 env steps
            base = dataclasses.replace(base, eval_every=20 if self.cfg.tiny else self.cfg.bug_eval_every,
                                       eval_epochs=2 if self.cfg.tiny else self.cfg.bug_eval_epochs,
                                       eval_seed=self.cfg.eval_seed)
        schedule: dict[str, Any] = {name: value for name, value in (("learn_every", self.cfg.bug_learn_every),
                                                                    ("n_step", self.cfg.bug_n_step)) if value}
        if not self.cfg.tiny and schedule:
            base = dataclasses.replace(base, td3=dataclasses.replace(base.td3, **schedule),
                                       sac=dataclasses.replace(base.sac, **schedule))
        return self.on_backend(base)  # (on warp the parallel schedule replaces learn_every; n_step is kept)

    def bug_trials(self) -> list[Trial]:
        return [t for sweep in self.sweeps() for t in trials(sweep, self.bug_base())]

    def ablation_trials(self) -> list[Trial]:
        """The DDPG Bug trials with each ablation (its own grid value), over the same seeds and budgets."""
        made: list[Trial] = []
        for item in self.cfg.ablations:
            field_name, raw, _ = ablation(item)
            made += trials(SweepConfig(grid=("learn=bug=ddpg", f"{field_name}={raw}",
                                             "seed=" + ",".join(str(s) for _, s in bug_runs(
                                                 ("ddpg",), self.cfg.seeds, self.cfg.ddpg_runs))),
                                       out=str(self.out / "ablations")), self.bug_base())
        return made

    def _train_trials(self, todo: list[Trial]) -> list[str]:
        left = [t for t in todo if not finished(t)]
        if self.cfg.ray:
            from triplesumo.integrations import ray_tasks  # only here: the core never imports Ray

            with self._on_ray():
                self._train_as_tasks(left, ray_tasks.RayRunner(), f"as Ray tasks, {self.cfg.cpus_per_trial} CPU each")
        elif self.cfg.workers > 1 and len(left) > 1:
            self._train_as_tasks(left, ProcessRunner(self.cfg.workers),
                                 f"in {min(self.cfg.workers, len(left))} processes at once")
        else:
            for t in left:
                print(f"  Bug trial {t.name}")
                run_trial(t.config)
        return [command_for(t.config) for t in todo]

    def _train_as_tasks(self, left: list[Trial], runner: TaskRunner, how: str) -> None:
        """The trials as tasks of ``runner`` (Ray, or this machine's processes), as many at once as it runs;
        ``RuntimeError`` naming any that failed (the others finish first, and a re-run resumes the failed ones)."""
        if not left:
            return
        print(f"  {len(left)} Bug trials {how}: " + ", ".join(t.name for t in left))

        def done(k: int, result: dict[str, Any]) -> None:
            state = f"error: {result['error']}" if "error" in result else f"{result['seconds']:.0f} s"
            print(f"  Bug trial {left[k].name}: {state}")

        results = run_trials(runner, [t.config for t in left], done, self.cfg.cpus_per_trial)
        failed = [f"{t.name} ({r['error']})" for t, r in zip(left, results, strict=True) if "error" in r]
        if failed:
            raise RuntimeError("Bug trials failed: " + "; ".join(failed) + "; run the same command again to resume "
                               "them")

    # ------------------------------------------------------------ Ray
    @contextlib.contextmanager
    def one_ray(self) -> Iterator[None]:
        """Inside, the stages on Ray (``ray``) share one: the first of them connects to ``ray_address`` or starts a
        local Ray of ``num_cpus``, and it is shut down at the end. Stage 1 trains in processes of its own and never
        waits for it. (A Ray per evaluation cost a start of seconds each, could time out starting on a busy machine,
        and sized a local one by all the cores instead of ``num_cpus``.)"""
        with contextlib.ExitStack() as kept:
            self._ray_kept = kept
            try:
                yield
            finally:
                self._ray_kept = None

    def _on_ray(self) -> contextlib.AbstractContextManager[None]:
        """Connected to Ray in the block: for the rest of :meth:`one_ray` when inside it, else for the block only."""
        from triplesumo.integrations import ray_tasks  # only here: the core never imports Ray

        connected = ray_tasks.session(self.cfg.ray_address, self.cfg.num_cpus or None)
        if self._ray_kept is None:
            return connected
        self._ray_kept.enter_context(connected)  # connects once; later calls find Ray connected and add nothing
        return contextlib.nullcontext()

    # ------------------------------------------------------------ evaluations
    def _evaluate(self, ecfg: EvaluateConfig, here: bool = False) -> list[str]:
        """Play ``ecfg`` (resuming its folder): as Ray tasks with ``ray``, on ``workers`` processes, else in this
        process; ``here``: in this process whatever the options (a screen, inside a side's own process)."""
        from triplesumo import _dcargs

        resume = (Path(ecfg.out) / "evaluation.json").exists()
        if self.cfg.ray and not here:  # the same rows, played as Ray tasks
            from triplesumo.integrations import ray_tasks  # only here: the core never imports Ray

            ecfg = dataclasses.replace(ecfg, ray=True, ray_address=self.cfg.ray_address)
            with self._on_ray():
                evaluate(dataclasses.replace(ecfg, resume=resume), ray_tasks.RayRunner())
        else:
            if self.cfg.workers > 1 and not here:  # the same rows, played on this machine's processes
                ecfg = dataclasses.replace(ecfg, workers=self.cfg.workers)
            evaluate(dataclasses.replace(ecfg, resume=resume))
        return [" ".join(shlex.quote(a) for a in ["triplesumo", "evaluate", *_dcargs.to_argv(ecfg)])]

    def _check_config(self, out: Path, learner: str, policy: str, others: tuple[str, ...], epochs: int,
                      seed: int) -> EvaluateConfig:
        """One policy, frozen, in the learner's seat against ``others`` on ``epochs`` starts from ``seed``."""
        return EvaluateConfig(learner=learner, policy=(policy,), policies=others, baselines=(), epochs=epochs,
                              seed=seed, steps_per_epoch=self.steps, physics=self.physics,
                              allow_other_ring=self.cfg.allow_other_ring, out=str(out), n_envs=self.n_envs,
                              progress=self.cfg.progress)

    def contest_configs(self) -> dict[str, EvaluateConfig]:
        """Stage 2's three evaluations on the same held-out starts: each side against a passive opponent, and the
        match with Bug passive (played from the Spider's seat; the team's MWR is minus the Spider's)."""
        def one(name: str, learner: str, policy: str, others: tuple[str, ...]) -> EvaluateConfig:
            return self._check_config(self.out / "contest" / name, learner, policy, others, self.epochs["contest"],
                                      self.cfg.contest_seed)

        return {"ant-pushes": one("ant-pushes", "ant", self.ant_policy, ("spider=passive", "bug=passive")),
                "spider-pushes": one("spider-pushes", "spider", self.spider_policy, ("ant=passive", "bug=passive")),
                "match": one("match", "spider", self.spider_policy, (f"ant={self.ant_policy}", "bug=passive"))}

    def _contest_complete(self) -> bool:
        path = self.out / "contest" / "contest.json"
        return path.exists() and json.loads(path.read_text()).get("matches") == self.epochs["contest"]

    def _contest(self) -> list[str]:
        """The checks in blocks (:func:`play_contest`), stopped as soon as one can no longer pass (tiny: each played
        whole, the verdict recorded, not enforced); a block resumes its check's evaluation up to its end."""
        configs = self.contest_configs()
        commands: dict[str, list[str]] = {}

        def play(check: str, end: int) -> dict[str, int]:
            ecfg = configs[check]
            done = _rows_in(Path(ecfg.out) / "trained" / "metrics.csv")  # (a run stopped mid-block, or before blocks)
            commands[check] = self._evaluate(dataclasses.replace(ecfg, epochs=max(end, done)))
            return counts_of(Path(ecfg.out) / "summary.json")

        n = self.epochs["contest"]
        counts = play_contest(play, n, least=self.n_envs, stop=not self.cfg.tiny)
        facts = contest_verdict(counts, self._in_out(self.ant_policy), self._in_out(self.spider_policy), matches=n)
        print(format_contest(facts))
        atomic_write_bytes(self.out / "contest" / "contest.json", (json.dumps(facts, indent=2) + "\n").encode())
        return [command for check in counts for command in commands[check]]

    def engagement_matches(self) -> int:
        return min(4 if self.cfg.tiny else ENGAGEMENT_MATCHES, self.epochs["contest"])

    def _engagement_complete(self) -> bool:
        path = self.out / "contest" / ENGAGEMENT_FILE
        return path.exists() and json.loads(path.read_text()).get("matches") == self.engagement_matches()

    def _engagement(self) -> list[str]:
        """The pair with Bug passive on the contest's first starts, watched match by match
        (:mod:`triplesumo.evaluation.exits`): who leaves first, who touched them, and whether the Spider meets the
        Bug at all. A Spider that hunts only the Ant passes the contest yet leaves a Bug nothing to learn from
        (docs/reproduce.md); this is reported beside the pair's Bugs and decides nothing."""
        from triplesumo.agents.zoo import make_policy
        from triplesumo.evaluation.exits import exit_rows, summarize_exits, write_rows

        base = self._base(name="engagement")
        policies = {"ant": make_policy(self.ant_policy, expect_obs_mode=base.obs_mode),  # (the torch actors, as the
                    "spider": make_policy(self.spider_policy, expect_obs_mode=base.obs_mode),  # contest plays them)
                    "bug": None}
        n, seed = self.engagement_matches(), self.cfg.contest_seed
        rows = exit_rows(policies, n, seed, base.match_config())
        folder = self.out / "contest"
        folder.mkdir(parents=True, exist_ok=True)
        write_rows(folder / "engagement.csv", rows)
        facts = {"ant": self._in_out(self.ant_policy), "spider": self._in_out(self.spider_policy), "bug": "passive",
                 "seed": seed, **summarize_exits(rows)}
        atomic_write_bytes(folder / ENGAGEMENT_FILE, (json.dumps(facts, indent=2) + "\n").encode())
        print(f"  with Bug passive on {n} starts: Bug out {facts['bug_out']:.1%}, Ant out {facts['ant_out']:.1%}, "
              f"Spider out {facts['spider_out']:.1%}; the Bug touches the Spider in {facts['bug_touched_spider']:.1%}")
        return [f"python benchmarks/skill_diagnosis.py --pair ant={self.ant_policy} spider={self.spider_policy} "
                f"--policy passive=passive --epochs {n} --seed {seed} --out {folder / 'engagement'}"]

    def _in_out(self, policy: str) -> str:
        """A policy path relative to the folder when it lies in it (records that stay true when it moves)."""
        path = Path(policy).resolve()
        return str(path.relative_to(self.out)) if path.is_relative_to(self.out) else policy

    def _bug_stage(self) -> list[str]:
        """Stage 3, after the contest rule: :class:`ContestError` on a pair that failed it (tiny: a warning)."""
        facts = json.loads((self.out / "contest" / "contest.json").read_text())
        if not facts["contest"]:
            problem = (f"the pair {self.ant_policy} / {self.spider_policy} failed the contest rule: "
                       + "; ".join(facts["failed"]) + f" ({self.out / 'contest' / 'contest.json'})")
            if not self.cfg.tiny:
                raise ContestError(f"stage bug refused: {problem}. Bug would learn in a match that is no contest; "
                                   "train the pair longer or check another (--pair), then re-run")
            print(f"  warning (tiny, not enforced): {problem}")
        return self._train_trials(self.bug_trials())

    def evaluation_config(self) -> EvaluateConfig:
        return EvaluateConfig(learner="bug", policy=tuple(str(Path(t.config.out) / t.name / "policy")
                                                          for t in self.bug_trials() + self.ablation_trials()),
                              policies=(f"ant={self.ant_policy}", f"spider={self.spider_policy}"),
                              baselines=("passive", "random"), epochs=self.epochs["eval"], seed=self.cfg.eval_seed,
                              physics=self.physics, allow_other_ring=self.cfg.allow_other_ring,
                              steps_per_epoch=self.steps, out=str(self.out / "evaluation"), n_envs=self.n_envs,
                              progress=self.cfg.progress)

    def evaluation_rows(self) -> list[dict[str, str]]:
        """The test's rows (``evaluation/per_seed.csv``, one per candidate), each Bug's policy named where it is now.

        The evaluation records its candidates by the paths it was given, absolute; a folder that moved since (a
        clone elsewhere, a copy) recorded them at its old place. A recorded path that ends with the path of one of
        this folder's Bug policies inside the folder (``bug/<trial>/policy``) is that policy, here; baselines and
        policies from elsewhere are kept as recorded."""
        inside = {Path(p).relative_to(self.out).parts: p for p in self.evaluation_config().policy}
        rows = _read_csv(self.out / "evaluation" / "per_seed.csv")
        for row in rows:
            parts = Path(row["policy"]).parts
            row["policy"] = next((inside[parts[k:]] for k in range(len(parts)) if parts[k:] in inside), row["policy"])
        return rows

    def _evaluation_complete(self) -> bool:
        rows = self.evaluation_rows()
        want = set(self.evaluation_config().policy) | {"passive", "random"}
        return ({r["policy"] for r in rows} == want and all(int(r["epochs"]) == self.epochs["eval"] for r in rows)
                and all(_rows_in(self.out / "evaluation" / r["candidate"] / "metrics.csv") == self.epochs["eval"]
                        for r in rows)  # a killed evaluation's rows: per_seed.csv may predate them
                and all(r["sha256"] == _fingerprint(r["policy"]) for r in rows))  # not a retrained or removed Bug's

    def _evaluation(self) -> list[str]:
        return self._evaluate(self.evaluation_config())

    def compare_config(self) -> CompareConfig:
        return CompareConfig(folders=(str(self.out / "evaluation"),), by="trial", out=str(self.out / "compare"),
                             seed=self.cfg.eval_seed, reps=1000 if self.cfg.tiny else 10_000)

    def _compare_complete(self) -> bool:
        path = self.out / "compare" / "compare.json"
        if not path.exists() or not (self.out / "compare" / "compare.png").exists():
            return False
        table = json.loads(path.read_text())
        rows = _read_csv(self.out / "evaluation" / "per_seed.csv")
        return sorted(s for g in table["groups"] for s in g["scores"]) == sorted(float(r["test_mwr"]) for r in rows)

    def _compare(self) -> list[str]:
        ccfg = self.compare_config()
        print(format_compare(compare(ccfg)))
        return [f"triplesumo compare {shlex.quote(ccfg.folders[0])} --by {ccfg.by} --seed {ccfg.seed} "
                f"--reps {ccfg.reps} --out {shlex.quote(ccfg.out)}"]


def train_side(cfg: ReproduceConfig, role: str) -> None:
    """A side's legs and screens until one passes, in a worker process (:meth:`Protocol.train_sides`)."""
    Protocol(cfg).side(role).until_pass(0)
