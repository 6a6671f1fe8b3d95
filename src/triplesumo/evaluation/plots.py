"""Read a run's metrics CSV and draw the paper's figures.

A metrics CSV has one row per epoch and at least the columns of
:data:`REQUIRED_COLUMNS`, plus any number of reward-term columns whose names start with
:data:`TERM_PREFIX` (``reward_opponent_velocity``, ``reward_still``, ...).

Figures are built with :class:`matplotlib.figure.Figure` directly, never through the
pyplot state machine, so plotting works under any Matplotlib backend (including ``Agg`` on a
headless machine), never opens a window and never changes Matplotlib's global backend. Each
figure is cleared once written.

All curves use the trailing window λ of :mod:`triplesumo.evaluation.metrics` with
partial windows at the start; the first λ − 1 epochs are shaded grey in every figure
so a reader can tell them apart.
"""

from __future__ import annotations

import csv
import errno
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Final

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from numpy.typing import NDArray

from triplesumo.evaluation.metrics import (
    OUTCOMES,
    PAPER_TEST_MWR,
    moving_winning_rate,
    rolling_mean,
    rolling_steps_to_win,
)
from triplesumo.evaluation.metrics_csv import open_table

__all__ = [
    "EVALUATION_COLUMNS",
    "REQUIRED_COLUMNS",
    "TERM_PREFIX",
    "plot_comparison",
    "plot_evaluations",
    "plot_run",
    "read_evaluations_csv",
    "read_metrics_csv",
]

REQUIRED_COLUMNS: Final[tuple[str, ...]] = (
    "epoch",
    "outcome",
    "local_winning_rate",
    "steps",
    "total_reward",
    "dense_reward",
    "sparse_reward",
)
"""Columns every metrics CSV must have."""

EVALUATION_COLUMNS: Final[tuple[str, ...]] = ("env_steps", "test_mwr", "test_mwr_lo", "test_mwr_hi")
"""Columns an evaluations CSV (a training run's ``eval.csv``) must have for :func:`plot_evaluations`."""

TERM_PREFIX: Final[str] = "reward_"
"""Prefix of the per-term reward columns (one column per named reward term)."""

_STRING_COLUMNS: Final[frozenset[str]] = frozenset({"outcome"})
_FIGSIZE: Final[tuple[float, float]] = (8.0, 4.5)
_DPI: Final[int] = 110
LABEL_MAX: Final[int] = 90
"""A comparison's legend labels are cut to this many characters (the middle elided): a run named by its
absolute policy path otherwise pushes the legend off the figure and squeezes the axes to a sliver."""
_LEGEND_ROW_INCHES: Final[float] = 0.22


# --------------------------------------------------------------------------- reading


def read_metrics_csv(path: str | os.PathLike[str]) -> dict[str, NDArray[np.generic]]:
    """Read a metrics CSV into one array per column.

    Required columns and ``reward_*`` columns become float64 arrays (an empty cell is
    NaN); ``outcome`` becomes a string array whose values are checked against
    :data:`~triplesumo.evaluation.metrics.OUTCOMES`. Any other column is float64 if
    every cell parses as a number, else a string array.

    Args:
        path: The CSV file.

    Returns:
        Column name -> array, in the file's column order, all of the same length.

    Raises:
        FileNotFoundError: If the file does not exist (plain, or packed as ``NAME.csv.gz``).
        ValueError: If the file is empty, lacks a required column (the message names
            the file and the missing columns), has a duplicate column, a row with the
            wrong number of fields, a non-numeric cell in a numeric column, or an
            unknown outcome (the message names the file and line).
    """
    return _read_columns(Path(path), REQUIRED_COLUMNS, f"plus optional '{TERM_PREFIX}*' terms")


