"""Actor, critic, Gaussian actor and value MLPs, and :class:`ActorPolicy`, the numpy-facing policy.

Architecture follows the paper's original code: two hidden layers (512, 256) with leaky
ReLU; the actor ends in ``tanh`` so actions are *normalized* to [-1, 1] (the env scales them
to each agent's control range, read from the MJCF). The last layer of both networks is
initialised uniformly in ±3e-3, as in DDPG (Lillicrap et al., 2015, §7), so initial actions
and Q-values are near zero.

:class:`Actor` and :class:`Critic` serve DDPG and TD3; :class:`GaussianActor` (SAC and PPO)
shares the actor's mean path, so its deterministic policy ``tanh(mean(s))`` exports as a
plain :class:`Actor` (:meth:`GaussianActor.to_actor`) that every policy-file reader loads;
:class:`ValueFunction` is PPO's V(s).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from triplesumo.agents.normalizer import ObsNormalizer

FINAL_INIT = 3e-3
"""Half-width of the uniform initialisation of the last layer (Lillicrap et al., 2015)."""


def _check_sizes(obs_dim: int, act_dim: int, hidden: tuple[int, ...]) -> None:
    for name, value in (("obs_dim", obs_dim), ("act_dim", act_dim)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be an int >= 1, got {value!r}")
    if len(hidden) == 0 or any(
        isinstance(h, bool) or not isinstance(h, int) or h < 1 for h in hidden
    ):
        raise ValueError(f"hidden must be a non-empty tuple of ints >= 1, got {hidden!r}")


class FloatHead(nn.Linear):
    """An output layer that stays in float32 under ``torch.autocast``: the hidden layers' matrix products may run
    in bfloat16 (an off-policy learner's ``update_dtype``), but a Q-value, a mean or a log σ read from a
    bfloat16 product would keep 8 bits of mantissa (a Q of 300 in steps of 2). Outside autocast it is exactly
    ``nn.Linear`` (same tensors, same state-dict keys, same results)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if torch.is_autocast_enabled(x.device.type):
            with torch.autocast(x.device.type, enabled=False):
                return F.linear(x.float(), self.weight, self.bias)
        return F.linear(x, self.weight, self.bias)


def plain_block(width_in: int, width: int) -> list[nn.Module]:
    """One hidden layer of :func:`mlp`: ``Linear -> LeakyReLU``."""
    return [nn.Linear(width_in, width), nn.LeakyReLU()]


def mlp(in_dim: int, hidden: tuple[int, ...], out_dim: int,
        block: Callable[[int, int], list[nn.Module]] = plain_block,
        before_head: Callable[[int], list[nn.Module]] = lambda width: []) -> nn.Sequential:
    """A stack of ``block(width_in, width)`` per hidden layer (:func:`plain_block` by default; a normalised critic
    states its own), then ``before_head(width)`` and a linear layer (:class:`FloatHead`) with a small uniform init."""
    layers: list[nn.Module] = []
    for width in hidden:
        layers += block(in_dim, width)
        in_dim = width
    last = FloatHead(in_dim, out_dim)
    nn.init.uniform_(last.weight, -FINAL_INIT, FINAL_INIT)
    nn.init.uniform_(last.bias, -FINAL_INIT, FINAL_INIT)
    return nn.Sequential(*layers, *before_head(in_dim), last)


class Actor(nn.Module):
    """Deterministic policy μ(s): observation -> normalized action in [-1, 1].

    Args:
        obs_dim: Size of the (flat) observation.
        act_dim: Size of the action.
        hidden: Widths of the hidden layers (leaky ReLU after each).
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...] = (512, 256)) -> None:
        super().__init__()
        hidden = tuple(hidden)
        _check_sizes(obs_dim, act_dim, hidden)
        self.obs_dim = obs_dim
        self.act_dim = act_dim
        self.hidden = hidden
        self.net = mlp(obs_dim, hidden, act_dim)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Map ``(..., obs_dim)`` observations to ``(..., act_dim)`` actions in [-1, 1]."""
        return torch.tanh(self.net(obs))

    @classmethod
    def from_state_dict(cls, tensors: Mapping[str, torch.Tensor], prefix: str = "actor.") -> Actor:
        """Rebuild an actor from (a flat, prefixed) state dict, inferring all sizes.

        ``tensors`` may be a whole :meth:`triplesumo.algos.ddpg.DDPG.state_dict` (e.g. loaded
        with ``safetensors.torch.load_file``); only keys starting with ``prefix`` are used.
        """
        own = {k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)}
        weights = sorted(
            (int(k.split(".")[1]), v)
            for k, v in own.items()
            if k.startswith("net.") and k.endswith(".weight")
        )
        if not weights:
            raise KeyError(
                f"no actor weights with prefix {prefix!r} (expected '{prefix}net.0.weight')"
            )
        obs_dim = int(weights[0][1].shape[1])
        widths = [int(w.shape[0]) for _, w in weights]
        actor = cls(obs_dim, widths[-1], tuple(widths[:-1]))
        actor.load_state_dict(own)
        return actor


