"""The README as a front door and the documentation site under docs/ (built by MkDocs from mkdocs.yml).

Every Python code block of the README and the site's pages runs (:func:`test_the_python_blocks_of_a_page_run`),
each in a fresh namespace, a page's blocks in one fresh process; a block marked ``<!-- example: NAME -->`` runs in
tests/test_clients.py with checks of what it leaves behind, and one marked ``<!-- no-test: REASON -->`` (a GPU, a
cluster) is not run, says why and is counted.

The README stays short and starts with the two commands; every relative link of the README and the
site's pages resolves to a file of the repository; every page of the nav exists and every page is
in the nav; the environment pages are what docs/gen_env_pages.py writes from the code; the API
reference covers every public module and shows the docstrings' Sphinx roles as code (and links), not
literally (docs/griffe_roles.py); and, where MkDocs is installed (the ``docs`` extra),
``mkdocs build --strict`` passes.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import pytest

from conftest import module_from_file, relative_links, tracked_files

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
README_LIMIT = 15_000
COMMANDS = (
    "python3 -m venv .venv && . .venv/bin/activate && pip install -e \".[all]\" && triplesumo demo\n"
    "python3 -m venv .venv && . .venv/bin/activate && pip install -e \".[test]\" && pytest -n 2 -q\n"
)


def site_pages() -> list[Path]:
    """The Markdown pages of the site: docs/ less the run outputs under docs/runs/."""
    return sorted(p for p in DOCS.rglob("*.md") if "runs" not in p.relative_to(DOCS).parts)


def test_readme_is_a_short_front_door_starting_with_the_two_commands() -> None:
    text = README.read_text()
    assert len(text) <= README_LIMIT, f"README.md: {len(text)} characters, at most {README_LIMIT} (guides go to docs/)"
    first = re.search(r"^```\w*\n(.*?)^```", text, re.S | re.M)
    assert first is not None and first.group(1) == COMMANDS, "README.md's first code block must be the two commands"
    assert text.index("```") < text.index("\n## "), "the two commands come before any section"


@pytest.mark.parametrize("page", [README, *site_pages()], ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page: Path) -> None:
    broken = []
    for target in relative_links(page):
        path = (page.parent / re.split(r"[#?]", target)[0]).resolve()  # (less an anchor or a query)
        rel = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else None
        if not path.exists() and (rel is None or not any(t == rel or t.startswith(rel + "/") for t in tracked_files())):
            broken.append(target)
        elif page != README and (path.is_dir() or (not path.exists() and rel not in tracked_files())):
            broken.append(target)  # a site page's link to a folder: `mkdocs build --strict` refuses it
    assert not broken, f"{page.relative_to(ROOT)}: links to missing files (or, from the site, to folders): {broken}"


def test_relative_links_are_found() -> None:
    links = relative_links(README)
    assert "docs/CONTEST.md" in links and "docs/figures/bodies.png" in links, links
    assert "../scenario_paper.mp4" in relative_links(DOCS / "environments" / "paper.md")


OUT_OF_NAV = ("bench", "notes")
"""Folders of docs/ whose pages are built but left out of the nav (mkdocs.yml's ``not_in_nav``): the benchmarks'
raw pages, and the records behind the result pages."""


def nav_pages() -> list[str]:
    """Every page named in mkdocs.yml's nav."""
    nav = (ROOT / "mkdocs.yml").read_text().split("\nnav:\n", 1)[1]
    return re.findall(r"^\s+- (?:[^:\n]+: )?(\S+\.md)\s*$", nav, re.M)


def test_nav_pages_exist_and_every_page_is_in_the_nav() -> None:
    nav = nav_pages()
    assert "index.md" in nav and "environments/paper.md" in nav and "api/envs.md" in nav, nav
    missing = [p for p in nav if not (DOCS / p).is_file()]
    assert not missing, f"mkdocs.yml's nav names missing pages: {missing}"
    left_out = [p.relative_to(DOCS).as_posix() for p in site_pages()
                if p.relative_to(DOCS).parts[0] not in OUT_OF_NAV and p.relative_to(DOCS).as_posix() not in nav]
    assert not left_out, f"pages not in mkdocs.yml's nav: {left_out}"



# ------------------------------------------------------------------ result pages, not diaries
RESULT_PAGE_LIMIT = 20_000
"""Bytes of a result page at most: the claim, the protocol, the tables, the figures and how to regenerate them."""
RESULT_PAGES = {"CONTEST.md": "notes/contest-log.md", "LEAGUE.md": "notes/league-log.md",
                "REPRODUCTION.md": "notes/reproduction-log.md"}
"""Each result page and the record of how it was made (attempt by attempt, session by session) under docs/notes/."""


@pytest.mark.parametrize("page", sorted(RESULT_PAGES))
def test_a_result_page_is_short_and_links_its_record(page: str) -> None:
    size = len((DOCS / page).read_bytes())
    assert size <= RESULT_PAGE_LIMIT, (f"docs/{page}: {size} bytes, at most {RESULT_PAGE_LIMIT}: the "
                                       f"attempt-by-attempt record goes to docs/{RESULT_PAGES[page]}")
    assert (DOCS / RESULT_PAGES[page]).is_file()
    links = {(DOCS / target.split("#")[0]).resolve() for target in relative_links(DOCS / page)}
    assert (DOCS / RESULT_PAGES[page]).resolve() in links, f"docs/{page} must link docs/{RESULT_PAGES[page]}"
    assert not re.search(r"^#+ .*\(20\d\d-\d\d-\d\d", (DOCS / page).read_text(), re.M), \
        f"docs/{page}: a dated heading is a diary entry (docs/{RESULT_PAGES[page]})"


def test_the_notes_are_built_linked_and_left_out_of_the_nav() -> None:
    notes = sorted(p.relative_to(DOCS).as_posix() for p in (DOCS / "notes").glob("*.md"))
    assert set(RESULT_PAGES.values()) <= set(notes), notes
    assert not set(notes) & set(nav_pages()), "docs/notes/ pages stay out of mkdocs.yml's nav"
    block = (ROOT / "mkdocs.yml").read_text().split("\nnot_in_nav: |\n", 1)[1].splitlines()
    not_in_nav = [line.strip() for line in block[:next(i for i, x in enumerate(block) if not x.startswith("  "))]]
    assert "/notes/*.md" in not_in_nav, "mkdocs.yml's not_in_nav must name /notes/*.md (else a strict build warns)"
    linked = {(DOCS / page).parent.joinpath(target.split("#")[0]).resolve()
              for page in nav_pages() for target in relative_links(DOCS / page)}
    unlinked = [n for n in notes if (DOCS / n).resolve() not in linked]
    assert not unlinked, f"notes no page of the nav links: {unlinked}"


def test_the_reproduction_page_keeps_the_markers_reproduce_writes_between() -> None:
    text = (DOCS / "REPRODUCTION.md").read_text()
    begin, end = text.find("\n<!-- reproduce:begin -->\n"), text.find("\n<!-- reproduce:end -->\n")
    assert 0 <= begin < end, "docs/REPRODUCTION.md: `triplesumo reproduce --docs` writes between these two lines"


def test_the_learners_page_shows_a_runnable_example() -> None:
    blocks = python_blocks(DOCS / "learners.md")
    run = [b for b in blocks if b.marker is None and "agent.update(" in b.code]
    assert run and not any(line.lstrip().startswith("#   ") for line in run[0].code.splitlines()), \
        "docs/learners.md: a learner loop that runs (test_the_python_blocks_of_a_page_run), not pseudocode"

def _docs_module(name: str) -> ModuleType:
    """A Python file of docs/ (not a package) as a module."""
    return module_from_file(DOCS / f"{name}.py")


def _generator() -> ModuleType:
    return _docs_module("gen_env_pages")


def test_environment_pages_are_in_sync_with_the_code() -> None:
    from triplesumo.rules.scenarios import SCENARIOS

    pages = _generator().pages()
    assert {p.name for p in pages} == {"index.md", *(f"{name}.md" for name in SCENARIOS)}
    stale = [p.relative_to(ROOT).as_posix() for p, text in pages.items() if not p.exists() or p.read_text() != text]
    assert not stale, f"out of date: {stale}; run python docs/gen_env_pages.py"


def test_environment_pages_document_each_scenario() -> None:
    from triplesumo.rules.scenarios import SCENARIOS

    pages = _generator().pages()
    overview = pages[DOCS / "environments" / "index.md"]
    for section in ("Description", "Action Space", "Observation Space", "Rewards", "Starting State", "Episode End",
                    "Arguments", "Version History"):
        assert f"### {section}\n" in overview, section
    for name, sc in SCENARIOS.items():
        page = pages[DOCS / "environments" / f"{name}.md"]
        assert sc.gym_id in page and sc.pettingzoo_name in page
        for section in ("Agents", "Rules", "Rewards", "Episode End"):
            assert f"## {section}\n" in page, (name, section)


def test_api_reference_covers_every_public_module() -> None:
    documented = set(re.findall(r"^::: (triplesumo[\w.]*)", "".join(p.read_text() for p in (DOCS / "api").glob("*.md")),
                                re.M))
    package = ROOT / "src" / "triplesumo"
    modules = {".".join(("triplesumo", *p.relative_to(package).with_suffix("").parts)).removesuffix(".__init__")
               for p in package.rglob("*.py")}
    public = {m for m in modules if not any(part.startswith("_") for part in m.split(".")[1:])
              and not m.startswith("triplesumo.benchmarks")}
    assert public - documented == set(), f"modules missing from docs/api/: {sorted(public - documented)}"


LITERAL_ROLE = re.compile(r":(?:py:)?(?:class|meth|func|data|mod|attr|obj|exc|const):`")


def test_sphinx_roles_become_optional_cross_references_shown_as_code() -> None:
    convert = _docs_module("griffe_roles").convert_roles
    ref = '<autoref identifier="{}" optional>`{}`</autoref>'.format
    assert convert("a :class:`~triplesumo.algos.replay.ReplayBuffer`.") == \
        f"a {ref('triplesumo.algos.replay.ReplayBuffer', 'ReplayBuffer')}."
    assert convert(":func:`triplesumo.rules.outcome.place_value`") == \
        ref("triplesumo.rules.outcome.place_value", "triplesumo.rules.outcome.place_value")
    # a relative target shows as written, under the path the resolver gives (none: the target itself)
    assert convert("see :meth:`DDPG.update`") == f"see {ref('DDPG.update', 'DDPG.update')}"
    paths = {("DDPG.update", "meth"): "triplesumo.algos.ddpg.DDPG.update"}
    assert convert("see :meth:`DDPG.update`", lambda t, r: paths.get((t, r))) == \
        f"see {ref('triplesumo.algos.ddpg.DDPG.update', 'DDPG.update')}"
    assert convert(":meth:`MatchBatch.step_arrays <triplesumo.envs.batch.MatchBatch.step_arrays>`") == \
        ref("triplesumo.envs.batch.MatchBatch.step_arrays", "MatchBatch.step_arrays")
    assert convert(":mod:`.rewards`, :py:data:`~.OUTCOMES`") == \
        f"{ref('rewards', 'rewards')}, {ref('OUTCOMES', 'OUTCOMES')}"
    for role in ("attr", "data", "mod", "exc", "obj", "const"):
        assert not LITERAL_ROLE.search(convert(f"x :{role}:`a.b` y")), role
    # inline code keeps a role literally (a docstring may show one), and text without roles is unchanged
    assert convert("``:class:`X` `` and :class:`X`") == f"``:class:`X` `` and {ref('X', 'X')}"
    assert convert("no roles: `code`, a: b") == "no roles: `code`, a: b"


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None, reason="needs the docs extra (mkdocs)")
@pytest.mark.slow  # 11 s alone on the shared 2-core box
def test_site_builds_strict(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (tmp_path / "site" / "environments" / "paper.html").is_file()
    assert "TripleSumoParallelEnv" in (tmp_path / "site" / "api" / "envs.html").read_text()
    # docs/hooks.py serves the linked files outside docs/ and under the excluded docs/runs/, and only those
    assert 'src="runs/reproduction-v1/compare/compare.png"' in (tmp_path / "site" / "REPRODUCTION.html").read_text()
    assert (tmp_path / "site" / "runs" / "reproduction-v1" / "compare" / "compare.png").is_file()
    # a file outside docs/
    assert 'href="repo/examples/rllib_bug_ppo.py"' in (tmp_path / "site" / "ray-rllib.html").read_text()
    assert (tmp_path / "site" / "repo" / "examples" / "rllib_bug_ppo.py").is_file()
    assert 'src="runs/contest-v2/reproduce/bug/learn%3Dbug%3Dsac%2Cseed%3D0/plots/mwr.png"' in (
        tmp_path / "site" / "CONTEST.html").read_text()  # the contest page's figure, from docs/runs
    assert (tmp_path / "site" / "runs" / "contest-v2" / "reproduce" / "bug" / "learn=bug=sac,seed=0" / "plots" /
            "mwr.png").is_file()
    assert (tmp_path / "site" / "runs" / "league" / "leaderboard.png").is_file()
    # the records behind the result pages are built, and the nav does not list them
    assert (tmp_path / "site" / "notes" / "contest-log.html").is_file()
    assert 'href="notes/' not in (tmp_path / "site" / "ratings.html").read_text().split('class="md-content"')[0]
    assert not (tmp_path / "site" / "runs" / "league" / "matches.csv").exists()
    # docs/griffe_roles.py: no Sphinx role is left literally in the API reference; a resolved one is a link
    api = {p.name: p.read_text() for p in (tmp_path / "site" / "api").glob("*.html")}
    literal = {name: LITERAL_ROLE.findall(text)[:3] for name, text in api.items() if LITERAL_ROLE.search(text)}
    assert not literal, f"Sphinx roles shown literally: {literal}"
    assert 'href="#triplesumo.algos.base.Algorithm"><code>Algorithm</code></a>' in api["algos.html"]


# ------------------------------------------------------------------ code examples
_PY_BLOCK = re.compile(r"(?:^<!--[ \t]*(example|no-test):[ \t]*([^\n]*?)[ \t]*-->[ \t]*\n)?^```python\n(.*?)^```",
                       re.S | re.M)
NOT_RUN_HERE = {"docs/gpu.md": 1, "docs/ray-rllib.md": 1}
"""Blocks marked ``<!-- no-test: REASON -->`` per page: a change here is a decision, not an accident."""
RUN_WITH_CHECKS = {"docs/libraries.md": 6}
"""Blocks marked ``<!-- example: NAME -->``, run by tests/test_clients.py with checks of their results."""


@dataclass(frozen=True)
class CodeBlock:
    page: str
    """The page, relative to the repository."""
    line: int
    """The line of the block's first line of code."""
    code: str
    marker: str | None
    """``"example"``, ``"no-test"`` or ``None`` (run here)."""
    note: str
    """The example's name, or why the block is not run."""


def python_blocks(page: Path) -> list[CodeBlock]:
    """The ``python`` code blocks of a page, with their markers."""
    text = page.read_text()
    return [CodeBlock(page.relative_to(ROOT).as_posix(), text.count("\n", 0, m.start(3)) + 1, m.group(3), m.group(1),
                      m.group(2)) for m in _PY_BLOCK.finditer(text)]


def example_pages() -> list[Path]:
    return [p for p in (README, *site_pages()) if python_blocks(p)]


def test_python_blocks_are_found_with_their_markers() -> None:
    blocks = python_blocks(DOCS / "libraries.md")
    assert [b.note for b in blocks if b.marker == "example"][:2] == ["gymnasium-vector", "sb3"]
    lines = (DOCS / "libraries.md").read_text().splitlines()
    assert blocks[0].code.startswith("import gymnasium as gym\n") and lines[blocks[0].line - 2:blocks[0].line] == [
        "```python", "import gymnasium as gym"]  # line: the block's first line of code, for tracebacks
    gpu = python_blocks(DOCS / "gpu.md")
    assert [b.marker for b in gpu] == ["no-test"] and "CUDA" in gpu[0].note


def test_every_python_block_runs_or_says_why_not() -> None:
    blocks = [b for p in example_pages() for b in python_blocks(p)]
    counts: dict[str, dict[str, int]] = {"no-test": {}, "example": {}}
    for b in blocks:
        if b.marker is not None:
            counts[b.marker][b.page] = counts[b.marker].get(b.page, 0) + 1
    silent = [f"{b.page}:{b.line}" for b in blocks if b.marker is not None and not b.note]
    assert not silent, f"a marked block must say why it is not run here (or name its example): {silent}"
    assert counts["no-test"] == NOT_RUN_HERE, counts["no-test"]
    assert counts["example"] == RUN_WITH_CHECKS, counts["example"]
    assert sum(b.marker is None for b in blocks) >= 10


_RUN_BLOCKS = """
import json, sys, time
for name, line, code in json.loads(sys.stdin.read()):
    print(f"--- {name}:{line}", flush=True)
    start = time.perf_counter()
    try:
        exec(compile("\\n" * (line - 1) + code, name, "exec"), {"__name__": "__main__"})
    finally:  # each block starts its own Ray, as a reader who runs it alone does
        ray = sys.modules.get("ray")
        if ray is not None and ray.is_initialized():
            ray.shutdown()
    print(f"+++ {time.perf_counter() - start:.1f} s", flush=True)
"""


PAGE_SECONDS = 480
"""A page's examples, all of them, in one process: the Ray and RLlib page starts Ray for each of its blocks, which
took over 240 s on a 2-core box shared with training runs."""


@pytest.mark.parametrize("page", example_pages(), ids=lambda p: str(p.relative_to(ROOT)))
@pytest.mark.slow  # 98 s alone on the shared 2-core box
def test_the_python_blocks_of_a_page_run(page: Path, tmp_path: Path) -> None:
    """A page's unmarked blocks, each in a fresh namespace (so each has its own imports), in one fresh process
    (imports are paid once) whose working folder is empty (what a block writes lands there)."""
    blocks = [(b.page, b.line, b.code) for b in python_blocks(page) if b.marker is None]
    if not blocks:
        pytest.skip("every block is marked (run in tests/test_clients.py, or not here)")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "MUJOCO_GL": "egl", "OMP_NUM_THREADS": "1", "RAY_DEDUP_LOGS": "0"}
    try:
        proc = subprocess.run([sys.executable, "-c", _RUN_BLOCKS], input=json.dumps(blocks), capture_output=True,
                              text=True, timeout=PAGE_SECONDS, env=env, cwd=tmp_path)
    except subprocess.TimeoutExpired as exc:
        raise AssertionError(f"{page.relative_to(ROOT)}: the examples did not finish in {PAGE_SECONDS} s") from exc
    ran = re.findall(r"^--- (\S+)$", proc.stdout, re.M)
    assert proc.returncode == 0, (f"{ran[-1] if ran else page}: the example failed\n--- stderr ---\n"
                                  f"{proc.stderr[-4000:]}")
    assert len(ran) == len(blocks)
