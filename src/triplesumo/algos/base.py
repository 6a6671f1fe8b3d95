"""What every learner shares: seeded networks, observation normalisation, acting,
checkpoint state, finite checks and policy export.

A learner names its networks in :attr:`Algorithm.modules` and its optimisers in
:attr:`Algorithm.optimizers`; from those two tuples this class gives

- :meth:`state_dict` / :meth:`load_state_dict`: every module's tensors, flat and prefixed
  (``actor.net.0.weight``, ``critic_target.net.2.bias``, ``obs_norm.mean``), for
  ``safetensors.torch.save_file``;
- :meth:`optimizer_state` / :meth:`load_optimizer_state`: Adam moments as tensors plus
  JSON-able ``param_groups``, ``num_updates`` and the learner's own torch generator (the
  noise of TD3's smoothing, SAC's sampling and PPO's minibatches), so that loading both into a
  fresh learner continues the run bit for bit on CPU;
- :meth:`check_finite`: raises :class:`DivergenceError` naming the update and the tensor;
- :meth:`act`: the deterministic policy on numpy observations (normaliser frozen);
- :meth:`export_actor`: that policy as a plain :class:`~triplesumo.agents.networks.Actor`
  for :func:`~triplesumo.agents.policy_file.save_policy` (with :attr:`obs_norm`).

Nothing here pickles: checkpoints are safetensors + JSON.
"""

from __future__ import annotations

import copy
import math
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np
import torch
from torch import nn

from triplesumo.agents.networks import Actor, ActorPolicy, GaussianActor
from triplesumo.agents.normalizer import ObsNormalizer

M = TypeVar("M", bound=nn.Module)


class DivergenceError(FloatingPointError):
    """A learner's losses, parameters or actions are no longer finite: the message says what (the update and
    the tensor), ``learner`` names the learner where one is known (the trainer adds its update count, where the
    run stood and its last good checkpoint)."""

    def __init__(self, message: str, learner: str | None = None) -> None:
        super().__init__(message)
        self.learner = learner


