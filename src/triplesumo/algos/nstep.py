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

    Args:
        n: Steps per return, >= 1.
        gamma: The discount γ.
        rows: Rows (agents × matches) whose steps arrive together in :meth:`push`.
        obs_dim: Size of one observation.
        act_dim: Size of one action.
    """

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

    def __len__(self) -> int:
        """Transitions pending, over all rows."""
        return int(self.count.sum())

    def push(self, obs: np.ndarray, act: np.ndarray, rew: np.ndarray, next_obs: np.ndarray, terminated: np.ndarray,
             truncated: np.ndarray, valid: np.ndarray, played: np.ndarray) -> dict[str, np.ndarray]:
        """Take one step of every row (``(rows, ...)`` arrays; ``played``: the row was in its match, ``valid``: its
        step is real, not a physics error) and return the transitions it completes, as replay fields (``obs``,
        ``act``, ``rew``, ``next_obs``, ``done``, ``discount``; float32), row by row and oldest first in a row."""
        played = np.asarray(played, dtype=bool)
        valid = np.asarray(valid, dtype=bool)
        terminated = np.asarray(terminated, dtype=bool)
        rew = np.asarray(rew)
        kept = played & valid
        broken = played & ~valid  # the pending ones bootstrap from s_t, the failed step's observation
        rows = np.flatnonzero(kept)
        c = self.count[rows]
        pending = np.arange(self.n)[:, None] < c[None, :]  # (n, kept rows)
        age = c[None, :] - np.arange(self.n)[:, None]  # steps since each pending transition began
        self.ret[:, rows] += np.where(pending, self.powers[np.clip(age, 0, self.n)], 0.0) * rew[rows]
        self.obs[c, rows], self.act[c, rows], self.ret[c, rows] = obs[rows], act[rows], rew[rows]
        self.count[rows] += 1
        ended = kept & (terminated | np.asarray(truncated, dtype=bool))
        full = kept & ~ended & (self.count == self.n)
        flush = ended | broken  # every pending transition leaves
        leave = (np.arange(self.n)[:, None] < np.where(flush, self.count, 0)[None, :])
        leave[0] |= full  # a full window's oldest leaves
        row, slot = np.nonzero(leave.T)  # row by row, oldest first
        out = {"obs": self.obs[slot, row], "act": self.act[slot, row],
               "rew": self.ret[slot, row].astype(np.float32),
               "next_obs": np.where(broken[row, None], obs[row], next_obs[row]).astype(np.float32, copy=False),
               "done": (terminated[row] & ended[row]).astype(np.float32),
               "discount": self.powers[self.count[row] - slot].astype(np.float32)}
        self.count[flush] = 0
        if full.any():  # the window moves on by one
            for name in ("obs", "act", "ret"):
                window = getattr(self, name)
                window[:-1, full] = window[1:, full]
            self.count[full] = self.n - 1
        return out

    def state_dict(self) -> dict[str, np.ndarray]:
        """The pending windows (numpy arrays, for a checkpoint's ``arrays.npz``)."""
        return {"obs": self.obs.copy(), "act": self.act.copy(), "ret": self.ret.copy(), "count": self.count.copy()}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore :meth:`state_dict`; ``ValueError`` naming the array whose shape does not fit."""
        for name in ("obs", "act", "ret", "count"):
            if name not in state:
                raise KeyError(f"n-step state is missing {name!r}")
            want = getattr(self, name).shape
            got = np.shape(state[name])
            if got != want:
                raise ValueError(f"n-step state {name!r} has shape {got}, this learner's is {want} (n = {self.n})")
        count = np.asarray(state["count"], dtype=np.int64)
        if count.min(initial=0) < 0 or count.max(initial=0) >= self.n:
            raise ValueError(f"n-step state 'count' must lie in [0, {self.n - 1}], got {count.min()}..{count.max()}")
        for name in ("obs", "act", "ret"):
            getattr(self, name)[...] = state[name]
        self.count[...] = count


class TorchNStepReturns(NStepReturns):
    """:class:`NStepReturns` whose windows are tensors on ``device``: :meth:`push` takes the step as tensors there
    (or anything ``torch.as_tensor`` takes) and returns the completed transitions as float32 tensors there, the
    same ones in the same order as the numpy windows; :meth:`state_dict` gives (and :meth:`load_state_dict` takes)
    the numpy windows' arrays, so a checkpoint is the same on either."""

    def __init__(self, n: int, gamma: float, rows: int, obs_dim: int, act_dim: int,
                 device: str | torch.device = "cpu") -> None:
        super().__init__(n, gamma, rows, obs_dim, act_dim)
        self.device = torch.device(device)
        for name in ("obs", "act", "ret", "count", "powers"):
            setattr(self, name, torch.as_tensor(getattr(self, name), device=self.device))
        self.slots = torch.arange(self.n, device=self.device)[:, None]

    def _put(self, x: Any, dtype: torch.dtype | None = None) -> torch.Tensor:
        return torch.as_tensor(x, dtype=dtype, device=self.device)

    def push(self, obs: Any, act: Any, rew: Any, next_obs: Any, terminated: Any,  # type: ignore[override]
             truncated: Any, valid: Any, played: Any) -> dict[str, torch.Tensor]:
        """As :meth:`NStepReturns.push`, on the device."""
        obs, act, next_obs = self._put(obs), self._put(act), self._put(next_obs)
        rew = self._put(rew, torch.float64)
        played, valid = self._put(played, torch.bool), self._put(valid, torch.bool)
        terminated, truncated = self._put(terminated, torch.bool), self._put(truncated, torch.bool)
        kept = played & valid
        broken = played & ~valid
        rows = torch.nonzero(kept).flatten()
        c = self.count[rows]
        pending = self.slots < c[None, :]
        age = c[None, :] - self.slots
        self.ret[:, rows] += torch.where(pending, self.powers[age.clamp(0, self.n)], 0.0) * rew[rows]
        self.obs[c, rows], self.act[c, rows], self.ret[c, rows] = obs[rows], act[rows], rew[rows]
        self.count[rows] += 1
        ended = kept & (terminated | truncated)
        full = kept & ~ended & (self.count == self.n)
        flush = ended | broken
        leave = self.slots < torch.where(flush, torch.as_tensor(self.count), 0)[None, :]
        leave[0] |= full
        row, slot = torch.nonzero(leave.T, as_tuple=True)  # row-major: row by row, oldest first
        out = {"obs": self.obs[slot, row], "act": self.act[slot, row], "rew": self.ret[slot, row].float(),
               "next_obs": torch.where(broken[row, None], obs[row], next_obs[row]).float(),
               "done": (terminated[row] & ended[row]).float(),
               "discount": self.powers[self.count[row] - slot].float()}
        self.count[flush] = 0
        if bool(full.any()):
            for name in ("obs", "act", "ret"):
                window = getattr(self, name)
                window[:-1, full] = window[1:, full].clone()
            self.count[full] = self.n - 1
        return out

    def state_dict(self) -> dict[str, np.ndarray]:
        """As :meth:`NStepReturns.state_dict`: numpy arrays (copied to the host)."""
        return {name: getattr(self, name).cpu().numpy().copy() for name in ("obs", "act", "ret", "count")}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """As :meth:`NStepReturns.load_state_dict`, onto the device."""
        host = NStepReturns(self.n, self.gamma, self.count.shape[0], self.obs.shape[2], self.act.shape[2])
        host.load_state_dict(state)  # (its checks)
        for name in ("obs", "act", "ret", "count"):
            getattr(self, name).copy_(torch.as_tensor(getattr(host, name)))
