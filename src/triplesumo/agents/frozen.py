"""A trained actor frozen into numpy: the fixed policy that drives opponents.

:class:`FrozenPolicy` computes the actor of :mod:`triplesumo.agents.networks` (linear
layers with leaky ReLU, ``tanh`` at the end) with numpy in float64 and returns float32
actions. Why not torch for a policy that never learns:

- **Fork-safe.** A process that forks after torch ran its thread pool leaves the child
  stuck in the next torch call (``load_state_dict`` of the zoo policies hung the workers
  of ``gym.make_vec(..., vectorization_mode="async")`` and SB3's
  ``SubprocVecEnv(start_method="fork")``). Loading and acting here touch no torch.
- **Cheap for one observation.** No torch dispatch: a zoo policy on one observation costs
  about 47 us against 74 us for the torch actor under ``inference_mode`` (2-core box, one
  thread each). A batch of 16 costs more (about 315 us against 183 us: float64 GEMM),
  still small beside the 16 matches' physics step it drives.
- **Independent of the batch size in practice.** float32 GEMM and GEMV sum in different
  orders and give last-bit differences between an observation alone and inside a batch;
  float64 sums differ by about 1e-16 before the cast to float32, which moves a float32
  action only when it falls that close to a rounding boundary (none in 2,000 random
  observations). So a batched env and single ones play the same game.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

LEAKY_SLOPE = 0.01
"""Negative slope of ``torch.nn.LeakyReLU``'s default, as the actor uses."""


class FrozenPolicy:
    """``action = policy(obs)`` for ``(obs_dim,)`` or ``(n, obs_dim)`` observations, in numpy.

    Args:
        weights: ``(out, in)`` matrices of the linear layers, first to last.
        biases: ``(out,)`` vectors, one per layer.
    """

    def __init__(self, weights: list[np.ndarray], biases: list[np.ndarray]) -> None:
        if not weights or len(weights) != len(biases):
            raise ValueError(f"need as many biases as weight matrices (>= 1), got {len(weights)} and {len(biases)}")
        self._w = [np.ascontiguousarray(np.asarray(w, np.float64).T) for w in weights]
        self._b = [np.asarray(b, np.float64) for b in biases]
        for k, (w, b) in enumerate(zip(self._w, self._b, strict=True)):
            if w.ndim != 2 or b.shape != (w.shape[1],) or (k and w.shape[0] != self._w[k - 1].shape[1]):
                raise ValueError(f"layer {k}: weight {w.T.shape} and bias {b.shape} do not chain")
        self.obs_dim = int(self._w[0].shape[0])
        self.act_dim = int(self._w[-1].shape[1])

    @classmethod
    def from_tensors(cls, tensors: Mapping[str, np.ndarray], prefix: str = "actor.") -> FrozenPolicy:
        """From an actor's state dict as numpy arrays (``safetensors.numpy.load_file``), keys
        ``{prefix}net.{i}.weight`` / ``.bias``."""
        layers = sorted(int(k[len(prefix):].split(".")[1]) for k in tensors
                        if k.startswith(prefix + "net.") and k.endswith(".weight"))
        if not layers:
            raise KeyError(f"no actor weights with prefix {prefix!r} (expected '{prefix}net.0.weight')")
        return cls([tensors[f"{prefix}net.{i}.weight"] for i in layers],
                   [tensors[f"{prefix}net.{i}.bias"] for i in layers])

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Normalised actions (float32): ``(act_dim,)`` for 1-D obs, ``(n, act_dim)`` for 2-D."""
        x = np.asarray(obs, dtype=np.float32)
        if x.ndim not in (1, 2) or x.shape[-1] != self.obs_dim:
            raise ValueError(f"obs must have shape ({self.obs_dim},) or (n, {self.obs_dim}), got {x.shape}")
        # float32 observations, as the torch actor sees them, summed in float64 row by row.
        h = x.astype(np.float64)[None] if x.ndim == 1 else x.astype(np.float64)
        last = len(self._w) - 1
        for k, (w, b) in enumerate(zip(self._w, self._b, strict=True)):
            h = h @ w + b
            if k < last:
                h = np.maximum(h, LEAKY_SLOPE * h)
        action = np.tanh(h).astype(np.float32)
        return action[0] if x.ndim == 1 else action
