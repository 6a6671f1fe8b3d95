"""Shared fixtures of the test suite.

``MUJOCO_GL`` must be chosen before anything imports mujoco, so it is set here, first.
"""

import contextlib
import functools
import importlib.util
import os
import re
import subprocess

os.environ.setdefault("MUJOCO_GL", "egl")

from collections.abc import Callable, Iterator  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from types import ModuleType  # noqa: E402
from typing import Any  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from triplesumo.algos.ddpg import DDPGConfig  # noqa: E402
from triplesumo.envs.match import Match  # noqa: E402
from triplesumo.rules.config import MatchConfig, ResetNoise  # noqa: E402
from triplesumo.train.config import TrainConfig  # noqa: E402

NO_NOISE = ResetNoise(position=0.0, yaw=0.0, joints=0.0, velocity=0.0)


@pytest.fixture
def no_noise() -> ResetNoise:
    """Reset noise switched off: every reset gives the documented start pose."""
    return NO_NOISE


@pytest.fixture
def make_match() -> Callable[..., Match]:
    """``make_match(**MatchConfig fields)``: a match reset with seed 0 (noise-free unless given)."""

    def make(**fields: object) -> Match:
        fields.setdefault("reset_noise", NO_NOISE)
        match = Match(MatchConfig(**fields))  # type: ignore[arg-type]
        match.reset(seed=0)
        return match

    return make


@pytest.fixture
def place() -> Callable[..., None]:
    """``place(match, agent, x=, y=, z=, vx=, vy=, vz=)``: set an agent's torso free joint and forward.

    Only the given coordinates change; positions are absolute, velocities world-frame.
    """

    def put(match: Match, agent: str, **coords: float) -> None:
        a = match.sim.agents[match.agents.index(agent)]
        for k, axis in enumerate("xyz"):
            if axis in coords:
                match.data.qpos[a.root_qpos + k] = coords[axis]
            if f"v{axis}" in coords:
                match.data.qvel[a.root_qvel + k] = coords[f"v{axis}"]
        mujoco.mj_forward(match.model, match.data)

    return put


@pytest.fixture
def zeros() -> Callable[[Match], np.ndarray]:
    """``zeros(match)``: the all-zero action array of a match."""
    return lambda match: np.zeros((match.n_agents, 8))


# ----------------------------------------------------------------- a tiny policy zoo
@dataclass(frozen=True)
class TinyZoo:
    """Policies from tiny real training runs, for tests that must not depend on shipped weights."""

    zoo_dir: Path
    """Folder holding ant, spider and bug .{json,safetensors} (published)."""
    ant_run: Path
    """Run folder of the tiny Ant training."""
    bug_policy: Path
    """Stem of a tiny trained Bug policy file."""


def _train_tiny(out: Path, learner: str, policies: tuple[str, ...]) -> Path:
    from triplesumo.algos.ddpg import DDPGConfig
    from triplesumo.train.config import TrainConfig
    from triplesumo.train.loop import train

    tiny = DDPGConfig(hidden=(16, 16), buffer_size=2000, learning_starts=20, batch_size=8, learn_every=2)
    result = train(TrainConfig(out=str(out), name=learner, learn=(f"{learner}=ddpg",), policies=policies, epochs=2,
                               steps_per_epoch=20, n_envs=2, ddpg=tiny, progress=False, tensorboard=False))
    return result.run_dir


@pytest.fixture(scope="session")
def tiny_zoo(tmp_path_factory: pytest.TempPathFactory) -> TinyZoo:
    """Ant and Spider trained for 2 epochs of 20 steps (16-unit networks) and published to a
    temporary zoo, plus a tiny Bug policy file."""
    from triplesumo.agents.zoo import publish

    root = tmp_path_factory.mktemp("tiny-zoo")
    zoo_dir = root / "zoo"
    runs = {}
    for learner, policies in (("ant", ("spider=random", "bug=zero")), ("spider", ("ant=random", "bug=zero"))):
        runs[learner] = _train_tiny(root / "runs", learner, policies)
        publish(runs[learner] / "policy", learner, zoo_dir=zoo_dir)
    bug = _train_tiny(root / "runs", "bug", ("ant=zero", "spider=random"))
    publish(bug / "policy", "bug", zoo_dir=zoo_dir)
    return TinyZoo(zoo_dir, runs["ant"], bug / "policy")


