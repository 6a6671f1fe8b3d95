"""The project's own matches as Ray tasks: test epochs spread over a Ray cluster.

Groundwork for ``evaluate --ray`` (issue 13, section 2): :func:`play_test_epochs_on_ray`
splits the test epochs ``first .. epochs - 1`` into chunks, plays each chunk as a Ray task
with :func:`triplesumo.evaluation.evaluate.play_test_epochs` and returns the rows in
epoch order. Test epoch ``i`` is seeded ``seed + i`` and depends on nothing else, so the
rows equal a local run's for the same seeds (only ``wall_time``, which is 0 there too,
would differ). Policies travel as specs (``"zoo:ant"``, a policy-file path every node can
read, ``"zero"``, ``"random"``) and are built inside each task.

Needs the ``ray`` extra (``pip install "triplesumo[ray]"``); ``ray.init()`` (or
``ray.init(address=...)`` for a cluster) is the caller's, before the call.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

try:
    import ray
except ImportError as exc:  # pragma: no cover - exercised in a subprocess test
    raise ImportError('triplesumo.integrations.ray_tasks needs Ray, which is not installed: '
                      'pip install "triplesumo[ray]"') from exc

from triplesumo.agents.zoo import make_policy
from triplesumo.evaluation.evaluate import play_test_epochs
from triplesumo.rules.config import MatchConfig

__all__ = ["play_test_epochs_on_ray"]


def _play_chunk(learner_spec: str, other_specs: dict[str, str], learner: str, first: int, end: int, seed: int,
                match_cfg: MatchConfig, n_envs: int) -> list[dict[str, Any]]:
    obs_mode = match_cfg.obs_mode
    learner_policy = make_policy(learner_spec, seed=seed, expect_obs_mode=obs_mode)
    others = {a: make_policy(s, seed=seed, expect_obs_mode=obs_mode) for a, s in other_specs.items()}
    return play_test_epochs(learner_policy, others, learner, end, seed, match_cfg, n_envs=n_envs, n_threads=1,
                            first=first)


def play_test_epochs_on_ray(learner_spec: str, other_specs: Mapping[str, str], learner: str, epochs: int, seed: int,
                            match_cfg: MatchConfig | None = None, first: int = 0, chunk: int = 50,
                            n_envs: int = 8, max_retries: int = 3) -> list[dict[str, Any]]:
    """Rows of test epochs ``first .. epochs - 1``, played as Ray tasks of ``chunk`` epochs each.

    The same rows as ``play_test_epochs`` with the same policies and seeds, in epoch order.
    A task whose worker dies is run again (``max_retries``); its epochs replay exactly.
    """
    if not ray.is_initialized():
        raise RuntimeError("call ray.init() (or ray.init(address=...)) before play_test_epochs_on_ray")
    for name, value in (("epochs", epochs), ("chunk", chunk), ("n_envs", n_envs)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be an int >= 1, got {value!r}")
    if not 0 <= first < epochs:
        raise ValueError(f"first must be in [0, epochs={epochs}), got {first}")
    match_cfg = match_cfg or MatchConfig()
    task = ray.remote(num_cpus=1, max_retries=max_retries)(_play_chunk)
    refs = [task.remote(learner_spec, dict(other_specs), learner, a, min(a + chunk, epochs), seed, match_cfg,
                        min(n_envs, chunk))
            for a in range(first, epochs, chunk)]
    return [row for rows in ray.get(refs) for row in rows]
