"""Exploration noise added to a deterministic policy's normalized actions (in [-1, 1]).

All randomness comes from the ``np.random.Generator`` passed to ``sample``, never from the
global ``np.random``; the noise objects only hold the process state, which
``state_dict``/``load_state_dict`` save and restore as numpy arrays.

Every noise has a ``shape``: ``(act_dim,)`` for one match or ``(n, act_dim)`` for ``n``
parallel matches; ``reset(mask)`` resets the rows whose match ended.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Protocol

import numpy as np

NOISE_KINDS = ("ou", "gaussian", "none")
"""Kinds accepted by :func:`make_noise`."""


def _check_shape(shape: int | tuple[int, ...]) -> tuple[int, ...]:
    shape = (shape,) if isinstance(shape, (int, np.integer)) else tuple(shape)
    if len(shape) not in (1, 2) or any(
        isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 1 for s in shape
    ):
        raise ValueError(f"shape must be (act_dim,) or (n, act_dim) of ints >= 1, got {shape!r}")
    return tuple(int(s) for s in shape)


def _check_real(name: str, value: float, *, positive: bool) -> float:
    real = not isinstance(value, bool) and isinstance(value, (int, float, np.floating, np.integer))
    if not real or not math.isfinite(value) or value < 0 or (positive and value == 0):
        raise ValueError(
            f"{name} must be finite and {'> 0' if positive else '>= 0'}, got {value!r}"
        )
    return float(value)


def _row_mask(shape: tuple[int, ...], mask: np.ndarray | bool | None) -> np.ndarray:
    """Boolean mask over rows (``shape[:-1]``); ``None`` selects every row."""
    rows = shape[:-1]
    if mask is None:
        return np.ones(rows, dtype=bool)
    mask = np.asarray(mask)
    if mask.dtype != bool or mask.shape != rows:
        raise ValueError(
            f"mask must be a bool array of shape {rows}, got {mask.dtype} {mask.shape}"
        )
    return mask


class ActionNoise(Protocol):
    """What the training loop needs from an exploration noise."""

    @property
    def shape(self) -> tuple[int, ...]:
        """``(act_dim,)`` or ``(n, act_dim)``."""
        ...

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """Next noise value (float32, of ``shape``), to add to the policy's action."""
        ...

    def reset(self, mask: np.ndarray | bool | None = None) -> None:
        """Reset the rows selected by ``mask`` (all rows when ``None``)."""
        ...

    def state_dict(self) -> dict[str, np.ndarray]:
        """Internal process state as numpy arrays."""
        ...

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore :meth:`state_dict`."""
        ...


class OrnsteinUhlenbeckNoise:
    """Temporally correlated Ornstein–Uhlenbeck noise (DDPG, Lillicrap et al., 2015).

    Euler–Maruyama discretisation, as in OpenAI Baselines and the paper's original code::

        x <- x + θ (μ - x) dt + σ √dt ε,   ε ~ N(0, I)
        sample = scale · x

    ``x`` starts at (and is reset to) μ. With ``a = 1 - θ dt`` this is an AR(1) process with
    ``E[x_t] = μ + (x_0 - μ) a^t`` and stationary variance::

        Var[x] = σ² dt / (1 - a²) = σ² / (θ (2 - θ dt))     (-> σ²/(2θ) as dt -> 0)

    times ``scale²`` for the samples. Defaults θ = 0.15, σ = 0.2, dt = 1e-2 give a stationary
    std of ≈ 0.365 and a correlation time of 1/(θ dt) ≈ 667 steps.

    Args:
        shape: ``(act_dim,)`` or ``(n, act_dim)``.
        sigma: Diffusion σ.
        theta: Mean-reversion rate θ.
        dt: Time step of the discretisation.
        mu: Long-run mean μ (in units of the unscaled process).
        scale: Multiplies every sample; 1.0 is the half-width of the normalized action range.
    """

    def __init__(
        self,
        shape: int | tuple[int, ...],
        sigma: float = 0.2,
        theta: float = 0.15,
        dt: float = 1e-2,
        mu: float = 0.0,
        scale: float = 1.0,
    ) -> None:
        self._shape = _check_shape(shape)
        self.sigma = _check_real("sigma", sigma, positive=False)
        self.theta = _check_real("theta", theta, positive=True)
        self.dt = _check_real("dt", dt, positive=True)
        if self.theta * self.dt > 1.0:
            raise ValueError(
                f"theta * dt must be <= 1 for a stable process, got {self.theta * self.dt}"
            )
        real = not isinstance(mu, bool) and isinstance(mu, (int, float, np.floating, np.integer))
        if not real or not math.isfinite(mu):
            raise ValueError(f"mu must be a finite real number, got {mu!r}")
        self.mu = float(mu)
        self.scale = _check_real("scale", scale, positive=True)
        self._x = np.full(self._shape, self.mu, dtype=np.float64)

    @property
    def shape(self) -> tuple[int, ...]:
        """``(act_dim,)`` or ``(n, act_dim)``."""
        return self._shape

    @property
    def stationary_std(self) -> float:
        """Standard deviation of the samples once the process is stationary."""
        return self.scale * self.sigma / math.sqrt(self.theta * (2.0 - self.theta * self.dt))

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """Advance the process one step and return ``scale · x`` (float32, of ``shape``)."""
        eps = rng.standard_normal(self._shape)
        self._x += (
            self.theta * (self.mu - self._x) * self.dt + self.sigma * math.sqrt(self.dt) * eps
        )
        return (self.scale * self._x).astype(np.float32)

    def reset(self, mask: np.ndarray | bool | None = None) -> None:
        """Set the rows selected by ``mask`` (bool, shape ``shape[:-1]``; all if None) back to μ."""
        self._x[_row_mask(self._shape, mask)] = self.mu

    def state_dict(self) -> dict[str, np.ndarray]:
        """``{"x": process state}`` (float64, a copy)."""
        return {"x": self._x.copy()}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore the process state saved by :meth:`state_dict`."""
        if "x" not in state:
            raise KeyError("OU noise state is missing 'x'")
        x = np.asarray(state["x"], dtype=np.float64)
        if x.shape != self._shape:
            raise ValueError(f"x must have shape {self._shape}, got {x.shape}")
        self._x = x.copy()


