"""Checkpoints of a training run: safetensors + JSON + npz, written atomically, checksummed.

Layout, inside ``RUN/checkpoints/``::

    epoch-000200/weights.safetensors   networks, target networks, Adam state tensors
    epoch-000200/state.json            config, counters, RNG states, policy manifest
    epoch-000200/arrays.npz            noise state, in-flight matches (physics state etc.)
    epoch-000200/replay.npz            replay buffer (optional)
    epoch-000200/manifest.json         the recorded epoch and the sha256 of every file above
    latest.json                        {"dir": "epoch-000200", "epoch": 200}

A checkpoint folder is written under a temporary name, fsynced, renamed, and only then
is ``latest.json`` replaced (``os.replace``): a kill at any moment leaves the previous
checkpoint intact and pointed to. Loading checks every file against its sha256 in
``manifest.json`` and names the file that fails; :func:`newest_intact` finds the newest
checkpoint that passes, for ``--resume RUN --from epoch-N``. Old checkpoints are pruned
by their recorded epoch, never by name. A failed write (disk full, read-only, no
permission) is a :class:`CheckpointWriteError` naming the file and the cause; the
half-written folder is removed and the previous checkpoint stays intact and pointed to.
Nothing is ever unpickled (``np.load`` with ``allow_pickle=False``, safetensors for tensors).

Every part of a run (the collector, each learner, the seats, the evaluations) gives its :class:`State`
(``state_dict()``) and takes it back (``load_state_dict``); a checkpoint is their union.
"""

from __future__ import annotations

import json
import os
import shutil
import zipfile
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

# CheckpointWriteError and writing stand beside the other file writers (evaluation's tables use them too)
from triplesumo.agents.policy_file import (
    CheckpointWriteError,
    PolicyFileError,
    atomic_save_tensors,
    atomic_write_bytes,
    file_sha256,
    load_json,
    load_tensors,
    writing,
)

CHECKPOINT_FORMAT = "triplesumo-checkpoint/1"
KEEP = 2
MANIFEST = "manifest.json"


class CheckpointError(PolicyFileError):
    """A checkpoint is missing, truncated, corrupt or incompatible (the message names the file)."""


@dataclass
class State:
    """What a part of a run keeps in a checkpoint, by the file it goes to."""

    json: dict[str, Any] = field(default_factory=dict)
    """``state.json``: counters, generator states, records."""
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    """``arrays.npz``: the matches' physics, noise and rollout state, frozen evaluation weights."""
    tensors: dict[str, torch.Tensor] = field(default_factory=dict)
    """``weights.safetensors``: networks and optimiser state."""
    replay: Mapping[str, np.ndarray] | None = None
    """``replay.npz`` (optional): replay buffers."""
    folder: Path | None = None
    """The checkpoint folder it was read from (named by the errors of :meth:`require`)."""

    def require(self, arrays: Iterable[str]) -> None:
        """:class:`CheckpointError` naming ``arrays.npz`` unless it holds every one of ``arrays``."""
        missing = [key for key in arrays if key not in self.arrays]
        if missing:
            raise CheckpointError(f"{Path(self.folder or '.') / 'arrays.npz'}: missing arrays {missing[:5]}")

    @staticmethod
    def union(parts: Iterable[State]) -> State:
        """The parts' states side by side (a key two parts share is an error; their ``learners`` entries
        merge)."""
        out = State()
        for part in parts:
            pairs: tuple[tuple[dict[str, Any], dict[str, Any]], ...] = (
                (out.json, part.json), (out.arrays, part.arrays), (out.tensors, part.tensors))
            for mine, theirs in pairs:
                for key, value in theirs.items():
                    if key == "learners" and key in mine:
                        mine[key] = {**mine[key], **value}
                        continue
                    if key in mine:
                        raise ValueError(f"checkpoint: two parts write {key!r}")
                    mine[key] = value
            if part.replay is not None:
                out.replay = {**(out.replay or {}), **part.replay}
        return out

    def named(self, name: str) -> State:
        """A learner's state inside a checkpoint: its files' keys prefixed ``NAME.``, its JSON under
        ``learners.NAME``."""
        def prefixed(values: Mapping[str, Any]) -> dict[str, Any]:
            return {f"{name}.{k}": v for k, v in values.items()}
        return State({"learners": {name: self.json}}, prefixed(self.arrays), prefixed(self.tensors),
                     None if self.replay is None else prefixed(self.replay), self.folder)

    def of(self, name: str) -> State:
        """Learner ``name``'s part of a whole checkpoint (:meth:`named` undone; its replay read lazily)."""
        prefix = f"{name}."

        def mine(values: Mapping[str, Any]) -> dict[str, Any]:
            return {k.removeprefix(prefix): v for k, v in values.items() if k.startswith(prefix)}
        replay = None if self.replay is None else _Prefixed(self.replay, prefix)
        return State(self.json["learners"][name], mine(self.arrays), mine(self.tensors), replay, self.folder)


