"""A run's legs: which code trained which epochs.

A long run is trained by several invocations of ``triplesumo train`` (``--resume``, ``--fork``),
possibly by several versions of the code. Every invocation appends one *leg* to ``RUN/legs.json``
when it starts training::

    {"format": "triplesumo-legs/1", "legs": [
      {"kind": "start", "epoch": 0, "env_steps": 0, "run_id": "...",
       "code": {"commit": "07161cf...", "dirty": false},
       "versions": {"triplesumo": "0.1.0", "mujoco": "4.0.0", "torch": "2.13.0+cpu"},
       "budget": {"epochs": 20000, "max_minutes": 100.0, "max_env_steps": 0},
       "started": "2026-11-26T08:48:15+00:00", "command": "triplesumo train ..."},
      {"kind": "resume", "epoch": 5100, ...}]}

``kind`` is ``start`` (a new run), ``fork`` (the first leg of a fork, from the parent's
checkpoint) or ``resume``; ``epoch`` and ``env_steps`` are where the leg starts, so a leg
trained the epochs up to the next leg's ``epoch``. ``code`` is the git commit of the
checkout the ``triplesumo`` package was imported from and whether tracked files under the
package differ from it (``dirty``; untracked files and changes outside the package do not
count), or ``null`` when the package is not a tracked part of a git checkout (an installed
wheel). A resume from a checkpoint older than the newest cuts the legs that started at or
after it (their epochs are trained again); a fork starts with its parent's legs up to the
fork's epoch. The trainer writes the legs into every policy manifest (its own and its league
snapshots), so a shipped policy names the code of every leg that trained it.

A ``resume`` or ``fork`` leg of a run with an off-policy learner also says what became of the
replay buffer: ``"replay": "restored"`` (the checkpoint's, so the leg goes on exactly as the run
would have) or ``"empty"`` (a checkpoint saved without it or compacted of it, ``triplesumo
compact --drop-replay``: the leg goes on with an empty buffer, not exactly as the run would have).
Legs written before this key existed lack it.
"""

from __future__ import annotations

import datetime
import json
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import torch

import triplesumo.version
from triplesumo.agents.policy_file import PolicyFileError, atomic_write_bytes, load_json, writing

LEGS_FILE = "legs.json"
LEGS_FORMAT = "triplesumo-legs/1"
LEG_KINDS = ("start", "resume", "fork")
LEG_KEYS = ("kind", "epoch", "env_steps", "run_id", "code", "versions", "budget", "started", "command")
"""What every leg records (module docstring)."""
REPLAY_STATES = ("restored", "empty")
"""What a resumed leg of an off-policy run says of its replay buffer (``"replay"``, module docstring)."""


def _git(package: Path, *args: str) -> str | None:
    """``git -C package ARGS`` stdout, or None when git is missing or the command fails."""
    try:
        done = subprocess.run(["git", "-C", str(package), *args], capture_output=True, text=True, timeout=20,
                              check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


def code_version(package: Path | str | None = None) -> dict[str, Any] | None:
    """``{"commit": SHA, "dirty": bool}`` of the git checkout that holds ``package`` (default: the
    imported ``triplesumo`` package's folder), or None when the folder's files are not tracked by git
    (an installed wheel, a copy, no git). ``dirty``: a tracked file under ``package`` differs from the
    commit (staged or not); untracked files and changes elsewhere in the checkout do not count."""
    package = Path(package) if package is not None else Path(triplesumo.version.__file__).parent
    if _git(package, "ls-files", "--error-unmatch", "__init__.py") is None:
        return None
    commit = _git(package, "rev-parse", "HEAD")
    status = _git(package, "status", "--porcelain", "--untracked-files=no", "--", ".")
    if commit is None or status is None:
        return None
    return {"commit": commit.strip(), "dirty": bool(status.strip())}


def versions() -> dict[str, str]:
    """The versions of triplesumo, MuJoCo and torch this process runs."""
    return {"triplesumo": triplesumo.version.__version__, "mujoco": mujoco.__version__, "torch": torch.__version__}


def make_leg(kind: str, epoch: int, env_steps: int, run_id: str | None, budget: dict[str, Any],
             command: str, code: dict[str, Any] | None = None, replay: str | None = None) -> dict[str, Any]:
    """A leg starting now at ``epoch`` / ``env_steps`` (``code``: default :func:`code_version`; ``replay``: what a
    resumed off-policy run's buffer is, one of :data:`REPLAY_STATES`, or None to say nothing)."""
    if kind not in LEG_KINDS:
        raise ValueError(f"leg kind {kind!r}: expected one of {LEG_KINDS}")
    if replay is not None and (kind == "start" or replay not in REPLAY_STATES):
        raise ValueError(f"a {kind} leg's replay {replay!r}: expected one of {REPLAY_STATES} on a resume or fork")
    return {"kind": kind, "epoch": int(epoch), "env_steps": int(env_steps), "run_id": run_id,
            "code": code_version() if code is None else code, "versions": versions(), "budget": dict(budget),
            "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"), "command": command,
            **({} if replay is None else {"replay": replay})}


