"""The paper's evaluation metrics, in pure numpy.

Every function takes per-epoch sequences (one entry per epoch, i.e. per match) and
returns a float array of the same length, so curves can be plotted against the epoch
index directly. All rolling statistics are O(n) (cumulative sums).

Definitions (Wang, Das, Millard, TAROS 2022, and the choices this project made where
the paper is silent):

* **Outcome** of an epoch, from the learner's team's point of view (Ant and Bug
  against Spider): ``"win"``, ``"loss"``, ``"draw"`` (the step limit was reached with
  nobody out) or ``"error"`` (the epoch was truncated by a physics error).
* **Local winning rate** (lwr): +1 for a win, −1 for a loss, 0 for a draw. The paper
  knows no physics errors; an ``"error"`` epoch also counts 0, as an epoch without a
  result. It is still an epoch, so it stays in every window and in every denominator.
* **Moving winning rate** (MWR) at epoch α with window λ: the sum of the lwr over the
  last λ epochs up to and including α, divided by λ (the paper uses λ = 200). The paper
  does not say what happens for α < λ − 1, where fewer than λ epochs exist. Here the
  default (``partial=True``) divides by the number of epochs so far, i.e. the mean over
  the partial window ``0..α``; dividing by λ instead would drag the first values towards
  zero. With ``partial=False`` those first λ − 1 epochs are NaN, so only full windows
  are shown; :func:`full_window_mask` tells which epochs have a full window.
* **Steps to win**: at epoch α, the mean number of steps of the epochs the team *won*
  among the last λ epochs up to α (a partial window at the start, as for the MWR);
  NaN where no epoch of the window was won. Losses, draws and errors are left out, not
  counted as the step limit.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Final, Literal, TypedDict

import numpy as np
from numpy.typing import ArrayLike, NDArray

from triplesumo.evaluation.stats import mean_interval, wilson_interval

__all__ = [
    "LOCAL_WINNING_RATE",
    "OUTCOMES",
    "Outcome",
    "PAPER_TEST_MWR",
    "Summary",
    "full_window_mask",
    "local_winning_rate",
    "moving_winning_rate",
    "rolling_mean",
    "rolling_steps_to_win",
    "summarize",
]

Outcome = Literal["win", "loss", "draw", "error"]
"""Outcome of one epoch from the learner's team's point of view."""

OUTCOMES: Final[tuple[str, ...]] = ("win", "loss", "draw", "error")
"""All valid outcomes: won, lost, step limit reached, truncated by a physics error."""

LOCAL_WINNING_RATE: Final[dict[str, float]] = {
    "win": 1.0,
    "loss": -1.0,
    "draw": 0.0,
    "error": 0.0,
}
"""Local winning rate of each outcome; an ``"error"`` epoch counts as a draw (0)."""

PAPER_TEST_MWR: Final[tuple[float, float]] = (0.15, 0.47)
"""The paper's band for its DDPG Bug's MWR in testing: it stays between these (Wang, Das & Millard, 2022)."""


def _check_window(window: int) -> int:
    """Return ``window`` as an ``int`` >= 1; errors name it."""
    if isinstance(window, bool) or not isinstance(window, int | np.integer):
        raise TypeError(f"window must be an integer >= 1, got {window!r}")
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    return int(window)


def _as_1d(x: ArrayLike, name: str) -> NDArray[np.float64]:
    """Convert ``x`` to a one-dimensional float64 array or raise a ``ValueError``."""
    try:
        values = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from exc
    if values.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {values.shape}")
    return values


def _outcome_array(outcomes: Iterable[str]) -> NDArray[np.str_]:
    """Validate outcomes and return them as a string array."""
    values = [str(o) for o in outcomes]
    unknown = sorted(set(values).difference(OUTCOMES))
    if unknown:
        raise ValueError(
            f"unknown outcome(s) {unknown}; expected one of {list(OUTCOMES)}"
        )
    return np.asarray(values, dtype=np.str_)


def _lwr(kinds: NDArray[np.str_]) -> NDArray[np.float64]:
    """Map validated outcomes to local winning rates via :data:`LOCAL_WINNING_RATE`."""
    lwr = np.zeros(kinds.size, dtype=np.float64)
    for outcome, value in LOCAL_WINNING_RATE.items():
        lwr[kinds == outcome] = value
    return lwr


def _window_sums(x: NDArray[np.float64], window: int) -> NDArray[np.float64]:
    """Sum of ``x`` over the last ``window`` entries up to each index (partial at start)."""
    csum = np.concatenate(([0.0], np.cumsum(x)))
    idx = np.arange(1, x.size + 1)
    return csum[idx] - csum[np.maximum(idx - window, 0)]


def full_window_mask(n: int, window: int) -> NDArray[np.bool_]:
    """Which of ``n`` epochs have a full window of ``window`` epochs behind them.

    Args:
        n: Number of epochs (>= 0).
        window: Window length λ (>= 1).

    Returns:
        Boolean array of length ``n``: ``False`` for the first ``window - 1`` epochs
        (α < λ − 1, zero-based), ``True`` from epoch ``window - 1`` on.

    Raises:
        TypeError: If ``n`` or ``window`` is not an integer.
        ValueError: If ``n < 0`` or ``window < 1``.
    """
    w = _check_window(window)
    if isinstance(n, bool) or not isinstance(n, int | np.integer):
        raise TypeError(f"n must be an integer >= 0, got {n!r}")
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    return np.arange(int(n)) >= w - 1


def local_winning_rate(outcomes: Sequence[str]) -> NDArray[np.float64]:
    """Local winning rate of each epoch: win +1, loss −1, draw 0, error 0.

    Args:
        outcomes: One outcome per epoch, each one of :data:`OUTCOMES`.

    Returns:
        Float array of the same length with values in {−1, 0, +1}.

    Raises:
        ValueError: If an outcome is not one of :data:`OUTCOMES`; the message names it.
    """
    return _lwr(_outcome_array(outcomes))


def rolling_mean(
    x: ArrayLike, window: int = 200, *, partial: bool = True
) -> NDArray[np.float64]:
    """Trailing mean of ``x`` over the last ``window`` epochs up to each epoch.

    Used for reward curves; the first ``window - 1`` epochs are treated as in
    :func:`moving_winning_rate`.

    Args:
        x: One value per epoch; one-dimensional and finite.
        window: Window length λ (>= 1); 200 as in the paper.
        partial: If ``True`` (default), epoch α < λ − 1 gets the mean of epochs
            ``0..α``; if ``False`` it gets NaN.

    Returns:
        Float array of the same length as ``x``.

    Raises:
        TypeError: If ``window`` is not an integer.
        ValueError: If ``window < 1``, or ``x`` is not one-dimensional or holds
            non-finite values (a NaN would poison every later cumulative sum).
    """
    w = _check_window(window)
    values = _as_1d(x, "x")
    if not np.all(np.isfinite(values)):
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise ValueError(f"x must be finite; epoch index {bad} holds {values[bad]}")
    counts = np.minimum(np.arange(1, values.size + 1), w).astype(np.float64)
    out = _window_sums(values, w) / counts
    if not partial:
        out[: w - 1] = np.nan
    return out


def moving_winning_rate(
    lwr: ArrayLike, window: int = 200, *, partial: bool = True
) -> NDArray[np.float64]:
    """Moving winning rate (MWR): trailing mean of the local winning rate.

    MWR at epoch α = (sum of lwr over the last λ epochs up to α) / λ. For α < λ − 1
    fewer than λ epochs exist: with ``partial=True`` (default) the sum is divided by
    the number of epochs so far (α + 1), with ``partial=False`` the value is NaN.

    Args:
        lwr: Local winning rate per epoch (see :func:`local_winning_rate`), values in
            [−1, 1].
        window: Window length λ (>= 1); 200 as in the paper.
        partial: How to treat the first λ − 1 epochs (see above).

    Returns:
        Float array of the same length as ``lwr`` with values in [−1, 1] (or NaN).

    Raises:
        TypeError: If ``window`` is not an integer.
        ValueError: If ``window < 1``, or ``lwr`` is not one-dimensional or holds a
            value outside [−1, 1].
    """
    values = _as_1d(lwr, "lwr")
    if not np.all((values >= -1.0) & (values <= 1.0)):
        bad = int(np.flatnonzero(~((values >= -1.0) & (values <= 1.0)))[0])
        raise ValueError(
            f"lwr values must lie in [-1, 1]; epoch index {bad} holds {values[bad]}"
        )
    return rolling_mean(values, window, partial=partial)


def rolling_steps_to_win(
    steps: ArrayLike, outcomes: Sequence[str], window: int = 200
) -> NDArray[np.float64]:
    """Mean steps needed to win over the epochs won within the last ``window`` epochs.

    At epoch α the window is epochs ``max(0, α − λ + 1)..α`` (partial at the start);
    the value is the mean of ``steps`` over the epochs of that window whose outcome is
    ``"win"``, and NaN if none was won. Steps of epochs that were not won are ignored
    (they may even be NaN).

    Args:
        steps: Number of steps each epoch lasted.
        outcomes: Outcome of each epoch, one of :data:`OUTCOMES`.
        window: Window length λ (>= 1); 200 as in the paper.

    Returns:
        Float array of the same length as ``steps``.

    Raises:
        TypeError: If ``window`` is not an integer.
        ValueError: If ``window < 1``, the lengths differ, an outcome is unknown, or a
            won epoch has a non-finite step count.
    """
    w = _check_window(window)
    values = _as_1d(steps, "steps")
    kinds = _outcome_array(outcomes)
    if kinds.size != values.size:
        raise ValueError(
            f"steps and outcomes must have the same length, got {values.size} and {kinds.size}"
        )
    won = kinds == "win"
    if not np.all(np.isfinite(values[won])):
        raise ValueError("steps must be finite for every won epoch")
    wins_in_window = _window_sums(won.astype(np.float64), w)
    steps_in_window = _window_sums(np.where(won, values, 0.0), w)
    out = np.full(values.size, np.nan)
    has_win = wins_in_window > 0.5  # counts are whole numbers; avoid float equality
    out[has_win] = steps_in_window[has_win] / wins_in_window[has_win]
    return out


class Summary(TypedDict):
    """Flat summary of a run (one row of a results table), see :func:`summarize`."""

    n: int
    """Number of epochs, errors included."""
    n_win: int
    """Epochs won."""
    n_loss: int
    """Epochs lost."""
    n_draw: int
    """Epochs that reached the step limit without a result."""
    n_error: int
    """Epochs truncated by a physics error."""
    win_rate: float
    """``n_win / n`` (NaN when ``n == 0``)."""
    loss_rate: float
    """``n_loss / n``."""
    draw_rate: float
    """``n_draw / n``."""
    error_rate: float
    """``n_error / n``."""
    win_rate_lo: float
    """Lower bound of the Wilson interval of ``win_rate``."""
    win_rate_hi: float
    """Upper bound of the Wilson interval of ``win_rate``."""
    loss_rate_lo: float
    """Lower bound of the Wilson interval of ``loss_rate``."""
    loss_rate_hi: float
    """Upper bound of the Wilson interval of ``loss_rate``."""
    draw_rate_lo: float
    """Lower bound of the Wilson interval of ``draw_rate``."""
    draw_rate_hi: float
    """Upper bound of the Wilson interval of ``draw_rate``."""
    mean_lwr: float
    """Mean local winning rate (the MWR over the whole run)."""
    mean_lwr_lo: float
    """Lower bound of the normal-approximation interval of ``mean_lwr``."""
    mean_lwr_hi: float
    """Upper bound of the normal-approximation interval of ``mean_lwr``."""
    mean_steps_to_win: float
    """Mean steps of the won epochs (NaN if none was won)."""


def summarize(
    outcomes: Sequence[str], steps: ArrayLike, confidence: float = 0.95
) -> Summary:
    """Counts, rates and confidence intervals of a run.

    Rates are over all ``n`` epochs, physics errors included (consistent with the MWR,
    where an error epoch counts 0 but stays in the window). Win, loss and draw rates
    get Wilson intervals; the mean local winning rate gets a normal-approximation
    interval (:func:`~triplesumo.evaluation.stats.mean_interval`).

    Args:
        outcomes: Outcome of each epoch, one of :data:`OUTCOMES`.
        steps: Number of steps each epoch lasted (only won epochs are used).
        confidence: Confidence level of the intervals; 0.95 by default.

    Returns:
        A flat :class:`Summary` dict (see its fields), ready for a CSV row or JSON.

    Raises:
        ValueError: If an outcome is unknown, the lengths differ, or a won epoch has a
            non-finite step count.
    """
    kinds = _outcome_array(outcomes)
    values = _as_1d(steps, "steps")
    if kinds.size != values.size:
        raise ValueError(
            f"steps and outcomes must have the same length, got {values.size} and {kinds.size}"
        )
    n = int(kinds.size)
    counts = {o: int(np.count_nonzero(kinds == o)) for o in OUTCOMES}

    def rate(k: int) -> float:
        return k / n if n else math.nan

    win_steps = values[kinds == "win"]
    if not np.all(np.isfinite(win_steps)):
        raise ValueError("steps must be finite for every won epoch")
    win_lo, win_hi = wilson_interval(counts["win"], n, confidence)
    loss_lo, loss_hi = wilson_interval(counts["loss"], n, confidence)
    draw_lo, draw_hi = wilson_interval(counts["draw"], n, confidence)
    mean_lwr, lwr_lo, lwr_hi = mean_interval(_lwr(kinds), confidence)
    return Summary(
        n=n,
        n_win=counts["win"],
        n_loss=counts["loss"],
        n_draw=counts["draw"],
        n_error=counts["error"],
        win_rate=rate(counts["win"]),
        loss_rate=rate(counts["loss"]),
        draw_rate=rate(counts["draw"]),
        error_rate=rate(counts["error"]),
        win_rate_lo=win_lo,
        win_rate_hi=win_hi,
        loss_rate_lo=loss_lo,
        loss_rate_hi=loss_hi,
        draw_rate_lo=draw_lo,
        draw_rate_hi=draw_hi,
        mean_lwr=mean_lwr,
        mean_lwr_lo=lwr_lo,
        mean_lwr_hi=lwr_hi,
        mean_steps_to_win=float(win_steps.mean()) if win_steps.size else math.nan,
    )
