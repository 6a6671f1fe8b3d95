"""Configuration of a training run (paper defaults), validated, and generated into the CLI."""

from __future__ import annotations

import dataclasses
import math
import os
import types
import typing
import warnings
from dataclasses import dataclass, field
from typing import Any

from triplesumo.agents.zoo import check_policy_pairs
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.ppo import PPOConfig
from triplesumo.algos.sac import SACConfig
from triplesumo.algos.td3 import TD3Config
from triplesumo.envs.seeding import check_seed
from triplesumo.model.specs import PhysicsConfig
from triplesumo.rules.config import OBS_MODES, MatchConfig, RewardConfig
from triplesumo.rules.scenarios import scenario_config, scenarios
from triplesumo.train.league_config import LeagueConfig

ALGOS = ("ddpg", "td3", "sac", "ppo")
"""Algorithms a learner can use (``--learn AGENT=ALGO``); each has its config field."""
SHARE_MODES = ("none", "team")
BACKENDS = ("cpu", "warp")
DEVICES = (None, "cpu", "cuda")
DEFAULT_LEARN = ("bug=ddpg",)
"""The paper's one learner: Bug, with DDPG."""
DEFAULT_POLICIES = ("ant=zoo:ant", "spider=zoo:spider")
"""The other agents of the paper's third stage: the ongoing match of the trained Ant and Spider."""


