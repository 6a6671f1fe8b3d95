"""``triplesumo reproduce``: the whole reproduction protocol from one command, resumable.

The paper trains an Ant (3,000 epochs), then a second agent (20,000 epochs) to make "an ongoing
game", then adds Bug. Built that way literally, the match was no contest (env v1, measured): an
Ant trained against a random Spider learned nothing (a random Spider walks off the ring by itself
in 28 of 32 matches, so a passive Ant already "wins" 87.5 %), and a Spider then trained for
20,000 epochs against that frozen Ant won 82 % with Bug passive. The stages here build the
ongoing match so that both sides learn to push, check that it is a contest, and only then train Bug:

1. ``match``: Ant and Spider learn together from scratch (DDPG each; ``train --learn ant=ddpg
   spider=ddpg``), Bug passive, for ``match_epochs`` (the paper's 20,000: its second agent's
   budget, which the Ant now shares, so neither side faces an opponent that stopped learning or one
   that leaves the ring by itself). Pre-training reward: the paper's terms with the still
   punishment ``pretrain_still`` (default -1), so that losing costs more than surviving: with the
   paper's -4 and gamma 0.99, still / (1 - gamma) = -400 = the loss reward, and being pushed out at
   any step is worth as much as surviving without winning (``__post_init__`` refuses such a value).
   ``pair`` skips the stage and checks a given pair instead (``--pair zoo:ant zoo:spider``).
2. ``contest``: the pair on ``contest_epochs`` held-out starts (``contest_seed`` + i, apart from
   the Bug's test starts), three evaluations (``OUT/contest``): the Ant against a passive Spider,
   the Spider against a passive Ant (each must push its opponent out in at least
   :data:`PUSH_MIN` of the matches), and the match with Bug passive, whose team MWR must lie in
   :data:`CONTEST_BAND` (the team loses without Bug's help, but not hopelessly). ``contest.json``
   holds each check and the verdict.
3. ``bug``: Bug trained with each algorithm x seed in that match, as the trials of
   :mod:`triplesumo.train.sweep` run here one after another (``OUT/bug/learn=bug=ALGO,seed=S``).
   **It refuses to start on a pair that failed the contest rule** (:class:`ContestError`); with
   ``tiny`` (2-epoch agents are no contest) the verdict is recorded and printed, not enforced.
   With ``ablations`` (``--ablations noise=gaussian still=-1``), stage ``ablations`` then trains
   the paper-preset DDPG Bug with each one change over the same seeds and env-step budget
   (``OUT/ablations/learn=bug=ddpg,ddpg.noise=gaussian,seed=S``).
4. ``evaluation``: every Bug (ablations included) plus the passive and random baselines on the
   same seeded test matches (``OUT/evaluation``, ``per_seed.csv``).
5. ``compare``: IQM with bootstrap intervals by trial (each algorithm, each ablation) and its
   plot (``OUT/compare``).

``--publish`` then ships the stage-1 Ant and Spider, the paper-preset DDPG Bug of the
best seed as ``zoo:bug`` and the best Bug of any algorithm as ``zoo:bug-<algo>``, each manifest
with its command, seed, env steps, the code version, its contest check and its test MWR with
95 % interval.

Time to skill comes from stage 3 itself: every Bug run evaluates its current policy every
``bug_eval_every`` env steps on the first ``bug_eval_epochs`` test matches of stage 4
(``train --eval-every``, ``eval.csv``), and the report gives, per algorithm and seed, the
env steps and training wall time until its test MWR first reached +0.2, with the curves
(``bug/test_mwr.png``).

A stage whose outputs exist and are complete is skipped; a killed one goes on where it
stopped (train runs resume from their last checkpoint, evaluations with ``resume``).
``reproduce.json`` records the stages done, their commands and the code version, and
``REPRODUCTION.md`` is written from the outputs each time. Redoing an earlier stage does
not invalidate later ones: delete their folders to redo them too.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import json
import math
import os
import re
import shlex
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import triplesumo
from triplesumo import ENV_VERSION
from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.agents.zoo import policy_fingerprint
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.ppo import PPOConfig
from triplesumo.algos.sac import SACConfig
from triplesumo.algos.td3 import TD3Config
from triplesumo.evaluation.compare import CompareConfig, compare, format_compare, trial_group
from triplesumo.evaluation.evaluate import EvaluateConfig, check_ray, evaluate
from triplesumo.model.specs import PhysicsConfig
from triplesumo.rules.config import RewardConfig
from triplesumo.train import legs, sweep
from triplesumo.train.config import ALGOS, TrainConfig
from triplesumo.train.run_folder import command_for, training_done
from triplesumo.train.sweep import SweepConfig, Trial, finished, run_facts, run_trial, trials

RECORD_FILE = "reproduce.json"
REPORT_FILE = "REPRODUCTION.md"
CONTEST_BAND = (-0.50, -0.10)
"""The contest rule: with Bug passive, the team's MWR on the contest starts lies in this band (both ends
included): the team loses without Bug's help, but not hopelessly."""
PUSH_MIN = 0.5
"""Each pre-trained side pushes a passive opponent out in at least this share of the contest starts."""


class ContestError(RuntimeError):
    """The Bug stage refused a pair that failed the contest rule (the message names each failed check)."""
ABLATION_ALIASES = {"noise": "ddpg.noise", "still": "reward.still"}
"""Short names of the ablations the issue asks about (Gaussian noise, a smaller still punishment)."""
RUN_OPTIONS = ("progress", "status", "ray", "ray_address", "num_cpus", "cpus_per_trial", "publish", "docs")
"""ReproduceConfig fields that say how the stages run (or what happens to their results afterwards), not what they
make: a folder resumes with other values."""
PROTOCOL_FIELDS = ("out", "name", "learn", "learner", "seed", "epochs", "max_env_steps", "policies")
"""TrainConfig fields the protocol sets for every Bug run: an ablation cannot change them."""
SKILL = 0.2
"""Time to skill: the test MWR Bug's team first reaches (the issue's +0.2)."""


