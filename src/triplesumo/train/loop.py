"""The training loop: learners of any algorithm in several matches at once, resumable.

Reads like the paper: collect a step of every match (each learner acts for its agents with
exploration, the others follow their fixed policies), hand each learner its transitions,
and let it learn on its schedule: an off-policy learner (DDPG, TD3, SAC) does
``gradient_steps`` updates every ``learn_every`` collected transitions, in a thread beside
the physics; PPO updates when its ``(n_steps, rows)`` rollout is full. Each finished match
is one *epoch*: every learning agent's outcome, steps and rewards become a row of its
metrics CSV, every learner's update count and mean losses a row of its learning CSV; the
match is reset with fresh seeded noise. The one-learner case (``--learner bug``, DDPG) is
the paper's, bit for bit.

The matches are the public batched API (``triplesumo.vector_env``'s contract): arrays
``(n_envs, n_agents, ...)`` in and out, Gymnasium SAME_STEP autoreset (a finished match's last
observation, outcome codes and reward terms in ``infos``), each next match seeded from the
trainer's generator through ``reset_seed``. ``backend="cpu"`` is :class:`VectorMatches`
(numpy), ``backend="warp"`` is MuJoCo Warp's ``WarpMatchBatch`` (torch tensors on ``device``,
kept there by the learners). On both a checkpoint holds every match's exact state (the env's
``snapshot``), so a resume continues the matches in progress. One collection path serves both.

With ``self_play`` a :class:`~triplesumo.train.league.League` seats the agents that do not
learn: at every match start one member of each such side's pool is drawn (in a free-for-all
one per seat); at every match end its players are rated, due learning sides are admitted
(their actors written as policy files under ``RUN/league``) and the league's epoch is logged.
When both sides learn, each match is live or one learner plays the other side's pool
(``League.draw_live``); the learner whose seats a member takes sits the match out (no
transitions, no metrics row: its metrics CSV counts its own matches).

Nothing is lost: a folder that already holds a run is never trained into again without
``resume`` (continue it) or ``start_over`` (move it aside first); the memory the replay
buffer needs is checked before anything is made; a learner whose losses, parameters or
actions stop being finite stops the run with a :class:`DivergenceError` naming the
learner, the update and the last good checkpoint.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import shlex
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from triplesumo import ENV_VERSION, __version__
from triplesumo.agents.builtin import BUILTIN, RandomPolicy, ZeroPolicy, act_batch
from triplesumo.agents.frozen import FrozenPolicy
from triplesumo.agents.policy_file import atomic_write_bytes, load_fixed_policy, load_json, save_policy
from triplesumo.agents.zoo import expand_pairs, policies_from_pairs
from triplesumo.algos.base import DivergedError
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.ppo import PPOConfig
from triplesumo.algos.sac import SACConfig
from triplesumo.algos.td3 import TD3Config
from triplesumo.envs.batch import MatchBatch, VectorMatches
from triplesumo.envs.match import Match
from triplesumo.evaluation.metrics import local_winning_rate, moving_winning_rate
from triplesumo.model.specs import V0_PHYSICS, PhysicsConfig, physics_record
from triplesumo.rules.config import RewardConfig, check_shared_network
from triplesumo.rules.outcome import ERROR_CODE, PLAYING
from triplesumo.rules.outcome import outcome_name as code_name
from triplesumo.rules.rewards import TERMS
from triplesumo.rules.scenarios import scenario_config
from triplesumo.train import checkpoint
from triplesumo.train.config import TrainConfig
from triplesumo.train.league import League
from triplesumo.train.league_config import LeagueConfig, check_seeds
from triplesumo.train.league_plots import plot_league
from triplesumo.train.learners import (
    Learner,
    LearnerSpec,
    OffPolicyLearner,
    PPOLearner,
    learner_specs,
    make_learner,
)
from triplesumo.train.legs import LEGS_FILE, legs_before, make_leg, read_legs, write_legs
from triplesumo.train.logger import COLUMNS, LEARNING_COLUMNS, MetricsLog, intact_rows, learning_row_problem, run_file


@dataclass
class TrainResult:
    """Where a finished (or stopped) run stands."""

    run_dir: Path
    epochs: int
    env_steps: int
    updates: int
    mwr: float
    """MWR of the first learning agent."""
    seconds: float
    timers: dict[str, float] = field(default_factory=dict)
    """Seconds spent in physics+rules (``env``), acting (``act``) and learning (``learn``)."""
    mwrs: dict[str, float] = field(default_factory=dict)
    """MWR of every learning agent."""


SAT_OUT: dict[str, Any] = {"outcome": "", "step": 0, "sat_out": True}
"""The ``final`` entry of a learning agent whose seat a league member takes for a match (self-play
with several learning sides): its epoch does not wait for it, and it writes no metrics row."""

RUN_FILES = ("config.json", "metrics.csv", "checkpoints", "policy.json", "policy.safetensors")
"""What makes a folder hold a run: training never writes into such a folder afresh (with
``metrics-*.csv`` and ``policy-*.json`` of runs with several learners)."""


class RunExistsError(FileExistsError):
    """The run folder already holds a run (the message offers ``--resume`` and ``--start-over``)."""


class DivergenceError(FloatingPointError):
    """A learner's losses, parameters or actions are no longer finite (names learner, update, checkpoint)."""


def config_to_json(cfg: TrainConfig) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def write_run_config(run_dir: Path, cfg: TrainConfig) -> None:
    """Write ``RUN/config.json`` (what ``--resume`` reads) atomically; a failed write names the file."""
    with checkpoint.writing(Path(run_dir) / "config.json"):
        atomic_write_bytes(Path(run_dir) / "config.json", (json.dumps(config_to_json(cfg), indent=2) + "\n").encode())


FORK_FILE = "fork.json"
"""In a run folder made by ``train --fork`` (:mod:`triplesumo.train.fork`): where it came from."""
RESUME_OVERRIDES = ("epochs", "max_minutes", "progress", "save_replay", "n_threads")
"""The TrainConfig fields a resumed run may change (``train --resume RUN --epochs N ...``): budgets, output,
and ``n_threads``, the threads stepping the CPU physics, which advance every match alone and bit for bit
whatever their number (``tests/test_batch.py``), so that a run started on a laptop goes on with the cores of a
larger machine and trains exactly what it would have."""


def flag_list(fields: Iterable[str]) -> str:
    """``--epochs, --max-minutes, ...``: the command-line flags of TrainConfig ``fields``, for the errors that
    say which may be given (a boolean's flag also has its ``--no-`` form)."""
    return ", ".join("--" + f.replace("_", "-") for f in fields)


def run_id_of(cfg: TrainConfig) -> str:
    """``NAME-HASH``: the run's name and a hash of its config less what a resume may change
    (:data:`RESUME_OVERRIDES`) or what only says where it is written (``out``). So a resumed run writes what
    the uninterrupted one would, and two runs share an id only if they are the same experiment. Taken when a
    run starts; its checkpoints keep it, whatever options later versions add."""
    kept = {k: v for k, v in config_to_json(cfg).items() if k not in ("out", *RESUME_OVERRIDES)}
    digest = hashlib.sha256(json.dumps(kept, sort_keys=True).encode()).hexdigest()
    return f"{cfg.name}-{digest[:12]}"


