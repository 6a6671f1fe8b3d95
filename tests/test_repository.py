"""The repository stays lean (issue 40): run folders are outputs, not source.

``results/`` (and ``runs/``) are ignored and hold nothing tracked; no replay buffer or TensorBoard event file is
tracked; the resume state of runs still in progress (``checkpoints/`` folders) takes at most 50 MB in all; and the
tracked files stay under a ceiling that is lowered as run outputs leave (the issue's goal: 100 MB). Test fixtures
under ``tests/data/`` are source, not run outputs.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from conftest import tracked_files

ROOT = Path(__file__).resolve().parents[1]
RESUME_STATE_LIMIT = 50 * 10**6
"""Bytes of ``checkpoints/`` folders (runs in progress, compacted) the repository may hold, in all."""
TRACKED_CEILING = 240 * 10**6
"""Bytes of tracked files, at most: 238 MB when this was written (2026-11-28, 747 MB when issue 40 was filed);
lowered as docs/runs shrinks to what their pages cite, down to the issue's 100 MB."""
FIXTURES = "tests/data/"


@pytest.fixture
def files() -> frozenset[str]:
    if not tracked_files():
        pytest.skip("not a git checkout")
    return tracked_files()


def size(rel: str) -> int:
    path = ROOT / rel
    return path.stat().st_size if path.is_file() else 0  # (a sparse checkout may lack it)


@pytest.mark.parametrize("folder", ["results", "runs"])
def test_run_folders_are_ignored_and_hold_nothing_tracked(files: frozenset[str], folder: str) -> None:
    assert not [f for f in files if f.startswith(f"{folder}/")], f"{folder}/ holds tracked files"
    ignored = subprocess.run(["git", "check-ignore", "-q", f"{folder}/some-run/metrics.csv"], cwd=ROOT, check=False)
    assert ignored.returncode == 0, f".gitignore must ignore {folder}/"


def test_no_replay_buffer_or_tensorboard_events_are_tracked(files: frozenset[str]) -> None:
    found = [f for f in files if not f.startswith(FIXTURES)
             and (Path(f).name == "replay.npz" or "tfevents" in Path(f).name or "/tensorboard/" in f)]
    assert not found, f"run outputs that never belong in the repository: {found}"


def test_resume_state_of_runs_in_progress_takes_at_most_50_mb(files: frozenset[str]) -> None:
    state = sum(size(f) for f in files if "/checkpoints/" in f and not f.startswith(FIXTURES))
    assert state <= RESUME_STATE_LIMIT, f"checkpoints/ folders hold {state / 1e6:.1f} MB (at most 50 MB in all)"


def test_tracked_files_stay_under_the_ceiling(files: frozenset[str]) -> None:
    total = sum(size(f) for f in files)
    biggest = sorted(files, key=size, reverse=True)[:5]
    assert total <= TRACKED_CEILING, (f"tracked files take {total / 1e6:.1f} MB, over {TRACKED_CEILING / 1e6:.0f} MB; "
                                      f"the largest: {[(f, size(f)) for f in biggest]}")
