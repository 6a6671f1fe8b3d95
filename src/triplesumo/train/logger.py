"""Per-epoch metrics and learning stats: CSVs (the source of the plots) and TensorBoard events.

The CSV is only ever appended to, row by row, or rewritten whole through
:func:`~triplesumo.agents.policy_file.atomic_write_bytes` (temp file, fsync, rename):
a kill or a full disk at any moment leaves either the old file or the new one.
The metrics CSV's columns and :func:`~triplesumo.evaluation.metrics_csv.repair_metrics_csv`,
the one routine that cuts a CSV back to its finished rows (a torn last line of a killed run,
rows past a checkpoint), live in :mod:`triplesumo.evaluation.metrics_csv` (``evaluate --resume``
uses them too, and evaluation stands below training); they are re-exported here.
"""

from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from triplesumo.agents.policy_file import atomic_write_bytes, writing
from triplesumo.evaluation.metrics_csv import (
    COLUMNS,
    intact_rows,
    metrics_row_problem,
    repair_metrics_csv,
    unpack_table,
    write_table,
)
from triplesumo.rules.rewards import TERMS

__all__ = ["COLUMNS", "EVAL_ADDED", "EVAL_COLUMNS", "LEARNING_COLUMNS", "MetricsLog", "intact_rows",
           "learning_row_problem", "repair_metrics_csv", "run_file"]

LEARNING_COLUMNS = ("epoch", "updates", "actor_loss", "critic_loss", "q_mean", "entropy", "alpha", "alpha_loss",
                    "approx_kl", "clip_fraction")
"""Learning CSV schema: one row per epoch of a learner, its update count and the means of the
stats its algorithm reported over the updates since the previous row (empty: none reported;
rows of a run resumed from before this file existed are all empty)."""


def learning_row_problem(row: list[str], epoch: int) -> str | None:
    """Why ``row`` is not the finished learning row of ``epoch`` (None if it is)."""
    if len(row) != len(LEARNING_COLUMNS):
        return f"{len(row)} fields, expected {len(LEARNING_COLUMNS)}"
    if row[0] != str(epoch):
        return f"epoch {row[0]!r}, expected {epoch}"
    if row[1] and not row[1].isdigit():
        return f"updates {row[1]!r} is not a count"
    for name, value in zip(LEARNING_COLUMNS[2:], row[2:], strict=True):
        try:
            if value and not math.isfinite(float(value)):
                return f"{name} {value!r} is not finite"
        except ValueError:
            return f"{name} {value!r} is not a number"
    return None


EVAL_COLUMNS = ("evaluation", "env_steps", "epochs", "policy_train_seconds", "train_seconds", "eval_seconds",
                "test_matches", "test_mwr", "test_mwr_lo", "test_mwr_hi", "n_win", "n_loss", "n_draw")
"""Evaluation CSV schema (``TrainConfig.eval_every``): one row per evaluation of a learner, numbered from 1:
the env steps and epochs trained when its policy was frozen, the training's wall time (evaluations excluded,
checkpoints included) when its policy was frozen (``policy_train_seconds``) and when the row was written
(``train_seconds``: the same inline; with ``eval_background`` the training went on while it played), the
time the training spent on evaluations, and the test MWR with its 95 % interval over the test matches.
``policy_train_seconds`` is empty in the rows of a run written before the column existed (resumed since)."""
EVAL_ADDED = ("policy_train_seconds",)


def policy_seconds(row: dict[str, str]) -> float:
    """The training clock when an evaluation's policy was frozen (its time to that skill): ``policy_train_seconds``,
    or in a row written before that column existed its ``train_seconds`` (the same inline; an upper bound for a
    background evaluation, written when its result came back)."""
    return float(row.get("policy_train_seconds") or row["train_seconds"])
"""Columns of :data:`EVAL_COLUMNS` that older eval CSVs lack: a resume adds them, empty in the old rows."""


def _eval_row_problem(row: list[str], number: int) -> str | None:
    """Why ``row`` is not the finished row of evaluation ``number`` (None if it is)."""
    if len(row) != len(EVAL_COLUMNS):
        return f"{len(row)} fields, expected {len(EVAL_COLUMNS)}"
    if row[0] != str(number):
        return f"evaluation {row[0]!r}, expected {number}"
    for name, value in zip(EVAL_COLUMNS[1:], row[1:], strict=True):
        if name in EVAL_ADDED and value == "":  # (a row from before the column: not known)
            continue
        try:
            float(value)  # (an interval of a single test match is nan)
        except ValueError:
            return f"{name} {value!r} is not a number"
    return None