@contextmanager
def restoring(state: State) -> Iterator[None]:
    """Where the parts load ``state``: an entry missing or malformed there is a :class:`CheckpointError` naming
    the checkpoint's files (``replay.npz`` when a replay array is missing)."""
    try:
        yield
    except CheckpointError:
        raise
    except (KeyError, IndexError, TypeError, ValueError, RuntimeError) as exc:
        where = "replay.npz" if state.replay is not None and "replay arrays" in str(exc) else (
            "state.json / arrays.npz / replay.npz / weights.safetensors")
        raise CheckpointError(f"{state.folder} ({where}): missing or malformed entry: {exc!r}") from exc


class _Prefixed(Mapping[str, np.ndarray]):
    """The members ``PREFIX<key>`` of a mapping, as ``<key>`` (read only when used)."""

    def __init__(self, source: Mapping[str, np.ndarray], prefix: str) -> None:
        self._source, self.prefix = source, prefix

    def __getitem__(self, key: str) -> np.ndarray:
        return self._source[self.prefix + key]

    def __iter__(self) -> Iterator[str]:
        return (k.removeprefix(self.prefix) for k in self._source if k.startswith(self.prefix))

    def __len__(self) -> int:
        return sum(1 for _ in self)


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


def recorded_epoch(folder: Path) -> int | None:
    """The epoch a checkpoint folder records (its manifest), or None if it records none readably."""
    try:
        epoch = load_json(Path(folder) / MANIFEST).get("epoch")
    except PolicyFileError:
        return None
    return epoch if isinstance(epoch, int) and not isinstance(epoch, bool) else None


def checkpoints(run_dir: Path) -> list[tuple[int, Path]]:
    """The checkpoint folders of ``run_dir`` that record their epoch, oldest first (by epoch)."""
    root = Path(run_dir) / "checkpoints"
    found = [(recorded_epoch(f), f) for f in root.glob("epoch-*") if f.is_dir()] if root.is_dir() else []
    return sorted((e, f) for e, f in found if e is not None)


def save(run_dir: Path, epoch: int, tensors: dict[str, torch.Tensor], state: dict[str, Any],
         arrays: dict[str, np.ndarray], replay: dict[str, np.ndarray] | None) -> Path:
    """Write checkpoint ``epoch`` and point ``latest.json`` at it; returns its folder.

    Raises :class:`CheckpointWriteError` (naming the file and the cause, and the checkpoint
    that is still the latest) when a write fails; the partial folder is removed.
    """
    root = Path(run_dir) / "checkpoints"
    name = f"epoch-{epoch:06d}"
    tmp = root / f".{name}.tmp"
    try:
        previous = f"; the last good checkpoint {latest(run_dir)} is intact"
    except CheckpointError:
        previous = "; no earlier checkpoint exists"
    files: dict[str, Path] = {}
    try:
        with writing(root, previous):
            root.mkdir(parents=True, exist_ok=True)
            shutil.rmtree(tmp, ignore_errors=True)
            tmp.mkdir()
        for file, write in (
            ("weights.safetensors", lambda p: atomic_save_tensors(tensors, p)),
            ("state.json", lambda p: atomic_write_bytes(p, _json_bytes({"format": CHECKPOINT_FORMAT, **state}))),
            ("arrays.npz", lambda p: _save_npz(p, arrays)),
            *([("replay.npz", lambda p: _save_npz(p, replay))] if replay is not None else []),
        ):
            with writing(tmp / file, previous):
                write(tmp / file)
            files[file] = tmp / file
        manifest = {"format": CHECKPOINT_FORMAT, "epoch": epoch,
                    "sha256": {file: file_sha256(path) for file, path in files.items()}}
        with writing(tmp / MANIFEST, previous):
            atomic_write_bytes(tmp / MANIFEST, _json_bytes(manifest))
            _fsync_dir(tmp)
        final = root / name
        with writing(final, previous):
            if final.exists():
                shutil.rmtree(final)
            os.replace(tmp, final)
            _fsync_dir(root)
        with writing(root / "latest.json", previous):
            point_latest(run_dir, final, epoch)
    except CheckpointWriteError:
        shutil.rmtree(tmp, ignore_errors=True)  # give the space back; the previous checkpoint stands
        raise
    prune(run_dir, epoch)
    return final