def read_evaluations_csv(path: str | os.PathLike[str]) -> dict[str, NDArray[np.generic]]:
    """Read a run's evaluations while training (``eval.csv``, one row per evaluation) into one float64 array per
    column; it needs the columns of :data:`EVALUATION_COLUMNS`. Errors as :func:`read_metrics_csv`'s."""
    return _read_columns(Path(path), EVALUATION_COLUMNS, "one row per evaluation")


def _read_columns(source: Path, required: tuple[str, ...], rest: str) -> dict[str, NDArray[np.generic]]:
    """A CSV with the columns ``required`` (numbers) and any others, as :func:`read_metrics_csv` describes."""
    with open_table(source) as fh:  # plain or packed (metrics.csv.gz)
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise ValueError(
                f"{source}: empty file; expected a header with columns {list(required)}"
            )
        names = [h.strip() for h in header]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(f"{source}: duplicate column(s) {duplicates}")
        missing = [c for c in required if c not in names]
        if missing:
            raise ValueError(f"{source}: missing column(s) {missing}; required: {list(required)} {rest}")
        cells: dict[str, list[str]] = {n: [] for n in names}
        lines: list[int] = []
        for row in reader:
            if not row:
                continue
            if len(row) != len(names):
                raise ValueError(
                    f"{source}, line {reader.line_num}: expected {len(names)} fields, "
                    f"got {len(row)}"
                )
            lines.append(reader.line_num)
            for name, cell in zip(names, row, strict=True):
                cells[name].append(cell.strip())

    out: dict[str, NDArray[np.generic]] = {}
    for name in names:
        column = cells[name]
        if name in _STRING_COLUMNS:
            for line, value in zip(lines, column, strict=True):
                if value not in OUTCOMES:
                    raise ValueError(
                        f"{source}, line {line}: unknown {name} {value!r}; "
                        f"expected one of {list(OUTCOMES)}"
                    )
            out[name] = np.asarray(column, dtype=np.str_)
        elif name in required or name.startswith(TERM_PREFIX):
            out[name] = _parse_floats(column, name, lines, source)
        else:
            try:
                out[name] = _parse_floats(column, name, lines, source)
            except ValueError:
                out[name] = np.asarray(column, dtype=np.str_)
    return out


def _parse_floats(
    column: list[str], name: str, lines: list[int], source: Path
) -> NDArray[np.float64]:
    """Parse a column of cells as floats; an empty cell is NaN."""
    values = np.empty(len(column), dtype=np.float64)
    for i, cell in enumerate(column):
        if cell == "":
            values[i] = math.nan
            continue
        try:
            values[i] = float(cell)
        except ValueError:
            raise ValueError(
                f"{source}, line {lines[i]}: column {name!r} is not a number: {cell!r}"
            ) from None
    return values


# --------------------------------------------------------------------------- helpers


def _prepare_dir(out_dir: str | os.PathLike[str]) -> Path:
    """Create ``out_dir`` if needed and check it is writable; errors name the folder."""
    folder = Path(out_dir)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _folder_error(folder, exc) from exc
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PermissionError(
            errno.EACCES,
            f"cannot write plots to folder {folder}: not writable",
            str(folder),
        )
    return folder


def _folder_error(folder: Path, exc: OSError) -> OSError:
    """An ``OSError`` of the same kind as ``exc`` whose message names ``folder``."""
    reason = exc.strerror or str(exc)
    if exc.errno is None:
        return OSError(f"cannot write plots to folder {folder}: {reason}")
    # OSError(errno, ...) picks the matching subclass (PermissionError, ...).
    return OSError(exc.errno, f"cannot write plots to folder {folder}: {reason}")


def _title(prefix: str, what: str) -> str:
    """Figure title: ``what``, preceded by the run's title when one is given."""
    return f"{prefix}: {what}" if prefix else what


def _new_axes(title: str, xlabel: str, ylabel: str,
              figsize: tuple[float, float] = _FIGSIZE) -> tuple[Figure, Axes]:
    """A new, pyplot-free figure with one labelled axes and a light grid."""
    fig = Figure(figsize=figsize, layout="constrained")
    ax = fig.add_subplot()
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    return fig, ax


