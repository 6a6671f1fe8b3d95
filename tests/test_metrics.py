"""Tests of the evaluation metrics and confidence intervals on hand-made sequences."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from triplesumo.evaluation import (
    OUTCOMES,
    full_window_mask,
    local_winning_rate,
    mean_interval,
    moving_winning_rate,
    rolling_mean,
    rolling_steps_to_win,
    summarize,
    wilson_interval,
)

SRC = Path(__file__).resolve().parents[1] / "src"


# --------------------------------------------------------------------------- local winning rate


def test_outcomes_are_the_four_documented_ones() -> None:
    assert OUTCOMES == ("win", "loss", "draw", "error")


def test_local_winning_rate_mapping() -> None:
    lwr = local_winning_rate(["win", "loss", "draw", "error", "win"])
    np.testing.assert_array_equal(lwr, [1.0, -1.0, 0.0, 0.0, 1.0])
    assert lwr.dtype == np.float64


def test_local_winning_rate_accepts_numpy_strings_and_empty() -> None:
    np.testing.assert_array_equal(local_winning_rate(np.array(["loss", "win"])), [-1.0, 1.0])
    assert local_winning_rate([]).shape == (0,)


def test_local_winning_rate_unknown_outcome_is_named() -> None:
    with pytest.raises(ValueError, match="'tie'"):
        local_winning_rate(["win", "tie"])


# --------------------------------------------------------------------------- MWR


def test_mwr_at_window_edges() -> None:
    # epochs:       0     1       2       3       4
    lwr = np.array([1.0, -1.0, 1.0, 1.0, 0.0])
    mwr = moving_winning_rate(lwr, window=3)
    # α = 0, 1 (< λ - 1): mean over the partial window.
    assert mwr[0] == pytest.approx(1.0)
    assert mwr[1] == pytest.approx(0.0)
    # α = λ - 1 = 2: first full window, epochs 0..2.
    assert mwr[2] == pytest.approx(1.0 / 3.0)
    # α = λ = 3: epochs 1..3; epoch 0 has left the window.
    assert mwr[3] == pytest.approx(1.0 / 3.0)
    # α = λ + 1 = 4: epochs 2..4.
    assert mwr[4] == pytest.approx(2.0 / 3.0)


def test_mwr_partial_false_is_nan_before_first_full_window() -> None:
    lwr = np.array([1.0, -1.0, 1.0, 1.0, 0.0])
    full = moving_winning_rate(lwr, window=3, partial=False)
    assert np.isnan(full[:2]).all()
    np.testing.assert_allclose(full[2:], moving_winning_rate(lwr, window=3)[2:])
    np.testing.assert_array_equal(full_window_mask(5, 3), [False, False, True, True, True])
    np.testing.assert_array_equal(~np.isnan(full), full_window_mask(5, 3))


def test_mwr_window_longer_than_run() -> None:
    lwr = local_winning_rate(["win", "loss", "win"])
    np.testing.assert_allclose(moving_winning_rate(lwr, window=200), [1.0, 0.0, 1.0 / 3.0])
    assert np.isnan(moving_winning_rate(lwr, window=200, partial=False)).all()


def test_mwr_window_one_is_the_lwr_itself() -> None:
    lwr = np.array([1.0, 0.0, -1.0, 1.0])
    np.testing.assert_array_equal(moving_winning_rate(lwr, window=1, partial=False), lwr)


def test_mwr_validation() -> None:
    with pytest.raises(ValueError, match="window"):
        moving_winning_rate([1.0, 0.0], window=0)
    with pytest.raises(TypeError, match="window"):
        moving_winning_rate([1.0, 0.0], window=2.5)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        moving_winning_rate([1.0, 2.0], window=2)
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        moving_winning_rate([1.0, math.nan], window=2)
    with pytest.raises(ValueError, match="one-dimensional"):
        moving_winning_rate([[1.0]], window=1)


def test_full_window_mask_validation() -> None:
    assert full_window_mask(0, 5).shape == (0,)
    with pytest.raises(ValueError, match="n must be"):
        full_window_mask(-1, 3)
    with pytest.raises(ValueError, match="window"):
        full_window_mask(3, 0)


# --------------------------------------------------------------------------- rolling mean


def _naive_rolling_mean(x: np.ndarray, window: int) -> np.ndarray:
    return np.array([x[max(0, i - window + 1) : i + 1].mean() for i in range(x.size)])


@pytest.mark.parametrize("window", [1, 2, 7, 50, 400])
def test_rolling_mean_equals_naive_loop(window: int) -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(loc=-30.0, scale=500.0, size=300)
    np.testing.assert_allclose(rolling_mean(x, window), _naive_rolling_mean(x, window), rtol=1e-9, atol=1e-9)
    strict = rolling_mean(x, window, partial=False)
    mask = full_window_mask(x.size, window)
    assert np.isnan(strict[~mask]).all()
    np.testing.assert_allclose(strict[mask], _naive_rolling_mean(x, window)[mask], rtol=1e-9, atol=1e-9)


def test_rolling_mean_rejects_non_finite_and_names_epoch() -> None:
    with pytest.raises(ValueError, match="index 2"):
        rolling_mean([1.0, 2.0, math.inf], window=2)


# --------------------------------------------------------------------------- steps to win


def test_steps_to_win_counts_only_wins_and_is_nan_without_wins() -> None:
    outcomes = ["loss", "win", "draw", "win", "loss", "error", "draw", "loss"]
    steps = [40.0, 100.0, 500.0, 200.0, 30.0, 7.0, 500.0, 20.0]
    got = rolling_steps_to_win(steps, outcomes, window=3)
    expected = [
        math.nan,  # [loss]
        100.0,  # [loss, win]
        100.0,  # [loss, win, draw]
        150.0,  # [win, draw, win]
        200.0,  # [draw, win, loss]
        200.0,  # [win, loss, error]
        math.nan,  # [loss, error, draw]
        math.nan,  # [error, draw, loss]
    ]
    np.testing.assert_allclose(got, expected, equal_nan=True)


def test_steps_to_win_ignores_steps_of_non_wins_even_nan() -> None:
    got = rolling_steps_to_win([math.nan, 10.0, math.nan], ["loss", "win", "draw"], window=2)
    np.testing.assert_allclose(got, [math.nan, 10.0, 10.0], equal_nan=True)


def test_steps_to_win_validation() -> None:
    with pytest.raises(ValueError, match="same length"):
        rolling_steps_to_win([1.0, 2.0], ["win"], window=2)
    with pytest.raises(ValueError, match="'lost'"):
        rolling_steps_to_win([1.0], ["lost"], window=2)
    with pytest.raises(ValueError, match="finite"):
        rolling_steps_to_win([math.nan], ["win"], window=2)
    with pytest.raises(ValueError, match="window"):
        rolling_steps_to_win([1.0], ["win"], window=0)


# --------------------------------------------------------------------------- summarize


def test_summarize_counts_rates_and_intervals() -> None:
    outcomes = ["win"] * 5 + ["loss"] * 3 + ["draw"] * 1 + ["error"] * 1
    steps = [100.0, 200.0, 300.0, 400.0, 500.0] + [50.0] * 3 + [500.0] + [12.0]
    s = summarize(outcomes, steps)
    assert (s["n"], s["n_win"], s["n_loss"], s["n_draw"], s["n_error"]) == (10, 5, 3, 1, 1)
    assert s["win_rate"] == pytest.approx(0.5)
    assert s["loss_rate"] == pytest.approx(0.3)
    assert s["draw_rate"] == pytest.approx(0.1)
    assert s["error_rate"] == pytest.approx(0.1)
    assert s["mean_steps_to_win"] == pytest.approx(300.0)
    assert (s["win_rate_lo"], s["win_rate_hi"]) == pytest.approx(wilson_interval(5, 10))
    assert (s["loss_rate_lo"], s["loss_rate_hi"]) == pytest.approx(wilson_interval(3, 10))
    assert (s["draw_rate_lo"], s["draw_rate_hi"]) == pytest.approx(wilson_interval(1, 10))
    assert s["mean_lwr"] == pytest.approx(0.2)
    assert s["mean_lwr_lo"] < 0.2 < s["mean_lwr_hi"]


def test_summarize_without_wins_and_without_epochs() -> None:
    s = summarize(["loss", "draw"], [10.0, 500.0])
    assert math.isnan(s["mean_steps_to_win"])
    assert s["win_rate"] == 0.0
    assert s["win_rate_lo"] == 0.0
    empty = summarize([], [])
    assert empty["n"] == 0
    assert math.isnan(empty["win_rate"])
    assert math.isnan(empty["win_rate_lo"])
    assert math.isnan(empty["mean_lwr"])


def test_summarize_validation() -> None:
    with pytest.raises(ValueError, match="same length"):
        summarize(["win"], [1.0, 2.0])
    with pytest.raises(ValueError, match="'bye'"):
        summarize(["bye"], [1.0])


# --------------------------------------------------------------------------- stats


def test_wilson_known_values() -> None:
    lo, hi = wilson_interval(50, 100)
    assert lo == pytest.approx(0.4038, abs=1e-3)
    assert hi == pytest.approx(0.5962, abs=1e-3)
    # 1 success in 10 at 95 %: (0.0179, 0.4042), a textbook value.
    lo, hi = wilson_interval(1, 10)
    assert (lo, hi) == pytest.approx((0.0179, 0.4042), abs=1e-3)


def test_wilson_bounds_at_the_extremes() -> None:
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0
    assert 0.0 < hi < 1.0
    assert hi == pytest.approx(0.2775, abs=1e-3)
    lo, hi = wilson_interval(10, 10)
    assert hi == 1.0
    assert lo == pytest.approx(1.0 - 0.2775, abs=1e-3)


def test_wilson_wider_with_higher_confidence_and_nan_without_data() -> None:
    lo95, hi95 = wilson_interval(30, 100, 0.95)
    lo99, hi99 = wilson_interval(30, 100, 0.99)
    assert lo99 < lo95 < 0.3 < hi95 < hi99
    lo, hi = wilson_interval(0, 0)
    assert math.isnan(lo) and math.isnan(hi)
    assert wilson_interval(np.int64(3), np.int64(4)) == wilson_interval(3, 4)


@pytest.mark.parametrize(
    ("args", "error", "pattern"),
    [
        ((11, 10), ValueError, "successes must be <= n"),
        ((-1, 10), ValueError, "successes"),
        ((1, -10), ValueError, "n must be"),
        ((1.5, 10), TypeError, "successes"),
        ((True, 10), TypeError, "successes"),
        ((1, 10, 1.0), ValueError, "confidence"),
        ((1, 10, 0.0), ValueError, "confidence"),
        ((1, 10, "95%"), TypeError, "confidence"),
    ],
)
def test_wilson_validation(args: tuple[object, ...], error: type[Exception], pattern: str) -> None:
    with pytest.raises(error, match=pattern):
        wilson_interval(*args)  # type: ignore[arg-type]


def test_mean_interval() -> None:
    x = np.array([1.0, -1.0, 0.0, 1.0, 1.0, 0.0, -1.0, 1.0])
    mean, lo, hi = mean_interval(x)
    half = 1.959964 * x.std(ddof=1) / math.sqrt(x.size)
    assert mean == pytest.approx(0.25)
    assert (lo, hi) == pytest.approx((0.25 - half, 0.25 + half), rel=1e-6)
    one = mean_interval([0.5])
    assert one[0] == 0.5 and math.isnan(one[1]) and math.isnan(one[2])
    assert all(math.isnan(v) for v in mean_interval([]))
    with pytest.raises(ValueError, match="finite"):
        mean_interval([1.0, math.nan])
    with pytest.raises(ValueError, match="confidence"):
        mean_interval([1.0, 2.0], confidence=1.5)


# --------------------------------------------------------------------------- import hygiene


def test_metrics_import_no_heavy_frameworks() -> None:
    code = (
        "import sys, triplesumo.evaluation, triplesumo.evaluation.metrics, "
        "triplesumo.evaluation.stats\n"
        # gymnasium is imported by `import triplesumo` to register the env ids; nothing heavier is.
        "bad = sorted({'torch', 'pettingzoo', 'matplotlib', 'mujoco'} & set(sys.modules))\n"
        "assert not bad, bad\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code],
        env={"PYTHONPATH": str(SRC)},
        capture_output=True,
        text=True,
        check=False,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
