"""Figures of tournaments and of cross-seed comparisons.

Built on :class:`matplotlib.figure.Figure` directly (never pyplot), like
:mod:`triplesumo.evaluation.plots`: any Matplotlib backend, no window, no global state.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from triplesumo.evaluation.plots import save_figure

_DPI = 120


def plot_leaderboard(results: dict[str, Any], path: Path, title: str = "") -> Path:
    """Bar chart of each policy's rating ``mu`` with its interval as error bars, best first."""
    board = results["leaderboard"]
    fig = Figure(figsize=(max(4.0, 1.1 * len(board) + 1.5), 3.8))
    ax = fig.add_subplot()
    mu = np.array([e["mu"] for e in board])
    err = np.array([[e["mu"] - e["lo"] for e in board], [e["hi"] - e["mu"] for e in board]])
    x = np.arange(len(board))
    ax.bar(x, mu, yerr=err, capsize=5, color="#4a7bd0", edgecolor="black", linewidth=0.6)
    ax.set_xticks(x, [e["policy"] for e in board], rotation=20)
    pct = round(100 * results["confidence"])
    ax.set_ylabel(f"rating mu ({pct}% interval)")
    ax.set_title(f"{title} ({results['rating_model']})".strip())
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path, _DPI)


def plot_ladder(results: dict[str, Any], path: Path, title: str = "") -> Path:
    """Rating (with its interval) of every trained entry against the epochs it had trained: a line through
    the entries of one run (``run``: a league folder or a training command) per trained agent (per seat with
    ``rate_by="seat"``), a labelled point for a trained entry alone of its run (a zoo policy), a band for
    each entry without epochs (built-ins)."""
    board = results["leaderboard"]
    fig = Figure(figsize=(7.0, 4.2))
    ax = fig.add_subplot()
    by_seat = results["rate_by"] == "seat"
    lines: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for e in board:
        if e["epochs"] is not None:
            key = e["policy"].rsplit("@", 1)[1] if by_seat else str(e["trained"])
            lines.setdefault((key, str(e.get("run"))), []).append(e)
    runs = sorted({run for (_, run), entries in lines.items() if len(entries) > 1})
    for (key, run), entries in sorted(lines.items()):
        entries.sort(key=lambda e: e["epochs"])
        epochs = np.array([e["epochs"] for e in entries], dtype=float)
        mu = np.array([e["mu"] for e in entries])
        err = np.array([[e["mu"] - e["lo"] for e in entries], [e["hi"] - e["mu"] for e in entries]])
        if len(entries) == 1:
            ax.errorbar(epochs, mu, yerr=err, fmt="s", capsize=4, color="black", alpha=0.7)
            ax.annotate(entries[0]["policy"], (epochs[0], mu[0]), textcoords="offset points", xytext=(5, 4),
                        fontsize=7)
            continue
        which = f", run {runs.index(run) + 1}" if len(runs) > 1 else ""
        ax.errorbar(epochs, mu, yerr=err, fmt="o-", capsize=4,
                    label=(f"in seat {key}" if by_seat else f"trained as {key}") + which)
    colours = iter(["#888888", "#c05050", "#50a050", "#b08030", "#7050b0", "#309090"])
    for e in board:
        if e["epochs"] is None:
            colour = next(colours, "#888888")
            ax.axhspan(e["lo"], e["hi"], color=colour, alpha=0.15)
            ax.axhline(e["mu"], color=colour, linestyle="--", linewidth=1, label=e["policy"])
    pct = round(100 * results["confidence"])
    ax.set_xlabel("training epochs of the entry")
    ax.set_ylabel(f"rating mu ({pct}% interval)")
    ax.set_title(f"{title}: rating against training ({results['rating_model']})".strip(": "), fontsize=9)
    ax.legend(loc="best", fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path, _DPI)


def plot_crossplay(results: dict[str, Any], path: Path, title: str = "") -> Path:
    """Heat map of the win rate of each row policy against each column policy (with intervals)."""
    names = [e["policy"] for e in results["leaderboard"]]
    idx = {n: i for i, n in enumerate(names)}
    rate = np.full((len(names), len(names)), np.nan)
    text = [["" for _ in names] for _ in names]
    for c in results["crossplay"]:
        i, j = idx[c["row"]], idx[c["column"]]
        if c["n"]:
            rate[i, j] = c["win_rate"]
            text[i][j] = f"{c['win_rate']:.2f}\n[{c['lo']:.2f}, {c['hi']:.2f}]\nn={c['n']}"
        else:
            text[i][j] = "never met" if i != j else ""
    size = 1.4 * len(names) + 2.0
    fig = Figure(figsize=(size + 1.0, size))
    ax = fig.add_subplot()
    image = ax.imshow(np.ma.masked_invalid(rate), vmin=0.0, vmax=1.0, cmap="RdYlGn")
    for i in range(len(names)):
        for j in range(len(names)):
            ax.text(j, i, text[i][j], ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(names)), names, rotation=20)
    ax.set_yticks(range(len(names)), names)
    ax.set_xlabel("against (column)")
    ax.set_ylabel("policy (row)")
    pct = round(100 * results["confidence"])
    ax.set_title(f"{title}: win rate of row against column [{pct}% Wilson]".strip(": "), fontsize=9)
    fig.colorbar(image, ax=ax, label="win rate")
    fig.tight_layout()
    return save_figure(fig, path, _DPI)


def plot_compare(table: dict[str, Any], path: Path, title: str = "") -> Path:
    """Per-seed test MWR of each group (dots) with its IQM and bootstrap interval (bar), or with their mean alone for a
    group of fewer runs than an interval needs."""
    groups = table["groups"]
    fig = Figure(figsize=(max(4.0, 1.2 * len(groups) + 1.5), 3.8))
    ax = fig.add_subplot()
    for k, g in enumerate(groups):
        if g["lo"] is None:  # fewer runs than an interval needs: their mean, no bar
            ax.scatter([k], [g["mean"]], marker="D", color="black", s=30, zorder=3,
                       label="mean (fewer than 5 runs)" if all(h["lo"] is not None for h in groups[:k]) else None)
        else:
            ax.errorbar([k], [g["iqm"]], yerr=[[g["iqm"] - g["lo"]], [g["hi"] - g["iqm"]]], fmt="s", color="black",
                        capsize=6, markersize=7, zorder=3,
                        label="IQM" if all(h["lo"] is None for h in groups[:k]) else None)
        seeds = np.asarray(g["scores"], dtype=float)
        jitter = np.linspace(-0.15, 0.15, len(seeds)) if len(seeds) > 1 else np.zeros(1)
        ax.scatter(k + jitter, seeds, color="#4a7bd0", alpha=0.7, s=18, zorder=2,
                   label="seeds" if k == 0 else None)
    ax.axhline(0.0, color="grey", linewidth=0.8)
    ax.set_xticks(range(len(groups)), [g["group"] for g in groups], rotation=20)
    pct = round(100 * table["confidence"])
    ax.set_ylabel(f"test MWR (IQM, {pct}% bootstrap CI)")
    ax.set_title(title or f"by {table['by']}")
    ax.legend(loc="best", fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path, _DPI)
