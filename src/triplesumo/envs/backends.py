"""The batched API's backends and the one function that picks between them: ``triplesumo.vector_env``.

``backend="cpu"`` is :class:`~triplesumo.envs.batch.VectorMatches` (MuJoCo, threaded, numpy arrays);
``backend="warp"`` is :class:`~triplesumo.envs.warp.WarpVectorMatches` (MuJoCo Warp, torch tensors on a
device; the ``gpu`` extra). Both keep one contract (arrays ``(num_envs, n_agents, ...)`` in and out,
Gymnasium SAME_STEP autoreset), held equal by tests.

Only this module and ``envs.warp`` itself reach the Warp backend, so every other env module is free of
torch, directly and through any chain of imports (the ``envs-without-torch`` import contract, which
allows no indirect import).
"""

from __future__ import annotations

from typing import Any

from triplesumo.envs.batch import VectorMatches
from triplesumo.rules.scenarios import scenario_config

__all__ = ["VECTOR_BACKENDS", "vector_env"]

VECTOR_BACKENDS = ("cpu", "warp")
"""The backends :func:`vector_env` steps matches on."""


def vector_env(num_envs: int, scenario: str = "paper", backend: str = "cpu", device: str | None = None,
               num_threads: int | None = None, **config: Any) -> VectorMatches:
    """``num_envs`` matches stepped together, as arrays (see :class:`~triplesumo.envs.batch.VectorMatches`).

    ``config`` are :class:`~triplesumo.rules.config.MatchConfig` fields (``max_steps``, ``obs_mode``, ...).
    ``scenario`` is any of ``triplesumo.scenarios()``. ``backend="cpu"`` steps MuJoCo on
    ``num_threads`` threads (default: one per usable CPU, at most ``num_envs``) and returns
    numpy arrays; results do not depend on it. ``backend="warp"`` steps MuJoCo Warp on
    ``device`` (``"cuda"``, or Warp's ``"cpu"``; default: a GPU when Warp sees one) and returns
    torch tensors on it (:class:`triplesumo.envs.warp.WarpVectorMatches`: the same contract,
    either rule set, with one body kind; the ``gpu`` extra).
    """
    if backend not in VECTOR_BACKENDS:
        raise ValueError(f"backend must be one of {VECTOR_BACKENDS}, got {backend!r}")
    if backend == "warp":
        try:
            from triplesumo.envs.warp import make_warp_vector_env
        except ImportError as exc:
            raise ImportError(f"backend='warp' needs MuJoCo Warp: pip install \"triplesumo[gpu]\" ({exc})") from None
        if num_threads is not None:
            raise ValueError("num_threads is for backend='cpu' (MuJoCo threads); backend='warp' runs on device")
        return make_warp_vector_env(scenario_config(scenario, **config), num_envs, device)  # type: ignore[return-value]
    if device not in (None, "cpu"):
        raise ValueError(f"backend='cpu' runs on the CPU: device must be None or 'cpu', got {device!r}")
    return VectorMatches(num_envs, scenario_config(scenario, **config), num_threads)
