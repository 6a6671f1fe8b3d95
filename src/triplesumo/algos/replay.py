"""Uniform experience replay for the off-policy learners (DDPG, TD3, SAC), in preallocated numpy arrays
(or torch tensors on a device: :class:`TorchReplayBuffer`).

What goes in (the caller's contract):

- ``done = 1`` means *no bootstrap*: a real terminal, i.e. the match was won or lost.
- A transition that ends in a truncation (a draw by the time limit) is stored with
  ``done = 0``: the value bootstraps through the time limit, since the state itself is not
  terminal.
- A transition that ends in a physics error (simulation instability) is dropped by the
  caller and never stored; its next observation is meaningless.
- With n-step returns (:class:`~triplesumo.algos.nstep.NStepReturns`) a buffer made with
  ``discount=True`` also keeps each transition's bootstrap factor γ^m (m: the steps it spans),
  since transitions cut short by a match's end span fewer than n.

The buffer is circular: once full, each new transition overwrites the oldest one. Its
:meth:`ReplayBuffer.state_dict` is a dict of plain numpy arrays, so a run can be saved with
``np.savez`` (no pickle) and resumed exactly.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

FIELDS = ("obs", "act", "rew", "next_obs", "done")
"""Names of the stored arrays, as used in sampled batches and in the state dict."""
DISCOUNT = "discount"
"""The extra field of a buffer made with ``discount=True``: each transition's bootstrap factor γ^m."""


