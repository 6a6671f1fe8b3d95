"""Command-line options generated from frozen config dataclasses.

Each field becomes ``--field-name`` (nested dataclasses: ``--outer.field-name``) with
its type, its default and its attribute docstring as help, so the CLI can never drift
from the configs. Values are validated by the dataclasses themselves.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import textwrap
import types
import typing
from functools import cache
from typing import Any


@cache
def field_docs(cls: type) -> dict[str, str]:
    """Attribute docstrings (the string literal under each field) of a dataclass and its bases."""
    docs: dict[str, str] = {}
    for base in reversed(cls.__mro__[1:]):
        if dataclasses.is_dataclass(base):
            docs |= field_docs(base)
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return docs
    body = ast.parse(source).body[0].body  # type: ignore[attr-defined]
    for node, nxt in zip(body, body[1:], strict=False):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                and isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant)
                and isinstance(nxt.value.value, str)):
            docs[node.target.id] = " ".join(nxt.value.value.split())
    return docs


def _flag(prefix: str, name: str) -> str:
    return "--" + prefix + name.replace("_", "-")


def add_arguments(parser: argparse.ArgumentParser, cls: type, prefix: str = "",
                  skip: tuple[str, ...] = (), defaults: Any = None) -> None:
    """Add one option per field of dataclass ``cls`` (recursing into nested dataclasses). The help gives each
    field's value in ``defaults`` (``cls()`` if None; a nested dataclass: its value in the outer default)."""
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    defaults = cls() if defaults is None else defaults
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        tp: Any = hints[f.name]
        default = getattr(defaults, f.name)
        dest = (prefix + f.name).replace(".", "__")
        if dataclasses.is_dataclass(tp):
            add_arguments(parser, typing.cast(type, tp), prefix=f"{prefix}{f.name}.", defaults=default)
            continue
        help_text = f"{docs.get(f.name, '')} (default: {default!r})".strip()
        kwargs: dict[str, Any] = {"dest": dest, "default": argparse.SUPPRESS, "help": help_text}
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if tp is bool:
            parser.add_argument(_flag(prefix, f.name), action=argparse.BooleanOptionalAction, **kwargs)
        elif origin is tuple:
            parser.add_argument(_flag(prefix, f.name), nargs="*", type=args[0], metavar=args[0].__name__.upper(),
                                **kwargs)
        elif origin in (typing.Union, types.UnionType):
            inner = next(a for a in args if a is not type(None))
            if typing.get_origin(inner) is tuple:  # tuple | None: None unless the option is given (maybe empty)
                item = typing.get_args(inner)[0]
                parser.add_argument(_flag(prefix, f.name), nargs="*", type=item, metavar=item.__name__.upper(),
                                    **kwargs)
            else:
                parser.add_argument(_flag(prefix, f.name), type=inner, metavar=inner.__name__.upper(), **kwargs)
        else:
            parser.add_argument(_flag(prefix, f.name), type=tp, metavar=tp.__name__.upper(), **kwargs)


def build(cls: type, namespace: argparse.Namespace, prefix: str = "", base: Any = None) -> Any:
    """Instantiate ``cls`` from parsed options; fields not given keep ``base``'s (or default) values."""
    hints = typing.get_type_hints(cls)
    base = base if base is not None else cls()
    values: dict[str, Any] = {}
    given = vars(namespace)
    for f in dataclasses.fields(cls):
        dest = (prefix + f.name).replace(".", "__")
        if dataclasses.is_dataclass(hints[f.name]):
            values[f.name] = build(hints[f.name], namespace, prefix=f"{prefix}{f.name}.",
                                   base=getattr(base, f.name))
        elif dest in given:
            value = given[dest]
            values[f.name] = tuple(value) if isinstance(value, list) else value
    return dataclasses.replace(base, **values)


def to_argv(obj: Any, prefix: str = "", defaults: Any = None) -> list[str]:
    """The options that rebuild dataclass ``obj`` from its class defaults (inverse of :func:`build`); ``defaults``:
    the values to rebuild from instead (a nested dataclass: its value in the outer default)."""
    cls = type(obj)
    hints = typing.get_type_hints(cls)
    defaults = cls() if defaults is None else defaults
    argv: list[str] = []
    for f in dataclasses.fields(cls):
        value, default = getattr(obj, f.name), getattr(defaults, f.name)
        if dataclasses.is_dataclass(hints[f.name]):
            argv += to_argv(value, prefix=f"{prefix}{f.name}.", defaults=default)
        elif value != default:
            flag = _flag(prefix, f.name)
            if hints[f.name] is bool:
                argv.append(flag if value else "--no-" + flag[2:])
            elif isinstance(value, tuple):
                argv += [flag, *map(str, value)]
            elif value is not None:
                argv += [flag, str(value)]
    return argv
