"""Built-in policies that need no weights: passive (zero action) and uniform random.

A policy is any callable from one observation to one normalised action in [-1, 1]^n
(n = 8 motors for an ant body, 12 for a bug, 16 for a spider); one with a ``reset(seed)``
method is re-seeded by the env at every reset.
"""

from __future__ import annotations

import numpy as np

ACTION_SIZE = 8
"""Action size of the default (ant) body."""


class ZeroPolicy:
    """Passive: zero torque on every motor (the legs hold no pose)."""

    def __init__(self, action_size: int = ACTION_SIZE) -> None:
        self.action_size = action_size

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(self.action_size, dtype=np.float32)


class RandomPolicy:
    """Uniform random actions in [-1, 1]^n from its own seeded generator."""

    def __init__(self, seed: int | None = None, action_size: int = ACTION_SIZE) -> None:
        self.rng = np.random.default_rng(seed)
        self.action_size = action_size

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, self.action_size).astype(np.float32)

    def sample(self, n: int) -> np.ndarray:
        """``n`` actions at once, ``(n, action_size)`` float32: the very numbers of ``n`` calls, in
        order (one draw instead of ``n``; no observation needed)."""
        return self.rng.uniform(-1.0, 1.0, (n, self.action_size)).astype(np.float32)


BUILTIN = {"zero": ZeroPolicy, "passive": ZeroPolicy, "random": RandomPolicy}


def act_batch(policy: object, obs: np.ndarray) -> np.ndarray:
    """Actions for a batch ``(n, obs_dim)`` of observations, as float64 ``(n, action_size)``.

    Batched policies (trained actors, which have an ``obs_dim``) are called once;
    others once per row.
    """
    if getattr(policy, "obs_dim", None) is not None:
        return np.asarray(policy(obs), dtype=np.float64)  # type: ignore[operator]
    return np.stack([np.asarray(policy(o), dtype=np.float64) for o in obs])  # type: ignore[operator]
