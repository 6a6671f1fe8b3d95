"""The repository stays lean (issue 40): run folders are outputs, not source.

``results/`` (and ``runs/``) are ignored and hold nothing tracked; no replay buffer or TensorBoard event file is
tracked; the resume state of runs still in progress (``checkpoints/`` folders) takes at most 50 MB in all; run outputs
(metrics tables, policy weights) are tracked only beside the pages that cite them (``docs/runs/``), in the shipped zoo
or as test fixtures; there, a large table is packed (``triplesumo pack``) and every plot or video is shown by a page;
and the tracked files take at most the issue's 100 MB. Test fixtures under ``tests/data/`` are source, not run outputs.
"""

from __future__ import annotations

import re
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


# ------------------------------------------------------------------ code, not history; no citation of a missing file
HISTORY = re.compile(r"\bissues?\s*#?\d+|\bissue's\b|\bthe issue\b|\bPR\s*#?\d+"
                     r"|(?<![\w.`'\"])sessions?(?![\w(`\"]|'(?!s\b))", re.I)
"""A mention of the project's history in the package: an issue or pull request, or a session as a word of prose.
The code names ``ray_tasks.session`` and ``session_command`` are names, not history, and do not match."""
PACKAGE = "src/"
TEXT = (".py", ".json", ".xml", ".md", ".toml", ".txt", ".yml", ".yaml", ".cfg", ".cff", ".in")
"""Suffixes of the tracked text files read here."""


def history_in(text: str) -> list[str]:
    """The lines of ``text`` that mention the project's history (:data:`HISTORY`)."""
    return [line.strip() for line in text.splitlines() if HISTORY.search(line)]


def test_history_is_found() -> None:
    for line in ("(issue 38)", "Issue 10: the batched path", "the issue's +0.2", "see issue #12", "fixed in PR 7",
                 "A run is trained over several sessions", "this session's leg"):
        assert history_in(line), line
    for line in ("with ray_tasks.session(address):", "session_command=typed", ":func:`session` connects",
                 '__all__ = ["session"]', "def session(address: str = ''):", "it issues a warning"):
        assert not history_in(line), line


def test_the_package_holds_code_not_history(files: frozenset[str]) -> None:
    """No issue, pull request or session in src/: a docstring or comment says what the code does and why."""
    found = [f"{f}: {line[:100]}" for f in sorted(files) if f.startswith(PACKAGE) and f.endswith(TEXT)
             and (ROOT / f).is_file() for line in history_in((ROOT / f).read_text())]
    assert not found, "history in the package (say what the code does and why instead):\n" + "\n".join(found)


_MARKDOWN = re.compile(r"(?<![\w./*{}<>$-])((?:\.{1,2}/|[\w.-]+/)*[\w-][\w.-]*\.md)(?![\w/])")
PLACEHOLDERS = {"NAME"}
"""File stems written as placeholders (``docs/environments/NAME.md``): not a citation of one file."""
RECORDS = ("docs/runs/", "tests/data/")
"""Run outputs and test fixtures: files recorded as they were written, not read here."""


def cited_markdown(text: str) -> list[str]:
    """The ``*.md`` files a text names: bare names (``README.md``) and paths (``docs/layout.md``,
    ``../README.md``), less web addresses."""
    return _MARKDOWN.findall(re.sub(r"[a-z][a-z0-9+.-]*://\S+", "", text))


def cite_resolves(cite: str, source: str, files: frozenset[str]) -> bool:
    """Whether the repository has the ``*.md`` file that ``cite`` names in the tracked file ``source``: a bare name
    anywhere; a path from the citing file's folder, the repository's root or ``docs/`` (where mkdocs.yml names its
    pages); a path inside a folder the repository does not have (an output folder: ``OUT/REPRODUCTION.md``) by its
    file name. A path from a folder the repository has (``docs/``, ``src/``, ``../``) must resolve."""
    path = Path(cite)
    if path.stem in PLACEHOLDERS:
        return True
    names = {Path(f).name for f in files}
    if len(path.parts) == 1:
        return path.name in names
    for base in ((ROOT / source).parent, ROOT, ROOT / "docs"):
        full = (base / path).resolve()
        if full.is_file() or (full.is_relative_to(ROOT) and full.relative_to(ROOT).as_posix() in files):
            return True
    tops = {f.split("/")[0] for f in files if "/" in f}
    return path.parts[0] not in {*tops, "..", "."} and path.name in names


def test_citations_of_markdown_files_are_found_and_checked() -> None:
    files = frozenset({"README.md", "docs/layout.md", "docs/REPRODUCTION.md", "src/triplesumo/cli.py"})
    text = ("Layers (STYLE.md); see docs/layout.md, [x](../README.md), OUT/REPRODUCTION.md, docs/NOPE.md, "
            "docs/environments/NAME.md and https://github.com/a/b/blob/main/CONTRIBUTING.md; globs: /bench/*.md")
    cites = cited_markdown(text)
    assert cites == ["STYLE.md", "docs/layout.md", "../README.md", "OUT/REPRODUCTION.md", "docs/NOPE.md",
                     "docs/environments/NAME.md"]
    missing = [c for c in cites if not cite_resolves(c, "docs/layout.md", files)]
    assert missing == ["STYLE.md", "docs/NOPE.md"]


def test_no_tracked_text_file_cites_a_markdown_file_the_repository_lacks(files: frozenset[str]) -> None:
    this = Path(__file__).resolve().relative_to(ROOT).as_posix()  # (its examples cite missing files on purpose)
    broken = [f"{f}: {cite}" for f in sorted(files) if f.endswith(TEXT) and not f.startswith(RECORDS)
              and f != this and (ROOT / f).is_file()
              for cite in cited_markdown((ROOT / f).read_text(errors="replace"))
              if not cite_resolves(cite, f, files)]
    assert not broken, "citations of *.md files the repository does not have:\n" + "\n".join(broken)


def test_the_fast_tier_is_a_registered_marker_that_ci_does_not_filter() -> None:
    """``pytest -m "not slow"`` is the contributors' fast tier (CONTRIBUTING.md): ``slow`` is a registered marker
    (an unregistered one would select nothing and warn), tests carry it, and CI runs the full suite unfiltered."""
    import tomllib

    markers = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["markers"]
    assert any(m.split(":")[0].strip() == "slow" for m in markers), markers
    assert 'pytest -m "not slow"' in (ROOT / "CONTRIBUTING.md").read_text()
    marked = [p.name for p in (ROOT / "tests").glob("test_*.py") if "mark.slow" in p.read_text()]
    assert len(marked) >= 10, marked
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if line.startswith("pytest")]
    assert ci and all("-m" not in line.split() for line in ci), ci
