"""Soft Actor-Critic (Haarnoja et al., 2018, with the learned temperature of the 2018 v2 paper).

On the off-policy core (replay, twin critics with targets, soft updates, schedule), SAC
states its own three pieces::

    target       y   = r + γ (1 - done) · (min_i Q'_i(s', a') - α log π(a'|s')),  a' ~ π(·|s')
    actor        L_π = mean (α log π(a|s) - min_i Q_i(s, a)),  a = tanh(μ + σ ε) (reparameterised)
    temperature  L_α = -mean log α · (log π(a|s) + H̄),   H̄ = -act_dim by default

With ``critic_norm="batch"`` the critics are CrossQ's (Bhatt et al., ICLR 2024): batch norm and no target networks.
The target's ``Q'`` is then the online critics' own, read from one forward pass of the stacked batch
``[(s, a); (s', a')]`` in training mode (so the batch statistics are those of both halves' mixture), its ``(s', a')``
half held fixed (no gradient).

The policy is a squashed Gaussian (:class:`~triplesumo.agents.networks.GaussianActor`,
state-dependent log σ), with the tanh change of variables in ``log π``. There is no target
actor. The temperature falls when the policy's entropy is above the target and rises when it
is below. Exploration samples the policy (no noise process); the deterministic policy (and
the exported one) is ``tanh(μ(s))``. ``min_i`` above is the default ``pessimism`` 1; another β reads
``mean - β |Q_1 - Q_2| / 2`` instead (:func:`~triplesumo.algos.offpolicy.combine_q`). Defaults are CleanRL's
``sac_continuous_action.py``, but for the update schedule: one update per 8 transitions with 5-step returns, the
recipe measured fastest to skill here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from triplesumo.agents.networks import Critic, GaussianActor, mlp, plain_block
from triplesumo.algos.base import adam, descend, frozen
from triplesumo.algos.config import OffPolicyConfig, at_least, flag, learning_rate, real, require
from triplesumo.algos.hlgauss import HLGaussCritic
from triplesumo.algos.noise import ActionNoise
from triplesumo.algos.offpolicy import Batch, OffPolicyAlgorithm, combine_q, joint_q

CRITIC_NORMS = ("none", "layer", "batch")
"""The values of :attr:`SACConfig.critic_norm`."""
CRITIC_LOSSES = ("mse", "hl_gauss")
"""The values of :attr:`SACConfig.critic_loss`."""


@dataclass(frozen=True)
class SACConfig(OffPolicyConfig):
    """SAC hyper-parameters; defaults from Haarnoja et al. (2018) and CleanRL's SAC, and the measured schedule
    (``learn_every`` 8, ``n_step`` 5)."""

    actor_lr: float = 3e-4
    """Adam learning rate of the actor, in (0, 1] (CleanRL: 3e-4)."""
    critic_lr: float = 1e-3
    """Adam learning rate of both critics, in (0, 1] (CleanRL: 1e-3)."""
    tau: float = 0.005
    """Soft target update factor τ of the critics, in (0, 1] (SAC paper: 0.005)."""
    batch_size: int = 256
    """Transitions per gradient step (SAC paper: 256)."""
    hidden: tuple[int, ...] = (256, 256)
    """Hidden layer widths of actor and critics (SAC paper: 256, 256)."""
    learn_every: int = 8
    """Update stride K: one update per 8 collected transitions, TripleSumo's measured recipe with ``n_step`` 5
    (docs/bench/skill.md: +0.2 in a median of 125,008 env steps over 5 seeds, the final skill held at 1 M). The SAC
    paper updates once per transition (``learn_every 1``, ``n_step 1``), several times slower on a CPU."""
    learning_starts: int = 5000
    """Transitions of random warm-up collected before the first update (CleanRL: 5e3)."""
    normalize_obs: bool = True
    """Normalise observations by their running mean and variance."""
    n_step: int = 5
    """n of n-step returns (:attr:`OffPolicyConfig.n_step`): 5, the recipe's (D4PG's n for continuous control); the
    SAC paper's and CleanRL's is 1."""
    alpha: float = 0.2
    """Temperature α: its initial value when learned, else fixed (CleanRL: 0.2); > 0."""
    learn_alpha: bool = True
    """Learn α towards the target entropy (SAC v2's automatic temperature)."""
    alpha_lr: float = 1e-3
    """Adam learning rate of log α, in (0, 1] (CleanRL uses the critic's, 1e-3)."""
    target_entropy: float | None = None
    """Target entropy H̄ of the learned temperature; None means -act_dim (SAC v2)."""

    critic_norm: str = "none"
    """Normalisation inside both critics: none; layer (LayerNorm after each hidden linear layer, before its
    activation, in the critics and their targets, as RLPD (Ball et al., 2023) and BRO (Nauman et al., 2024) do to
    keep Q bounded at high update-to-data ratios); or batch (CrossQ's critics: batch norm before each linear layer,
    and no target networks, so ``tau`` is unused: :class:`BatchNormCritic`). It makes the critics' tensors, so a
    fork keeps it."""

    critic_loss: str = "mse"
    """How both critics learn their TD targets: mse (the mean squared error, SAC's); or hl_gauss (each critic gives
    a histogram of ``value_bins`` bins on ``[value_low, value_high]``, its Q their expected value, learned by the
    cross-entropy against the target's Gaussian-smoothed histogram: Farebrother et al., ICML 2024,
    :mod:`triplesumo.algos.hlgauss`). It makes the critics' tensors, so a fork keeps it; not with
    ``critic_norm="batch"``."""
    value_low: float = -1000.0
    """Lower end of hl_gauss's support: below every return of the game (a loss, -400, after a match of still
    punishment, about -400 more)."""
    value_high: float = 1000.0
    """Upper end of hl_gauss's support: above every return of the game (a win, +500, and its velocity terms)."""
    value_bins: int = 101
    """hl_gauss's bins on ``[value_low, value_high]`` (20 units wide on the default support)."""

    TUNABLE: ClassVar[tuple[str, ...]] = (*OffPolicyConfig.TUNABLE, "alpha_lr", "target_entropy")

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self, "critic_norm", self.critic_norm in CRITIC_NORMS,
                f"must be one of {', '.join(CRITIC_NORMS)}, got {self.critic_norm!r}")
        require(self, "critic_loss", self.critic_loss in CRITIC_LOSSES,
                f"must be one of {', '.join(CRITIC_LOSSES)}, got {self.critic_loss!r}")
        require(self, "critic_loss", not (self.critic_loss == "hl_gauss" and self.critic_norm == "batch"),
                "hl_gauss does not go with critic_norm batch (CrossQ's joint pass regresses Q-values)")
        require(self, "value_high", real(self, "value_high") > real(self, "value_low"),
                f"must be above value_low ({self.value_low}), got {self.value_high}")
        at_least(self, "value_bins", 2)
        require(self, "alpha", real(self, "alpha") > 0, "must be > 0")
        flag(self, "learn_alpha")
        learning_rate(self, "alpha_lr")
        if self.target_entropy is not None:
            real(self, "target_entropy")


