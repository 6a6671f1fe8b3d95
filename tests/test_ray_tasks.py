"""Test epochs played as Ray tasks give the rows of a local run for the same seeds."""

from __future__ import annotations

import dataclasses
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from conftest import own_ray_workers
from triplesumo.agents.zoo import make_policy
from triplesumo.evaluation.evaluate import play_test_epochs
from triplesumo.rules.config import MatchConfig

OTHERS = {"ant": "zoo:ant", "spider": "zoo:spider"}


@pytest.fixture(scope="module")
def ray_tasks(ray_session: Any) -> Any:
    from triplesumo.integrations import ray_tasks

    return ray_tasks


@pytest.mark.slow  # 19 s alone on the shared 2-core box
def test_rows_on_ray_equal_a_local_run(ray_tasks: Any) -> None:
    cfg = MatchConfig(max_steps=40)
    local = play_test_epochs(make_policy("random", seed=3), {a: make_policy(s) for a, s in OTHERS.items()},
                             "bug", 7, 100, cfg, n_envs=4, n_threads=1, first=1)
    remote = ray_tasks.play_test_epochs_on_ray("random", OTHERS, "bug", 7, 100, cfg, first=1, chunk=2, n_envs=2)
    assert [r["epoch"] for r in remote] == list(range(2, 8))
    assert remote == local
    assert {r["outcome"] for r in remote} <= {"win", "loss", "draw"}


@pytest.mark.slow  # starts a Ray cluster for the module, 12 s
def test_bad_arguments_are_named(ray_tasks: Any) -> None:
    with pytest.raises(ValueError, match="chunk must be an int >= 1"):
        ray_tasks.play_test_epochs_on_ray("zero", OTHERS, "bug", 4, 0, chunk=0)
    with pytest.raises(ValueError, match=r"first must be in \[0, epochs=4\)"):
        ray_tasks.play_test_epochs_on_ray("zero", OTHERS, "bug", 4, 0, first=4)


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds Ray's worker processes through /proc")
@pytest.mark.slow  # starts a Ray cluster for the module, 12 s
def test_a_killed_worker_is_retried_and_its_epochs_replay_exactly(ray_tasks: Any) -> None:
    cfg = MatchConfig(max_steps=150)
    result: dict[str, Any] = {}
    thread = threading.Thread(target=lambda: result.update(rows=ray_tasks.play_test_epochs_on_ray(
        "random", OTHERS, "bug", 8, 7, cfg, chunk=4, n_envs=2)))
    thread.start()
    killed = None
    deadline = time.monotonic() + 60
    while killed is None and thread.is_alive() and time.monotonic() < deadline:
        pids = own_ray_workers("play_test_chunk")
        if pids:
            killed = pids[0]
            os.kill(killed, signal.SIGKILL)
        time.sleep(0.05)
    thread.join(timeout=240)
    assert killed is not None, "no chunk worker was seen running"
    assert not thread.is_alive() and "rows" in result, "the killed chunk's retry did not finish within 240 s"
    local = play_test_epochs(make_policy("random"), {a: make_policy(s) for a, s in OTHERS.items()},
                             "bug", 8, 7, cfg, n_envs=4, n_threads=1)
    assert result["rows"] == local


def _csv_rows(path: Path) -> list[bytes]:
    return path.read_bytes().splitlines()


@pytest.mark.slow  # 14 s alone on the shared 2-core box
def test_evaluate_on_ray_writes_the_bytes_of_a_local_run_and_resumes(ray_tasks: Any, tmp_path: Path) -> None:
    from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate

    base = EvaluateConfig(policy=("random",), epochs=6, steps_per_epoch=40, n_envs=4, n_threads=1, progress=False,
                          baselines=("passive",), out=str(tmp_path / "local"))
    local = evaluate(base)
    on_ray = dataclasses.replace(base, out=str(tmp_path / "ray"), ray=True, ray_chunk=4, epochs=3)
    evaluate(on_ray, ray_tasks.RayRunner())  # a first part, as if killed after 3 epochs, then resumed to 6 on Ray
    summary = evaluate(dataclasses.replace(on_ray, epochs=6, resume=True), ray_tasks.RayRunner())
    for label in ("trained", "passive"):
        ray_rows = _csv_rows(tmp_path / "ray" / label / "metrics.csv")
        assert len(ray_rows) == 7
        assert ray_rows == _csv_rows(tmp_path / "local" / label / "metrics.csv")
    assert summary["candidates"] == local["candidates"]


@pytest.mark.slow  # starts a Ray cluster for the module, 12 s
def test_tournament_on_ray_writes_the_rows_of_a_local_run_and_resumes(ray_tasks: Any, tmp_path: Path) -> None:
    from triplesumo.evaluation.tournament import TournamentConfig, run_tournament
    from triplesumo.model.specs import AgentSpec

    duel = MatchConfig(agents=(AgentSpec("a", "a", 0.2), AgentSpec("b", "b", 0.2)), max_steps=60)
    base = TournamentConfig(policies=("passive=passive", "random=random"), rounds=3, steps_per_epoch=60,
                            n_envs=4, n_threads=1, progress=False, out=str(tmp_path / "local"))
    run_tournament(base, duel)
    on_ray = dataclasses.replace(base, out=str(tmp_path / "ray"), ray=True, ray_chunk=2, rounds=2)
    run_tournament(on_ray, duel, ray_tasks.RayRunner())
    run_tournament(dataclasses.replace(on_ray, rounds=3, resume=True), duel, ray_tasks.RayRunner())
    ray_rows = _csv_rows(tmp_path / "ray" / "matches.csv")
    assert len(ray_rows) == 7  # header + 3 rounds of 2 lineups
    assert ray_rows == _csv_rows(tmp_path / "local" / "matches.csv")
    assert (tmp_path / "ray" / "leaderboard.csv").read_bytes() == (tmp_path / "local" / "leaderboard.csv").read_bytes()


def test_ray_options_without_ray_name_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib.util

    from triplesumo.evaluation.evaluate import EvaluateConfig
    from triplesumo.evaluation.tournament import TournamentConfig

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a))
    for cls in (EvaluateConfig, TournamentConfig):
        with pytest.raises(ValueError, match=r'ray: Ray is not installed.*pip install "triplesumo\[ray\]"'):
            cls(ray=True)
        with pytest.raises(ValueError, match="ray_address needs"):
            cls(ray_address="auto")


def test_a_local_ray_started_by_session_runs_its_tasks_at_the_callers_priority() -> None:
    """Ray lowers its workers by 15 by default, which starved the Bug trials of ``reproduce --ray`` on a busy box;
    ``session`` starts a local Ray whose tasks run at the caller's niceness, and leaves the environment as it was.
    In a process of its own: the module's Ray may already run in this one."""
    import os
    import subprocess
    import sys

    pytest.importorskip("ray", reason='the "ray" extra is not installed (pip install "triplesumo[ray]")')
    script = """
import os, ray
from triplesumo.integrations import ray_tasks
def niceness():
    import os
    return os.nice(0)
with ray_tasks.session(num_cpus=1):
    print("worker", ray.get(ray.remote(niceness).remote()), "caller", os.nice(0))
print("left", os.environ.get("RAY_worker_niceness"))
"""
    env = {k: v for k, v in os.environ.items() if k != "RAY_worker_niceness"}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=240,
                          check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.split("\n")
    worker = next(line.split() for line in lines if line.startswith("worker"))
    assert worker[1] == worker[3]  # a worker's niceness: the caller's (Ray's default would add 15)
    assert "left None" in lines  # the environment as it was
