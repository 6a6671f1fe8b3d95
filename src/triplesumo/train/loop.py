"""The trainer: learners of any algorithm in several matches at once, resumable, wired from parts.

Reads like the paper: collect a step of every match (each learner acts for its agents with exploration, the
others follow their fixed policies), hand each learner its transitions, and let it learn on its schedule: an
off-policy learner (DDPG, TD3, SAC) does ``gradient_steps`` updates every ``learn_every`` collected transitions,
in a thread beside the physics; PPO updates when its ``(n_steps, rows)`` rollout is full. Each finished match is
one *epoch*: every learning agent's outcome, steps and rewards become a row of its metrics CSV, every learner's
update count and mean losses a row of its learning CSV. The one-learner case (``--learner bug``, DDPG) is the
paper's, bit for bit.

The parts, each usable without the others:

- :mod:`~triplesumo.train.preflight`: what is checked before anything is made (memory, schedule, sizes);
- :mod:`~triplesumo.train.learners`: the learners (one per network) and their updates;
- :mod:`~triplesumo.train.seats`: who sits in which seat (fixed policies, self-play league members);
- :mod:`~triplesumo.train.collect`: collection over the batched matches, epochs and their rows;
- :mod:`~triplesumo.train.evaluations`: evaluation while training, beside the loop;
- :mod:`~triplesumo.train.run_folder`: the run folder (config, ids, plots) and reading older checkpoints.

:class:`Trainer` wires them, runs the loop and checkpoints them: a checkpoint holds every match's exact state
(the env's ``snapshot``), so a resume continues the matches in progress.

Nothing is lost: a folder that already holds a run is never trained into again without ``resume`` (continue it)
or ``start_over`` (move it aside first); the memory the replay buffer needs is checked before anything is made;
a learner whose losses, parameters or actions stop being finite stops the run with a :class:`DivergenceError`
naming the learner, the update and the last good checkpoint.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from triplesumo._lock import held
from triplesumo.agents.frozen import FrozenPolicy
from triplesumo.agents.policy_file import load_json, save_policy
from triplesumo.agents.zoo import expand_pairs
from triplesumo.envs.batch import MatchBatch
from triplesumo.envs.match import Match
from triplesumo.model.specs import PhysicsConfig, describe_ring
from triplesumo.train import checkpoint
from triplesumo.train.collect import ACC_KEYS, Collector, DivergenceError, make_env
from triplesumo.train.config import TrainConfig
from triplesumo.train.evaluations import Evaluations
from triplesumo.train.league import League
from triplesumo.train.league_config import check_seed_rings, check_seeds
from triplesumo.train.learners import Learner, OffPolicyLearner, host, learner_specs, make_learner
from triplesumo.train.legs import LEGS_FILE, legs_before, make_leg, read_legs, write_legs
from triplesumo.train.logger import MetricsLog, run_file
from triplesumo.train.preflight import check_memory, learner_dims, warn_heavy_schedule
from triplesumo.train.run_folder import (
    FORK_FILE,
    checkpoint_within_rows,
    command_for,
    config_from_json,
    config_to_json,
    match_parts,
    one_learner_checkpoint,
    plot_metrics,
    prepare_run_dir,
    refuse_existing_run,
    run_id_of,
    write_run_config,
)
from triplesumo.train.seats import Seats
from triplesumo.version import ENV_VERSION, __version__
from triplesumo.zoo import policies_from_pairs

__all__ = ["DivergenceError", "TrainResult", "Trainer", "train"]


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


class Trainer:
    """Trains the learners of ``cfg``; :meth:`run` until ``cfg.epochs``, ``max_env_steps``, ``max_minutes`` or
    an evaluation at ``eval_target``.

    Wires the parts: the preflight checks, the learners, the seats (:class:`~triplesumo.train.seats.Seats`), the
    collector (:class:`~triplesumo.train.collect.Collector`, which owns the matches and their epochs), the
    evaluations and the run folder's tables; checkpoints and restores them all.
    """

    def __init__(self, cfg: TrainConfig, run_dir: Path | None = None, resume: bool = False,
                 command: str | None = None, start_over: bool = False, from_checkpoint: str | None = None,
                 session_command: str | None = None) -> None:
        self.cfg = cfg
        self.resumed = resume
        """This leg continues a checkpoint (a resume, or a fork's first leg)."""
        self.match_cfg = cfg.match_config()
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
        dims = {spec.name: learner_dims(sizing, spec) for spec in self.specs}
        if not resume:
            refuse_existing_run(run_dir, start_over)
            if cfg.self_play:  # a new league copies its seeds' files into its pools (a resumed one has them)
                check_seeds(cfg.league.zoo)
                check_seed_rings(cfg.league.zoo, cfg.physics, cfg.allow_other_ring)
        check_memory(cfg, [(spec.name, spec.algo, *dims[spec.name]) for spec in self.specs])
        self.probe = probe = sizing
        """A match of the run's config (never stepped): roster, observation and action sizes."""
        env = make_env(cfg, self.match_cfg)
        """The matches, through the batched API (arrays ``(n_envs, n_agents, ...)``, autoreset)."""
        self.device: torch.device | None = getattr(env, "device", None) if cfg.backend == "warp" else None
        """Where a ``warp`` run keeps observations, actions, replay and rollouts (None: numpy on the host)."""
        self.run_dir = prepare_run_dir(run_dir)
        fork = load_json(self.run_dir / FORK_FILE) if resume and (self.run_dir / FORK_FILE).is_file() else None
        self.forked_from: dict[str, Any] | None = None if fork is None else {
            "run": fork["parent"], "run_id": fork["parent_run_id"], "checkpoint": fork["checkpoint"],
            "epoch": fork["epoch"], "command": fork["parent_command"], "changes": fork["changes"]}
        """A fork's parent (``fork.json``), named in every policy manifest it writes; None for other runs."""
        self.command = command or (fork["command"] if fork is not None else command_for(cfg))
        self.session_command = session_command or self.command
        """What started this leg (its command): the typed command line where the CLI gives it."""
        self.legs: list[dict[str, Any]] = []
        """The run's legs (:mod:`triplesumo.train.legs`), this one's last once :meth:`run` starts."""
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
                teams={a.name: a.team for a in self.match_cfg.agents}, physics=cfg.physics,
                allow_other_ring=cfg.allow_other_ring)
        except ValueError as err:
            raise ValueError(f"TrainConfig.policies (scenario {cfg.scenario!r}): {err}") from None
        others = [(probe.agents.index(a), p) for a, p in self.policies.items()]
        on_device = {i: p.on_device(self.device) for i, p in others
                     if self.device is not None and isinstance(p, FrozenPolicy)}
        self.learners = [make_learner(spec, [probe.agents.index(a) for a in spec.agents], position, cfg,
                                      *dims[spec.name], self.device) for position, spec in enumerate(self.specs)]
        self.rng = np.random.default_rng(cfg.seed)
        """Warm-up actions, exploration, every match's reset seed (and the league's seed)."""
        self.train_seconds = 0.0
        """Wall time of training so far, over every leg of the run: collection, learning and checkpoints,
        the evaluations excluded (as of the last evaluation or checkpoint)."""
        self.evaluations = Evaluations(cfg, self.match_cfg, probe.observer.sizes,
                                       dict(zip(probe.agents, probe.action_sizes, strict=True)), pairs)
        self.seats = Seats(cfg, self.match_cfg, probe, self.specs, pairs, self.run_dir,
                           lambda: int(self.rng.integers(2**31 - 1)), resume, self.device)
        self.collector = Collector(cfg, probe, env, self.device, self.learners, others, on_device, self.seats,
                                   self.rng, self.diverged)
        self.collector.on_match_end = self._league_match
        self.restored: Path | None = None
        """The checkpoint folder this resume restored (None for a new run)."""
        if resume:
            self._restore(from_checkpoint)
        else:
            self.collector.start()
            write_run_config(self.run_dir, cfg)
        c = self.collector
        self.log = MetricsLog(self.run_dir, self.agents, [s.name for s in self.specs],
                              c.epochs_done if resume else None, cfg.tensorboard,
                              {a: len(c.lwr[a]) for a in self.agents} if resume else None,
                              self.evaluations.count if cfg.eval_every else None)
        c.log = self.log

    # ---------------------------------------------------- the parts' state, as the run's
    @property
    def env(self) -> Any:
        """The matches (:attr:`Collector.env`)."""
        return self.collector.env

    @property
    def batch(self) -> MatchBatch:
        """The matches of a ``cpu`` run (:attr:`Collector.batch`)."""
        return self.collector.batch

    @property
    def obs(self) -> Any:
        return self.collector.obs

    @property
    def epochs_done(self) -> int:
        return self.collector.epochs_done

    @property
    def env_steps(self) -> int:
        return self.collector.env_steps

    @property
    def timers(self) -> dict[str, float]:
        return self.collector.timers

    @property
    def finished_epoch_steps(self) -> list[int]:
        return self.collector.finished_epoch_steps

    @property
    def league(self) -> League | None:
        """The self-play league (:attr:`Seats.league`), None without ``self_play``."""
        return self.seats.league

    @property
    def seat_members(self) -> list[list[str | None]]:
        """Per match, per seat: the league member playing it (:attr:`Seats.members`)."""
        return self.seats.members

    @property
    def updates(self) -> int:
        return sum(learner.algo.num_updates for learner in self.learners)

    def collect_step(self) -> int:
        """Step every match once (:meth:`Collector.step`); returns the number of epochs that finished."""
        return self.collector.step()

    def mwr(self, agent: str | None = None) -> float:
        """MWR of ``agent`` (default: the first learning agent) over the last λ epochs."""
        return self.collector.mwr(agent)

    def evaluate(self) -> bool:
        """One evaluation (:class:`~triplesumo.train.evaluations.Evaluations`); True when every learner's test MWR
        reached ``eval_target``."""
        c = self.collector
        return self.evaluations(self.learners, self.log, c.env_steps, c.epochs_done, self.train_seconds)

    # ------------------------------------------------------------------ self-play
    def _league_match(self, k: int, outcomes: np.ndarray, places: np.ndarray) -> None:
        """Match ``k`` ended: the league rates it, admits due sides and its epoch's scalars are logged."""
        epoch = self.collector.epochs_done
        self.log.scalars(self.seats.match_end(k, outcomes, places, epoch, self._write_snapshot), epoch)

    def _write_snapshot(self, side: str, stems: Mapping[str, Path]) -> None:
        """A learning side's snapshot: each role's policy files from the learner acting for it."""
        for role, stem in stems.items():
            agent = self.specs[0].agents[0] if self.seats.ffa else role
            learner = next(lr for lr in self.learners if agent in lr.spec.agents)
            manifest = self.manifest(learner) | {"league_member": stem.parent.name, "side": side, "role": role}
            save_policy(stem, learner.algo.export_actor(), manifest, obs_norm=learner.algo.obs_norm)

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
        """Append this leg to ``RUN/legs.json`` (cutting the legs of epochs trained again) and
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
        self.adopt_restored()
        start = time.perf_counter()
        start_steps = self.env_steps
        trained_before, evals_before = self.train_seconds, self.evaluations.seconds

        def clock() -> None:  # the training's own wall time so far (the evaluations apart)
            self.train_seconds = (trained_before + time.perf_counter() - start
                                  - (self.evaluations.seconds - evals_before))

        bar = self.progress_bar() if cfg.progress else None
        try:
            while self.epochs_done < cfg.epochs:
                before, steps_before = self.epochs_done, self.env_steps
                finished = self.collect_step()
                if bar is not None:
                    bar.update(min(self.progress_count(), int(bar.total)) - bar.n)
                reached = False
                if self.evaluations.due(steps_before, self.env_steps):
                    clock()
                    reached = self.evaluate()
                if self.evaluations.ready():  # a background evaluation is back: its row, at this moment
                    clock()
                    reached = self.evaluations.collect(self.log, self.train_seconds) or reached
                if finished and bar is not None:
                    rate = (self.env_steps - start_steps) / max(time.perf_counter() - start, 1e-9)
                    mwrs = {f"MWR {a}" if len(self.agents) > 1 else "MWR": f"{self.mwr(a):+.3f}" for a in self.agents}
                    bar.set_postfix(mwrs | {"steps_s": f"{rate:.0f}"}, refresh=False)
                crossed = finished and (self.epochs_done // cfg.checkpoint_every > before // cfg.checkpoint_every)
                timed_out = ((cfg.max_minutes > 0 and (time.perf_counter() - start) > cfg.max_minutes * 60)
                             or 0 < cfg.max_env_steps <= self.env_steps)
                stopping = (timed_out and finished) or self.epochs_done >= cfg.epochs
                if stopping and self.evaluations.pending:  # the run's last evaluations are written before it ends
                    clock()
                    reached = self.evaluations.collect(self.log, self.train_seconds, wait=True) or reached
                if crossed or stopping or reached:
                    clock()
                    self.save()
                if stopping or reached:
                    break
        except checkpoint.CheckpointWriteError as exc:
            if "last good checkpoint" in str(exc) or "no earlier checkpoint" in str(exc):
                raise
            raise checkpoint.CheckpointWriteError(exc.errno, f"{exc.strerror}; {self.last_good()}") from exc
        finally:
            self.evaluations.close()
            if bar is not None:
                bar.close()
            self.log.close()
        self.finish_outputs()
        return TrainResult(self.run_dir, self.epochs_done, self.env_steps, self.updates, self.mwr(),
                           time.perf_counter() - start, dict(self.timers), {a: self.mwr(a) for a in self.agents})

    def progress_count(self) -> int:
        """What the progress bar counts: env steps when the run has an env-step budget (``max_env_steps``),
        else epochs."""
        return self.env_steps if self.cfg.max_env_steps > 0 else self.epochs_done

    def progress_bar(self) -> Any:
        """A tqdm bar to the run's budget: env steps to ``max_env_steps`` when that is set (a run whose epochs
        are only a backstop, as ``bench skill``'s), else epochs to ``epochs``."""
        from tqdm import tqdm

        cfg = self.cfg
        steps = cfg.max_env_steps > 0
        total = cfg.max_env_steps if steps else cfg.epochs
        return tqdm(total=total, initial=min(self.progress_count(), total), unit="step" if steps else "epoch",
                    unit_scale=steps, desc=f"train {' '.join(s.name for s in self.specs)}", dynamic_ncols=True)

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
            "legs": self.legs,  # which code trained which epochs, leg by leg
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
        c = self.collector
        snaps = c.env.snapshot()
        obs = host(c.obs)
        for k, s in enumerate(snaps):
            arrays |= {f"match{k}.{key}": v for key, v in s.items() if isinstance(v, np.ndarray)}
            arrays[f"match{k}.obs"] = np.array(obs[k])
        acc = host(c.acc).tolist()
        for agent, lwr in c.lwr.items():
            arrays[f"lwr.{agent}"] = np.array(lwr)
        pending, frozen = self.evaluations.state()  # evaluations in flight: played again by a resume
        arrays |= frozen
        state = {
            "config": config_to_json(self.cfg), "manifests": {lr.name: self.manifest(lr) for lr in self.learners},
            "epochs_done": c.epochs_done, "env_steps": c.env_steps, "rng": self.rng.bit_generator.state,
            "run_id": self.run_id, "learners": {lr.name: lr.state() for lr in self.learners},
            "matches": [{key: v for key, v in s.items() if not isinstance(v, np.ndarray)}
                        for s in snaps],  # steps, generator, who is still in play (elimination rules)
            "acc": {agent: [dict(zip(ACC_KEYS, per_match[j], strict=True)) for per_match in acc]
                    for j, agent in enumerate(self.agents)},
            "final": c.final, "timers": c.timers, "train_seconds": self.train_seconds,
            "evaluations": self.evaluations.count, "eval_seconds": self.evaluations.seconds,
            "pending_evaluations": pending,
            "policy_rngs": {a: p.rng.bit_generator.state for a, p in self.policies.items() if hasattr(p, "rng")},
        }
        if self.league is not None:
            state |= self.seats.state()
        keep_replay = self.cfg.save_replay and bool(replay)
        folder = checkpoint.save(self.run_dir, c.epochs_done, tensors, state, arrays,
                                 replay if keep_replay else None)
        self._write_policies(folder)
        return folder

    def _write_policies(self, folder: Path) -> None:
        """Every learner's policy files (``RUN/policy*``) from its actor as it is now (checkpoint ``folder``'s)."""
        for learner in self.learners:
            stem = self.policy_stem(learner)
            with checkpoint.writing(f"{stem}.safetensors/.json", f"; the last good checkpoint {folder} is intact"):
                save_policy(stem, learner.algo.export_actor(), self.manifest(learner), obs_norm=learner.algo.obs_norm)

    def adopt_restored(self) -> None:
        """Make the run folder that of the checkpoint this resume restored, before any epoch is trained.

        A resume from another checkpoint than the one ``latest.json`` names (``--from epoch-N``, or the newest
        checkpoint within torn rows) has cut the tables back to its epoch; so that the folder never contradicts
        itself, even when no epoch is left to train (``--epochs`` not past it), the policy files are written
        from the restored learners, then ``latest.json`` names the restored checkpoint, then the checkpoints of
        later epochs are removed (the rows no longer reach them; the epochs trained next re-create them, as
        the first checkpoint after a ``--from`` always pruned them). In that order, a kill in between leaves
        ``latest.json`` beyond the rows, which the next plain ``--resume`` steps back from and adopts again.
        """
        folder = self.restored
        if folder is None:
            return
        try:
            named: Path | None = checkpoint.latest(self.run_dir)
        except checkpoint.CheckpointError:
            named = None
        if named is not None and named.resolve() == folder.resolve():
            return
        epoch = checkpoint.recorded_epoch(folder)
        epoch = self.epochs_done if epoch is None else epoch
        self._write_policies(folder)
        with checkpoint.writing(self.run_dir / "checkpoints" / "latest.json"):
            checkpoint.point_latest(self.run_dir, folder, epoch)
        checkpoint.drop_after(self.run_dir, epoch)

    def _needs_replay(self) -> bool:
        return self.cfg.save_replay and any(isinstance(lr, OffPolicyLearner) for lr in self.learners)

    def _restore(self, from_checkpoint: str | None) -> None:
        def load(folder: Path) -> tuple[Any, ...]:
            # a checkpoint that holds no replay buffer (saved without, or compacted of it) resumes with an empty one
            need_replay = self._needs_replay() and checkpoint.holds_replay(folder)
            if self._needs_replay() and not need_replay:
                print(f"{folder}: the checkpoint holds no replay buffer (saved without or compacted of it): the "
                      "run resumes with an empty one, not exactly as it would have gone on")
            return checkpoint.load(folder, need_replay=need_replay)

        if from_checkpoint is not None:
            folder = checkpoint.find(self.run_dir, from_checkpoint)
            loaded = load(folder)
        else:
            try:
                folder = checkpoint.latest(self.run_dir)
                if self.league is None:  # (self-play runs, whose agents may sit matches out, check their own tables)
                    folder = checkpoint_within_rows(self.run_dir, folder, self.agents, [s.name for s in self.specs])
                loaded = load(folder)
            except checkpoint.CheckpointError as exc:
                intact = checkpoint.newest_intact(self.run_dir)
                if intact is None:
                    raise
                raise checkpoint.CheckpointError(
                    f"{exc} -- the latest checkpoint is damaged or missing; the newest intact one is {intact.name} "
                    f"(epoch {checkpoint.recorded_epoch(intact)}): `triplesumo train --resume {self.run_dir} "
                    f"--from {intact.name}` continues from it (later epochs are trained again)") from exc
        self.restored = folder
        tensors, state, arrays, lazy_replay = loaded
        replay: Mapping[str, np.ndarray] | None = lazy_replay
        if "learners" not in state and "optimizer" in state:
            tensors, state, arrays, replay = one_learner_checkpoint(self.learners[0].name, self.cfg.n_envs, tensors,
                                                                    state, arrays, replay)
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
        if saved.physics != self.cfg.physics:
            raise checkpoint.CheckpointError(physics_mismatch(folder / "state.json", saved.physics,
                                                              self.run_dir / "config.json", self.cfg.physics))
        for name in ("learner", "learn", "share", "scenario", "obs_mode", "n_envs", "steps_per_epoch", "policies",
                     "reward", "ddpg", "td3", "sac", "ppo", "learner_config", "seed", "self_play", "league", "backend"):
            # (save_replay may differ: resuming without the replay buffer is allowed, not exact)
            if getattr(saved, name) != getattr(self.cfg, name):
                raise checkpoint.CheckpointError(
                    f"{folder / 'state.json'}: incompatible checkpoint: it was made with {name}="
                    f"{getattr(saved, name)!r}, this run has {getattr(self.cfg, name)!r} (from config.json)")
        need_arrays = [f"lwr.{a}" for a in self.agents] + [f"{lr.name}.active" for lr in self.learners] + [
            f"match{k}.{part}" for k in range(self.cfg.n_envs) for part in match_parts(self.device is not None, arrays)]
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
        c = self.collector
        n, parts = self.cfg.n_envs, match_parts(self.device is not None, arrays)
        if parts:  # every match continues exactly where it was
            obs = np.stack([np.asarray(arrays[f"match{k}.obs"], dtype=np.float32) for k in range(n)])
            c.obs = obs if self.device is None else torch.as_tensor(obs, device=self.device)
            c.env.restore([{part: arrays[f"match{k}.{part}"] for part in parts if part != "obs"}
                           | state["matches"][k] for k in range(n)], c.obs)
            c.final = {a: state["final"][a] for a in self.agents}
            acc = np.array([[[state["acc"][a][k][key] for key in ACC_KEYS] for a in self.agents]
                            for k in range(n)], dtype=np.float64)
            c.acc = acc if self.device is None else torch.as_tensor(acc, device=self.device)
        else:  # a warp checkpoint of before exact warp resume: the unfinished matches restart (epochs dropped)
            c.obs = c.env.reset(seed=[c.episode_seed() for _ in range(n)])[0]
            for learner in self.learners:
                learner.active[:] = True
        c.playing = np.array([[c.final[a][k] is None for a in self.agents] for k in range(n)], dtype=bool)
        for agent, rng_state in state.get("policy_rngs", {}).items():
            self.policies[agent].rng.bit_generator.state = rng_state
        c.epochs_done = int(state["epochs_done"])
        c.env_steps = int(state["env_steps"])
        self.run_id = state.get("run_id")
        c.lwr = {a: [float(x) for x in arrays[f"lwr.{a}"]] for a in self.agents}
        c.timers = {**c.timers, **state.get("timers", {})}
        # (0 in a checkpoint written before the trainer counted them)
        self.train_seconds = float(state.get("train_seconds", 0.0))
        self.evaluations.count = int(state.get("evaluations", 0))
        self.evaluations.seconds = float(state.get("eval_seconds", 0.0))
        self.evaluations.restore(state.get("pending_evaluations", []), arrays)
        if self.league is not None:
            self.seats.restore(state, c.epochs_done)

    def finish_outputs(self) -> None:
        """Plots from the metrics CSVs (skipped for an agent without a finished epoch)."""
        plot_metrics(self.run_dir, self.cfg.window)


