"""Proximal Policy Optimization (Schulman et al., 2017), clipped objective, with GAE(λ).

PPO shares the networks (:class:`~triplesumo.agents.networks.GaussianActor`,
:class:`~triplesumo.agents.networks.ValueFunction`), the observation normaliser, the
checkpoint state, the finite checks and the policy export of
:class:`~triplesumo.algos.base.Algorithm`. Its own pieces, as in CleanRL's
``ppo_continuous_action.py``::

    advantages  Â_t = δ_t + γλ (1 - end_t) Â_{t+1},  δ_t = r_t + γ (1 - term_t) V(s_{t+1}) - V(s_t)
    policy      L_π = mean max(-Â ρ, -Â clip(ρ, 1-ε, 1+ε)),  ρ = π(u|s) / π_old(u|s)
    value       L_V = ½ mean max((V - R)², (V_old + clip(V - V_old, -ε, ε) - R)²)   (clip optional)
    loss        L_π - c_H · entropy + c_V · L_V,  Adam over minibatches for several epochs

**Action distribution (the choice made here).** The policy samples a pre-squash action
``u ~ N(μ(s), σ)`` and the env receives ``a = tanh(u)``. The rollout stores ``u``, so the
ratio ρ is the Gaussian's ratio at ``u``: the tanh Jacobian is the same under the old and the
new policy and cancels, so no ``atanh`` of a saturated action is ever needed. The entropy
bonus is the Gaussian's. Unlike CleanRL's clip-at-the-env Gaussian, actions need no clipping
and the deterministic policy ``tanh(μ(s))`` is exactly an
:class:`~triplesumo.agents.networks.Actor`, so it exports as a plain policy file. log σ is a
free vector by default (CleanRL), or a state-dependent head (``state_dependent_std``).

**Episode ends in a rollout.** A terminated step does not bootstrap; a truncated one (a draw
by the time limit) bootstraps from V of its real final observation (``final_obs`` in
:meth:`PPO.record`); neither carries the advantage across into the next episode.

**Using it.** For ``T = n_steps`` collection steps of ``N`` matches: ``observe(obs)`` (the
normaliser), ``action = explore(obs, rng)``, step, ``record(reward, terminated, truncated,
final_obs)``; when :attr:`PPO.rollout_full`, ``update(next_obs)`` trains on the rollout and
empties it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
import torch.nn.functional as F

from triplesumo.agents.networks import GaussianActor, ValueFunction, gaussian_entropy, gaussian_log_prob
from triplesumo.algos.base import Algorithm, adam, descend
from triplesumo.algos.config import at_least, flag, fraction, hidden_sizes, learning_rate, non_negative, real, require


@dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters; defaults from Schulman et al. (2017) and CleanRL's continuous PPO."""

    lr: float = 3e-4
    """Adam learning rate of policy and value networks, in (0, 1] (CleanRL: 3e-4)."""
    n_steps: int = 2048
    """T: collection steps per match in one rollout; a rollout holds T x N transitions."""
    gamma: float = 0.99
    """Discount factor γ, in (0, 1]."""
    gae_lambda: float = 0.95
    """λ of GAE, in [0, 1] (0: one-step TD advantages; 1: Monte-Carlo returns)."""
    n_epochs: int = 10
    """Passes over the rollout per update (CleanRL: 10)."""
    n_minibatches: int = 32
    """Minibatches per pass; the rollout's T x N transitions are split evenly (CleanRL: 32)."""
    clip_coef: float = 0.2
    """ε of the clipped objective, > 0 (PPO paper: 0.2)."""
    clip_value: bool = True
    """Clip the value update around the rollout's values with the same ε (CleanRL's default)."""
    normalize_advantages: bool = True
    """Normalise advantages per minibatch to zero mean and unit variance."""
    ent_coef: float = 0.0
    """c_H: weight of the entropy bonus, >= 0 (CleanRL: 0)."""
    vf_coef: float = 0.5
    """c_V: weight of the value loss, >= 0 (CleanRL: 0.5)."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip, > 0 (CleanRL: 0.5)."""
    target_kl: float | None = None
    """Stop an update's epochs early once the approximate KL exceeds this; None never stops."""
    hidden: tuple[int, ...] = (64, 64)
    """Hidden layer widths of the policy and value networks (CleanRL: 64, 64)."""
    state_dependent_std: bool = False
    """log σ from a head on the policy's features (True) or one learned vector (CleanRL)."""
    log_std_init: float = 0.0
    """Initial log σ of the state-independent Gaussian."""
    normalize_obs: bool = True
    """Normalise observations by their running mean and variance."""

    TUNABLE: ClassVar[tuple[str, ...]] = ("lr", "gamma", "gae_lambda", "n_epochs", "n_minibatches", "clip_coef",
                                          "clip_value", "normalize_advantages", "ent_coef", "vf_coef",
                                          "max_grad_norm", "target_kl")
    """The fields a run continued from a checkpoint may change (fine-tuning; see
    :attr:`~triplesumo.algos.config.OffPolicyConfig.TUNABLE`): not the rollout length, widths, σ's
    parametrisation or normalisation, which make what the checkpoint holds."""

    def __post_init__(self) -> None:
        hidden_sizes(self)
        learning_rate(self, "lr")
        fraction(self, "gamma")
        fraction(self, "gae_lambda", zero_ok=True)
        for name in ("n_steps", "n_epochs", "n_minibatches"):
            at_least(self, name, 1)
        require(self, "clip_coef", real(self, "clip_coef") > 0, "must be > 0")
        require(self, "max_grad_norm", real(self, "max_grad_norm") > 0, "must be > 0")
        for name in ("ent_coef", "vf_coef"):
            non_negative(self, name)
        if self.target_kl is not None:
            require(self, "target_kl", real(self, "target_kl") > 0, "must be > 0 (or None)")
        real(self, "log_std_init")
        for name in ("clip_value", "normalize_advantages", "state_dependent_std", "normalize_obs"):
            flag(self, name)


