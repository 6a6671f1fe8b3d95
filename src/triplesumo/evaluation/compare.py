"""``triplesumo compare``: statistics across seeds, the ``rliable`` recipe.

Reads the ``per_seed.csv`` of evaluation folders (written by ``triplesumo evaluate``,
one row per candidate policy: each training seed of ``--policy runs/s0/policy
runs/s1/policy ...`` is its own row) and groups the rows (``by``: the candidate group,
``trained``/``passive``/``random``/...; the algorithm that made the policy; the sweep trial that
trained it, :func:`trial_group`; or the folder).
For each group it reports the test MWR of each seed, their **interquartile mean** (IQM,
the 25 % trimmed mean, :func:`rliable.metrics.aggregate_iqm`) with a **stratified
bootstrap** percentile interval, and for each pair of groups the **probability of
improvement** P(X > Y) (:func:`rliable.metrics.probability_of_improvement`, the
Mann-Whitney U statistic over ``n_x n_y``; ties count one half) with its bootstrap
interval (Agarwal et al., 2021, "Deep RL at the Edge of the Statistical Precipice").

The bootstrap follows ``rliable.library.StratifiedBootstrap``: scores are a
``(runs, tasks)`` matrix (one task, the test match, unless ``tasks="folder"``) and each resample draws runs
with replacement within each task. It is computed here with numpy, vectorised over
resamples and seeded from ``seed`` (rliable's ``get_interval_estimates`` draws from
numpy's global generator, so its intervals are not reproducible from a seed); the point
estimates are rliable's own functions, and a test holds the intervals to
``rliable.library.get_interval_estimates`` on the same scores.

An evaluation repeated in several folders (same policy files by sha256, same opponents by the sha256 its
``evaluation.json`` records, same test seed and epochs) is counted once: identical evaluations are not independent
seeds. The same policy against other opponents (a passive Bug in two from-scratch pairs) is another evaluation.

``tasks="folder"`` makes each evaluation folder a task of the stratified bootstrap: runs are drawn within each
folder, so every resample keeps each folder's share of the runs (the headline over several from-scratch pairs:
5 SAC seeds in each pair's folder are a ``(5, pairs)`` matrix, as rliable holds Atari games). A group needs the
same number of runs in every folder for that; one that lacks it gets its values and mean, no interval, and the
table names why.

A group of fewer than :data:`MIN_RUNS` runs gets no interval and takes part in no probability of improvement:
over three runs a bootstrap's 95 % interval is their minimum and maximum, and P(X > Y) of two groups that never
overlap is 1.00 however few runs stand behind it. Such a group shows its per-run values and their mean
(``lo``, ``hi`` null in ``compare.json``, empty in ``compare.csv``; the printed table says so).
"""

from __future__ import annotations

import csv
import io
import itertools
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.envs.seeding import check_seed
from triplesumo.evaluation.evaluate import PER_SEED_COLUMNS, PER_SEED_FILE, RECORD_FILE
from triplesumo.evaluation.metrics_csv import open_table, table_exists, write_table
from triplesumo.evaluation.video import check_writable

BY = ("group", "algo", "folder", "trial")
TASKS = ("one", "folder")
MIN_RUNS = 5
"""Fewest runs (seeds) of a group for a bootstrap interval or a probability of improvement."""


@dataclass(frozen=True)
class CompareConfig:
    """Interquartile means with bootstrap intervals and probabilities of improvement across seeds."""

    folders: tuple[str, ...] = ()
    """Evaluation folders (each holds per_seed.csv from triplesumo evaluate)."""
    by: str = "group"
    """Group the seeds by: group (trained, passive, random, ...), algo (from the policy manifest), folder, or trial
    (the sweep trial of the policy's run folder without its seed: learn=bug=ddpg,ddpg.noise=gaussian,seed=0 ->
    ddpg,ddpg.noise=gaussian)."""
    tasks: str = "one"
    """What the stratified bootstrap draws runs within: one (all runs of a group are one task) or folder (each
    evaluation folder is a task, e.g. one per from-scratch pair; a group needs as many runs in every folder)."""
    reps: int = 10_000
    """Bootstrap resamples."""
    confidence: float = 0.95
    """Confidence of the intervals."""
    seed: int = 0
    """Seed of the bootstrap."""
    out: str = "runs/compare"
    """Folder for compare.csv, compare.json, improvement.csv and compare.png."""

    def __post_init__(self) -> None:
        check_seed(self.seed, "CompareConfig.seed")
        if self.by not in BY:
            raise ValueError(f"CompareConfig.by must be one of {BY}, got {self.by!r}")
        if self.tasks not in TASKS:
            raise ValueError(f"CompareConfig.tasks must be one of {TASKS}, got {self.tasks!r}")
        if isinstance(self.reps, bool) or not isinstance(self.reps, int) or self.reps < 100:
            raise ValueError(f"CompareConfig.reps must be an int >= 100, got {self.reps!r}")
        if not 0.0 < self.confidence < 1.0:
            raise ValueError(f"CompareConfig.confidence must be in (0, 1), got {self.confidence!r}")