class Critic(nn.Module):
    """Action-value function Q(s, a) on the concatenation ``[obs, action]``.

    :meth:`forward` returns shape ``(batch,)`` (the trailing unit dimension is squeezed), so
    it lines up with 1-D reward and done arrays without broadcasting surprises.

    Args:
        obs_dim: Size of the (flat) observation.
        act_dim: Size of the action.
        hidden: Widths of the hidden layers (leaky ReLU after each).
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...] = (512, 256)) -> None:
        super().__init__()
        hidden = tuple(hidden)
        _check_sizes(obs_dim, act_dim, hidden)
        self.obs_dim = obs_dim
        self.act_dim = act_dim
        self.hidden = hidden
        self.net = mlp(obs_dim + act_dim, hidden, 1)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Q-values ``(...,)`` for ``(..., obs_dim)`` obs and ``(..., act_dim)`` actions."""
        return self.net(torch.cat([obs, action], dim=-1)).squeeze(-1)

    def regression_loss(self, obs: torch.Tensor, action: torch.Tensor,
                        target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The loss of regressing ``Q(s, a)`` onto the TD targets ``target (B,)``, and the Q-values ``(B,)`` (with
        their graph): ``mean (Q - y)²``. A critic that learns another way (a histogram of returns) states its own."""
        q = self(obs, action)
        return F.mse_loss(q, target), q


LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0
"""Bounds of a state-dependent log σ (CleanRL's SAC squashes into them with tanh)."""


def tanh_log_det_jacobian(u: torch.Tensor) -> torch.Tensor:
    """``sum log(1 - tanh(u)²)`` over the last axis, in the stable form ``2(log 2 - u - softplus(-2u))``.

    Subtracted from a Gaussian log-density of ``u`` it gives the log-density of ``tanh(u)``
    (SAC, Haarnoja et al., 2018, appendix C).
    """
    return (2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))).sum(-1)


