"""Griffe extension (mkdocs.yml, mkdocstrings ``extensions:``): Sphinx roles in docstrings as code and links.

The docstrings cross-reference with Sphinx roles (``:class:`~triplesumo.algos.replay.ReplayBuffer```,
``:meth:`DDPG.update```, ``:func:``, ``:data:``, ``:mod:``, ``:attr:``), which Markdown would show
literally. Once griffe has loaded the package, this rewrites each role into an optional mkdocs-autorefs
cross-reference whose text is the role's target as code: a link where the site documents the target,
plain code where it does not (an optional reference never fails ``mkdocs build --strict``).

As in Sphinx, ``~`` shows only the last component, ``:meth:`text <target>``` shows ``text``, and a
relative target (``DDPG.update``, ``step``) is looked up in the documented object's scope (its class,
its module and their imports); failing that, or for a ``.name`` target, the one object of the package
whose path ends with it.
"""

from __future__ import annotations

import html
import re
from collections.abc import Callable, Sequence
from typing import Any

try:
    from griffe import Extension
except ImportError:  # convert_roles needs no griffe (tests/test_docs.py runs without the docs extra)
    Extension = object  # type: ignore[assignment,misc]

ROLE = re.compile(r":(?:py:)?(?P<role>class|meth|func|data|mod|attr|obj|exc|const):`(?P<body>[^`]+)`")
"""A Sphinx Python role: ``:class:`X```, ``:py:meth:`~a.b.C.m```, ``:func:`text <a.b.f>```."""
_ROLE_OR_CODE = re.compile(rf"{ROLE.pattern}|(?P<ticks>`+).+?(?P=ticks)", re.S)
KINDS = {"class": "class", "exc": "class", "meth": "function", "func": "function", "attr": "attribute",
         "data": "attribute", "const": "attribute", "mod": "module"}
"""The griffe kind (``Object.kind.value``) each role names; ``obj`` names any."""
_TITLED = re.compile(r"(?P<title>.*?)\s*<(?P<target>[^<>]+)>", re.S)


def convert_roles(text: str, resolve: Callable[[str, str], str | None] | None = None) -> str:
    """The text with each Sphinx role replaced by an optional cross-reference shown as code.

    ``resolve`` maps a target as written (less ``~``) and its role to its full dotted path, or ``None`` where it
    cannot; the identifier is then the target as written, and one the site does not document renders
    as plain code. Inline code (``` ``:class:`X` `` ```) is left alone.
    """

    def role(m: re.Match[str]) -> str:
        if m.group("body") is None:  # inline code
            return m.group(0)
        body = " ".join(m.group("body").split())
        titled = _TITLED.fullmatch(body)
        if titled:
            title, target = titled.group("title"), titled.group("target").strip()
        else:
            target = body.lstrip("!~")
            title = target.lstrip(".")
            if body.lstrip("!").startswith("~"):
                title = title.rsplit(".", 1)[-1]
        identifier = (resolve(target, m.group("role")) if resolve else None) or target.lstrip(".")
        return f'<autoref identifier="{html.escape(identifier)}" optional>`{title}`</autoref>'

    return _ROLE_OR_CODE.sub(role, text)


def scope_resolver(obj: Any, paths: Sequence[tuple[str, str]] = (),
                   collection: Any = None) -> Callable[[str, str], str | None]:
    """Resolve a role's target for the docstring of griffe object ``obj``.

    The first component through ``obj``'s, its parents' and its module's names and imports, the rest
    appended; where that fails, or for a ``.name`` target, the one of ``paths`` (path and griffe kind)
    of the role's kind that ends with the target (if exactly one does; else the target as written);
    then, for an alias the ``collection`` (griffe's modules collection) knows, its target's path.
    """

    def resolve(target: str, role: str = "obj") -> str | None:
        path = None
        if not target.startswith("."):
            first, _, rest = target.partition(".")
            try:
                path = obj.resolve(first)
            except Exception:  # noqa: BLE001 - griffe's NameResolutionError, or an alias it cannot follow
                path = None
            else:
                path = f"{path}.{rest}" if rest else path
        if path is None:
            suffix = "." + target.lstrip(".")
            found = [p for p, kind in paths if p.endswith(suffix) and KINDS.get(role, kind) == kind]
            path = found[0] if len(found) == 1 else target.lstrip(".")
        if collection is not None:
            try:
                path = collection[path].canonical_path
            except Exception:  # noqa: BLE001 - unknown to griffe (another package, or no such object)
                pass
        return path

    return resolve


class SphinxRoles(Extension):  # type: ignore[misc,valid-type]
    """Rewrite the Sphinx roles of every docstring of a loaded package (see the module docstring)."""

    def on_package(self, *, pkg: Any, loader: Any, **kwargs: Any) -> None:
        objects, stack = [], [pkg]
        while stack:
            obj = stack.pop()
            if not obj.is_alias:
                objects.append(obj)
                stack.extend(obj.members.values())
        paths = [(obj.path, obj.kind.value) for obj in objects]
        for obj in objects:
            if obj.docstring is not None and ROLE.search(obj.docstring.value):
                resolve = scope_resolver(obj, paths, loader.modules_collection)
                obj.docstring.value = convert_roles(obj.docstring.value, resolve)
                obj.docstring.__dict__.pop("parsed", None)  # parsed again from the new text
