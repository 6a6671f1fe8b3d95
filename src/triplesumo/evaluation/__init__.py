"""Evaluation: the paper's metrics, their confidence intervals, and plots.

:mod:`~triplesumo.evaluation.metrics` and :mod:`~triplesumo.evaluation.stats` are pure
numpy and imported eagerly. :mod:`~triplesumo.evaluation.plots` needs matplotlib and is
imported only when one of its names is first used, so importing this package for the
metrics alone stays light. Nothing here imports torch, gymnasium or pettingzoo.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from triplesumo.evaluation.metrics import (
    OUTCOMES,
    Outcome,
    Summary,
    full_window_mask,
    local_winning_rate,
    moving_winning_rate,
    rolling_mean,
    rolling_steps_to_win,
    summarize,
)
from triplesumo.evaluation.stats import mean_interval, wilson_interval

if TYPE_CHECKING:
    from triplesumo.evaluation.plots import plot_comparison, plot_run, read_metrics_csv

__all__ = [
    "OUTCOMES",
    "Outcome",
    "Summary",
    "full_window_mask",
    "local_winning_rate",
    "mean_interval",
    "moving_winning_rate",
    "plot_comparison",
    "plot_run",
    "read_metrics_csv",
    "rolling_mean",
    "rolling_steps_to_win",
    "summarize",
    "wilson_interval",
]

_LAZY_PLOTS = frozenset({"plot_comparison", "plot_run", "read_metrics_csv"})


def __getattr__(name: str) -> Any:
    """Import the plotting functions (and matplotlib) on first use."""
    if name in _LAZY_PLOTS:
        plots = importlib.import_module("triplesumo.evaluation.plots")
        return getattr(plots, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
