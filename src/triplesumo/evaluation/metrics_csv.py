"""The metrics CSV: its columns (one row per epoch of the learner) and the one routine that cuts a
row-appended CSV back to its finished rows.

A run killed while writing leaves a torn last line; :func:`repair_metrics_csv` keeps the
complete, valid rows and rewrites the file atomically
(:func:`~triplesumo.agents.policy_file.atomic_write_bytes`). Training's resume
(:mod:`triplesumo.train.logger`), ``evaluate --resume``, tournaments and the league log all
use it, so it stands here, below training.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from pathlib import Path

from triplesumo.agents.policy_file import atomic_write_bytes, writing
from triplesumo.evaluation.metrics import OUTCOMES
from triplesumo.rules.rewards import TERMS

COLUMNS = ("epoch", "outcome", "local_winning_rate", "steps", "total_reward", "dense_reward", "sparse_reward",
           *TERMS, "env_steps", "wall_time")
"""Metrics CSV schema: one row per epoch (match) of the learner."""


def metrics_row_problem(row: list[str], epoch: int) -> str | None:
    """Why ``row`` is not the finished row of ``epoch`` (None if it is)."""
    if len(row) != len(COLUMNS):
        return f"{len(row)} fields, expected {len(COLUMNS)}"
    values = dict(zip(COLUMNS, row, strict=True))
    if values["epoch"] != str(epoch):
        return f"epoch {values['epoch']!r}, expected {epoch}"
    if values["outcome"] not in OUTCOMES:
        return f"outcome {values['outcome']!r}, expected one of {list(OUTCOMES)}"
    for c in COLUMNS[2:]:
        try:
            if not math.isfinite(float(values[c])):
                return f"{c} {values[c]!r} is not finite"
        except ValueError:
            return f"{c} {values[c]!r} is not a number"
    return None


def repair_metrics_csv(path: Path, keep_through: int | None = None, columns: tuple[str, ...] = COLUMNS,
                       row_problem: Callable[[list[str], int], str | None] | None = None,
                       what: str = "metrics CSV") -> int:
    """Cut the metrics CSV ``path`` back to its finished rows; returns how many it keeps.

    Kept: the complete (newline-terminated) rows for epochs 1, 2, ... in order, up to
    ``keep_through`` if given. Dropped: a torn last line (a kill while writing it), an
    invalid last row, and rows after ``keep_through``. The file is rewritten atomically,
    and only when something is dropped. An invalid row with rows after it is not a torn
    tail: ``ValueError`` names the file and line instead of dropping finished rows. So is
    a file that is not a metrics CSV. A missing file holds 0 rows.

    Other row-appended tables (tournament matches, ...) use the same routine with their own
    ``columns``, ``row_problem(row, number)`` (why a row is not row ``number``, or None) and
    ``what`` (the table's name in errors).
    """
    good, complete, whole = _finished_rows(Path(path), keep_through, columns, row_problem or metrics_row_problem, what)
    if not whole:
        with writing(path):
            atomic_write_bytes(path, ("\n".join(complete[: good + 1]) + "\n").encode("utf-8"))
    return good


def intact_rows(path: Path, columns: tuple[str, ...] = COLUMNS,
                row_problem: Callable[[list[str], int], str | None] | None = None, what: str = "metrics CSV") -> int:
    """How many finished rows :func:`repair_metrics_csv` would keep, without changing the file (its errors alike)."""
    return _finished_rows(Path(path), None, columns, row_problem or metrics_row_problem, what)[0]


def _finished_rows(path: Path, keep_through: int | None, columns: tuple[str, ...],
                   row_problem: Callable[[list[str], int], str | None], what: str) -> tuple[int, list[str], bool]:
    """The finished rows a table keeps, its complete lines, and whether it holds nothing else (no rewrite)."""
    if not path.exists():
        return 0, [], True
    data = path.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a {what} (byte {exc.start} is not UTF-8 text)") from None
    header = ",".join(columns)
    if header.startswith(text.rstrip("\n")) and text.count("\n") <= 1:  # empty, or killed while writing the header
        return 0, [header], text == header + "\n"
    lines = text.split("\n")
    complete = lines[:-1]  # a file ending in a newline leaves "" last; anything else is cut off
    if not complete or tuple(next(csv.reader(complete[:1]), [])) != columns:
        raise ValueError(f"{path}: not a {what} (expected the header {list(columns)})")
    good = 0
    for number, row in enumerate(csv.reader(complete[1:]), start=2):
        if keep_through is not None and good >= keep_through:
            break
        problem = row_problem(row, good + 1)
        if problem is not None:
            if number < len(complete):  # not the last complete line: finished rows follow it
                which = f"the row of epoch {good + 1}" if columns == COLUMNS else f"row {good + 1}"
                raise ValueError(f"{path}, line {number}: not {which} ({problem}), and rows "
                                 f"follow it; fix or delete that line by hand, nothing was changed")
            break
        good += 1
    return good, complete, not (good + 1 < len(complete) or lines[-1] != "")