def iqm(scores: NDArray[np.float64]) -> float:
    """Interquartile mean of a ``(runs, tasks)`` score matrix (rliable's ``aggregate_iqm``)."""
    from rliable import metrics as rly_metrics  # (here: rliable loads scipy.stats, ~1 s the CLI's parser skips)

    return float(rly_metrics.aggregate_iqm(np.asarray(scores, dtype=np.float64)))


def probability_of_improvement(x: NDArray[np.float64], y: NDArray[np.float64]) -> float:
    """P(X > Y) + P(X = Y) / 2, averaged over tasks (rliable's ``probability_of_improvement``)."""
    from rliable import metrics as rly_metrics

    return float(rly_metrics.probability_of_improvement(np.asarray(x, dtype=np.float64),
                                                        np.asarray(y, dtype=np.float64)))


def stratified_resamples(scores: NDArray[np.float64], reps: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``reps`` stratified bootstrap resamples ``(reps, runs, tasks)`` of a ``(runs, tasks)`` matrix:
    runs drawn with replacement within each task (``rliable.library.StratifiedBootstrap``)."""
    runs, tasks = scores.shape
    picks = rng.integers(runs, size=(reps, runs, tasks))
    return scores[picks, np.arange(tasks)]


def _iqm_rows(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """IQM of each resample ``(reps, runs, tasks)``: the 25 % trimmed mean over runs and tasks together."""
    from scipy.stats import trim_mean

    return np.asarray(trim_mean(samples.reshape(len(samples), -1), 0.25, axis=1), dtype=np.float64)


def _poi_rows(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Probability of improvement of each resample pair ``(reps, runs_x, tasks)``, ``(reps, runs_y, tasks)``."""
    out = np.empty(len(x))
    for start in range(0, len(x), 1000):  # in chunks: the pairwise comparison is reps x runs_x x runs_y
        a, b = x[start:start + 1000, :, None, :], y[start:start + 1000, None, :, :]
        out[start:start + 1000] = ((a > b).mean(axis=(1, 2)) + 0.5 * (a == b).mean(axis=(1, 2))).mean(axis=1)
    return out


def interval_estimates(scores: dict[str, NDArray[np.float64]], reps: int = 10_000, confidence: float = 0.95,
                       seed: int = 0, compared: tuple[str, ...] | None = None) -> dict[str, Any]:
    """IQM with stratified-bootstrap percentile intervals per group, and the probability of improvement
    (with its interval) of every ordered pair of the ``compared`` groups (all when None; their score matrices
    have the same tasks)."""
    rng = np.random.default_rng(seed)
    alpha = 100.0 * (1.0 - confidence) / 2.0
    samples = {g: stratified_resamples(np.asarray(s, dtype=np.float64), reps, rng) for g, s in scores.items()}
    groups = {}
    for g, s in scores.items():
        lo, hi = np.percentile(_iqm_rows(samples[g]), [alpha, 100.0 - alpha])
        groups[g] = {"iqm": iqm(s), "lo": float(lo), "hi": float(hi)}
    pairs = {}
    for gx, gy in itertools.permutations(scores if compared is None else compared, 2):
        lo, hi = np.percentile(_poi_rows(samples[gx], samples[gy]), [alpha, 100.0 - alpha])
        pairs[(gx, gy)] = {"poi": probability_of_improvement(scores[gx], scores[gy]), "lo": float(lo),
                           "hi": float(hi)}
    return {"groups": groups, "pairs": pairs}


def trial_group(row: dict[str, str]) -> str:
    """The trial group of a per-seed row: the name of the policy's run folder (a ``triplesumo sweep`` or
    ``reproduce`` trial, ``learn=bug=ddpg,ddpg.noise=gaussian,seed=0``) without its ``seed=`` value, a leading
    one-learner ``learn=AGENT=ALGO`` shortened to ALGO (``ddpg,ddpg.noise=gaussian``); the row's algo for a
    trained policy from elsewhere, its group for a baseline or compared policy."""
    if row["group"] != "trained":
        return row["group"]
    values = Path(row["policy"]).parent.name.split(",")
    if not all("=" in v for v in values):  # not a trial's run folder
        return row["algo"]
    kept = [v for v in values if not v.startswith("seed=")]
    kept = [v.split("=")[2] if v.startswith("learn=") and v.count("=") == 2 and "+" not in v else v for v in kept]
    return ",".join(kept) or row["algo"]


def folder_labels(folders: tuple[str, ...]) -> dict[str, str]:
    """Each folder's label for ``by="folder"``: its name, or as many trailing parts of its path as tell it from the
    others (``seed-1/evaluation`` and ``seed-3/evaluation``, not two groups called ``evaluation``)."""
    parts = {f: Path(f).resolve().parts for f in folders}
    labels = {}
    for f in folders:
        k = 1
        while k < len(parts[f]) and any(g != f and parts[g][-k:] == parts[f][-k:] for g in folders):
            k += 1
        labels[f] = "/".join(parts[f][-k:])
    return labels


def _opponents(folder: Path) -> tuple[str, ...]:
    """The sha256 of the opponents an evaluation folder's rows played (its ``evaluation.json``), sorted; none
    recorded (a ``per_seed.csv`` alone) reads as no opponents."""
    path = folder / RECORD_FILE
    if not path.exists():
        return ()
    try:
        others = json.loads(path.read_text())["others"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not an evaluation record of triplesumo evaluate (no readable 'others': "
                         f"{exc!r})") from exc
    if not isinstance(others, dict):
        raise ValueError(f"{path}: 'others' must map each opponent to its sha256, got {type(others).__name__}")
    return tuple(sorted(f"{k}:{v}" for k, v in others.items()))


def read_per_seed(folders: tuple[str, ...], by: str) -> dict[str, list[dict[str, str]]]:
    """The per-seed rows of evaluation folders, grouped; repeated evaluations counted once."""
    if not folders:
        raise ValueError("compare needs at least one evaluation folder")
    labels = folder_labels(folders)
    grouped: dict[str, list[dict[str, str]]] = {}
    seen: set[tuple[str, ...]] = set()
    for folder in folders:
        path = Path(folder) / PER_SEED_FILE
        if not table_exists(path):
            raise FileNotFoundError(f"{path} not found: {folder} is not an evaluation folder of triplesumo evaluate "
                                    "(run evaluate there, with one --policy per seed)")
        with open_table(path) as fh:
            reader = csv.DictReader(fh)
            if tuple(reader.fieldnames or ()) != PER_SEED_COLUMNS:
                raise ValueError(f"{path}: expected the columns {list(PER_SEED_COLUMNS)}, got {reader.fieldnames}")
            rows = list(reader)
        opponents = _opponents(Path(folder))
        for row in rows:
            key = (row["sha256"], row["learner"], row["eval_seed"], row["epochs"], *opponents)
            if key in seen:
                continue
            seen.add(key)
            name = {"group": row["group"], "algo": row["algo"], "folder": f"{labels[folder]}/{row['group']}",
                    "trial": trial_group(row) if by == "trial" else ""}[by]
            grouped.setdefault(name, []).append({**row, "folder": str(folder)})
    return grouped


def task_matrix(rows: list[dict[str, str]], folders: tuple[str, ...]) -> tuple[NDArray[np.float64], str]:
    """A group's test MWR as the ``(runs, tasks)`` matrix of the stratified bootstrap, and why it gets no interval
    ("" when it may have one). No ``folders``: one task. ``folders``: one task (column) per folder, in their
    order; a group without the same number of runs in every folder is one column, with the reason."""
    column = np.array([[float(r["test_mwr"])] for r in rows])
    if not folders:
        return column, ""
    counts = [sum(r["folder"] == str(f) for r in rows) for f in folders]
    if len(set(counts)) > 1:
        return column, "runs per folder differ (" + ", ".join(str(c) for c in counts) + "): no task matrix"
    return np.array([[float(r["test_mwr"]) for r in rows if r["folder"] == str(f)] for f in folders]).T, ""


def compare(cfg: CompareConfig) -> dict[str, Any]:
    """Group the per-seed rows, estimate, write ``compare.csv``, ``improvement.csv``, ``compare.json``
    and ``compare.png``; returns the table."""
    from triplesumo.evaluation.tournament_plots import plot_compare

    out = check_writable(Path(cfg.out), folder=True)
    grouped = read_per_seed(cfg.folders, cfg.by)
    scores, why = {}, {}
    for g, rows in grouped.items():
        scores[g], reason = task_matrix(rows, cfg.folders if cfg.tasks == "folder" else ())
        if reason or len(rows) < MIN_RUNS:
            why[g] = reason or f"fewer than {MIN_RUNS} runs"
    compared = tuple(g for g in scores if g not in why)
    est = interval_estimates(scores, cfg.reps, cfg.confidence, cfg.seed, compared=compared)
    table: dict[str, Any] = {"config": asdict(cfg), "by": cfg.by, "tasks": cfg.tasks, "confidence": cfg.confidence,
                             "min_runs": MIN_RUNS, "groups": [], "improvement": []}
    for g, rows in sorted(grouped.items(), key=lambda kv: -est["groups"][kv[0]]["iqm"]):
        interval = {"lo": None, "hi": None, "no_interval": why[g]} if g in why else {}  # values and mean only
        table["groups"].append({"group": g, "n_seeds": len(rows), "scores": [float(r["test_mwr"]) for r in rows],
                                "policies": [r["policy"] for r in rows], "mean": float(np.mean(scores[g])),
                                **est["groups"][g], **interval})
    table["improvement"] = [{"x": gx, "y": gy, **p} for (gx, gy), p in est["pairs"].items()]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["group", "n_seeds", "iqm", "lo", "hi", "mean", "seed_scores"])
    for g in table["groups"]:
        w.writerow([g["group"], g["n_seeds"], f"{g['iqm']:.4f}", *(("", "") if g["lo"] is None else (
            f"{g['lo']:.4f}", f"{g['hi']:.4f}")), f"{g['mean']:.4f}", " ".join(f"{s:.4f}" for s in g["scores"])])
    write_table(out / "compare.csv", buf.getvalue().encode())
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["x", "y", "probability_of_improvement", "lo", "hi"])
    for p in table["improvement"]:
        w.writerow([p["x"], p["y"], f"{p['poi']:.4f}", f"{p['lo']:.4f}", f"{p['hi']:.4f}"])
    write_table(out / "improvement.csv", buf.getvalue().encode())
    atomic_write_bytes(out / "compare.json", (json.dumps(table, indent=2) + "\n").encode())
    plot_compare(table, out / "compare.png", title=f"test MWR across seeds, by {cfg.by}")
    return table


