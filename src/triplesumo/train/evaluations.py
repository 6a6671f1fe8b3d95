"""Evaluation while training (``eval_every``), a piece beside the loop as SB3's ``EvalCallback`` is: every
``eval_every`` env steps each learner's current policy, frozen, plays the run's seeded test matches and a row
goes to its eval CSV. It draws on none of the training's generators: a run trains the same with or without it.

An evaluation plays inline (the training waits for it) or, with ``eval_background``, in a worker process
while the training goes on: its row is written when it comes back, with the same figures (the frozen policy
and the test matches are the same; only the times differ). Each row gives the training's clock twice: when its
policy was frozen (``policy_train_seconds``, the time to that skill) and when its row was written
(``train_seconds``; the same inline, later in the background). An evaluation still in flight at a checkpoint is
saved with it (the frozen weights it plays) and played again by a resume."""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from multiprocessing.pool import AsyncResult, Pool
from typing import Any

import numpy as np

from triplesumo.agents.frozen import FrozenPolicy
from triplesumo.agents.zoo import policies_from_pairs
from triplesumo.rules.config import MatchConfig
from triplesumo.train.checkpoint import State
from triplesumo.train.config import TrainConfig
from triplesumo.train.learners import Learner
from triplesumo.train.logger import MetricsLog

Frozen = dict[str, tuple[tuple[str, ...], dict[str, np.ndarray], bool]]
"""Per learner: the agents it plays, its actor's tensors (``actor.*``, ``obs_norm.*``) as numpy, whether it
normalises observations: what its policy file would hold now."""


def frozen_tensors(learner: Learner) -> tuple[dict[str, np.ndarray], bool]:
    """The learner's current deterministic policy as numpy tensors (``actor.*``, and ``obs_norm.*`` when it
    normalises observations), copied (the worker pickles them while the learner trains on): what its policy file
    would hold now."""
    tensors = {f"actor.{k}": v.detach().cpu().numpy().copy()
               for k, v in learner.algo.export_actor().state_dict().items()}
    norm = learner.algo.obs_norm
    if norm is not None:
        tensors |= {f"obs_norm.{k}": v.detach().cpu().numpy().copy() for k, v in norm.state_dict().items()}
    return tensors, norm is not None


def frozen_policy(tensors: Mapping[str, np.ndarray], normalizes: bool) -> FrozenPolicy:
    """The numpy :class:`FrozenPolicy` of :func:`frozen_tensors`."""
    return FrozenPolicy.from_tensors(tensors, prefix="actor.", obs_norm_prefix="obs_norm." if normalizes else None)


Played = dict[str, list[tuple[str, int]]]
"""Per learner, the outcome and length of each test match played, in order."""


def play_evaluation_part(frozen: Frozen, pairs: tuple[str, ...], match_cfg: MatchConfig, obs_mode: str,
                         obs_dims: Mapping[str, int], action_sizes: Mapping[str, int], first: int, end: int,
                         seed: int, n_envs: int, n_threads: int) -> tuple[Played, float]:
    """Test matches ``first .. end - 1`` of one evaluation: each learner's frozen policy on the seeded test matches
    (test match ``i`` resets with ``seed + i``) against the fixed policies of ``pairs`` (built afresh from ``seed``)
    and the other learners' frozen policies, rated in its first agent's seat. Returns, for each learner, the outcome
    and length of each match, and the seconds they took. Depends on its arguments only, so a worker process plays it
    as the training process does; and as a match depends on its seed only, the parts of an evaluation played apart
    and put together in order are the evaluation played whole."""
    from triplesumo.evaluation.evaluate import play_test_epochs

    t0 = time.perf_counter()
    fixed = policies_from_pairs(pairs, seed, obs_mode, obs_dims=dict(obs_dims), action_sizes=dict(action_sizes))
    policies = {name: frozen_policy(tensors, norm) for name, (_, tensors, norm) in frozen.items()}
    seats = {agent: policies[name] for name, (agents, _, _) in frozen.items() for agent in agents}
    played: Played = {}
    for name, (agents, _, _) in frozen.items():
        agent = agents[0]
        others = {**fixed, **{a: p for a, p in seats.items() if a != agent}}
        rows = play_test_epochs(policies[name], others, agent, end, seed, match_cfg, n_envs, n_threads, first=first)
        played[name] = [(r["outcome"], r["steps"]) for r in rows]
    return played, time.perf_counter() - t0


def summaries(played: Played) -> list[tuple[str, dict[str, Any]]]:
    """Each learner's summary (:func:`~triplesumo.evaluation.metrics.summarize`) of its test matches."""
    from triplesumo.evaluation.metrics import summarize

    return [(name, dict(summarize([o for o, _ in games], [n for _, n in games]))) for name, games in played.items()]


def shares(epochs: int, workers: int) -> list[tuple[int, int]]:
    """The ``(first, end)`` ranges an evaluation of ``epochs`` test matches is split into for ``workers`` processes:
    four per worker (the matches last differently, and a worker that finishes early takes the next), none empty,
    in order."""
    parts = min(epochs, 4 * workers) if workers > 1 else 1
    bounds = [round(k * epochs / parts) for k in range(parts + 1)]
    return list(zip(bounds[:-1], bounds[1:], strict=True))