def ablation(item: str) -> tuple[str, str, Any]:
    """``"noise=gaussian"`` -> ``("ddpg.noise", "gaussian", "gaussian")``: the TrainConfig field (aliases
    :data:`ABLATION_ALIASES`), the value as given and as typed; ``ValueError`` names the problem."""
    key, sep, raw = item.partition("=")
    if not sep or not key or not raw or "," in raw:
        raise ValueError(f"ReproduceConfig.ablations: expected FIELD=VALUE (one change, e.g. noise=gaussian, "
                         f"still=-1, ddpg.noise_sigma=0.1), got {item!r}")
    field_name = ABLATION_ALIASES.get(key, key)
    if field_name.split(".")[0] in PROTOCOL_FIELDS:
        raise ValueError(f"ReproduceConfig.ablations: {field_name} is set by the protocol for every Bug run, got "
                         f"{item!r}")
    try:
        value = sweep.field_value(field_name, raw)
        sweep.with_field(TrainConfig(), field_name, value)  # the field's own validation
    except (TypeError, ValueError) as exc:
        raise ValueError(f"ReproduceConfig.ablations: {item!r}: {exc}") from None
    return field_name, raw, value


@dataclass(frozen=True)
class ReproduceConfig:
    """The reproduction protocol: Ant, Spider, the contest check, Bug per algorithm x seed, evaluation, compare."""

    out: str = "runs/reproduce"
    """Folder for every stage's outputs, reproduce.json and REPRODUCTION.md."""
    algos: tuple[str, ...] = ALGOS
    """Algorithms Bug is trained with (ddpg is the paper preset)."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Training seeds of Bug, for every algorithm."""
    match_epochs: int = 20_000
    """Stage 1: epochs of Ant and Spider learning together (the paper's 20,000 for its second agent)."""
    match_seed: int = 1
    """Seed of the stage-1 run."""
    pretrain_still: float = -1.0
    """Stage 1: the still punishment of the pre-training reward (the paper's other terms as they are). It must
    make losing cost more than surviving: still / (1 - gamma) > the loss reward (-1 / 0.01 = -100 > -400); the
    paper's -4 gives exactly -400."""
    pair: tuple[str, ...] = ()
    """Skip stage 1 and check this Ant and Spider instead (two policy specs: ``zoo:ant zoo:spider``, files,
    ``passive``); the contest rule and everything after it run on them."""
    bug_epochs: int = 20_000
    """Stage 3: at most this many epochs per Bug run (the paper's 20,000)."""
    bug_env_steps: int = 1_000_000
    """Stage 3: the env-step budget of every Bug run, the same for every algorithm whatever its matches
    last (``train --max-env-steps``); a run stops at the first epoch end past it. 0: epochs only."""
    bug_learn_every: int = 16
    """Stage 3 (and the ablations): collected transitions per gradient step of the TD3 and SAC Bugs, one per step
    of the 16 matches, the algorithm schedule of ``bench train``. Their library default, 1 (the papers' one update
    per transition), costs 11-16 ms of CPU per update on a 2-core machine: 3-4 h per 1 M env steps and run.
    0 keeps the algorithm's default. DDPG keeps the paper preset (30) and PPO its rollouts."""
    bug_eval_every: int = 100_000
    """Stage 3 (and the ablations): every this many env steps each Bug run evaluates its current policy on the
    first bug_eval_epochs test matches of stage 4 (``train --eval-every``): the test-MWR curves and time to skill.
    0: none."""
    bug_eval_epochs: int = 200
    """Test matches of each evaluation during stage 4."""
    contest_epochs: int = 1000
    """Stage 2: held-out starts of each contest check (Ant vs passive Spider, Spider vs passive Ant, the match
    with Bug passive)."""
    contest_seed: int = 20_000
    """Contest start i resets with contest_seed + i: held out from training and from the Bug's test starts."""
    eval_epochs: int = 2000
    """Stage 4: test matches per Bug policy and per baseline (the same seeded matches for all)."""
    eval_seed: int = 10_000
    """Test match i resets with eval_seed + i (stage 4 and the Bug's evaluations while training), and seeds
    the bootstrap."""
    n_envs: int = 16
    """Matches collected or played at once."""
    border_rim: bool = True
    """Train and evaluate on the paper's ring with its solid rim (``PhysicsConfig.border_rim``; env v2: a box rim
    and the fair start); False: visual-only border markers, as env v0."""
    save_replay: bool = True
    """Checkpoints hold the replay buffer (an exact resume); False keeps them small enough to commit
    (a resume then starts with an empty buffer)."""
    tiny: bool = False
    """Budgets of seconds (a smoke run, CI): 2 epochs of 20-step matches, tiny networks, 4 test matches;
    overrides the budgets above."""
    publish: bool = False
    """After stage 6, publish the stage-1 Ant, stage-2 Spider and the best Bug (highest test MWR) into the zoo."""
    progress: bool = True
    """Show progress bars."""
    ablations: tuple[str, ...] = ()
    """FIELD=VALUE changes of the paper-preset DDPG Bug, each trained over the same seeds and env-step budget and
    compared as its own group (noise=gaussian, still=-1, or any TrainConfig field: ddpg.noise_sigma=0.1)."""
    docs: str = ""
    """Also write the report into this Markdown file (e.g. docs/REPRODUCTION.md), between its lines
    ``<!-- reproduce:begin -->`` and ``<!-- reproduce:end -->``: headings one level down, links to this folder's files
    relative to that file; the rest of the file is kept."""
    status: bool = False
    """Run nothing: print where each stage and Bug run stands (env steps, the newest test MWR while training) and
    regenerate REPRODUCTION.md from the outputs there are so far (a long reproduction, between sessions)."""
    ray: bool = False
    """Train the Bug runs of stage 4 and the ablations as Ray tasks, several at once (as ``triplesumo sweep``: a
    task whose worker dies runs again and resumes its run), and play the test matches of stages 3 and 5 as Ray
    tasks. The outputs are those of a run without Ray. Needs pip install "triplesumo[ray]"."""
    ray_address: str = ""
    """With ray: the Ray cluster to use (e.g. auto, ray://HOST:10001); empty: start a local Ray on this machine."""
    num_cpus: int = 0
    """With ray, local Ray only: the CPUs it may use (0: all)."""
    cpus_per_trial: int = 1
    """With ray: the CPUs Ray reserves for each Bug run (so at most num_cpus / cpus_per_trial train at once)."""

    def __post_init__(self) -> None:
        if isinstance(self.ablations, list):
            object.__setattr__(self, "ablations", tuple(self.ablations))
        fields = [ablation(a)[0] + "=" + ablation(a)[1] for a in self.ablations]
        if len(set(fields)) < len(fields):
            raise ValueError(f"ReproduceConfig.ablations: a change given twice: {self.ablations}")
        if self.ablations and "ddpg" not in self.algos:
            raise ValueError("ReproduceConfig.ablations change the paper-preset DDPG Bug: algos must include ddpg")
        for name in ("algos", "seeds"):
            value = getattr(self, name)
            if isinstance(value, list):
                object.__setattr__(self, name, tuple(value))
            if not getattr(self, name) or len(set(getattr(self, name))) < len(getattr(self, name)):
                raise ValueError(f"ReproduceConfig.{name} must be non-empty and without repeats, got {value!r}")
        bad = [a for a in self.algos if a not in ALGOS]
        if bad:
            raise ValueError(f"ReproduceConfig.algos must be among {ALGOS}, got {bad}")
        for name in ("bug_env_steps", "bug_learn_every", "bug_eval_every"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"ReproduceConfig.{name} must be an int >= 0, got {value!r}")
        if isinstance(self.pair, list):
            object.__setattr__(self, "pair", tuple(self.pair))
        if self.pair and len(self.pair) != 2:
            raise ValueError(f"ReproduceConfig.pair must be two policies (Ant, Spider), got {self.pair!r}")
        gamma = DDPGConfig().gamma
        if not (isinstance(self.pretrain_still, int | float) and math.isfinite(self.pretrain_still)
                and self.pretrain_still <= 0):
            raise ValueError(f"ReproduceConfig.pretrain_still must be a finite number <= 0, "
                             f"got {self.pretrain_still!r}")
        worth, loss = self.pretrain_still / (1 - gamma), RewardConfig().loss
        if worth <= loss or math.isclose(worth, loss):  # (-4 / (1 - 0.99) is -399.99999999999966 in floats)
            raise ValueError(f"ReproduceConfig.pretrain_still {self.pretrain_still}: surviving without a result would "
                             f"be worth {worth:.0f} (still / (1 - gamma), gamma {gamma}), no more than losing "
                             f"({loss:.0f}); the pre-trained sides would not learn to stay in. Use a value above "
                             f"{loss * (1 - gamma):g}")
        for name in ("match_epochs", "bug_epochs", "bug_eval_epochs", "contest_epochs", "eval_epochs",
                     "n_envs"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"ReproduceConfig.{name} must be an int >= 1, got {value!r}")
        if any(isinstance(s, bool) or not isinstance(s, int) or s < 0 for s in self.seeds):
            raise ValueError(f"ReproduceConfig.seeds must be ints >= 0, got {self.seeds!r}")
        for name, low in (("num_cpus", 0), ("cpus_per_trial", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(f"ReproduceConfig.{name} must be an int >= {low}, got {value!r}")
        if (self.ray_address or self.num_cpus) and not self.ray:
            raise ValueError("ReproduceConfig.ray_address and num_cpus are options of ray (--ray)")
        check_ray("ReproduceConfig", self.ray, self.ray_address)


@dataclass(frozen=True)
class Stage:
    """One stage of the protocol: what it writes, whether that is complete, how to make it."""

    name: str
    title: str
    outputs: tuple[Path, ...]
    complete: Callable[[], bool]
    run: Callable[[], list[str]]
    """Makes (or finishes) the outputs; returns the commands that do the same by hand."""


class Protocol:
    """The stages of one reproduction folder, built from its config."""

    def __init__(self, cfg: ReproduceConfig) -> None:
        self.cfg = cfg
        self.out = Path(cfg.out).resolve()
        tiny = cfg.tiny
        self.steps = 20 if tiny else 500
        self.n_envs = 2 if tiny else cfg.n_envs
        self.epochs = {"match": 2, "bug": 2, "contest": 4, "eval": 4} if tiny else {
            "match": cfg.match_epochs, "bug": cfg.bug_epochs, "contest": cfg.contest_epochs, "eval": cfg.eval_epochs}
        self.physics = PhysicsConfig(border_rim=cfg.border_rim)
        match_dir = self.out / "match"
        self.ant_policy, self.spider_policy = cfg.pair or (str(match_dir / "policy-ant"),
                                                           str(match_dir / "policy-spider"))
        self.stages = [
            *([] if cfg.pair else [
                Stage("match", "Ant and Spider learn together, Bug passive",
                      (match_dir / "policy-ant.json", match_dir / "policy-spider.json"),
                      lambda: self._trained(self._match()), lambda: self._train(self._match()))]),
            Stage("contest", "is the pair a contest? (each side pushes; the team loses without Bug, not hopelessly)",
                  (self.out / "contest" / "contest.json",), self._contest_complete, self._contest),
            Stage("bug", "Bug per algorithm x seed in the stage-1 match", (self.out / "bug",),
                  lambda: all(finished(t) for t in self.bug_trials()), self._bug_stage),
            *([Stage("ablations", "paper-preset DDPG Bug with one change each, per seed", (self.out / "ablations",),
                     lambda: all(finished(t) for t in self.ablation_trials()),
                     lambda: self._train_trials(self.ablation_trials()))] if cfg.ablations else []),
            Stage("evaluation", "every Bug and the baselines on the same test matches",
                  (self.out / "evaluation" / "per_seed.csv",), self._evaluation_complete, self._evaluation),
            Stage("compare", "IQM [CI] by trial (algorithm, ablation)", (self.out / "compare" / "compare.json",),
                  self._compare_complete, self._compare),
        ]

    # ------------------------------------------------------------ train stages
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
                           save_replay=self.cfg.save_replay, **extra, **kw)

    def _match(self) -> TrainConfig:
        """Stage 1: Ant and Spider learn together (DDPG each), Bug passive, on the pre-training reward."""
        base = self._base(name="match", learn=("ant=ddpg", "spider=ddpg"), policies=("bug=passive",),
                          epochs=self.epochs["match"], seed=self.cfg.match_seed,
                          reward=RewardConfig(still=self.cfg.pretrain_still))
        # one gradient step per 5 transitions of each learner, as the v1 pair learned (docs/REPRODUCTION.md)
        return base if self.cfg.tiny else dataclasses.replace(base, ddpg=DDPGConfig(learn_every=5),
                                                              checkpoint_every=500)

    def _trained(self, cfg: TrainConfig) -> bool:
        run = Path(cfg.out) / cfg.name
        return training_done(cfg) and all((run / f"policy-{a.split('=')[0]}.json").exists() for a in cfg.learn)

    def _train(self, cfg: TrainConfig) -> list[str]:
        run_trial(cfg)  # resumes the run from its last checkpoint when there is one
        return [command_for(cfg)]

    def sweep(self) -> SweepConfig:
        return SweepConfig(grid=("learn=" + ",".join(f"bug={a}" for a in self.cfg.algos),
                                 "seed=" + ",".join(map(str, self.cfg.seeds))), out=str(self.out / "bug"))

    def bug_base(self) -> TrainConfig:
        base = self._base(name="bug", learner="bug", policies=(f"ant={self.ant_policy}",
                                                               f"spider={self.spider_policy}"),
                          epochs=self.epochs["bug"],
                          **({} if self.cfg.tiny else {"checkpoint_every": 500,
                                                       "max_env_steps": self.cfg.bug_env_steps}))
        if self.cfg.bug_eval_every:  # tiny: an evaluation of 2 matches every 20 env steps
            base = dataclasses.replace(base, eval_every=20 if self.cfg.tiny else self.cfg.bug_eval_every,
                                       eval_epochs=2 if self.cfg.tiny else self.cfg.bug_eval_epochs,
                                       eval_seed=self.cfg.eval_seed)
        k = self.cfg.bug_learn_every
        if self.cfg.tiny or not k:
            return base
        return dataclasses.replace(base, td3=dataclasses.replace(base.td3, learn_every=k),
                                   sac=dataclasses.replace(base.sac, learn_every=k))

    def bug_trials(self) -> list[Trial]:
        return trials(self.sweep(), self.bug_base())

    def ablation_trials(self) -> list[Trial]:
        """The DDPG Bug trials with each ablation (its own grid value), over the same seeds and budgets."""
        made: list[Trial] = []
        for item in self.cfg.ablations:
            field_name, raw, _ = ablation(item)
            made += trials(SweepConfig(grid=("learn=bug=ddpg", f"{field_name}={raw}",
                                             "seed=" + ",".join(map(str, self.cfg.seeds))),
                                       out=str(self.out / "ablations")), self.bug_base())
        return made

    def _train_trials(self, todo: list[Trial]) -> list[str]:
        left = [t for t in todo if not finished(t)]
        if self.cfg.ray:
            self._train_on_ray(left)
        else:
            for t in left:
                print(f"  Bug trial {t.name}")
                run_trial(t.config)
        return [command_for(t.config) for t in todo]

    def _train_on_ray(self, left: list[Trial]) -> None:
        """The trials as Ray tasks, as many at once as Ray has CPUs for; ``RuntimeError`` naming any that failed
        (the others finish first, and a re-run resumes the failed ones)."""
        if not left:
            return
        from triplesumo.integrations import ray_tasks  # only here: the core never imports Ray

        print(f"  {len(left)} Bug trials as Ray tasks, {self.cfg.cpus_per_trial} CPU each: "
              + ", ".join(t.name for t in left))

        def done(k: int, result: dict[str, Any]) -> None:
            state = f"error: {result['error']}" if "error" in result else f"{result['seconds']:.0f} s"
            print(f"  Bug trial {left[k].name}: {state}")

        with ray_tasks.session(self.cfg.ray_address, self.cfg.num_cpus or None):
            results = ray_tasks.run_trials_on_ray([t.config for t in left], done, self.cfg.cpus_per_trial)
        failed = [f"{t.name} ({r['error']})" for t, r in zip(left, results, strict=True) if "error" in r]
        if failed:
            raise RuntimeError("Bug trials failed on Ray: " + "; ".join(failed) + "; run the same command again "
                               "to resume them")

    # ------------------------------------------------------------ evaluations
    def _evaluate(self, ecfg: EvaluateConfig) -> list[str]:
        from triplesumo import _dcargs

        resume = (Path(ecfg.out) / "evaluation.json").exists()
        if self.cfg.ray:  # the same rows, played as Ray tasks
            ecfg = dataclasses.replace(ecfg, ray=True, ray_address=self.cfg.ray_address)
        evaluate(dataclasses.replace(ecfg, resume=resume))
        return [" ".join(shlex.quote(a) for a in ["triplesumo", "evaluate", *_dcargs.to_argv(ecfg)])]

    def contest_configs(self) -> dict[str, EvaluateConfig]:
        """Stage 2's three evaluations on the same held-out starts: each side against a passive opponent, and the
        match with Bug passive (played from the Spider's seat; the team's MWR is minus the Spider's)."""
        def one(name: str, learner: str, policy: str, others: tuple[str, ...]) -> EvaluateConfig:
            return EvaluateConfig(learner=learner, policy=(policy,), policies=others, baselines=(),
                                  epochs=self.epochs["contest"], seed=self.cfg.contest_seed,
                                  steps_per_epoch=self.steps, physics=self.physics,
                                  out=str(self.out / "contest" / name), n_envs=self.n_envs, progress=self.cfg.progress)

        return {"ant-pushes": one("ant-pushes", "ant", self.ant_policy, ("spider=passive", "bug=passive")),
                "spider-pushes": one("spider-pushes", "spider", self.spider_policy, ("ant=passive", "bug=passive")),
                "match": one("match", "spider", self.spider_policy, (f"ant={self.ant_policy}", "bug=passive"))}

    def _contest_complete(self) -> bool:
        path = self.out / "contest" / "contest.json"
        return path.exists() and json.loads(path.read_text()).get("matches") == self.epochs["contest"]

    def _contest(self) -> list[str]:
        commands: list[str] = []
        counts: dict[str, dict[str, int]] = {}
        for name, ecfg in self.contest_configs().items():
            commands += self._evaluate(ecfg)
            summary = json.loads((Path(ecfg.out) / "summary.json").read_text())
            c = next(iter(summary["candidates"].values()))
            counts[name] = {k: int(c[k]) for k in ("n", "n_win", "n_loss", "n_draw")}
        facts = contest_verdict(counts, *(self._in_out(p) for p in (self.ant_policy, self.spider_policy)))
        print(format_contest(facts))
        atomic_write_bytes(self.out / "contest" / "contest.json", (json.dumps(facts, indent=2) + "\n").encode())
        return commands

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
                              physics=self.physics,
                              steps_per_epoch=self.steps, out=str(self.out / "evaluation"), n_envs=self.n_envs,
                              progress=self.cfg.progress)

    def _evaluation_complete(self) -> bool:
        rows = _read_csv(self.out / "evaluation" / "per_seed.csv")
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


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with path.open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _fingerprint(policy: str) -> str | None:
    """:func:`policy_fingerprint`, None when the policy's files are gone."""
    try:
        return policy_fingerprint(policy)
    except FileNotFoundError:
        return None