def _check_keys(data: Any, cls: type, where: str, source: str) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise ValueError(f"{source}: {where or 'the file'} must be a JSON object, got {type(data).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown, missing = sorted(set(data) - names), sorted(names - set(data))
    if unknown or missing:
        problems = [f"unknown key(s) {[where + k for k in unknown]}"] if unknown else []
        problems += [f"missing key(s) {[where + k for k in missing]}"] if missing else []
        raise ValueError(f"{source}: {' and '.join(problems)} (a {cls.__name__} has {sorted(names)})")
    return dict(data)


ADDED_LATER = ("learn", "share", "td3", "sac", "ppo", "self_play", "league", "max_env_steps", "physics", "backend",
               "device", "eval_every", "eval_epochs", "eval_seed", "eval_target", "learner_config")
"""TrainConfig fields newer than the first run folders (several learners, self-play, an env-step
budget, evaluations while training): a config.json without them gets their defaults; any other
missing key is an error."""
LEAGUE_ADDED_LATER = ("live_share", "draw_score", "side_draw_score", "side_threshold", "keep_zoo",
                      "zoo_share")
"""LeagueConfig fields newer than the first self-play runs (both sides learning), likewise."""


def config_from_json(data: dict[str, Any], source: str = "config.json") -> TrainConfig:
    """The :class:`TrainConfig` saved as ``data``; ``ValueError`` names ``source`` and any unknown or
    missing key (a config written by another version, or edited by hand)."""
    if isinstance(data, dict):  # written before a field existed: that field's default, what the run used
        defaults = config_to_json(TrainConfig(physics=V0_PHYSICS))  # (physics came in env v0)
        data = {**{k: defaults[k] for k in ADDED_LATER if k not in data}, **data}
    data = _check_keys(data, TrainConfig, "", source)
    data["reward"] = RewardConfig(**_check_keys(data["reward"], RewardConfig, "reward.", source))
    try:
        data["physics"] = PhysicsConfig(**_check_keys(physics_record(data["physics"]), PhysicsConfig, "physics.",
                                                      source))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from exc
    for name, cls in (("ddpg", DDPGConfig), ("td3", TD3Config), ("sac", SACConfig), ("ppo", PPOConfig)):
        try:
            data[name] = cls(**_check_keys(data[name], cls, f"{name}.", source))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: {exc}") from exc
    data["policies"] = tuple(data["policies"])
    data["learn"] = tuple(data["learn"])
    if isinstance(data["league"], dict):
        league_defaults = dataclasses.asdict(LeagueConfig())
        data["league"] = {**{k: league_defaults[k] for k in LEAGUE_ADDED_LATER}, **data["league"]}
    try:
        league: dict[str, Any] = _check_keys(data["league"], LeagueConfig, "league.", source)
        data["league"] = LeagueConfig(**league)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from exc
    try:
        return TrainConfig(**data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from exc


def training_done(cfg: TrainConfig, run_dir: Path | None = None) -> bool:
    """Whether the run of ``cfg`` (in ``run_dir``, default ``OUT/NAME``) has reached its budget (``epochs``,
    or ``max_env_steps`` collected): its newest checkpoint says so, or, in a finished run whose
    checkpoints were deleted to keep it small (a run folder committed to a repository), its policy
    files do (each is written after the checkpoint it comes from, with that checkpoint's epochs and env steps)."""
    run_dir = Path(run_dir) if run_dir is not None else Path(cfg.out) / cfg.name
    saved = checkpoint.checkpoints(run_dir)
    if saved:
        epoch, folder = saved[-1]
        done: dict[str, Any] = {"epochs": epoch, "env_steps": load_json(folder / "state.json").get("env_steps", 0)}
    else:
        manifests = [load_json(p) for p in sorted(run_dir.glob("policy*.json"))] if run_dir.is_dir() else []
        if not manifests:
            return False
        done = {k: min(int(m.get(k, 0)) for m in manifests) for k in ("epochs", "env_steps")}
    if int(done["epochs"]) >= cfg.epochs:
        return True
    return cfg.max_env_steps > 0 and int(done["env_steps"]) >= cfg.max_env_steps


def command_for(cfg: TrainConfig) -> str:
    """The ``triplesumo train`` command line that makes ``cfg`` (its non-default options)."""
    from triplesumo import _dcargs

    return " ".join(shlex.quote(a) for a in ["triplesumo", "train", *_dcargs.to_argv(cfg)])


def holds_run(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds (part of) a training run."""
    run_dir = Path(run_dir)
    return (any((run_dir / name).exists() for name in RUN_FILES)
            or any(run_dir.glob("metrics-*.csv")) or any(run_dir.glob("policy-*.json")))


def refuse_existing_run(run_dir: Path, start_over: bool) -> Path | None:
    """Refuse to train afresh into a folder holding a run; with ``start_over`` move it aside.

    Returns where the old run went (``RUN.old-K``, the first free K), or None.
    """
    run_dir = Path(run_dir)
    if not holds_run(run_dir):
        return None
    if not start_over:
        raise RunExistsError(
            f"run folder {run_dir} already holds a run ({', '.join(n for n in RUN_FILES if (run_dir / n).exists())}); "
            f"nothing was changed. Continue it with `triplesumo train --resume {run_dir}` (add --epochs N for more), "
            f"or start over with the same command plus --start-over (the old run is moved to {run_dir}.old-K), "
            "or choose another --name")
    k = 1
    while (aside := run_dir.with_name(f"{run_dir.name}.old-{k}")).exists():
        k += 1
    with checkpoint.writing(aside):
        os.replace(run_dir, aside)
    print(f"start over: the earlier run in {run_dir} was moved to {aside}")
    return aside


def replay_bytes(capacity: int, obs_dim: int, act_dim: int) -> int:
    """Bytes a full replay buffer of ``capacity`` transitions takes (float32 arrays)."""
    return capacity * (2 * obs_dim + act_dim + 2) * 4


def machine_memory() -> int:
    """Physical memory plus swap of this machine, in bytes (0 if unknown)."""
    try:
        info = dict(line.split(":", 1) for line in Path("/proc/meminfo").read_text().splitlines() if ":" in line)
        return sum(int(info[k].split()[0]) * 1024 for k in ("MemTotal", "SwapTotal") if k in info)
    except (OSError, ValueError):
        try:
            return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (ValueError, OSError, AttributeError):
            return 0


def network_bytes(hidden: Sequence[int], obs_dim: int, act_dim: int, critics: int = 1) -> int:
    """Bytes an actor-critic learner's float32 networks take with their targets, gradients and Adam's two moments
    (about five copies of every parameter; ``critics`` Q networks of the same widths)."""
    def params(widths: list[int]) -> int:
        return sum((a + 1) * b for a, b in zip(widths[:-1], widths[1:], strict=True))

    actor = params([obs_dim, *hidden, 2 * act_dim])
    critic = params([obs_dim + act_dim, *hidden, 1])
    return 5 * 4 * (actor + critics * critic)


def check_memory(cfg: TrainConfig, learners: list[tuple[str, str, int, int]]) -> None:
    """``ValueError`` naming the fields if what the learners hold at once (``(learner, algo, obs_dim, act_dim)``
    each) cannot fit this machine: full replay buffers (``buffer_size``), networks (``hidden``) and PPO's
    rollouts (``n_steps`` x the matches' transitions). Checked before anything is made: a MemoryError there left
    a run folder behind."""
    own = cfg.learner_configs()
    fields: set[str] = set()
    need = 0
    for name, algo, obs, act in learners:
        c = cfg.algo_config(name)

        def field(key: str, value: Any, name: str = name, algo: str = algo) -> None:
            own_key = key in own.get(name, {})
            fields.add(f"TrainConfig.{f'learner_config {name}' if own_key else algo}.{key}={value}")

        field("hidden", list(c.hidden))
        need += network_bytes(c.hidden, obs, act, critics=1 if algo in ("ddpg", "ppo") else 2)
        if algo == "ppo":
            field("n_steps", c.n_steps)
            need += c.n_steps * cfg.n_envs * (obs + 2 * act + 8) * 4  # observations, actions, flags, values
        else:
            field("buffer_size", c.buffer_size)
            need += replay_bytes(c.buffer_size, obs, act)
    have = machine_memory()
    if have and need > have:
        raise ValueError(f"{', '.join(sorted(fields))} need {need / 2**30:.1f} GiB for {len(learners)} learner(s) "
                         f"({learners[0][2]}-value observations), more than this machine's {have / 2**30:.1f} GiB "
                         "of memory and swap; nothing was made")


HEAVY_SCHEDULE = 64
"""Gradient steps per collection step past which :func:`warn_heavy_schedule` warns."""


def warn_heavy_schedule(cfg: TrainConfig, specs: Sequence[LearnerSpec]) -> None:
    """Warn when an off-policy learner's schedule makes more than :data:`HEAVY_SCHEDULE` gradient steps per
    step of all the matches: ``learn_every`` counts transitions, so a CPU schedule (``learn_every 5``) kept
    for thousands of GPU matches makes thousands of updates per step and collects almost nothing (README
    "GPU training": ``learn_every N_ENVS``)."""
    for spec in specs:
        if spec.algo == "ppo":
            continue
        c = cfg.algo_config(spec.name)
        transitions = cfg.n_envs * len(spec.agents)
        per_step = transitions / c.learn_every * c.gradient_steps
        if per_step > HEAVY_SCHEDULE:
            warnings.warn(f"learner {spec.name}: {spec.algo}.learn_every={c.learn_every} and gradient_steps="
                          f"{c.gradient_steps} with {transitions:,} transitions per step of the {cfg.n_envs:,} "
                          f"matches make {per_step:,.0f} gradient steps per step, so the run will mostly update "
                          f"and barely collect; for G updates per step of all the matches set learn_every to "
                          f"{transitions} and gradient_steps to G (README \"GPU training\")", UserWarning,
                          stacklevel=3)


def prepare_run_dir(run_dir: Path) -> Path:
    """Create the run folder and prove it is writable now, not after hours."""
    run_dir = Path(run_dir)
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        probe = run_dir / ".write-test"
        probe.write_bytes(b"ok")
        probe.unlink()
    except OSError as exc:
        raise PermissionError(f"run folder {run_dir} is not writable: {exc.strerror or exc}") from exc
    return run_dir


class _Updates(threading.Thread):
    """Runs the off-policy updates due at one collection step (every learner's, in turn), in a
    thread beside the physics or inline."""

    def __init__(self, trainer: Trainer, due: list[tuple[OffPolicyLearner, int]]) -> None:
        super().__init__(name="offpolicy-updates", daemon=True)
        self.trainer, self.due, self.seconds = trainer, due, 0.0
        self.error: BaseException | None = None
        self._launched = False

    def start(self) -> None:
        self._launched = True
        super().start()

    def run(self) -> None:
        t = time.perf_counter()
        try:
            for learner, due in self.due:
                try:
                    learner.run_updates(due)
                except DivergedError as exc:
                    raise self.trainer.diverged(learner, str(exc)) from None
        except BaseException as exc:  # re-raised in the collecting thread by finish()
            self.error = exc
        self.seconds = time.perf_counter() - t

    def finish(self) -> None:
        if self._launched:
            self.join()
        if self.error is not None:
            raise self.error


class Trainer:
    """Trains the learners of ``cfg``; :meth:`run` until ``cfg.epochs``, ``max_env_steps``, ``max_minutes`` or
    an evaluation at ``eval_target``.

    One *epoch* is one match: it ends when the match is over or when every learning agent in
    it is out (elimination rules); each learning agent then gets one row in its metrics CSV
    (self-play with both sides learning: each agent that played it; one that sat it out has none).
    """

    def __init__(self, cfg: TrainConfig, run_dir: Path | None = None, resume: bool = False,
                 command: str | None = None, start_over: bool = False, from_checkpoint: str | None = None,
                 session_command: str | None = None) -> None:
        self.cfg = cfg
        self.resumed = resume
        """This session continues a checkpoint (a resume, or a fork's first session)."""
        self.match_cfg = scenario_config(cfg.scenario, max_steps=cfg.steps_per_epoch, obs_mode=cfg.obs_mode,
                                         reward=cfg.reward, physics=cfg.physics)
        agent_names = list(self.match_cfg.agent_names)
        self.specs = learner_specs(cfg, agent_names, {a.name: a.team for a in self.match_cfg.agents})
        self.agents = [a for spec in self.specs for a in spec.agents]
        """The learning agents, learner by learner."""
        warn_heavy_schedule(cfg, self.specs)
        pairs = expand_pairs(cfg.policies, [a for a in agent_names if a not in self.agents])
        unknown = [p.split("=")[0] for p in pairs if p.split("=")[0] not in agent_names]
        if unknown:
            raise ValueError(f"TrainConfig.policies names unknown agents {unknown}; agents are {agent_names}")
        run_dir = Path(run_dir) if run_dir else Path(cfg.out) / cfg.name
        sizing = Match(self.match_cfg)
        dims = {spec.name: self._dims(sizing, spec) for spec in self.specs}
        if not resume:
            refuse_existing_run(run_dir, start_over)
            if cfg.self_play:  # a new league copies its seeds' files into its pools (a resumed one has them)
                check_seeds(cfg.league.zoo)
        check_memory(cfg, [(spec.name, spec.algo, *dims[spec.name]) for spec in self.specs])
        self.probe = probe = sizing
        """A match of the run's config (never stepped): roster, observation and action sizes."""
        self.elimination = probe.elimination
        """Elimination rules (ffa, pursuit): an agent may leave its match before the match ends."""
        self.env = self._make_env()
        """The matches, through the batched API (arrays ``(n_envs, n_agents, ...)``, autoreset)."""
        self.device: torch.device | None = getattr(self.env, "device", None) if cfg.backend == "warp" else None
        """Where a ``warp`` run keeps observations, actions, replay and rollouts (None: numpy on the host)."""
        self.run_dir = prepare_run_dir(run_dir)
        fork = load_json(self.run_dir / FORK_FILE) if resume and (self.run_dir / FORK_FILE).is_file() else None
        self.forked_from: dict[str, Any] | None = None if fork is None else {
            "run": fork["parent"], "run_id": fork["parent_run_id"], "checkpoint": fork["checkpoint"],
            "epoch": fork["epoch"], "command": fork["parent_command"], "changes": fork["changes"]}
        """A fork's parent (``fork.json``), named in every policy manifest it writes; None for other runs."""
        self.command = command or (fork["command"] if fork is not None else command_for(cfg))
        self.session_command = session_command or self.command
        """What started this session (its leg's command): the typed command line where the CLI gives it."""
        self.legs: list[dict[str, Any]] = []
        """The run's legs (:mod:`triplesumo.train.legs`), this session's last once :meth:`run` starts."""
        self.run_id: str | None = run_id_of(cfg)
        """This run's id (:func:`run_id_of`), kept by its checkpoints: every policy file it writes (its own and
        its league snapshots, across resumes) names it, so copies of them still group by run. None for a run
        started before ids (its checkpoint has none): its files go on without one, as its first ones did."""
        torch.set_num_threads(cfg.torch_threads)
        self.pairs = pairs
        """AGENT=POLICY of every agent that does not learn (the evaluations build their own from them)."""
        try:
            self.policies = policies_from_pairs(
                pairs, cfg.seed, cfg.obs_mode, obs_dims=probe.observer.sizes,
                action_sizes=dict(zip(probe.agents, probe.action_sizes, strict=True)),
                teams={a.name: a.team for a in self.match_cfg.agents})
        except ValueError as err:
            raise ValueError(f"TrainConfig.policies (scenario {cfg.scenario!r}): {err}") from None
        self.others = [(probe.agents.index(a), p) for a, p in self.policies.items()]
        self.on_device = {i: p.on_device(self.device) for i, p in self.others
                          if self.device is not None and isinstance(p, FrozenPolicy)}
        """Roster index -> a trained fixed policy acting on the device (``warp``; others act on the host)."""
        self.learners = [make_learner(spec, [probe.agents.index(a) for a in spec.agents], position, cfg,
                                      *dims[spec.name], self.device) for position, spec in enumerate(self.specs)]
        self.rng = np.random.default_rng(cfg.seed)
        """Warm-up actions, exploration, and every match's reset seed."""
        self.env.reset_seed = lambda k: self._episode_seed()  # a finished match's next seed, in match order
        self.agent_index = [probe.agents.index(a) for a in self.agents]
        """Roster index of each learning agent."""
        self.epochs_done = 0
        self.env_steps = 0
        self.lwr: dict[str, list[float]] = {a: [] for a in self.agents}
        self.finished_epoch_steps: list[int] = []
        """Length of every epoch finished by this process (not restored on resume)."""
        self.acc: Any = self._zeros((cfg.n_envs, len(self.agents), len(ACC_KEYS)), float64=True)
        """Each match's sums of :data:`ACC_KEYS` so far, per learning agent (on the device for warp)."""
        self.final: dict[str, list[dict[str, Any] | None]] = {a: [None] * cfg.n_envs for a in self.agents}
        """The last info (outcome, step) of a learning agent already out of a match still running."""
        self.playing = np.ones((cfg.n_envs, len(self.agents)), dtype=bool)
        """Per match, per learning agent: still in play (``final`` is None)."""
        self.obs: Any = None
        """Every match's current observations ``(n_envs, n_agents, obs_dim)`` (numpy, or a device tensor)."""
        self.train_seconds = 0.0
        """Wall time of training so far, over every session of the run: collection, learning and checkpoints,
        the evaluations excluded (as of the last evaluation or checkpoint)."""
        self.evaluations = 0
        """Evaluations made so far (``eval_every``): the rows of each learner's eval CSV."""
        self._eval_seconds = 0.0
        """Wall time of the evaluations, over every session of the run."""
        self.timers = {"env": 0.0, "act": 0.0, "learn": 0.0, "wait": 0.0}
        """Seconds collecting (physics and rules), acting, learning (off-policy updates run in a
        thread: they overlap "env" when overlap_learning is on; PPO's run inline) and waiting
        for learning."""
        self.league: League | None = None
        """The self-play league (``cfg.self_play``): pools whose members take the seats that do not learn."""
        self.seat_members: list[list[str | None]] = [[None] * probe.n_agents for _ in range(cfg.n_envs)]
        """Per match, per seat: the league member playing it this match (None: a learner's or fixed seat)."""
        self.seat_policies: list[dict[int, Any]] = [{} for _ in range(cfg.n_envs)]
        self._member_policies: dict[tuple[str, str], Any] = {}
        self._seat_groups: tuple[list[tuple[int, Any, torch.Tensor]], list[tuple[int, int, Any]]] | None = None
        """warp: the seats' trained members with the matches each plays, and the random seats (None: stale)."""
        self._device_policies: dict[int, tuple[FrozenPolicy, Any]] = {}
        if cfg.self_play:
            self._setup_league(pairs, resume)
        if resume:
            self._restore(from_checkpoint)
        else:
            for k in range(cfg.n_envs):
                self._seat_opponents(k)
            self.playing = np.array([[self.final[a][k] is None for a in self.agents] for k in range(cfg.n_envs)],
                                    dtype=bool)  # False: the agent sits the match out
            self.obs = self.env.reset(seed=[self._episode_seed() for _ in range(cfg.n_envs)])[0]
            write_run_config(self.run_dir, cfg)
        self.log = MetricsLog(self.run_dir, self.agents, [s.name for s in self.specs],
                              self.epochs_done if resume else None, cfg.tensorboard,
                              {a: len(self.lwr[a]) for a in self.agents} if resume else None,
                              self.evaluations if cfg.eval_every else None)

    # ------------------------------------------------------------------ self-play
    def _setup_league(self, pairs: tuple[str, ...], resume: bool = False) -> None:
        """Sides, roles and seeds of the league (README "Self-play"); errors name the config field.

        A side is a team of the roster (paper: ``team`` = Ant and Bug, ``spider``); in a free-for-all
        (every team one agent) one side ``ffa`` whose one role takes any seat. A side learns as a
        whole or not at all; the seats of sides that do not learn are drawn from their pools, each
        pool seeded by ``league.zoo`` or else by those seats' ``policies`` (passive when not named).
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
            for side, members in sides.items():
                learning = [a for a in members if a in self.agents]
                if learning and len(learning) != len(members):
                    raise ValueError(
                        f"TrainConfig.self_play: side {side!r} has learning agents {learning} and fixed ones "
                        f"{[a for a in members if a not in learning]}; a side learns as a whole (e.g. "
                        f"--learn {' '.join(f'{a}=sac' for a in members)} --share team) or not at all")
        self.learning_sides = list(dict.fromkeys(self.side_of[a] for a in self.agents))
        """Sides whose learners learn; with several, each match is live or one plays the others' pools."""
        self.opponent_sides = list(dict.fromkeys(self.side_of[a] for a in fixed))
        if not fixed and len(self.learning_sides) < 2:
            raise ValueError(f"TrainConfig.self_play: every agent learns ({roster}) in one side; self-play draws "
                             "the seats of the agents that do not learn from pools, so leave a side out of learn")
        spec_of = dict(p.split("=", 1) for p in pairs)
        seeded = {e.split("=", 1)[0] for e in cfg.league.zoo}
        extra: list[str] = []
        for side in self.opponent_sides:
            roles = sides[side]
            if not any(r in seeded for r in roles):
                extra += [f"{r}={spec_of.get(a, 'passive')}" for r, a in
                          zip(roles, [a for a in fixed if self.side_of[a] == side], strict=False)]
        lcfg = dataclasses.replace(cfg.league, zoo=(*cfg.league.zoo, *extra))
        try:
            # (resuming: the checkpoint's league state holds the seeded members, so seeding would only rewrite them)
            self.league = League(self.run_dir, lcfg, sides, seed=int(self.rng.integers(2**31 - 1)),
                                 seed_zoo=not resume)
        except ValueError as err:
            raise ValueError(f"TrainConfig.league: {err}") from None

    def _seat_opponents(self, k: int) -> None:
        """Draw match ``k``'s opponents (at its start) from the pools of the sides that do not learn and,
        when several sides learn, of the learning sides that sit this match out (``League.draw_live``):
        their learners' rows are out of play and they get no metrics row for it."""
        league = self.league
        if league is None:
            return
        roster = self.probe.agents
        members: list[str | None] = [None] * len(roster)
        live = league.draw_live(self.learning_sides)
        for side in (*self.opponent_sides, *(s for s in self.learning_sides if s not in live)):
            seats = [i for i, a in enumerate(roster)
                     if self.side_of[a] == side and not (a in self.agents and side in live)]
            picks = league.sample(side, len(seats) if self.ffa else 1)
            for j, i in enumerate(seats):
                members[i] = picks[j if self.ffa else 0].id
        seed = int(league.rng.integers(2**31 - 1))
        self.seat_members[k] = members
        self.seat_policies[k] = self._policies_of(members, seed)
        self._seat_groups = None
        for learner in self.learners:
            plays = self._plays(learner, k)
            learner.active[learner.rows_of(k)] = plays
            for agent in learner.spec.agents:
                self.final[agent][k] = None if plays else dict(SAT_OUT)

    def _plays(self, learner: Learner, k: int) -> bool:
        """Whether ``learner`` plays match ``k`` (a league member may take its seats, see ``_seat_opponents``)."""
        return all(self.seat_members[k][i] is None for i in learner.index)

    def _policies_of(self, members: list[str | None], seed: int) -> dict[int, Any]:
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

    def _league_match(self, k: int, outcomes: np.ndarray, places: np.ndarray) -> None:
        """Rate match ``k`` (its seats' outcome codes and places; seats still in play when every learner
        is out share the best place), admit the learning sides that are due, and log the league's epoch."""
        league = self.league
        assert league is not None
        if not (outcomes == ERROR_CODE).any():
            players = [self.seat_members[k][i] or League.learner(self.side_of[a])
                       for i, a in enumerate(self.probe.agents)]
            league.record_seats(players, [float(p) if int(p) > 0 else 1.0 for p in places],
                                [a.team for a in self.match_cfg.agents])
        for side in self.learning_sides:
            if league.admit_due(side, self.epochs_done):
                league.admit(side, self.epochs_done, write=functools.partial(self._write_snapshot, side))
                self._member_policies = {key: p for key, p in self._member_policies.items()
                                         if key[0] in {m.id for pool in league.pools.values() for m in pool.members}}
                kept = {id(p) for p in self._member_policies.values()}
                self._device_policies = {key: v for key, v in self._device_policies.items() if key in kept}
        self.log.scalars(league.epoch_end(self.epochs_done), self.epochs_done)

    def _write_snapshot(self, side: str, stems: Mapping[str, Path]) -> None:
        """A learning side's snapshot: each role's policy files from the learner acting for it."""
        for role, stem in stems.items():
            agent = self.specs[0].agents[0] if self.ffa else role
            learner = next(lr for lr in self.learners if agent in lr.spec.agents)
            manifest = self.manifest(learner) | {"league_member": stem.parent.name, "side": side, "role": role}
            save_policy(stem, learner.algo.export_actor(), manifest, obs_norm=learner.algo.obs_norm)

    # ------------------------------------------------------------------ helpers
    def _dims(self, match: Match, spec: LearnerSpec) -> tuple[int, int]:
        obs = {match.observer.sizes[a] for a in spec.agents}
        act = {match.action_sizes[match.agents.index(a)] for a in spec.agents}
        if len(obs) > 1 or len(act) > 1:
            raise ValueError(f"TrainConfig.share=team: agents {list(spec.agents)} have different observation "
                             f"or action sizes ({sorted(obs)}, {sorted(act)}); they cannot share a network")
        return obs.pop(), act.pop()

    def _episode_seed(self) -> int:
        return int(self.rng.integers(2**31 - 1))

    def _make_env(self) -> Any:
        """The run's matches through the batched API (``triplesumo.vector_env``'s contract):
        :class:`VectorMatches` (``backend="cpu"``, numpy) or ``WarpMatchBatch`` (``"warp"``,
        torch tensors on the device). Errors name the option."""
        cfg = self.cfg
        if cfg.backend == "warp":
            try:
                from triplesumo.envs.warp import make_warp_vector_env
            except ImportError as exc:
                raise ImportError(f"TrainConfig.backend='warp' needs MuJoCo Warp: pip install \"triplesumo[gpu]\" "
                                  f"({exc})") from None
            try:
                return make_warp_vector_env(self.match_cfg, cfg.n_envs, cfg.device)
            except (NotImplementedError, ValueError) as exc:
                raise ValueError(f"TrainConfig.backend='warp' (scenario {cfg.scenario!r}, device {cfg.device!r}): "
                                 f"{exc}") from None
        try:
            return VectorMatches(cfg.n_envs, self.match_cfg, cfg.n_threads)
        except ValueError as exc:
            raise ValueError(f"TrainConfig (scenario {cfg.scenario!r}, obs_mode {cfg.obs_mode!r}): {exc}") from None

    def _zeros(self, shape: tuple[int, ...], float64: bool = False) -> Any:
        """Zeros where the run's arrays live: numpy float64 on ``cpu``, a float32 (or float64) tensor on the device."""
        if self.device is None:
            return np.zeros(shape)
        return torch.zeros(shape, dtype=torch.float64 if float64 else torch.float32, device=self.device)

    @staticmethod
    def _host(x: Any) -> np.ndarray:
        """``x`` as a numpy array (a device tensor is copied to the host)."""
        return x.cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)

    def _rows(self, learner: Learner) -> Any:
        """The learner's observations, ``(n_envs x len(agents), obs_dim)``, match-major."""
        return self.obs[:, learner.index].reshape(-1, learner.obs_dim)

    @property
    def batch(self) -> MatchBatch:
        """The matches of a ``cpu`` run (``VectorMatches.batch``), e.g. for a scenario test placing an
        agent by hand (then ``batch.reload(k)``); a ``warp`` run has none."""
        if not isinstance(self.env, VectorMatches):
            raise AttributeError("a backend='warp' run has no MatchBatch (its matches live on the device)")
        return self.env.batch

    @property
    def updates(self) -> int:
        return sum(learner.algo.num_updates for learner in self.learners)

    # -------------------------------------------------------------------- loop
    def collect_step(self) -> int:
        """Step every match once; returns the number of epochs that finished."""
        cfg, n, probe = self.cfg, self.cfg.n_envs, self.probe
        t0 = time.perf_counter()
        actions = self._zeros((n, probe.n_agents, probe.action_width))
        seen, acted = [], []
        for learner in self.learners:
            obs = self._rows(learner)
            try:
                act = learner.act(obs, self.rng)
            except DivergedError as exc:
                raise self.diverged(learner, str(exc)) from None
            actions[:, learner.index, :learner.act_dim] = act.reshape(n, len(learner.index), learner.act_dim)
            seen.append(obs)
            acted.append(act)
        for i, policy in self.others:
            if self.league is not None or (self.device is not None and isinstance(policy, ZeroPolicy)):
                continue
            if i in self.on_device:
                actions[:, i, :probe.action_sizes[i]] = self.on_device[i](self.obs[:, i])
            elif self.device is None:
                actions[:, i, :probe.action_sizes[i]] = act_batch(policy, self.obs[:, i])
            else:  # warp: drawn on the host from the policy's own generator (its cpu stream), one copy
                fixed = policy.sample(n) if isinstance(policy, RandomPolicy) else act_batch(
                    policy, self._host(self.obs[:, i]))
                actions[:, i, :probe.action_sizes[i]] = torch.as_tensor(fixed, dtype=torch.float32,
                                                                        device=self.device)
        if self.device is None:
            for k, seated in enumerate(self.seat_policies):
                for i, policy in seated.items():
                    actions[k, i, :probe.action_sizes[i]] = act_batch(policy, self.obs[k, i][None])[0]
        elif self.league is not None:
            self._seat_actions_on_device(actions)
        t1 = time.perf_counter()
        # The off-policy updates due at this step learn from the replay as it was before the
        # step, so they can run while MuJoCo steps the matches (GIL released in mujoco.batch and
        # in torch's kernels). Overlapped or not, the result is bit for bit the same.
        due = [(lr, d) for lr in self.learners if isinstance(lr, OffPolicyLearner) and (d := lr.updates_due())]
        updates = _Updates(self, due)
        if due and cfg.overlap_learning:
            updates.start()
        elif due:
            updates.run()
        obs, _, terminated, truncated, infos = self.env.step(actions)  # finished matches are already reset
        t2 = time.perf_counter()
        updates.finish()
        t_joined = time.perf_counter()
        self.env_steps += n  # counted before epochs end, so their rows include this step
        where = np.where if self.device is None else torch.where
        done = infos["_final_obs"]
        next_obs = where(done[:, None, None], infos["final_obs"], obs)  # a finished match's last observation
        reward = infos["dense_reward"] + infos["sparse_reward"]
        error = infos["outcome"] == ERROR_CODE
        for learner, seen_obs, act in zip(self.learners, seen, acted, strict=True):
            self._store(learner, seen_obs, act, next_obs, reward, terminated, truncated, error)
        finished = self._account(obs, terminated, infos)
        t3 = time.perf_counter()
        for learner in self.learners:
            if isinstance(learner, PPOLearner):
                try:
                    learner.update_if_full(self._rows(learner))
                except DivergedError as exc:
                    raise self.diverged(learner, str(exc)) from None
        learned = time.perf_counter() - t3
        self.timers["act"] += t1 - t0
        self.timers["env"] += (t2 - t1) + (t3 - t_joined)
        self.timers["learn"] += updates.seconds + learned  # the thread's part overlaps "env"
        self.timers["wait"] += t_joined - t2
        return finished

    def _seat_actions_on_device(self, actions: torch.Tensor) -> None:
        """The league members' actions of a ``warp`` run: each trained member acts once per seat on the
        observations of all the matches it plays there (``FrozenPolicy.on_device``); passive members
        leave their zeros; random ones draw on the host from their own generators (as on ``cpu``), one
        copy to the device for all of them."""
        if self._seat_groups is None:  # recomputed only when seats change (a match start, a resume)
            groups: dict[tuple[int, int], tuple[Any, list[int]]] = {}
            host: list[tuple[int, int, Any]] = []
            for k, seated in enumerate(self.seat_policies):
                for i, policy in seated.items():
                    if isinstance(policy, FrozenPolicy):
                        groups.setdefault((i, id(policy)), (policy, []))[1].append(k)
                    elif not isinstance(policy, ZeroPolicy):
                        host.append((k, i, policy))
            self._seat_groups = ([(i, self._device_policy(p), torch.as_tensor(ks, device=self.device))
                                  for (i, _), (p, ks) in groups.items()], host)
        trained, host = self._seat_groups
        sizes = self.probe.action_sizes
        for i, act, rows in trained:
            actions[rows, i, :sizes[i]] = act(self.obs[rows, i])
        if host:  # one copy to the device for all of them (and one of the observations only if one needs it)
            ks, seats = (torch.as_tensor(v, device=self.device) for v in zip(*[(k, i) for k, i, _ in host],
                                                                             strict=True))
            seen = None if all(isinstance(p, RandomPolicy) for *_, p in host) else self._host(self.obs[ks, seats])
            drawn = np.zeros((len(host), actions.shape[-1]), dtype=np.float32)
            for r, (_, i, policy) in enumerate(host):
                drawn[r, :sizes[i]] = policy.sample(1)[0] if seen is None else policy(seen[r])
            actions[ks, seats] = torch.as_tensor(drawn, device=self.device)

    def _device_policy(self, policy: FrozenPolicy) -> Any:
        """``policy.on_device`` (made once per member policy; dropped with the member)."""
        key = id(policy)
        if key not in self._device_policies:
            self._device_policies[key] = (policy, policy.on_device(self.device))
        return self._device_policies[key][1]

    def _store(self, learner: Learner, obs: Any, act: Any, next_obs: Any, reward: Any, terminated: Any,
               truncated: Any, error: Any) -> None:
        """Hand the learner its rows' step (``(n_envs, n_agents, ...)`` arrays of the whole batch):
        rewards, next observations, ends, which rows played."""
        idx = learner.index
        rew = reward[:, idx].reshape(-1)
        nxt = next_obs[:, idx].reshape(-1, learner.obs_dim)
        term = terminated[:, idx].reshape(-1)  # the match was won or lost, or the agent left it
        trunc = truncated[:, idx].reshape(-1) & ~term  # a draw by time limit bootstraps
        valid = ~error[:, idx].reshape(-1)  # a physics error's transition is never learned from
        active = learner.active
        if not active.all():  # rows out of play (elimination rules, or sat out in self-play): nothing
            on: Any = active if self.device is None else torch.as_tensor(active, device=self.device)
            where: Any = np.where if self.device is None else torch.where
            rew, term, trunc = where(on, rew, 0.0), term & on, trunc & on
            valid, nxt = valid | ~on, where(on[:, None], nxt, obs)
        learner.store(obs, act, rew, nxt, term, trunc, valid, active.copy())
        if self.elimination:  # an agent that left stays out until its match is reset
            learner.active &= ~term

    def _account(self, obs: Any, terminated: Any, infos: Mapping[str, Any]) -> int:
        """Add the step to every learning agent's sums; end the epoch of each match that is over
        (already reset by the env) or whose learning agents are all out (reset here). Returns how
        many epochs ended."""
        terms: Any
        if self.device is None:
            terms = np.stack([infos[key][:, self.agent_index] for key in ACC_KEYS], axis=-1)
        else:
            terms = torch.stack([infos[key][:, self.agent_index] for key in ACC_KEYS], dim=-1).double()
        if self.playing.all():
            self.acc += terms
        elif self.device is None:  # an agent out of a match still running adds nothing more to its epoch
            self.acc += np.where(self.playing[..., None], terms, 0.0)
        else:  # (or one sitting it out, self-play)
            self.acc += torch.where(torch.as_tensor(self.playing[..., None], device=self.device), terms, 0.0)
        self.obs = obs
        done = self._host(infos["_final_obs"])
        out = self._host(terminated[:, self.agent_index]) if self.elimination else None
        events = done | out.any(-1) if out is not None else done
        rows = np.flatnonzero(events)
        if not len(rows):
            return 0
        sel: Any = rows if self.device is None else torch.as_tensor(rows, device=self.device)
        outcome, steps = self._host(infos["outcome"][sel]), self._host(infos["step"][sel])
        places = self._host(infos["place"][sel]) if self.league is not None else None
        sums = self._host(self.acc[sel])
        ended = []
        for r, k in enumerate(rows.tolist()):
            if out is not None:
                for j, agent in enumerate(self.agents):
                    if self.final[agent][k] is None and out[k, j]:  # left the match: its epoch waits for the match
                        code = outcome[r, self.agent_index[j]]
                        self.final[agent][k] = {"outcome": _name(code), "step": int(steps[r])}
                        self.playing[k, j] = False
            over = bool(done[k])
            if not over and any(self.final[a][k] is None for a in self.agents):
                continue
            self.epochs_done += 1
            for j, agent in enumerate(self.agents):
                code = outcome[r, self.agent_index[j]]
                last = self.final[agent][k] or {"outcome": _name(code), "step": int(steps[r])}
                if "sat_out" not in last:  # a learner that sat the match out (self-play) has no row for it
                    self._agent_row(agent, last, sums[r, j])
                self.final[agent][k] = None
            self.finished_epoch_steps.append(int(steps[r]))
            for learner in self.learners:
                self.log.learned(learner.name, self.epochs_done, learner.algo.num_updates, learner.take_stats())
            if self.league is not None:
                assert places is not None
                self._league_match(k, outcome[r], places[r])
                self._seat_opponents(k)
            if not over:  # every learning agent is out: the epoch ends before the match does
                self.obs[k] = self.env.restart(k, self._episode_seed())
            for learner in self.learners:
                lrows = learner.rows_of(k)
                learner.active[lrows] = self._plays(learner, k) if self.league is not None else True
                learner.reset_rows(lrows)
            self.playing[k] = [self.final[a][k] is None for a in self.agents]  # False: sits this match out
            ended.append(k)
        if ended:
            self.acc[ended if self.device is None else torch.as_tensor(ended, device=self.device)] = 0.0
        return len(ended)

    def _agent_row(self, agent: str, last: dict[str, Any], acc: np.ndarray) -> None:
        sums = dict(zip(ACC_KEYS, acc.tolist(), strict=True))
        lwr = float(local_winning_rate([last["outcome"]])[0])
        self.lwr[agent].append(lwr)
        total = sums["dense_reward"] + sums["sparse_reward"]
        row = {"epoch": len(self.lwr[agent]), "outcome": last["outcome"], "local_winning_rate": lwr,
               "steps": last["step"], "total_reward": total, **sums, "env_steps": self.env_steps,
               "wall_time": round(time.time(), 3)}  # epoch: the agent's own matches (= the run's, unless it sat out)
        self.log.epoch(agent, row, self.mwr(agent))

    def mwr(self, agent: str | None = None) -> float:
        """MWR of ``agent`` (default: the first learning agent) over the last λ epochs (mean
        over what exists for the first λ-1)."""
        lwr = self.lwr[agent or self.agents[0]]
        if not lwr:
            return 0.0
        return float(moving_winning_rate(np.array(lwr[-self.cfg.window:]), self.cfg.window)[-1])

    def last_good(self) -> str:
        """Where the run can go on from: its latest checkpoint, in words."""
        try:
            folder = checkpoint.latest(self.run_dir)
        except checkpoint.CheckpointError:
            return "no checkpoint was saved before it (no good one exists)"
        return (f"the last good checkpoint {folder} is intact; "
                f"`triplesumo train --resume {self.run_dir}` continues from it")

    def diverged(self, learner: Learner, what: str) -> DivergenceError:
        """The error that stops a diverging learner: names it, its update count and the last good checkpoint."""
        algo = learner.spec.algo
        rates = "--ppo.lr" if algo == "ppo" else f"--{algo}.actor-lr, --{algo}.critic-lr"
        return DivergenceError(f"learner {learner.name!r} diverged at update {learner.algo.num_updates} "
                               f"(epoch {self.epochs_done}, env step {self.env_steps}, {algo}): {what}. Stopped; "
                               f"{self.last_good()}. Lower the learning rates ({rates}) or the reward scale")

    def start_leg(self) -> dict[str, Any]:
        """Append this session's leg to ``RUN/legs.json`` (cutting the legs of epochs trained again) and
        return it: ``start`` for a new run, ``fork`` for a fork continued from its fork epoch, else ``resume``."""
        kind = "start"
        if self.resumed:
            at_fork = self.forked_from is not None and self.epochs_done == int(self.forked_from["epoch"])
            kind = "fork" if at_fork else "resume"
        cfg = self.cfg
        leg = make_leg(kind, self.epochs_done, self.env_steps, self.run_id,
                       {"epochs": cfg.epochs, "max_minutes": cfg.max_minutes, "max_env_steps": cfg.max_env_steps},
                       self.session_command)
        self.legs = [*legs_before(read_legs(self.run_dir), self.epochs_done), leg]
        with checkpoint.writing(self.run_dir / LEGS_FILE):
            write_legs(self.run_dir, self.legs)
        return leg

    def run(self) -> TrainResult:
        cfg = self.cfg
        self.start_leg()
        start = time.perf_counter()
        start_steps = self.env_steps
        trained_before, evals_before = self.train_seconds, self._eval_seconds

        def clock() -> None:  # the training's own wall time so far (the evaluations apart)
            self.train_seconds = trained_before + time.perf_counter() - start - (self._eval_seconds - evals_before)

        bar = None
        if cfg.progress:
            from tqdm import tqdm

            bar = tqdm(total=cfg.epochs, initial=min(self.epochs_done, cfg.epochs), unit="epoch",
                       desc=f"train {' '.join(s.name for s in self.specs)}", dynamic_ncols=True)
        try:
            while self.epochs_done < cfg.epochs:
                before, steps_before = self.epochs_done, self.env_steps
                finished = self.collect_step()
                reached = False
                if cfg.eval_every and self.env_steps // cfg.eval_every > steps_before // cfg.eval_every:
                    clock()
                    reached = self.evaluate()
                if finished and bar is not None:
                    bar.update(min(self.epochs_done, cfg.epochs) - min(before, cfg.epochs))
                    rate = (self.env_steps - start_steps) / max(time.perf_counter() - start, 1e-9)
                    mwrs = {f"MWR {a}" if len(self.agents) > 1 else "MWR": f"{self.mwr(a):+.3f}" for a in self.agents}
                    bar.set_postfix(mwrs | {"steps_s": f"{rate:.0f}"}, refresh=False)
                crossed = finished and (self.epochs_done // cfg.checkpoint_every > before // cfg.checkpoint_every)
                timed_out = ((cfg.max_minutes > 0 and (time.perf_counter() - start) > cfg.max_minutes * 60)
                             or 0 < cfg.max_env_steps <= self.env_steps)
                if crossed or (timed_out and finished) or reached or self.epochs_done >= cfg.epochs:
                    clock()
                    self.save()
                if (timed_out and finished) or reached:
                    break
        except checkpoint.CheckpointWriteError as exc:
            if "last good checkpoint" in str(exc) or "no earlier checkpoint" in str(exc):
                raise
            raise checkpoint.CheckpointWriteError(exc.errno, f"{exc.strerror}; {self.last_good()}") from exc
        finally:
            if bar is not None:
                bar.close()
            self.log.close()
        self.finish_outputs()
        return TrainResult(self.run_dir, self.epochs_done, self.env_steps, self.updates, self.mwr(),
                           time.perf_counter() - start, dict(self.timers), {a: self.mwr(a) for a in self.agents})

    def evaluate(self) -> bool:
        """Each learner's current policy, frozen (no exploration), on the run's seeded test matches
        (``eval_epochs`` from ``eval_seed``, on the CPU): a row of its eval CSV. True when every
        learner's test MWR reached ``eval_target``.

        The other agents play the run's fixed policies, built afresh from ``eval_seed`` (so every
        evaluation meets the same matches), and the other learners their current policies, frozen;
        a learner that plays several agents (``share="team"``) is rated in its first agent's seat.
        Nothing of the training is touched: it trains the same with or without evaluations."""
        from triplesumo.evaluation.evaluate import play_test_epochs
        from triplesumo.evaluation.metrics import summarize

        cfg, probe = self.cfg, self.probe
        t0 = time.perf_counter()
        fixed = policies_from_pairs(self.pairs, cfg.eval_seed, cfg.obs_mode, obs_dims=probe.observer.sizes,
                                    action_sizes=dict(zip(probe.agents, probe.action_sizes, strict=True)))
        frozen: dict[str, FrozenPolicy] = {}
        for learner in self.learners:
            policy = frozen_copy(learner)
            frozen |= {agent: policy for agent in learner.spec.agents}
        self.evaluations += 1
        done: list[tuple[str, Any]] = []
        for learner in self.learners:
            agent = learner.spec.agents[0]
            others = {**fixed, **{a: p for a, p in frozen.items() if a != agent}}
            rows = play_test_epochs(frozen[agent], others, agent, cfg.eval_epochs, cfg.eval_seed, self.match_cfg,
                                    cfg.n_envs, cfg.n_threads)
            done.append((learner.name, summarize([r["outcome"] for r in rows], [r["steps"] for r in rows])))
        self._eval_seconds += time.perf_counter() - t0
        for name, stats in done:
            self.log.evaluated(name, {
                "evaluation": self.evaluations, "env_steps": self.env_steps, "epochs": self.epochs_done,
                "train_seconds": round(self.train_seconds, 3), "eval_seconds": round(self._eval_seconds, 3),
                "test_matches": cfg.eval_epochs, "test_mwr": float(stats["mean_lwr"]),
                "test_mwr_lo": float(stats["mean_lwr_lo"]), "test_mwr_hi": float(stats["mean_lwr_hi"]),
                "n_win": stats["n_win"], "n_loss": stats["n_loss"], "n_draw": stats["n_draw"]})
            if cfg.progress:
                print(f"  evaluation {self.evaluations} at {self.env_steps:,} env steps: {name} test MWR "
                      f"{float(stats['mean_lwr']):+.3f} [{float(stats['mean_lwr_lo']):+.3f}, "
                      f"{float(stats['mean_lwr_hi']):+.3f}] over {cfg.eval_epochs} matches")
        return cfg.eval_target is not None and all(float(stats["mean_lwr"]) >= cfg.eval_target for _, stats in done)

    # ---------------------------------------------------------- checkpoints
    def policy_stem(self, learner: Learner) -> Path:
        """``RUN/policy`` (one learning agent) or ``RUN/policy-<learner>``."""
        return self.run_dir / run_file("policy", learner.name, self.log.several)

    def manifest(self, learner: Learner) -> dict[str, Any]:
        probe = self.probe
        spec = {a.name: a for a in self.match_cfg.agents}[learner.spec.agents[0]]
        return {
            "agent": learner.name, "algo": learner.spec.algo, "plays": list(learner.spec.agents),
            "learners": {s.name: s.algo for s in self.specs}, "obs_mode": self.cfg.obs_mode,
            "action_scaling": f"normalised [-1, 1] scaled linearly to ctrl [-{spec.ctrl_range}, {spec.ctrl_range}]",
            "ctrl_range": spec.ctrl_range, "env_version": ENV_VERSION, "triplesumo_version": __version__,
            "mujoco_version": mujoco.__version__, "torch_version": torch.__version__,
            "seed": self.cfg.seed, "epochs": self.epochs_done, "env_steps": self.env_steps,
            "updates": learner.algo.num_updates, "command": self.command,
            **({"run_id": self.run_id} if self.run_id else {}),
            **({"forked_from": self.forked_from} if self.forked_from else {}),
            "legs": self.legs,  # which code trained which epochs, session by session
            # self-play: the seeds of the opponent pools (league.zoo, else the seats' policies)
            "trained_against": list(self.league.config.zoo if self.league is not None else self.cfg.policies),
            "agents": list(probe.agents), "scenario": self.cfg.scenario,
            "partners": len(probe.teams.partners[probe.agents.index(spec.name)]),
            "physics": dataclasses.asdict(self.cfg.physics),  # the simulation (e.g. the paper's solid rim)
        }

    def save(self) -> Path:
        self.log.flush()
        tensors: dict[str, torch.Tensor] = {}
        arrays: dict[str, np.ndarray] = {}
        replay: dict[str, np.ndarray] = {}
        for learner in self.learners:
            tensors |= {f"{learner.name}.{k}": v for k, v in learner.tensors().items()}
            arrays |= {f"{learner.name}.{k}": v for k, v in learner.arrays().items()}
            if isinstance(learner, OffPolicyLearner):
                replay |= {f"{learner.name}.{k}": v for k, v in learner.replay.state_dict().items()}
        # every match's exact state (either backend): its arrays here, the rest in state.json's "matches"
        snaps = self.env.snapshot()
        obs = self._host(self.obs)
        for k, s in enumerate(snaps):
            arrays |= {f"match{k}.{key}": v for key, v in s.items() if isinstance(v, np.ndarray)}
            arrays[f"match{k}.obs"] = np.array(obs[k])
        acc = self._host(self.acc).tolist()
        for agent, lwr in self.lwr.items():
            arrays[f"lwr.{agent}"] = np.array(lwr)
        state = {
            "config": config_to_json(self.cfg), "manifests": {lr.name: self.manifest(lr) for lr in self.learners},
            "epochs_done": self.epochs_done, "env_steps": self.env_steps, "rng": self.rng.bit_generator.state,
            "run_id": self.run_id, "learners": {lr.name: lr.state() for lr in self.learners},
            "matches": [{key: v for key, v in s.items() if not isinstance(v, np.ndarray)}
                        for s in snaps],  # steps, generator, who is still in play (elimination rules)
            "acc": {agent: [dict(zip(ACC_KEYS, per_match[j], strict=True)) for per_match in acc]
                    for j, agent in enumerate(self.agents)},
            "final": self.final, "timers": self.timers, "train_seconds": self.train_seconds,
            "evaluations": self.evaluations, "eval_seconds": self._eval_seconds,
            "policy_rngs": {a: p.rng.bit_generator.state for a, p in self.policies.items() if hasattr(p, "rng")},
        }
        if self.league is not None:
            self.league.save()
            state["league"] = self.league.state_dict()
            state["seats"] = self.seat_members
            state["seat_rngs"] = [{str(i): p.rng.bit_generator.state for i, p in seated.items() if hasattr(p, "rng")}
                                  for seated in self.seat_policies]
        keep_replay = self.cfg.save_replay and bool(replay)
        folder = checkpoint.save(self.run_dir, self.epochs_done, tensors, state, arrays,
                                 replay if keep_replay else None)
        for learner in self.learners:
            stem = self.policy_stem(learner)
            with checkpoint.writing(f"{stem}.safetensors/.json", f"; the last good checkpoint {folder} is intact"):
                save_policy(stem, learner.algo.export_actor(), self.manifest(learner), obs_norm=learner.algo.obs_norm)
        return folder

    def _needs_replay(self) -> bool:
        return self.cfg.save_replay and any(isinstance(lr, OffPolicyLearner) for lr in self.learners)

    def _checkpoint_within_rows(self, folder: Path) -> Path:
        """``folder`` (the latest checkpoint), or, where a kill tore the run's last rows at or before its epoch,
        the newest checkpoint that the intact rows reach (the rows after it are cut and its epochs trained
        again, as the torn-row repair promises); ``CheckpointError`` names ``--start-over`` when none does.
        Self-play runs, whose agents may sit matches out, keep the check of their own tables."""
        epoch = checkpoint.recorded_epoch(folder)
        if self.league is not None or epoch is None:
            return folder
        learners = [s.name for s in self.specs]
        several = len(self.agents) > 1 or len(learners) > 1 or self.agents != learners
        tables: list[tuple[Path, tuple[str, ...], Callable[[list[str], int], str | None] | None]] = [
            (self.run_dir / run_file("metrics", a, several, ".csv"), COLUMNS, None) for a in self.agents]
        tables += [(self.run_dir / run_file("learning", n, several, ".csv"), LEARNING_COLUMNS, learning_row_problem)
                   for n in learners]
        rows = min(intact_rows(path, columns, problem) for path, columns, problem in tables if path.exists())
        if rows >= epoch:
            return folder
        fits = [(e, f) for e, f in checkpoint.checkpoints(self.run_dir) if e <= rows]
        if not fits:
            raise checkpoint.CheckpointError(
                f"{self.run_dir}: its tables hold the rows of epochs 1..{rows} only (a kill tore the rest), but every "
                f"checkpoint is later (the newest at epoch {epoch}): nothing to resume from; `triplesumo train "
                f"--resume {self.run_dir} --start-over` trains it again from the start")
        e, chosen = fits[-1]
        print(f"resume: the run's tables hold epochs 1..{rows} (a kill tore the rest) and the latest checkpoint is "
              f"at epoch {epoch}; resuming from {chosen.name} (epoch {e}), the newest within them")
        return chosen

    def _restore(self, from_checkpoint: str | None) -> None:
        need_replay = self._needs_replay()
        if from_checkpoint is not None:
            folder = checkpoint.find(self.run_dir, from_checkpoint)
            loaded = checkpoint.load(folder, need_replay=need_replay)
        else:
            try:
                folder = self._checkpoint_within_rows(checkpoint.latest(self.run_dir))
                loaded = checkpoint.load(folder, need_replay=need_replay)
            except checkpoint.CheckpointError as exc:
                intact = checkpoint.newest_intact(self.run_dir)
                if intact is None:
                    raise
                raise checkpoint.CheckpointError(
                    f"{exc} -- the latest checkpoint is damaged or missing; the newest intact one is {intact.name} "
                    f"(epoch {checkpoint.recorded_epoch(intact)}): `triplesumo train --resume {self.run_dir} "
                    f"--from {intact.name}` continues from it (later epochs are trained again)") from exc
        tensors, state, arrays, lazy_replay = loaded
        replay: Mapping[str, np.ndarray] | None = lazy_replay
        if "learners" not in state and "optimizer" in state:
            tensors, state, arrays, replay = self._one_learner_checkpoint(tensors, state, arrays, replay)
        need_state: tuple[str, ...] = ("config", "learners", "rng", "matches", "epochs_done", "env_steps", "acc",
                                       "final")
        need_state += ("league", "seats", "seat_rngs") if self.league is not None else ()
        missing = [k for k in need_state if k not in state]
        if missing:
            raise checkpoint.CheckpointError(f"{folder / 'state.json'}: missing entries {missing}")
        try:
            saved = config_from_json(state["config"], f"{folder / 'state.json'} (its config)")
        except ValueError as exc:
            raise checkpoint.CheckpointError(str(exc)) from exc
        for name in ("learner", "learn", "share", "scenario", "obs_mode", "n_envs", "steps_per_epoch", "policies",
                     "reward", "ddpg", "td3", "sac", "ppo", "learner_config", "seed", "self_play", "league", "backend"):
            # (save_replay may differ: resuming without the replay buffer is allowed, not exact)
            if getattr(saved, name) != getattr(self.cfg, name):
                raise checkpoint.CheckpointError(
                    f"{folder / 'state.json'}: incompatible checkpoint: it was made with {name}="
                    f"{getattr(saved, name)!r}, this run has {getattr(self.cfg, name)!r} (from config.json)")
        need_arrays = [f"lwr.{a}" for a in self.agents] + [f"{lr.name}.active" for lr in self.learners] + [
            f"match{k}.{part}" for k in range(self.cfg.n_envs) for part in self._match_parts(arrays)]
        missing = [k for k in need_arrays if k not in arrays]
        if missing:
            raise checkpoint.CheckpointError(f"{folder / 'arrays.npz'}: missing arrays {missing[:5]}")
        try:
            self._restore_from(tensors, state, arrays, replay)
        except (KeyError, IndexError, TypeError, ValueError, RuntimeError) as exc:
            if isinstance(exc, checkpoint.CheckpointError):
                raise
            where = "replay.npz" if replay is not None and "replay arrays" in str(exc) else (
                "state.json / arrays.npz / replay.npz / weights.safetensors")
            raise checkpoint.CheckpointError(f"{folder} ({where}): missing or malformed entry: {exc!r}") from exc

    def _match_parts(self, arrays: Mapping[str, np.ndarray]) -> tuple[str, ...]:
        """The arrays of each match (``match<k>.<part>``) a checkpoint of this backend holds: cpu every
        ``Match.snapshot`` array; warp the world's state, or none in a checkpoint written before warp
        resumed exactly (its matches then restart)."""
        if self.device is None:
            return ("physics", "last_obs", "warnings", "obs")
        return ("physics", "obs") if "match0.physics" in arrays else ()

    def _one_learner_checkpoint(self, tensors: dict[str, torch.Tensor], state: dict[str, Any],
                                arrays: dict[str, np.ndarray], replay: Mapping[str, np.ndarray] | None) -> tuple[
            dict[str, torch.Tensor], dict[str, Any], dict[str, np.ndarray], Mapping[str, np.ndarray] | None]:
        """A checkpoint of the one-DDPG-learner trainer (before several learners) in today's layout."""
        name = self.learners[0].name
        upgraded = {**state, "acc": {name: state["acc"]}, "final": {name: [None] * self.cfg.n_envs},
                    "learners": {name: {"optimizer": state["optimizer"], "sample_rng": state["sample_rng"],
                                        "collected": state["env_steps"], "stats": [{}, {}]}}}
        moved = {f"{name}.{k}" if k.startswith("noise.") else k: v for k, v in arrays.items() if k != "lwr"}
        moved |= {f"lwr.{name}": arrays["lwr"], f"{name}.active": np.ones(self.cfg.n_envs, dtype=bool)}
        if replay is not None:
            replay = _Prefixed(replay, f"{name}.")
        return {f"{name}.{k}": v for k, v in tensors.items()}, upgraded, moved, replay

    def _restore_from(self, tensors: dict[str, torch.Tensor], state: dict[str, Any],
                      arrays: dict[str, np.ndarray], replay: Mapping[str, np.ndarray] | None) -> None:
        for learner in self.learners:
            prefix = f"{learner.name}."
            learner.load({k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)},
                         state["learners"][learner.name],
                         {k.removeprefix(prefix): v for k, v in arrays.items() if k.startswith(prefix)})
            if replay is not None and isinstance(learner, OffPolicyLearner):
                learner.load_replay(replay, prefix)
        self.rng.bit_generator.state = state["rng"]
        n, parts = self.cfg.n_envs, self._match_parts(arrays)
        if parts:  # every match continues exactly where it was
            obs = np.stack([np.asarray(arrays[f"match{k}.obs"], dtype=np.float32) for k in range(n)])
            self.obs = obs if self.device is None else torch.as_tensor(obs, device=self.device)
            self.env.restore([{part: arrays[f"match{k}.{part}"] for part in parts if part != "obs"}
                              | state["matches"][k] for k in range(n)], self.obs)
            self.final = {a: state["final"][a] for a in self.agents}
            acc = np.array([[[state["acc"][a][k][key] for key in ACC_KEYS] for a in self.agents]
                            for k in range(n)], dtype=np.float64)
            self.acc = acc if self.device is None else torch.as_tensor(acc, device=self.device)
        else:  # a warp checkpoint of before exact warp resume: the unfinished matches restart (epochs dropped)
            self.obs = self.env.reset(seed=[self._episode_seed() for _ in range(n)])[0]
            for learner in self.learners:
                learner.active[:] = True
        self.playing = np.array([[self.final[a][k] is None for a in self.agents] for k in range(n)], dtype=bool)
        for agent, rng_state in state.get("policy_rngs", {}).items():
            self.policies[agent].rng.bit_generator.state = rng_state
        self.epochs_done = int(state["epochs_done"])
        self.env_steps = int(state["env_steps"])
        self.run_id = state.get("run_id")
        self.lwr = {a: [float(x) for x in arrays[f"lwr.{a}"]] for a in self.agents}
        self.timers = {**self.timers, **state.get("timers", {})}
        # (0 in a checkpoint written before the trainer counted them)
        self.train_seconds = float(state.get("train_seconds", 0.0))
        self.evaluations = int(state.get("evaluations", 0))
        self._eval_seconds = float(state.get("eval_seconds", 0.0))
        if self.league is not None:
            self.league.load_state_dict(state["league"])
            self.league.truncate_log(self.epochs_done)
            self.seat_members = [list(m) for m in state["seats"]]
            for k, members in enumerate(self.seat_members):
                self.seat_policies[k] = self._policies_of(members, 0)
                for i, rng_state in state["seat_rngs"][k].items():
                    self.seat_policies[k][int(i)].rng.bit_generator.state = rng_state
            self._seat_groups = None

    def finish_outputs(self) -> None:
        """Plots from the metrics CSVs (skipped for an agent without a finished epoch)."""
        plot_metrics(self.run_dir, self.cfg.window)


def frozen_copy(learner: Learner) -> FrozenPolicy:
    """The learner's current deterministic policy as a numpy :class:`FrozenPolicy` (with its observation
    normaliser, frozen), what its policy file would hold now."""
    tensors = {f"actor.{k}": v.detach().cpu().numpy() for k, v in learner.algo.export_actor().state_dict().items()}
    norm = learner.algo.obs_norm
    if norm is not None:
        tensors |= {f"obs_norm.{k}": v.detach().cpu().numpy() for k, v in norm.state_dict().items()}
    return FrozenPolicy.from_tensors(tensors, prefix="actor.", obs_norm_prefix=None if norm is None else "obs_norm.")


class _Prefixed(Mapping[str, np.ndarray]):
    """``mapping`` with every key prefixed (members still read lazily, one at a time)."""

    def __init__(self, mapping: Mapping[str, np.ndarray], prefix: str) -> None:
        self.mapping, self.prefix = mapping, prefix

    def __getitem__(self, key: str) -> np.ndarray:
        if not key.startswith(self.prefix):
            raise KeyError(key)
        return self.mapping[key.removeprefix(self.prefix)]

    def __iter__(self) -> Iterator[str]:
        return (self.prefix + k for k in self.mapping)

    def __len__(self) -> int:
        return len(self.mapping)


ACC_KEYS = ("dense_reward", "sparse_reward", *TERMS)
"""What a learning agent's epoch sums (its metrics row's reward columns), in the order of ``state.json``'s ``acc``."""


def _name(code: int) -> str:
    """An outcome code as the metrics' name (win, loss, draw, error; "" while the match goes on)."""
    return "" if int(code) == PLAYING else code_name(int(code))


def plot_metrics(run_dir: Path, window: int) -> list[Path]:
    """The paper's figures of every learning agent of a run: ``metrics.csv`` -> ``plots/``,
    ``metrics-<agent>.csv`` -> ``plots/<agent>/`` (agents without a finished epoch are skipped)."""
    from triplesumo.evaluation.plots import plot_run, read_metrics_csv

    run_dir = Path(run_dir)
    learner = "bug"
    if (run_dir / "config.json").is_file():
        learner = str(load_json(run_dir / "config.json").get("learner", learner))
    paths: list[Path] = []
    files = sorted(run_dir.glob("metrics-*.csv")) or [run_dir / "metrics.csv"]
    for path in files:
        agent = path.stem.removeprefix("metrics-") if path.name != "metrics.csv" else learner
        metrics = read_metrics_csv(path)
        if len(metrics["epoch"]):
            out = run_dir / "plots" if path.name == "metrics.csv" else run_dir / "plots" / agent
            paths += plot_run(metrics, out, window=window, title=f"{agent} training ({run_dir.name})",
                              label=agent.capitalize())
    if (run_dir / "league" / "league.csv").is_file():  # a self-play run: rating curves and pool members
        paths.append(plot_league(run_dir))
    return paths


def train(cfg: TrainConfig, resume_dir: Path | None = None, overrides: dict[str, Any] | None = None,
          start_over: bool = False, from_checkpoint: str | None = None,
          session_command: str | None = None) -> TrainResult:
    """Start a run, or resume the one in ``resume_dir`` (with e.g. more epochs).

    A new run refuses a folder that already holds a run (:class:`RunExistsError`) unless
    ``start_over``, which moves that run aside to ``RUN.old-K`` first. ``from_checkpoint``
    (``epoch-N``) resumes from an older checkpoint than the latest, e.g. when the latest is
    damaged; the epochs after it are trained again. ``session_command`` is what started this session
    (the CLI's command line), recorded in its leg of ``RUN/legs.json`` (:mod:`triplesumo.train.legs`).
    """
    if resume_dir is not None:
        resume_dir = Path(resume_dir)
        saved = config_from_json(load_json(resume_dir / "config.json"), str(resume_dir / "config.json"))
        cfg = dataclasses.replace(saved, **(overrides or {}))
        trainer = Trainer(cfg, run_dir=resume_dir, resume=True, from_checkpoint=from_checkpoint,
                          session_command=session_command)
    else:
        if from_checkpoint is not None:
            raise ValueError("--from needs --resume RUN_DIR (it names a checkpoint of that run)")
        trainer = Trainer(cfg, start_over=start_over, session_command=session_command)
    return trainer.run()