def prune(run_dir: Path, current: int) -> None:
    """Keep checkpoint ``current`` and the KEEP - 1 newest before it, by recorded epoch.

    Folders recording a later epoch belong to a history abandoned by ``--resume --from``
    and are removed too; folders that record no epoch are left alone.
    """
    older = [f for e, f in checkpoints(run_dir) if e < current]
    for old in older[:max(len(older) - (KEEP - 1), 0)]:
        shutil.rmtree(old, ignore_errors=True)
    drop_after(run_dir, current)


def remove_folder(folder: Path) -> None:
    """Delete ``folder`` for good, or fail naming it: it is first renamed aside (``.NAME.removing``, which
    :func:`checkpoints` does not list), so a folder that cannot be removed (a read-only run folder) stays whole
    under its name and is never left half-deleted there; ``OSError`` names the folder and the cause."""
    folder = Path(folder)
    aside = folder.with_name(f".{folder.name}.removing")
    try:
        shutil.rmtree(aside, ignore_errors=True)  # (left by an earlier removal that failed)
        os.replace(folder, aside)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot remove {folder}: {exc.strerror or exc}; it was left as it was") from exc
    try:
        shutil.rmtree(aside)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot remove {aside} (was {folder}): {exc.strerror or exc}") from exc


def drop_after(run_dir: Path, epoch: int) -> None:
    """Remove the checkpoint folders of ``run_dir`` that record an epoch later than ``epoch``: a history
    abandoned by ``--resume --from`` (its rows are cut; the epochs are trained again). Folders that record
    no epoch are left alone."""
    for e, folder in checkpoints(run_dir):
        if e > epoch:
            shutil.rmtree(folder, ignore_errors=True)


def _json_bytes(value: dict[str, Any]) -> bytes:
    return (json.dumps(value) + "\n").encode()


def rewrite_state(folder: Path, state: dict[str, Any]) -> None:
    """Replace checkpoint ``folder``'s ``state.json`` with ``state`` and record its new sha256 in the
    manifest, which then names only the files the folder holds (a fork copies no replay buffer it does not
    keep). Forks and compaction change what a checkpoint's config or league names, not its tensors."""
    folder = Path(folder)
    atomic_write_bytes(folder / "state.json", _json_bytes(state))
    manifest = load_json(folder / MANIFEST)
    manifest["sha256"] = {f: d for f, d in manifest["sha256"].items() if (folder / f).is_file()}
    manifest["sha256"]["state.json"] = file_sha256(folder / "state.json")
    atomic_write_bytes(folder / MANIFEST, _json_bytes(manifest))


def point_latest(run_dir: Path, folder: Path, epoch: int) -> None:
    """Make ``latest.json`` of ``run_dir`` name checkpoint ``folder`` (recording ``epoch``)."""
    atomic_write_bytes(Path(run_dir) / "checkpoints" / "latest.json", _json_bytes({"dir": Path(folder).name,
                                                                                  "epoch": epoch}))


def latest(run_dir: Path) -> Path:
    """The folder of the newest complete checkpoint of ``run_dir``: the one ``latest.json`` names, or,
    when a run was killed after a checkpoint's folder was renamed into place but before
    ``latest.json`` was written, the newest folder by recorded epoch (each is complete once renamed)."""
    pointer = Path(run_dir) / "checkpoints" / "latest.json"
    if not Path(run_dir).is_dir():
        raise CheckpointError(f"{run_dir}: run folder not found")
    if not pointer.exists():
        saved = checkpoints(run_dir)
        if saved:
            return saved[-1][1]
        raise CheckpointError(f"{pointer}: no checkpoint to resume from (file not found: the run was stopped before "
                              f"its first checkpoint); train it again with its command plus --start-over (the "
                              f"folder is moved aside to {Path(run_dir).name}.old-K), or choose another --name")
    try:
        info = load_json(pointer)
    except PolicyFileError as exc:
        raise CheckpointError(str(exc)) from exc
    folder = pointer.parent / str(info.get("dir", ""))
    if not info.get("dir") or not folder.is_dir():
        raise CheckpointError(f"{pointer}: points to {folder}, which does not exist")
    return folder


