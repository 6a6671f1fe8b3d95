"""Deep Deterministic Policy Gradient (Lillicrap et al., 2015) on the off-policy core.

The learner owns the actor μ, the critic Q, their target copies μ', Q' and two Adam
optimisers. It does not collect data: the training loop acts with :meth:`DDPG.act` (adding
exploration noise itself, or through :meth:`~triplesumo.algos.offpolicy.OffPolicyAlgorithm.explore`),
stores transitions in a :class:`~triplesumo.algos.replay.ReplayBuffer`, and calls
:meth:`DDPG.update` with sampled batches as many times as
:meth:`~triplesumo.algos.offpolicy.OffPolicyAlgorithm.updates_due` says.

One update is, in order::

    y      = r + γ (1 - done) · Q'(s', μ'(s'))        # TARGET critic at the TARGET actor's action
    L_Q    = mean (Q(s, a) - y)²                       # critic step
    L_μ    = -mean Q(s, μ(s))                          # actor step (critic held fixed)
    θ'     <- τ θ + (1 - τ) θ'                         # soft update of both targets

TD3 (:mod:`triplesumo.algos.td3`) is this class with its three changes stated in the three
named places :meth:`DDPG.build` (twin critics), :meth:`DDPG.target_action` (target policy
smoothing) and :meth:`DDPG.actor_due` (delayed actor and target updates); SB3's DDPG is
likewise its TD3 with one critic, no smoothing and no delay.

Checkpoints are safetensors + JSON, never pickle (:class:`~triplesumo.algos.base.Algorithm`):
loading :meth:`state_dict` and :meth:`optimizer_state` into a fresh learner continues the
run bit-for-bit on CPU.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from triplesumo.agents.networks import Actor, Critic
from triplesumo.algos.base import descend, frozen
from triplesumo.algos.config import OffPolicyConfig, real, require
from triplesumo.algos.noise import NOISE_KINDS
from triplesumo.algos.offpolicy import Batch, OffPolicyAlgorithm, joint_q


@dataclass(frozen=True)
class DDPGConfig(OffPolicyConfig):
    """DDPG hyper-parameters; defaults are the paper's (Table 2) and its original code's.

    Table 2 gives the learning rates, γ, τ, batch size, buffer size and the update stride 30;
    the original code gives the hidden sizes (512, 256) and the OU noise (θ 0.15, σ 0.2).
    The paper's original code had the stride condition inverted and learned on 29 of every
    30 steps; we learn on 1 of every ``learn_every``.
    """

    noise: str = "ou"
    """Exploration noise kind: "ou" (paper's original code), "gaussian" or "none"."""
    noise_sigma: float = 0.2
    """σ of the exploration noise, in normalized action units (paper's original code)."""
    noise_theta: float = 0.15
    """θ of the OU noise (paper's original code); ignored by other kinds."""

    TUNABLE: ClassVar[tuple[str, ...]] = (*OffPolicyConfig.TUNABLE, "noise_sigma", "noise_theta")

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self, "noise", self.noise in NOISE_KINDS,
                f"must be one of {NOISE_KINDS}, got {self.noise!r}")
        require(self, "noise_sigma", real(self, "noise_sigma") >= 0, "must be >= 0")
        require(self, "noise_theta", real(self, "noise_theta") > 0, "must be > 0")


class DDPG(OffPolicyAlgorithm):
    """DDPG learner for one agent: networks, targets, optimisers and the update rule.

    Built as every learner is (:class:`~triplesumo.algos.base.Algorithm`:
    ``DDPG(obs_dim, act_dim, config, seed, device="cpu")``).
    """

    config: DDPGConfig
    actor: Actor
    modules: tuple[str, ...] = ("actor", "critic", "actor_target", "critic_target")
    target_pairs: tuple[tuple[str, str], ...] = (("actor", "actor_target"), ("critic", "critic_target"))

    # ------------------------------------------------------ the places TD3 changes

    def build(self) -> None:
        """Actor μ and critic Q (seeded, in this order), and their target copies μ', Q'."""
        hidden = self.config.hidden
        self.actor = Actor(self.obs_dim, self.act_dim, hidden)
        self.critic = Critic(self.obs_dim, self.act_dim, hidden)
        self.actor_target = self.target_copy(self.actor)
        self.critic_target = self.target_copy(self.critic)
        self.critics = [self.critic]
        self.critic_targets = [self.critic_target]

    def target_action(self, next_obs: torch.Tensor) -> torch.Tensor:
        """The action the TD target evaluates at s': the TARGET actor's μ'(s')."""
        return self.actor_target(next_obs)

    def actor_due(self) -> bool:
        """Whether this update also steps the actor and the targets: always, in DDPG."""
        return True

    # ------------------------------------------------------------------------ learning

    def td_target(self, batch: Batch) -> torch.Tensor:
        """Critic regression target ``y = r + γ (1 - done) Q'(s', μ'(s'))``, shape ``(B,)`` (γ^m with n-step
        returns: :meth:`~triplesumo.algos.offpolicy.OffPolicyAlgorithm.bootstrap`).

        Uses the TARGET actor μ' and the TARGET critic Q' (Lillicrap et al., 2015), without
        gradients. ``done = 1`` (a real win/loss terminal) removes the bootstrap term.
        (TD3: the smoothed target action and the two target critics' joint estimate, by default the smaller.)
        """
        b = self.batch(batch)
        with torch.no_grad():
            next_action = self.target_action(b["next_obs"])  # μ'(s'): TARGET actor
            # Q'(s', μ'(s')): the TARGET critic (TD3: both, joined by the config's pessimism)
            next_q = joint_q(self.critic_targets, b["next_obs"], next_action, self.config.pessimism)
            return b["rew"] + self.bootstrap(b) * next_q

    def update_critic(self, batch: Batch) -> dict[str, float]:
        """One Adam critic step on ``mean (Q(s, a) - y)²``, with ``y`` from :meth:`td_target`.

        Returns ``critic_loss`` and ``q_mean`` (mean Q(s, a)), both before the step.
        """
        b = self.batch(batch)
        return self.regress_critics(self.critics, self.critic_optimizer, b, self.td_target(b))

    def update_actor(self, batch: Batch) -> dict[str, float]:
        """One Adam step on the actor: minimise ``-mean Q(s, μ(s))``; the critic is not changed.

        Returns ``actor_loss`` before the step.
        """
        obs = self.batch(batch)["obs"]
        with frozen(self.critic):  # no critic weight gradients: the critic is fixed here
            loss = -self.critic(obs, self.actor(obs)).mean()
            descend(self.actor_optimizer, loss)
        return {"actor_loss": loss.item()}

    def train_step(self, b: dict[str, torch.Tensor]) -> dict[str, float]:
        """Critic step, then (when :meth:`actor_due`) actor step on the updated critic and soft update.

        Returns ``{"critic_loss", "q_mean"}`` and, when the actor stepped, ``"actor_loss"``
        (losses before their steps).
        """
        stats = self.update_critic(b)
        if self.actor_due():
            stats |= self.update_actor(b)
            self.soft_update_targets()
        return stats
