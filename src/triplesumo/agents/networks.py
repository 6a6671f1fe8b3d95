"""Actor and critic MLPs for DDPG, and :class:`ActorPolicy`, the numpy-facing policy.

Architecture follows the paper's original code: two hidden layers (512, 256) with leaky
ReLU; the actor ends in ``tanh`` so actions are *normalized* to [-1, 1] (the env scales them
to each agent's control range, read from the MJCF). The last layer of both networks is
initialised uniformly in ±3e-3, as in DDPG (Lillicrap et al., 2015, §7), so initial actions
and Q-values are near zero.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from torch import nn

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


def _mlp(in_dim: int, hidden: tuple[int, ...], out_dim: int) -> nn.Sequential:
    """Linear/LeakyReLU stack ending in a linear layer with a small uniform init."""
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, width), nn.LeakyReLU()]
        in_dim = width
    last = nn.Linear(in_dim, out_dim)
    nn.init.uniform_(last.weight, -FINAL_INIT, FINAL_INIT)
    nn.init.uniform_(last.bias, -FINAL_INIT, FINAL_INIT)
    layers.append(last)
    return nn.Sequential(*layers)


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
        self.net = _mlp(obs_dim, hidden, act_dim)

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
        self.net = _mlp(obs_dim + act_dim, hidden, 1)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Q-values ``(...,)`` for ``(..., obs_dim)`` obs and ``(..., act_dim)`` actions."""
        return self.net(torch.cat([obs, action], dim=-1)).squeeze(-1)


class ActorPolicy:
    """A trained (or training) actor as a plain numpy callable: ``action = policy(obs)``.

    Holds a *reference* to the actor (no copy), so a policy built from a learner's actor
    follows its training. Runs under ``torch.inference_mode()``.

    Args:
        actor: The actor network; its device is taken from its parameters.
    """

    def __init__(self, actor: Actor) -> None:
        self.actor = actor

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
        device = next(self.actor.parameters()).device
        with torch.inference_mode():
            action = self.actor(torch.as_tensor(obs, device=device))
        return action.cpu().numpy().astype(np.float32, copy=False)