def gae(rewards: torch.Tensor, values: torch.Tensor, next_values: torch.Tensor,
        terminated: torch.Tensor, truncated: torch.Tensor, gamma: float, lam: float,
        valid: torch.Tensor | None = None) -> torch.Tensor:
    """Generalised advantage estimates over a ``(T, N)`` rollout (Schulman et al., 2016).

    ``next_values[t]`` is V of the state that followed step t (for a truncated step, its
    real final observation). ``δ_t = r_t + γ (1 - terminated_t) next_values_t - values_t``;
    ``Â_t = δ_t + γλ (1 - end_t) Â_{t+1}`` with ``end = terminated or truncated``, and
    ``Â_T = 0`` (the value of the state after the last step is in ``next_values[T-1]``).
    A row with ``valid == 0`` (an agent already out, a physics error: left out of the loss)
    carries nothing back: the step before it ends its trace at ``δ_t``, bootstrapping from V
    of the state it reached, as at a truncation.
    """
    advantages = torch.zeros_like(rewards)
    carry = torch.zeros_like(rewards[0])
    for t in reversed(range(rewards.shape[0])):
        delta = rewards[t] + gamma * (1.0 - terminated[t]) * next_values[t] - values[t]
        end = torch.maximum(terminated[t], truncated[t])
        carry = delta + gamma * lam * (1.0 - end) * carry
        advantages[t] = carry
        if valid is not None:
            carry = carry * valid[t]
    return advantages


def clipped_surrogate(log_ratio: torch.Tensor, advantages: torch.Tensor, clip: float) -> torch.Tensor:
    """PPO's policy loss ``mean max(-Â ρ, -Â clip(ρ, 1-ε, 1+ε))`` with ``ρ = exp(log_ratio)``.

    The gradient is zero where the ratio has left ``[1-ε, 1+ε]`` on the side the advantage
    pushes it to (ρ > 1+ε with Â > 0, ρ < 1-ε with Â < 0).
    """
    ratio = log_ratio.exp()
    return torch.max(-advantages * ratio, -advantages * ratio.clamp(1.0 - clip, 1.0 + clip)).mean()