class _Table:
    """One row-appended CSV of a run, cut back to the resumed epoch on resume."""

    def __init__(self, path: Path, columns: tuple[str, ...], row_problem: Callable[[list[str], int], str | None],
                 resume_epoch: int | None, what: str, backfill: bool = False, added: tuple[str, ...] = ()) -> None:
        self.path, self.columns = path, columns
        header = _csv_bytes(columns)
        if resume_epoch is None:
            write_table(path, header)
        else:
            unpack_table(path)  # a packed table (NAME.csv.gz, triplesumo pack) goes back to its plain file
            if added:
                _add_columns(path, columns, added)
            if backfill and not path.exists():  # a run from before this table: its epochs get empty rows
                blank = "".join(f"{e}{',' * (len(columns) - 1)}\n" for e in range(1, resume_epoch + 1))
                with writing(path):
                    atomic_write_bytes(path, header + blank.encode())
            if resume_epoch > 0 and not path.exists():
                raise ValueError(f"{path}: file not found, but the checkpoint resumed from is at epoch "
                                 f"{resume_epoch}: its rows would be lost")
            if not path.exists():
                with writing(path):
                    atomic_write_bytes(path, header)
            kept = repair_metrics_csv(path, resume_epoch, columns, row_problem, what)
            if kept < resume_epoch:
                raise ValueError(f"{path}: holds the rows of epochs 1..{kept}, but the checkpoint resumed from "
                                 f"is at epoch {resume_epoch}: rows {kept + 1}..{resume_epoch} are missing")
        with writing(path):
            self._fh = path.open("a", newline="", buffering=1)  # line-buffered: rows show up as epochs end
        self._csv = csv.DictWriter(self._fh, columns, lineterminator="\n")

    def write(self, row: dict[str, Any]) -> None:
        with writing(self.path):
            self._csv.writerow(row)

    def flush(self) -> None:
        with writing(self.path):
            self._fh.flush()
            os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()


def _add_columns(path: Path, columns: tuple[str, ...], added: tuple[str, ...]) -> None:
    """A table written before the columns ``added`` existed (its header is ``columns`` without them) is rewritten,
    atomically, with them, empty in its finished rows (a torn last line is left as it is, for the repair)."""
    if not path.exists():
        return
    lines = path.read_bytes().decode("utf-8", errors="replace").split("\n")
    old = tuple(c for c in columns if c not in added)
    if tuple(next(csv.reader(lines[:1]), [])) != old:
        return
    where = [columns.index(c) for c in added]
    out = [",".join(columns)]
    for k, line in enumerate(lines[1:], start=1):
        row = next(csv.reader([line]), [])
        if k == len(lines) - 1 or len(row) != len(old):  # the torn tail, or a row the repair will judge
            out.append(line)
            continue
        for i in where:
            row.insert(i, "")
        buf = io.StringIO()
        csv.writer(buf, lineterminator="").writerow(row)
        out.append(buf.getvalue())
    with writing(path):
        atomic_write_bytes(path, "\n".join(out).encode("utf-8"))


def _csv_bytes(columns: tuple[str, ...] = COLUMNS) -> bytes:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(columns)
    return buf.getvalue().encode("utf-8")


def run_file(stem: str, name: str, several: bool, suffix: str = "") -> str:
    """A run folder's file for agent or learner ``name``: ``metrics.csv`` when the run has one
    learning agent, ``metrics-<name>.csv`` when it has several (``stem`` "metrics", ``suffix`` ".csv")."""
    return f"{stem}-{name}{suffix}" if several else f"{stem}{suffix}"