def typed_value(tp: Any, text: str, where: str) -> Any:
    """``text`` read as type ``tp`` (int, float, bool, str, ``X | None`` with ``none``, a tuple of
    space-separated items); ``ValueError`` starting with ``where`` otherwise."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is tuple:
        return tuple(typed_value(args[0], item, where) for item in text.split())
    if origin in (typing.Union, types.UnionType):
        if text.lower() == "none" and type(None) in args:
            return None
        return typed_value(next(a for a in args if a is not type(None)), text, where)
    if tp is bool:
        if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
            raise ValueError(f"{where}: {text!r} is not a bool (true or false)")
        return text.lower() in ("true", "1", "yes")
    try:
        return tp(text)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {text!r} is not a {getattr(tp, '__name__', tp)}") from None


@dataclass(frozen=True)
class TrainConfig:
    """Learners trained in a match whose other agents follow given policies.

    ``learn`` names the learners, each with its algorithm (by default ``bug=ddpg``, the paper's one
    DDPG learner; ``ant=sac bug=td3`` two), and ``share="team"`` gives the learning agents of a team
    one shared network. The paper's stages are runs of the one-learner case with different
    arguments: Ant first (learn ant=ddpg, Spider random, Bug passive), then Spider against the
    trained Ant, then Bug in the ongoing match of the trained Ant and Spider.
    """

    name: str = "bug"
    """Run name: the run folder is OUT/NAME."""
    out: str = "runs"
    """Folder that holds run folders."""
    learn: tuple[str, ...] = DEFAULT_LEARN
    """AGENT=ALGO for every learning agent (algo: ddpg, td3, sac or ppo), e.g. ant=sac bug=sac; the paper's
    one-learner case is bug=ddpg."""
    learner: str | None = None
    """Deprecated, use learn AGENT=ddpg: the one agent trained with DDPG."""
    share: str = "none"
    """none: one network per learning agent; team: one shared network (and replay or rollout)
    per team, fed by all its learning agents (they must use the same algorithm)."""
    policies: tuple[str, ...] = DEFAULT_POLICIES
    """AGENT=POLICY for the other agents (zero, passive, random, zoo:NAME or a policy file);
    agents not named are passive. Left at its default, the pairs of agents that learn are dropped."""
    epochs: int = 20_000
    """Epochs (matches) to train; one epoch = one match of at most steps_per_epoch steps. Matches
    run n_envs at a time, so those ending on the same final step can add up to n_envs - 1 more."""
    steps_per_epoch: int = 500
    """Step limit of a match (paper: 500); reaching it is a draw."""
    n_envs: int = 16
    """Matches collected at once (one batched acting call, threaded physics): 16 keep 2 threads busy
    (``triplesumo bench env``; ``docs/bench/index.md``)."""
    n_threads: int = 1
    """Threads MuJoCo uses to step the matches. 1 by default: the updates run in a thread of
    their own beside the physics (overlap_learning), so one MuJoCo thread plus the update
    thread use two cores, as fast as 2 MuJoCo threads (``triplesumo bench train``;
    ``docs/bench/index.md``)."""
    seed: int = 0
    """Seeds networks, exploration, replay sampling and every match's reset noise."""
    obs_mode: str = "paper"
    """Observation mode of the learner: paper or egocentric."""
    reward: RewardConfig = field(default_factory=RewardConfig)
    """The hybrid reward's weights (C1, C2, C3, still punishment, win/loss/draw)."""
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    """The simulation (timestep, integrator, start layout, ``border_rim``: the paper's solid ring rim)."""
    allow_other_ring: bool = False
    """Let a policy file trained on another ring (its manifest's physics: rim, start layout) play on this one, as a
    fixed policy or a league seed; without it such a policy is refused, naming both rings. A resume may change it."""
    ddpg: DDPGConfig = field(default_factory=DDPGConfig)
    """DDPG hyper-parameters (paper Table 2)."""
    td3: TD3Config = field(default_factory=TD3Config)
    """TD3 hyper-parameters (learners with algo td3)."""
    sac: SACConfig = field(default_factory=SACConfig)
    """SAC hyper-parameters (learners with algo sac)."""
    ppo: PPOConfig = field(default_factory=PPOConfig)
    """PPO hyper-parameters (learners with algo ppo); a rollout is ppo.n_steps x n_envs steps."""
    checkpoint_every: int = 200
    """Save a checkpoint every this many epochs (and at the end)."""
    save_replay: bool = True
    """Save the replay buffers in checkpoints, for an exact resume (large for long runs)."""
    window: int = 200
    """λ of the MWR and the rolling curves (paper: 200)."""
    overlap_learning: bool = True
    """Run the off-policy updates due at a step in a thread while MuJoCo steps the matches
    (same results)."""
    torch_threads: int = 1
    """torch.set_num_threads on CPU (two threads collapse when the other core is busy)."""
    progress: bool = True
    """Show a progress bar (epochs, or env steps when max_env_steps is set; MWR, steps/s)."""
    tensorboard: bool = True
    """Write TensorBoard events beside the CSV."""
    max_minutes: float = 0.0
    """Stop (after a checkpoint) once this many minutes have passed; 0 = no limit."""
    max_env_steps: int = 0
    """Stop (after a checkpoint, at the next epoch end) once this many env steps were collected, a
    budget that compares algorithms whose matches last differently; 0 = no limit."""
    eval_every: int = 0
    """Every this many env steps (at the step that crosses a multiple of it) play each learner's current
    policy, frozen (no exploration), on eval_epochs seeded test matches against the run's other policies
    (other learners: their current policies, frozen) and append its test MWR to eval.csv (eval-NAME.csv
    with several learners) and TensorBoard; 0: never. The test matches run on the CPU and draw on none of
    the training's generators: a run trains the same with or without them. Not with self_play (its
    league rates the learners)."""
    eval_background: bool = False
    """Play each evaluation in a worker process while the training goes on (a spare core), its row written
    when it is back: the same figures, with train_seconds the training's clock at that moment
    (policy_train_seconds: when its policy was frozen, as inline). An evaluation
    in flight at a checkpoint is saved with it and played again by a resume; the run's end waits for the
    last ones. Off: the training waits for each evaluation."""
    eval_workers: int = 1
    """With eval_background: the worker processes an evaluation's test matches are split over, each playing a
    share of them in turn (the figures those of one process, as every match depends on its seed only); a machine
    with cores to spare has each result sooner. 1: one worker."""
    eval_epochs: int = 200
    """Test matches per evaluation (eval_every); test match i resets with eval_seed + i."""
    eval_seed: int = 10_000
    """Seed of the evaluations' test matches (and of the random policies playing in them)."""
    eval_target: float | None = None
    """Stop (after a checkpoint) at the first evaluation in which every learner's test MWR is >= this: a
    skill reached (``triplesumo bench skill``); None: train on."""
    scenario: str = "paper"
    """Named game (paper, ffa, pursuit, 2v2) with its default roster; policies may use *=POLICY
    for every other agent. Under elimination rules the learner's epoch ends when it is out."""
    self_play: bool = False
    """Fill the seats of the agents that do not learn from opponent pools (RUN/league) sampled at every
    match start; the learners' snapshots join their side's pool when they beat it (see league)."""
    league: LeagueConfig = field(default_factory=LeagueConfig)
    """The self-play league's rules (used with self_play): admission, sampling, pool size, zoo seeds."""
    backend: str = "cpu"
    """Where the matches run: cpu (MuJoCo, numpy; the exact reference) or warp (MuJoCo Warp on
    device, first-out rules and one body kind; observations, actions, replay and rollouts stay
    torch tensors on the device). See "GPU training" in docs/gpu.md."""
    device: str | None = None
    """Torch/Warp device of backend warp: cuda, or cpu (Warp's CPU device: tests, no speed);
    default cuda when Warp sees a GPU. backend cpu runs on the CPU (None or cpu)."""
    learner_config: tuple[str, ...] = ()
    """LEARNER.FIELD=VALUE: one learner's own value of a field of its algorithm's config, over the
    --ALGO.FIELD all learners of that algorithm share, e.g. spider.learn_every=5 (LEARNER: a learning
    agent, or with share=team its team's learner, ant+bug; a tuple value's items space-separated)."""

    def __post_init__(self) -> None:
        check_seed(self.seed, "TrainConfig.seed")
        for name in ("policies", "learn", "learner_config"):
            if isinstance(getattr(self, name), list):
                object.__setattr__(self, name, tuple(getattr(self, name)))
        if self.learner is not None:  # the deprecated name of a one-DDPG-learner learn
            warnings.warn("TrainConfig.learner is deprecated: use learn AGENT=ddpg (--learn AGENT=ddpg)",
                          DeprecationWarning, stacklevel=3)
            if self.learn != DEFAULT_LEARN:
                raise ValueError(f"TrainConfig.learner (deprecated) and learn both name the learners "
                                 f"({self.learner!r}, {self.learn!r}): give learn only")
            object.__setattr__(self, "learn", (f"{self.learner}=ddpg",))
            object.__setattr__(self, "learner", None)
        if not self.learn:
            raise ValueError("TrainConfig.learn must name at least one learning agent (AGENT=ALGO)")
        if not self.name or self.name in (".", "..") or any(sep in self.name for sep in ("/", "\\", os.sep)):
            raise ValueError(f"TrainConfig.name must be a plain folder name inside out (no path separator, "
                             f"not . or ..), got {self.name!r}")
        for pair in self.learn:
            agent, _, algo = pair.partition("=")
            if not agent or "=" in algo or algo not in ALGOS:
                raise ValueError(f"TrainConfig.learn: expected AGENT=ALGO with ALGO one of {ALGOS}, got {pair!r}")
        agents = [p.split("=")[0] for p in self.learn]
        if len(set(agents)) < len(agents):
            twice = sorted({a for a in agents if agents.count(a) > 1})
            raise ValueError(f"TrainConfig.learn names an agent twice: {twice}")
        if self.policies == DEFAULT_POLICIES:
            learning = set(self.learners())
            object.__setattr__(self, "policies", tuple(p for p in self.policies if p.split("=")[0] not in learning))
        if self.share not in SHARE_MODES:
            raise ValueError(f"TrainConfig.share must be one of {SHARE_MODES}, got {self.share!r}")
        for agent in self.learners():
            check_policy_pairs("TrainConfig.policies", self.policies, agent)
        for name in ("epochs", "steps_per_epoch", "n_envs", "n_threads", "checkpoint_every", "window",
                     "torch_threads"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"TrainConfig.{name} must be an int >= 1, got {value!r}")
        if self.obs_mode not in OBS_MODES:
            raise ValueError(f"TrainConfig.obs_mode must be one of {OBS_MODES}, got {self.obs_mode!r}")
        for name in ("max_env_steps", "eval_every", "eval_seed"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"TrainConfig.{name} must be an int >= 0, got {value!r}")
        for name in ("eval_epochs", "eval_workers"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"TrainConfig.{name} must be an int >= 1, got {value!r}")
        if self.eval_workers > 1 and not self.eval_background:
            raise ValueError("TrainConfig.eval_workers splits the background evaluations over processes: set "
                             "eval_background too")
        if self.eval_target is not None:
            if isinstance(self.eval_target, bool) or not isinstance(self.eval_target, int | float) or not (
                    -1 <= self.eval_target <= 1):
                raise ValueError(f"TrainConfig.eval_target must be a test MWR in [-1, 1], got {self.eval_target!r}")
            if not self.eval_every:
                raise ValueError("TrainConfig.eval_target stops at an evaluation: set eval_every too")
        if self.eval_every and self.self_play:
            raise ValueError("TrainConfig.eval_every: a self-play run is rated by its league (league.csv, "
                             "plots/league.png), not evaluated against fixed policies; leave eval_every at 0")
        if not (math.isfinite(self.max_minutes) and self.max_minutes >= 0):
            raise ValueError(f"TrainConfig.max_minutes must be >= 0, got {self.max_minutes!r}")
        if not self.self_play and self.league != LeagueConfig():
            raise ValueError("TrainConfig.league is set (--league.*) but self_play is off: add --self-play")
        if self.backend not in BACKENDS:
            raise ValueError(f"TrainConfig.backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.device not in DEVICES:
            raise ValueError(f"TrainConfig.device must be one of {DEVICES}, got {self.device!r}")
        if self.backend == "cpu" and self.device == "cuda":
            raise ValueError("TrainConfig.device='cuda' needs backend='warp' (--backend warp): backend='cpu' "
                             "steps MuJoCo on the CPU")
        if self.scenario not in scenarios():
            raise ValueError(f"TrainConfig.scenario must be one of {scenarios()}, got {self.scenario!r}")
        for learner in self.learner_configs():
            self.algo_config(learner)  # every value read and checked by its algorithm's config

    def learner_configs(self) -> dict[str, dict[str, Any]]:
        """``learner_config`` as learner -> {field: typed value}; ``ValueError`` names the entry."""
        learning = self.learners()
        out: dict[str, dict[str, Any]] = {}
        for entry in self.learner_config:
            key, sep, raw = entry.partition("=")
            learner, dot, name = key.partition(".")
            where = f"TrainConfig.learner_config {entry!r}"
            if not sep or not dot or not learner or not name or not raw:
                raise ValueError(f"{where}: expected LEARNER.FIELD=VALUE, e.g. spider.learn_every=5")
            agents = learner.split("+")
            if any(a not in learning for a in agents) or len(set(agents)) < len(agents):
                raise ValueError(f"{where}: {learner!r} is not a learner; the learning agents are {list(learning)}"
                                 + (" (a team's shared learner is named AGENT+AGENT)" if self.share == "team" else ""))
            if len(agents) > 1 and self.share != "team":
                raise ValueError(f"{where}: {learner!r} names a team's shared learner, which needs share=team")
            cls = type(getattr(self, learning[agents[0]]))
            fields = {f.name for f in dataclasses.fields(cls)}
            hints = {k: v for k, v in typing.get_type_hints(cls).items() if k in fields}  # not TUNABLE
            if name not in hints:
                raise ValueError(f"{where}: {cls.__name__} (the {learning[agents[0]]} config) has no field {name!r} "
                                 f"(its fields: {', '.join(hints)})")
            if name in out.get(learner, {}):
                raise ValueError(f"{where}: {learner}.{name} given twice")
            out.setdefault(learner, {})[name] = typed_value(hints[name], raw, where)
        return out

    def algo_config(self, learner: str) -> Any:
        """The algorithm config of ``learner`` (an agent, or a shared team learner ``ant+bug``): its
        algorithm's (``self.<algo>``) with that learner's ``learner_config`` values."""
        algo = self.learners()[learner.split("+")[0]]
        fields = self.learner_configs().get(learner, {})
        try:
            return dataclasses.replace(getattr(self, algo), **fields)
        except ValueError as err:
            raise ValueError(f"TrainConfig.learner_config (learner {learner}): {err}") from None

    def match_config(self) -> MatchConfig:
        """The run's match: its scenario with its epoch length, observations, rewards and physics."""
        return scenario_config(self.scenario, max_steps=self.steps_per_epoch, obs_mode=self.obs_mode,
                               reward=self.reward, physics=self.physics)

    def learners(self) -> dict[str, str]:
        """Learning agent -> algorithm, in the order given."""
        return {pair.split("=")[0]: pair.split("=")[1] for pair in self.learn}


def parallel_schedule(cfg: TrainConfig, algo: str, updates_per_step: int, batch_size: int,
                      warmup_steps: int) -> TrainConfig:
    """``cfg`` with the off-policy ``algo``'s update schedule for many matches at once (MuJoCo Warp's, docs/gpu.md):
    after every step of all ``cfg.n_envs`` matches (``learn_every = n_envs`` transitions), ``updates_per_step``
    gradient steps of ``batch_size`` transitions, once ``warmup_steps`` such steps of random warm-up are collected
    (``learning_starts = warmup_steps x n_envs``). The algorithm's other fields are kept."""
    if algo not in ALGOS or algo == "ppo":
        raise ValueError(f"parallel_schedule: an off-policy algorithm ({', '.join(a for a in ALGOS if a != 'ppo')}) "
                         f"updates on this schedule, got {algo!r}")
    schedule = dataclasses.replace(getattr(cfg, algo), learn_every=cfg.n_envs, gradient_steps=updates_per_step,
                                   batch_size=batch_size, learning_starts=warmup_steps * cfg.n_envs)
    return dataclasses.replace(cfg, **{algo: schedule})
