"""Deprecated: the figures of tournaments are :mod:`triplesumo.evaluation.tournament_plots`.

This module re-exports its functions and warns once on import; it goes in a later release. (The league's own
figure, the pool over a training run, is :mod:`triplesumo.train.league_plots`.)
"""

from __future__ import annotations

import warnings

from triplesumo.evaluation.tournament_plots import plot_compare, plot_crossplay, plot_ladder, plot_leaderboard

__all__ = ["plot_compare", "plot_crossplay", "plot_ladder", "plot_leaderboard"]

warnings.warn("triplesumo.evaluation.league_plots is deprecated: import triplesumo.evaluation.tournament_plots "
              "(it draws tournaments and comparisons, not leagues)", DeprecationWarning, stacklevel=2)