def _save(fig: Figure, path: Path) -> Path:
    """Write ``fig`` as a PNG at ``path``, then clear it to release its artists."""
    return save_figure(fig, path, _DPI)


def save_figure(fig: Figure, path: Path, dpi: int) -> Path:
    """Write ``fig`` as a PNG at ``path``, then clear it to release its artists. An ``OSError`` (a full disk, a
    read-only folder) is re-raised, of the same kind, naming the file."""
    try:
        fig.savefig(path, dpi=dpi)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise (OSError(exc.errno, f"cannot write plot {path}: {reason}") if exc.errno is not None
               else OSError(f"cannot write plot {path}: {reason}")) from exc
    finally:
        fig.clear()
    return path


def _shade_partial(ax: Axes, epochs: NDArray[np.float64], window: int) -> None:
    """Shade the first ``window - 1`` epochs, whose trailing window is partial."""
    if window <= 1 or epochs.size < 2:
        return
    end = epochs[min(window - 1, epochs.size - 1)]
    ax.axvspan(
        float(epochs[0]),
        float(end),
        color="0.85",
        alpha=0.5,
        lw=0,
        label=f"partial window (first {window - 1} epochs)",
    )


def _column(
    metrics: Mapping[str, NDArray[np.generic]],
    name: str,
    what: str,
    n: int | None = None,
) -> NDArray[np.generic]:
    """Fetch a column, with errors that name the column and whose metrics it is."""
    if name not in metrics:
        raise ValueError(f"{what}: missing column {name!r}; have {sorted(metrics)}")
    values = np.asarray(metrics[name])
    if values.ndim != 1:
        raise ValueError(f"{what}: column {name!r} must be one-dimensional")
    if n is not None and values.size != n:
        raise ValueError(
            f"{what}: column {name!r} has {values.size} rows, expected {n}"
        )
    return values


def _smooth(
    values: NDArray[np.generic], window: int, name: str, what: str
) -> NDArray[np.float64]:
    """Rolling mean of a column, with errors that name the column."""
    try:
        return rolling_mean(np.asarray(values, dtype=np.float64), window)
    except ValueError as exc:
        raise ValueError(f"{what}: column {name!r}: {exc}") from exc


def _epochs(
    metrics: Mapping[str, NDArray[np.generic]], n: int, what: str
) -> NDArray[np.float64]:
    """The epoch column as floats, or ``0..n-1`` when the metrics have none."""
    if "epoch" not in metrics:
        return np.arange(n, dtype=np.float64)
    return np.asarray(_column(metrics, "epoch", what, n), dtype=np.float64)


def _pretty_term(name: str) -> str:
    """``reward_opponent_velocity`` -> ``opponent velocity``."""
    return name.removeprefix(TERM_PREFIX).replace("_", " ")


# --------------------------------------------------------------------------- one run


