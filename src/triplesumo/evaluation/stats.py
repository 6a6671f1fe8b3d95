"""Confidence intervals for evaluation results, without scipy.

Two intervals are provided:

* :func:`wilson_interval` for a proportion (win, loss or draw rate over ``n`` epochs).
  The Wilson score interval stays inside ``[0, 1]`` and behaves well near 0 and 1,
  where the textbook Wald interval collapses to a point.
* :func:`mean_interval` for a mean under a normal approximation (for example the mean
  local winning rate of a test run, whose value equals the MWR with λ = the run length).

Compute intervals on per-epoch values (independent matches), never on a moving
average: consecutive MWR values share λ − 1 epochs and are strongly correlated.

The normal quantile comes from :meth:`statistics.NormalDist.inv_cdf`.
"""

from __future__ import annotations

import math
import numbers
from statistics import NormalDist

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["mean_interval", "normal_quantile", "wilson_interval"]


def normal_quantile(confidence: float) -> float:
    """Two-sided standard normal quantile ``z`` for a confidence level.

    Args:
        confidence: Confidence level in the open interval (0, 1), e.g. 0.95.

    Returns:
        ``z`` such that a standard normal variable lies in ``[-z, z]`` with probability
        ``confidence`` (1.959964 for 0.95).

    Raises:
        TypeError: If ``confidence`` is not a real number (``bool`` included).
        ValueError: If ``confidence`` is not strictly between 0 and 1.
    """
    if isinstance(confidence, bool) or not isinstance(confidence, numbers.Real):
        raise TypeError(f"confidence must be a number in (0, 1), got {confidence!r}")
    c = float(confidence)
    if not (0.0 < c < 1.0):
        raise ValueError(
            f"confidence must be in the open interval (0, 1), got {confidence!r}"
        )
    return NormalDist().inv_cdf(0.5 + c / 2.0)


def _as_count(value: object, name: str) -> int:
    """Return ``value`` as a non-negative ``int``; errors name it."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    count = int(value)
    if count < 0:
        raise ValueError(f"{name} must be >= 0, got {count}")
    return count


def wilson_interval(
    successes: int, n: int, confidence: float = 0.95
) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion ``successes / n``.

    Args:
        successes: Number of successes (e.g. epochs won); an integer in ``[0, n]``.
        n: Number of trials (epochs); a non-negative integer.
        confidence: Confidence level in (0, 1); 0.95 by default.

    Returns:
        ``(lo, hi)`` with ``0 <= lo <= successes / n <= hi <= 1``; ``lo`` is exactly 0
        when ``successes == 0`` and ``hi`` exactly 1 when ``successes == n``.
        ``(nan, nan)`` when ``n == 0`` (no data, no interval).

    Raises:
        TypeError: If a count is not an integer or ``confidence`` not a number.
        ValueError: If a count is negative, ``successes > n``, or ``confidence`` is
            outside (0, 1).

    Example:
        >>> lo, hi = wilson_interval(50, 100)
        >>> round(lo, 4), round(hi, 4)
        (0.4038, 0.5962)
    """
    k = _as_count(successes, "successes")
    total = _as_count(n, "n")
    if k > total:
        raise ValueError(f"successes must be <= n, got successes={k}, n={total}")
    z = normal_quantile(confidence)
    if total == 0:
        return (math.nan, math.nan)
    p = k / total
    z2 = z * z
    denom = 1.0 + z2 / total
    centre = (p + z2 / (2.0 * total)) / denom
    half = z * math.sqrt(p * (1.0 - p) / total + z2 / (4.0 * total * total)) / denom
    lo = 0.0 if k == 0 else max(0.0, centre - half)
    hi = 1.0 if k == total else min(1.0, centre + half)
    return (lo, hi)


def mean_interval(x: ArrayLike, confidence: float = 0.95) -> tuple[float, float, float]:
    """Mean of ``x`` with a normal-approximation confidence interval.

    The interval is ``mean ± z · s / sqrt(n)`` with ``s`` the sample standard deviation
    (``ddof=1``). It assumes independent samples, so pass per-epoch values such as local
    winning rates, not a moving average of them.

    Args:
        x: One-dimensional finite samples.
        confidence: Confidence level in (0, 1); 0.95 by default.

    Returns:
        ``(mean, lo, hi)``. With no samples all three are NaN; with one sample the
        mean is returned and both bounds are NaN (the spread is unknown).

    Raises:
        TypeError: If ``confidence`` is not a number.
        ValueError: If ``x`` is not one-dimensional, holds non-finite values, or
            ``confidence`` is outside (0, 1).
    """
    z = normal_quantile(confidence)
    values = np.asarray(x, dtype=np.float64)
    if values.ndim != 1:
        raise ValueError(f"x must be one-dimensional, got shape {values.shape}")
    if not np.all(np.isfinite(values)):
        raise ValueError("x must hold only finite values")
    n = values.size
    if n == 0:
        return (math.nan, math.nan, math.nan)
    mean = float(values.mean())
    if n == 1:
        return (mean, math.nan, math.nan)
    half = z * float(values.std(ddof=1)) / math.sqrt(n)
    return (mean, mean - half, mean + half)
