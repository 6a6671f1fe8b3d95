"""A trained actor frozen into numpy: the fixed policy that drives opponents.

:class:`FrozenPolicy` computes the actor of :mod:`triplesumo.agents.networks` (linear
layers with leaky ReLU, ``tanh`` at the end) with numpy in float64 and returns float32
actions. Why not torch for a policy that never learns:

- **Fork-safe.** A process that forks after torch ran its thread pool leaves the child
  stuck in the next torch call (``load_state_dict`` of the zoo policies hung the workers
  of ``gym.make_vec(..., vectorization_mode="async")`` and SB3's
  ``SubprocVecEnv(start_method="fork")``). Loading and acting here touch no torch.
- **Cheap for one observation.** No torch dispatch: a zoo policy on one observation costs
  less than the torch actor under ``inference_mode``. A batch costs more (float64 GEMM),
  still small beside the matches' physics step it drives (``docs/bench/index.md``).
- **Independent of the batch size in practice.** float32 GEMM and GEMV sum in different
  orders and give last-bit differences between an observation alone and inside a batch;
  float64 sums differ by about 1e-16 before the cast to float32, which moves a float32
  action only when it falls that close to a rounding boundary (none in 2,000 random
  observations). So a batched env and single ones play the same game.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

LEAKY_SLOPE = 0.01
"""Negative slope of ``torch.nn.LeakyReLU``'s default, as the actor uses."""
NORM_EPS = 1e-8
"""Added to the variance before the square root (as :class:`~triplesumo.agents.normalizer.ObsNormalizer`)."""
NORM_CLIP = 10.0
"""Normalised observations are clipped to ``[-NORM_CLIP, NORM_CLIP]`` (as the normaliser)."""


class FrozenPolicy:
    """``action = policy(obs)`` for ``(obs_dim,)`` or ``(n, obs_dim)`` observations, in numpy.

    Args:
        weights: ``(out, in)`` matrices of the linear layers, first to last.
        biases: ``(out,)`` vectors, one per layer.
        obs_mean: a frozen observation normaliser's mean (give ``obs_var`` too, or neither):
            observations become ``clip((obs - mean) / sqrt(var + eps))`` first.
        obs_var: that normaliser's variance.
    """

    def __init__(self, weights: list[np.ndarray], biases: list[np.ndarray],
                 obs_mean: np.ndarray | None = None, obs_var: np.ndarray | None = None) -> None:
        if not weights or len(weights) != len(biases):
            raise ValueError(f"need as many biases as weight matrices (>= 1), got {len(weights)} and {len(biases)}")
        self._w = [np.ascontiguousarray(np.asarray(w, np.float64).T) for w in weights]
        self._b = [np.asarray(b, np.float64) for b in biases]
        for k, (w, b) in enumerate(zip(self._w, self._b, strict=True)):
            if w.ndim != 2 or b.shape != (w.shape[1],) or (k and w.shape[0] != self._w[k - 1].shape[1]):
                raise ValueError(f"layer {k}: weight {w.T.shape} and bias {b.shape} do not chain")
        self.obs_dim = int(self._w[0].shape[0])
        self.act_dim = int(self._w[-1].shape[1])
        if (obs_mean is None) != (obs_var is None):
            raise ValueError("give both obs_mean and obs_var of the normaliser, or neither")
        self._norm: tuple[np.ndarray, np.ndarray] | None = None
        """(mean, std) of the frozen observation normaliser, if any."""
        if obs_mean is not None and obs_var is not None:
            mean, std = np.asarray(obs_mean, np.float64), np.sqrt(np.asarray(obs_var, np.float64) + NORM_EPS)
            if mean.shape != (self.obs_dim,) or std.shape != (self.obs_dim,):
                raise ValueError(f"normaliser statistics must have shape ({self.obs_dim},), "
                                 f"got {mean.shape} and {std.shape}")
            self._norm = (mean, std)

    @classmethod
    def from_tensors(cls, tensors: Mapping[str, np.ndarray], prefix: str = "actor.",
                     obs_norm_prefix: str | None = None) -> FrozenPolicy:
        """From an actor's state dict as numpy arrays (``safetensors.numpy.load_file``), keys
        ``{prefix}net.{i}.weight`` / ``.bias``; with ``obs_norm_prefix``, the normaliser's
        ``{obs_norm_prefix}mean`` / ``var`` too."""
        layers = sorted(int(k.removeprefix(prefix).split(".")[1]) for k in tensors
                        if k.startswith(prefix + "net.") and k.endswith(".weight"))
        if not layers:
            raise KeyError(f"no actor weights with prefix {prefix!r} (expected '{prefix}net.0.weight')")
        mean = var = None
        if obs_norm_prefix is not None:
            mean, var = tensors[f"{obs_norm_prefix}mean"], tensors[f"{obs_norm_prefix}var"]
        return cls([tensors[f"{prefix}net.{i}.weight"] for i in layers],
                   [tensors[f"{prefix}net.{i}.bias"] for i in layers], mean, var)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Normalised actions (float32): ``(act_dim,)`` for 1-D obs, ``(n, act_dim)`` for 2-D."""
        x = np.asarray(obs, dtype=np.float32)
        if x.ndim not in (1, 2) or x.shape[-1] != self.obs_dim:
            raise ValueError(f"obs must have shape ({self.obs_dim},) or (n, {self.obs_dim}), got {x.shape}")
        # float32 observations, as the torch actor sees them, summed in float64 row by row.
        h = x.astype(np.float64)[None] if x.ndim == 1 else x.astype(np.float64)
        if self._norm is not None:  # as ObsNormalizer.forward: float64, clipped, back to float32
            mean, std = self._norm
            h = np.clip((h - mean) / std, -NORM_CLIP, NORM_CLIP).astype(np.float32).astype(np.float64)
        last = len(self._w) - 1
        for k, (w, b) in enumerate(zip(self._w, self._b, strict=True)):
            h = h @ w + b
            if k < last:
                h = np.maximum(h, LEAKY_SLOPE * h)
        action = np.tanh(h).astype(np.float32)
        return action[0] if x.ndim == 1 else action

    def on_device(self, device: Any) -> Callable[[Any], Any]:
        """The same policy on torch tensors on ``device`` (``(n, obs_dim)`` in, float32 ``(n, act_dim)``
        out, computed in float64 as :meth:`__call__`), for a collection whose observations live on a
        GPU (``train --backend warp``). torch is imported here only: loading stays fork-safe."""
        import torch

        ws = [torch.as_tensor(w, device=device) for w in self._w]
        bs = [torch.as_tensor(b, device=device) for b in self._b]
        norm = None if self._norm is None else tuple(torch.as_tensor(a, device=device) for a in self._norm)
        last = len(ws) - 1

        def act(obs: Any) -> Any:
            h = obs.to(torch.float32).to(torch.float64)
            if norm is not None:
                h = ((h - norm[0]) / norm[1]).clamp(-NORM_CLIP, NORM_CLIP).to(torch.float32).to(torch.float64)
            for k, (w, b) in enumerate(zip(ws, bs, strict=True)):
                h = h @ w + b
                if k < last:
                    h = torch.maximum(h, LEAKY_SLOPE * h)
            return torch.tanh(h).to(torch.float32)

        return act