def _rows_in(path: Path) -> int:
    """Complete rows of a metrics CSV (lines ending in a newline, less the header)."""
    if not path.exists():
        return 0
    return max(path.read_bytes().count(b"\n") - 1, 0)


def code_version() -> str:
    """``git SHORT-SHA`` (``-dirty`` when the package's tracked files differ from it) of the checkout the
    package was imported from (:func:`triplesumo.train.legs.code_version`), else the package version."""
    code = legs.code_version()
    if code is not None:
        return f"git {code['commit'][:7]}{'-dirty' if code['dirty'] else ''}"
    return f"triplesumo {triplesumo.__version__}"


def contest_verdict(counts: dict[str, dict[str, int]], ant: str, spider: str) -> dict[str, Any]:
    """The contest rule on stage 2's counts (``{"ant-pushes" | "spider-pushes" | "match": {n, n_win, n_loss,
    n_draw}}``, each from the learner's seat): every check with its value and bound, ``failed`` (one line per
    failed check) and the verdict ``contest``."""
    ant_push = counts["ant-pushes"]["n_win"] / counts["ant-pushes"]["n"]
    spider_push = counts["spider-pushes"]["n_win"] / counts["spider-pushes"]["n"]
    m = counts["match"]
    team_mwr = (m["n_loss"] - m["n_win"]) / m["n"]  # the Spider's losses are the team's wins
    lo, hi = CONTEST_BAND
    failed = []
    if ant_push < PUSH_MIN:
        failed.append(f"the Ant pushes a passive Spider out in {ant_push:.1%} of the starts (at least {PUSH_MIN:.0%})")
    if spider_push < PUSH_MIN:
        failed.append(f"the Spider pushes a passive Ant out in {spider_push:.1%} of the starts "
                      f"(at least {PUSH_MIN:.0%})")
    if not lo <= team_mwr <= hi:
        failed.append(f"with Bug passive the team's MWR is {team_mwr:+.3f} (the band is [{lo:+.2f}, {hi:+.2f}])")
    return {"ant": ant, "spider": spider, "matches": m["n"], "counts": counts, "push_min": PUSH_MIN,
            "band": list(CONTEST_BAND), "ant_pushes": ant_push, "spider_pushes": spider_push, "team_mwr": team_mwr,
            "team_wins": m["n_loss"] / m["n"], "team_losses": m["n_win"] / m["n"], "draws": m["n_draw"] / m["n"],
            "failed": failed, "contest": not failed}


