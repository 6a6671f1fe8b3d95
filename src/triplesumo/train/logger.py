"""Per-epoch metrics: a CSV (the source of the plots) and TensorBoard events."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from triplesumo.rules.rewards import TERMS

COLUMNS = ("epoch", "outcome", "local_winning_rate", "steps", "total_reward", "dense_reward", "sparse_reward",
           *TERMS, "env_steps", "wall_time")
"""Metrics CSV schema: one row per epoch (match) of the learner."""


class MetricsLog:
    """Appends epoch rows to ``metrics.csv`` and mirrors them to TensorBoard."""

    def __init__(self, run_dir: Path, resume_epoch: int | None, tensorboard: bool) -> None:
        self.path = Path(run_dir) / "metrics.csv"
        if resume_epoch is not None and self.path.exists():
            # Drop rows written after the checkpoint we resume from (a killed run goes on).
            with self.path.open(newline="") as fh:
                rows = [r for r in csv.DictReader(fh) if int(r["epoch"]) <= resume_epoch]
            self._write_header()
            with self.path.open("a", newline="") as fh:
                csv.DictWriter(fh, COLUMNS).writerows(rows)
        else:
            self._write_header()
        self._fh = self.path.open("a", newline="", buffering=1)  # line-buffered: rows show up as epochs end
        self._csv = csv.DictWriter(self._fh, COLUMNS)
        self._tb: Any = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            purge = None if resume_epoch is None else resume_epoch + 1
            self._tb = SummaryWriter(str(Path(run_dir) / "tensorboard"), purge_step=purge)

    def _write_header(self) -> None:
        with self.path.open("w", newline="") as fh:
            csv.DictWriter(fh, COLUMNS).writeheader()

    def epoch(self, row: dict[str, Any], mwr: float) -> None:
        self._csv.writerow(row)
        if self._tb is not None:
            e = row["epoch"]
            self._tb.add_scalar("charts/mwr", mwr, e)
            self._tb.add_scalar("charts/local_winning_rate", row["local_winning_rate"], e)
            self._tb.add_scalar("charts/episodic_length", row["steps"], e)
            for key in ("total_reward", "dense_reward", "sparse_reward", *TERMS):
                self._tb.add_scalar(f"rewards/{key}", row[key], e)

    def losses(self, values: dict[str, float], step: int) -> None:
        if self._tb is not None:
            for key, value in values.items():
                self._tb.add_scalar(f"losses/{key}", value, step)

    def flush(self) -> None:
        self._fh.flush()
        if self._tb is not None:
            self._tb.flush()

    def close(self) -> None:
        self._fh.close()
        if self._tb is not None:
            self._tb.close()
