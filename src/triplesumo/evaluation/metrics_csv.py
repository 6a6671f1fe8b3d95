"""The metrics CSV: its columns (one row per epoch of the learner), the one routine that cuts a
row-appended CSV back to its finished rows, and packed tables.

A run killed while writing leaves a torn last line; :func:`repair_metrics_csv` keeps the
complete, valid rows and rewrites the file atomically
(:func:`~triplesumo.agents.policy_file.atomic_write_bytes`). Training's resume
(:mod:`triplesumo.train.logger`), ``evaluate --resume``, tournaments and the league log all
use it, so it stands here, below training.

**Packed tables.** A finished output folder kept in a repository (``docs/runs/``) may hold its large
tables gzipped, ``NAME.csv.gz`` in place of ``NAME.csv`` (:func:`pack_tables`, ``triplesumo pack``).
Every reader of the project reads a table through :func:`open_table` and asks for it by its plain name
(:func:`table_exists`, :func:`stored`), so a packed folder reads, plots and resumes as it did. Appending
goes through :func:`repair_metrics_csv`, which unpacks a packed table first (:func:`unpack_table`). A
folder holding both forms of one table is refused with both names: which one holds the rows is not
for the code to guess.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import os
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

from triplesumo._lock import held_tree
from triplesumo.agents.policy_file import atomic_write_bytes, writing
from triplesumo.evaluation.metrics import OUTCOMES
from triplesumo.rules.rewards import TERMS

COLUMNS = ("epoch", "outcome", "local_winning_rate", "steps", "total_reward", "dense_reward", "sparse_reward",
           *TERMS, "env_steps", "wall_time")
"""Metrics CSV schema: one row per epoch (match) of the learner."""


PACKED = ".gz"
"""The suffix of a packed table: ``metrics.csv.gz`` holds ``metrics.csv`` gzipped."""
PACK_MIN_BYTES = 64 * 1024
"""Tables smaller than this stay plain when a folder is packed (:func:`pack_tables`)."""


def packed_path(path: Path | str) -> Path:
    """Where table ``path`` lies when packed: ``path`` with :data:`PACKED` appended."""
    path = Path(path)
    return path.with_name(path.name + PACKED)


def stored(path: Path | str) -> Path | None:
    """The file holding table ``path`` (named by its plain name, e.g. ``metrics.csv``): the plain file, else
    its packed form (``metrics.csv.gz``), else None. ``ValueError`` names both if both are there."""
    path = Path(path)
    packed = packed_path(path)
    if path.exists():
        if packed.exists():
            raise ValueError(f"{path} and {packed} are both there: two copies of one table; keep the one that "
                             "holds the rows (gunzip -c the packed one to compare) and delete the other")
        return path
    return packed if packed.exists() else None


def table_exists(path: Path | str) -> bool:
    """Whether table ``path`` is there, plain or packed."""
    return stored(path) is not None


def tables_in(folder: Path | str, pattern: str = "*.csv") -> list[Path]:
    """The tables of ``folder`` (not its subfolders) whose plain names match ``pattern``, each by its plain name,
    whether it lies plain or packed; sorted."""
    folder = Path(folder)
    names = {p.name for p in folder.glob(pattern) if p.is_file()}
    names |= {p.name.removesuffix(PACKED) for p in folder.glob(pattern + PACKED) if p.is_file()}
    return sorted(folder / name for name in names)


def read_table_bytes(path: Path | str) -> bytes:
    """The bytes of table ``path`` as written (a packed one decompressed); ``FileNotFoundError`` names the table,
    ``ValueError`` a packed file that does not decompress (not gzip, cut short, or bytes damaged mid-stream)."""
    where = stored(path)
    if where is None:
        raise FileNotFoundError(f"{path} not found (nor {packed_path(path).name})")
    data = where.read_bytes()
    if where.name.endswith(PACKED):
        try:
            return gzip.decompress(data)
        except (OSError, EOFError, zlib.error) as exc:  # not gzip; cut short; damaged inside its stream
            raise ValueError(f"{where}: not a gzipped table, or a damaged one ({exc}); nothing was changed") from None
    return data


def open_table(path: Path | str) -> TextIO:
    """Table ``path`` opened for reading as UTF-8 text with ``newline=""`` (for :mod:`csv`), plain or packed: a
    plain one is read as it streams from disk, a packed one decompressed first (a damaged one named)."""
    where = stored(path)
    if where is not None and not where.name.endswith(PACKED):
        return where.open(newline="", encoding="utf-8")
    return io.StringIO(read_table_bytes(path).decode("utf-8"), newline="")


def write_table(path: Path | str, payload: bytes) -> None:
    """Write table ``path`` whole (atomically, plain), replacing a packed copy of it: a table rewritten by a later
    run is no longer the packed one."""
    path = Path(path)
    with writing(path):
        atomic_write_bytes(path, payload)
    packed_path(path).unlink(missing_ok=True)


def unpack_table(path: Path | str) -> bool:
    """Put a packed table back as its plain file (before rows are appended to it); returns whether it was packed.
    Atomic: the plain file is written in full before the packed one goes."""
    path = Path(path)
    where = stored(path)
    if where is None or where == path:
        return False
    data = read_table_bytes(path)
    with writing(path):
        atomic_write_bytes(path, data)
    where.unlink()
    return True


def pack_tables(folder: Path | str, min_bytes: int = PACK_MIN_BYTES) -> list[Path]:
    """Gzip every ``*.csv`` under ``folder`` of at least ``min_bytes`` into ``NAME.csv.gz`` in its place (level 9, no
    name or time in the header, so packing the same table twice gives the same bytes); returns the packed files.
    Each is written atomically and checked (decompressed, it is the table) before the plain file goes."""
    folder = Path(folder)
    if not folder.is_dir():
        raise NotADirectoryError(f"{folder}: not a folder")
    if isinstance(min_bytes, bool) or not isinstance(min_bytes, int) or min_bytes < 0:
        raise ValueError(f"min_bytes must be an int >= 0, got {min_bytes!r}")
    with held_tree(folder, "pack"):  # not while a run, evaluation or tournament in it still writes
        return _pack(folder, min_bytes)


def _pack(folder: Path, min_bytes: int) -> list[Path]:
    done = []
    for path in sorted(folder.rglob("*.csv")):
        if not path.is_file() or path.stat().st_size < min_bytes:
            continue
        stored(path)  # refuses a table already there in both forms
        before = path.stat()
        data = path.read_bytes()
        packed = packed_path(path)
        payload = gzip.compress(data, compresslevel=9, mtime=0)
        with writing(packed):
            atomic_write_bytes(packed, payload)
        status = path.stat()
        if (status.st_size, status.st_mtime_ns) != (before.st_size, before.st_mtime_ns) or len(data) != before.st_size:
            packed.unlink()  # a run still appending to it: its rows would go to a file about to be removed
            raise ValueError(f"{path} changed while it was being packed (a run still writing it?); it was left "
                             "plain: pack a folder once nothing writes to it")
        if gzip.decompress(packed.read_bytes()) != data:  # pragma: no cover (a disk that returns other bytes)
            packed.unlink()
            raise OSError(f"{packed}: reads back other bytes than {path}; {path} was kept")
        os.chmod(packed, status.st_mode & 0o7777)  # the table's permissions and times, not the temp file's
        os.utime(packed, (status.st_atime, status.st_mtime))
        path.unlink()
        done.append(packed)
    return done


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
    a file that is not a metrics CSV. A missing file holds 0 rows. A packed table (``NAME.csv.gz``) is
    unpacked first: the rows to come are appended to the plain file.

    Other row-appended tables (tournament matches, ...) use the same routine with their own
    ``columns``, ``row_problem(row, number)`` (why a row is not row ``number``, or None) and
    ``what`` (the table's name in errors).
    """
    unpack_table(path)  # rows are appended to the plain file
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
    if not table_exists(path):
        return 0, [], True
    data = read_table_bytes(path)
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
