"""The reproduction's config (:class:`ReproduceConfig`), its stages and the rules they are held to."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.envs.seeding import check_seed
from triplesumo.evaluation.evaluate import check_ray
from triplesumo.rules.config import RewardConfig
from triplesumo.train import sweep
from triplesumo.train.config import ALGOS, BACKENDS, TrainConfig

RECORD_FILE = "reproduce.json"
REPORT_FILE = "REPRODUCTION.md"
CONTEST_BAND = (-0.50, -0.10)
"""The contest rule: with Bug passive, the team's MWR on the contest starts lies in this band (both ends
included): the team loses without Bug's help, but not hopelessly."""
PUSH_MIN = 0.5
"""Each pre-trained side pushes a passive opponent out in at least this share of the contest starts."""


class ContestError(RuntimeError):
    """The Bug stage refused a pair that failed the contest rule (the message names each failed check)."""


class PairError(RuntimeError):
    """Stage 1 found no pair by its rules within the sides' epoch budgets (the message names the side, its screens
    and the record)."""
ABLATION_ALIASES = {"noise": "ddpg.noise", "still": "reward.still"}
"""Short names of the ablations of the paper preset (Gaussian noise, a smaller still punishment)."""
RUN_OPTIONS = ("progress", "sides_at_once", "status", "ray", "ray_address", "num_cpus", "cpus_per_trial", "workers",
               "publish", "docs", "allow_other_ring", "device", "warp_eval_workers")
