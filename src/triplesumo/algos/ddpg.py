"""Deep Deterministic Policy Gradient (Lillicrap et al., 2015) as a library.

The learner owns the actor μ, the critic Q, their target copies μ', Q' and two Adam
optimisers. It does not collect data: the training loop acts with :meth:`DDPG.act` (adding
exploration noise itself), stores transitions in a
:class:`~triplesumo.algos.replay.ReplayBuffer`, and calls :meth:`DDPG.update` with sampled
batches on the schedule of :meth:`DDPGConfig.is_update_step`.

One update is, in order::

    y      = r + γ (1 - done) · Q'(s', μ'(s'))        # TARGET critic at the TARGET actor's action
    L_Q    = mean (Q(s, a) - y)²                       # critic step
    L_μ    = -mean Q(s, μ(s))                          # actor step (critic held fixed)
    θ'     <- τ θ + (1 - τ) θ'                         # soft update of both targets

Checkpoints are safetensors + JSON, never pickle: :meth:`DDPG.state_dict` and
:meth:`DDPG.optimizer_state` give flat tensor dicts (plus a JSON-able dict of optimiser
hyper-parameters), and loading both into a fresh learner continues the run bit-for-bit on CPU.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from triplesumo.agents.networks import Actor, ActorPolicy, Critic
from triplesumo.algos.noise import NOISE_KINDS

_MODULES = ("actor", "critic", "actor_target", "critic_target")
_OPTIMIZERS = ("actor_optimizer", "critic_optimizer")


@dataclass(frozen=True)
class DDPGConfig:
    """DDPG hyper-parameters; defaults are the paper's (Table 2) and its original code's.

    Table 2 gives the learning rates, γ, τ, batch size, buffer size and the update stride 30;
    the original code gives the hidden sizes (512, 256) and the OU noise (θ 0.15, σ 0.2).

    The update schedule is explicit: once ``learning_starts`` transitions of random warm-up
    have been collected, the learner does ``G = gradient_steps`` gradient steps every
    ``K = learn_every`` collected transitions (see :meth:`is_update_step`). The paper's
    original code had the stride condition inverted and learned on 29 of every 30 steps;
    we learn on 1 of every ``K``.
    """

    actor_lr: float = 1e-4
    """Adam learning rate of the actor (paper Table 2)."""
    critic_lr: float = 1e-3
    """Adam learning rate of the critic (paper Table 2)."""
    gamma: float = 0.99
    """Discount factor γ, in (0, 1] (paper Table 2)."""
    tau: float = 0.01
    """Soft target update factor τ, in (0, 1]: θ' <- τθ + (1-τ)θ' (paper Table 2)."""
    batch_size: int = 64
    """Transitions per gradient step (paper Table 2)."""
    buffer_size: int = 1_000_000
    """Replay buffer capacity in transitions (paper Table 2)."""
    hidden: tuple[int, ...] = (512, 256)
    """Hidden layer widths of actor and critic (paper's original code)."""
    noise: str = "ou"
    """Exploration noise kind: "ou" (paper's original code), "gaussian" or "none"."""
    noise_sigma: float = 0.2
    """σ of the exploration noise, in normalized action units (paper's original code)."""
    noise_theta: float = 0.15
    """θ of the OU noise (paper's original code); ignored by other kinds."""
    learn_every: int = 30
    """Update stride K: gradient updates happen once every K collected transitions (Table 2)."""
    gradient_steps: int = 1
    """G: gradient steps done each time an update happens."""
    learning_starts: int = 1000
    """Transitions of random warm-up collected before the first update."""
    weight_decay: float = 0.0
    """L2 weight decay of the critic's Adam (Lillicrap et al. used 1e-2; the paper none)."""

    def __post_init__(self) -> None:
        if isinstance(self.hidden, list):  # e.g. loaded back from JSON
            object.__setattr__(self, "hidden", tuple(self.hidden))
        for name in ("actor_lr", "critic_lr"):
            _require(name, _real(self, name) > 0, "must be > 0")
        _require("gamma", 0 < _real(self, "gamma") <= 1, "must be in (0, 1]")
        _require("tau", 0 < _real(self, "tau") <= 1, "must be in (0, 1]")
        for name in ("batch_size", "buffer_size", "learn_every", "gradient_steps"):
            _require(name, _int(self, name) >= 1, "must be >= 1")
        _require("learning_starts", _int(self, "learning_starts") >= 0, "must be >= 0")
        _require(
            "hidden",
            isinstance(self.hidden, tuple)
            and len(self.hidden) > 0
            and all(isinstance(h, int) and not isinstance(h, bool) and h >= 1 for h in self.hidden),
            f"must be a non-empty tuple of ints >= 1, got {self.hidden!r}",
        )
        _require(
            "noise", self.noise in NOISE_KINDS, f"must be one of {NOISE_KINDS}, got {self.noise!r}"
        )
        _require("noise_sigma", _real(self, "noise_sigma") >= 0, "must be >= 0")
        _require("noise_theta", _real(self, "noise_theta") > 0, "must be > 0")
        _require("weight_decay", _real(self, "weight_decay") >= 0, "must be >= 0")

    def is_update_step(self, transitions_collected: int) -> bool:
        """Whether to run the ``gradient_steps`` updates after this many transitions in total.

        True once warm-up is over and ``transitions_collected`` is a multiple of
        ``learn_every`` (1 step in K, not the original code's K-1 in K).
        """
        return (
            transitions_collected >= self.learning_starts
            and transitions_collected > 0
            and transitions_collected % self.learn_every == 0
        )


def _require(name: str, ok: bool, message: str) -> None:
    if not ok:
        raise ValueError(f"DDPGConfig.{name} {message}")


def _real(config: DDPGConfig, name: str) -> float:
    """The field as a float; ``ValueError`` unless it is a finite real number."""
    value = getattr(config, name)
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
    _require(name, ok, f"must be a finite real number, got {value!r}")
    return float(value)


def _int(config: DDPGConfig, name: str) -> int:
    """The field; ``ValueError`` unless it is an int (bools are rejected)."""
    value = getattr(config, name)
    _require(
        name,
        isinstance(value, int) and not isinstance(value, bool),
        f"must be an int, got {value!r}",
    )
    return int(value)


class DDPG:
    """DDPG learner for one agent: networks, targets, optimisers and the update rule.

    Args:
        obs_dim: Size of the agent's (flat) observation.
        act_dim: Size of its normalized action (in [-1, 1]).
        config: Hyper-parameters.
        seed: Seeds the network initialisation (the global torch RNG is left untouched).
        device: Torch device of all networks.
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        config: DDPGConfig,
        seed: int,
        device: str | torch.device = "cpu",
    ) -> None:
        self.obs_dim = obs_dim
        self.act_dim = act_dim
        self.config = config
        self.device = torch.device(device)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            actor = Actor(obs_dim, act_dim, config.hidden)
            critic = Critic(obs_dim, act_dim, config.hidden)
        self.actor = actor.to(self.device)
        self.critic = critic.to(self.device)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr)
        self.critic_optimizer = torch.optim.Adam(
            self.critic.parameters(), lr=config.critic_lr, weight_decay=config.weight_decay
        )
        self.policy = ActorPolicy(self.actor)
        """Numpy policy following the online actor (deterministic, no noise)."""
        self.num_updates = 0
        """Gradient updates done so far (each = critic step + actor step + soft update)."""

    # ----------------------------------------------------------------------------- acting

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic action μ(s) in [-1, 1] (float32); the caller adds exploration noise."""
        return self.policy(obs)

    # ---------------------------------------------------------------------------- learning

    def _batch(self, batch: Mapping[str, np.ndarray | torch.Tensor]) -> dict[str, torch.Tensor]:
        """Batch as float32 tensors on the device; ``rew`` and ``done`` flattened to ``(B,)``."""
        out = {}
        for key in ("obs", "act", "rew", "next_obs", "done"):
            if key not in batch:
                raise KeyError(f"batch is missing {key!r}")
            out[key] = torch.as_tensor(batch[key], dtype=torch.float32, device=self.device)
        n = out["obs"].shape[0]
        for key in ("rew", "done"):
            out[key] = out[key].reshape(-1)
            if out[key].shape != (n,):
                raise ValueError(f"batch[{key!r}] must have {n} entries, got {out[key].shape}")
        return out

    def td_target(self, batch: Mapping[str, np.ndarray | torch.Tensor]) -> torch.Tensor:
        """Critic regression target ``y = r + γ (1 - done) Q'(s', μ'(s'))``, shape ``(B,)``.

        Uses the TARGET actor μ' and the TARGET critic Q' (Lillicrap et al., 2015), without
        gradients. ``done = 1`` (a real win/loss terminal) removes the bootstrap term.
        """
        b = self._batch(batch)
        with torch.no_grad():
            next_action = self.actor_target(b["next_obs"])  # μ'(s'): TARGET actor
            next_q = self.critic_target(b["next_obs"], next_action)  # Q'(s', μ'(s')): TARGET critic
            return b["rew"] + self.config.gamma * (1.0 - b["done"]) * next_q

    def update_critic(self, batch: Mapping[str, np.ndarray | torch.Tensor]) -> dict[str, float]:
        """One Adam critic step on ``mean (Q(s, a) - y)²``, with ``y`` from :meth:`td_target`.

        Returns ``critic_loss`` and ``q_mean`` (mean Q(s, a)), both before the step.
        """
        b = self._batch(batch)
        y = self.td_target(b)
        q = self.critic(b["obs"], b["act"])
        loss = F.mse_loss(q, y)
        self.critic_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.critic_optimizer.step()
        return {"critic_loss": loss.item(), "q_mean": q.detach().mean().item()}

    def update_actor(self, batch: Mapping[str, np.ndarray | torch.Tensor]) -> dict[str, float]:
        """One Adam step on the actor: minimise ``-mean Q(s, μ(s))``; the critic is not changed.

        Returns ``actor_loss`` before the step.
        """
        obs = self._batch(batch)["obs"]
        self.critic.requires_grad_(False)  # no critic weight gradients: the critic is fixed here
        try:
            loss = -self.critic(obs, self.actor(obs)).mean()
            self.actor_optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.actor_optimizer.step()
        finally:
            self.critic.requires_grad_(True)
        return {"actor_loss": loss.item()}

    def soft_update_targets(self) -> None:
        """Polyak-average both targets toward the online nets: θ' <- τθ + (1 - τ)θ'."""
        tau = self.config.tau
        with torch.no_grad():
            for online, target in (
                (self.actor, self.actor_target),
                (self.critic, self.critic_target),
            ):
                for p, p_targ in zip(online.parameters(), target.parameters(), strict=True):
                    p_targ.lerp_(p, tau)

    def update(self, batch: Mapping[str, np.ndarray | torch.Tensor]) -> dict[str, float]:
        """One gradient update: critic step, actor step (on the updated critic), soft update.

        Returns ``{"critic_loss", "actor_loss", "q_mean"}`` (losses before their steps).
        """
        b = self._batch(batch)
        info = self.update_critic(b)
        info |= self.update_actor(b)
        self.soft_update_targets()
        self.num_updates += 1
        return info

    # ------------------------------------------------------------------------ checkpoints

    def state_dict(self) -> dict[str, torch.Tensor]:
        """All network weights as one flat dict for ``safetensors.torch.save_file``.

        Keys are prefixed ``actor.``, ``critic.``, ``actor_target.``, ``critic_target.``;
        tensors are contiguous copies on the learner's device (no aliasing of live weights).
        """
        out: dict[str, torch.Tensor] = {}
        for name in _MODULES:
            module: torch.nn.Module = getattr(self, name)
            for key, value in module.state_dict().items():
                out[f"{name}.{key}"] = value.detach().clone().contiguous()
        return out

    def load_state_dict(self, tensors: Mapping[str, torch.Tensor]) -> None:
        """Load weights saved by :meth:`state_dict`.

        Raises:
            KeyError: A key is missing or unexpected (the message names it).
            ValueError: A tensor's shape does not match (the message names the key).
        """
        expected = {k: v.shape for k, v in self.state_dict().items()}
        missing = sorted(set(expected) - set(tensors))
        if missing:
            raise KeyError(f"DDPG state is missing key {missing[0]!r} ({len(missing)} missing)")
        unexpected = sorted(set(tensors) - set(expected))
        if unexpected:
            raise KeyError(
                f"DDPG state has unexpected key {unexpected[0]!r} ({len(unexpected)} unexpected)"
            )
        for key, shape in expected.items():
            if tuple(tensors[key].shape) != tuple(shape):
                raise ValueError(
                    f"DDPG state key {key!r}: shape {tuple(tensors[key].shape)}, "
                    f"expected {tuple(shape)}"
                )
        for name in _MODULES:
            module: torch.nn.Module = getattr(self, name)
            prefix = f"{name}."
            module.load_state_dict(
                {k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)}
            )

    def optimizer_state(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Adam states as ``(tensors, meta)``: safetensors-ready tensors + JSON-able metadata.

        Tensor keys are ``{actor,critic}_optimizer.state.<param index>.<exp_avg|exp_avg_sq|step>``;
        ``meta`` holds each optimiser's ``param_groups`` (lr, betas, ...) and ``num_updates``.
        """
        tensors: dict[str, torch.Tensor] = {}
        meta: dict[str, Any] = {"num_updates": self.num_updates}
        for name in _OPTIMIZERS:
            sd = getattr(self, name).state_dict()
            for index, param_state in sd["state"].items():
                for key, value in param_state.items():
                    tensors[f"{name}.state.{index}.{key}"] = value.detach().clone().contiguous()
            meta[name] = {"param_groups": _jsonable(sd["param_groups"])}
        return tensors, meta

    def load_optimizer_state(
        self, tensors: Mapping[str, torch.Tensor], meta: Mapping[str, Any]
    ) -> None:
        """Restore :meth:`optimizer_state` output (and ``num_updates``).

        Raises:
            KeyError: ``meta`` lacks an entry, or a tensor key is malformed or unexpected.
            ValueError: A state tensor's shape does not match its parameter.
        """
        for name in ("num_updates", *_OPTIMIZERS):
            if name not in meta:
                raise KeyError(f"optimizer meta is missing {name!r}")
        loaded: dict[str, dict[str, Any]] = {}
        for name in _OPTIMIZERS:
            optimizer: torch.optim.Optimizer = getattr(self, name)
            params = [p for group in optimizer.param_groups for p in group["params"]]
            state: dict[int, dict[str, torch.Tensor]] = {}
            prefix = f"{name}.state."
            for key, value in tensors.items():
                if not key.startswith(prefix):
                    continue
                index_str, _, field = key.removeprefix(prefix).partition(".")
                if not index_str.isdigit() or not field or int(index_str) >= len(params):
                    raise KeyError(f"unexpected optimizer state key {key!r}")
                index = int(index_str)
                if field in ("exp_avg", "exp_avg_sq") and value.shape != params[index].shape:
                    raise ValueError(
                        f"optimizer state key {key!r}: shape {tuple(value.shape)}, "
                        f"expected {tuple(params[index].shape)}"
                    )
                state.setdefault(index, {})[field] = value.clone()
            groups = copy.deepcopy(list(meta[name]["param_groups"]))
            for group in groups:
                if "betas" in group:
                    group["betas"] = tuple(group["betas"])
            loaded[name] = {"state": state, "param_groups": groups}
        stray = [k for k in tensors if not k.startswith(tuple(f"{n}.state." for n in _OPTIMIZERS))]
        if stray:
            raise KeyError(f"unexpected optimizer state key {stray[0]!r}")
        for name in _OPTIMIZERS:
            getattr(self, name).load_state_dict(loaded[name])
        self.num_updates = int(meta["num_updates"])


def _jsonable(value: Any) -> Any:
    """Tuples to lists, recursively, so ``json.dumps`` round-trips the value."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, torch.Tensor):
        return value.item()
    return value