WORKER_NICE = 19
"""The evaluation worker's niceness: on a busy machine the training keeps its cores and the evaluations take
what is left (on one with cores to spare, nothing changes)."""


def _worker_init(parent: int) -> None:
    import torch

    from triplesumo.evaluation.parallel import die_with_parent

    die_with_parent(parent)  # a training run killed with kill -9 leaves no evaluation worker behind

    torch.set_num_threads(1)  # the worker plays numpy policies; its MuJoCo threads are the run's n_threads
    if hasattr(os, "nice"):  # (POSIX; Windows has no niceness)
        os.nice(WORKER_NICE)


@dataclass
class Pending:
    """An evaluation handed to the worker, not yet written: its number, when it was made (env steps, epochs and
    the training's clock; None: restored from a checkpoint that did not record it), what it plays."""

    number: int
    env_steps: int
    epochs: int
    train_seconds: float | None
    frozen: Frozen
    futures: list[AsyncResult[tuple[Played, float]]] = field(default_factory=list)
    """The parts of its test matches handed to the workers (:func:`shares`), in order."""
    handed: float = 0.0
    """When it was handed to the workers (``time.perf_counter``)."""

    def ready(self) -> bool:
        """Whether every part is back."""
        return bool(self.futures) and all(f.ready() for f in self.futures)

    def result(self) -> tuple[list[tuple[str, dict[str, Any]]], float]:
        """Each learner's summary over the parts put together, and the seconds from handing it over to its last part
        (the wall time it took, its parts side by side); a worker's error is raised here."""
        played: Played = {}
        for future in self.futures:
            for name, games in future.get()[0].items():
                played.setdefault(name, []).extend(games)
        return summaries(played), time.perf_counter() - self.handed


