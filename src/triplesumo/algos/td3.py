"""Twin Delayed DDPG (Fujimoto, van Hoof & Meger, 2018): DDPG with three changes.

TD3 states only what differs from :class:`~triplesumo.algos.ddpg.DDPG`, in its three named
places::

    1. clipped double Q      y = r + γ (1 - done) · min_i Q'_i(s', ã)      (build: twin critics)
    2. target smoothing      ã = clip(μ'(s') + clip(ε, -c, c), -1, 1), ε ~ N(0, σ̃²)   (target_action)
    3. delayed updates       actor and targets step once every d critic steps       (actor_due)

Both critics regress onto the same ``y``; the actor ascends Q_1 only. ``min_i`` is the default ``pessimism`` 1;
another β reads ``mean - β |Q'_1 - Q'_2| / 2`` (:func:`~triplesumo.algos.offpolicy.combine_q`). Defaults are the
paper's and CleanRL's ``td3_continuous_action.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from triplesumo.agents.networks import Critic
from triplesumo.algos.config import at_least, non_negative
from triplesumo.algos.ddpg import DDPG, DDPGConfig


@dataclass(frozen=True)
class TD3Config(DDPGConfig):
    """TD3 hyper-parameters; defaults from Fujimoto et al. (2018) and CleanRL's TD3."""

    actor_lr: float = 3e-4
    """Adam learning rate of the actor, in (0, 1] (CleanRL: 3e-4)."""
    critic_lr: float = 3e-4
    """Adam learning rate of both critics, in (0, 1] (CleanRL: 3e-4)."""
    tau: float = 0.005
    """Soft target update factor τ, in (0, 1] (TD3 paper: 0.005)."""
    batch_size: int = 256
    """Transitions per gradient step (CleanRL: 256)."""
    hidden: tuple[int, ...] = (256, 256)
    """Hidden layer widths of actor and critics (TD3 paper: 256, 256 in its released code)."""
    learn_every: int = 1
    """Update stride K: one update per collected transition (TD3 paper)."""
    learning_starts: int = 25_000
    """Transitions of random warm-up collected before the first update (TD3 paper, CleanRL)."""
    noise: str = "gaussian"
    """Exploration noise kind: Gaussian, N(0, 0.1²) (TD3 paper)."""
    noise_sigma: float = 0.1
    """σ of the Gaussian exploration noise (TD3 paper: 0.1)."""
    normalize_obs: bool = True
    """Normalise observations by their running mean and variance."""
    policy_noise: float = 0.2
    """σ̃ of the target policy smoothing noise, >= 0 (TD3 paper: 0.2)."""
    noise_clip: float = 0.5
    """c: the smoothing noise is clipped to [-c, c], >= 0 (TD3 paper: 0.5)."""
    policy_delay: int = 2
    """d: the actor and the targets are updated once every d critic updates (TD3 paper: 2)."""

    TUNABLE: ClassVar[tuple[str, ...]] = (*DDPGConfig.TUNABLE, "policy_noise", "noise_clip", "policy_delay")

    def __post_init__(self) -> None:
        super().__post_init__()
        non_negative(self, "policy_noise")
        non_negative(self, "noise_clip")
        at_least(self, "policy_delay", 1)


class TD3(DDPG):
    """TD3 learner for one agent (same API as :class:`~triplesumo.algos.ddpg.DDPG`)."""

    config: TD3Config
    modules = ("actor", "critic", "critic2", "actor_target", "critic_target", "critic2_target")
    target_pairs = (("actor", "actor_target"), ("critic", "critic_target"),
                    ("critic2", "critic2_target"))
    uses_generator = True

    def build(self) -> None:
        """1. Clipped double Q: a second critic Q_2 and its target; the TD target takes the min."""
        super().build()
        self.critic2 = Critic(self.obs_dim, self.act_dim, self.config.hidden)
        self.critic2_target = self.target_copy(self.critic2)
        self.critics = [self.critic, self.critic2]
        self.critic_targets = [self.critic_target, self.critic2_target]

    def target_action(self, next_obs: torch.Tensor) -> torch.Tensor:
        """2. Target policy smoothing: ``clip(μ'(s') + clip(ε, -c, c), -1, 1)``, ε ~ N(0, σ̃²)."""
        action = self.actor_target(next_obs)
        eps = torch.randn(action.shape, generator=self.generator, device=action.device)
        noise = (eps * self.config.policy_noise).clamp(-self.config.noise_clip, self.config.noise_clip)
        return (action + noise).clamp(-1.0, 1.0)

    def actor_due(self) -> bool:
        """3. Delayed updates: the actor and targets step on every ``policy_delay``-th update."""
        return (self.num_updates + 1) % self.config.policy_delay == 0
