"""Data flows one way: a module imports only what stands to its left (STYLE.md).

    model -> sim -> rules -> envs -> agents / algos -> evaluation / train / benchmarks / integrations -> cli

Checked on the source with ``ast`` (imports inside functions count too), plus the
third-party imports each layer must not make (torch below agents, gymnasium and
pettingzoo in the game rules).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "triplesumo"

LEVEL = {
    "_gl": 0, "model": 0, "sim": 1, "rules": 2, "envs": 3, "registration": 3,
    "agents": 4, "algos": 4, "evaluation": 5, "train": 5, "benchmarks": 5, "integrations": 5,
    "zoo": 6, "demo": 6, "reproduce": 6, "cli": 7, "_dcargs": 7,
}
FORBIDDEN_THIRD_PARTY = {
    "model": {"torch", "gymnasium", "pettingzoo"},
    "sim": {"torch", "gymnasium", "pettingzoo"},
    "rules": {"torch", "gymnasium", "pettingzoo"},
    "envs": {"torch"},
    "evaluation/metrics.py": {"torch", "gymnasium", "pettingzoo", "mujoco"},
    "evaluation/stats.py": {"torch", "gymnasium", "pettingzoo", "mujoco"},
}

EXCEPTIONS = {
    # The MuJoCo Warp backend hands out torch tensors that share memory with the GPU
    # simulator (the batched API's contract); it is imported only for backend="warp".
    "envs/warp.py": {"torch"},
}
"""Single modules allowed one of their layer's forbidden imports, each with its reason."""


def _part(path: Path) -> str:
    rel = path.relative_to(SRC)
    return rel.parts[0].removesuffix(".py")


def _imports(path: Path) -> list[str]:
    names: list[str] = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return names


MODULES = sorted(p for p in SRC.rglob("*.py") if p.name != "__init__.py" or p.parent != SRC)


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(SRC)))
def test_module_imports_only_leftwards(path: Path) -> None:
    here = _part(path)
    assert here in LEVEL, f"{here} has no place in the layer map of this test"
    for name in _imports(path):
        if not name.startswith("triplesumo."):
            continue
        target = name.split(".")[1]
        if target in ("_gl",):
            continue
        assert LEVEL[target] <= LEVEL[here], f"{path.relative_to(SRC)} imports {name} (a layer to its right)"


@pytest.mark.parametrize("where", sorted(FORBIDDEN_THIRD_PARTY))
def test_layers_do_not_import_frameworks_they_must_not_know(where: str) -> None:
    target = SRC / where
    files = [target] if target.suffix == ".py" else sorted(target.rglob("*.py"))
    for path in files:
        used = {name.split(".")[0] for name in _imports(path)}
        bad = used & FORBIDDEN_THIRD_PARTY[where] - EXCEPTIONS.get(str(path.relative_to(SRC)), set())
        assert not bad, f"{path.relative_to(SRC)} imports {sorted(bad)}"


@pytest.mark.parametrize("where", ["agents", "algos"])
def test_agents_and_algorithms_take_array_sizes_not_envs(where: str) -> None:
    for path in sorted((SRC / where).rglob("*.py")):
        for name in _imports(path):
            parts = name.split(".")
            below = ("envs", "sim", "rules", "model")
            assert not (parts[0] == "triplesumo" and len(parts) > 1 and parts[1] in below), (
                f"{path.relative_to(SRC)} imports {name}")


def test_the_layer_check_can_fail(tmp_path: Path) -> None:
    bad = tmp_path / "x.py"
    bad.write_text("def f():\n    from triplesumo.train.loop import Trainer\n")
    assert "triplesumo.train.loop" in _imports(bad)
