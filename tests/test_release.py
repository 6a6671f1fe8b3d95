"""What a released library carries: its licence, how to cite it (and the paper it reimplements), a changelog, one
version everywhere, and the source distribution holding them."""

from __future__ import annotations

import re
import subprocess
import sys
import tarfile
import tomllib
from pathlib import Path
from typing import Any

import pytest

import triplesumo

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT: dict[str, Any] = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def _citation() -> dict[str, Any]:
    yaml = pytest.importorskip("yaml")
    data = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert isinstance(data, dict)
    return data


def test_the_licence_is_mit_and_pyproject_says_so() -> None:
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License\n") and "Copyright (c) 2026 The TripleSumo developers" in text
    assert "THE SOFTWARE IS PROVIDED \"AS IS\"" in text
    assert PYPROJECT["license"] == "MIT" and PYPROJECT["license-files"] == ["LICENSE"]
    assert PYPROJECT["readme"] == "README.md" and (ROOT / "README.md").is_file()


def test_one_version_in_the_package_pyproject_citation_and_changelog() -> None:
    version = triplesumo.__version__
    assert re.fullmatch(r"\d+\.\d+\.\d+", version)
    assert PYPROJECT["version"] == version
    assert str(_citation()["version"]) == version
    headings = re.findall(r"^## \[(\d+\.\d+\.\d+)\] - \d{4}-\d{2}-\d{2}$", (ROOT / "CHANGELOG.md").read_text(), re.M)
    assert headings and headings[0] == version, headings  # the newest entry is this release


def test_the_citation_is_cff_1_2_0_citing_this_project_and_the_paper() -> None:
    cff = _citation()
    assert cff["cff-version"] == "1.2.0"
    for key in ("message", "title", "authors"):  # what CFF 1.2.0 requires
        assert cff[key], key
    assert cff["type"] == "software" and cff["license"] == "MIT" and "TripleSumo" in cff["title"]
    (paper,) = [r for r in cff["references"] if r["type"] == "conference-paper"]
    assert paper["title"] == "Learning Cooperative Behaviours in Adversarial Multi-agent Systems"
    assert [a["family-names"] for a in paper["authors"]] == ["Wang", "Das", "Millard"]
    assert "TAROS 2022" in paper["collection-title"] and paper["year"] == 2022 and paper["volume"] == 13546
    assert paper["doi"].startswith("10.1007/")


def test_the_changelog_starts_with_env_v0_v1_v2_and_names_this_env_version() -> None:
    text = (ROOT / "CHANGELOG.md").read_text()
    assert "Keep a Changelog" in text
    envs = re.findall(r"^### Env (v\d+)", text, re.M)
    assert envs == ["v2", "v1", "v0"], envs  # newest first, as every entry
    assert triplesumo.ENV_VERSION == envs[0]


def test_the_source_distribution_carries_the_licence_changelog_and_citation(tmp_path: Path) -> None:
    """Built as a user's ``pip`` would (setuptools' PEP 517 backend), into a temporary folder."""
    made = subprocess.run([sys.executable, "-c", "import sys, setuptools.build_meta as b; "
                           "print(b.build_sdist(sys.argv[1]))", str(tmp_path)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr[-3000:]
    sdist = tmp_path / made.stdout.strip().splitlines()[-1]
    with tarfile.open(sdist) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    assert {"LICENSE", "CHANGELOG.md", "CITATION.cff", "README.md", "pyproject.toml"} <= names
