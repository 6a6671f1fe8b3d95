"""The repository stays lean (issue 40): run folders are outputs, not source.

``results/`` (and ``runs/``) are ignored and hold nothing tracked; no replay buffer or TensorBoard event file is
tracked; the resume state of runs still in progress (``checkpoints/`` folders) takes at most 50 MB in all; run outputs
(metrics tables, policy weights) are tracked only beside the pages that cite them (``docs/runs/``), in the shipped zoo
or as test fixtures; there, a large table is packed (``triplesumo pack``) and every plot or video is shown by a page;
and the tracked files take at most the issue's 100 MB. Test fixtures under ``tests/data/`` are source, not run outputs.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from conftest import relative_links, tracked_files
from triplesumo.evaluation.metrics_csv import PACK_MIN_BYTES

ROOT = Path(__file__).resolve().parents[1]
RESUME_STATE_LIMIT = 50 * 10**6
"""Bytes of ``checkpoints/`` folders (runs in progress, compacted) the repository may hold, in all."""
TRACKED_LIMIT = 100 * 10**6
"""Bytes of tracked files, at most (issue 40): 747 MB when the issue was filed, 69 MB when this limit was set."""
FIXTURES = "tests/data/"
BESIDE_PAGES = "docs/runs/"
ZOO = "src/triplesumo/agents/zoo/"


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


def test_tracked_files_take_at_most_100_mb(files: frozenset[str]) -> None:
    total = sum(size(f) for f in files)
    biggest = sorted(files, key=size, reverse=True)[:5]
    assert total <= TRACKED_LIMIT, (f"tracked files take {total / 1e6:.1f} MB, over {TRACKED_LIMIT / 1e6:.0f} MB; "
                                    f"the largest: {[(f, size(f)) for f in biggest]}")


def _run_output(path: str) -> bool:
    return path.endswith((".safetensors", ".csv", ".csv.gz"))


def test_run_outputs_live_beside_the_pages_in_the_zoo_or_as_fixtures(files: frozenset[str]) -> None:
    stray = sorted(f for f in files if _run_output(f) and not f.startswith((BESIDE_PAGES, ZOO, FIXTURES)))
    assert not stray, f"run outputs outside {BESIDE_PAGES} (beside the pages), {ZOO} and {FIXTURES}: {stray[:10]}"


def test_large_tables_beside_the_pages_are_packed(files: frozenset[str]) -> None:
    plain = sorted(f for f in files if f.startswith(BESIDE_PAGES) and f.endswith(".csv") and size(f) >= PACK_MIN_BYTES)
    folders = sorted({str(Path(f).parent) for f in plain})
    assert not plain, (f"{len(plain)} table(s) of at least {PACK_MIN_BYTES // 1024} KiB left plain, e.g. {plain[:3]}; "
                       f"run `triplesumo pack` on {folders[:5]}")


def test_every_plot_or_video_beside_the_pages_is_shown_by_a_page(files: frozenset[str]) -> None:
    shown = set()
    for page in (f for f in files if f.endswith(".md") and (ROOT / f).is_file()):
        for target in relative_links(ROOT / page):
            shown.add((ROOT / page).parent.joinpath(target.split("#")[0]).resolve())
    unseen = sorted(f for f in files if f.startswith(BESIDE_PAGES) and f.endswith((".png", ".mp4", ".gif"))
                    and (ROOT / f).resolve() not in shown)
    assert not unseen, f"plots or videos under {BESIDE_PAGES} no page shows (link or drop them): {unseen[:10]}"