def physics_mismatch(state: Path, made: PhysicsConfig, config: Path, given: PhysicsConfig) -> str:
    """Why a checkpoint (``state``, made on ``made``) cannot resume on the physics ``given`` that the run's
    ``config`` says: a run never trains on another simulation than its checkpoint's. A ``config.json`` that
    records no physics is read as env v0's (:data:`~triplesumo.model.specs.V0_PHYSICS`, what run folders made
    before it was recorded ran); one whose checkpoint records other physics was written by hand or damaged."""
    raw = load_json(config) if config.is_file() else {}
    said = "records no physics, which reads as env v0's" if "physics" not in raw else "records other physics"
    fields = [f.name for f in dataclasses.fields(PhysicsConfig) if getattr(made, f.name) != getattr(given, f.name)]
    differ = ", ".join(f"physics.{f} {getattr(made, f)!r} there, {getattr(given, f)!r} here" for f in fields)
    return (f"{state}: incompatible checkpoint: it was made on {describe_ring(made)} ({differ}), but {config} "
            f"{said}: {describe_ring(given)}. Nothing was trained; to resume, set config.json's \"physics\" to the "
            f"checkpoint's (the \"physics\" inside the \"config\" of {state})")


def check_checkpoint_physics(run_dir: Path, physics: PhysicsConfig) -> None:
    """:class:`~triplesumo.train.checkpoint.CheckpointError` (:func:`physics_mismatch`) unless the newest
    checkpoint of ``run_dir`` whose ``state.json`` reads was made on ``physics``, before anything is loaded onto it
    (every checkpoint of a run is made on its one simulation); a run without a readable one passes here."""
    for _, folder in reversed(checkpoint.checkpoints(run_dir)):
        try:
            made = config_from_json(load_json(folder / "state.json")["config"]).physics
        except (ValueError, KeyError, TypeError):
            continue  # damaged: the resume names it, or goes on from an older one
        if made != physics:
            raise checkpoint.CheckpointError(physics_mismatch(folder / "state.json", made, run_dir / "config.json",
                                                              physics))
        return


