"""Where a run's arrays live, written once: numpy on the host (``backend="cpu"``) or torch tensors on a device
(``backend="warp"``). Collection, the learners and the seats use the few operations here, never a branch of
their own on the device."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch


def host(x: Any) -> np.ndarray:
    """``x`` as a numpy array (a device tensor is copied to the host)."""
    return x.cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def finite(x: Any) -> bool:
    """Whether every entry of ``x`` (a numpy array or a tensor) is finite."""
    return bool(torch.isfinite(x).all()) if isinstance(x, torch.Tensor) else bool(np.isfinite(x).all())


class Arrays:
    """The array namespace of a run: numpy (``device`` None) or torch on ``device``."""

    def __init__(self, device: torch.device | None) -> None:
        self.device = device
        """Torch device of a device-resident run (``backend="warp"``); None: numpy on the host."""

    @property
    def on_device(self) -> bool:
        return self.device is not None

    def zeros(self, shape: tuple[int, ...], float64: bool = False) -> Any:
        """Zeros: numpy float64, or a float32 (``float64``: float64) tensor on the device."""
        if self.device is None:
            return np.zeros(shape)
        return torch.zeros(shape, dtype=torch.float64 if float64 else torch.float32, device=self.device)

    def put(self, x: Any, float32: bool = False) -> Any:
        """A host array where the run's arrays live: itself on the host; on the device a tensor (float32 with
        ``float32``, else of its dtype)."""
        if self.device is None:
            return x
        return torch.as_tensor(x, dtype=torch.float32 if float32 else None, device=self.device)

    def where(self, condition: Any, a: Any, b: Any) -> Any:
        return np.where(condition, a, b) if self.device is None else torch.where(condition, a, b)

    def stack(self, xs: Sequence[Any], axis: int) -> Any:
        """``xs`` stacked along ``axis`` (float64 on the device, as numpy's sums are)."""
        if self.device is None:
            return np.stack(xs, axis=axis)
        return torch.stack(list(xs), dim=axis).double()
