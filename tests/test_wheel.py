"""The wheel holds the package and its shipped zoo, nothing else (no tests, docs, run folders), in at most 20 MB;
installed alone (``pip install triplesumo``: the core dependencies, no extra) it plays every scenario and the zoo
without torch, and a command that needs an extra names it.

Built from this checkout with pip, as a user's ``pip install`` would build it (issue 40: run folders are outputs,
not source; the zoo is the one set of weights that ships).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "triplesumo"
MAX_BYTES = 20 * 1024 * 1024
SHIPPED_DATA = {".xml", ".json", ".safetensors"}
"""What the package ships besides Python: the MJCF assets and the zoo's manifests and weights."""
WEB = {"triplesumo/evaluation/web/" + name for name in ("three.min.js", "three-LICENSE", "viewer.js", "viewer.css")}
"""The replay page's scripts and styles (three.js vendored with its licence), inlined into every page it writes; the
script that vendors three.js stays in the source tree."""


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w",
                            str(out), str(ROOT)], capture_output=True, text=True, timeout=300)
    assert built.returncode == 0, f"pip wheel failed ({built.returncode}):\n{built.stdout}\n{built.stderr}"
    (built,) = out.glob("triplesumo-*.whl")
    return built


def test_the_wheel_holds_the_package_and_the_zoo_only(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert tops == {"triplesumo", wheel.name.split("-py3")[0] + ".dist-info"}, tops
    strays = [n for n in names if n.startswith("triplesumo/") and not n.endswith("/") and n not in WEB
              and Path(n).suffix not in {".py", *SHIPPED_DATA} and Path(n).name != "py.typed"]
    assert strays == []
    assert WEB <= set(names)
    data = [n for n in names if Path(n).suffix in SHIPPED_DATA]
    assert all(n.startswith(("triplesumo/assets/", "triplesumo/agents/zoo/")) for n in data), data


def test_every_zoo_policy_and_asset_ships(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    zoo = sorted(p.relative_to(PACKAGE.parent).as_posix() for p in (PACKAGE / "agents" / "zoo").iterdir()
                 if p.suffix in {".json", ".safetensors"})
    assets = sorted(p.relative_to(PACKAGE.parent).as_posix() for p in (PACKAGE / "assets").glob("*.xml"))
    assert zoo and assets
    assert set(zoo + assets) <= names
    from triplesumo.agents.zoo import alias_target

    stems = {s for s in {Path(n).stem for n in zoo} if alias_target(s) is None}
    assert all(f"triplesumo/agents/zoo/{s}.json" in names and f"triplesumo/agents/zoo/{s}.safetensors" in names
               for s in stems)  # each policy whole: manifest and weights (an alias: its manifest, naming another)


def test_the_wheel_is_at_most_20_mb(wheel: Path) -> None:
    assert wheel.stat().st_size <= MAX_BYTES, f"{wheel.name}: {wheel.stat().st_size / 2**20:.1f} MiB"


EXTRA_ONLY = {"torch", "matplotlib", "tensorboard", "tqdm", "pandas", "scipy", "rliable", "openskill", "imageio",
              "imageio-ffmpeg", "ray", "mujoco-warp", "stable-baselines3"}
"""Distributions that only an extra installs (pip's names, lower case)."""

CORE_SCRIPT = """
import json, sys
import gymnasium as gym
import numpy as np
import triplesumo
from triplesumo.agents.frozen import FrozenPolicy
from triplesumo.registration import ENV_IDS
from triplesumo.rules.scenarios import SCENARIOS
from triplesumo.zoo import make_policy

out = {"scenarios": {}, "ids": {}}
for name in SCENARIOS:  # the PettingZoo view of every scenario, random actions
    env = triplesumo.parallel_env(scenario=name)
    env.reset(seed=0)
    for _ in range(5):
        _, rewards, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
    out["scenarios"][name] = sorted(rewards)
    env.close()
for env_id in ENV_IDS:  # every Gymnasium id; TripleSumo-Paper plays zoo:ant and zoo:spider
    env = gym.make(env_id)
    env.reset(seed=1)
    for _ in range(5):
        _, reward, *_ = env.step(env.action_space.sample())
    out["ids"][env_id] = float(reward)
    env.close()
policy = make_policy("zoo:ant")
action = policy(np.zeros(policy.obs_dim, np.float32))
out["policy"] = [type(policy).__name__, isinstance(policy, FrozenPolicy), action.shape[0],
                 bool(np.all(np.abs(action) <= 1))]
with triplesumo.vector_env(2, scenario="2v2") as batch:
    obs, _ = batch.reset(seed=0)
    obs, *_ = batch.step(np.zeros((2, batch.n_agents, batch.act_dim), np.float32))
out["vector"] = list(obs.shape)
out["heavy"] = sorted({m.split(".")[0] for m in sys.modules} & {"torch", "matplotlib", "tqdm", "pandas", "scipy",
                                                                 "imageio", "openskill", "rliable", "tensorboard"})
print(json.dumps(out))
"""
"""What a user of the environments alone does: every scenario's PettingZoo view, every Gymnasium id (the paper's
with the zoo's Ant and Spider), a zoo policy by name, a vector env; then which heavy modules it imported."""


@pytest.fixture(scope="module")
def core_venv(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh venv holding the wheel and its core dependencies only, from the registry (pip's cache reused)."""
    where = tmp_path_factory.mktemp("core-venv") / "venv"
    venv.create(where, with_pip=True)
    python = where / "bin" / "python"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    done = subprocess.run([str(python), "-m", "pip", "install", "-q", str(wheel)], capture_output=True, text=True,
                          timeout=300, env=env)
    assert done.returncode == 0, f"pip install {wheel.name} failed:\n{done.stdout}\n{done.stderr}"
    return where


def _run_in(where: Path, *cmd: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{where / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return subprocess.run(list(cmd), capture_output=True, text=True, timeout=300, env=env, cwd=cwd)


@pytest.mark.slow
def test_the_core_install_holds_no_extra(core_venv: Path) -> None:
    listed = subprocess.run([str(core_venv / "bin" / "python"), "-m", "pip", "list", "--format", "json"],
                            capture_output=True, text=True, check=True).stdout
    names = {d["name"].lower().replace("_", "-") for d in json.loads(listed)}
    assert {"triplesumo", "mujoco", "gymnasium", "pettingzoo", "numpy", "safetensors"} <= names, names
    assert names & EXTRA_ONLY == set()


@pytest.mark.slow
def test_the_core_install_plays_every_scenario_and_the_zoo_without_torch(core_venv: Path, tmp_path: Path) -> None:
    from triplesumo.registration import ENV_IDS
    from triplesumo.rules.scenarios import SCENARIOS

    done = _run_in(core_venv, "python", "-c", CORE_SCRIPT, cwd=tmp_path)  # (cwd: not this checkout's src/)
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout.splitlines()[-1])
    assert set(out["scenarios"]) == set(SCENARIOS)
    assert out["scenarios"]["pursuit"] == ["evader", "pursuer_0", "pursuer_1", "pursuer_2"]
    assert set(out["ids"]) == set(ENV_IDS)
    assert out["policy"] == ["FrozenPolicy", True, 8, True]
    assert out["vector"][:2] == [2, 4]  # two matches of the 2v2's four agents
    assert out["heavy"] == []


@pytest.mark.slow
def test_a_command_that_needs_an_extra_names_it(core_venv: Path, tmp_path: Path) -> None:
    train = _run_in(core_venv, "triplesumo", "train", "--epochs", "1", cwd=tmp_path)
    assert (train.returncode, train.stderr) == (2, 'triplesumo train needs PyTorch: pip install "triplesumo[train]"\n')
    assert not (tmp_path / "runs").exists()  # refused before it started
    demo = _run_in(core_venv, "triplesumo", "demo", cwd=tmp_path)
    assert (demo.returncode, demo.stderr) == (2, 'triplesumo demo needs PyTorch: pip install "triplesumo[all]"\n')
    video = _run_in(core_venv, "triplesumo", "play", "--video", "m.mp4", cwd=tmp_path)
    assert (video.returncode, video.stderr) == (2, 'triplesumo play needs imageio (ffmpeg): pip install '
                                                   '"triplesumo[video]"\n')
    play = _run_in(core_venv, "triplesumo", "play", "--policies", "ant=zoo:ant", "spider=zoo:spider",
                   "--max-steps", "50", cwd=tmp_path)  # the commands that need no extra run
    assert play.returncode == 0, play.stderr
    assert play.stdout.startswith("match seed 0: ")