def train(cfg: TrainConfig, resume_dir: Path | None = None, overrides: dict[str, Any] | None = None,
          start_over: bool = False, from_checkpoint: str | None = None,
          session_command: str | None = None) -> TrainResult:
    """Start a run, or resume the one in ``resume_dir`` (with e.g. more epochs).

    The run folder is held for the whole call (:func:`triplesumo._lock.held`): a second process training,
    resuming or starting over the same folder meanwhile is refused at once, naming this one's PID.

    A new run refuses a folder that already holds a run (:class:`RunExistsError`) unless
    ``start_over``, which moves that run aside to ``RUN.old-K`` first. ``from_checkpoint``
    (``epoch-N``) resumes from an older checkpoint than the latest, e.g. when the latest is
    damaged; the epochs after it are trained again. ``session_command`` is what started this leg of the run
    (the CLI's command line), recorded in it of ``RUN/legs.json`` (:mod:`triplesumo.train.legs`).
    """
    if resume_dir is None and from_checkpoint is not None:
        raise ValueError("--from needs --resume RUN_DIR (it names a checkpoint of that run)")
    run_dir = Path(resume_dir) if resume_dir is not None else Path(cfg.out) / cfg.name
    what = "train --resume" if resume_dir is not None else "train --start-over" if start_over else "train"
    with held(run_dir, what):  # one writer per run folder, from before its config is read to the end
        if resume_dir is not None:
            raw = load_json(run_dir / "config.json")
            saved = config_from_json(raw, str(run_dir / "config.json"))
            if isinstance(raw, dict) and "physics" not in raw:  # read as env v0's: unless its checkpoints say otherwise
                check_checkpoint_physics(run_dir, saved.physics)
            cfg = dataclasses.replace(saved, **(overrides or {}))
            trainer = Trainer(cfg, run_dir=run_dir, resume=True, from_checkpoint=from_checkpoint,
                              session_command=session_command)
        else:
            trainer = Trainer(cfg, start_over=start_over, session_command=session_command)
        return trainer.run()
