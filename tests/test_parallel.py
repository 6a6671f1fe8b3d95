"""Parallel execution is handed down: evaluate, tournaments and sweeps run their chunks on the runner they are
given, and a runner changes where the chunks run, never the rows."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest

from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate
from triplesumo.evaluation.parallel import (
    ONE_THREAD,
    Finished,
    ProcessRunner,
    TaskRunner,
    ThreadRunner,
    play_chunks,
    play_schedules,
)
from triplesumo.evaluation.tournament import TournamentConfig, run_tournament
from triplesumo.model.specs import AgentSpec
from triplesumo.rules.config import MatchConfig
from triplesumo.train.sweep import run_trials


def _span(tag: str, first: int, end: int) -> list[dict[str, Any]]:
    if tag == "boom" and first >= 4:
        raise RuntimeError(f"chunk {first}..{end} failed")
    return [{"i": i, "tag": tag} for i in range(first, end)]


def _threads_env() -> dict[str, str | None]:
    return {name: os.environ.get(name) for name in ONE_THREAD}


def test_play_chunks_hands_on_rows_in_schedule_order_from_any_runner() -> None:
    seen: list[int] = []
    rows = play_chunks(ThreadRunner(3), _span, ("ok",), 11, first=1, chunk=3, on_row=lambda r: seen.append(r["i"]))
    assert [r["i"] for r in rows] == seen == list(range(1, 11))
    with pytest.raises(ValueError, match="chunk must be an int >= 1"):
        play_chunks(ThreadRunner(), _span, ("ok",), 4, chunk=0)
    with pytest.raises(ValueError, match=r"first must be in \[0, n=4\)"):
        play_chunks(ThreadRunner(), _span, ("ok",), 4, first=4)
    with pytest.raises(ValueError, match="ThreadRunner.workers must be an int >= 1"):
        ThreadRunner(0)


def test_a_failing_chunk_raises_its_error_after_the_rows_before_it() -> None:
    seen: list[int] = []
    with pytest.raises(RuntimeError, match="chunk 4..6 failed"):
        play_chunks(ThreadRunner(1), _span, ("boom",), 8, chunk=2, on_row=lambda r: seen.append(r["i"]))
    assert seen == [0, 1, 2, 3]


@dataclasses.dataclass
class _Recording:
    """A runner that notes the tasks it is given and hands them to ``runner``."""

    runner: TaskRunner
    tasks: list[tuple[Any, ...]] = dataclasses.field(default_factory=list)

    def __call__(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]], cpus: int = 1) -> Finished[Any]:
        self.tasks.extend(tasks)
        yield from self.runner(fn, tasks, cpus)


def test_play_schedules_queues_chunk_major_and_hands_on_each_schedules_rows_in_order() -> None:
    runner = _Recording(ThreadRunner(3))
    seen: list[tuple[str, int]] = []
    rows = play_schedules(runner, _span, {"a": ("a",), "b": ("b",), "c": ("c",)}, 7, {"b": 2, "c": 6}, chunk=2,
                          on_row=lambda key, r: seen.append((key, r["i"])))
    assert runner.tasks == [("a", 0, 2), ("b", 2, 4), ("c", 6, 7), ("a", 2, 4), ("b", 4, 6), ("a", 4, 6),
                            ("b", 6, 7), ("a", 6, 7)]  # the first chunk of every schedule before the second of any
    assert {key: [r["i"] for r in got] for key, got in rows.items()} == {"a": list(range(7)), "b": [2, 3, 4, 5, 6],
                                                                         "c": [6]}
    assert [(key, i) for key, i in seen if key == "b"] == [("b", i) for i in range(2, 7)]
    assert sorted(seen) == sorted((key, r["i"]) for key, got in rows.items() for r in got)
    assert play_schedules(runner, _span, {}, 7) == {}
    with pytest.raises(ValueError, match=r"first must be in \[0, n=7\), got 7 \('c'\)"):
        play_schedules(runner, _span, {"a": ("a",), "c": ("c",)}, 7, {"c": 7})


@pytest.mark.slow  # 29 s alone on the shared 2-core box
def test_a_process_runner_plays_the_rows_of_a_thread_runner_in_order(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ONE_THREAD:
        monkeypatch.delenv(name, raising=False)
    schedules = {"a": ("ok",), "b": ("ok2",)}
    seen: list[tuple[str, int]] = []
    in_processes = play_schedules(ProcessRunner(2), _span, schedules, 11, {"b": 4}, chunk=3,
                                  on_row=lambda key, r: seen.append((key, r["i"])))
    assert in_processes == play_schedules(ThreadRunner(2), _span, schedules, 11, {"b": 4}, chunk=3)
    assert [i for key, i in seen if key == "a"] == list(range(11))
    assert [i for key, i in seen if key == "b"] == list(range(4, 11))
    assert play_chunks(ProcessRunner(1), _span, ("ok",), 5, first=1, chunk=2) == [
        {"i": i, "tag": "ok"} for i in range(1, 5)]
    # each worker process on one core, this process's variables as they were
    assert [get() for _, get in ProcessRunner(1)(_threads_env, [()])] == [dict.fromkeys(ONE_THREAD, "1")]
    assert _threads_env() == dict.fromkeys(ONE_THREAD)
    with pytest.raises(ValueError, match="ProcessRunner.workers must be an int >= 1"):
        ProcessRunner(0)


@pytest.mark.slow  # 7 s alone on the shared 2-core box
def test_a_failing_chunk_in_a_process_raises_its_error_after_the_rows_before_it() -> None:
    seen: list[int] = []
    with pytest.raises(RuntimeError, match="chunk 4..6 failed"):
        play_chunks(ProcessRunner(1), _span, ("boom",), 8, chunk=2, on_row=lambda r: seen.append(r["i"]))
    assert seen == [0, 1, 2, 3]


def _csv(path: Path) -> bytes:
    return path.read_bytes()


@pytest.mark.slow  # 17 s alone on the shared 2-core box
def test_evaluate_on_a_thread_runner_writes_the_bytes_of_a_local_run_and_resumes(tmp_path: Path) -> None:
    base = EvaluateConfig(policy=("random",), epochs=6, steps_per_epoch=40, n_envs=4, n_threads=1, progress=False,
                          baselines=("passive",), out=str(tmp_path / "local"))
    local = evaluate(base)
    spread = dataclasses.replace(base, out=str(tmp_path / "threads"), ray_chunk=2, epochs=3)
    evaluate(spread, ThreadRunner(2))  # a first part, then resumed to 6 epochs
    summary = evaluate(dataclasses.replace(spread, epochs=6, resume=True), ThreadRunner(2))
    for label in ("trained", "passive"):
        assert _csv(tmp_path / "threads" / label / "metrics.csv") == _csv(tmp_path / "local" / label / "metrics.csv")
    assert summary["candidates"] == local["candidates"]


def test_tournament_on_a_thread_runner_writes_the_rows_of_a_local_run(tmp_path: Path) -> None:
    duel = MatchConfig(agents=(AgentSpec("a", "a", 0.2), AgentSpec("b", "b", 0.2)), max_steps=60)
    base = TournamentConfig(policies=("passive=passive", "random=random"), rounds=3, steps_per_epoch=60,
                            n_envs=4, n_threads=1, progress=False, out=str(tmp_path / "local"))
    run_tournament(base, duel)
    run_tournament(dataclasses.replace(base, out=str(tmp_path / "threads"), ray_chunk=2), duel, ThreadRunner(2))
    for name in ("matches.csv", "leaderboard.csv"):
        assert _csv(tmp_path / "threads" / name) == _csv(tmp_path / "local" / name)


def test_ray_asked_for_without_a_runner_is_refused_before_anything_is_written(tmp_path: Path) -> None:
    pytest.importorskip("ray", reason="ray=True is refused by the config itself without the extra")
    with pytest.raises(ValueError, match="EvaluateConfig.ray: evaluate plays on the runner it is handed"):
        evaluate(EvaluateConfig(ray=True, epochs=1, out=str(tmp_path / "e")))
    with pytest.raises(ValueError, match="TournamentConfig.ray: run_tournament plays on the runner it is handed"):
        run_tournament(TournamentConfig(ray=True, out=str(tmp_path / "t")))
    with pytest.raises(ValueError, match="workers and a runner both spread"):
        evaluate(EvaluateConfig(workers=2, epochs=1, out=str(tmp_path / "w")), ThreadRunner())
    assert not list(tmp_path.iterdir())


@dataclasses.dataclass
class _Canned:
    """A runner that hands back canned outcomes (a result, or an error to raise) instead of training."""

    outcomes: list[Any]
    cpus: list[int] = dataclasses.field(default_factory=list)

    def __call__(self, fn: Callable[..., Any], tasks: Sequence[tuple[Any, ...]], cpus: int = 1) -> Finished[Any]:
        self.cpus.append(cpus)
        assert len(tasks) == len(self.outcomes)
        for k in reversed(range(len(tasks))):  # finishing out of order
            outcome = self.outcomes[k]

            def get(outcome: Any = outcome) -> Any:
                if isinstance(outcome, BaseException):
                    raise outcome
                return outcome

            yield k, get


def test_a_failed_trial_gives_its_error_and_the_others_go_on() -> None:
    configs = [type("Cfg", (), {"name": n})() for n in ("a", "b", "c")]
    runner = _Canned([{"trial": "a"}, ValueError("first line\nlast line"), {"trial": "c"}])
    done: list[int] = []
    results = run_trials(runner, configs, lambda k, r: done.append(k), cpus_per_trial=2)
    assert results == [{"trial": "a"}, {"trial": "b", "error": "ValueError: last line"}, {"trial": "c"}]
    assert done == [2, 1, 0] and runner.cpus == [2]


def _children(pid: int) -> set[int]:
    """Live (not zombie) processes whose parent is ``pid``."""
    found = set()
    for proc in Path("/proc").iterdir():
        try:
            stat = (proc / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # state, ppid, ... (the command may hold spaces)
        if proc.name.isdigit() and int(fields[1]) == pid and fields[0] != "Z":
            found.add(int(proc.name))
    return found


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2:].split()[0] != "Z"  # a zombie has exited (nothing reaps it here)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processes from /proc (Linux)")
@pytest.mark.slow  # 8 s alone on the shared 2-core box
def test_evaluate_workers_and_their_resource_tracker_die_with_a_killed_evaluate(tmp_path: Path) -> None:
    import signal
    import subprocess
    import sys
    import time

    import triplesumo

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(triplesumo.__file__).parents[1]),
                                                        os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-m", "triplesumo.cli", "evaluate", "--policy", "passive", "--workers",
                             "2", "--epochs", "400", "--steps-per-epoch", "200", "--no-progress",
                             "--out", str(tmp_path / "ev")], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while len(children := _children(proc.pid)) < 3:  # the resource tracker and two spawned workers
            assert proc.poll() is None and time.monotonic() < deadline, "evaluate --workers 2 started no workers"
            time.sleep(0.2)
        time.sleep(1.0)  # the workers' initializers have run (they play their first chunks)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    deadline = time.monotonic() + 5
    while (alive := [p for p in children if _alive(p)]) and time.monotonic() < deadline:
        time.sleep(0.1)
    for pid in alive:  # (clean up before failing)
        os.kill(pid, signal.SIGKILL)
    assert not alive, f"orphans of the killed evaluate still running: {alive}"