def plot_run(
    metrics: Mapping[str, NDArray[np.generic]],
    out_dir: str | os.PathLike[str],
    *,
    window: int = 200,
    title: str = "",
    label: str = "Bug",
) -> list[Path]:
    """Draw the paper's figures for one run (training or test).

    Writes four PNGs into ``out_dir``:

    * ``rewards.png``: rolling mean of the total, dense and sparse reward per epoch;
    * ``reward_terms.png``: rolling mean of every ``reward_*`` term column (a note
      when there is none);
    * ``mwr.png``: moving winning rate with a zero line (above zero: more wins than
      losses);
    * ``steps_to_win.png``: rolling mean of the steps needed to win, over won epochs
      only (gaps where the window holds no win).

    Args:
        metrics: Column name -> per-epoch array, as returned by
            :func:`read_metrics_csv`; needs the columns of :data:`REQUIRED_COLUMNS`.
        out_dir: Folder for the figures; created if missing.
        window: Window length λ of every rolling statistic; 200 as in the paper.
        title: Run title shown before each figure's own title (e.g. ``"training"``).
        label: Name of the learning agent, used in legends.

    Returns:
        Paths of the written files, in the order above.

    Raises:
        ValueError: If a required column is missing (named), columns differ in length,
            a plotted column holds non-finite values, or ``window < 1``.
        OSError: If ``out_dir`` cannot be created or written (the message names it).
    """
    what = "metrics"
    n = _column(metrics, "outcome", what).size
    for name in REQUIRED_COLUMNS:
        _column(metrics, name, what, n)
    epochs = _epochs(metrics, n, what)
    # Validate the numbers before touching the disk.
    rewards = {
        kind: _smooth(metrics[f"{kind}_reward"], window, f"{kind}_reward", what)
        for kind in ("total", "dense", "sparse")
    }
    terms = {
        name: _smooth(_column(metrics, name, what, n), window, name, what)
        for name in metrics
        if name.startswith(TERM_PREFIX)
    }
    try:
        mwr = moving_winning_rate(
            np.asarray(metrics["local_winning_rate"], np.float64), window
        )
    except ValueError as exc:
        raise ValueError(f"{what}: column 'local_winning_rate': {exc}") from exc
    outcomes = [str(o) for o in metrics["outcome"]]
    try:
        steps = rolling_steps_to_win(
            np.asarray(metrics["steps"], np.float64), outcomes, window
        )
    except ValueError as exc:
        raise ValueError(f"{what}: columns 'steps' and 'outcome': {exc}") from exc
    folder = _prepare_dir(out_dir)
    smoothing = f"rolling mean over λ = {window} epochs"
    written: list[Path] = []

    fig, ax = _new_axes(
        _title(title, f"{label}'s reward per epoch"), "epoch", f"reward ({smoothing})"
    )
    _shade_partial(ax, epochs, window)
    for kind, curve in rewards.items():
        ax.plot(epochs, curve, lw=1.2, label=f"{label} {kind}")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.legend(loc="best")
    written.append(_save(fig, folder / "rewards.png"))

    fig, ax = _new_axes(
        _title(title, f"{label}'s reward terms per epoch"),
        "epoch",
        f"reward ({smoothing})",
    )
    _shade_partial(ax, epochs, window)
    for name, curve in terms.items():
        ax.plot(epochs, curve, lw=1.2, label=_pretty_term(name))
    ax.axhline(0.0, color="k", lw=0.6)
    if terms:
        ax.legend(loc="best")
    else:
        ax.text(
            0.5,
            0.5,
            f"no '{TERM_PREFIX}*' columns",
            transform=ax.transAxes,
            ha="center",
            va="center",
        )
    written.append(_save(fig, folder / "reward_terms.png"))

    fig, ax = _new_axes(
        _title(title, f"moving winning rate of {label}'s team (λ = {window})"),
        "epoch",
        "MWR",
    )
    _shade_partial(ax, epochs, window)
    ax.plot(epochs, mwr, lw=1.2, color="C0", label=f"{label}'s team MWR")
    ax.axhline(0.0, color="k", lw=0.8, ls="--", label="0: as many wins as losses")
    ax.set_ylim(-1.05, 1.05)
    ax.legend(loc="best")
    written.append(_save(fig, folder / "mwr.png"))

    fig, ax = _new_axes(
        _title(title, f"steps needed to win ({label}'s team, λ = {window})"),
        "epoch",
        "steps (mean over won epochs in window)",
    )
    _shade_partial(ax, epochs, window)
    ax.plot(epochs, steps, lw=1.2, color="C2", label=f"{label}'s team, won epochs")
    if np.all(np.isnan(steps)):
        ax.text(
            0.5, 0.5, "no epoch won", transform=ax.transAxes, ha="center", va="center"
        )
    ax.legend(loc="best")
    written.append(_save(fig, folder / "steps_to_win.png"))
    return written