def format_contest(facts: dict[str, Any]) -> str:
    """The contest checks as lines of text."""
    lo, hi = facts["band"]
    return "\n".join([
        f"  Ant pushes a passive Spider out: {facts['ant_pushes']:.1%} (at least {facts['push_min']:.0%})",
        f"  Spider pushes a passive Ant out: {facts['spider_pushes']:.1%} (at least {facts['push_min']:.0%})",
        f"  Bug passive: team wins {facts['team_wins']:.1%}, loses {facts['team_losses']:.1%}, draws "
        f"{facts['draws']:.1%}; team MWR {facts['team_mwr']:+.3f} (band [{lo:+.2f}, {hi:+.2f}])",
        f"  verdict: {'a contest' if facts['contest'] else 'NOT a contest'} ({facts['matches']:,} starts each)"])


def check_same_options(out: Path, recorded: dict[str, Any], cfg: ReproduceConfig) -> None:
    """``ValueError`` unless the reproduction recorded in ``out`` was made with ``cfg``'s options (:data:`RUN_OPTIONS`
    aside);
    an option added since the record was written counts as its default, what that run used."""
    config = json.loads(json.dumps(dataclasses.asdict(cfg)))
    defaults = json.loads(json.dumps(dataclasses.asdict(ReproduceConfig())))
    recorded = {**{k: v for k, v in defaults.items() if k not in recorded}, **recorded}
    # the folder by its place, however it was written; --status only reads, so a moved folder may be read
    config["out"], recorded["out"] = str(Path(config["out"]).resolve()), str(Path(recorded["out"]).resolve())
    ignore = (*RUN_OPTIONS, "out") if cfg.status else RUN_OPTIONS
    differ = sorted(k for k in {*config, *recorded} if k not in ignore and recorded.get(k) != config.get(k))
    if differ:
        raise ValueError(f"{out} holds a reproduction with other options ("
                         + ", ".join(f"{k}: {recorded.get(k)!r} there, {config.get(k)!r} given" for k in differ)
                         + "); re-running resumes it and needs the same options: choose another --out")


