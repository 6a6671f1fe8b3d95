"""The project's own work as Ray tasks: evaluations, tournaments and training sweeps on a Ray cluster.

:func:`play_chunks_on_ray` is the one pattern: a schedule of matches ``first .. n - 1``
is cut into chunks, each chunk is a Ray task that plays its matches with the same code as
a local run (:func:`~triplesumo.evaluation.evaluate.play_test_epochs`,
:func:`~triplesumo.evaluation.tournament.play_schedule`), and the rows come back in
schedule order, handed to ``on_row`` as soon as a chunk and every earlier one are done
(so a killed run keeps its finished rows and ``--resume`` continues it). Match ``i``
depends on its seed and lineup alone, so the rows equal a local run's for the same seeds.
A task whose worker dies is run again (``max_retries``); its matches replay exactly.

:func:`run_trials_on_ray` runs training runs (:func:`triplesumo.train.sweep.run_trial`)
as tasks; a retried trial resumes from its run's last checkpoint.

Policies travel as specs (``"zoo:ant"``, a policy-file path every node can read,
``"zero"``, ``"random"``) and are built inside each task. :func:`session` connects to
Ray (``address``: a cluster; empty: a local ``ray.init()``) unless it already is.

Needs the ``ray`` extra (``pip install "triplesumo[ray]"``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

try:
    import ray
except ImportError as exc:  # pragma: no cover - exercised in a subprocess test
    raise ImportError('triplesumo.integrations.ray_tasks needs Ray, which is not installed: '
                      'pip install "triplesumo[ray]"') from exc

from triplesumo.agents.builtin import BUILTIN
from triplesumo.evaluation.evaluate import play_test_chunk
from triplesumo.rules.config import MatchConfig

__all__ = ["play_chunks_on_ray", "play_test_epochs_on_ray", "play_tournament_on_ray", "portable_spec",
           "run_trials_on_ray", "session"]

Row = dict[str, Any]


@contextmanager
def session(address: str = "", num_cpus: int | None = None) -> Iterator[None]:
    """Connected to Ray inside the block: the Ray already initialised, else ``ray.init(address)``
    (empty: start a local Ray with ``num_cpus``, default all cores), shut down again at the end."""
    if ray.is_initialized():
        yield
        return
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        ray.init(num_cpus=num_cpus or None, include_dashboard=False, log_to_driver=False)
    try:
        yield
    finally:
        ray.shutdown()


def portable_spec(spec: str) -> str:
    """A policy spec that means the same in a Ray worker: policy-file paths made absolute."""
    if spec in BUILTIN or spec.startswith("zoo:"):
        return spec
    return str(Path(spec).resolve())


def _check_counts(**values: int) -> None:
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be an int >= 1, got {value!r}")


def play_chunks_on_ray(play: Callable[..., list[Row]], args: Sequence[Any], n: int, first: int = 0, chunk: int = 50,
                       on_row: Callable[[Row], None] | None = None, max_retries: int = 3,
                       progress: str | None = None) -> list[Row]:
    """Rows of matches ``first .. n - 1``: ``play(*args, a, b)`` (the rows of matches ``a .. b - 1``)
    run as one Ray task per chunk of ``chunk`` matches; rows in schedule order, each handed to
    ``on_row`` once it and every earlier row are in. ``play`` must be a module-level function."""
    if not ray.is_initialized():
        raise RuntimeError("call ray.init() (or ray.init(address=...)) before playing matches on Ray")
    _check_counts(n=n, chunk=chunk)
    if not 0 <= first < n:
        raise ValueError(f"first must be in [0, n={n}), got {first}")
    task = ray.remote(num_cpus=1, max_retries=max_retries)(play)
    bounds = [(a, min(a + chunk, n)) for a in range(first, n, chunk)]
    pending = {task.remote(*args, a, b): k for k, (a, b) in enumerate(bounds)}
    done: dict[int, list[Row]] = {}
    rows: list[Row] = []
    next_chunk = 0
    bar = None
    if progress is not None:
        from tqdm import tqdm

        bar = tqdm(total=n, initial=first, unit="match", desc=progress, dynamic_ncols=True)
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                k = pending.pop(ref)
                done[k] = ray.get(ref)
                if bar is not None:
                    bar.update(bounds[k][1] - bounds[k][0])
            while next_chunk in done:
                for row in done.pop(next_chunk):
                    rows.append(row)
                    if on_row is not None:
                        on_row(row)
                next_chunk += 1
    finally:
        if bar is not None:
            bar.close()
        for ref in pending:
            ray.cancel(ref, force=True)
    return rows


def play_test_epochs_on_ray(learner_spec: str, other_specs: Mapping[str, str], learner: str, epochs: int, seed: int,
                            match_cfg: MatchConfig | None = None, first: int = 0, chunk: int = 50,
                            n_envs: int = 8, max_retries: int = 3, on_row: Callable[[Row], None] | None = None,
                            record: int = 0, record_dir: Path | None = None, policy_names: dict[str, str] | None = None,
                            progress: str | None = None) -> list[Row]:
    """Rows of test epochs ``first .. epochs - 1``, played as Ray tasks of ``chunk`` epochs each.

    The same rows as ``play_test_epochs`` with the same policies and seeds, in epoch order
    (``on_row`` gets each as soon as it and every earlier one are in). A task whose worker
    dies is run again (``max_retries``); its epochs replay exactly. Match files of epochs
    ``< record`` are written by the workers into ``record_dir`` (a folder every node can reach), with
    ``policy_names`` (default: the specs) stored in them.
    """
    _check_counts(epochs=epochs, chunk=chunk, n_envs=n_envs)
    if not 0 <= first < epochs:
        raise ValueError(f"first must be in [0, epochs={epochs}), got {first}")
    specs = {a: portable_spec(s) for a, s in other_specs.items()}
    args = (portable_spec(learner_spec), specs, learner, seed, match_cfg or MatchConfig(), n_envs, record,
            None if record_dir is None else str(Path(record_dir).resolve()), policy_names)
    return play_chunks_on_ray(play_test_chunk, args, epochs, first, chunk, on_row, max_retries, progress)


def _play_tournament_chunk(cfg: Any, match_cfg: MatchConfig | None, first: int, end: int) -> list[Row]:
    from triplesumo.evaluation.tournament import play_schedule

    return play_schedule(cfg, match_cfg, first, end)


def play_tournament_on_ray(cfg: Any, match_cfg: MatchConfig | None = None, first: int = 0, n: int | None = None,
                           chunk: int = 50, on_row: Callable[[Row], None] | None = None, max_retries: int = 3,
                           progress: str | None = None) -> list[Row]:
    """Rows of matches ``first .. n - 1`` of the tournament of ``cfg`` (a
    :class:`~triplesumo.evaluation.tournament.TournamentConfig`; ``n``: its whole schedule), as Ray
    tasks: the rows of ``matches.csv`` a local run writes."""
    import dataclasses

    from triplesumo.evaluation.tournament import Tournament, parse_entries

    if n is None:
        n = Tournament(cfg, match_cfg).n_matches
    portable = dataclasses.replace(cfg, policies=tuple(f"{k}={portable_spec(v)}"
                                                       for k, v in parse_entries(cfg.policies).items()))
    return play_chunks_on_ray(_play_tournament_chunk, (portable, match_cfg), n, first, chunk, on_row, max_retries,
                              progress)


def _run_trial(cfg: Any) -> dict[str, Any]:
    from triplesumo.train.sweep import run_trial

    return run_trial(cfg)


def run_trials_on_ray(configs: Sequence[Any], on_done: Callable[[int, dict[str, Any]], None] | None = None,
                      cpus_per_trial: int = 1, max_retries: int = 3) -> list[dict[str, Any]]:
    """Train every :class:`~triplesumo.train.config.TrainConfig` of ``configs`` as a Ray task
    (:func:`~triplesumo.train.sweep.run_trial`); results in ``configs`` order, each handed to
    ``on_done(index, result)`` as it finishes. A task whose worker dies is run again and resumes
    its run from the last checkpoint; a trial that fails for good gives ``{"trial", "error"}``
    and the others go on."""
    if not ray.is_initialized():
        raise RuntimeError("call ray.init() (or ray.init(address=...)) before running trials on Ray")
    _check_counts(cpus_per_trial=cpus_per_trial)
    task = ray.remote(num_cpus=cpus_per_trial, max_retries=max_retries)(_run_trial)
    pending = {task.remote(cfg): k for k, cfg in enumerate(configs)}
    results: dict[int, dict[str, Any]] = {}
    try:
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                k = pending.pop(ref)
                try:
                    results[k] = ray.get(ref)
                except ray.exceptions.RayError as exc:  # the trial failed (or its retries ran out): the others go on
                    cause = getattr(exc, "cause", None) or exc
                    last = str(cause).strip().splitlines()[-1:] or [""]
                    results[k] = {"trial": getattr(configs[k], "name", str(k)),
                                  "error": f"{type(cause).__name__}: {last[0]}"}
                if on_done is not None:
                    on_done(k, results[k])
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
    return [results[k] for k in range(len(configs))]