class GaussianNoise:
    """Independent Gaussian noise: ``sample = scale · σ · ε``, ``ε ~ N(0, I)``; stateless.

    Args:
        shape: ``(act_dim,)`` or ``(n, act_dim)``.
        sigma: Standard deviation σ before scaling.
        scale: Multiplies every sample; 1.0 is the half-width of the normalized action range.
    """

    def __init__(
        self, shape: int | tuple[int, ...], sigma: float = 0.1, scale: float = 1.0
    ) -> None:
        self._shape = _check_shape(shape)
        self.sigma = _check_real("sigma", sigma, positive=False)
        self.scale = _check_real("scale", scale, positive=True)

    @property
    def shape(self) -> tuple[int, ...]:
        """``(act_dim,)`` or ``(n, act_dim)``."""
        return self._shape

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """Fresh noise (float32, of ``shape``)."""
        return (self.scale * self.sigma * rng.standard_normal(self._shape)).astype(np.float32)

    def reset(self, mask: np.ndarray | bool | None = None) -> None:
        """Nothing to reset (the mask is still validated)."""
        _row_mask(self._shape, mask)

    def state_dict(self) -> dict[str, np.ndarray]:
        """Empty: the noise has no state."""
        return {}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Accept an empty state."""
        if state:
            raise ValueError(f"GaussianNoise has no state, got keys {sorted(state)}")


class ZeroNoise(GaussianNoise):
    """No exploration noise: ``sample`` returns zeros (still of ``shape``)."""

    def __init__(self, shape: int | tuple[int, ...]) -> None:
        super().__init__(shape, sigma=0.0)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """Zeros (float32, of ``shape``); ``rng`` is not used."""
        return np.zeros(self._shape, dtype=np.float32)


def make_noise(
    kind: str,
    shape: int | tuple[int, ...],
    sigma: float = 0.2,
    theta: float = 0.15,
    *,
    dt: float = 1e-2,
    scale: float = 1.0,
) -> ActionNoise:
    """Build a noise by name: ``"ou"`` (uses σ, θ, dt), ``"gaussian"`` (σ) or ``"none"``.

    Raises:
        ValueError: Unknown ``kind`` (the message lists :data:`NOISE_KINDS`) or bad parameter.
    """
    if kind == "ou":
        return OrnsteinUhlenbeckNoise(shape, sigma=sigma, theta=theta, dt=dt, scale=scale)
    if kind == "gaussian":
        return GaussianNoise(shape, sigma=sigma, scale=scale)
    if kind == "none":
        return ZeroNoise(shape)
    raise ValueError(f"noise kind must be one of {NOISE_KINDS}, got {kind!r}")
