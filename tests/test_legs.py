"""A run's legs (``RUN/legs.json``): which code trained which epochs.

``code_version`` against a real temporary git repository (clean, dirty, untracked, outside the
package, not tracked at all); the file's errors name it; and the tiny two-sided self-play run of
``test_train_selfplay``: its start, a resume, a resume from an older checkpoint (which cuts the
legs after it) and a fork, each leg in ``legs.json`` and in every policy manifest written after it.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
from pathlib import Path

import pytest

from test_train_selfplay import BOTH_COMMAND, both
from triplesumo.agents.policy_file import PolicyFileError, load_policy
from triplesumo.cli import main
from triplesumo.train.fork import fork_run
from triplesumo.train.legs import (
    LEG_KEYS,
    LEGS_FILE,
    LEGS_FORMAT,
    code_version,
    legs_before,
    make_leg,
    read_legs,
    write_legs,
)
from triplesumo.train.loop import Trainer, train

needs_git = pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")


def git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                          check=True, capture_output=True, text=True).stdout.strip()


@needs_git
def test_code_version_reads_the_checkout_that_holds_the_package(tmp_path: Path) -> None:
    repo = tmp_path / "repo"
    pkg = repo / "src" / "pkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("x = 1\n")
    (repo / "README").write_text("readme\n")
    git(repo, "init", "-q")
    git(repo, "add", ".")
    git(repo, "commit", "-q", "-m", "first")
    head = git(repo, "rev-parse", "HEAD")
    assert code_version(pkg) == {"commit": head, "dirty": False}
    # untracked files anywhere and changes outside the package do not make it dirty
    (pkg / "scratch.py").write_text("y = 2\n")
    (repo / "README").write_text("changed\n")
    assert code_version(pkg) == {"commit": head, "dirty": False}
    # a tracked package file that differs from the commit does, staged or not
    (pkg / "__init__.py").write_text("x = 2\n")
    assert code_version(pkg) == {"commit": head, "dirty": True}
    git(repo, "add", "src/pkg/__init__.py")
    assert code_version(pkg) == {"commit": head, "dirty": True}
    git(repo, "commit", "-q", "-m", "second")
    assert code_version(pkg) == {"commit": git(repo, "rev-parse", "HEAD"), "dirty": False}
    # a package the checkout does not track (an installed copy inside an ignored folder), or no checkout
    ignored = repo / ".venv" / "pkg"
    ignored.mkdir(parents=True)
    (ignored / "__init__.py").write_text("x = 1\n")
    (repo / ".gitignore").write_text(".venv/\n")
    assert code_version(ignored) is None
    plain = tmp_path / "plain"
    plain.mkdir()
    (plain / "__init__.py").write_text("")
    assert code_version(plain) is None


def test_legs_file_errors_name_the_file(tmp_path: Path) -> None:
    assert read_legs(tmp_path) == []  # a run from before legs were kept
    path = tmp_path / LEGS_FILE
    leg = make_leg("start", 0, 0, "run-1", {"epochs": 4}, "triplesumo train", code={"commit": "abc", "dirty": False})
    assert set(leg) == set(LEG_KEYS) and leg["versions"]["triplesumo"]
    with pytest.raises(ValueError, match="leg kind 'begin'"):
        make_leg("begin", 0, 0, None, {}, "")
    assert make_leg("resume", 8, 80, "run-1", {}, "", replay="empty")["replay"] == "empty"
    for kind, replay in (("start", "empty"), ("resume", "lost")):
        with pytest.raises(ValueError, match=f"a {kind} leg's replay '{replay}'"):
            make_leg(kind, 0, 0, None, {}, "", replay=replay)
    write_legs(tmp_path, [leg])
    assert read_legs(tmp_path) == [leg]
    cases = {
        "{not json": "corrupt JSON",
        json.dumps([leg]): "expected a JSON object",
        json.dumps({"format": "other/1", "legs": []}): "format 'other/1'",
        json.dumps({"format": LEGS_FORMAT, "legs": {}}): "'legs' must be a list",
        json.dumps({"format": LEGS_FORMAT, "legs": [{"kind": "start"}]}): r"leg 0 lacks \['epoch'",
        json.dumps({"format": LEGS_FORMAT, "legs": [leg | {"kind": "begin"}]}): "leg 0 has kind 'begin'",
        json.dumps({"format": LEGS_FORMAT, "legs": [leg | {"replay": "partial"}]}): "leg 0 has replay 'partial'",
    }
    for text, message in cases.items():
        path.write_text(text)
        with pytest.raises(PolicyFileError, match=message) as err:
            read_legs(tmp_path)
        assert str(path) in str(err.value)
    legs = [leg | {"epoch": e} for e in (0, 8, 12)]
    assert legs_before(legs, 12) == legs[:2] and legs_before(legs, 8) == legs[:1] and legs_before(legs, 13) == legs


def member_manifests(trainer: Trainer) -> dict[str, dict[str, object]]:
    """Every league member's policy manifest (the first role's), by member id."""
    assert trainer.seats.league is not None
    return {m.id: load_policy(trainer.seats.league.root / next(iter(m.policies.values())))[1]
            for pool in trainer.seats.league.pools.values() for m in (*pool.members, *pool.evicted)}


@pytest.mark.slow  # 69 s alone on the shared 2-core box
def test_a_run_its_resume_an_older_resume_and_a_fork_record_their_legs(tmp_path: Path) -> None:
    run = Trainer(both(tmp_path, epochs=8), command=BOTH_COMMAND)
    run.run()
    legs = read_legs(run.run_dir)
    assert [(leg["kind"], leg["epoch"], leg["env_steps"]) for leg in legs] == [("start", 0, 0)]
    assert legs[0]["code"] == code_version() and legs[0]["run_id"] == run.record.run_id
    assert legs[0]["budget"] == {"epochs": 8, "max_minutes": run.cfg.max_minutes, "max_env_steps": 0}
    assert legs[0]["command"] == BOTH_COMMAND
    assert load_policy(run.run_dir / "policy-spider")[1]["legs"] == legs
    first_members = member_manifests(run)
    assert first_members and all(m["legs"] == legs for m in first_members.values())

    # a resume from the command line appends a leg at the checkpoint's epoch, with the typed command
    argv = ["train", "--resume", str(run.run_dir), "--epochs", "16"]
    assert main(argv) == 0
    legs = read_legs(run.run_dir)
    assert [(leg["kind"], leg["epoch"]) for leg in legs] == [("start", 0), ("resume", 8)]
    assert legs[1]["command"] == "triplesumo " + " ".join(argv) and legs[1]["budget"]["epochs"] == 16
    assert legs[1]["env_steps"] > 0
    assert "replay" not in legs[0] and legs[1]["replay"] == "restored"  # the checkpoint's buffer, an exact resume
    assert load_policy(run.run_dir / "policy-ant+bug")[1]["legs"] == legs
    resumed = Trainer(both(tmp_path, epochs=16), run_dir=run.run_dir, resume=True)
    after = member_manifests(resumed)
    assert all(after[i]["legs"] == first_members[i]["legs"] for i in first_members)  # earlier snapshots unchanged
    assert any(m["legs"] == legs for i, m in after.items() if i not in first_members)  # later ones name both legs

    # resuming from the epoch-8 checkpoint again: the leg that trained epochs 8-16 is cut
    again = Trainer(both(tmp_path, epochs=12), run_dir=run.run_dir, resume=True, from_checkpoint="epoch-000008")
    again.run()
    cut = read_legs(run.run_dir)
    assert [(leg["kind"], leg["epoch"]) for leg in cut] == [("start", 0), ("resume", 8)] and cut[1] != legs[1]

    # a fork from epoch 8 starts with the parent's legs before it, then its own
    cfg = dataclasses.replace(run.cfg, name="fork", epochs=10)
    fork_dir = fork_run(run.run_dir, cfg, "epoch-000008")
    assert read_legs(fork_dir) == cut[:1]
    result = train(cfg, resume_dir=fork_dir)
    fork_legs = read_legs(fork_dir)
    assert [(leg["kind"], leg["epoch"]) for leg in fork_legs] == [("start", 0), ("fork", 8)]
    assert fork_legs[1]["replay"] == "restored"  # a fork copies the parent checkpoint's buffer
    assert load_policy(result.run_dir / "policy-spider")[1]["legs"] == fork_legs
    assert train(cfg, resume_dir=fork_dir, overrides={"epochs": 12}).epochs >= 12
    assert [leg["kind"] for leg in read_legs(fork_dir)] == ["start", "fork", "resume"]

    # a corrupt legs.json stops a resume before it trains, naming the file
    (fork_dir / LEGS_FILE).write_text("{")
    with pytest.raises(PolicyFileError, match=f"{fork_dir / LEGS_FILE}: corrupt JSON"):
        train(cfg, resume_dir=fork_dir, overrides={"epochs": 14})
