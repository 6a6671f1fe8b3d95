"""The extras of pyproject.toml and the table the commands name them from (triplesumo/_extras.py) agree.

``pip install triplesumo`` is the environments alone; tests/test_wheel.py installs that in a fresh venv and runs it.
Here, in the full venv: each module a command expects of an extra comes with that extra, torch is bounded wherever
an extra brings it, and the message a command prints names the extra to install.
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from packaging.requirements import Requirement

from triplesumo import _extras, cli

PYPROJECT = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
OPTIONAL = PYPROJECT["optional-dependencies"]
NEEDS_TORCH = {"torch", "stable-baselines3", "ray", "torchrl", "tensordict", "mujoco-warp"}
"""Distributions that are torch or bring it (or, for mujoco-warp, whose backend hands torch tensors)."""


def norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def expand(extra: str) -> set[str]:
    """The distributions an extra names, its ``triplesumo[...]`` references followed."""
    out: set[str] = set()
    for line in OPTIONAL[extra]:
        req = Requirement(line)
        if norm(req.name) == "triplesumo":
            for inner in req.extras:
                out |= expand(inner)
        else:
            out.add(norm(req.name))
    return out


def brought_by(names: set[str]) -> set[str]:
    """``names`` and what each of them requires (one level, any of its own extras: imageio[ffmpeg] brings
    imageio-ffmpeg, rliable brings scipy)."""
    out = set(names)
    for name in names:
        out |= {norm(Requirement(line).name) for line in md.requires(name) or []}
    return out


def test_the_core_is_the_environments_and_the_zoo_reader_only() -> None:
    assert {norm(Requirement(line).name) for line in PYPROJECT["dependencies"]} == {
        "mujoco", "gymnasium", "pettingzoo", "numpy", "safetensors"}


@pytest.mark.parametrize("extra", sorted(_extras.EXTRAS))
def test_each_module_a_command_expects_of_an_extra_comes_with_it(extra: str) -> None:
    dists = md.packages_distributions()
    installed = brought_by(expand(extra))
    for module in _extras.EXTRAS[extra]:
        (dist, *_) = dists[module]
        assert norm(dist) in installed, f"[{extra}] does not install {module} ({dist})"


def test_all_is_train_eval_and_video_and_test_holds_every_extra_but_the_docs() -> None:
    assert _extras.ALL == ("train", "eval", "video")
    assert expand("all") == expand("train") | expand("eval") | expand("video")
    for extra in set(OPTIONAL) - {"docs", "test"}:
        assert expand(extra) <= expand("test"), extra
    assert set(_extras.EXTRAS) == set(OPTIONAL) - {"all", "docs", "test"}


@pytest.mark.parametrize("extra", sorted(OPTIONAL))
def test_every_extra_that_brings_torch_bounds_it(extra: str) -> None:
    own = {norm(Requirement(line).name): Requirement(line) for line in OPTIONAL[extra]}
    if not set(own) & NEEDS_TORCH:
        return
    assert "torch" in own, f"[{extra}] brings torch through {set(own) & NEEDS_TORCH} without bounding it"
    spec = own["torch"].specifier
    assert spec.contains("2.13.0") and not spec.contains("2.14.0") and not spec.contains("3.0"), (extra, spec)


def test_the_commands_named_are_commands_and_their_extras_are_extras() -> None:
    sub = next(a for a in cli._parser("")._actions if isinstance(a, argparse._SubParsersAction))
    assert set(_extras.COMMAND_EXTRAS) <= set(sub.choices)
    assert {e for extras in _extras.COMMAND_EXTRAS.values() for e in extras} <= set(_extras.EXTRAS)


@pytest.mark.parametrize(("command", "module", "message"), [
    ("train", "torch", 'triplesumo train needs PyTorch: pip install "triplesumo[train]"'),
    ("train", "torch.utils.tensorboard", 'triplesumo train needs PyTorch: pip install "triplesumo[train]"'),
    ("demo", "torch", 'triplesumo demo needs PyTorch: pip install "triplesumo[all]"'),  # once, not per extra
    ("demo", "imageio", 'triplesumo demo needs imageio (ffmpeg): pip install "triplesumo[all]"'),
    ("evaluate", "tqdm", 'triplesumo evaluate needs tqdm: pip install "triplesumo[eval]"'),
    ("train", "tqdm", 'triplesumo train needs tqdm: pip install "triplesumo[train]"'),
    ("play", "imageio", 'triplesumo play needs imageio (ffmpeg): pip install "triplesumo[video]"'),
    ("sweep", "ray", 'triplesumo sweep needs Ray: pip install "triplesumo[ray]"'),
    ("compact", "torch", 'triplesumo compact needs PyTorch: pip install "triplesumo[train]"'),
    ("play", "mujoco_warp", 'triplesumo play needs MuJoCo Warp: pip install "triplesumo[gpu]"'),
    ("train", "yaml", None),  # no extra installs it: a bug, whose traceback shows
])
def test_a_missing_module_names_the_extra_to_install(command: str, module: str, message: str | None) -> None:
    assert _extras.missing_message(command, module) == message


def test_make_policy_plays_a_policy_file_with_torch_where_installed_or_numpy_on_request() -> None:
    from triplesumo.agents.frozen import FrozenPolicy
    from triplesumo.agents.networks import ActorPolicy
    from triplesumo.zoo import make_policy

    default, torch_actor, numpy_actor = (make_policy("zoo:ant", frozen=f) for f in (None, False, True))
    assert isinstance(default, ActorPolicy) and isinstance(torch_actor, ActorPolicy)  # torch is installed here
    assert isinstance(numpy_actor, FrozenPolicy)  # what a core install (no torch) gets by default
    obs = np.random.default_rng(0).normal(size=(16, numpy_actor.obs_dim)).astype(np.float32)
    np.testing.assert_allclose(numpy_actor(obs), torch_actor(obs), atol=1e-4)


@pytest.mark.parametrize("argv", [["reproduce", "--tiny", "--backend", "warp", "--device", "cpu", "--algos", "sac"],
                                  ["train", "--backend", "warp", "--device", "cpu", "--epochs", "1"]])
def test_backend_warp_without_the_gpu_extra_is_refused_before_it_starts(
        argv: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "mujoco_warp" else real(name, *a))
    out = tmp_path / "out"
    assert cli.main([*argv, "--out", str(out)]) == 2
    assert capsys.readouterr().err == (f'triplesumo {argv[0]} needs MuJoCo Warp: pip install "triplesumo[gpu]"\n')
    assert not out.exists()  # nothing started: no folder, no record


def test_require_passes_where_everything_is_installed() -> None:
    for command in _extras.COMMAND_EXTRAS:
        _extras.require(command, ("video",))  # (the refusals: tests/test_wheel.py, in a venv without the extras)
