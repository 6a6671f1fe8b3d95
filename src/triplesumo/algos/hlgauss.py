"""Critics that learn a histogram of returns with the HL-Gauss loss (Farebrother et al., "Stop Regressing",
ICML 2024), in place of the mean squared TD error.

The critic's head gives ``bins`` logits over a fixed support of equal bins on ``[low, high]``; its Q-value is the
expectation of the bin centres under their softmax, so everything that reads a critic's Q (the clipped double Q,
the actor's loss, the TD target) reads it unchanged. Its loss is the cross-entropy of its logits against the
target's histogram: the mass a Gaussian ``N(y, σ²)`` puts on each bin, ``σ`` = ``sigma_ratio`` bin widths (the
paper's 0.75), ``y`` clipped into the support and the mass renormalised. A TD error of 500 then pushes the logits as
hard as one of 50 does: the game's win and loss (+500, -400) do not swamp what the critic learns from the rest.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn

from triplesumo.agents.networks import Critic, mlp, plain_block

SIGMA_RATIO = 0.75
"""σ of the target's Gaussian in bin widths (Farebrother et al.'s recommended σ/ζ)."""


def bin_edges(low: float, high: float, bins: int) -> torch.Tensor:
    """The ``bins + 1`` edges of ``bins`` equal bins on ``[low, high]`` (float32)."""
    if not (low < high) or bins < 2:
        raise ValueError(f"a histogram support needs low < high and at least 2 bins, got [{low}, {high}], {bins}")
    return torch.linspace(low, high, bins + 1, dtype=torch.float32)


def hl_gauss(target: torch.Tensor, edges: torch.Tensor, sigma: float) -> torch.Tensor:
    """The HL-Gauss histogram ``(B, bins)`` of targets ``(B,)``: each row the mass of ``N(y, σ²)`` in each bin of
    ``edges``, with ``y`` clipped into ``[edges[0], edges[-1]]`` and the row renormalised to sum to 1."""
    y = target.clamp(float(edges[0]), float(edges[-1])).unsqueeze(-1)
    cdf = torch.special.erf((edges - y) / (sigma * 2.0 ** 0.5))
    mass = cdf[..., 1:] - cdf[..., :-1]
    return mass / (cdf[..., -1:] - cdf[..., :1])


class HLGaussCritic(Critic):
    """:class:`~triplesumo.agents.networks.Critic` whose head gives ``bins`` logits over ``[low, high]``;
    :meth:`forward` is their expected value, :meth:`regression_loss` HL-Gauss's cross-entropy. ``block`` is the
    hidden layer's (:func:`~triplesumo.agents.networks.plain_block`, or a normalised one)."""

    edges: torch.Tensor
    """The ``bins + 1`` bin edges (a buffer made from the config, not checkpointed)."""
    centres: torch.Tensor
    """The ``bins`` bin centres."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: tuple[int, ...], low: float, high: float, bins: int,
                 block: Callable[[int, int], list[nn.Module]] = plain_block) -> None:
        nn.Module.__init__(self)
        self.obs_dim, self.act_dim, self.hidden = obs_dim, act_dim, tuple(hidden)
        edges = bin_edges(low, high, bins)
        self.sigma = SIGMA_RATIO * (high - low) / bins
        self.register_buffer("edges", edges, persistent=False)
        self.register_buffer("centres", (edges[:-1] + edges[1:]) / 2, persistent=False)
        self.net = mlp(obs_dim + act_dim, self.hidden, bins, block=block)

    def logits(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The histogram's logits ``(..., bins)``."""
        return self.net(torch.cat([obs, action], dim=-1))

    def expected(self, logits: torch.Tensor) -> torch.Tensor:
        """The expected return ``(...,)`` of a histogram's logits."""
        return torch.softmax(logits, dim=-1) @ self.centres

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Q-values ``(...,)``: the expected bin centre."""
        return self.expected(self.logits(obs, action))

    def regression_loss(self, obs: torch.Tensor, action: torch.Tensor,
                        target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``mean_b CE(hl_gauss(y_b), softmax(logits_b))`` and the Q-values ``(B,)`` (with their graph)."""
        logits = self.logits(obs, action)
        histogram = hl_gauss(target.detach(), self.edges, self.sigma)
        loss = -(histogram * F.log_softmax(logits, dim=-1)).sum(-1).mean()
        return loss, self.expected(logits)