def run_reproduce(cfg: ReproduceConfig) -> dict[str, Any]:
    """Run (or finish) every stage in order, skipping complete ones; write reproduce.json and the report."""
    protocol = Protocol(cfg)
    out = protocol.out
    if cfg.docs:  # before hours of training: the file and its markers are there
        _docs_markers(Path(cfg.docs).read_text().splitlines())
    out.mkdir(parents=True, exist_ok=True)
    path = out / RECORD_FILE
    record: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    config = json.loads(json.dumps(dataclasses.asdict(cfg)))
    if record:
        check_same_options(out, record["config"], cfg)
    record = {"config": config, "stages": record.get("stages", {}), "runs": record.get("runs", []),
              **{k: record[k] for k in ("published",) if k in record}}  # kept until a later --publish replaces it
    run_now: dict[str, Any] = {"version": code_version(), "started": _now(), "ran": [], "skipped": []}
    if cfg.status:
        print(format_status(protocol))
        _write_report(protocol, {**record, "runs": [*record["runs"], run_now]})
        print(f"report (so far): {out / REPORT_FILE}")
        return record
    record["runs"].append(run_now)
    n = len(protocol.stages)
    for k, stage in enumerate(protocol.stages, 1):
        if stage.complete():
            print(f"[{k}/{n}] {stage.name}: complete, skipped ({stage.title})")
            run_now["skipped"].append(stage.name)
            continue
        print(f"[{k}/{n}] {stage.name}: {stage.title}")
        start = time.perf_counter()
        commands = stage.run()
        if not stage.complete():
            raise RuntimeError(f"stage {stage.name} ran but its outputs are not complete: {stage.outputs}")
        record["stages"][stage.name] = {"done": _now(), "seconds": round(time.perf_counter() - start, 3),
                                        "version": run_now["version"], "commands": commands,
                                        "outputs": [str(p.relative_to(out)) for p in stage.outputs]}
        run_now["ran"].append(stage.name)
        atomic_write_bytes(path, (json.dumps(record, indent=2) + "\n").encode())
    if cfg.publish:
        record["published"] = _publish(protocol, run_now["version"])
    atomic_write_bytes(path, (json.dumps(record, indent=2) + "\n").encode())
    _write_report(protocol, record)
    print(f"report: {out / REPORT_FILE}; record: {path}")
    return record


DOCS_BEGIN, DOCS_END = "<!-- reproduce:begin -->", "<!-- reproduce:end -->"