def plot_evaluations(
    evaluations: Mapping[str, Mapping[str, NDArray[np.generic]]],
    path: str | os.PathLike[str],
    *,
    title: str = "",
    band: tuple[float, float] | None = PAPER_TEST_MWR,
    groups: Mapping[str, str] | None = None,
    reference: float | None = None,
) -> Path:
    """Draw test MWR against env steps for the evaluations runs played while training (``eval.csv``).

    One line per run, each evaluation a point with its 95 % interval shaded, the zero line dashed, and ``band``
    shaded: by default the paper's band for its Bug in testing
    (:data:`~triplesumo.evaluation.metrics.PAPER_TEST_MWR`), the figure's reference.

    Args:
        evaluations: Run label -> columns, as returned by :func:`read_evaluations_csv` (needs
            :data:`EVALUATION_COLUMNS`).
        path: The PNG to write; its folder is created if missing.
        title: The run's title, shown before the figure's own.
        band: ``(lo, hi)`` MWRs to shade, or ``None`` for none.
        groups: Run label -> its group (e.g. its algorithm, for one line per seed): the runs of a group share a
            colour and one legend entry. ``None``: every run its own colour and entry.
        reference: An MWR drawn as a dotted line (e.g. the +0.2 of time to skill), or ``None`` for none.

    Returns:
        ``path``.

    Raises:
        ValueError: If there is no run, a run has no evaluation, lacks a column (named), its columns differ in
            length, or a value is not finite (the run named), or ``groups`` misses a run (named).
        OSError: If the file cannot be written (named).
    """
    if not evaluations:
        raise ValueError("plot_evaluations: no run to draw")
    runs: dict[str, dict[str, NDArray[np.float64]]] = {}
    for label, columns in evaluations.items():
        what = f"evaluations of {label}"
        n = _column(columns, "env_steps", what).size
        if n == 0:
            raise ValueError(f"{what}: no evaluation to draw")
        runs[label] = {name: np.asarray(_column(columns, name, what, n), np.float64) for name in EVALUATION_COLUMNS}
        bad = [name for name, values in runs[label].items() if not np.all(np.isfinite(values))]
        if bad:
            raise ValueError(f"{what}: column(s) {bad} hold non-finite values")
    group = dict(groups) if groups is not None else {label: label for label in runs}
    ungrouped = [label for label in runs if label not in group]
    if ungrouped:
        raise ValueError(f"plot_evaluations: groups names no group for run(s) {ungrouped}")
    colours = {g: f"C{i}" for i, g in enumerate(dict.fromkeys(group[label] for label in runs))}
    target = Path(path)
    _prepare_dir(target.parent)
    fig, ax = _new_axes(_title(title, "test MWR while training (seeded test matches, 95 % interval)"),
                        "env steps", "test MWR")
    if band is not None:
        ax.axhspan(band[0], band[1], color="tab:green", alpha=0.12,
                   label=f"the paper's Bug in testing ({band[0]:.2f} to {band[1]:.2f})")
    shade = 0.15 if len(runs) <= 3 else 0.06
    entered: set[str] = set()
    for label, run in runs.items():
        order = np.argsort(run["env_steps"], kind="stable")
        x, colour = run["env_steps"][order], colours[group[label]]
        ax.fill_between(x, run["test_mwr_lo"][order], run["test_mwr_hi"][order], color=colour, alpha=shade, lw=0)
        ax.plot(x, run["test_mwr"][order], marker="o", ms=3, lw=1.2, color=colour,
                label=None if group[label] in entered else group[label])
        entered.add(group[label])
    ax.axhline(0.0, color="k", lw=0.8, ls="--", label="0: as many wins as losses")
    if reference is not None:
        ax.axhline(reference, color="grey", lw=1.0, ls=":", label=f"{reference:+.2f}")
    ax.set_ylim(-1.05, 1.05)
    ax.legend(loc="best", fontsize=8)
    return _save(fig, target)


# --------------------------------------------------------------------------- several runs