class GaussianActor(Actor):
    """Diagonal Gaussian policy over a pre-squash action ``u``; the action is ``tanh(u)``.

    An :class:`Actor` (its mean path ``net`` and deterministic :meth:`forward`,
    ``tanh(mean(s))``) plus a log σ: either a head on the last hidden layer
    (``state_dependent_std``, SAC's; squashed into [:data:`LOG_STD_MIN`,
    :data:`LOG_STD_MAX`]) or one learned vector (PPO's, CleanRL's). :meth:`to_actor` drops
    the log σ, leaving the deterministic policy that policy files hold.

    Args:
        obs_dim: Size of the (flat) observation.
        act_dim: Size of the action.
        hidden: Widths of the hidden layers (leaky ReLU after each).
        state_dependent_std: log σ from a head on the features (True) or a free parameter.
        log_std_init: Initial value of the free log σ (state-independent only).
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...] = (256, 256),
                 state_dependent_std: bool = True, log_std_init: float = 0.0) -> None:
        super().__init__(obs_dim, act_dim, hidden)
        self.state_dependent_std = state_dependent_std
        self.log_std_head: nn.Linear | None = None
        self.log_std: nn.Parameter | None = None
        if state_dependent_std:
            self.log_std_head = FloatHead(self.hidden[-1], act_dim)
        else:
            self.log_std = nn.Parameter(torch.full((act_dim,), float(log_std_init)))

    def distribution(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and log σ of the Gaussian over ``u``, each ``(..., act_dim)``."""
        *body, head = self.net  # (slicing the Sequential would build a new one at every call)
        features = obs
        for layer in body:
            features = layer(features)
        mean = head(features)
        if self.log_std_head is not None:
            squashed = torch.tanh(self.log_std_head(features))
            log_std = LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (squashed + 1.0)
        else:
            assert self.log_std is not None
            log_std = self.log_std.expand_as(mean)
        return mean, log_std

    def sample(self, obs: torch.Tensor, generator: torch.Generator | None = None
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """Reparameterised ``a = tanh(μ + σ ε)`` and its log-density ``log π(a|s)``, ``(...,)``.

        ``log π(a|s) = log N(u; μ, σ) - Σ log(1 - tanh(u)²)`` (the tanh change of variables).
        """
        mean, log_std = self.distribution(obs)
        eps = torch.randn(mean.shape, generator=generator, device=mean.device, dtype=mean.dtype)
        u = mean + log_std.exp() * eps
        return torch.tanh(u), gaussian_log_prob(u, mean, log_std) - tanh_log_det_jacobian(u)

    def to_actor(self) -> Actor:
        """A detached :class:`Actor` computing :meth:`forward` (for policy files)."""
        actor = Actor(self.obs_dim, self.act_dim, self.hidden).to(next(self.parameters()).device)
        actor.net.load_state_dict(self.net.state_dict())
        return actor


def gaussian_log_prob(u: torch.Tensor, mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """Log-density of a diagonal Gaussian at ``u``, summed over the last axis."""
    z = (u - mean) * torch.exp(-log_std)
    return (-0.5 * z.square() - log_std - 0.5 * math.log(2.0 * math.pi)).sum(-1)


def gaussian_entropy(log_std: torch.Tensor) -> torch.Tensor:
    """Entropy of a diagonal Gaussian, summed over the last axis."""
    return (log_std + 0.5 * (1.0 + math.log(2.0 * math.pi))).sum(-1)


class ValueFunction(nn.Module):
    """State-value function V(s) (PPO's critic); :meth:`forward` returns shape ``(batch,)``."""

    def __init__(self, obs_dim: int, hidden: tuple[int, ...] = (64, 64)) -> None:
        super().__init__()
        hidden = tuple(hidden)
        _check_sizes(obs_dim, 1, hidden)
        self.obs_dim = obs_dim
        self.net = mlp(obs_dim, hidden, 1)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Values ``(...,)`` of ``(..., obs_dim)`` observations."""
        return self.net(obs).squeeze(-1)


class ActorPolicy:
    """A trained (or training) actor as a plain numpy callable: ``action = policy(obs)``.

    Holds a *reference* to the actor (no copy), so a policy built from a learner's actor
    follows its training. Runs under ``torch.inference_mode()``. With an observation
    normaliser, observations are normalised by it first; the policy never updates it
    (frozen at evaluation).

    Args:
        actor: The actor network (an :class:`Actor`, or a :class:`GaussianActor`, acting by
            its mean); its device is taken from its parameters.
        obs_norm: Optional running observation normaliser, applied before the actor.
    """

    def __init__(self, actor: Actor, obs_norm: ObsNormalizer | None = None) -> None:
        self.actor = actor
        self.obs_norm = obs_norm
        self._weight = next(actor.parameters())
        """A parameter of the actor, whose device is the actor's (``Module.to`` keeps the parameter objects);
        looking one up per call walked every submodule."""

    @property
    def obs_dim(self) -> int:
        """Observation size the actor expects."""
        return self.actor.obs_dim

    @property
    def act_dim(self) -> int:
        """Size of the returned actions."""
        return self.actor.act_dim

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Normalized actions (float32): ``(act_dim,)`` for 1-D obs, ``(n, act_dim)`` for 2-D."""
        obs = np.asarray(obs, dtype=np.float32)
        if obs.ndim not in (1, 2) or obs.shape[-1] != self.obs_dim:
            raise ValueError(
                f"obs must have shape ({self.obs_dim},) or (n, {self.obs_dim}), got {obs.shape}"
            )
        device = self._weight.device
        with torch.inference_mode():
            x = torch.as_tensor(obs, device=device)
            if self.obs_norm is not None:
                x = self.obs_norm(x)
            action = self.actor(x)
        return action.cpu().numpy().astype(np.float32, copy=False)
