"""Checkpoints of a training run: safetensors + JSON + npz, written atomically.

Layout, inside ``RUN/checkpoints/``::

    epoch-000200/weights.safetensors   networks, target networks, Adam state tensors
    epoch-000200/state.json            config, counters, RNG states, manifest
    epoch-000200/arrays.npz            noise state, in-flight matches (physics state etc.)
    epoch-000200/replay.npz            replay buffer (optional)
    latest.json                        {"dir": "epoch-000200"}

A checkpoint folder is written under a temporary name, fsynced, renamed, and only then
is ``latest.json`` replaced (``os.replace``): a kill at any moment leaves the previous
checkpoint intact and pointed to. Nothing is ever unpickled (``np.load`` with
``allow_pickle=False``, safetensors for tensors).
"""

from __future__ import annotations

import json
import os
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from triplesumo.agents.policy_file import (
    PolicyFileError,
    atomic_save_tensors,
    atomic_write_bytes,
    load_json,
    load_tensors,
)

CHECKPOINT_FORMAT = "triplesumo-checkpoint/1"
KEEP = 2


class CheckpointError(PolicyFileError):
    """A checkpoint is missing, truncated, corrupt or incompatible (the message names the file)."""


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    with open(path, "wb") as fh:
        named: dict[str, Any] = dict(arrays)  # keyword names, not savez's own options
        np.savez(fh, **named)
        fh.flush()
        os.fsync(fh.fileno())


def save(run_dir: Path, epoch: int, tensors: dict[str, torch.Tensor], state: dict[str, Any],
         arrays: dict[str, np.ndarray], replay: dict[str, np.ndarray] | None) -> Path:
    """Write checkpoint ``epoch`` and point ``latest.json`` at it; returns its folder."""
    root = Path(run_dir) / "checkpoints"
    root.mkdir(parents=True, exist_ok=True)
    name = f"epoch-{epoch:06d}"
    tmp = root / f".{name}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    atomic_save_tensors(tensors, tmp / "weights.safetensors")
    atomic_write_bytes(tmp / "state.json", (json.dumps({"format": CHECKPOINT_FORMAT, **state}) + "\n").encode())
    _save_npz(tmp / "arrays.npz", arrays)
    if replay is not None:
        _save_npz(tmp / "replay.npz", replay)
    _fsync_dir(tmp)
    final = root / name
    if final.exists():
        shutil.rmtree(final)
    os.replace(tmp, final)
    _fsync_dir(root)
    atomic_write_bytes(root / "latest.json", (json.dumps({"dir": name}) + "\n").encode())
    for old in sorted(root.glob("epoch-*"))[:-KEEP]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def latest(run_dir: Path) -> Path:
    """The folder of the newest complete checkpoint of ``run_dir``."""
    pointer = Path(run_dir) / "checkpoints" / "latest.json"
    if not Path(run_dir).is_dir():
        raise CheckpointError(f"{run_dir}: run folder not found")
    if not pointer.exists():
        raise CheckpointError(f"{pointer}: no checkpoint to resume from (file not found)")
    try:
        info = load_json(pointer)
    except PolicyFileError as exc:
        raise CheckpointError(str(exc)) from exc
    folder = pointer.parent / str(info.get("dir", ""))
    if not info.get("dir") or not folder.is_dir():
        raise CheckpointError(f"{pointer}: points to {folder}, which does not exist")
    return folder


def _load_npz(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise CheckpointError(f"{path}: file not found")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        raise CheckpointError(f"{path}: corrupt or truncated npz: {exc}") from exc


def load(folder: Path, need_replay: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any],
                                                    dict[str, np.ndarray], dict[str, np.ndarray] | None]:
    """Read a checkpoint folder: tensors, state, arrays, replay (or None)."""
    folder = Path(folder)
    try:
        state = load_json(folder / "state.json")
        tensors = load_tensors(folder / "weights.safetensors")
    except PolicyFileError as exc:
        raise CheckpointError(str(exc)) from exc
    if state.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{folder / 'state.json'}: format {state.get('format')!r}, "
                              f"expected {CHECKPOINT_FORMAT!r}")
    arrays = _load_npz(folder / "arrays.npz")
    replay = None
    if need_replay:
        replay = _load_npz(folder / "replay.npz")
    return tensors, state, arrays, replay
