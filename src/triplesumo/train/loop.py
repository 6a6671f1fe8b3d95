"""The trainer: learners of any algorithm in several matches at once, resumable, wired from parts.

:meth:`Trainer.run` and :meth:`Trainer.step` are the algorithm: the off-policy updates due (``gradient_steps``
every ``learn_every`` transitions) run in a thread beside the rest of the step; each learner acts for its agents
with exploration, the fixed policies and league members for theirs; the matches step; each learner stores its
transitions; every finished match is one *epoch*: its rows are written, the league rates it, its next match seats
the players drawn; PPO learns when its rollout is full. ``--learn bug=ddpg`` (the default) is the paper's.

The parts, each keeping its own state (``state_dict``): :mod:`~triplesumo.train.preflight` (checks before anything
is made: memory, schedule, sizes), :mod:`~triplesumo.train.collect` (the batched matches, stepped into transitions
and finished-match records), :mod:`~triplesumo.train.learners` (act, store, learn), :mod:`~triplesumo.train.seats`
(fixed policies, self-play league members), :mod:`~triplesumo.train.evaluations` (evaluation beside the loop), and
:mod:`~triplesumo.train.checkpoint` with :mod:`~triplesumo.train.run_folder` (the run folder and its checkpoints;
every match's exact state too, so a resume continues the matches in progress).

Nothing is lost: a folder that already holds a run is never trained into again without ``resume`` or
``start_over`` (move it aside first); a learner whose losses, parameters or actions stop being finite stops the
run with a :class:`DivergenceError` naming the learner, the update and the last good checkpoint.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from triplesumo._lock import held
from triplesumo.agents.policy_file import load_json, save_policy
from triplesumo.agents.zoo import expand_pairs
from triplesumo.algos.base import DivergenceError
from triplesumo.envs.match import Match
from triplesumo.train import checkpoint
from triplesumo.train.checkpoint import State
from triplesumo.train.collect import Collector, MatchEnd
from triplesumo.train.config import TrainConfig
from triplesumo.train.evaluations import Evaluations
from triplesumo.train.league_config import check_seed_rings, check_seeds
from triplesumo.train.learners import Learner, OffPolicyLearner, Updates, learner_specs, make_learner
from triplesumo.train.legs import RunRecord
from triplesumo.train.logger import MetricsLog, progress_bar, run_file
from triplesumo.train.preflight import check_memory, learner_dims, warn_heavy_schedule
from triplesumo.train.run_folder import (
    adopt_checkpoint,
    check_checkpoint_physics,
    check_resumable,
    command_for,
    config_from_json,
    config_to_json,
    forked_from,
    load_to_resume,
    plot_metrics,
    policy_manifest,
    prepare_run_dir,
    refuse_existing_run,
    run_id_of,
    write_run_config,
)
from triplesumo.train.seats import Seats

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
    """Seconds spent in physics+rules (``env``), acting (``act``), learning (``learn``) and waiting for it."""
    mwrs: dict[str, float] = field(default_factory=dict)
    """MWR of every learning agent."""


class Trainer:
    """Trains the learners of ``cfg``; :meth:`run` until ``cfg.epochs``, ``max_env_steps``, ``max_minutes`` or
    an evaluation at ``eval_target``.

    Wires the parts: the :attr:`collector` (the matches), the :attr:`learners`, the :attr:`seats` (fixed
    policies and the league), the :attr:`evaluations` and the run folder's tables (:attr:`log`); runs the loop
    over them; checkpoints their states side by side and restores them.
    """

    def __init__(self, cfg: TrainConfig, run_dir: Path | None = None, resume: bool = False,
                 command: str | None = None, start_over: bool = False, from_checkpoint: str | None = None,
                 session_command: str | None = None) -> None:
        self.cfg, self.resumed = cfg, resume  # resumed: this leg continues a checkpoint (a resume, a fork's first)
        self.match_cfg = cfg.match_config()
        agent_names = list(self.match_cfg.agent_names)
        self.specs = learner_specs(cfg, agent_names, {a.name: a.team for a in self.match_cfg.agents})
        self.agents = [a for spec in self.specs for a in spec.agents]
        """The learning agents, learner by learner."""
        warn_heavy_schedule(cfg, self.specs)
        self.pairs = expand_pairs(cfg.policies, [a for a in agent_names if a not in self.agents])
        """AGENT=POLICY of every agent that does not learn (the evaluations build their own from them)."""
        unknown = [p.split("=")[0] for p in self.pairs if p.split("=")[0] not in agent_names]
        if unknown:
            raise ValueError(f"TrainConfig.policies names unknown agents {unknown}; agents are {agent_names}")
        run_dir = Path(run_dir) if run_dir else Path(cfg.out) / cfg.name
        self.probe = probe = Match(self.match_cfg)
        """A match of the run's config (never stepped): roster, observation and action sizes."""
        dims = {spec.name: learner_dims(probe, spec) for spec in self.specs}
        if not resume:
            refuse_existing_run(run_dir, start_over)
            if cfg.self_play:  # a new league copies its seeds' files into its pools (a resumed one has them)
                check_seeds(cfg.league.zoo)
                check_seed_rings(cfg.league.zoo, cfg.physics, cfg.allow_other_ring)
        check_memory(cfg, [(spec.name, spec.algo, *dims[spec.name]) for spec in self.specs])
        self.rng = np.random.default_rng(cfg.seed)
        """Warm-up actions, exploration, every match's reset seed (and the league's seed)."""
        self.collector = Collector(cfg, self.match_cfg, probe, self.agents, self.rng)
        """The matches and where they stand."""
        device = self.collector.xp.device
        self.run_dir = prepare_run_dir(run_dir)
        forked, fork_command = forked_from(self.run_dir) if resume else (None, None)
        command = command or fork_command or command_for(cfg)
        self.record = RunRecord(command, session_command or command, run_id_of(cfg), forked)
        """The run's command, id, fork parent and legs, as every policy file it writes says."""
        torch.set_num_threads(cfg.torch_threads)
        self.seats = Seats(cfg, self.match_cfg, probe, self.specs, self.pairs, self.run_dir,
                           lambda: int(self.rng.integers(2**31 - 1)), resume, device)
        """Who plays every seat a learner does not: the fixed policies and, with ``self_play``, the league."""
        self.learners = [make_learner(spec, [probe.agents.index(a) for a in spec.agents], position, cfg,
                                      *dims[spec.name], device, probe.elimination)
                         for position, spec in enumerate(self.specs)]
        self.timers = {"env": 0.0, "act": 0.0, "learn": 0.0, "wait": 0.0}
        """Seconds collecting (physics and rules), acting, learning (off-policy updates run in a thread: they
        overlap "act" and "env" when overlap_learning is on; PPO's run inline) and waiting for learning."""
        self.train_seconds = 0.0
        """Wall time of training so far, over every leg of the run: collection, learning and checkpoints,
        the evaluations excluded (as of the last evaluation or checkpoint)."""
        self.evaluations = Evaluations(cfg, self.match_cfg, probe.observer.sizes,
                                       dict(zip(probe.agents, probe.action_sizes, strict=True)), self.pairs)
        self.restored: Path | None = None
        """The checkpoint folder this resume restored (None for a new run)."""
        self.replay: str | None = None
        """What this resume's replay buffer is, as its leg says: "restored", "empty" (the checkpoint held none, or
        ``save_replay`` is off), or None (a new run, or one with no off-policy learner)."""
        if resume:
            self._restore(from_checkpoint)
        else:
            for k in range(cfg.n_envs):
                self.begin_match(k)
            self.collector.reset()
            write_run_config(self.run_dir, cfg)
        lwr = self.collector.lwr
        self.log = MetricsLog(self.run_dir, self.agents, [s.name for s in self.specs],
                              self.collector.epochs_done if resume else None, cfg.tensorboard,
                              {a: len(lwr[a]) for a in self.agents} if resume else None,
                              self.evaluations.count if cfg.eval_every else None)

    # ------------------------------------------------------------------ the loop
    def run(self) -> TrainResult:
        """Train until the run's budget is spent (or an evaluation reached ``eval_target``), checkpointing every
        ``checkpoint_every`` epochs and at the end."""
        cfg, c, evaluations = self.cfg, self.collector, self.evaluations
        self.start_leg()
        start, start_steps = time.perf_counter(), c.env_steps
        trained_before, evals_before = self.train_seconds, evaluations.seconds

        def clock() -> None:  # the training's own wall time so far (the evaluations apart)
            self.train_seconds = trained_before + time.perf_counter() - start - (evaluations.seconds - evals_before)

        steps = cfg.max_env_steps > 0  # (a run with an env-step budget counts env steps, as bench skill's)
        count = (lambda: c.env_steps) if steps else (lambda: c.epochs_done)
        bar = progress_bar(cfg.max_env_steps if steps else cfg.epochs, count(), steps,
                           f"train {' '.join(s.name for s in self.specs)}") if cfg.progress else None
        try:
            while c.epochs_done < cfg.epochs:
                before, steps_before = c.epochs_done, c.env_steps
                finished = self.step()
                if bar is not None:
                    bar.update(min(count(), int(bar.total)) - bar.n)
                reached = False
                if evaluations.due(steps_before, c.env_steps):
                    clock()
                    reached = evaluations(self.learners, self.log, c.env_steps, c.epochs_done, self.train_seconds)
                if evaluations.ready():  # a background evaluation is back: its row, at this moment
                    clock()
                    reached = evaluations.collect(self.log, self.train_seconds) or reached
                if finished and bar is not None:
                    rate = (c.env_steps - start_steps) / max(time.perf_counter() - start, 1e-9)
                    mwrs = {f"MWR {a}" if len(self.agents) > 1 else "MWR": f"{c.mwr(a):+.3f}" for a in self.agents}
                    bar.set_postfix(mwrs | {"steps_s": f"{rate:.0f}"}, refresh=False)
                crossed = finished and (c.epochs_done // cfg.checkpoint_every > before // cfg.checkpoint_every)
                timed_out = ((cfg.max_minutes > 0 and (time.perf_counter() - start) > cfg.max_minutes * 60)
                             or 0 < cfg.max_env_steps <= c.env_steps)
                stopping = (timed_out and finished) or c.epochs_done >= cfg.epochs
                if stopping and evaluations.pending:  # the run's last evaluations are written before it ends
                    clock()
                    reached = evaluations.collect(self.log, self.train_seconds, wait=True) or reached
                if crossed or stopping or reached:
                    clock()
                    self.save()
                if stopping or reached:
                    break
        except checkpoint.CheckpointWriteError as exc:
            if "last good checkpoint" in str(exc) or "no earlier checkpoint" in str(exc):
                raise
            good = checkpoint.last_good(self.run_dir)
            raise checkpoint.CheckpointWriteError(exc.errno, f"{exc.strerror}; {good}") from exc
        finally:
            evaluations.close()
            if bar is not None:
                bar.close()
            self.log.close()
        plot_metrics(self.run_dir, cfg.window)  # (skipped for an agent without a finished epoch)
        return TrainResult(self.run_dir, c.epochs_done, c.env_steps, self.updates(), c.mwr(),
                           time.perf_counter() - start, dict(self.timers), {a: c.mwr(a) for a in self.agents})

    def step(self) -> int:
        """Step every match once; returns the number of epochs that finished. The off-policy updates due now
        (on the replay as it was before this step, the normaliser with this step's observations) run beside the
        rest: each learner acts on its rows with exploration (a copy of its actor as the last updates left it),
        the seats it does not take act too, the matches step, each learner stores its transitions; then each
        finished epoch is written, rated and its match's next epoch seated; PPO learns when its rollout is full."""
        c, learners, timers = self.collector, self.learners, self.timers
        where = c.epochs_done, c.env_steps
        try:
            t0 = time.perf_counter()
            seen = [c.rows(learner) for learner in learners]
            for learner, obs in zip(learners, seen, strict=True):
                learner.prepare(obs)  # the normaliser the updates read, the actor copy that acts
            updates = Updates(learners).begin(self.cfg.overlap_learning)
            try:
                acted = [learner.act(obs, self.rng) for learner, obs in zip(learners, seen, strict=True)]
                actions = c.actions(learners, acted)
                self.seats.act(actions, c.obs)
                t1 = time.perf_counter()
                step = c.step(actions)
                updates.drawn()  # (long since, as a rule)
                for learner, obs, act in zip(learners, seen, acted, strict=True):
                    learner.store(obs, act, step)
            finally:
                t2 = time.perf_counter()
                updates.finish()  # (before the epochs' rows: they read the learners' update counts and losses)
            t3 = time.perf_counter()
            for end in step.ended:
                self.end_match(end)
            t4 = time.perf_counter()
            for learner in learners:
                learner.learn(c.rows(learner))
        except DivergenceError as exc:
            raise self.diverged(exc, *where) from None
        inline = 0.0 if updates.overlapped else updates.seconds
        timers["act"] += t1 - t0 - inline
        timers["env"] += (t2 - t1) + (t4 - t3)
        timers["learn"] += updates.seconds + time.perf_counter() - t4  # the thread's part overlaps "act" and "env"
        timers["wait"] += t3 - t2
        return len(step.ended)

    def end_match(self, end: MatchEnd) -> None:
        """An epoch ended: its rows and every learner's learning row are written, the league rates it and admits
        the learning sides that are due; then its match's next epoch starts (:meth:`begin_match`)."""
        for agent, (row, mwr) in end.rows.items():
            self.log.epoch(agent, row, mwr)
        for learner in self.learners:
            self.log.learned(learner.name, end.epoch, learner.algo.num_updates, learner.take_stats())
        if self.seats.league is not None:
            write = functools.partial(self.write_snapshot, epoch=end.epoch)
            self.log.scalars(self.seats.match_end(end.match, end.outcomes, end.places, end.epoch, write), end.epoch)
        self.begin_match(end.match)

    def begin_match(self, k: int) -> None:
        """Match ``k``'s next epoch: the league draws its members; a learner whose seats they take sits it out."""
        self.seats.draw(k)
        plays = [self.seats.plays(learner, k) for learner in self.learners]
        for learner, playing in zip(self.learners, plays, strict=True):
            learner.begin_match(k, playing)
        self.collector.begin_match(k, [a for lr, p in zip(self.learners, plays, strict=True) if not p
                                       for a in lr.spec.agents])

    def write_snapshot(self, side: str, stems: Mapping[str, Path], epoch: int) -> None:
        """A learning side's league snapshot at ``epoch``: each role's policy files from the learner acting for it."""
        for role, stem in stems.items():
            agent = self.specs[0].agents[0] if self.seats.ffa else role
            learner = next(lr for lr in self.learners if agent in lr.spec.agents)
            manifest = self.manifest(learner, epoch) | {"league_member": stem.parent.name, "side": side, "role": role}
            save_policy(stem, learner.algo.export_actor(), manifest, obs_norm=learner.algo.obs_norm)

    def diverged(self, exc: DivergenceError, epoch: int, env_steps: int) -> DivergenceError:
        """What stops a diverging learner (in the step from ``epoch``): its update count, the last good checkpoint."""
        learner = next((lr for lr in self.learners if lr.name == exc.learner), None)
        if learner is None:
            return exc
        algo = learner.spec.algo
        rates = "--ppo.lr" if algo == "ppo" else f"--{algo}.actor-lr, --{algo}.critic-lr"
        return DivergenceError(f"learner {learner.name!r} diverged at update {learner.algo.num_updates} (epoch "
                               f"{epoch}, env step {env_steps}, {algo}): {exc}. Stopped; "
                               f"{checkpoint.last_good(self.run_dir)}. Lower the learning rates ({rates}) or the "
                               "reward scale", learner=learner.name)

    def start_leg(self) -> None:
        """Before this leg's first epoch: record it in ``RUN/legs.json``; a resume from another checkpoint than
        the latest makes the folder that checkpoint's (:func:`adopt_checkpoint`)."""
        cfg, c = self.cfg, self.collector
        self.record.start_leg(self.run_dir, self.resumed, c.epochs_done, c.env_steps, {
            "epochs": cfg.epochs, "max_minutes": cfg.max_minutes, "max_env_steps": cfg.max_env_steps},
            replay=self.replay)
        if self.restored is not None:
            adopt_checkpoint(self.run_dir, self.restored, c.epochs_done, self._write_policies)

    def updates(self) -> int:
        """Updates done by every learner together."""
        return sum(learner.algo.num_updates for learner in self.learners)

    # ---------------------------------------------------------- checkpoints
    def manifest(self, learner: Learner, epochs: int | None = None) -> dict[str, Any]:
        """What a policy file of ``learner`` says of itself (as of ``epochs``, default: the epochs done)."""
        c, league = self.collector, self.seats.league
        progress = {"epochs": c.epochs_done if epochs is None else epochs, "env_steps": c.env_steps,
                    "updates": learner.algo.num_updates}
        return policy_manifest(self.cfg, self.probe, self.match_cfg, self.specs, learner.spec, progress,
                               self.record.fields(), league.config.zoo if league is not None else self.cfg.policies)

    def state_dict(self) -> State:
        """The run's checkpoint: its own config, generator, ids and clocks beside every part's state."""
        own = State(json={
            "config": config_to_json(self.cfg), "manifests": {lr.name: self.manifest(lr) for lr in self.learners},
            "rng": self.rng.bit_generator.state, "run_id": self.record.run_id, "timers": self.timers,
            "train_seconds": self.train_seconds})
        return State.union([own, self.collector.state_dict(), self.seats.state_dict(), self.evaluations.state_dict(),
                            *(lr.state_dict(replay=self.cfg.save_replay).named(lr.name) for lr in self.learners)])

    def save(self) -> Path:
        """Write a checkpoint (the tables flushed first: none counts rows the disk lacks) and the policy files."""
        self.log.flush()
        state = self.state_dict()
        folder = checkpoint.save(self.run_dir, self.collector.epochs_done, dict(state.tensors), state.json,
                                 dict(state.arrays), None if state.replay is None else dict(state.replay))
        self._write_policies(folder)
        return folder

    def _write_policies(self, folder: Path) -> None:
        """Every learner's policy files (``RUN/policy*``) from its actor as it is now (checkpoint ``folder``'s)."""
        for learner in self.learners:
            stem = self.run_dir / run_file("policy", learner.name, self.log.several)
            with checkpoint.writing(f"{stem}.safetensors/.json", f"; the last good checkpoint {folder} is intact"):
                save_policy(stem, learner.algo.export_actor(), self.manifest(learner), obs_norm=learner.algo.obs_norm)

    def _restore(self, from_checkpoint: str | None) -> None:
        """Restore every part from the latest checkpoint (or ``from_checkpoint``), checked to fit this run."""
        wants_replay = self.cfg.save_replay and any(isinstance(lr, OffPolicyLearner) for lr in self.learners)
        within = None if self.cfg.self_play else (self.agents, [s.name for s in self.specs])  # (self-play: own tables)
        saved = load_to_resume(self.run_dir, from_checkpoint, wants_replay, within, self.learners[0].name,
                               self.cfg.n_envs)
        self.restored = saved.folder
        if any(isinstance(lr, OffPolicyLearner) for lr in self.learners):
            self.replay = "empty" if saved.replay is None else "restored"
        check_resumable(saved, self.cfg, self.run_dir)
        with checkpoint.restoring(saved):
            for learner in self.learners:
                learner.load_state_dict(saved.of(learner.name))
            self.rng.bit_generator.state = saved.json["rng"]
            if not self.collector.load_state_dict(saved):  # (an old warp checkpoint: its matches restarted)
                for learner in self.learners:
                    learner.all_in_play()
            self.seats.load_state_dict(saved, self.collector.epochs_done)
            self.record.run_id = saved.json.get("run_id")
            self.timers |= saved.json.get("timers", {})
            self.train_seconds = float(saved.json.get("train_seconds", 0.0))  # (0: from before it was kept)
            self.evaluations.load_state_dict(saved)


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
