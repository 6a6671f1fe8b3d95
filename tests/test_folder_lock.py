"""One writer per output folder (:mod:`triplesumo._lock`), with real processes: a second writer is refused at
once naming the holder's PID, nothing in the folder changes, and a holder killed with ``kill -9`` lets go."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

import triplesumo
from triplesumo._lock import LOCK_FILE, held
from triplesumo._lock import holder as holder_of
from triplesumo.cli import main

ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(triplesumo.__file__).parents[1]),
                                                    os.environ.get("PYTHONPATH", "")])}
"""The test's own triplesumo for the child processes."""

HOLD = """
import sys, time
from triplesumo._lock import held
with held(sys.argv[1]):
    print("held", flush=True)
    time.sleep(600)
"""

TINY = ["--epochs", "100000", "--n-envs", "1", "--steps-per-epoch", "20", "--ddpg.hidden", "8", "8",
        "--ddpg.learning-starts", "10", "--checkpoint-every", "2", "--no-tensorboard", "--no-progress"]


def wait_for(check: object, what: str, proc: subprocess.Popen[bytes], timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not check():  # type: ignore[operator]
        assert proc.poll() is None, f"the holder exited (rc {proc.returncode}) before {what}"
        assert time.monotonic() < deadline, f"no {what} within {timeout} s"
        time.sleep(0.2)


def files(folder: Path) -> dict[str, int]:
    """Every file under ``folder`` (but the lock) with its size."""
    return {str(p.relative_to(folder)): p.stat().st_size for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != LOCK_FILE}


def latest_epoch(run: Path) -> int:
    return int(json.loads((run / "checkpoints" / "latest.json").read_text())["epoch"])


@pytest.mark.slow  # 16 s alone on the shared 2-core box
def test_a_second_train_is_refused_naming_the_holder_and_a_kill_9_lets_a_resume_go_on(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "CF"
    train = ["train", "--out", str(tmp_path), "--name", "CF", *TINY]
    holder = subprocess.Popen([sys.executable, "-m", "triplesumo.cli", *train, "--seed", "5"], env=ENV,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        wait_for(lambda: (run / "checkpoints" / "latest.json").is_file(), "checkpoint", holder)
        assert (run / LOCK_FILE).read_text().strip() == str(holder.pid)
        for argv in ([*train, "--seed", "6", "--start-over"], [*train, "--seed", "5"], ["train", "--resume", str(run)]):
            capsys.readouterr()
            assert main(argv) == 2
            err = capsys.readouterr().err
            assert f"{run} is in use: PID {holder.pid}" in err, err
        # start-over moved nothing: the first run's folder is whole, its config its own, and it goes on writing
        assert not (tmp_path / "CF.old-1").exists()
        assert json.loads((run / "config.json").read_text())["seed"] == 5
        first = latest_epoch(run)
        wait_for(lambda: latest_epoch(run) > first, "later checkpoint", holder)
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    done = latest_epoch(run)
    assert main(["train", "--resume", str(run), "--epochs", str(done + 1)]) == 0  # the OS let go of the lock
    assert json.loads((run / "policy.json").read_text())["epochs"] == done + 1
    assert not (run / LOCK_FILE).exists()  # a finished writer leaves no lock file behind


@pytest.fixture
def holder(tmp_path: Path) -> Iterator[tuple[Path, int]]:
    """``tmp_path/out`` held by another process (its PID), a file in it."""
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "config.json").write_text("{}\n")
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], env=ENV, stdout=subprocess.PIPE)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == b"held\n"
        yield folder, proc.pid
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.parametrize("argv", [
    ["evaluate", "--resume", "--policy", "passive", "--out", "{out}"],
    ["tournament", "--resume", "--policies", "a=passive", "b=random", "c=random", "--out", "{out}"],
    ["train", "--resume", "{out}"],
    ["train", "--out", "{parent}", "--name", "out", "--start-over"],
    ["compact", "{out}"],
    ["pack", "{parent}"],  # (a run inside the folder packed)
    ["reproduce", "--tiny", "--out", "{out}"],
], ids=lambda argv: " ".join(a for a in argv[:2] if not a.startswith("{")))
def test_every_writer_of_a_held_folder_is_refused_naming_the_holder_and_changes_nothing(
        holder: tuple[Path, int], argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    folder, pid = holder
    before = files(folder.parent)
    assert main([a.format(out=folder, parent=folder.parent) for a in argv]) == 2
    err = capsys.readouterr().err
    assert f"{folder} is in use: PID {pid} writes there" in err, err
    assert files(folder.parent) == before
    assert (folder / LOCK_FILE).read_text().strip() == str(pid)  # the holder's lock is untouched


def test_holds_nest_in_one_process_and_the_last_release_removes_what_the_hold_made(tmp_path: Path) -> None:
    folder = tmp_path / "new" / "run"
    with held(folder):
        with held(folder):  # a reproduction holding its folder while one of its stages holds it too
            assert (folder / LOCK_FILE).read_text().strip() == str(os.getpid())
        assert (folder / LOCK_FILE).exists()
    assert not folder.exists()  # made by the hold and left empty: gone with it
    folder.mkdir(parents=True)
    (folder / LOCK_FILE).write_text("12345\n")  # a stale lock file (its holder was killed): taken over
    with held(folder):
        assert (folder / LOCK_FILE).read_text().strip() == str(os.getpid())
    assert folder.is_dir() and not (folder / LOCK_FILE).exists()



def test_holder_names_a_live_holder_only_and_leaves_the_lock_to_the_writers(
        holder: tuple[Path, int], tmp_path: Path) -> None:
    """:func:`holder` (what ``reproduce --status`` shows) reads the lock file: another process's live hold, this
    process's own, none once a hold ends or when the file names a process that is gone (a ``kill -9``)."""
    folder, pid = holder
    assert holder_of(folder) == f"PID {pid}"
    assert main(["compact", str(folder)]) == 2  # reading took nothing: the holder still refuses a writer
    free = tmp_path / "free"
    assert holder_of(free) is None  # no folder
    with held(free):
        assert holder_of(free) == f"PID {os.getpid()}"
    assert holder_of(free) is None and free.exists() is False
    gone = subprocess.Popen([sys.executable, "-c", HOLD, str(free)], env=ENV, stdout=subprocess.PIPE)
    assert gone.stdout is not None and gone.stdout.readline() == b"held\n"
    assert holder_of(free) == f"PID {gone.pid}"
    gone.send_signal(signal.SIGKILL)
    gone.wait()
    assert (free / LOCK_FILE).read_text().strip() == str(gone.pid)  # left behind, naming a process that is gone
    assert holder_of(free) is None
