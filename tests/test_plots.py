"""Tests of the metrics CSV reader and the figure writers on synthetic runs."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from triplesumo.evaluation import local_winning_rate
from triplesumo.evaluation.metrics import PAPER_TEST_MWR
from triplesumo.evaluation.plots import (
    EVALUATION_COLUMNS,
    REQUIRED_COLUMNS,
    plot_comparison,
    plot_evaluations,
    plot_run,
    read_evaluations_csv,
    read_metrics_csv,
)
from triplesumo.train.logger import EVAL_COLUMNS

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
TERMS = (
    "reward_opponent_velocity",
    "reward_self_velocity",
    "reward_partner_velocity",
    "reward_still",
    "reward_outcome",
)


def _synthetic_run(n: int, seed: int, p_win: float = 0.4) -> dict[str, np.ndarray]:
    """A run whose rewards obey total = dense + sparse and dense = sum of velocity terms."""
    rng = np.random.default_rng(seed)
    p_loss = (1.0 - p_win) * 0.6
    outcome = rng.choice(
        ["win", "loss", "draw", "error"],
        size=n,
        p=[p_win, p_loss, 1.0 - p_win - p_loss - 0.01, 0.01],
    )
    steps = np.where(outcome == "draw", 500.0, rng.integers(20, 500, size=n).astype(float))
    terms = {
        "reward_opponent_velocity": rng.normal(5.0, 3.0, n),
        "reward_self_velocity": rng.normal(2.0, 2.0, n),
        "reward_partner_velocity": rng.normal(1.0, 2.0, n),
        "reward_still": -4.0 * steps / 100.0,
        "reward_outcome": np.select([outcome == "win", outcome == "loss"], [500.0, -400.0], 0.0),
    }
    dense = sum(v for k, v in terms.items() if k != "reward_outcome")
    sparse = terms["reward_outcome"]
    return {
        "epoch": np.arange(n, dtype=float),
        "outcome": outcome.astype(np.str_),
        "local_winning_rate": local_winning_rate(list(outcome)),
        "steps": steps,
        "total_reward": dense + sparse,
        "dense_reward": dense,
        "sparse_reward": sparse,
        **terms,
    }


def _write_csv(path: Path, run: dict[str, np.ndarray], drop: str | None = None) -> None:
    names = [c for c in run if c != drop]
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(names)
        for i in range(run["epoch"].size):
            writer.writerow([run[c][i] if c == "outcome" else repr(float(run[c][i])) for c in names])


def _assert_real_png(path: Path) -> None:
    assert path.is_file(), path
    assert path.read_bytes()[:8] == PNG_SIGNATURE, path
    image = imread(path)
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
    assert float(image.std()) > 0.0, f"{path} is a single colour"


@pytest.fixture(scope="module")
def run() -> dict[str, np.ndarray]:
    return _synthetic_run(240, seed=1)


def test_csv_round_trip(tmp_path: Path, run: dict[str, np.ndarray]) -> None:
    path = tmp_path / "metrics.csv"
    _write_csv(path, run)
    got = read_metrics_csv(path)
    assert list(got) == list(run)
    for name in REQUIRED_COLUMNS:
        assert got[name].shape == (240,)
    assert got["outcome"].dtype.kind == "U"
    np.testing.assert_array_equal(got["outcome"], run["outcome"])
    for name in run:
        if name != "outcome":
            assert got[name].dtype == np.float64
            np.testing.assert_array_equal(got[name], run[name])


def test_csv_extra_columns_and_empty_cells(tmp_path: Path) -> None:
    path = tmp_path / "metrics.csv"
    header = [*REQUIRED_COLUMNS, "reward_still", "agent", "seed"]
    path.write_text(
        ",".join(header) + "\n"
        "0,win,1,120,480,-20,500,,bug,7\n"
        "1,draw,0,500,-80,-80,0,-20,bug,7\n",
        encoding="utf-8",
    )
    got = read_metrics_csv(path)
    assert np.isnan(got["reward_still"][0]) and got["reward_still"][1] == -20.0
    assert got["agent"].dtype.kind == "U"
    np.testing.assert_array_equal(got["seed"], [7.0, 7.0])


def test_csv_missing_column_is_named(tmp_path: Path, run: dict[str, np.ndarray]) -> None:
    path = tmp_path / "broken.csv"
    _write_csv(path, run, drop="dense_reward")
    with pytest.raises(ValueError, match="dense_reward") as info:
        read_metrics_csv(path)
    assert "broken.csv" in str(info.value)


@pytest.mark.parametrize(
    ("body", "pattern"),
    [
        ("", "empty file"),
        (",".join(REQUIRED_COLUMNS) + "\n0,win,1,120,480,-20\n", "line 2: expected 7 fields"),
        (",".join(REQUIRED_COLUMNS) + "\n0,win,1,many,480,-20,500\n", "line 2: column 'steps'"),
        (",".join(REQUIRED_COLUMNS) + "\n0,won,1,120,480,-20,500\n", "line 2: unknown outcome 'won'"),
    ],
)
def test_csv_schema_errors_name_file_and_line(tmp_path: Path, body: str, pattern: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(body, encoding="utf-8")
    with pytest.raises(ValueError, match=pattern) as info:
        read_metrics_csv(path)
    assert "bad.csv" in str(info.value)


def test_plot_run_writes_four_real_pngs(tmp_path: Path, run: dict[str, np.ndarray]) -> None:
    csv_path = tmp_path / "metrics.csv"
    _write_csv(csv_path, run)
    out = tmp_path / "new" / "plots"  # created on demand
    paths = plot_run(read_metrics_csv(csv_path), out, window=50, title="training", label="Bug")
    assert [p.name for p in paths] == [
        "rewards.png",
        "reward_terms.png",
        "mwr.png",
        "steps_to_win.png",
    ]
    for path in paths:
        assert path.parent == out
        _assert_real_png(path)


def test_plot_run_without_terms_or_wins(tmp_path: Path) -> None:
    run = _synthetic_run(60, seed=2, p_win=0.0)
    minimal = {name: run[name] for name in REQUIRED_COLUMNS}
    paths = plot_run(minimal, tmp_path, window=10)
    assert len(paths) == 4
    for path in paths:
        _assert_real_png(path)


def test_plot_run_missing_column_is_named(tmp_path: Path, run: dict[str, np.ndarray]) -> None:
    broken = {k: v for k, v in run.items() if k != "sparse_reward"}
    with pytest.raises(ValueError, match="sparse_reward"):
        plot_run(broken, tmp_path / "plots", window=20)
    assert not (tmp_path / "plots").exists()  # nothing written before validation


def test_plot_run_unwritable_folder_is_named(tmp_path: Path, run: dict[str, np.ndarray]) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder", encoding="utf-8")
    target = blocker / "plots"
    with pytest.raises(OSError, match="cannot write plots to folder") as info:
        plot_run(run, target, window=20)
    assert str(target) in str(info.value)


def test_plot_comparison_writes_both_files(tmp_path: Path, run: dict[str, np.ndarray]) -> None:
    curves = {
        "trained Bug": run,
        "passive": _synthetic_run(240, seed=3, p_win=0.1),
        "random": {  # no epoch column, shorter run
            k: v[:150] for k, v in _synthetic_run(240, seed=4, p_win=0.2).items() if k != "epoch"
        },
    }
    paths = plot_comparison(curves, tmp_path / "compare", window=30)
    assert [p.name for p in paths] == ["compare_mwr.png", "compare_rewards.png"]
    for path in paths:
        _assert_real_png(path)


def test_plot_comparison_validation(tmp_path: Path, run: dict[str, np.ndarray]) -> None:
    with pytest.raises(ValueError, match="empty"):
        plot_comparison({}, tmp_path)
    broken = {k: v for k, v in run.items() if k != "total_reward"}
    with pytest.raises(ValueError, match=r"run 'random'.*total_reward"):
        plot_comparison({"trained": run, "random": broken}, tmp_path)


def _write_evaluations(path: Path, mwrs: list[float], drop: str | None = None) -> None:
    """An ``eval.csv`` as a training run writes it (an evaluation every 100,000 env steps on 200 matches)."""
    columns = [c for c in EVAL_COLUMNS if c != drop]
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, columns, extrasaction="ignore")
        writer.writeheader()
        for k, mwr in enumerate(mwrs, 1):
            writer.writerow({"evaluation": k, "env_steps": 100_000 * k, "epochs": 600 * k, "policy_train_seconds": "",
                             "train_seconds": 300.0 * k, "eval_seconds": 60.0, "test_matches": 200, "test_mwr": mwr,
                             "test_mwr_lo": mwr - 0.12, "test_mwr_hi": mwr + 0.12, "n_win": 0, "n_loss": 0,
                             "n_draw": 0})


def test_evaluations_are_read_as_a_run_writes_them_and_drawn_against_the_band(tmp_path: Path) -> None:
    assert set(EVALUATION_COLUMNS) <= set(EVAL_COLUMNS)
    _write_evaluations(tmp_path / "eval.csv", [-0.3, -0.1, 0.2, 0.35])
    columns = read_evaluations_csv(tmp_path / "eval.csv")
    assert columns["env_steps"].tolist() == [100_000, 200_000, 300_000, 400_000]
    assert columns["test_mwr"].tolist() == [-0.3, -0.1, 0.2, 0.35]
    assert np.isnan(columns["policy_train_seconds"]).all()  # an empty cell (a row from before the column)
    _write_evaluations(tmp_path / "other.csv", [-0.5, 0.0])
    runs = {"seed 0": columns, "seed 1": read_evaluations_csv(tmp_path / "other.csv")}
    with_band = plot_evaluations(runs, tmp_path / "new" / "test_mwr.png", title="pair 1")
    without = plot_evaluations(runs, tmp_path / "bare.png", band=None)
    for path in (with_band, without):
        _assert_real_png(path)
    assert with_band == tmp_path / "new" / "test_mwr.png"
    assert not np.array_equal(imread(with_band), imread(without))  # the paper's band is drawn
    assert PAPER_TEST_MWR == (0.15, 0.47)


def test_evaluations_of_one_group_share_a_colour_and_a_legend_entry(tmp_path: Path) -> None:
    for k, mwrs in enumerate(([-0.3, 0.1, 0.4], [-0.2, 0.0, 0.3], [-0.6, -0.5, -0.4])):
        _write_evaluations(tmp_path / f"{k}.csv", mwrs)
    runs = {f"seed {k}": read_evaluations_csv(tmp_path / f"{k}.csv") for k in range(3)}
    grouped = plot_evaluations(runs, tmp_path / "grouped.png", band=None,
                               groups={"seed 0": "sac", "seed 1": "sac", "seed 2": "ddpg"})
    own = plot_evaluations(runs, tmp_path / "own.png", band=None)
    skill = plot_evaluations(runs, tmp_path / "skill.png", band=None, reference=0.2,
                             groups={"seed 0": "sac", "seed 1": "sac", "seed 2": "ddpg"})
    for path in (grouped, own, skill):
        _assert_real_png(path)
    # seed 1 takes seed 0's colour (not a colour of its own), and the +0.2 line is drawn
    assert not np.array_equal(imread(grouped), imread(own))
    assert not np.array_equal(imread(grouped), imread(skill))
    with pytest.raises(ValueError, match=r"no group for run\(s\) \['seed 2'\]"):
        plot_evaluations(runs, tmp_path / "x.png", groups={"seed 0": "sac", "seed 1": "sac"})
    assert not (tmp_path / "x.png").exists()


def test_bad_evaluations_are_named(tmp_path: Path) -> None:
    _write_evaluations(tmp_path / "eval.csv", [0.1], drop="test_mwr_hi")
    with pytest.raises(ValueError, match=r"eval\.csv: missing column\(s\) \['test_mwr_hi'\]"):
        read_evaluations_csv(tmp_path / "eval.csv")
    empty = {name: np.zeros(0) for name in EVALUATION_COLUMNS}
    with pytest.raises(ValueError, match="evaluations of seed 3: no evaluation"):
        plot_evaluations({"seed 3": empty}, tmp_path / "x.png")
    nan = {name: np.array([1.0, np.nan]) if name == "test_mwr" else np.ones(2) for name in EVALUATION_COLUMNS}
    with pytest.raises(ValueError, match=r"evaluations of s: column\(s\) \['test_mwr'\] hold non-finite"):
        plot_evaluations({"s": nan}, tmp_path / "x.png")
    with pytest.raises(ValueError, match="no run"):
        plot_evaluations({}, tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_a_comparison_of_runs_named_by_long_paths_keeps_its_axes_and_its_legend_on_the_figure(
        tmp_path: Path, run: dict[str, np.ndarray]) -> None:
    """evaluate names each curve by its candidate and absolute policy path (150+ characters): the legend goes below
    the axes with labels cut to LABEL_MAX, so neither squeezes the axes nor runs off the figure (it did both)."""
    from matplotlib.figure import Figure

    from triplesumo.evaluation import plots
    from triplesumo.evaluation.plots import LABEL_MAX, legend_label

    long = "bug trained-work-main-results-scratch-v4-seed-1-bug-learn-bug-sac-seed-{0}-policy " \
           "(/work/main/results/scratch-v4/seed-1/bug/learn=bug=sac,seed={0}/policy)"
    label = legend_label(long.format(4))
    assert len(label) == LABEL_MAX and label.startswith("bug trained-") and label.endswith("seed=4/policy)")
    assert legend_label("passive") == "passive"

    drawn: list[Figure] = []
    real_save = plots.save_figure

    def keep(fig: Figure, path: Path, dpi: int) -> Path:
        fig.draw_without_rendering()  # lay out as savefig does, then measure before the figure is cleared
        box = fig.bbox
        axes = fig.axes[0].get_window_extent()
        legend = fig.legends[0].get_window_extent()
        assert axes.width > 0.75 * box.width and axes.height > 0.45 * box.height, (path.name, axes, box)
        assert box.x0 <= legend.x0 and legend.x1 <= box.x1 and box.y0 <= legend.y0 and legend.y1 <= axes.y0, (
            path.name, legend, box)
        drawn.append(fig)
        return real_save(fig, path, dpi)

    curves = {long.format(s): _synthetic_run(240, seed=s) for s in range(5)}
    curves["bug passive (passive)"] = _synthetic_run(240, seed=9, p_win=0.1)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plots, "save_figure", keep)
        paths = plot_comparison(curves, tmp_path / "compare", window=30)
    assert len(drawn) == 2
    for path in paths:
        _assert_real_png(path)
