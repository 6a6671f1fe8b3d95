"""Data flows one way (docs/layout.md): the import-linter contracts in ``pyproject.toml`` hold, cover every module,
and fail on a planted upward import and a planted import circle.

    cli -> reproduce | demo | benchmarks -> integrations -> train -> evaluation -> algos | zoo -> agents
        -> envs -> registration -> rules -> sim -> model | version | _gl | _dcargs
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

pytest.importorskip("importlinter", reason='import-linter comes with the "test" extra')

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "triplesumo"
CONFIG = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["importlinter"]
CONTRACTS = {c["id"]: c for c in CONFIG["contracts"]}


def lint_imports(root: Path, *contracts: str) -> subprocess.CompletedProcess[str]:
    """``lint-imports`` on the package under ``root/src`` with the contracts of ``root/pyproject.toml``."""
    script = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")
    assert script, "lint-imports is not installed (the test extra has import-linter)"
    args = [script, "--no-cache", "--no-logo", *(a for c in contracts for a in ("--contract", c))]
    return subprocess.run(args, cwd=root, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(root / "src")})


def layer_names(contract: dict) -> set[str]:
    return {name.strip().strip("()") for layer in contract["layers"] for name in re.split(r"[|:]", layer)}


def test_the_contracts_are_kept() -> None:
    result = lint_imports(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"Contracts: {len(CONTRACTS)} kept, 0 broken." in result.stdout


def test_no_contract_ignores_an_import() -> None:
    assert {"layers", "acyclic"} <= CONTRACTS.keys()
    assert not [c["id"] for c in CONTRACTS.values() if "ignore_imports" in c]


def test_every_module_belongs_to_a_layer() -> None:
    layers = CONTRACTS["layers"]
    assert layers["containers"] == ["triplesumo"] and layers["exhaustive"]
    names = layer_names(layers)
    modules = [p for p in SRC.rglob("*.py") if p != SRC / "__init__.py"]  # (the package root is the container)
    assert len(modules) > 50
    homeless = sorted(str(p.relative_to(SRC)) for p in modules if p.relative_to(SRC).parts[0].removesuffix(".py")
                      not in names)
    assert not homeless, f"modules in no layer of the contract: {homeless}"
    assert all((SRC / name).is_dir() or (SRC / f"{name}.py").is_file() for name in names), names


def test_the_envs_without_torch_are_every_env_module_but_the_warp_backend_and_its_chooser() -> None:
    contract = CONTRACTS["envs-without-torch"]
    listed = set(contract["source_modules"])
    every = {"triplesumo.envs." + p.stem for p in (SRC / "envs").glob("*.py") if p.stem != "__init__"}
    assert listed == {"triplesumo.envs"} | every - {"triplesumo.envs.warp", "triplesumo.envs.backends"}
    assert not contract.get("allow_indirect_imports", False)  # no chain of imports reaches torch either


def _planted_copy(tmp_path: Path) -> Path:
    shutil.copytree(SRC, tmp_path / "src" / "triplesumo", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    return tmp_path


def _plant(root: Path, module: str, line: str) -> None:
    path = root / "src" / "triplesumo" / f"{module}.py"
    path.write_text(path.read_text(encoding="utf-8") + f"\n\ndef _planted() -> None:\n    {line}\n", encoding="utf-8")


def test_a_planted_upward_import_breaks_the_layers(tmp_path: Path) -> None:
    root = _planted_copy(tmp_path)
    _plant(root, "rules/config", "from triplesumo.train.loop import Trainer  # noqa")  # inside a function: counted
    result = lint_imports(root, "layers")
    assert result.returncode != 0
    assert "BROKEN" in result.stdout and "triplesumo.rules is not allowed to import triplesumo.train" in result.stdout
    assert "triplesumo.rules.config -> triplesumo.train.loop" in result.stdout


def test_a_planted_circle_breaks_the_acyclic_contract(tmp_path: Path) -> None:
    root = _planted_copy(tmp_path)
    # two modules of one layer (the layers contract allows it), where train.loop already imports train.checkpoint
    _plant(root, "train/checkpoint", "import triplesumo.train.loop  # noqa")
    assert lint_imports(root, "layers").returncode == 0
    result = lint_imports(root, "acyclic")
    assert result.returncode != 0
    assert "No cycles are allowed in triplesumo.train." in result.stdout


@pytest.mark.slow  # 8 s alone on the shared 2-core box
def test_evaluation_and_train_import_neither_ray_nor_the_integrations() -> None:
    """Parallel execution is handed down (a task runner): importing every module of evaluation and train, and
    running a tiny evaluation on a thread runner, imports neither Ray nor triplesumo.integrations."""
    names = sorted(f"triplesumo.{p.relative_to(SRC).with_suffix('').as_posix().replace('/', '.')}"
                   for folder in ("evaluation", "train") for p in (SRC / folder).rglob("*.py"))
    script = (
        "import importlib, sys, tempfile\n"
        f"for name in {names!r}:\n"
        "    importlib.import_module(name.removesuffix('.__init__'))\n"
        "from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate\n"
        "from triplesumo.evaluation.parallel import ThreadRunner\n"
        "with tempfile.TemporaryDirectory() as out:\n"
        "    evaluate(EvaluateConfig(policy=('random',), baselines=(), epochs=2, steps_per_epoch=10, n_envs=2,\n"
        "                            progress=False, out=out, ray_chunk=1), ThreadRunner(2))\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] == 'ray' or m.startswith('triplesumo.integrations'))\n"
        "assert not bad, bad\n"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600,
                            env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert result.returncode == 0, result.stderr