def read_legs(run_dir: Path | str) -> list[dict[str, Any]]:
    """The legs of the run in ``run_dir`` (``[]`` where it has no ``legs.json``: a run started before
    legs were kept); :class:`PolicyFileError` naming the file when it is corrupt or of another format."""
    path = Path(run_dir) / LEGS_FILE
    if not path.is_file():
        return []
    data = load_json(path)
    if data.get("format") != LEGS_FORMAT:
        raise PolicyFileError(f"{path}: format {data.get('format')!r}, expected {LEGS_FORMAT!r}")
    legs = data.get("legs")
    if not isinstance(legs, list) or not all(isinstance(leg, dict) for leg in legs):
        raise PolicyFileError(f"{path}: 'legs' must be a list of objects")
    for i, leg in enumerate(legs):
        missing = [k for k in LEG_KEYS if k not in leg]
        if missing:
            raise PolicyFileError(f"{path}: leg {i} lacks {missing}")
        if leg["kind"] not in LEG_KINDS:
            raise PolicyFileError(f"{path}: leg {i} has kind {leg['kind']!r}, expected one of {LEG_KINDS}")
        if leg.get("replay", "restored") not in REPLAY_STATES:
            raise PolicyFileError(f"{path}: leg {i} has replay {leg['replay']!r}, expected one of {REPLAY_STATES}")
    return legs


def legs_before(legs: list[dict[str, Any]], epoch: int) -> list[dict[str, Any]]:
    """The legs that started before ``epoch``: what a run continued from its checkpoint at ``epoch``
    keeps (a leg that started at or after it trained epochs that are trained again)."""
    return [leg for leg in legs if int(leg["epoch"]) < epoch]


def write_legs(run_dir: Path | str, legs: list[dict[str, Any]]) -> None:
    """Write ``RUN/legs.json`` atomically."""
    data = {"format": LEGS_FORMAT, "legs": legs}
    atomic_write_bytes(Path(run_dir) / LEGS_FILE, (json.dumps(data, indent=1) + "\n").encode())


@dataclass
class RunRecord:
    """How a run was made, as every policy file it writes says (:meth:`fields`): its command, its id, a fork's
    parent and its legs (this one's last once :meth:`start_leg` is called)."""

    command: str
    """The run's command (a fork's own, from ``fork.json``)."""
    session_command: str
    """What started this leg: the typed command line where the CLI gives it."""
    run_id: str | None
    """The run's id, kept by its checkpoints: every policy file it writes (its own and its league snapshots,
    across resumes) names it, so copies of them still group by run. None for a run started before ids (its
    checkpoint has none): its files go on without one, as its first ones did."""
    forked_from: dict[str, Any] | None = None
    """A fork's parent (``fork.json``); None for other runs."""
    legs: list[dict[str, Any]] = field(default_factory=list)

    def start_leg(self, run_dir: Path, resumed: bool, epoch: int, env_steps: int,
                  budget: dict[str, Any], replay: str | None = None) -> dict[str, Any]:
        """Append this leg to ``RUN/legs.json`` (cutting the legs of epochs trained again) and return it:
        ``start`` for a new run, ``fork`` for a fork continued from its fork epoch, else ``resume``; ``replay``
        (:data:`REPLAY_STATES`) is what a resumed off-policy run's replay buffer is."""
        kind = "start"
        if resumed:
            kind = "fork" if self.forked_from is not None and epoch == int(self.forked_from["epoch"]) else "resume"
        leg = make_leg(kind, epoch, env_steps, self.run_id, budget, self.session_command,
                       replay=replay if resumed else None)
        self.legs = [*legs_before(read_legs(run_dir), epoch), leg]
        with writing(Path(run_dir) / LEGS_FILE):
            write_legs(run_dir, self.legs)
        return leg

    def fields(self) -> dict[str, Any]:
        """What a policy manifest says of the run: command, id (where it has one), fork parent (a fork's), legs."""
        return {"command": self.command, **({"run_id": self.run_id} if self.run_id else {}),
                **({"forked_from": self.forked_from} if self.forked_from else {}),
                "legs": self.legs}  # which code trained which epochs, leg by leg
