"""n-step returns for the off-policy learners: each agent's one-step transitions become n-step ones before they
reach the replay buffer (as TorchRL's ``MultiStep`` and FastTD3's buffer do).

A stored transition from step t of one row (one agent in one match) is::

    (s_t, a_t, R = r_t + γ r_{t+1} + ... + γ^(m-1) r_{t+m-1}, s_{t+m}, done, γ^m)

with m = n, except where the row's match ends first:

- a win or loss (or, with elimination rules, the agent leaving) at step t+m-1 < t+n-1: every pending
  transition of the row is stored with ``done = 1`` (no bootstrap);
- a draw by the time limit: they are stored with ``done = 0`` and bootstrap from the last observation with
  their own γ^m (the state is not terminal);
- a physics error: that step is never stored (its next observation is meaningless); the row's pending
  transitions bootstrap from the observation before it, s_t of the failed step.

The TD target then reads ``y = R + γ^m (1 - done) V(s_{t+m})``
(:meth:`~triplesumo.algos.offpolicy.OffPolicyAlgorithm.bootstrap`). The returns are not corrected for the
policy having changed since the transition was collected (no importance weights), as in the n-step DDPG / TD3 /
SAC of D4PG, Rainbow-style agents and FastTD3. SAC's entropy bonus counts at the bootstrap state only.

The pending window of every row is part of a checkpoint (:meth:`NStepReturns.state_dict`), so a resumed run
stores what an uninterrupted one would. n = 1 is plain one-step TD. :class:`TorchNStepReturns` keeps the windows
as tensors on a device for a device-resident collection (``train --backend warp --device cuda``): the same
transitions, and the same checkpoint arrays, without the steps visiting the host.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch


class NStepReturns:
    """The pending window of each of ``rows`` rows (at most n one-step transitions, oldest first) and what leaves it.

    The windows are numpy arrays; :class:`TorchNStepReturns` runs the same :meth:`push` on tensors. The arithmetic is
    written once against ``xp`` (``numpy`` or ``torch``, whose ``where``, indexing and comparisons it uses alike);
    a subclass names its ``xp`` and how a step's inputs, float32 outputs and checkpoint arrays convert.

    Args:
        n: Steps per return, >= 1.
        gamma: The discount γ.
        rows: Rows (agents × matches) whose steps arrive together in :meth:`push`.
        obs_dim: Size of one observation.
        act_dim: Size of one action.
    """

    xp: Any = np
    """The array module the windows live in."""

    def __init__(self, n: int, gamma: float, rows: int, obs_dim: int, act_dim: int) -> None:
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"n-step returns need n >= 1, got {n!r}")
        self.n, self.gamma = n, float(gamma)
        self.obs = np.zeros((n, rows, obs_dim), dtype=np.float32)
        """``(n, rows, obs_dim)`` s_t of each pending transition, oldest first."""
        self.act = np.zeros((n, rows, act_dim), dtype=np.float32)
        """``(n, rows, act_dim)`` a_t of each pending transition."""
        self.ret = np.zeros((n, rows), dtype=np.float64)
        """``(n, rows)`` the discounted reward each pending transition has gathered so far."""
        self.count = np.zeros(rows, dtype=np.int64)
        """``(rows,)`` pending transitions per row."""
        self.powers = self.gamma ** np.arange(n + 1, dtype=np.float64)
        """γ^0 ... γ^n."""
        self.slots = np.arange(n)[:, None]
        """``(n, 1)`` the window's slot numbers."""

    def __len__(self) -> int:
        """Transitions pending, over all rows."""
        return int(self.count.sum())

    def _take(self, x: Any, dtype: str | None = None) -> Any:
        """One of :meth:`push`'s inputs as an array of ``xp`` (of the dtype named, if one is)."""
        return np.asarray(x, dtype=dtype)

    def _f32(self, x: Any) -> Any:
        """An output field as float32."""
        return x.astype(np.float32, copy=False)

    def _host(self, x: Any) -> np.ndarray:
        """A window as a numpy array of its own (for a checkpoint)."""
        return np.array(x, copy=True)

    def push(self, obs: Any, act: Any, rew: Any, next_obs: Any, terminated: Any, truncated: Any, valid: Any,
             played: Any) -> dict[str, Any]:
        """Take one step of every row (``(rows, ...)`` arrays; ``played``: the row was in its match, ``valid``: its
        step is real, not a physics error) and return the transitions it completes, as replay fields (``obs``,
        ``act``, ``rew``, ``next_obs``, ``done``, ``discount``; float32 arrays of ``xp``), row by row and oldest
        first in a row."""
        xp = self.xp
        obs, act, next_obs, rew = self._take(obs), self._take(act), self._take(next_obs), self._take(rew, "float64")
        played, valid = self._take(played, "bool"), self._take(valid, "bool")
        terminated, truncated = self._take(terminated, "bool"), self._take(truncated, "bool")
        kept = played & valid
        broken = played & ~valid  # the pending ones bootstrap from s_t, the failed step's observation
        rows = xp.where(kept)[0]
        c = self.count[rows]
        pending = self.slots < c[None, :]  # (n, kept rows)
        age = c[None, :] - self.slots  # steps since each pending transition began
        self.ret[:, rows] += xp.where(pending, self.powers[age.clip(0, self.n)], 0.0) * rew[rows]
        self.obs[c, rows], self.act[c, rows], self.ret[c, rows] = obs[rows], act[rows], rew[rows]
        self.count[rows] += 1
        ended = kept & (terminated | truncated)
        full = kept & ~ended & (self.count == self.n)
        flush = ended | broken  # every pending transition leaves
        leave = self.slots < xp.where(flush, self.count, 0)[None, :]
        leave[0] |= full  # a full window's oldest leaves
        row, slot = xp.where(leave.T)  # row by row, oldest first
        out = {"obs": self.obs[slot, row], "act": self.act[slot, row], "rew": self._f32(self.ret[slot, row]),
               "next_obs": self._f32(xp.where(broken[row, None], obs[row], next_obs[row])),
               "done": self._f32(terminated[row] & ended[row]),
               "discount": self._f32(self.powers[self.count[row] - slot])}
        self.count[flush] = 0
        if bool(full.any()):  # the window moves on by one (the right side's mask index copies)
            for name in ("obs", "act", "ret"):
                window = getattr(self, name)
                window[:-1, full] = window[1:, full]
            self.count[full] = self.n - 1
        return out

    def state_dict(self) -> dict[str, np.ndarray]:
        """The pending windows (numpy arrays, for a checkpoint's ``arrays.npz``)."""
        return {name: self._host(getattr(self, name)) for name in ("obs", "act", "ret", "count")}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore :meth:`state_dict`; ``ValueError`` naming the array whose shape does not fit."""
        for name in ("obs", "act", "ret", "count"):
            if name not in state:
                raise KeyError(f"n-step state is missing {name!r}")
            want = tuple(getattr(self, name).shape)
            got = np.shape(state[name])
            if got != want:
                raise ValueError(f"n-step state {name!r} has shape {got}, this learner's is {want} (n = {self.n})")
        count = np.asarray(state["count"], dtype=np.int64)
        if count.min(initial=0) < 0 or count.max(initial=0) >= self.n:
            raise ValueError(f"n-step state 'count' must lie in [0, {self.n - 1}], got {count.min()}..{count.max()}")
        for name in ("obs", "act", "ret", "count"):
            getattr(self, name)[...] = self._take(state[name])  # (cast to the window's own dtype)


class TorchNStepReturns(NStepReturns):
    """:class:`NStepReturns` whose windows are tensors on ``device``: :meth:`push` takes the step as tensors there
    (or anything ``torch.as_tensor`` takes) and returns the completed transitions as float32 tensors there, the
    same ones in the same order as the numpy windows; :meth:`state_dict` gives (and :meth:`load_state_dict` takes)
    the numpy windows' arrays, so a checkpoint is the same on either."""

    xp = torch

    def __init__(self, n: int, gamma: float, rows: int, obs_dim: int, act_dim: int,
                 device: str | torch.device = "cpu") -> None:
        super().__init__(n, gamma, rows, obs_dim, act_dim)
        self.device = torch.device(device)
        for name in ("obs", "act", "ret", "count", "powers", "slots"):
            setattr(self, name, torch.as_tensor(getattr(self, name), device=self.device))

    def _take(self, x: Any, dtype: str | None = None) -> torch.Tensor:
        return torch.as_tensor(x, dtype=None if dtype is None else getattr(torch, dtype), device=self.device)

    def _f32(self, x: torch.Tensor) -> torch.Tensor:
        return x.float()

    def _host(self, x: torch.Tensor) -> np.ndarray:
        return x.cpu().numpy().copy()