def format_compare(table: dict[str, Any]) -> str:
    """The table printed by ``triplesumo compare``."""
    pct = round(100 * table["confidence"])
    w = max([24, *(len(g["group"]) for g in table["groups"])])  # whole names: ablations are long
    lines = [f"{'group':{w}s} {'seeds':>5s} {f'IQM [{pct}% CI]':>26s}  per-seed test MWR"]
    for g in table["groups"]:
        ci = f"{g['iqm']:+.3f} [{g['lo']:+.3f}, {g['hi']:+.3f}]" if g["lo"] is not None else f"mean {g['mean']:+.3f}"
        lines.append(f"{g['group']:{w}s} {g['n_seeds']:5d} {ci:>26s}  " + " ".join(f"{s:+.3f}" for s in g["scores"]))
    few: dict[str, list[str]] = {}
    for g in table["groups"]:
        if g["lo"] is None:
            reason = g.get("no_interval", f"fewer than {table.get('min_runs', MIN_RUNS)} runs")
            few.setdefault(reason, []).append(g["group"])
    for reason, names in few.items():
        lines.append(f"({reason}, no interval and no P(X > Y): the per-run values and their mean: {', '.join(names)})")
    if table["improvement"]:
        lines.append("")
        lines.append(f"{'P(X > Y)':{2 * w + 3}s} {f'[{pct}% CI]':>18s}")
        for p in table["improvement"]:
            lines.append(f"{p['x']:>{w}s} > {p['y']:{w}s}  {p['poi']:.3f} [{p['lo']:.3f}, {p['hi']:.3f}]")
    return "\n".join(lines)