class PPO(Algorithm):
    """PPO learner for one agent: Gaussian policy, value function, rollout and update.

    Built as every learner is (``PPO(obs_dim, act_dim, config, seed)``); the seed also seeds
    the learner's torch generator, which shuffles the minibatches.
    """

    config: PPOConfig
    actor: GaussianActor
    modules = ("actor", "critic")
    optimizers = ("optimizer",)
    uses_generator = True
    _ROLLOUT = ("obs", "u", "log_prob", "value", "reward", "terminated", "truncated", "bootstrap", "valid")
    _MINIBATCH = ("obs", "u", "log_prob", "value", "advantage", "return")
    """What a minibatch step reads: the first four from the rollout, then GAE's two."""

    def __init__(self, obs_dim: int, act_dim: int, config: PPOConfig, seed: int,
                 device: str | torch.device = "cpu") -> None:
        super().__init__(obs_dim, act_dim, config, seed, device)
        self.rollout: dict[str, torch.Tensor] = {}
        """The rollout being collected, ``(T, N, ...)`` tensors (allocated at the first step)."""
        self.step = 0
        """Steps recorded in the current rollout."""
        self._pending: dict[str, torch.Tensor] | None = None

    def build(self) -> None:
        c = self.config
        self.actor = GaussianActor(self.obs_dim, self.act_dim, c.hidden, c.state_dependent_std,
                                   c.log_std_init)
        self.critic = ValueFunction(self.obs_dim, c.hidden)

    def build_optimizers(self) -> None:
        params = [*self.actor.parameters(), *self.critic.parameters()]
        self.optimizer = adam(params, self.config.lr, eps=1e-5)  # CleanRL's eps

    # ------------------------------------------------------------------------ collecting

    @property
    def rollout_full(self) -> bool:
        """Whether ``n_steps`` steps have been recorded (time for :meth:`update`)."""
        return self.step >= self.config.n_steps

    def explore(self, obs: np.ndarray | torch.Tensor, rng: np.random.Generator) -> Any:
        """Sample ``a = tanh(u)``, ``u ~ N(μ(s), σ)`` (ε from ``rng``) for ``(N, obs_dim)`` obs.

        Remembers the normalised obs, ``u``, ``log π(u|s)`` and ``V(s)`` for :meth:`record`.
        """
        on_device = isinstance(obs, torch.Tensor)  # a device-resident collection: stay a tensor
        x = self.normalize(self.tensor(obs if on_device else np.asarray(obs, dtype=np.float32)))
        if x.ndim != 2 or x.shape[1] != self.obs_dim:
            raise ValueError(f"obs must have shape (N, {self.obs_dim}), got {tuple(x.shape)}")
        with torch.no_grad():
            mean, log_std = self.actor.distribution(x)
            u = mean + log_std.exp() * self.tensor(rng.standard_normal(mean.shape))
            self._pending = {"obs": x, "u": u, "log_prob": gaussian_log_prob(u, mean, log_std),
                             "value": self.critic(x)}
        return torch.tanh(u) if on_device else torch.tanh(u).cpu().numpy().astype(np.float32, copy=False)

    def record(self, reward: np.ndarray | torch.Tensor, terminated: np.ndarray | torch.Tensor,
               truncated: np.ndarray | torch.Tensor, final_obs: np.ndarray | torch.Tensor | None = None,
               valid: np.ndarray | torch.Tensor | None = None) -> None:
        """Store the step just taken: ``(N,)`` rewards and end flags, and for truncated
        matches their real final observations (rows of ``final_obs``, raw) to bootstrap from.

        ``valid`` (``(N,)``, default all) marks the rows that are real steps: a row of an agent
        already out of its match (elimination rules) or of a physics error is kept in the
        rollout's shape but left out of the loss; record it as terminated (no bootstrap, no
        advantage carried across)."""
        if self._pending is None:
            raise RuntimeError("record() needs a preceding explore()")
        if self.rollout_full:
            raise RuntimeError("the rollout is full: call update() first")
        step = dict(self._pending)
        n = step["obs"].shape[0]
        step["reward"], step["terminated"], step["truncated"] = (
            self.tensor(_float32(x)).reshape(n) for x in (reward, terminated, truncated))
        step["valid"] = torch.ones(n, device=self.device) if valid is None else self.tensor(
            _float32(valid)).reshape(n)
        step["bootstrap"] = torch.zeros(n, device=self.device)
        if bool(step["truncated"].any()):
            if final_obs is None:
                raise ValueError("a truncated match needs its final observation (final_obs)")
            with torch.no_grad():
                step["bootstrap"] = self.critic(self.normalize(self.tensor(final_obs)))
        if not self.rollout:
            t = self.config.n_steps
            self.rollout = {k: torch.zeros((t, *v.shape), device=self.device) for k, v in step.items()}
        for key in self._ROLLOUT:
            self.rollout[key][self.step] = step[key]
        self.step += 1
        self._pending = None

    def rollout_state(self) -> dict[str, np.ndarray]:
        """The rollout collected so far as numpy arrays (for a checkpoint's npz; no pickle).

        Saved between a :meth:`record` and the next :meth:`explore` (no step pending), it
        lets a resumed run finish the rollout exactly.
        """
        if self._pending is not None:
            raise RuntimeError("a step is pending (explore() without record()): checkpoint after record()")
        state = {k: v[: self.step].cpu().numpy() for k, v in self.rollout.items()}
        return state | {"step": np.asarray(self.step, dtype=np.int64)}

    def load_rollout_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore :meth:`rollout_state` (``KeyError``/``ValueError`` name what does not fit)."""
        step = int(np.asarray(state["step"]))
        if not 0 <= step <= self.config.n_steps:
            raise ValueError(f"rollout step {step} is outside [0, {self.config.n_steps}]")
        self.rollout, self.step, self._pending = {}, step, None
        if step == 0:
            return
        for key in self._ROLLOUT:
            if key not in state:
                raise KeyError(f"rollout state is missing {key!r}")
            value = self.tensor(state[key])
            if value.shape[0] != step:
                raise ValueError(f"rollout {key!r} has {value.shape[0]} steps, expected {step}")
            self.rollout[key] = torch.zeros((self.config.n_steps, *value.shape[1:]), device=self.device)
            self.rollout[key][:step] = value

    # ------------------------------------------------------------------------ learning

    def advantages(self, next_obs: np.ndarray | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """GAE advantages and returns ``(T, N)`` of the full rollout; ``next_obs`` follows its last step."""
        r = self.rollout
        with torch.no_grad():
            last_value = self.critic(self.normalize(self.tensor(next_obs)))
        next_values = torch.cat([r["value"][1:], last_value[None]])
        next_values = torch.where(r["truncated"] > 0, r["bootstrap"], next_values)
        adv = gae(r["reward"], r["value"], next_values, r["terminated"], r["truncated"],
                  self.config.gamma, self.config.gae_lambda, r["valid"])
        return adv, adv + r["value"]

    def update(self, next_obs: np.ndarray | torch.Tensor) -> dict[str, float]:
        """Train on the full rollout (``n_epochs`` x ``n_minibatches`` Adam steps) and empty it.

        Returns the means over minibatches of ``actor_loss``, ``critic_loss``, ``entropy``,
        ``approx_kl`` and ``clip_fraction``, finite-checked.
        """
        if not self.rollout_full:
            raise RuntimeError(f"the rollout holds {self.step} of {self.config.n_steps} steps")
        c = self.config
        adv, returns = self.advantages(next_obs)
        flat = {k: self.rollout[k].flatten(0, 1) for k in self._MINIBATCH[:4]} | {
            "advantage": adv.flatten(), "return": returns.flatten()}
        valid = self.rollout["valid"].flatten() > 0
        if not bool(valid.all()):
            flat = {k: v[valid] for k, v in flat.items()}
        size = flat["value"].shape[0]
        minibatch = max(size // c.n_minibatches, 1)
        totals: dict[str, float] = {}
        count = 0
        for _ in range(c.n_epochs):
            order = torch.randperm(size, generator=self.generator, device=self.device)
            for start in range(0, size - minibatch + 1, minibatch):
                rows = order[start:start + minibatch]
                stats = self.minibatch_step({k: v.index_select(0, rows) for k, v in flat.items()})
                totals = {k: totals.get(k, 0.0) + v for k, v in stats.items()}
                count += 1
            if c.target_kl is not None and count and stats["approx_kl"] > c.target_kl:
                break
        self.rollout, self.step = {}, 0
        return self.finish_update({k: v / count for k, v in totals.items()})

    def minibatch_step(self, mb: dict[str, torch.Tensor]) -> dict[str, float]:
        """One Adam step on the clipped policy loss, the (clipped) value loss and the entropy bonus."""
        c = self.config
        mean, log_std = self.actor.distribution(mb["obs"])
        log_ratio = gaussian_log_prob(mb["u"], mean, log_std) - mb["log_prob"]
        advantage = mb["advantage"]
        if c.normalize_advantages and advantage.numel() > 1:
            advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
        policy_loss = clipped_surrogate(log_ratio, advantage, c.clip_coef)
        value = self.critic(mb["obs"])
        value_loss = F.mse_loss(value, mb["return"], reduction="none")
        if c.clip_value:
            clipped = mb["value"] + (value - mb["value"]).clamp(-c.clip_coef, c.clip_coef)
            value_loss = torch.max(value_loss, (clipped - mb["return"]).square())
        value_loss = 0.5 * value_loss.mean()
        entropy = gaussian_entropy(log_std).mean()
        loss = policy_loss - c.ent_coef * entropy + c.vf_coef * value_loss
        descend(self.optimizer, loss, c.max_grad_norm)
        with torch.no_grad():
            ratio_minus_1 = log_ratio.exp() - 1.0
            approx_kl = (ratio_minus_1 - log_ratio).mean()  # k3 estimator (CleanRL)
            clip_fraction = (ratio_minus_1.abs() > c.clip_coef).float().mean()
            stats = torch.stack([policy_loss, value_loss, entropy, approx_kl, clip_fraction]).tolist()
        return dict(zip(("actor_loss", "critic_loss", "entropy", "approx_kl", "clip_fraction"), stats, strict=True))


def _float32(x: Any) -> np.ndarray | torch.Tensor:
    """``x`` as float32: numpy stays numpy, a tensor (device-resident collection) stays on its device."""
    return x.to(torch.float32) if isinstance(x, torch.Tensor) else np.asarray(x, dtype=np.float32)