class Evaluations:
    """The evaluations of a run: how many were written (:attr:`count`, the rows of each learner's eval CSV),
    those in flight (:attr:`pending`, ``eval_background``) and the wall time the training spent on them
    (:attr:`seconds`), over every leg of the run (:mod:`triplesumo.train.legs`)."""

    def __init__(self, cfg: TrainConfig, match_cfg: MatchConfig, obs_dims: Mapping[str, int],
                 action_sizes: Mapping[str, int], pairs: tuple[str, ...]) -> None:
        self.cfg, self.match_cfg, self.pairs = cfg, match_cfg, pairs
        self.obs_dims, self.action_sizes = dict(obs_dims), dict(action_sizes)
        self.count = 0
        """Evaluations written so far (``eval_every``): the rows of each learner's eval CSV."""
        self.seconds = 0.0
        """Wall time the training spent on evaluations, over every leg of the run: all of an inline
        evaluation's, only the waits for a background one (at the run's end)."""
        self.pending: list[Pending] = []
        """Background evaluations handed to the worker and not yet written, oldest first."""
        self._pool: Pool | None = None

    def due(self, steps_before: int, steps_now: int) -> bool:
        """Whether a step from ``steps_before`` to ``steps_now`` env steps crossed a multiple of ``eval_every``."""
        every = self.cfg.eval_every
        return bool(every) and steps_now // every > steps_before // every

    def _args(self, frozen: Frozen, first: int, end: int) -> tuple[Any, ...]:
        """The arguments of :func:`play_evaluation_part` for test matches ``first .. end - 1``."""
        cfg = self.cfg
        return (frozen, self.pairs, self.match_cfg, cfg.obs_mode, self.obs_dims, self.action_sizes, first, end,
                cfg.eval_seed, cfg.n_envs, cfg.n_threads)

    def _submit(self, job: Pending) -> None:
        cfg = self.cfg
        if self._pool is None:  # spawned, not forked: the training process holds threads (torch, the learner's)
            self._pool = multiprocessing.get_context("spawn").Pool(cfg.eval_workers, initializer=_worker_init,
                                                                   initargs=(os.getpid(),))
        job.handed = time.perf_counter()
        job.futures = [self._pool.apply_async(play_evaluation_part, self._args(job.frozen, first, end))
                       for first, end in shares(cfg.eval_epochs, cfg.eval_workers)]
        self.pending.append(job)

    def __call__(self, learners: Sequence[Learner], log: MetricsLog, env_steps: int, epochs: int,
                 train_seconds: float) -> bool:
        """Evaluate each learner's current policy, frozen (no exploration), on the run's seeded test matches
        (``eval_epochs`` from ``eval_seed``, on the CPU; :func:`play_evaluation_part`). Inline: its row is written
        now, and True means every learner's test MWR reached ``eval_target``. With ``eval_background`` it is
        handed to the worker and False is returned: :meth:`collect` writes it when it is back.

        The other agents play the run's fixed policies, built afresh from ``eval_seed`` (so every
        evaluation meets the same matches), and the other learners their current policies, frozen;
        a learner that plays several agents (``share="team"``) is rated in its first agent's seat.
        Nothing of the training is touched: it trains the same with or without evaluations."""
        frozen: Frozen = {lr.name: (tuple(lr.spec.agents), *frozen_tensors(lr)) for lr in learners}
        job = Pending(self.count + len(self.pending) + 1, env_steps, epochs, train_seconds, frozen)
        if self.cfg.eval_background:
            self._submit(job)
            return False
        reached = self.collect(log, train_seconds, wait=True)  # (ones a resume handed to the worker come first)
        t0 = time.perf_counter()
        games, played = play_evaluation_part(*self._args(frozen, 0, self.cfg.eval_epochs))
        done = summaries(games)
        self.seconds += time.perf_counter() - t0
        return self._write(job, done, played, log, train_seconds) or reached

    def collect(self, log: MetricsLog, train_seconds: float, wait: bool = False) -> bool:
        """Write the rows of the background evaluations that are back, in order (``wait``: all of them, the
        wait counted in :attr:`seconds`). True when one of them reached ``eval_target``."""
        reached = False
        while self.pending:
            job = self.pending[0]
            if not job.ready():
                if not wait:
                    break
                t0 = time.perf_counter()
                for future in job.futures:
                    future.wait()
                self.seconds += time.perf_counter() - t0  # the wait is the evaluations', not the training's
            done, played = job.result()  # (an error in the worker is raised here)
            self.pending.pop(0)
            reached = self._write(job, done, played, log, train_seconds) or reached
        return reached

    def ready(self) -> bool:
        """Whether the oldest background evaluation is back (:meth:`collect` would write it)."""
        return bool(self.pending) and self.pending[0].ready()

    def _write(self, job: Pending, done: list[tuple[str, dict[str, Any]]], played: float, log: MetricsLog,
               train_seconds: float) -> bool:
        cfg = self.cfg
        self.count += 1
        assert job.number == self.count, (job.number, self.count)
        for name, stats in done:
            log.evaluated(name, {
                "evaluation": job.number, "env_steps": job.env_steps, "epochs": job.epochs,
                "policy_train_seconds": "" if job.train_seconds is None else round(job.train_seconds, 3),
                "train_seconds": round(train_seconds, 3), "eval_seconds": round(self.seconds, 3),
                "test_matches": cfg.eval_epochs, "test_mwr": float(stats["mean_lwr"]),
                "test_mwr_lo": float(stats["mean_lwr_lo"]), "test_mwr_hi": float(stats["mean_lwr_hi"]),
                "n_win": stats["n_win"], "n_loss": stats["n_loss"], "n_draw": stats["n_draw"]})
            if cfg.progress:
                where = " (in the background)" if cfg.eval_background else ""
                print(f"  evaluation {job.number} at {job.env_steps:,} env steps: {name} test MWR "
                      f"{float(stats['mean_lwr']):+.3f} [{float(stats['mean_lwr_lo']):+.3f}, "
                      f"{float(stats['mean_lwr_hi']):+.3f}] over {cfg.eval_epochs} matches, "
                      f"played in {played:.0f} s{where}")
        return cfg.eval_target is not None and all(float(stats["mean_lwr"]) >= cfg.eval_target for _, stats in done)

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> State:
        """The evaluations written and the time spent on them; those in flight, as records (state.json) and
        frozen weights (arrays), which a resume hands to the worker again."""
        records: list[dict[str, Any]] = []
        arrays: dict[str, np.ndarray] = {}
        for job in self.pending:
            learners = {}
            for name, (agents, tensors, norm) in job.frozen.items():
                learners[name] = {"agents": list(agents), "obs_norm": norm, "tensors": sorted(tensors)}
                arrays |= {f"pending_eval{job.number}.{name}.{k}": v for k, v in tensors.items()}
            records.append({"number": job.number, "env_steps": job.env_steps, "epochs": job.epochs,
                            "train_seconds": job.train_seconds, "learners": learners})
        return State(json={"evaluations": self.count, "eval_seconds": self.seconds, "pending_evaluations": records},
                     arrays=arrays)

    def load_state_dict(self, state: State) -> None:
        """Restore :meth:`state_dict` (0 evaluations for a checkpoint written before they were counted)."""
        saved, arrays = state.json, state.arrays
        self.count = int(saved.get("evaluations", 0))
        self.seconds = float(saved.get("eval_seconds", 0.0))
        for record in saved.get("pending_evaluations", []):
            number = int(record["number"])
            frozen: Frozen = {name: (tuple(entry["agents"]),
                                     {k: np.asarray(arrays[f"pending_eval{number}.{name}.{k}"])
                                      for k in entry["tensors"]}, bool(entry["obs_norm"]))
                              for name, entry in record["learners"].items()}
            seconds = record.get("train_seconds")  # (None: a checkpoint from before it was kept)
            job = Pending(number, int(record["env_steps"]), int(record["epochs"]),
                          None if seconds is None else float(seconds), frozen)
            if job.number != self.count + len(self.pending) + 1:
                raise ValueError(f"checkpoint: pending evaluation {number} does not follow the "
                                 f"{self.count} written")
            self._submit(job)  # (in the worker even when the run goes on without eval_background)

    def close(self) -> None:
        """Stop the worker at once (evaluations still in flight are dropped: a checkpoint holds them)."""
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None