E = 2
"""Checkpoint interval of the tiny training runs; the uninterrupted reference run trains 2E epochs."""
TINY_DDPG = DDPGConfig(hidden=(16, 16), buffer_size=5000, learning_starts=50, batch_size=16, learn_every=2)


def tiny(out: Path, name: str = "run", **fields: Any) -> TrainConfig:
    """A training config small enough for a test: 2 matches of 30 steps, 16-unit networks."""
    values: dict[str, Any] = {
        "name": name, "out": str(out), "learn": ("bug=ddpg",), "policies": ("spider=random", "ant=zero"),
        "epochs": 2 * E, "steps_per_epoch": 30, "n_envs": 2, "checkpoint_every": E, "seed": 0,
        "ddpg": TINY_DDPG, "progress": False, "tensorboard": False,
    }
    values.update(fields)
    return TrainConfig(**values)


@contextlib.contextmanager
def small_disk(folder: Path, size: str) -> Iterator[Path]:
    """A real tmpfs of ``size`` (``"16k"``) mounted at ``folder`` for a full-disk test, unmounted after; the test
    is skipped where mounting needs rights this user lacks (CI runs as root)."""
    import subprocess

    folder.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                                           capture_output=True).returncode != 0:
        pytest.skip("a small tmpfs needs root and mount (CI runs as root)")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


@contextlib.contextmanager
def read_only(folder: Path) -> Iterator[Path]:
    """``folder`` made read-only for the block: ``chmod a-w``, or, as root (whom permissions do not stop; CI runs
    as root), ``chattr +i`` (immutable: no entry is created, removed or renamed in it, whoever asks); the test is
    skipped where root's file system has no immutable flag."""
    if os.geteuid() != 0:
        mode = folder.stat().st_mode
        folder.chmod(0o555)
        try:
            yield folder
        finally:
            folder.chmod(mode)
        return
    if subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode != 0:
        pytest.skip("as root a read-only folder needs chattr +i, which this file system does not support")
    try:
        yield folder
    finally:
        subprocess.run(["chattr", "-i", str(folder)], check=True)


def own_ray_workers(task: str) -> list[int]:
    """Pids of the Ray workers now running ``task`` (Ray titles them ``ray::TASK``) that belong to this
    test process's own local Ray: descendants of it (driver -> raylet -> worker). Other pytest-xdist
    workers run Ray sessions of their own on the same machine; a test that kills a worker must not
    kill theirs."""
    me, title = os.getpid(), b"ray::" + task.encode()

    def parent(pid: int) -> int:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return int(stat[stat.rindex(")") + 2:].split()[1])  # the command may hold spaces and parentheses

    pids = []
    for proc in Path("/proc").iterdir():
        try:
            if not (proc.name.isdigit() and (proc / "cmdline").read_bytes().startswith(title)):
                continue
            pid = int(proc.name)
            while pid > 1 and pid != me:
                pid = parent(pid)
            if pid == me:
                pids.append(int(proc.name))
        except (OSError, ValueError, IndexError):  # gone meanwhile
            continue
    return pids


@pytest.fixture(scope="module")
def ray_session() -> Iterator[Any]:
    """A real local Ray of 2 CPUs for the module's tests (skipped without the ``ray`` extra)."""
    ray = pytest.importorskip("ray", reason='the "ray" extra is not installed (pip install "triplesumo[ray]")')
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


@functools.cache
def tracked_files() -> frozenset[str]:
    """Paths git tracks in this checkout (a sparse checkout lacks some of them on disk); empty outside a git
    checkout."""
    root = Path(__file__).resolve().parents[1]
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return frozenset()
    return frozenset(p for p in out.decode().split("\0") if p)


_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)|\bsrc=\"([^\"]+)\"")
_FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def relative_links(page: Path) -> list[str]:
    """Targets of a Markdown page's links and images and of its HTML ``src=`` outside code blocks, less web
    addresses and anchors (as written: relative to the page)."""
    text = _FENCE.sub("", page.read_text())
    text = re.sub(r"`[^`\n]*`", "", text)  # inline code
    targets = [a or b for a, b in _LINK.findall(text)]
    return [t for t in targets if not re.match(r"[a-z]+:", t) and not t.startswith("#")]


def module_from_file(path: Path) -> ModuleType:
    """A Python file outside the package (a script of benchmarks/, a file of docs/) loaded as a module named after
    it."""
    spec = importlib.util.spec_from_file_location(path.stem, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
