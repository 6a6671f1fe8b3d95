"""Test epochs played as Ray tasks give the rows of a local run for the same seeds."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from triplesumo.agents.zoo import make_policy
from triplesumo.evaluation.evaluate import play_test_epochs
from triplesumo.rules.config import MatchConfig

OTHERS = {"ant": "zoo:ant", "spider": "zoo:spider"}


@pytest.fixture(scope="module")
def ray_tasks() -> Iterator[Any]:
    ray = pytest.importorskip("ray", reason='the "ray" extra is not installed (pip install "triplesumo[ray]")')
    from triplesumo.integrations import ray_tasks

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray_tasks
    finally:
        ray.shutdown()


def test_rows_on_ray_equal_a_local_run(ray_tasks: Any) -> None:
    cfg = MatchConfig(max_steps=40)
    local = play_test_epochs(make_policy("random", seed=3), {a: make_policy(s) for a, s in OTHERS.items()},
                             "bug", 7, 100, cfg, n_envs=4, n_threads=1, first=1)
    remote = ray_tasks.play_test_epochs_on_ray("random", OTHERS, "bug", 7, 100, cfg, first=1, chunk=2, n_envs=2)
    assert [r["epoch"] for r in remote] == list(range(2, 8))
    assert remote == local
    assert {r["outcome"] for r in remote} <= {"win", "loss", "draw"}


def test_bad_arguments_are_named(ray_tasks: Any) -> None:
    with pytest.raises(ValueError, match="chunk must be an int >= 1"):
        ray_tasks.play_test_epochs_on_ray("zero", OTHERS, "bug", 4, 0, chunk=0)
    with pytest.raises(ValueError, match=r"first must be in \[0, epochs=4\)"):
        ray_tasks.play_test_epochs_on_ray("zero", OTHERS, "bug", 4, 0, first=4)