class LayerNormCritic(Critic):
    """:class:`Critic` with a LayerNorm (learned gain and bias) after each hidden linear layer, before its leaky
    ReLU: ``Linear -> LayerNorm -> LeakyReLU`` per hidden layer, then the small-init linear output. The features
    the output reads have unit scale whatever the inputs and weights do, so Q cannot grow by feature growth alone."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...] = (256, 256)) -> None:
        nn.Module.__init__(self)
        self.obs_dim, self.act_dim, self.hidden = obs_dim, act_dim, tuple(hidden)
        self.net = mlp(obs_dim + act_dim, self.hidden, 1, block=self.block)

    @staticmethod
    def block(width_in: int, width: int) -> list[nn.Module]:
        """One hidden layer: ``Linear -> LayerNorm -> LeakyReLU``."""
        return [nn.Linear(width_in, width), nn.LayerNorm(width), nn.LeakyReLU()]


BATCH_NORM_MOMENTUM = 0.01
"""Weight of a batch's statistics in a batch-norm critic's running ones (CrossQ's decay 0.99)."""
BATCH_NORM_EPS = 1e-3
"""ε of a batch-norm critic's variance (CrossQ's)."""


class BatchNormCritic(Critic):
    """:class:`Critic` with CrossQ's batch norm before each linear layer: ``BatchNorm -> Linear -> LeakyReLU`` per
    hidden layer, then ``BatchNorm ->`` the small-init linear output (sb3-contrib's CrossQ layout, with torch's
    ``BatchNorm1d`` where CrossQ uses batch renormalisation).

    In training mode (the critic step's joint pass) each layer normalises by the batch's own statistics and moves
    its running ones; in evaluation mode (the actor step, the default outside the critic step) by the running ones.
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...] = (256, 256)) -> None:
        nn.Module.__init__(self)
        self.obs_dim, self.act_dim, self.hidden = obs_dim, act_dim, tuple(hidden)
        self.net = mlp(obs_dim + act_dim, self.hidden, 1,
                       block=lambda width_in, width: [self._norm(width_in), *plain_block(width_in, width)],
                       before_head=lambda width: [self._norm(width)])
        self.eval()

    @staticmethod
    def _norm(width: int) -> nn.BatchNorm1d:
        return nn.BatchNorm1d(width, eps=BATCH_NORM_EPS, momentum=BATCH_NORM_MOMENTUM)


class Temperature(nn.Module):
    """The entropy temperature α, learned as ``log α`` (so α stays positive)."""

    def __init__(self, alpha: float) -> None:
        super().__init__()
        self.log_alpha = nn.Parameter(torch.tensor(math.log(alpha)))

    def forward(self) -> torch.Tensor:
        """α = exp(log α)."""
        return self.log_alpha.exp()


class SAC(OffPolicyAlgorithm):
    """SAC learner for one agent, built as every learner is (``SAC(obs_dim, act_dim, config, seed)``).

    The seed also seeds the learner's torch generator, which draws the update's samples.
    """

    config: SACConfig
    actor: GaussianActor
    acting: GaussianActor
    modules: tuple[str, ...] = ("actor", "critic", "critic2", "critic_target", "critic2_target", "temperature")
    target_pairs: tuple[tuple[str, str], ...] = (("critic", "critic_target"), ("critic2", "critic2_target"))
    uses_generator = True

    def build(self) -> None:
        """Squashed Gaussian actor, twin critics with targets (no target actor; with batch-norm critics no targets
        at all), temperature."""
        hidden = self.config.hidden
        self.actor = GaussianActor(self.obs_dim, self.act_dim, hidden, state_dependent_std=True)
        self.critic, self.critic2 = self.build_critic(), self.build_critic()
        self.critics = [self.critic, self.critic2]
        if self.config.critic_norm == "batch":
            self.modules = ("actor", "critic", "critic2", "temperature")
            self.target_pairs = ()
            self.critic_targets = []
        else:
            self.critic_target = self.target_copy(self.critic)
            self.critic2_target = self.target_copy(self.critic2)
            self.critic_targets = [self.critic_target, self.critic2_target]
        self.temperature = Temperature(self.config.alpha)
        self.target_entropy = (float(-self.act_dim) if self.config.target_entropy is None
                               else float(self.config.target_entropy))
        """H̄: the entropy the temperature steers the policy towards."""

    def build_critic(self) -> Critic:
        """One critic as :attr:`SACConfig.critic_norm` and :attr:`SACConfig.critic_loss` make it."""
        c = self.config
        if c.critic_loss == "hl_gauss":
            block = LayerNormCritic.block if c.critic_norm == "layer" else plain_block
            return HLGaussCritic(self.obs_dim, self.act_dim, c.hidden, c.value_low, c.value_high, c.value_bins,
                                 block=block)
        critic = {"none": Critic, "layer": LayerNormCritic, "batch": BatchNormCritic}[c.critic_norm]
        return critic(self.obs_dim, self.act_dim, c.hidden)

    def build_optimizers(self) -> None:
        """The actor's and the critics' Adam, and log α's when the temperature is learned."""
        super().build_optimizers()
        if self.config.learn_alpha:
            self.alpha_optimizer = adam(self.temperature.parameters(), self.config.alpha_lr)
            self.optimizers = (*self.optimizers, "alpha_optimizer")

    @property
    def alpha(self) -> float:
        """The current temperature α."""
        return float(self.temperature().item())

    # ------------------------------------------------------------------------ learning

    def td_target(self, batch: Batch) -> torch.Tensor:
        """``y = r + γ (1 - done) (Q'(s', a') - α log π(a'|s'))``, ``a' ~ π(·|s')``, ``(B,)``, with ``Q'`` the target
        critics' joint estimate (by default ``min_i Q'_i``: :func:`~triplesumo.algos.offpolicy.combine_q`) and γ^m
        with n-step returns (:meth:`~triplesumo.algos.offpolicy.OffPolicyAlgorithm.bootstrap`)."""
        b = self.batch(batch)
        with torch.no_grad():
            next_action, next_log_prob = self.actor.sample(b["next_obs"], self.generator)
            next_q = joint_q(self.critic_targets, b["next_obs"], next_action, self.config.pessimism)  # TARGETs
            soft_value = next_q - self.temperature() * next_log_prob
            return b["rew"] + self.bootstrap(b) * soft_value

    def regress_critics_jointly(self, b: dict[str, torch.Tensor]) -> dict[str, float]:
        """CrossQ's critic step (batch-norm critics, no targets): one Adam step on ``Σ_i mean (Q_i(s, a) - y)²`` with
        ``y = r + γ (1 - done) (Q(s', a') - α log π(a'|s'))``, ``a' ~ π(·|s')`` and ``Q`` the critics' joint estimate
        (by default ``min_i Q_i``), where each critic reads
        ``[(s, a); (s', a')]`` in one pass in training mode and its ``(s', a')`` half enters ``y`` detached. Returns
        ``critic_loss`` and ``q_mean`` (mean Q_1(s, a)), both before the step; the critics are back in evaluation
        mode after it."""
        with torch.no_grad():
            next_action, next_log_prob = self.actor.sample(b["next_obs"], self.generator)
        obs, act = torch.cat([b["obs"], b["next_obs"]]), torch.cat([b["act"], next_action])
        n = b["obs"].shape[0]
        for critic in self.critics:
            critic.train()
        try:
            qs, next_qs = zip(*(critic(obs, act).split(n) for critic in self.critics), strict=True)
        finally:
            for critic in self.critics:
                critic.eval()
        with torch.no_grad():
            next_q = combine_q(next_qs, self.config.pessimism)
            y = b["rew"] + self.bootstrap(b) * (next_q - self.temperature() * next_log_prob)
        return self.step_critics(list(qs), y, self.critic_optimizer)

    def update_actor(self, batch: Batch) -> tuple[dict[str, float], torch.Tensor]:
        """One Adam step on ``mean (α log π(a|s) - Q(s, a))``, ``Q`` the critics' joint estimate (by default
        ``min_i Q_i``; critics and α held fixed).

        Returns ``actor_loss`` and ``entropy`` (mean ``-log π``) before the step, and the
        batch's ``log π(a|s)`` (detached) for the temperature step.
        """
        obs = self.batch(batch)["obs"]
        with frozen(*self.critics):
            action, log_prob = self.actor.sample(obs, self.generator)
            alpha = self.temperature().detach()
            loss = (alpha * log_prob - joint_q(self.critics, obs, action, self.config.pessimism)).mean()
            descend(self.actor_optimizer, loss)
        log_prob = log_prob.detach()
        return {"actor_loss": loss.item(), "entropy": -log_prob.mean().item()}, log_prob

    def update_temperature(self, log_prob: torch.Tensor) -> dict[str, float]:
        """One Adam step on ``-mean log α (log π + H̄)``: α rises while the entropy is below H̄."""
        loss = -(self.temperature.log_alpha * (log_prob + self.target_entropy)).mean()
        descend(self.alpha_optimizer, loss)
        return {"alpha_loss": loss.item()}

    def train_step(self, b: dict[str, torch.Tensor]) -> dict[str, float]:
        """Critic step, actor step, temperature step (if learned), soft update of the critics (with targets).

        Returns ``critic_loss``, ``q_mean``, ``actor_loss``, ``entropy``, ``alpha`` (after
        the step) and, when α is learned, ``alpha_loss``.
        """
        if self.target_pairs:
            stats = self.regress_critics(self.critics, self.critic_optimizer, b, self.td_target(b))
        else:
            stats = self.regress_critics_jointly(b)
        actor_stats, log_prob = self.update_actor(b)
        stats |= actor_stats
        if self.config.learn_alpha:
            stats |= self.update_temperature(log_prob)
        if self.target_pairs:
            self.soft_update_targets()
        return stats | {"alpha": self.alpha}

    # ------------------------------------------------------------------------- acting

    def explore(self, obs: Any, rng: np.random.Generator,
                noise: ActionNoise | None = None) -> Any:
        """Training action sampled from the policy (:attr:`acting`), ``tanh(μ(s) + σ(s) ε)``, ε from ``rng``.

        SAC explores by its own stochasticity: passing a noise process is an error.
        """
        if noise is not None:
            raise ValueError("SAC explores by sampling its policy; do not pass an action noise")
        on_device = isinstance(obs, torch.Tensor)  # a device-resident collection: stay a tensor
        obs = obs if on_device else np.asarray(obs, dtype=np.float32)
        with torch.inference_mode():
            mean, log_std = self.acting.distribution(self.normalize(self.tensor(obs)))
            eps = self.tensor(rng.standard_normal(mean.shape))
            action = torch.tanh(mean + log_std.exp() * eps)
        return action if on_device else action.cpu().numpy().astype(np.float32, copy=False)