def __getattr__(name: str) -> Any:
    if name == "DivergedError":  # the name of DivergenceError until both were one
        warnings.warn("triplesumo.algos.base.DivergedError is deprecated: use DivergenceError",
                      DeprecationWarning, stacklevel=2)
        return DivergenceError
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class Algorithm:
    """Base of every learner. Subclasses build their networks in :meth:`build`.

    Args:
        obs_dim: Size of the agent's (flat) observation.
        act_dim: Size of its normalized action (in [-1, 1]).
        config: The algorithm's frozen config (needs ``hidden`` and ``normalize_obs``).
        seed: Seeds the network initialisation and the learner's torch generator (the global
            torch RNG is left untouched).
        device: Torch device of all networks.
    """

    modules: tuple[str, ...] = ()
    """Attribute names of the ``nn.Module`` s saved by :meth:`state_dict` (in this order)."""
    optimizers: tuple[str, ...] = ()
    """Attribute names of the optimisers saved by :meth:`optimizer_state`."""
    uses_generator = False
    """Whether updates draw random numbers (then the generator is part of the checkpoint)."""

    actor: Actor
    acting: Actor

    def __init__(self, obs_dim: int, act_dim: int, config: Any, seed: int,
                 device: str | torch.device = "cpu") -> None:
        self.obs_dim = obs_dim
        self.act_dim = act_dim
        self.config = config
        self.seed = seed
        """The seed the networks were built under (and the generator's, plus 1)."""
        self.device = torch.device(device)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            self.build()
        for name in self.modules:
            getattr(self, name).to(self.device)
        self.obs_norm: ObsNormalizer | None = None
        """Running observation normaliser (``config.normalize_obs``); updated by :meth:`observe` only."""
        if config.normalize_obs:
            self.obs_norm = ObsNormalizer(obs_dim).to(self.device)
            self.modules = (*self.modules, "obs_norm")
        self.generator: torch.Generator | None = None
        if self.uses_generator:
            self.generator = torch.Generator(device=self.device)
            self.generator.manual_seed(seed + 1)
        self.build_optimizers()
        self.policy = ActorPolicy(self.actor, self.obs_norm)
        """Numpy policy following the online actor (deterministic, no noise, normaliser frozen)."""
        self.acting = self.actor
        """The actor that collects (exploration acts with it): the online actor itself, or after
        :meth:`act_apart` a copy of it that :meth:`sync_acting` refreshes."""
        self.acting_policy = self.policy
        """:attr:`policy` of :attr:`acting`."""
        self._acting_pairs: list[tuple[torch.Tensor, torch.Tensor]] = []
        self._acting_at: int | None = None
        """:attr:`num_updates` when :attr:`acting` last took the actor's weights (None: not since a load)."""
        self.num_updates = 0
        """Gradient updates done so far."""

    # --------------------------------------------------------------- what subclasses state

    def build(self) -> None:
        """Create the networks named in :attr:`modules` (under the learner's seed)."""
        raise NotImplementedError

    def build_optimizers(self) -> None:
        """Create the optimisers named in :attr:`optimizers`."""
        raise NotImplementedError

    # ------------------------------------------------------------------------ helpers

    def target_copy(self, module: M) -> M:
        """A frozen deep copy of ``module`` (a target network)."""
        return copy.deepcopy(module).requires_grad_(False)

    def normalize(self, obs: torch.Tensor) -> torch.Tensor:
        """``obs`` through the normaliser, or unchanged without one."""
        return obs if self.obs_norm is None else self.obs_norm(obs)

    def tensor(self, value: np.ndarray | torch.Tensor) -> torch.Tensor:
        """A float32 tensor on the learner's device."""
        return torch.as_tensor(value, dtype=torch.float32, device=self.device)

    def finish_update(self, stats: dict[str, float]) -> dict[str, float]:
        """Count the update and check its stats; ``DivergenceError`` names the update and the stat."""
        index = self.num_updates
        self.num_updates += 1
        for key, value in stats.items():
            if not math.isfinite(value):
                raise DivergenceError(f"{type(self).__name__} update {index}: {key} is {value}")
        return stats

    # ------------------------------------------------------------------------- acting

    def observe(self, obs: np.ndarray) -> None:
        """Merge raw observations ``(n, obs_dim)`` the learner has just seen into its normaliser.

        A no-op without normalisation. Call it on collection steps only, never while an
        update runs (updates read the statistics).
        """
        if self.obs_norm is not None:
            self.obs_norm.update(obs)

    def act(self, obs: np.ndarray | torch.Tensor) -> Any:
        """Deterministic action in [-1, 1] (float32), as a policy file would give it: numpy for
        numpy observations, a tensor on the learner's device for a tensor (a device-resident
        collection, ``train --backend warp``)."""
        if isinstance(obs, torch.Tensor):
            with torch.inference_mode():
                return self.actor(self.normalize(self.tensor(obs)))
        return self.policy(obs)

    def act_apart(self) -> None:
        """Collect with a copy of the actor from now on (:attr:`acting`), which takes the actor's weights at each
        :meth:`sync_acting`: updates may then change the actor while the copy acts (the trainer runs them in a
        thread beside acting). Same weights, same forward pass: the actions are bit for bit the actor's."""
        if self.acting is not self.actor:
            return
        self.acting = copy.deepcopy(self.actor).requires_grad_(False)
        self.acting_policy = ActorPolicy(self.acting, self.obs_norm)
        self._acting_pairs = list(zip([*self.acting.parameters(), *self.acting.buffers()],
                                      [*self.actor.parameters(), *self.actor.buffers()], strict=True))

    def sync_acting(self) -> None:
        """:attr:`acting` takes the actor's current weights if an update or a load may have changed them since it
        last did (a no-op without :meth:`act_apart`). Call it while no update runs."""
        if self._acting_pairs and self._acting_at != self.num_updates:
            with torch.no_grad():
                torch._foreach_copy_([a for a, _ in self._acting_pairs], [b for _, b in self._acting_pairs])
            self._acting_at = self.num_updates

    def export_actor(self) -> Actor:
        """The deterministic policy as a plain :class:`Actor` (a copy), for policy files."""
        if isinstance(self.actor, GaussianActor):
            return self.actor.to_actor()  # drop the log σ
        return copy.deepcopy(self.actor)

    # --------------------------------------------------------------------- checkpoints

    def state_dict(self) -> dict[str, torch.Tensor]:
        """All module tensors as one flat dict for ``safetensors.torch.save_file``.

        Keys are prefixed with the module's name (:attr:`modules`); tensors are contiguous
        copies on the learner's device (no aliasing of live weights).
        """
        out: dict[str, torch.Tensor] = {}
        for name in self.modules:
            module: nn.Module = getattr(self, name)
            for key, value in module.state_dict().items():
                out[f"{name}.{key}"] = value.detach().clone().contiguous()
        return out

    def load_state_dict(self, tensors: Mapping[str, torch.Tensor]) -> None:
        """Load weights saved by :meth:`state_dict`.

        Raises:
            KeyError: A key is missing or unexpected (the message names it).
            ValueError: A tensor's shape does not match (the message names the key).
        """
        label = type(self).__name__
        expected = {k: v.shape for k, v in self.state_dict().items()}
        missing = sorted(set(expected) - set(tensors))
        if missing:
            raise KeyError(f"{label} state is missing key {missing[0]!r} ({len(missing)} missing)")
        unexpected = sorted(set(tensors) - set(expected))
        if unexpected:
            raise KeyError(
                f"{label} state has unexpected key {unexpected[0]!r} ({len(unexpected)} unexpected)"
            )
        for key, shape in expected.items():
            if tuple(tensors[key].shape) != tuple(shape):
                raise ValueError(
                    f"{label} state key {key!r}: shape {tuple(tensors[key].shape)}, "
                    f"expected {tuple(shape)}"
                )
        self._acting_at = None  # (the actor's weights change here)
        for name in self.modules:
            module: nn.Module = getattr(self, name)
            prefix = f"{name}."
            module.load_state_dict(
                {k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)}
            )

    def optimizer_state(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Training state beside the weights as ``(tensors, meta)`` (safetensors + JSON).

        Tensor keys are ``<optimizer>.state.<param index>.<exp_avg|exp_avg_sq|step>`` and,
        for learners that draw random numbers in updates, ``generator.state``; ``meta`` holds
        each optimiser's ``param_groups`` (lr, betas, ...; on loading, :data:`CONFIG_KEYS` come from the
        learner's config), ``num_updates`` and the learner's ``seed`` (a reset draws from it).
        """
        tensors: dict[str, torch.Tensor] = {}
        meta: dict[str, Any] = {"num_updates": self.num_updates, "seed": self.seed}
        for name in self.optimizers:
            sd = getattr(self, name).state_dict()
            for index, param_state in sd["state"].items():
                for key, value in param_state.items():
                    tensors[f"{name}.state.{index}.{key}"] = value.detach().clone().contiguous()
            meta[name] = {"param_groups": _jsonable(sd["param_groups"])}
        if self.generator is not None:
            tensors["generator.state"] = self.generator.get_state().clone()
        return tensors, meta

    def load_optimizer_state(
        self, tensors: Mapping[str, torch.Tensor], meta: Mapping[str, Any]
    ) -> None:
        """Restore :meth:`optimizer_state` output (and ``num_updates``).

        Raises:
            KeyError: ``meta`` lacks an entry, or a tensor key is malformed, missing or unexpected.
            ValueError: A state tensor's shape does not match its parameter.
        """
        for name in ("num_updates", *self.optimizers):
            if name not in meta:
                raise KeyError(f"optimizer meta is missing {name!r}")
        if self.generator is not None and "generator.state" not in tensors:
            raise KeyError("optimizer state is missing 'generator.state'")
        loaded: dict[str, dict[str, Any]] = {}
        for name in self.optimizers:
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
            # strict=False: a group count that differs is torch's load_state_dict to refuse, with its own message
            for group, live in zip(groups, optimizer.param_groups, strict=False):
                if "betas" in group:
                    group["betas"] = tuple(group["betas"])
                for key in IMPLEMENTATION_FLAGS:  # how the step runs, not state: keep this learner's
                    if key in optimizer.defaults:
                        group[key] = optimizer.defaults[key]
                for key in CONFIG_KEYS:  # the config's step sizes, not state: keep this learner's
                    if key in live:
                        group[key] = live[key]
            loaded[name] = {"state": state, "param_groups": groups}
        known = (*(f"{n}.state." for n in self.optimizers), "generator.state")
        stray = [k for k in tensors if not k.startswith(known)
                 or (k == "generator.state" and self.generator is None)]
        if stray:
            raise KeyError(f"unexpected optimizer state key {stray[0]!r}")
        for name in self.optimizers:
            getattr(self, name).load_state_dict(loaded[name])
        if self.generator is not None:
            self.generator.set_state(tensors["generator.state"].to(torch.uint8).cpu())
        self.num_updates = int(meta["num_updates"])
        self.seed = int(meta.get("seed", self.seed))  # (a checkpoint from before resets kept no seed)

    def check_finite(self) -> None:
        """Raise :class:`DivergenceError` if any weight or statistic is NaN or infinite."""
        bad = not_finite([(f"{name}.{key}", value) for name in self.modules
                          for key, value in getattr(self, name).state_dict().items()])
        if bad:
            raise DivergenceError(f"{type(self).__name__} after {self.num_updates} updates: {bad[0]} is not finite")


def not_finite(named: Sequence[tuple[str, torch.Tensor]]) -> list[str]:
    """Names of the tensors in ``named`` holding a NaN or an infinity (empty when all are finite).

    One reduction per tensor and one check for the common all-finite case (a NaN or an
    infinity anywhere makes a tensor's sum non-finite), several times cheaper than an
    ``isfinite`` mask per tensor (and than ``max |x|``, which copies each tensor for ``abs``);
    the tensors are looked at element by element only to name the bad ones (and when a sum
    of finite values overflows, which then names none).
    """
    floats = [t.detach() for _, t in named if t.is_floating_point()]  # integers are always finite
    if not floats or bool(torch.isfinite(torch.stack([t.sum() for t in floats])).all()):
        return []
    return [name for name, t in named if t.is_floating_point() and not bool(torch.isfinite(t).all())]


def _jsonable(value: Any) -> Any:
    """Tuples to lists, recursively, so ``json.dumps`` round-trips the value."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, torch.Tensor):
        return value.item()
    return value


@contextmanager
def frozen(*modules: nn.Module) -> Iterator[None]:
    """Within the block, ``modules`` get no weight gradients (a critic held fixed for the actor step)."""
    for module in modules:
        module.requires_grad_(False)
    try:
        yield
    finally:
        for module in modules:
            module.requires_grad_(True)


def descend(optimizer: torch.optim.Optimizer, loss: torch.Tensor, max_grad_norm: float | None = None) -> None:
    """One optimiser step on ``loss``: zero the gradients, backpropagate, (clip,) step.

    The gradient-norm clip runs as one multi-tensor (``foreach``) call, bit for bit the
    per-tensor one.
    """
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if max_grad_norm is not None:
        params = [p for group in optimizer.param_groups for p in group["params"]]
        torch.nn.utils.clip_grad_norm_(params, max_grad_norm, foreach=True)
    optimizer.step()


IMPLEMENTATION_FLAGS = ("foreach", "fused")
"""Adam options that choose how a step runs, not what it computes; a loaded checkpoint keeps the live ones."""
CONFIG_KEYS = ("lr", "weight_decay")
"""Adam options the learner's config sets (``actor_lr``, ``weight_decay``, ...); a loaded checkpoint keeps the
live ones, so that a run forked with another learning rate (``TUNABLE``) steps with it. Resuming with the
same config, they are the saved ones."""


def adam(params: Any, lr: float, weight_decay: float = 0.0, eps: float = 1e-8) -> torch.optim.Adam:
    """The Adam optimiser every learner uses.

    ``foreach=True``: each step is a handful of multi-tensor kernels instead of a Python loop
    over the parameters, with bit-for-bit the same result on CPU (``fused=True`` would be
    faster still but rounds differently in the last bits, so it is not used).
    """
    return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay, eps=eps, foreach=True)
