"""Where chunks of work run: handed down by the caller, never chosen here.

:func:`~triplesumo.evaluation.evaluate.evaluate`, :func:`~triplesumo.evaluation.tournament.run_tournament`
and :func:`~triplesumo.train.sweep.run_sweep` are given a :class:`TaskRunner`: a map-like
callable that runs ``fn(*task)`` for every task and hands back each result as its task
finishes. :class:`ThreadRunner` runs the tasks on threads of this process, :class:`ProcessRunner` in
worker processes of this machine (what ``evaluate --workers N`` plays on); Ray's runner is
:class:`triplesumo.integrations.ray_tasks.RayRunner`, which the command line builds for
``--ray``. So nothing in :mod:`triplesumo.evaluation` or :mod:`triplesumo.train` imports Ray
or :mod:`triplesumo.integrations`: the layers stay one-way (the import-linter contracts in ``pyproject.toml``).

:func:`play_chunks` is the one pattern of a schedule of matches: matches ``first .. n - 1``
are cut into chunks, each chunk is a task that plays its matches with the same code as a
local run, and the rows come back in schedule order, handed to ``on_row`` as soon as a
chunk and every earlier one are done (so a killed run keeps its finished rows and
``--resume`` continues it). Match ``i`` depends on its seed and lineup alone, so the rows
equal a local run's for the same seeds, whichever runner played them. :func:`play_schedules`
does the same for several schedules at once (an evaluation's candidates): their tasks go to the
runner in one queue, chunk-major (the first chunk of every schedule before the second of any),
so a stopped run leaves them about equally far.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Generator, Hashable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

from triplesumo.agents.builtin import BUILTIN

__all__ = ["ONE_THREAD", "Finished", "ProcessRunner", "Row", "TaskRunner", "ThreadRunner", "check_counts",
           "die_with_parent", "play_chunks", "play_schedules", "portable_spec"]

T = TypeVar("T")
K = TypeVar("K", bound=Hashable)
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
            yield from _finished(pool, fn, tasks)


ONE_THREAD = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
"""Variables a :class:`ProcessRunner` sets to 1 for its worker processes (unless set already)."""


@dataclass(frozen=True)
class ProcessRunner:
    """A :class:`TaskRunner` on ``workers`` processes of this machine, each on one core (:data:`ONE_THREAD`).

    The processes are started with ``spawn``, never ``fork``: a child forked after torch ran its
    thread pool can hang in its next torch call (see :mod:`triplesumo.agents.frozen`). So ``fn``
    and the tasks' arguments are pickled, and ``fn`` must be importable by module and name. They die with
    this process (:func:`die_with_parent`), ``kill -9`` included."""

    workers: int = 1
    """Tasks run at once."""

    def __post_init__(self) -> None:
        check_counts(**{"ProcessRunner.workers": self.workers})

    def __call__(self, fn: Callable[..., T], tasks: Sequence[tuple[Any, ...]], cpus: int = 1) -> Finished[T]:
        check_counts(cpus=cpus)
        saved = {name: os.environ.get(name) for name in ONE_THREAD}
        os.environ.update({name: os.environ.get(name) or "1" for name in ONE_THREAD})  # inherited by the workers
        try:
            with ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                     initializer=die_with_parent, initargs=(os.getpid(),)) as pool:
                yield from _finished(pool, fn, tasks)
        finally:
            for name, value in saved.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value


def die_with_parent(parent: int) -> None:
    """Make this worker process end when its parent ``parent`` (a PID) does, however the parent ends (``kill -9``
    included): a worker initializer. On Linux the kernel sends it SIGKILL when the parent exits
    (``prctl(PR_SET_PDEATHSIG)``); elsewhere a daemon thread checks every half second that the parent is still
    the one it was started by. A worker whose parent is gone already exits at once. With its workers gone, the
    resource tracker of :mod:`multiprocessing` reads the end of its pipe and exits too: nothing is left running."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            set_pdeathsig = 1  # PR_SET_PDEATHSIG, <linux/prctl.h>
            armed = libc.prctl(set_pdeathsig, signal.SIGKILL, 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    else:
        armed = False
    if os.getppid() != parent:  # the parent died before the signal was armed
        os._exit(1)
    if armed:
        return

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, name="die-with-parent", daemon=True).start()


def _finished(pool: Executor, fn: Callable[..., T], tasks: Sequence[tuple[Any, ...]]) -> Finished[T]:
    """The tasks submitted to ``pool`` in order, yielded as they finish (:data:`Finished`); closing cancels the rest."""
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
    once it and every earlier row are in. ``play`` must be a module-level function. (:func:`play_schedules`
    with one schedule.)"""

    def hand_on(_: int, row: Row) -> None:
        if on_row is not None:
            on_row(row)

    return play_schedules(runner, play, {0: args}, n, {0: first}, chunk, hand_on, progress)[0]


def play_schedules(runner: TaskRunner, play: Callable[..., list[Row]], args: Mapping[K, Sequence[Any]], n: int,
                   firsts: Mapping[K, int] | None = None, chunk: int = 50,
                   on_row: Callable[[K, Row], None] | None = None, progress: str | None = None) -> dict[K, list[Row]]:
    """Rows of several schedules of ``n`` matches: schedule ``key`` plays matches ``firsts[key] .. n - 1``
    (default from 0) as ``play(*args[key], a, b)`` (the rows of matches ``a .. b - 1``), in chunks of ``chunk``.

    All the chunks go to ``runner`` as tasks in one queue, chunk-major: the first chunk of every schedule
    before the second of any. Each schedule's rows come back in its order, each handed to ``on_row(key, row)``
    once it and every earlier row of its schedule are in. A failing task raises its error after the rows
    handed on before it. ``play`` must be a module-level function."""
    check_counts(n=n, chunk=chunk)
    starts = {key: 0 if firsts is None else firsts.get(key, 0) for key in args}
    for key, first in starts.items():
        if not 0 <= first < n:
            raise ValueError(f"first must be in [0, n={n}), got {first}" + ("" if len(args) == 1 else f" ({key!r})"))
    bounds = {key: [(a, min(a + chunk, n)) for a in range(first, n, chunk)] for key, first in starts.items()}
    order = [(key, k) for k in range(max(map(len, bounds.values()), default=0)) for key in bounds
             if k < len(bounds[key])]
    done: dict[K, dict[int, list[Row]]] = {key: {} for key in args}
    rows: dict[K, list[Row]] = {key: [] for key in args}
    next_chunk = dict.fromkeys(args, 0)
    if not order:
        return rows
    bar = None
    if progress is not None:
        from tqdm import tqdm

        bar = tqdm(total=n * len(args), initial=sum(starts.values()), unit="match", desc=progress,
                   dynamic_ncols=True)
    try:
        with closing(runner(play, [(*args[key], *bounds[key][k]) for key, k in order])) as finished:
            for t, get in finished:
                key, k = order[t]
                done[key][k] = get()
                if bar is not None:
                    bar.update(bounds[key][k][1] - bounds[key][k][0])
                while next_chunk[key] in done[key]:
                    for row in done[key].pop(next_chunk[key]):
                        rows[key].append(row)
                        if on_row is not None:
                            on_row(key, row)
                    next_chunk[key] += 1
    finally:
        if bar is not None:
            bar.close()
    return rows
