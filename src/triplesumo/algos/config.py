"""Validation shared by every algorithm's frozen config, and the off-policy family's fields.

Each algorithm has one frozen dataclass (``DDPGConfig``, ``TD3Config``, ``SACConfig``,
``PPOConfig``) with a docstring per field, validated in ``__post_init__``: an error names
the class and the field (``TD3Config.tau must be in (0, 1]``). Learning rates must be
finite, > 0 and <= 1 (a rate of 1e30 is refused here, not discovered as NaN hours later).

:class:`OffPolicyConfig` holds what DDPG, TD3 and SAC share; its defaults are the paper's
DDPG values (Table 2). TD3 and SAC redeclare only the defaults that their papers (and
CleanRL) set differently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar


def require(config: Any, name: str, ok: bool, message: str) -> None:
    """``ValueError("<Class>.<name> <message>")`` unless ``ok``."""
    if not ok:
        raise ValueError(f"{type(config).__name__}.{name} {message}")


def real(config: Any, name: str) -> float:
    """The field as a float; ``ValueError`` unless it is a finite real number."""
    value = getattr(config, name)
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
    require(config, name, ok, f"must be a finite real number, got {value!r}")
    return float(value)


def integer(config: Any, name: str) -> int:
    """The field; ``ValueError`` unless it is an int (bools are rejected)."""
    value = getattr(config, name)
    require(config, name, isinstance(value, int) and not isinstance(value, bool),
            f"must be an int, got {value!r}")
    return int(value)


def learning_rate(config: Any, name: str) -> None:
    """A learning rate: finite, > 0 and <= 1."""
    require(config, name, 0 < real(config, name) <= 1, "must be in (0, 1]")


def fraction(config: Any, name: str, *, zero_ok: bool = False) -> None:
    """A discount or averaging factor in (0, 1] (or [0, 1] with ``zero_ok``)."""
    value = real(config, name)
    require(config, name, (0 <= value if zero_ok else 0 < value) and value <= 1,
            f"must be in {'[0' if zero_ok else '(0'}, 1]")


def at_least(config: Any, name: str, low: int) -> None:
    """An int field >= ``low``."""
    require(config, name, integer(config, name) >= low, f"must be >= {low}")


def non_negative(config: Any, name: str) -> None:
    """A finite real field >= 0."""
    require(config, name, real(config, name) >= 0, "must be >= 0")


def flag(config: Any, name: str) -> None:
    """A bool field."""
    value = getattr(config, name)
    require(config, name, isinstance(value, bool), f"must be true or false, got {value!r}")


def hidden_sizes(config: Any, name: str = "hidden") -> None:
    """Hidden layer widths: a non-empty tuple of ints >= 1 (a JSON list is turned into one)."""
    value = getattr(config, name)
    if isinstance(value, list):  # e.g. loaded back from JSON
        object.__setattr__(config, name, value := tuple(value))
    require(
        config, name,
        isinstance(value, tuple) and len(value) > 0
        and all(isinstance(h, int) and not isinstance(h, bool) and h >= 1 for h in value),
        f"must be a non-empty tuple of ints >= 1, got {value!r}",
    )


UPDATE_DTYPES = ("float32", "bfloat16")
"""The values of :attr:`OffPolicyConfig.update_dtype`."""


@dataclass(frozen=True)
class OffPolicyConfig:
    """What DDPG, TD3 and SAC share: replay, target networks and the update schedule.

    The update schedule is explicit: once ``learning_starts`` transitions of random warm-up
    have been collected (and the replay holds a batch), the learner does
    ``G = gradient_steps`` gradient steps every ``K = learn_every`` collected transitions
    (:meth:`triplesumo.algos.offpolicy.OffPolicyAlgorithm.updates_due`).
    """

    actor_lr: float = 1e-4
    """Adam learning rate of the actor, in (0, 1] (paper Table 2)."""
    critic_lr: float = 1e-3
    """Adam learning rate of the critic(s), in (0, 1] (paper Table 2)."""
    gamma: float = 0.99
    """Discount factor γ, in (0, 1] (paper Table 2)."""
    tau: float = 0.01
    """Soft target update factor τ, in (0, 1]: θ' <- τθ + (1-τ)θ' (paper Table 2)."""
    batch_size: int = 64
    """Transitions per gradient step (paper Table 2)."""
    buffer_size: int = 1_000_000
    """Replay buffer capacity in transitions (paper Table 2)."""
    hidden: tuple[int, ...] = (512, 256)
    """Hidden layer widths of actor and critics (paper's original code)."""
    learn_every: int = 30
    """Update stride K: gradient updates happen once every K collected transitions (Table 2)."""
    gradient_steps: int = 1
    """G: gradient steps done each time an update happens."""
    learning_starts: int = 1000
    """Transitions of random warm-up collected before the first update."""
    weight_decay: float = 0.0
    """L2 weight decay of the critics' Adam (Lillicrap et al. used 1e-2; the paper none)."""
    normalize_obs: bool = False
    """Normalise observations by their running mean and variance (off in the paper)."""
    n_step: int = 1
    """n of n-step returns: each stored transition carries its agent's next n rewards, discounted, and bootstraps
    from the observation n steps on with γ^n (fewer where its match ends first:
    :mod:`triplesumo.algos.nstep`). 1: one-step TD (the paper, SB3, CleanRL). It makes the replay's contents, so
    a fork keeps it."""

    reset_every: int = 0
    """Re-initialise the learner every this many gradient updates (0: never): every network, its target and its
    optimiser as a learner of the same config builds them under a seed drawn from the learner's and the reset's
    index; the replay, the observation normaliser and the update count are kept (Nikishin et al., ICML 2022;
    D'Oro et al., ICLR 2023: resets let a learner take more updates per transition without losing plasticity)."""

    pessimism: float = 1.0
    """β of twin critics' joint estimate ``mean - β |Q_1 - Q_2| / 2`` in the TD target (and SAC's actor loss): 1,
    their minimum (clipped double Q: TD3's and SAC's), 0 their mean, below 0 optimistic (TOP, Moskovitz et al.,
    NeurIPS 2021; BRO, Nauman et al., 2024). In [-1, 1]. DDPG's one critic is its own estimate whatever β."""

    update_dtype: str = "float32"
    """The dtype of the gradient updates' matrix products: float32, or bfloat16 (``torch.autocast`` around each
    update: the hidden layers' products in bfloat16, each network's output layer, the losses, the weights and
    Adam's state in float32; FastTD3's ``amp``). Acting, evaluation and exported policies stay float32. On a CPU
    with bfloat16 instructions (AVX-512 BF16, AMX) it makes SAC's update about 1.5x cheaper; it changes the
    updates' rounding, so runs are not bit for bit those in float32."""

    TUNABLE: ClassVar[tuple[str, ...]] = ("actor_lr", "critic_lr", "gamma", "tau", "batch_size", "learn_every",
                                          "gradient_steps", "weight_decay", "update_dtype", "reset_every",
                                          "pessimism")
    """The fields a run continued from a checkpoint may change (``train --fork RUN --ddpg.actor-lr 2e-5``,
    fine-tuning): step sizes, the update schedule and exploration, on which no saved tensor's shape or
    meaning depends. The others (widths, replay size, normalisation, noise kind, warm-up) make what the
    checkpoint holds, or act only before it. A class variable, not a field."""

    def __post_init__(self) -> None:
        hidden_sizes(self)
        for name in ("actor_lr", "critic_lr"):
            learning_rate(self, name)
        for name in ("gamma", "tau"):
            fraction(self, name)
        for name in ("batch_size", "buffer_size", "learn_every", "gradient_steps", "n_step"):
            at_least(self, name, 1)
        at_least(self, "learning_starts", 0)
        at_least(self, "reset_every", 0)
        non_negative(self, "weight_decay")
        require(self, "pessimism", -1 <= real(self, "pessimism") <= 1, f"must be in [-1, 1], got {self.pessimism}")
        flag(self, "normalize_obs")
        require(self, "update_dtype", self.update_dtype in UPDATE_DTYPES,
                f"must be one of {', '.join(UPDATE_DTYPES)}, got {self.update_dtype!r}")