def _write_report(protocol: Protocol, record: dict[str, Any]) -> None:
    """``OUT/REPRODUCTION.md``, and with ``--docs`` the same report inside that Markdown file."""
    text = report(protocol, record)
    atomic_write_bytes(protocol.out / REPORT_FILE, text.encode())
    if protocol.cfg.docs:
        docs = Path(protocol.cfg.docs)
        atomic_write_bytes(docs, embed_report(text, protocol.out, docs.read_text(), docs.parent).encode())
        print(f"report written into {docs}")


def _docs_markers(lines: list[str]) -> tuple[int, int]:
    """Where a docs page's two marker lines are; ``ValueError`` unless both are there, in order."""
    if DOCS_BEGIN not in lines or DOCS_END not in lines or lines.index(DOCS_BEGIN) > lines.index(DOCS_END):
        raise ValueError(f"--docs file needs a line {DOCS_BEGIN} and, after it, a line {DOCS_END}: the report goes "
                         "between them")
    return lines.index(DOCS_BEGIN), lines.index(DOCS_END)


def embed_report(text: str, out: Path, page: str, page_dir: Path) -> str:
    """``page`` with the report ``text`` (of the folder ``out``) between its two marker lines: the report's title
    left out, its headings one level down, its links to files of ``out`` made relative to ``page_dir``."""
    lines = page.splitlines()
    start, end = _docs_markers(lines)
    prefix = os.path.relpath(out.resolve(), page_dir.resolve())
    body, fenced = [], False
    for line in text.splitlines()[1:]:
        fenced ^= line.startswith("```")
        if not fenced and line.startswith("#"):
            line = "#" + line
        elif not fenced:
            line = re.sub(r"\]\((?![a-z]+:|/|#)([^)]+)\)", lambda m: f"]({prefix}/{m.group(1)})", line)
        body.append(line)
    return "\n".join([*lines[:start + 1], *body, *lines[end:]]) + "\n"


def status(protocol: Protocol) -> list[dict[str, Any]]:
    """Where each stage and each Bug run of the folder stands: rows of stage, run, state (``complete``, ``running
    or stopped``, ``not started``), env steps and the newest test MWR of the run's evaluations while training."""
    trials = {"bug": protocol.bug_trials(), "ablations": protocol.ablation_trials()}
    rows: list[dict[str, Any]] = []
    for stage in protocol.stages:
        if stage.name in trials:  # one row per Bug run
            runs = [(t.name, Path(t.config.out) / t.name, finished(t)) for t in trials[stage.name]]
        else:  # one row for the stage; a training stage's run folder is named after it
            runs = [(stage.name, protocol.out / stage.name, stage.complete())]
        for name, folder, done in runs:
            csv_name = "metrics-ant.csv" if stage.name == "match" else "metrics.csv"  # stage 1: two learners
            started = (folder / csv_name).exists()
            evals = _evals(folder)
            rows.append({"stage": stage.name, "run": name,
                         "state": "complete" if done else "running or stopped" if started else "not started",
                         "env_steps": run_facts(folder, 200, csv_name)["env_steps"] if started else None,
                         "test_mwr": float(evals[-1]["test_mwr"]) if evals else None})
    return rows


def format_status(protocol: Protocol) -> str:
    """:func:`status` as a table."""
    lines = [f"{'stage':<11} {'run':<44} {'state':<19} {'env steps':>11} {'test MWR':>9}"]
    for r in status(protocol):
        steps = "-" if r["env_steps"] is None else f"{r['env_steps']:,}"
        mwr = "-" if r["test_mwr"] is None else f"{r['test_mwr']:+.3f}"
        lines.append(f"{r['stage']:<11} {r['run']:<44} {r['state']:<19} {steps:>11} {mwr:>9}")
    return "\n".join(lines)


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def _publish(protocol: Protocol, version: str) -> list[dict[str, Any]]:
    """Ship Ant, Spider, the paper-preset DDPG Bug of the best seed (``bug``) and the best Bug of any algorithm
    (``bug-<algo>``); each manifest with the code version and the Bug's test MWR with its 95 % interval."""
    from triplesumo.agents import zoo

    ours = {str(Path(t.config.out) / t.name / "policy") for t in protocol.bug_trials()}  # not the ablations
    rows = [r for r in _read_csv(protocol.out / "evaluation" / "per_seed.csv") if r["policy"] in ours]
    # the ring every stage trained on, and the env version whose default it is (the trainer wrote the one it ran under)
    extra: dict[str, Any] = {"code_version": version, "reproduction": str(protocol.out),
                             "physics": dataclasses.asdict(protocol.physics),
                             **({"env_version": ENV_VERSION} if protocol.physics == PhysicsConfig() else {})}

    def evaluation(row: dict[str, str]) -> dict[str, Any]:
        return {"test_mwr": float(row["test_mwr"]), "test_mwr_lo": float(row["test_mwr_lo"]),
                "test_mwr_hi": float(row["test_mwr_hi"]), "confidence": 0.95, "test_matches": int(row["epochs"]),
                "eval_seed": int(row["eval_seed"]), "n_win": int(row["n_win"]), "n_loss": int(row["n_loss"]),
                "n_draw": int(row["n_draw"]), "opponents": [f"ant={protocol.ant_policy}",
                                                            f"spider={protocol.spider_policy}"]}

    def mwr(row: dict[str, str]) -> float:
        return float(row["test_mwr"])

    # Ant and Spider: the stage-2 contest checks they passed (recomputable from contest/*/metrics.csv)
    contest = {"contest": json.loads((protocol.out / "contest" / "contest.json").read_text())}
    ship: list[tuple[Path, str, dict[str, Any] | None]] = [(Path(protocol.ant_policy), "ant", None),
                                                           (Path(protocol.spider_policy), "spider", None)]
    preset = [r for r in rows if r["algo"] == "ddpg"]
    if preset:
        top = max(preset, key=mwr)
        ship.append((Path(top["policy"]), "bug", top))
    else:
        print("  publish: no paper-preset DDPG Bug (ddpg not in --algos): zoo:bug is left as it is")
    best = max(rows, key=mwr)
    ship.append((Path(best["policy"]), f"bug-{best['algo']}", best))
    made = []
    for stem, name, row in ship:
        path = zoo.publish(stem, name, contest if row is None else evaluation(row), extra=extra)
        made.append({"name": name, "file": str(path), "policy": str(stem),
                     **({} if row is None else {"algo": row["algo"], "train_seed": row["train_seed"],
                                                "test_mwr": mwr(row), "test_mwr_lo": float(row["test_mwr_lo"]),
                                                "test_mwr_hi": float(row["test_mwr_hi"])})})
    return made


