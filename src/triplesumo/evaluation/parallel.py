"""Where chunks of work run: handed down by the caller, never chosen here.

:func:`~triplesumo.evaluation.evaluate.evaluate`, :func:`~triplesumo.evaluation.tournament.run_tournament`
and :func:`~triplesumo.train.sweep.run_sweep` are given a :class:`TaskRunner`: a map-like
callable that runs ``fn(*task)`` for every task and hands back each result as its task
finishes. :class:`ThreadRunner` runs the tasks on threads of this process; Ray's runner is
:class:`triplesumo.integrations.ray_tasks.RayRunner`, which the command line builds for
``--ray``. So nothing in :mod:`triplesumo.evaluation` or :mod:`triplesumo.train` imports Ray
or :mod:`triplesumo.integrations`: the layers stay one-way (STYLE.md).

:func:`play_chunks` is the one pattern of a schedule of matches: matches ``first .. n - 1``
are cut into chunks, each chunk is a task that plays its matches with the same code as a
local run, and the rows come back in schedule order, handed to ``on_row`` as soon as a
chunk and every earlier one are done (so a killed run keeps its finished rows and
``--resume`` continues it). Match ``i`` depends on its seed and lineup alone, so the rows
equal a local run's for the same seeds, whichever runner played them.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

from triplesumo.agents.builtin import BUILTIN

__all__ = ["Finished", "Row", "TaskRunner", "ThreadRunner", "check_counts", "play_chunks", "portable_spec"]

T = TypeVar("T")
Row = dict[str, Any]
Finished = Generator[tuple[int, Callable[[], T]], None, None]
"""What a runner yields: ``(k, get)`` for task ``k`` as it finishes (in any order); ``get()`` returns the task's
result or raises its error. Closing the generator cancels the tasks not yet finished."""


class TaskRunner(Protocol):
    """Runs ``fn(*tasks[k])`` for every ``k`` and yields ``(k, get)`` as each task finishes (:data:`Finished`).

    ``fn`` is a module-level function and its arguments plain data (a runner may run it in
    another process or on another machine); ``cpus``: the cores one task needs."""

    def __call__(self, fn: Callable[..., T], tasks: Sequence[tuple[Any, ...]], cpus: int = 1) -> Finished[T]: ...


@dataclass(frozen=True)
class ThreadRunner:
    """A :class:`TaskRunner` on ``workers`` threads of this process (MuJoCo steps outside the GIL)."""

    workers: int = 1
    """Tasks run at once."""

    def __post_init__(self) -> None:
        check_counts(**{"ThreadRunner.workers": self.workers})

    def __call__(self, fn: Callable[..., T], tasks: Sequence[tuple[Any, ...]], cpus: int = 1) -> Finished[T]:
        check_counts(cpus=cpus)
        with ThreadPoolExecutor(self.workers) as pool:
            pending: dict[Future[T], int] = {pool.submit(fn, *args): k for k, args in enumerate(tasks)}
            try:
                while pending:
                    done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
                    for future in sorted(done, key=pending.__getitem__):
                        yield pending.pop(future), future.result
            finally:
                for future in pending:
                    future.cancel()


def check_counts(**values: int) -> None:
    """``ValueError`` naming the first of ``values`` that is not an int >= 1."""
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be an int >= 1, got {value!r}")


def portable_spec(spec: str) -> str:
    """A policy spec that means the same in another process or on another node: policy-file paths made absolute."""
    if spec in BUILTIN or spec.startswith("zoo:"):
        return spec
    return str(Path(spec).resolve())


def play_chunks(runner: TaskRunner, play: Callable[..., list[Row]], args: Sequence[Any], n: int, first: int = 0,
                chunk: int = 50, on_row: Callable[[Row], None] | None = None, progress: str | None = None) -> list[Row]:
    """Rows of matches ``first .. n - 1``: ``play(*args, a, b)`` (the rows of matches ``a .. b - 1``) run by
    ``runner`` as one task per chunk of ``chunk`` matches; rows in schedule order, each handed to ``on_row``
    once it and every earlier row are in. ``play`` must be a module-level function."""
    check_counts(n=n, chunk=chunk)
    if not 0 <= first < n:
        raise ValueError(f"first must be in [0, n={n}), got {first}")
    bounds = [(a, min(a + chunk, n)) for a in range(first, n, chunk)]
    done: dict[int, list[Row]] = {}
    rows: list[Row] = []
    next_chunk = 0
    bar = None
    if progress is not None:
        from tqdm import tqdm

        bar = tqdm(total=n, initial=first, unit="match", desc=progress, dynamic_ncols=True)
    try:
        with closing(runner(play, [(*args, a, b) for a, b in bounds])) as finished:
            for k, get in finished:
                done[k] = get()
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
    return rows