def plot_comparison(
    curves: Mapping[str, Mapping[str, NDArray[np.generic]]],
    out_dir: str | os.PathLike[str],
    window: int = 200,
) -> list[Path]:
    """Compare several runs (e.g. a trained Bug against ``passive`` and ``random``).

    Writes ``compare_mwr.png`` (one MWR curve per run, with a zero line) and
    ``compare_rewards.png`` (rolling mean total reward per run) into ``out_dir``.

    Args:
        curves: Run name (used as legend label) -> metrics of that run; each needs the
            columns ``local_winning_rate`` and ``total_reward``; ``epoch`` is used for
            the x axis when present, else ``0..n-1``. Runs may differ in length.
        out_dir: Folder for the figures; created if missing.
        window: Window length λ of the rolling statistics; 200 as in the paper.

    Returns:
        Paths of the two written files, MWR first.

    Raises:
        ValueError: If ``curves`` is empty, a run lacks a column (run and column are
            named), or a column holds invalid values.
        OSError: If ``out_dir`` cannot be created or written (the message names it).
    """
    if not curves:
        raise ValueError("curves is empty: nothing to compare")
    prepared: list[
        tuple[str, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]
    ] = []
    longest = np.zeros(0)
    for name, metrics in curves.items():
        what = f"run {name!r}"
        lwr = _column(metrics, "local_winning_rate", what)
        n = lwr.size
        total = _column(metrics, "total_reward", what, n)
        epochs = _epochs(metrics, n, what)
        try:
            mwr = moving_winning_rate(np.asarray(lwr, np.float64), window)
        except ValueError as exc:
            raise ValueError(f"{what}: column 'local_winning_rate': {exc}") from exc
        reward = _smooth(total, window, "total_reward", what)
        prepared.append((name, epochs, mwr, reward))
        if epochs.size > longest.size:
            longest = epochs
    folder = _prepare_dir(out_dir)

    rows = len(prepared) + 2  # the runs, the partial window and the zero line
    fig, ax = _comparison_axes(f"moving winning rate (λ = {window})", "MWR", rows)
    _shade_partial(ax, longest, window)
    for name, epochs, mwr, _ in prepared:
        ax.plot(epochs, mwr, lw=1.2, label=legend_label(name))
    ax.axhline(0.0, color="k", lw=0.8, ls="--", label="0: as many wins as losses")
    ax.set_ylim(-1.05, 1.05)
    _legend_below(fig, ax)
    mwr_path = _save(fig, folder / "compare_mwr.png")

    fig, ax = _comparison_axes("total reward per epoch", f"reward (rolling mean over λ = {window} epochs)", rows)
    _shade_partial(ax, longest, window)
    for name, epochs, _, reward in prepared:
        ax.plot(epochs, reward, lw=1.2, label=legend_label(name))
    ax.axhline(0.0, color="k", lw=0.6)
    _legend_below(fig, ax)
    rewards_path = _save(fig, folder / "compare_rewards.png")
    return [mwr_path, rewards_path]


def legend_label(name: str, limit: int = LABEL_MAX) -> str:
    """``name`` if it fits in ``limit`` characters, else its start and end around an ellipsis (the end of a
    policy path names the run)."""
    if len(name) <= limit:
        return name
    tail = (limit - 1) // 2
    return f"{name[:limit - 1 - tail]}…{name[-tail:]}"


def _comparison_axes(title: str, ylabel: str, legend_rows: int) -> tuple[Figure, Axes]:
    """The axes of a comparison, on a figure made taller by the legend rows that go below it, so the axes keep
    :data:`_FIGSIZE`'s height however many runs are compared."""
    width, height = _FIGSIZE
    return _new_axes(title, "epoch", ylabel, figsize=(width, height + _LEGEND_ROW_INCHES * legend_rows))


def _legend_below(fig: Figure, ax: Axes) -> None:
    """One legend entry per row below the axes, outside them (the constrained layout makes room)."""
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=1, fontsize="small", frameon=False)
