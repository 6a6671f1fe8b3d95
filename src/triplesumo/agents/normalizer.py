"""Running observation normalisation: ``(obs - mean) / sqrt(var + eps)``, clipped.

One :class:`ObsNormalizer` per learning agent. Its statistics are float64 buffers of an
``nn.Module``, so they travel in the learner's ``state_dict`` (checkpoints) and in policy
files (``obs_norm.*`` tensors) without anything new. The statistics change only when
:meth:`ObsNormalizer.update` is called by a learner: a policy loaded for evaluation calls
only :meth:`forward`, so it is frozen there by construction.

The update is the parallel (Chan et al., 1979) form of Welford's algorithm, merging the
mean and variance of a whole batch at once; updating in chunks gives numpy's mean and
(population) variance over all rows seen, as SB3's ``RunningMeanStd`` does.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from torch import nn

from triplesumo.agents.frozen import NORM_CLIP, NORM_EPS

EPS = NORM_EPS
"""Added to the variance before the square root (as SB3's ``VecNormalize``)."""
CLIP = NORM_CLIP
"""Normalised observations are clipped to ``[-CLIP, CLIP]`` (SB3's and CleanRL's default)."""


class ObsNormalizer(nn.Module):
    """Running mean and variance of observations, and the normalisation they give.

    Args:
        obs_dim: Size of one (flat) observation.
        clip: Normalised values are clipped to ``[-clip, clip]``.
    """

    mean: torch.Tensor
    var: torch.Tensor
    count: torch.Tensor

    def __init__(self, obs_dim: int, clip: float = CLIP) -> None:
        super().__init__()
        if isinstance(obs_dim, bool) or not isinstance(obs_dim, int) or obs_dim < 1:
            raise ValueError(f"obs_dim must be an int >= 1, got {obs_dim!r}")
        if not (np.isfinite(clip) and clip > 0):
            raise ValueError(f"clip must be finite and > 0, got {clip!r}")
        self.obs_dim = obs_dim
        self.clip = float(clip)
        self.register_buffer("mean", torch.zeros(obs_dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(obs_dim, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))

    @torch.no_grad()
    def update(self, obs: np.ndarray | torch.Tensor) -> None:
        """Merge a batch ``(n, obs_dim)`` (or one ``(obs_dim,)`` row) into the statistics."""
        x = torch.as_tensor(obs, dtype=torch.float64, device=self.mean.device)
        if x.ndim == 1:
            x = x[None]
        if x.ndim != 2 or x.shape[1] != self.obs_dim:
            raise ValueError(f"obs must have shape (n, {self.obs_dim}), got {tuple(x.shape)}")
        if not torch.isfinite(x).all():
            raise ValueError("obs holds non-finite values; the normaliser refuses them")
        n = x.shape[0]
        if n == 0:
            return
        batch_mean = x.mean(0)
        batch_var = x.var(0, unbiased=False)
        total = self.count + n
        delta = batch_mean - self.mean
        m2 = self.var * self.count + batch_var * n + delta.square() * self.count * n / total
        self.mean += delta * n / total
        self.var.copy_(m2 / total)
        self.count.copy_(total)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Normalised, clipped observations in ``obs``'s dtype (statistics unchanged)."""
        out = (obs.to(torch.float64) - self.mean) / torch.sqrt(self.var + EPS)
        return out.clamp(-self.clip, self.clip).to(obs.dtype)

    @classmethod
    def from_state_dict(cls, tensors: Mapping[str, torch.Tensor], prefix: str = "obs_norm.") -> ObsNormalizer:
        """Rebuild from (a flat, prefixed) state dict, e.g. a policy file's tensors."""
        own = {k.removeprefix(prefix): v for k, v in tensors.items() if k.startswith(prefix)}
        if "mean" not in own:
            raise KeyError(f"no normaliser with prefix {prefix!r} (expected '{prefix}mean')")
        norm = cls(int(own["mean"].shape[0]))
        norm.load_state_dict(own)
        return norm