def _positive_int(name: str, value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be an int >= 1, got {value!r}")
    return int(value)


class ReplayBuffer:
    """Circular buffer of ``(obs, act, rew, next_obs, done)`` transitions, all float32.

    Storage is allocated up front with ``np.zeros`` (pages are only committed by the OS
    when written, so a large, mostly empty buffer is cheap).

    Args:
        capacity: Maximum number of transitions kept (paper: 1,000,000).
        obs_dim: Size of one (flat) observation.
        act_dim: Size of one action.
        discount: Also keep each transition's bootstrap factor (:data:`DISCOUNT`; n-step returns).
    """

    def __init__(self, capacity: int, obs_dim: int, act_dim: int, discount: bool = False) -> None:
        self._capacity = _positive_int("capacity", capacity)
        self.obs_dim = _positive_int("obs_dim", obs_dim)
        self.act_dim = _positive_int("act_dim", act_dim)
        self.fields: tuple[str, ...] = (*FIELDS, DISCOUNT) if discount else FIELDS
        """The stored arrays: :data:`FIELDS`, and :data:`DISCOUNT` when made with ``discount``."""
        for name, shape in self._row_shapes().items():
            setattr(self, name, np.zeros((self._capacity, *shape), dtype=np.float32))
        self._pos = 0  # index the next transition is written to
        self._size = 0  # number of filled slots (saturates at capacity)

    @property
    def capacity(self) -> int:
        """Maximum number of transitions kept."""
        return self._capacity

    @property
    def pos(self) -> int:
        """Index the next transition will be written to."""
        return self._pos

    def __len__(self) -> int:
        return self._size

    def _row_shapes(self) -> dict[str, tuple[int, ...]]:
        shapes: dict[str, tuple[int, ...]] = {"obs": (self.obs_dim,), "act": (self.act_dim,), "rew": (),
                                              "next_obs": (self.obs_dim,), "done": (), DISCOUNT: ()}
        return {name: shapes[name] for name in self.fields}

    def _arrays(self, obs: Any, act: Any, rew: Any, next_obs: Any, done: Any, discount: Any) -> dict[str, Any]:
        """The fields of one ``add_batch`` call by name; ``discount`` given exactly when the buffer keeps it."""
        if (discount is not None) != (DISCOUNT in self.fields):
            raise ValueError("discount must be given exactly when the buffer keeps it (made with discount=True)")
        arrays = {"obs": obs, "act": act, "rew": rew, "next_obs": next_obs, "done": done}
        return arrays if discount is None else {**arrays, DISCOUNT: discount}

    def add(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        rew: float,
        next_obs: np.ndarray,
        done: float | bool,
    ) -> None:
        """Store ONE transition (``done`` true only for a real terminal: win or loss)."""
        self.add_batch(
            np.asarray(obs)[None],
            np.asarray(act)[None],
            np.asarray(rew)[None],
            np.asarray(next_obs)[None],
            np.asarray(done)[None],
        )

    def add_batch(
        self,
        obs: np.ndarray,
        act: np.ndarray,
        rew: np.ndarray,
        next_obs: np.ndarray,
        done: np.ndarray,
        discount: np.ndarray | None = None,
    ) -> None:
        """Store ``n`` transitions at once (leading axis ``n``), in order, wrapping around.

        Equivalent to ``n`` calls of :meth:`add`; if ``n > capacity`` only the last
        ``capacity`` transitions survive, exactly as with sequential adds. ``discount``: their
        bootstrap factors, given exactly when the buffer keeps them.
        """
        arrays = self._arrays(obs, act, rew, next_obs, done, discount)
        n = int(np.shape(obs)[0]) if np.ndim(obs) > 0 else 0
        checked: dict[str, np.ndarray] = {}
        for name, row_shape in self._row_shapes().items():
            arr = np.asarray(arrays[name], dtype=np.float32)
            if arr.shape != (n, *row_shape):
                raise ValueError(f"{name} must have shape {(n, *row_shape)}, got {arr.shape}")
            checked[name] = arr
        if n == 0:
            return
        start = 0
        if n > self._capacity:  # only the newest `capacity` transitions would survive
            start = n - self._capacity
        idx = (self._pos + start + np.arange(n - start)) % self._capacity
        for name, arr in checked.items():
            getattr(self, name)[idx] = arr[start:]
        self._pos = int((self._pos + n) % self._capacity)
        self._size = min(self._size + n, self._capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Draw ``batch_size`` transitions uniformly (with replacement) from the filled part.

        Returns fresh arrays keyed by :attr:`fields`: ``obs (B, obs_dim)``, ``act (B, act_dim)``,
        ``rew (B,)``, ``next_obs (B, obs_dim)``, ``done (B,)`` (and ``discount (B,)``).
        """
        batch_size = _positive_int("batch_size", batch_size)
        if self._size == 0:
            raise ValueError("cannot sample from an empty ReplayBuffer")
        idx = rng.integers(0, self._size, size=batch_size)
        return {name: getattr(self, name)[idx] for name in self.fields}

    def state_dict(self) -> dict[str, np.ndarray]:
        """Filled part of every array plus ``pos``, ``size``, ``capacity`` as 0-d int64 arrays.

        All values are numpy arrays, so ``np.savez(path, **buffer.state_dict())`` works
        without pickle.
        """
        state = {name: getattr(self, name)[: self._size].copy() for name in self.fields}
        state["pos"] = np.asarray(self._pos, dtype=np.int64)
        state["size"] = np.asarray(self._size, dtype=np.int64)
        state["capacity"] = np.asarray(self._capacity, dtype=np.int64)
        return state

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore from :meth:`state_dict` (e.g. an ``np.load`` of a saved ``.npz``).

        Only the filled part is written, one array at a time, so a resumed run needs no more
        memory than the run it resumes (``state`` may read its arrays lazily, e.g. an open
        ``np.load`` of an ``.npz``). If an array has the wrong shape the buffer keeps its
        size and position but the arrays before it are already overwritten.

        Raises:
            KeyError: A key is missing.
            ValueError: Capacity, sizes or array shapes do not match this buffer.
        """
        size, pos = self._checked_extent(state)
        for name in self._row_shapes():  # one array at a time: never two copies at once
            arr = self._checked_rows(state, name, size)
            target = getattr(self, name)
            target[:size] = arr
            del arr
            if self._size > size:  # zero what an earlier fill left beyond the restored part (untouched
                target[size:self._size] = 0.0  # pages are still the allocation's zeros: never touch them)
        self._pos = pos
        self._size = size

    def _checked_extent(self, state: Mapping[str, np.ndarray]) -> tuple[int, int]:
        """``(size, pos)`` of a saved state, once its keys, capacity, size and position fit this buffer."""
        for key in (*self.fields, "pos", "size", "capacity"):
            if key not in state:
                raise KeyError(f"replay state is missing {key!r}")
        capacity, size, pos = (int(np.asarray(state[k])) for k in ("capacity", "size", "pos"))
        if capacity != self._capacity:
            raise ValueError(f"capacity: saved {capacity}, this buffer has {self._capacity}")
        if not 0 <= size <= capacity:
            raise ValueError(f"size must be in [0, {capacity}], got {size}")
        if not 0 <= pos < capacity or (size < capacity and pos != size):
            raise ValueError(f"pos {pos} is inconsistent with size {size} and capacity {capacity}")
        return size, pos

    def _checked_rows(self, state: Mapping[str, np.ndarray], name: str, size: int,
                      dtype: type | None = None) -> np.ndarray:
        """The saved rows of field ``name``, once their shape is ``(size, *row shape)``."""
        arr = np.asarray(state[name], dtype=dtype)
        want = (size, *self._row_shapes()[name])
        if arr.shape != want:
            raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
        return arr


class TorchReplayBuffer(ReplayBuffer):
    """:class:`ReplayBuffer` whose storage is float32 torch tensors on ``device`` (a GPU run:
    ``train --backend warp --device cuda``), fed and sampled with tensors on that device.

    Transitions arrive as tensors on the device and never visit the host: :meth:`add_batch`
    writes them in place, :meth:`sample` gathers a batch on the device. The sample's indices
    are drawn by the same numpy generator as the numpy buffer's (``batch_size`` integers
    copied to the device), so its stream and checkpoint are those of the numpy buffer:
    :meth:`state_dict` gives (and :meth:`load_state_dict` takes) the same numpy arrays.
    The whole capacity is allocated on the device up front.
    """

    def __init__(self, capacity: int, obs_dim: int, act_dim: int, device: str | torch.device = "cpu",
                 discount: bool = False) -> None:
        self._capacity = _positive_int("capacity", capacity)
        self.obs_dim = _positive_int("obs_dim", obs_dim)
        self.act_dim = _positive_int("act_dim", act_dim)
        self.fields = (*FIELDS, DISCOUNT) if discount else FIELDS
        self.device = torch.device(device)
        shapes = self._row_shapes()
        for name in self.fields:
            setattr(self, name, torch.zeros((self._capacity, *shapes[name]), dtype=torch.float32, device=self.device))
        self._pos = 0
        self._size = 0

    def add_batch(self, obs: Any, act: Any, rew: Any, next_obs: Any, done: Any, discount: Any = None) -> None:
        """Store ``n`` transitions (tensors, or anything ``torch.as_tensor`` takes), in order, wrapping."""
        arrays = self._arrays(obs, act, rew, next_obs, done, discount)
        checked = {name: torch.as_tensor(arrays[name], dtype=torch.float32, device=self.device)
                   for name in self.fields}
        n = int(checked["obs"].shape[0]) if checked["obs"].ndim > 0 else 0
        for name, row_shape in self._row_shapes().items():
            if tuple(checked[name].shape) != (n, *row_shape):
                raise ValueError(f"{name} must have shape {(n, *row_shape)}, got {tuple(checked[name].shape)}")
        if n == 0:
            return
        start = max(0, n - self._capacity)
        idx = torch.remainder(torch.arange(self._pos + start, self._pos + n, device=self.device), self._capacity)
        for name, arr in checked.items():
            getattr(self, name)[idx] = arr[start:]
        self._pos = int((self._pos + n) % self._capacity)
        self._size = min(self._size + n, self._capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, Any]:
        """``batch_size`` transitions drawn uniformly (with replacement), as tensors on the device."""
        batch_size = _positive_int("batch_size", batch_size)
        if self._size == 0:
            raise ValueError("cannot sample from an empty ReplayBuffer")
        idx = torch.as_tensor(rng.integers(0, self._size, size=batch_size), device=self.device)
        return {name: getattr(self, name)[idx] for name in self.fields}

    def state_dict(self) -> dict[str, np.ndarray]:
        """As :meth:`ReplayBuffer.state_dict`: numpy arrays of the filled part (copied to the host)."""
        state = {name: getattr(self, name)[: self._size].cpu().numpy() for name in self.fields}
        state["pos"] = np.asarray(self._pos, dtype=np.int64)
        state["size"] = np.asarray(self._size, dtype=np.int64)
        state["capacity"] = np.asarray(self._capacity, dtype=np.int64)
        return state

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore :meth:`state_dict` output (or a numpy buffer's); errors as :meth:`ReplayBuffer.load_state_dict`."""
        size, pos = self._checked_extent(state)
        for name in self._row_shapes():
            arr = self._checked_rows(state, name, size, np.float32)
            target = getattr(self, name)
            target[:size] = torch.as_tensor(arr, device=self.device)
            target[size:] = 0.0
        self._pos, self._size = pos, size