class MetricsLog:
    """Per-epoch rows of every learning agent and every learner, mirrored to TensorBoard.

    Writes ``metrics.csv`` (the agent's matches: outcome, rewards, the source of the plots)
    and ``learning.csv`` (the learner's update count and mean losses and stats since the
    previous epoch). With several learning agents or learners every file is named after
    its agent or learner (``metrics-ant.csv``, ``learning-ant+bug.csv``) and TensorBoard tags
    are prefixed with the name (``ant/charts/mwr``, ``ant+bug/losses/critic_loss``).

    ``resume_epoch`` None starts new CSVs; otherwise each is cut back to the rows of epochs
    1..``resume_epoch`` (:func:`repair_metrics_csv`), which must all be there; an agent's metrics
    CSV to its ``resume_rows`` entry where given (its own matches: in self-play with several
    learning sides an agent that sits a match out writes no row for it).
    """

    def __init__(self, run_dir: Path, agents: list[str], learners: list[str], resume_epoch: int | None,
                 tensorboard: bool, resume_rows: Mapping[str, int] | None = None,
                 evaluations: int | None = None) -> None:
        self.several = len(agents) > 1 or len(learners) > 1 or agents != learners
        self.metrics = {a: _Table(Path(run_dir) / run_file("metrics", a, self.several, ".csv"), COLUMNS,
                                  metrics_row_problem, resume_epoch if resume_rows is None else resume_rows[a],
                                  "metrics CSV") for a in agents}
        self.learning = {n: _Table(Path(run_dir) / run_file("learning", n, self.several, ".csv"), LEARNING_COLUMNS,
                                   learning_row_problem, resume_epoch, "learning CSV", backfill=True)
                         for n in learners}
        self.evals = {} if evaluations is None else {
            n: _Table(Path(run_dir) / run_file("eval", n, self.several, ".csv"), EVAL_COLUMNS, _eval_row_problem,
                      None if resume_epoch is None else evaluations, "evaluation CSV", added=EVAL_ADDED)
            for n in learners}
        """Per learner its evaluations (``TrainConfig.eval_every``; none when off), cut back to the
        ``evaluations`` of the checkpoint resumed from."""
        self.path = self.metrics[agents[0]].path
        self._tb: Any = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            purge = None if resume_epoch is None else resume_epoch + 1
            self._tb = SummaryWriter(str(Path(run_dir) / "tensorboard"), purge_step=purge)

    def _tag(self, name: str, tag: str) -> str:
        return f"{name}/{tag}" if self.several else tag

    def epoch(self, agent: str, row: dict[str, Any], mwr: float) -> None:
        self.metrics[agent].write(row)
        if self._tb is not None:
            e = row["epoch"]
            self._tb.add_scalar(self._tag(agent, "charts/mwr"), mwr, e)
            self._tb.add_scalar(self._tag(agent, "charts/local_winning_rate"), row["local_winning_rate"], e)
            self._tb.add_scalar(self._tag(agent, "charts/episodic_length"), row["steps"], e)
            for key in ("total_reward", "dense_reward", "sparse_reward", *TERMS):
                self._tb.add_scalar(self._tag(agent, f"rewards/{key}"), row[key], e)

    def learned(self, learner: str, epoch: int, updates: int, stats: dict[str, float]) -> None:
        """The learning row of ``learner`` at ``epoch`` (stats: means since the previous row)."""
        known = {k: v for k, v in stats.items() if k in LEARNING_COLUMNS}
        self.learning[learner].write({"epoch": epoch, "updates": updates, **known})
        if self._tb is not None:
            self._tb.add_scalar(self._tag(learner, "charts/updates"), updates, epoch)
            for key, value in known.items():
                self._tb.add_scalar(self._tag(learner, f"losses/{key}"), value, epoch)

    def evaluated(self, learner: str, row: dict[str, Any]) -> None:
        """An evaluation row of ``learner`` (:data:`EVAL_COLUMNS`); TensorBoard's ``eval/test_mwr`` at its epoch
        (the step of every other chart, which a resume purges past its checkpoint)."""
        self.evals[learner].write(row)
        if self._tb is not None:
            self._tb.add_scalar(self._tag(learner, "eval/test_mwr"), row["test_mwr"], row["epochs"])

    def scalars(self, values: dict[str, float], epoch: int) -> None:
        """Other per-epoch scalars (e.g. the league's ``league/SIDE/...``) to TensorBoard."""
        if self._tb is not None:
            for tag, value in values.items():
                self._tb.add_scalar(tag, value, epoch)

    def flush(self) -> None:
        """Flush and fsync the CSVs (before a checkpoint: no checkpoint counts rows the disk lacks)."""
        for table in (*self.metrics.values(), *self.learning.values(), *self.evals.values()):
            table.flush()
        if self._tb is not None:
            self._tb.flush()

    def close(self) -> None:
        for table in (*self.metrics.values(), *self.learning.values(), *self.evals.values()):
            table.close()
        if self._tb is not None:
            self._tb.close()


def progress_bar(total: int, initial: int, steps: bool, desc: str) -> Any:
    """A tqdm bar to a run's budget: ``total`` env steps (``steps``) or epochs, from ``initial``."""
    from tqdm import tqdm

    return tqdm(total=total, initial=min(initial, total), unit="step" if steps else "epoch", unit_scale=steps,
                desc=desc, dynamic_ncols=True)