def last_good(run_dir: Path) -> str:
    """Where a stopped run can go on from: its latest checkpoint, in words."""
    try:
        folder = latest(run_dir)
    except CheckpointError:
        return "no checkpoint was saved before it (no good one exists)"
    return f"the last good checkpoint {folder} is intact; `triplesumo train --resume {run_dir}` continues from it"


def find(run_dir: Path, name: str) -> Path:
    """Checkpoint ``name`` (``epoch-N``, any number of digits) of ``run_dir``, for ``--from``."""
    prefix, _, number = name.partition("-")
    if prefix != "epoch" or not number.isdigit():
        raise CheckpointError(f"--from must name a checkpoint like epoch-000200, got {name!r}")
    for epoch, folder in checkpoints(run_dir):
        if epoch == int(number):
            return folder
    have = ", ".join(f.name for _, f in checkpoints(run_dir)) or "none"
    raise CheckpointError(f"{Path(run_dir) / 'checkpoints' / name}: no such checkpoint (the run has: {have})")


def verify(folder: Path, need_replay: bool = True) -> None:
    """Check every file of a checkpoint against the sha256 its manifest records
    (``replay.npz`` only with ``need_replay``)."""
    folder = Path(folder)
    try:
        manifest = load_json(folder / MANIFEST)
    except PolicyFileError as exc:
        raise CheckpointError(str(exc)) from exc
    sums = manifest.get("sha256")
    if not isinstance(sums, dict) or not {"weights.safetensors", "state.json", "arrays.npz"} <= set(sums):
        raise CheckpointError(f"{folder / MANIFEST}: lacks the sha256 of the checkpoint's files")
    for file, expected in sums.items():
        if file == "replay.npz" and not need_replay:
            continue
        path = folder / str(file)
        if not path.is_file():
            raise CheckpointError(f"{path}: file not found")
        if file_sha256(path) != expected:
            raise CheckpointError(f"{path}: sha256 differs from {folder / MANIFEST} (damaged or truncated)")


def holds_replay(folder: Path) -> bool:
    """Whether a checkpoint holds a replay buffer: its manifest records ``replay.npz``. One saved without
    (``save_replay=False``) or compacted of it (``triplesumo compact --drop-replay``) does not, and a resume from it
    starts with an empty buffer; one that records the file and lacks it is damaged (:func:`verify` names it)."""
    try:
        sums = load_json(Path(folder) / MANIFEST).get("sha256")
    except PolicyFileError as exc:
        raise CheckpointError(str(exc)) from exc
    return isinstance(sums, dict) and "replay.npz" in sums


def newest_intact(run_dir: Path, below: int | None = None) -> Path | None:
    """The newest checkpoint of ``run_dir`` (recording an epoch < ``below``) whose files all verify."""
    for epoch, folder in reversed(checkpoints(run_dir)):
        if below is not None and epoch >= below:
            continue
        try:
            verify(folder)
        except CheckpointError:
            continue
        return folder
    return None


def _load_npz(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise CheckpointError(f"{path}: file not found")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        raise CheckpointError(f"{path}: corrupt or truncated npz: {exc}") from exc


class LazyNpz(Mapping[str, np.ndarray]):
    """The members of an npz file, read one at a time (so a large replay buffer is never held twice)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise CheckpointError(f"{self.path}: file not found")
        try:
            with np.load(self.path, allow_pickle=False) as data:
                self.files = list(data.files)
        except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
            raise CheckpointError(f"{self.path}: corrupt or truncated npz: {exc}") from exc

    def __iter__(self) -> Iterator[str]:
        return iter(self.files)

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, key: str) -> np.ndarray:
        try:
            with np.load(self.path, allow_pickle=False) as data:
                return data[key]
        except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
            raise CheckpointError(f"{self.path}: corrupt or truncated npz: {exc}") from exc


def load(folder: Path, need_replay: bool) -> tuple[dict[str, torch.Tensor], dict[str, Any],
                                                    dict[str, np.ndarray], LazyNpz | None]:
    """Read a checkpoint folder, checked against its manifest: tensors, state, arrays, replay (or None).

    The replay buffer comes as a :class:`LazyNpz` (members read when used).
    """
    folder = Path(folder)
    verify(folder, need_replay)
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
        replay = LazyNpz(folder / "replay.npz")
    return tensors, state, arrays, replay