# ---------------------------------------------------------------- the report
def _run_row(protocol: Protocol, name: str, learner: str = "") -> str:
    """A table row of a run's training; ``learner`` names one learner of a run with several."""
    run = protocol.out / name
    csv_name = f"metrics-{learner}.csv" if learner else "metrics.csv"
    if learner:
        name = f"{name} ({learner})"
    if not (run / csv_name).exists():
        return f"| {name} | - | - | - |"
    facts = run_facts(run, 200, csv_name)
    return f"| {name} | {facts['epochs']:,} | {facts['env_steps']:,} | {facts['final_mwr']:+.3f} |"


def _trial_group(trial: Trial) -> str:
    """The compare group of a trial's policy (``ddpg``, ``ddpg,ddpg.noise=gaussian``)."""
    return trial_group({"group": "trained", "algo": "", "policy": str(Path(trial.config.out) / trial.name / "policy")})


def _ci(x: float, lo: float, hi: float) -> str:
    return f"{x:+.3f} [{lo:+.3f}, {hi:+.3f}]"


def report(protocol: Protocol, record: dict[str, Any]) -> str:
    """``REPRODUCTION.md`` of a reproduction folder, every number read from the files it wrote."""
    out, cfg = protocol.out, protocol.cfg
    ring = ("`border_rim=True`: the paper's ring with its solid 3 cm rim (env v2: four boxes), agents starting "
            "fair (each 1.0 m from its nearest edge and from the edge behind it)" if cfg.border_rim
            else "`border_rim=False`: visual-only border markers (the ring of the first shipped zoo)")
    lines = [f"# Reproduction report ({out.name})", "",
             f"Written by `triplesumo reproduce` (code version {record['runs'][-1]['version']}) from the files in "
             f"`{out.name}/`." + (" **Tiny budgets (a smoke run): the numbers mean nothing.**"
                                                    if cfg.tiny else ""), "",
             f"Ring: {ring}; every stage trained and was evaluated on it.", "",
             "## Stage 1: the ongoing match (Ant and Spider learn together, Bug passive)", "",
             *([f"Skipped: the pair was given (`--pair {' '.join(cfg.pair)}`).", ""] if cfg.pair else [
                 f"Pre-training reward: the paper's terms with still = {cfg.pretrain_still:g} (losing costs more than "
                 "surviving).", "",
                 "| run | epochs | env steps | final training MWR (last 200 epochs) |", "| --- | ---: | ---: | ---: |",
                 _run_row(protocol, "match", "ant"), _run_row(protocol, "match", "spider"), ""])]
    contest_path = out / "contest" / "contest.json"
    lines += ["## Stage 2: is it a contest?", ""]
    if contest_path.exists():
        c = json.loads(contest_path.read_text())
        lo, hi = c["band"]
        verdict = "a contest" if c["contest"] else "**not a contest**: the Bug stage refuses it"
        lines += [f"On {c['matches']:,} held-out starts each (seed {cfg.contest_seed}): each side must push a passive "
                  f"opponent out in at least {c['push_min']:.0%} of them, and with Bug passive the team's MWR must lie "
                  f"in [{lo:+.2f}, {hi:+.2f}].", "",
                  "| check | value | bound | |", "| --- | ---: | ---: | --- |",
                  f"| Ant pushes a passive Spider out | {c['ant_pushes']:.1%} | >= {c['push_min']:.0%} | "
                  f"{'ok' if c['ant_pushes'] >= c['push_min'] else 'failed'} |",
                  f"| Spider pushes a passive Ant out | {c['spider_pushes']:.1%} | >= {c['push_min']:.0%} | "
                  f"{'ok' if c['spider_pushes'] >= c['push_min'] else 'failed'} |",
                  f"| team MWR, Bug passive (wins {c['team_wins']:.1%}, losses {c['team_losses']:.1%}, draws "
                  f"{c['draws']:.1%}) | {c['team_mwr']:+.3f} | [{lo:+.2f}, {hi:+.2f}] | "
                  f"{'ok' if lo <= c['team_mwr'] <= hi else 'failed'} |", "", f"Verdict: {verdict}.", ""]
    budget = "" if cfg.tiny else f" (budget {cfg.bug_env_steps:,} env steps per run)"
    schedule = [] if cfg.tiny else [
        "DDPG: the paper preset (one gradient step per 30 transitions); TD3 and SAC: one gradient step per "
        + (f"{cfg.bug_learn_every} transitions (`--bug-learn-every`)" if cfg.bug_learn_every
           else "transition (their default)") + "; PPO: its rollouts. The exact commands are at the end.", ""]
    lines += [f"## Stage 3: Bug per algorithm and seed (training){budget}", "", *schedule,
              "| run | epochs | env steps | final training MWR (last 200 epochs) |", "| --- | ---: | ---: | ---: |"]
    lines += [_run_row(protocol, f"bug/{t.name}") for t in protocol.bug_trials()]
    lines += [_run_row(protocol, f"ablations/{t.name}") for t in protocol.ablation_trials()] + [""]
    rows = _read_csv(out / "evaluation" / "per_seed.csv")
    epochs = rows[0]["epochs"] if rows else "-"
    lines += [f"## Stage 4: test MWR per seed ({epochs} seeded test matches each, the same for all)", "",
              "| run | train seed | test MWR [95% CI] | wins | losses | draws |",
              "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {trial_group(r)} | {r['train_seed'] or '-'} | "
                     f"{_ci(float(r['test_mwr']), float(r['test_mwr_lo']), float(r['test_mwr_hi']))} | "
                     f"{r['n_win']} | {r['n_loss']} | {r['n_draw']} |")
    lines.append("")
    ablated = {_trial_group(t): t.name for t in protocol.ablation_trials()}
    cmp_path = out / "compare" / "compare.json"
    if cmp_path.exists():
        table = json.loads(cmp_path.read_text())
        pct = round(100 * table["confidence"])
        lines += ["## Stage 5: per algorithm across seeds (IQM, stratified bootstrap)", "",
                  f"| algorithm | seeds | per-seed test MWR | IQM [{pct}% CI] |", "| --- | ---: | --- | ---: |"]
        for g in table["groups"]:
            if g["group"] in ablated:
                continue
            kind = " (baseline)" if g["group"] in ("passive", "random") else ""
            lines.append(f"| {g['group']}{kind} | {g['n_seeds']} | {' '.join(f'{s:+.3f}' for s in g['scores'])} | "
                         f"{_ci(g['iqm'], g['lo'], g['hi'])} |")
        lines += ["", "Plots: `compare/compare.png` (IQM by group), `evaluation/compare_mwr.png` (test curves), "
                  "`*/plots/` (training curves).", ""]
        lines += _ablation_section(table, ablated, pct)
    lines += _skill_section(protocol)
    if record.get("published"):
        lines += ["## Published into the zoo", "", "| zoo name | algorithm | train seed | test MWR [95% CI] | file |",
                  "| --- | --- | ---: | ---: | --- |"]
        for p in record["published"]:
            if isinstance(p, str):  # a record written before the table
                lines.append(f"| - | - | - | - | `{p}` |")
                continue
            mwr = _ci(p["test_mwr"], p["test_mwr_lo"], p["test_mwr_hi"]) if "test_mwr" in p else "-"
            lines.append(f"| `zoo:{p['name']}` | {p.get('algo', '-')} | {p.get('train_seed', '-')} | {mwr} | "
                         f"`{p['file']}` |")
        lines.append("")
    lines += ["## Commands", "", "The whole protocol: `triplesumo reproduce "
              + " ".join(shlex.quote(a) for a in _argv(cfg)) + "`. Stage by stage:", "", "```bash"]
    for name, stage in record["stages"].items():
        lines.append(f"# {name} ({stage['seconds']:.0f} s, {stage['version']}, done {stage['done']})")
        lines += stage["commands"]
    lines += ["```", ""]
    return "\n".join(lines)


