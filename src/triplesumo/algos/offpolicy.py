"""The off-policy core that DDPG, TD3 and SAC share (as SB3's ``OffPolicyAlgorithm``).

It owns what the three have in common and nothing else:

- **batches**: replay samples as float32 tensors on the device, observations normalised with
  the current running statistics (the replay stores raw observations, as SB3 does);
- **update scheduling**: :meth:`OffPolicyAlgorithm.updates_due`;
- **critic regression**: :meth:`OffPolicyAlgorithm.regress_critics`, one Adam step of
  ``Σ_i mean (Q_i(s, a) - y)²`` onto a target ``y`` that each algorithm states;
- **target networks**: :meth:`OffPolicyAlgorithm.soft_update_targets`, θ' <- τθ + (1-τ)θ'
  for every pair in ``target_pairs``;
- **exploration** by a deterministic actor plus the caller's noise process
  (:meth:`OffPolicyAlgorithm.explore`; SAC samples its own policy instead);
- and, from :class:`~triplesumo.algos.base.Algorithm`, seeded networks, checkpoints,
  finite checks and policy export.

Each algorithm states what differs in :meth:`OffPolicyAlgorithm.train_step`: its TD target,
its actor loss and when the targets move. :meth:`OffPolicyAlgorithm.update` runs it in float32, or under
``torch.autocast`` with the config's ``update_dtype`` bfloat16.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from triplesumo.agents.networks import Critic
from triplesumo.algos.base import Algorithm, adam, descend
from triplesumo.algos.noise import ActionNoise

Batch = Mapping[str, np.ndarray | torch.Tensor]
"""A replay sample: ``obs``, ``act``, ``rew``, ``next_obs``, ``done`` and, with n-step returns, ``discount`` (see
``ReplayBuffer.sample``)."""


def combine_q(qs: Sequence[torch.Tensor], pessimism: float = 1.0) -> torch.Tensor:
    """The critics' joint estimate of Q from their values ``qs``: one critic's own; two critics'
    ``mean - β |Q_1 - Q_2| / 2`` with β = ``pessimism``. β = 1 is their minimum (clipped double Q, Fujimoto et al.,
    2018), computed as ``torch.minimum`` so that the default stays bit for bit what it was; β = 0 is their mean;
    β < 0 is optimistic (TOP, Moskovitz et al., 2021; BRO, Nauman et al., 2024)."""
    if len(qs) == 1:
        return qs[0]
    if len(qs) != 2:
        raise ValueError(f"combine_q takes one or two critics' values, got {len(qs)}")
    if pessimism == 1.0:
        return functools.reduce(torch.minimum, qs)
    q1, q2 = qs
    return (q1 + q2) / 2 - pessimism * (q1 - q2).abs() / 2


def joint_q(critics: Sequence[Critic], obs: torch.Tensor, action: torch.Tensor,
            pessimism: float = 1.0) -> torch.Tensor:
    """The critics' joint estimate of ``Q(s, a)`` (:func:`combine_q`): by default ``min_i Q_i(s, a)`` (clipped
    double Q); one critic gives its own Q."""
    return combine_q([critic(obs, action) for critic in critics], pessimism)


class OffPolicyAlgorithm(Algorithm):
    """Base of DDPG, TD3 and SAC; subclasses build networks and state :meth:`train_step`."""

    target_pairs: tuple[tuple[str, str], ...] = ()
    """``(online, target)`` attribute names that :meth:`soft_update_targets` averages."""
    optimizers: tuple[str, ...] = ("actor_optimizer", "critic_optimizer")
    critics: list[Critic]
    """Q_1 (, Q_2): the online critics, all regressed onto the same target."""
    critic_targets: list[Critic]
    """Q'_1 (, Q'_2): their target copies."""

    def build_optimizers(self) -> None:
        """Adam for the actor, and one Adam over all critics (with the critics' weight decay)."""
        critic_params = [p for critic in self.critics for p in critic.parameters()]
        self.actor_optimizer = adam(self.actor.parameters(), self.config.actor_lr)
        self.critic_optimizer = adam(critic_params, self.config.critic_lr, self.config.weight_decay)

    # ------------------------------------------------------------------------- batches

    def batch(self, batch: Batch) -> dict[str, torch.Tensor]:
        """Batch as float32 tensors on the device; ``rew``, ``done`` (and ``discount``, where the batch has it)
        flattened to ``(B,)``; ``obs`` and ``next_obs`` normalised (when the learner normalises observations).

        Already-prepared batches (as returned here) pass through unchanged.
        """
        if isinstance(batch, _PreparedBatch):
            return batch
        out = _PreparedBatch()
        for key in ("obs", "act", "rew", "next_obs", "done"):
            if key not in batch:
                raise KeyError(f"batch is missing {key!r}")
            out[key] = self.tensor(batch[key])
        if "discount" in batch:
            out["discount"] = self.tensor(batch["discount"])
        n = out["obs"].shape[0]
        for key in [k for k in ("rew", "done", "discount") if k in out]:
            out[key] = out[key].reshape(-1)
            if out[key].shape != (n,):
                raise ValueError(f"batch[{key!r}] must have {n} entries, got {out[key].shape}")
        for key in ("obs", "next_obs"):
            out[key] = self.normalize(out[key])
        return out

    # ------------------------------------------------------------------------ learning

    def update(self, batch: Batch) -> dict[str, float]:
        """One gradient update on a replay sample; returns its finite-checked scalar stats.

        Raises:
            DivergenceError: A loss or statistic is not finite (names the update index).
            ValueError: ``n_step`` is above 1 and the batch has no ``discount``: one-step transitions would be
                learned from as if they were n-step ones' (the trainer makes n-step ones; a loop of one's own needs
                :class:`~triplesumo.algos.nstep.NStepReturns`, or ``n_step=1``).
        """
        if self.config.n_step > 1 and "discount" not in batch:
            name = type(self.config).__name__
            raise ValueError(f"{name}.n_step is {self.config.n_step} but the batch has no 'discount': feed n-step "
                             "transitions (triplesumo.algos.nstep.NStepReturns into ReplayBuffer(..., discount=True)) "
                             f"or make the learner with {name}(n_step=1) for one-step ones")
        prepared = self.batch(batch)
        with self.update_precision():
            stats = self.train_step(prepared)
        stats = self.finish_update(stats)
        if self.config.reset_every and self.num_updates % self.config.reset_every == 0:
            self.reset()
        return stats

    def reset(self) -> None:
        """Re-initialise the learner (``reset_every``): every network, target and optimiser as a learner of the same
        config builds them under a seed drawn from this learner's seed and the reset's index
        (``num_updates // reset_every``), so a resumed run resets as an uninterrupted one does. The weights are
        copied into the networks in place (the optimisers, the exported policy and an acting copy keep pointing
        at them) and Adam's moments start again; the observation normaliser, the update count, the learner's
        generator and the caller's replay are kept."""
        index = self.num_updates // self.config.reset_every
        seed = int(np.random.SeedSequence([self.seed, index]).generate_state(1)[0])
        fresh = type(self)(self.obs_dim, self.act_dim, self.config, seed, device=self.device)
        with torch.no_grad():
            for name in self.modules:
                if name != "obs_norm":
                    getattr(self, name).load_state_dict(getattr(fresh, name).state_dict())
        for name in self.optimizers:
            getattr(self, name).state.clear()

    def update_precision(self) -> contextlib.AbstractContextManager[Any]:
        """The context an update runs in: nothing for float32; for bfloat16, ``torch.autocast`` without its cache
        of cast weights (a cached cast would hand a later step of the same update the weights from before an
        earlier step: SAC's actor step reads the critics its critic step has just moved)."""
        if self.config.update_dtype == "float32":
            return contextlib.nullcontext()
        return torch.autocast(self.device.type, dtype=getattr(torch, self.config.update_dtype), cache_enabled=False)

    def train_step(self, b: dict[str, torch.Tensor]) -> dict[str, float]:
        """The algorithm's update on a prepared batch (``self.num_updates`` is its index)."""
        raise NotImplementedError

    def bootstrap(self, b: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """The factor of each transition's bootstrap value in its TD target, ``(B,)``: ``γ (1 - done)``, or
        ``γ^m (1 - done)`` with the batch's ``discount`` γ^m (n-step returns: m is the steps the transition
        spans)."""
        return b.get("discount", self.config.gamma) * (1.0 - b["done"])

    def updates_due(self, before: int, after: int, stored: int) -> int:
        """Gradient updates due when the collected transitions go from ``before`` to ``after``.

        ``G = gradient_steps`` for every multiple of ``K = learn_every`` crossed, once
        ``after >= learning_starts`` and the replay holds ``stored >= batch_size``
        transitions (1 step in K, not the paper's original code's K-1 in K).
        """
        c = self.config
        if after < c.learning_starts or stored < c.batch_size:
            return 0
        return int((after // c.learn_every - before // c.learn_every) * c.gradient_steps)

    def regress_critics(self, critics: Sequence[Critic], optimizer: torch.optim.Optimizer,
                        b: Mapping[str, torch.Tensor], y: torch.Tensor) -> dict[str, float]:
        """One Adam step on the sum of the critics' regression losses onto ``y`` (``Σ_i mean (Q_i(s, a) - y)²`` for
        plain critics: :meth:`~triplesumo.agents.networks.Critic.regression_loss`); returns ``critic_loss`` and
        ``q_mean`` (mean Q_1(s, a)), both before the step."""
        losses, qs = zip(*(critic.regression_loss(b["obs"], b["act"], y) for critic in critics), strict=True)
        return self.descend_critics(losses, qs, optimizer)

    def step_critics(self, qs: Sequence[torch.Tensor], y: torch.Tensor,
                     optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """One Adam step on ``Σ_i mean (q_i - y)²`` for critics' Q-values ``qs`` already computed (with their graph);
        returns ``critic_loss`` and ``q_mean`` (mean ``qs[0]``), both before the step."""
        return self.descend_critics([F.mse_loss(q, y) for q in qs], qs, optimizer)

    @staticmethod
    def descend_critics(losses: Sequence[torch.Tensor], qs: Sequence[torch.Tensor],
                        optimizer: torch.optim.Optimizer) -> dict[str, float]:
        """One Adam step on the sum of the critics' ``losses``; returns it as ``critic_loss`` and ``q_mean`` (mean
        ``qs[0]``), both before the step."""
        loss = sum(losses[1:], losses[0])
        descend(optimizer, loss)
        return {"critic_loss": loss.item(), "q_mean": qs[0].detach().mean().item()}

    def soft_update_targets(self) -> None:
        """Polyak-average every target toward its online net: θ' <- τθ + (1 - τ)θ'.

        One multi-tensor ``lerp`` over all pairs (bit for bit the per-tensor ``lerp_``)."""
        online: list[torch.Tensor] = []
        target: list[torch.Tensor] = []
        for online_name, target_name in self.target_pairs:
            online_net: nn.Module = getattr(self, online_name)
            target_net: nn.Module = getattr(self, target_name)
            pairs = zip(online_net.parameters(), target_net.parameters(), strict=True)
            for p, p_targ in pairs:
                online.append(p)
                target.append(p_targ)
        with torch.no_grad():
            torch._foreach_lerp_(target, online, self.config.tau)

    # ------------------------------------------------------------------------- acting

    def explore(self, obs: Any, rng: np.random.Generator, noise: ActionNoise | None = None) -> Any:
        """Training action: ``clip(μ(s) + noise, -1, 1)`` (no noise: the deterministic action); the noise is
        drawn on the host from ``rng``. Observations on the device (a tensor) give a tensor there. The actor that
        acts is :attr:`acting` (the online actor, or its copy)."""
        if isinstance(obs, torch.Tensor):
            with torch.inference_mode():
                action = self.acting(self.normalize(self.tensor(obs)))
        else:
            action = self.acting_policy(obs)
        if noise is None:
            return action
        if isinstance(action, torch.Tensor):
            return (action + self.tensor(noise.sample(rng))).clamp(-1.0, 1.0)
        return np.clip(action + noise.sample(rng), -1.0, 1.0)


class _PreparedBatch(dict[str, torch.Tensor]):
    """A batch already converted and normalised by :meth:`OffPolicyAlgorithm.batch`."""

    prepared = True

