"""MkDocs hook (mkdocs.yml ``hooks:``): serve the repository files that the pages link to.

Pages link run outputs kept in the repository: plots and CSVs under ``docs/runs/`` (left out of
the site as a whole for its size, ``exclude_docs``) and files outside ``docs/``
(``../examples/``). This adds exactly the linked files
that exist to the site, those outside ``docs/`` under ``repo/``, and points the links there,
so that links and images work on the site as they do on a Git host.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files, InclusionLevel

_LINK = re.compile(r"(!?\[[^\]]*\]\()([^)\s#]+)(#[^)\s]*)?(\))")
REPO_PREFIX = "repo"
_outside: dict[str, str] = {}
"""Link target as written from the docs root (``../x/y.png``) -> its site path (``repo/x/y.png``)."""


def _targets(page_uri: str, text: str) -> list[str]:
    """The page's relative link targets, normalised from the docs root."""
    base = posixpath.dirname(page_uri)
    return [posixpath.normpath(posixpath.join(base, m.group(2))) for m in _LINK.finditer(text)
            if not re.match(r"[a-z]+:", m.group(2)) and not m.group(2).startswith("/")]


def on_files(files: Files, config: Any) -> Files:
    docs = Path(config.docs_dir)
    root = docs.parent
    _outside.clear()
    for page in list(files.documentation_pages()):
        text = Path(page.abs_src_path).read_text(encoding="utf-8")
        for target in _targets(page.src_uri, text):
            if target.startswith("../"):
                path = (docs / target).resolve()
                if path.is_file() and path.is_relative_to(root) and target not in _outside:
                    uri = f"{REPO_PREFIX}/{path.relative_to(root).as_posix()}"
                    _outside[target] = uri
                    files.append(File.generated(config, uri, abs_src_path=str(path), inclusion=InclusionLevel.INCLUDED))
            else:
                linked = files.get_file_from_path(target)
                if linked is not None and linked.inclusion.is_excluded():
                    linked.inclusion = InclusionLevel.INCLUDED
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    base = posixpath.dirname(page.file.src_uri)

    def point(m: re.Match[str]) -> str:
        target = posixpath.normpath(posixpath.join(base, m.group(2)))
        if target not in _outside:
            return m.group(0)
        rel = posixpath.relpath(_outside[target], base or ".")
        return f"{m.group(1)}{rel}{m.group(3) or ''}{m.group(4)}"

    return _LINK.sub(point, markdown)

