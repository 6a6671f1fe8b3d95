"""One writer per output folder: an exclusive lock a process holds on a run, evaluation, tournament or
reproduction folder while it writes there.

The lock is ``fcntl.flock`` on ``FOLDER/.lock``, a file holding the holder's PID. The operating system lets go
of it when the holder exits, however it exits (``kill -9`` included), so a killed run never leaves its folder
locked: the next command takes the lock over and resumes. A second process asking for a held folder is refused
at once (:class:`FolderInUseError`, naming the folder and the holder's PID), before it reads or writes
anything there. Within one process a folder may be held again (a reproduction holds its folder while the runs
it trains hold theirs; a resume started by the same process): holds nest, and the last release lets go.

A hold that ends removes ``.lock`` (and the folder itself where the hold created it and left it empty), so a
folder whose writer finished holds no lock file; one killed leaves a stale ``.lock``, which the next holder
reuses. Where ``fcntl`` is missing (Windows) holding is a no-op.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover (Windows: no advisory locks; holding does nothing)
    fcntl = None  # type: ignore[assignment]

__all__ = ["LOCK_FILE", "FolderInUseError", "held", "held_tree", "holder", "move_held"]

LOCK_FILE = ".lock"
"""The lock file inside a held folder (it holds the holder's PID)."""


class FolderInUseError(RuntimeError):
    """Another process holds the folder (the message names the folder and that process's PID)."""


@dataclass
class _Hold:
    fd: int
    path: Path
    count: int
    created: bool
    """The hold made the folder (an empty one is removed when the hold ends)."""


_HOLDS: dict[str, _Hold] = {}
_GUARD = threading.Lock()


def _key(folder: Path) -> str:
    return os.path.realpath(folder)


def _holder(path: Path) -> str:
    try:
        text = path.read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        text = ""
    return f"PID {text}" if text.isdigit() else "a process whose PID is not written yet"


def holder(folder: Path | str) -> str | None:
    """Who holds ``folder`` now (``"PID N"``), read from its lock file without touching the lock, or None. A holder
    that lets go removes the file, and one killed leaves it naming a process that is gone, so the file names a
    holder only while that process is alive. For a status to show, not a guard: it never gets in a writer's way
    (a probe of the lock itself would refuse a writer that asked at that moment), and a PID the system has reused
    since reads as a holder."""
    if fcntl is None:  # pragma: no cover (no lock files where holding does nothing)
        return None
    path = Path(folder) / LOCK_FILE
    try:
        text = path.read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        return None
    if not text.isdigit():
        return _holder(path)  # its holder took it a moment ago and is writing its PID
    try:
        os.kill(int(text), 0)
    except ProcessLookupError:
        return None
    except PermissionError:  # alive, another user's
        pass
    return f"PID {text}"


def _lock(folder: Path, what: str) -> int:
    """An open descriptor of ``folder/.lock`` holding its exclusive lock, this process's PID written in it."""
    path = folder / LOCK_FILE
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        except OSError as exc:  # a read-only folder: whatever the command would write there fails too
            raise OSError(exc.errno, f"{folder}: cannot write its lock file {path} ({exc.strerror or exc}); "
                                     f"{what or 'this command'} writes into the folder and was refused, nothing "
                                     "was changed") from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise FolderInUseError(
                f"{folder} is in use: {_holder(path)} writes there (it holds {path}); {what or 'this command'} "
                "was refused and nothing was changed. Wait for that process to finish (or stop it), or choose "
                "another folder") from None
        except BaseException:
            os.close(fd)
            raise
        try:  # the file locked is still the one at path (a holder letting go removes it)
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            return fd
        os.close(fd)


def _let_go(hold: _Hold) -> None:
    """Remove the lock file (while still holding it), then release it; an empty folder the hold made goes too."""
    with contextlib.suppress(OSError):
        if os.stat(hold.path).st_ino == os.fstat(hold.fd).st_ino:
            os.unlink(hold.path)
    os.close(hold.fd)
    if hold.created:
        with contextlib.suppress(OSError):
            hold.path.parent.rmdir()  # only if empty


def acquire(folder: Path | str, what: str = "") -> None:
    """Hold ``folder`` (created if missing) for this process until a matching :func:`release`; holds nest.
    :class:`FolderInUseError` if another process holds it. ``what`` names the refused command in that error."""
    if fcntl is None:  # pragma: no cover
        return
    folder = Path(folder)
    key = _key(folder)
    with _GUARD:
        hold = _HOLDS.get(key)
        if hold is not None:
            hold.count += 1
            return
        created = not folder.exists()
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OSError(exc.errno, f"cannot create output folder {folder}: {exc.strerror or exc}") from exc
        try:
            fd = _lock(folder, what)
        except BaseException:
            if created:
                with contextlib.suppress(OSError):
                    folder.rmdir()
            raise
        _HOLDS[key] = _Hold(fd, folder / LOCK_FILE, 1, created)


def release(folder: Path | str) -> None:
    """End one hold of ``folder`` (:func:`acquire`); the last one lets the lock go."""
    if fcntl is None:  # pragma: no cover
        return
    key = _key(Path(folder))
    with _GUARD:
        hold = _HOLDS.get(key)
        if hold is None:
            return
        hold.count -= 1
        if hold.count == 0:
            del _HOLDS[key]
            _let_go(hold)


@contextlib.contextmanager
def held(folder: Path | str, what: str = "") -> Iterator[Path]:
    """Hold ``folder`` for the block (:func:`acquire`, then :func:`release`); yields it as a Path."""
    acquire(folder, what)
    try:
        yield Path(folder)
    finally:
        release(folder)


@contextlib.contextmanager
def held_tree(folder: Path | str, what: str = "") -> Iterator[Path]:
    """Hold ``folder`` and every folder under it that has a lock file (a run or evaluation inside it, whose
    writer may still be at work): refused if any of them is held by another process."""
    folder = Path(folder)
    with contextlib.ExitStack() as stack:
        stack.enter_context(held(folder, what))
        if folder.is_dir():
            for lock in sorted(folder.rglob(LOCK_FILE)):
                if lock.parent != folder:
                    stack.enter_context(held(lock.parent, what))
        yield folder


def move_held(folder: Path | str, dest: Path | str, what: str = "") -> None:
    """Move ``folder``, which this process holds, to ``dest`` (``os.replace``) and go on holding a new, empty
    ``folder`` in its place (re-made at once); ``dest`` is left without a lock file. Refused as :func:`acquire`
    is if another process took the new folder in between (``dest`` then holds the moved folder)."""
    folder, dest = Path(folder), Path(dest)
    if fcntl is None:  # pragma: no cover
        os.replace(folder, dest)
        return
    key = _key(folder)
    with _GUARD:
        hold = _HOLDS.get(key)
        if hold is None:
            raise RuntimeError(f"move_held: {folder} is not held by this process")
        os.replace(folder, dest)
        moved = _Hold(hold.fd, dest / LOCK_FILE, 1, False)
        try:
            folder.mkdir(parents=True, exist_ok=True)
            hold.fd = _lock(folder, what)
        except BaseException:
            del _HOLDS[key]
            _let_go(moved)
            raise
        hold.path, hold.created = folder / LOCK_FILE, False
        _let_go(moved)