"""ReproduceConfig fields that say how the stages run (or what happens to their results afterwards), not what they
make: a folder resumes with other values."""
GROWABLE = ("bug_epochs", "bug_env_steps")
"""Bug budgets a reproduction's folder may grow on a re-run (never shrink; ``bug_env_steps`` 0, no env-step limit, is
the largest): each Bug goes on from its last checkpoint, replay buffer included, to the larger budget, as ``train
--resume RUN --max-env-steps N`` does, which trains what one run at the larger budget would have. The test of the
smaller budget is set aside, not lost (:func:`triplesumo.reproduce.run.set_aside_test`), and the test is played
again."""
PROTOCOL_FIELDS = ("out", "name", "learn", "learner", "seed", "epochs", "max_env_steps", "policies")
"""TrainConfig fields the protocol sets for every Bug run: an ablation cannot change them."""
PRETRAIN_REWARD = RewardConfig(still=-1.0, draw=-200.0, axis_dead_zone=0.25, opponents="sum")
"""The pre-training reward (docs/CONTEST.md): the paper's terms and win and loss rewards, with

* still = -1 (the paper's code: -4, which makes surviving without a result worth exactly a loss at gamma 0.99);
* draw = -200, so that a standoff costs more than trying (co-training ended in standoffs without it);
* a 0.25 m dead zone on the per-axis signs (on the fair start the paper's sign paid the Spider for approaching
  an opponent by the coin of the reset noise);
* the per-opponent velocity terms summed (a mean paid the Spider, with two opponents, half the Ant's signal).

Bug's stage trains on the paper's reward (the env's default)."""
SKILL = 0.2
"""Time to skill: the test MWR Bug's team first reaches (+0.2)."""


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
    algos: tuple[str, ...] = ("ddpg", "sac")
    """Algorithms Bug is trained with: DDPG (the paper preset) and the best of TD3/SAC/PPO, SAC, chosen by the rule
    fixed beforehand in docs/CONTEST.md (seed 0 of each in the contest's match, by the training MWR of its last 200
    training matches: SAC +0.445, TD3 +0.210, PPO -0.290). ``--algos ddpg td3 sac ppo`` reruns the comparison."""
    seeds: tuple[int, ...] = (0, 1, 2, 3, 4)
    """Training seeds of Bug, for every algorithm (DDPG: the first ``ddpg_runs`` of them): 5, the fewest runs an
    interval across runs is drawn over. A folder resumes with more seeds (or algorithms) than it was made with: the
    runs made are kept and the new ones trained and tested on the same starts."""
    ddpg_runs: int = 3
    """The paper-preset DDPG Bug trains on the first this many of ``seeds`` (0: all of them): the comparison with the
    paper's algorithm, beside the best algorithm's headline."""
    ant_epochs: int = 10_000
    """Stage ``ant``: at most this many epochs of the Ant learning to push a still Spider, Bug still; it stops at its
    earliest screened checkpoint that pushes at least :data:`PUSH_MIN` of the screen's still opponents out (the pair
    rule may train it on to a later one). The paper gives its Ant 3,000; the Ant of docs/CONTEST.md first passed at
    5,000 (11 of 100 at 2,000, 20 at 3,000). A side that reaches its budget without passing stops the protocol
    (:class:`PairError`)."""
    spider_epochs: int = 10_000
    """Stage ``spider``: at most this many epochs of the Spider learning to push a still Ant and Bug, screened as the
    Ant is: the Spider of docs/CONTEST.md first passed at 6,000 (33 of 100 at 3,000, 47 at 5,000)."""
    screen_every: int = 1000
    """Stage 1: each side is screened every this many epochs (its policy kept as ``ROLE/screens/policy-EPOCH``)."""
    screen_epochs: int = 100
    """Stage 1: starts of each screen and of each pair's match (screen_seed + i; held out from training, from the
    contest's starts and from the Bug's test starts)."""
    screen_seed: int = 30_000
    """Screen start i resets with screen_seed + i."""
    sides_at_once: bool = True
    """Train the Ant and the Spider side by side, each in a process of its own on one core (their runs are
    independent: the outputs are those of one after the other)."""
    pretrain_seed: int = 1
    """Seed of both pre-training runs."""
    pretrain: RewardConfig = PRETRAIN_REWARD
    """The reward of both pre-training runs (:data:`PRETRAIN_REWARD`). Its still punishment must make losing cost
    more than surviving: still / (1 - gamma) > the loss reward (-1 / 0.01 = -100 > -400); the paper's -4 gives
    exactly -400."""
    pair: tuple[str, ...] = ()
    """Skip stage 1 and check this Ant and Spider instead (two policy specs: ``zoo:ant zoo:spider``, files,
    ``passive``); the contest rule and everything after it run on them."""
    allow_other_ring: bool = False
    """Let a pair trained on another ring than this reproduction's (``border_rim``; the fair start) play on it;
    without it such a pair is refused, naming both rings."""
    bug_epochs: int = 20_000
    """Stage 3: at most this many epochs per Bug run (the paper's 20,000)."""
    bug_env_steps: int = 2_000_000
    """Stage 3: the env-step budget of every Bug run, the same for every algorithm whatever its matches
    last (``train --max-env-steps``); a run stops at the first epoch end past it (or at ``bug_epochs``, whichever
    comes first). 0: epochs only. 2 M is protocol change 2's budget, the default since its headline over both
    from-scratch pairs met the targets (docs/reproduce.md); protocol change 1 ran 1 M."""
    bug_learn_every: int = 8
    """Stage 3 (and the ablations): collected transitions per gradient step of the TD3 and SAC Bugs: 8, SAC's
    default and the recipe measured fastest to skill (``docs/bench/skill.md``; the shipped pair's Bugs trained with
    16). 0 keeps the algorithm's default (TD3: 1, the paper's one update per transition, several times slower).
    DDPG keeps the paper preset (30) and PPO its rollouts."""
    bug_n_step: int = 5
    """Stage 3 (and the ablations): n of the TD3 and SAC Bugs' n-step returns: 5, the same recipe's (the shipped
    pair's Bugs trained with 1). 0 keeps the algorithm's default. DDPG keeps the paper preset (1)."""
    bug_eval_every: int = 100_000
    """Stage 3 (and the ablations): every this many env steps each Bug run evaluates its current policy on the
    first bug_eval_epochs test matches of stage 4 (``train --eval-every``): the test-MWR curves and time to skill.
    0: none."""
    bug_eval_epochs: int = 200
    """Test matches of each evaluation during stage 4."""
    contest_epochs: int = 1000
    """Stage 2: held-out starts of each contest check (Ant vs passive Spider, Spider vs passive Ant, the match
    with Bug passive). A check that can no longer pass stops the contest sooner (a passive pair: after 501 of
    1,000 starts of the first check); a pair that passes plays them all."""
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
    """After the last stage, publish into the zoo the pair (``ant``, ``spider``, with their contest check), each
    algorithm's Bug (``bug-<algo>``: its seed with the highest training MWR over its last 200 training matches; the
    test starts pick nothing) and ``bug``, that Bug of the algorithm with the highest IQM test MWR across seeds."""
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
    regenerate REPRODUCTION.md from the outputs there are so far (a long reproduction, between its runs)."""
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
    workers: int = 1
    """Without ray: the Bug runs of stage 4 and the ablations train in this many processes of this machine at once,
    and the contest's and the test's matches play on as many (``evaluate --workers``). The outputs are those of one
    process. Stage 1's two sides train as ``sides_at_once`` says, and their screens play in their own processes."""
    backend: str = "cpu"
    """Where stage 1's sides and the Bugs train: cpu (MuJoCo on this machine's cores, the exact reference) or warp
    (MuJoCo Warp: ``warp_envs`` matches at once on ``device``; every learner on the parallel schedule of
    ``warp_updates`` gradient steps of ``warp_batch`` transitions per step of all the matches, as ``bench skill-gpu``;
    a checkpoint at each leg's and run's end only). The screens, the pairs' matches, the contest, the engagement and
    the test play on the CPU in ``n_envs`` matches whatever the backend: every rule is checked, and every figure
    measured, on the reference backend. Warp runs no PPO (its rollouts are sized for 16 matches) and no Ray (whose
    tasks reserve CPUs, not the device): the Bugs train one after another, or on ``workers`` processes sharing the
    device."""
    device: str = "cuda"
    """With backend warp: Warp's device, cuda (a GPU) or cpu (Warp's CPU device: a check of the protocol, not a
    speed)."""
    warp_envs: int = 4096
    """With backend warp: matches stepped at once on the device while a side or a Bug trains (an epoch stays one
    match, so the epoch budgets and screens count what they count on the CPU)."""
    warp_updates: int = 16
    """With backend warp: gradient steps after every step of all the matches (``bench skill-gpu``'s
    updates_per_step)."""
    warp_batch: int = 4096
    """With backend warp: transitions per gradient step."""
    warp_warmup: int = 8
    """With backend warp: steps of all the matches of random warm-up before the first update."""
    warp_eval_workers: int = 8
    """With backend warp: the Bug runs' evaluations (``bug_eval_every``) play in the background, on this many
    worker processes of the host, while the device trains on (``train --eval-workers``)."""

    def __post_init__(self) -> None:
        for name in ("pretrain_seed", "contest_seed", "eval_seed"):
            check_seed(getattr(self, name), f"ReproduceConfig.{name}")
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
        for name in ("bug_env_steps", "bug_learn_every", "bug_n_step", "bug_eval_every", "ddpg_runs"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"ReproduceConfig.{name} must be an int >= 0, got {value!r}")
        if isinstance(self.pair, list):
            object.__setattr__(self, "pair", tuple(self.pair))
        if self.pair and len(self.pair) != 2:
            raise ValueError(f"ReproduceConfig.pair must be two policies (Ant, Spider), got {self.pair!r}")
        gamma = DDPGConfig().gamma
        if isinstance(self.pretrain, dict):  # a record's config, read back
            object.__setattr__(self, "pretrain", RewardConfig(**self.pretrain))
        if not isinstance(self.pretrain, RewardConfig):
            raise ValueError(f"ReproduceConfig.pretrain must be a RewardConfig, got {self.pretrain!r}")
        still, loss = self.pretrain.still, self.pretrain.loss
        worth = still / (1 - gamma)
        if worth <= loss or math.isclose(worth, loss):  # (-4 / (1 - 0.99) is -399.99999999999966 in floats)
            raise ValueError(f"ReproduceConfig.pretrain.still {still}: surviving without a result would be worth "
                             f"{worth:.0f} (still / (1 - gamma), gamma {gamma}), no more than losing ({loss:.0f}); the "
                             f"pre-trained sides would not learn to stay in. Use a value above {loss * (1 - gamma):g}")
        for name in ("ant_epochs", "spider_epochs", "screen_every", "screen_epochs", "bug_epochs", "bug_eval_epochs",
                     "contest_epochs", "eval_epochs", "n_envs"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"ReproduceConfig.{name} must be an int >= 1, got {value!r}")
        if any(isinstance(s, bool) or not isinstance(s, int) or s < 0 for s in self.seeds):
            raise ValueError(f"ReproduceConfig.seeds must be ints >= 0, got {self.seeds!r}")
        for name, low in (("num_cpus", 0), ("cpus_per_trial", 1), ("workers", 1), ("warp_envs", 1), ("warp_updates", 1),
                          ("warp_batch", 1), ("warp_warmup", 0), ("warp_eval_workers", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(f"ReproduceConfig.{name} must be an int >= {low}, got {value!r}")
        if (self.ray_address or self.num_cpus) and not self.ray:
            raise ValueError("ReproduceConfig.ray_address and num_cpus are options of ray (--ray)")
        if self.workers > 1 and self.ray:
            raise ValueError("ReproduceConfig.workers and ReproduceConfig.ray: Ray runs the tasks on its own CPUs "
                             "(num_cpus, cpus_per_trial); give one of the two")
        check_ray("ReproduceConfig", self.ray, self.ray_address)
        if self.backend not in BACKENDS:
            raise ValueError(f"ReproduceConfig.backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.device not in ("cuda", "cpu"):
            raise ValueError(f"ReproduceConfig.device must be cuda or cpu (Warp's CPU device), got {self.device!r}")
        if self.backend == "warp":
            if "ppo" in self.algos:
                raise ValueError("ReproduceConfig.algos: ppo does not train on backend warp here (its rollouts are "
                                 "sized for 16 matches, not thousands); train it with --backend cpu, or leave it out")
            if self.ray:
                raise ValueError("ReproduceConfig.ray with backend warp: Ray's tasks reserve CPUs, not the device; "
                                 "the Bugs train one after another on the device, or on --workers processes sharing it")


def bug_runs(algos: Any, seeds: Any, ddpg_runs: int) -> list[tuple[str, int]]:
    """The Bug runs (algorithm, seed) of a reproduction: every algorithm on every seed, DDPG on the first
    ``ddpg_runs`` (0: all)."""
    return [(a, s) for a in algos for s in (seeds[:ddpg_runs] if a == "ddpg" and ddpg_runs else seeds)]


@dataclass(frozen=True)
class Stage:
    """One stage of the protocol: what it writes, whether that is complete, how to make it."""

    name: str
    title: str
    outputs: tuple[Path, ...]
    complete: Callable[[], bool]
    run: Callable[[], list[str]]
    """Makes (or finishes) the outputs; returns the commands that do the same by hand."""
    commands: Callable[[], list[str]] | None = None
    """The commands that make the outputs by hand, for a stage an earlier one made alongside its own (the Spider,
    trained beside the Ant)."""