def _ablation_section(table: dict[str, Any], ablated: dict[str, str], pct: int) -> list[str]:
    """The ablations of the paper preset against it: IQM per change and P(change > preset)."""
    if not ablated:
        return []
    lines = ["## Ablations of the paper preset (DDPG Bug, one change each, same seeds and budget)", "",
             "Why: with a still punishment of -4 per step and gamma 0.99 the discounted cost of surviving is about the "
             "loss penalty, and OU noise reset per match stays small early in each match. The paper preset is kept "
             "as it is; these runs measure whether the choices matter.", "",
             f"| change | seeds | per-seed test MWR | IQM [{pct}% CI] | P(change > preset) [{pct}% CI] |",
             "| --- | ---: | --- | ---: | ---: |"]
    poi = {(p["x"], p["y"]): p for p in table["improvement"]}
    for g in table["groups"]:
        if g["group"] not in ablated:
            continue
        p = poi.get((g["group"], "ddpg"))
        vs = "-" if p is None else f"{p['poi']:.2f} [{p['lo']:.2f}, {p['hi']:.2f}]"
        change = g["group"].removeprefix("ddpg,")
        lines.append(f"| {change} | {g['n_seeds']} | {' '.join(f'{s:+.3f}' for s in g['scores'])} | "
                     f"{_ci(g['iqm'], g['lo'], g['hi'])} | {vs} |")
    return [*lines, ""]


def _evals(run: Path) -> list[dict[str, str]]:
    return _read_csv(run / "eval.csv")


def _skill_section(protocol: Protocol) -> list[str]:
    """Time to skill per algorithm and seed, from the evaluations the stage-4 runs made while training."""
    cfg, out = protocol.cfg, protocol.out
    if not cfg.bug_eval_every:
        return []
    runs = [(t, Path(t.config.out) / t.name) for t in protocol.bug_trials()]
    if not any(_evals(run) for _, run in runs):
        return []
    first = runs[0][0].config
    lines = ["## Time to skill", "",
             f"Env steps and training wall time (collection, learning, checkpoints; the evaluations apart) until "
             f"Bug's test MWR first reached {SKILL:+.2f}, from the evaluations stage 4 made while training: every "
             f"{first.eval_every:,} env steps, the current policy frozen on the first {first.eval_epochs} test "
             "matches of stage 5. Measured on the machine that ran each run, never projected; a run resumed "
             "across sessions adds its sessions' training times, and restarts with an empty replay buffer.", "",
             "| run | reached | env steps | training wall time | evaluations | best test MWR (at env steps) |",
             "| --- | --- | ---: | ---: | ---: | ---: |"]
    for trial, run in runs:
        rows = _evals(run)
        if not rows:
            lines.append(f"| {trial.name} | not yet | - | - | 0 | - |")
            continue
        hit = next((r for r in rows if float(r["test_mwr"]) >= SKILL), None)
        best = max(rows, key=lambda r: float(r["test_mwr"]))
        top = f"{float(best['test_mwr']):+.3f} ({int(best['env_steps']):,})"
        if hit is None:  # not within the env steps and training time so far
            last = rows[-1]
            lines.append(f"| {trial.name} | {'no' if finished(trial) else 'not yet'} | > {int(last['env_steps']):,} | "
                         f"> {_duration(float(last['train_seconds']))} | {len(rows)} | {top} |")
        else:
            lines.append(f"| {trial.name} | yes | {int(hit['env_steps']):,} | "
                         f"{_duration(float(hit['train_seconds']))} | {len(rows)} | {top} |")
    plot = _plot_curves(runs, out / "bug" / "test_mwr.png")
    return [*lines, "", f"![test MWR while training]({plot.relative_to(out)})", ""]


def _duration(seconds: float) -> str:
    minutes = round(seconds / 60)
    return f"{minutes // 60} h {minutes % 60:02d} min" if minutes >= 60 else f"{seconds / 60:.1f} min"


def _plot_curves(runs: list[tuple[Trial, Path]], path: Path) -> Path:
    """Test MWR against env steps of every stage-4 run, one colour per algorithm, the +0.2 line dashed."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 4.2))
    ax = fig.subplots()
    colours: dict[str, Any] = {}
    for trial, run in runs:
        rows = _evals(run)
        if not rows:
            continue
        algo = trial.config.learners()["bug"]
        first = algo not in colours
        colours.setdefault(algo, f"C{len(colours)}")
        ax.plot([int(r["env_steps"]) for r in rows], [float(r["test_mwr"]) for r in rows], marker=".",
                color=colours[algo], alpha=0.8, label=algo if first else None)
    ax.axhline(SKILL, linestyle="--", color="grey", label=f"{SKILL:+.1f}")
    ax.set_xlabel("env steps")
    ax.set_ylabel("test MWR (seeded test matches)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Bug's test MWR while training, one line per seed")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def _argv(cfg: ReproduceConfig) -> list[str]:
    """The command-line options that make ``cfg``'s outputs (how it ran, :data:`RUN_OPTIONS`, left out)."""
    from triplesumo import _dcargs

    return _dcargs.to_argv(dataclasses.replace(cfg, **{k: getattr(ReproduceConfig(), k) for k in RUN_OPTIONS}))
