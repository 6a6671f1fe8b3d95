"""The project's own work as Ray tasks: evaluations, tournaments and training sweeps on a Ray cluster.

:class:`RayRunner` is the :class:`~triplesumo.evaluation.parallel.TaskRunner` of Ray: each task
(a chunk of matches, a training trial) is one Ray task, and results come back as they finish.
The command line builds one for ``--ray`` (:func:`ray_runner`) and hands it down to
:func:`~triplesumo.evaluation.evaluate.evaluate`, :func:`~triplesumo.evaluation.tournament.run_tournament`
and :func:`~triplesumo.train.sweep.run_sweep`, which never import Ray or this module. The
chunks are played with the same code as a local run
(:func:`~triplesumo.evaluation.parallel.play_chunks`), so the rows equal a local run's for the
same seeds. A task whose worker dies is run again (``max_retries``); its matches replay
exactly, and a retried trial resumes from its run's last checkpoint.

Policies travel as specs (``"zoo:ant"``, a policy-file path every node can read,
``"zero"``, ``"random"``) and are built inside each task. :func:`session` connects to
Ray (``address``: a cluster; empty: a local ``ray.init()``) unless it already is.

:func:`play_chunks_on_ray`, :func:`play_test_epochs_on_ray`, :func:`play_tournament_on_ray` and
:func:`run_trials_on_ray` are those calls with a :class:`RayRunner`.

Needs the ``ray`` extra (``pip install "triplesumo[ray]"``).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

try:
    import ray
except ImportError as exc:  # pragma: no cover - exercised in a subprocess test
    raise ImportError('triplesumo.integrations.ray_tasks needs Ray, which is not installed: '
                      'pip install "triplesumo[ray]"') from exc

from triplesumo.evaluation.evaluate import play_test_epochs_on
from triplesumo.evaluation.parallel import Finished, check_counts, play_chunks, portable_spec
from triplesumo.evaluation.tournament import play_tournament_on
from triplesumo.rules.config import MatchConfig
from triplesumo.train.sweep import run_trials

__all__ = ["RayRunner", "play_chunks_on_ray", "play_test_epochs_on_ray", "play_tournament_on_ray", "portable_spec",
           "ray_runner", "run_trials_on_ray", "session"]

T = TypeVar("T")
Row = dict[str, Any]


NICENESS_VARIABLE = "RAY_worker_niceness"
WORKER_NICENESS = 0
"""How much a local Ray started by :func:`session` lowers its workers' priority below the caller's (Ray's default:
15)."""


@contextmanager
def session(address: str = "", num_cpus: int | None = None) -> Iterator[None]:
    """Connected to Ray inside the block: the Ray already initialised, else ``ray.init(address)``
    (empty: start a local Ray with ``num_cpus``, default all cores), shut down again at the end.

    A local Ray started here runs its tasks at this process's priority (:data:`WORKER_NICENESS`): Ray's own default
    lowers its workers by 15, so on a machine doing other work the tasks, which are the work here, would wait for
    everything else. ``RAY_worker_niceness`` set in the environment still wins."""
    if ray.is_initialized():
        yield
        return
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        before = os.environ.get(NICENESS_VARIABLE)
        os.environ.setdefault(NICENESS_VARIABLE, str(WORKER_NICENESS))  # read when ray.init starts the raylet
        try:
            ray.init(num_cpus=num_cpus or None, include_dashboard=False, log_to_driver=False)
        finally:
            if before is None:
                os.environ.pop(NICENESS_VARIABLE, None)
    try:
        yield
    finally:
        ray.shutdown()


@dataclass(frozen=True)
class RayRunner:
    """A :class:`~triplesumo.evaluation.parallel.TaskRunner` on Ray (connected first: :func:`session`)."""

    max_retries: int = 3
    """Times a task whose worker died is run again."""

    def __call__(self, fn: Callable[..., T], tasks: Sequence[tuple[Any, ...]], cpus: int = 1) -> Finished[T]:
        if not ray.is_initialized():
            raise RuntimeError("call ray.init() (or ray.init(address=...)) before running tasks on Ray")
        check_counts(cpus=cpus)
        task = ray.remote(num_cpus=cpus, max_retries=self.max_retries)(fn)
        pending = {task.remote(*args): k for k, args in enumerate(tasks)}
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    yield pending.pop(ref), _getter(ref)
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)


def _getter(ref: Any) -> Callable[[], Any]:
    """``ray.get`` of ``ref``, called when the result is wanted (raising the task's error then)."""
    return lambda: ray.get(ref)


@contextmanager
def ray_runner(address: str = "", num_cpus: int | None = None, max_retries: int = 3) -> Iterator[RayRunner]:
    """A :class:`RayRunner` inside a :func:`session` (what the command line hands down for ``--ray``)."""
    with session(address, num_cpus):
        yield RayRunner(max_retries)


def play_chunks_on_ray(play: Callable[..., list[Row]], args: Sequence[Any], n: int, first: int = 0, chunk: int = 50,
                       on_row: Callable[[Row], None] | None = None, max_retries: int = 3,
                       progress: str | None = None) -> list[Row]:
    """:func:`~triplesumo.evaluation.parallel.play_chunks` on a :class:`RayRunner`."""
    return play_chunks(RayRunner(max_retries), play, args, n, first, chunk, on_row, progress)


def play_test_epochs_on_ray(learner_spec: str, other_specs: Mapping[str, str], learner: str, epochs: int, seed: int,
                            match_cfg: MatchConfig | None = None, first: int = 0, chunk: int = 50,
                            n_envs: int = 8, max_retries: int = 3, on_row: Callable[[Row], None] | None = None,
                            record: int = 0, record_dir: Path | None = None, policy_names: dict[str, str] | None = None,
                            progress: str | None = None) -> list[Row]:
    """:func:`~triplesumo.evaluation.evaluate.play_test_epochs_on` on a :class:`RayRunner`: the rows of
    ``play_test_epochs`` with the same policies and seeds."""
    return play_test_epochs_on(RayRunner(max_retries), learner_spec, other_specs, learner, epochs, seed, match_cfg,
                               first, chunk, n_envs, on_row, record, record_dir, policy_names, progress)


def play_tournament_on_ray(cfg: Any, match_cfg: MatchConfig | None = None, first: int = 0, n: int | None = None,
                           chunk: int = 50, on_row: Callable[[Row], None] | None = None, max_retries: int = 3,
                           progress: str | None = None) -> list[Row]:
    """:func:`~triplesumo.evaluation.tournament.play_tournament_on` on a :class:`RayRunner`: the rows of
    ``matches.csv`` a local run writes."""
    return play_tournament_on(RayRunner(max_retries), cfg, match_cfg, first, n, chunk, on_row, progress)


def run_trials_on_ray(configs: Sequence[Any], on_done: Callable[[int, dict[str, Any]], None] | None = None,
                      cpus_per_trial: int = 1, max_retries: int = 3) -> list[dict[str, Any]]:
    """:func:`~triplesumo.train.sweep.run_trials` on a :class:`RayRunner`: a task whose worker dies is run
    again and resumes its run from the last checkpoint; a trial that fails for good gives ``{"trial", "error"}``
    and the others go on."""
    if not ray.is_initialized():
        raise RuntimeError("call ray.init() (or ray.init(address=...)) before running trials on Ray")
    return run_trials(RayRunner(max_retries), configs, on_done, cpus_per_trial)
