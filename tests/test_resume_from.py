"""``--resume RUN --from epoch-N``: the run folder is the restored checkpoint's, whatever the budget.

A resume from an older checkpoint cuts the tables back to its epoch; before the fix, a budget not past that
epoch (``--epochs N``) trained nothing and left ``latest.json`` and the policy files at the newer checkpoint,
so the folder contradicted itself and a later plain ``--resume`` started from epochs the rows did not reach.
Every test here checks the folder's three witnesses agree (``latest.json``, the metrics/learning rows, the
policy manifest) and that the policy weights are the restored checkpoint's actor.
"""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from conftest import E, tiny
from triplesumo.cli import main
from triplesumo.train import checkpoint
from triplesumo.train.config import TrainConfig
from triplesumo.train.loop import Trainer, TrainResult, train
from triplesumo.train.run_folder import config_from_json


def rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def without_wall_time(table: list[dict[str, str]]) -> list[dict[str, str]]:
    return [{k: v for k, v in r.items() if k != "wall_time"} for r in table]


def actor_of(folder: Path) -> dict[str, torch.Tensor]:
    """The actor's tensors of checkpoint ``folder`` (learner ``bug``), named as in a policy file."""
    return {k.removeprefix("bug."): v for k, v in load_file(str(folder / "weights.safetensors")).items()
            if k.startswith("bug.actor.")}


def same_tensors(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def assert_consistent(run: Path, epoch: int) -> None:
    """``run`` stands at ``epoch``: latest.json, the rows, the policy manifest and weights, no later checkpoint."""
    latest = json.loads((run / "checkpoints" / "latest.json").read_text())
    assert latest == {"dir": f"epoch-{epoch:06d}", "epoch": epoch}
    assert [int(r["epoch"]) for r in rows(run / "metrics.csv")] == list(range(1, epoch + 1))
    assert [int(r["epoch"]) for r in rows(run / "learning.csv")] == list(range(1, epoch + 1))
    assert json.loads((run / "policy.json").read_text())["epochs"] == epoch
    assert [e for e, _ in checkpoint.checkpoints(run)][-1] == epoch  # none later is left
    assert same_tensors(load_file(str(run / "policy.safetensors")), actor_of(checkpoint.latest(run)))


@pytest.fixture(scope="module")
def whole(tmp_path_factory: pytest.TempPathFactory) -> TrainResult:
    """2E epochs straight through, a checkpoint every E (at E and 2E)."""
    return train(tiny(tmp_path_factory.mktemp("runs"), name="A"))


@pytest.fixture
def run(whole: TrainResult, tmp_path: Path) -> Path:
    copy = Path(shutil.copytree(whole.run_dir, tmp_path / "copy"))
    assert_consistent(copy, 2 * E)
    # the two checkpoints' actors differ, so the policy files can tell which one they came from
    assert not same_tensors(actor_of(checkpoint.find(copy, f"epoch-{E:06d}")), actor_of(checkpoint.latest(copy)))
    return copy


@pytest.mark.slow  # 11 s alone on the shared 2-core box
def test_resume_from_an_older_checkpoint_with_no_epoch_left_restores_the_folder_to_it(
        run: Path, whole: TrainResult, capsys: pytest.CaptureFixture[str]) -> None:
    restored = actor_of(checkpoint.find(run, f"epoch-{E:06d}"))
    assert main(["train", "--resume", str(run), "--from", f"epoch-{E:06d}", "--epochs", str(E), "--no-progress"]) == 0
    assert f"trained {E} epochs" in capsys.readouterr().out
    assert_consistent(run, E)
    assert same_tensors(load_file(str(run / "policy.safetensors")), restored)
    assert not (run / "checkpoints" / f"epoch-{2 * E:06d}").exists()  # the abandoned history is gone
    # a later plain --resume continues from it and trains what the uninterrupted run did
    result = train(TrainConfig(), resume_dir=run, overrides={"epochs": 2 * E})
    assert (result.epochs, result.env_steps, result.updates) == (whole.epochs, whole.env_steps, whole.updates)
    assert_consistent(run, 2 * E)
    assert same_tensors(load_file(str(run / "policy.safetensors")),
                        load_file(str(whole.run_dir / "policy.safetensors")))
    assert same_tensors(actor_of(checkpoint.latest(run)), actor_of(checkpoint.latest(whole.run_dir)))
    assert without_wall_time(rows(run / "metrics.csv")) == without_wall_time(rows(whole.run_dir / "metrics.csv"))
    assert without_wall_time(rows(run / "learning.csv")) == without_wall_time(rows(whole.run_dir / "learning.csv"))


def test_a_resume_from_an_older_checkpoint_is_consistent_before_its_first_epoch(run: Path) -> None:
    """Killed after the restore, before any epoch (or checkpoint) of the session: the folder is already E's."""
    cfg = config_from_json(json.loads((run / "config.json").read_text()))
    trainer = Trainer(cfg, run_dir=run, resume=True, from_checkpoint=f"epoch-{E:06d}")
    assert trainer.collector.epochs_done == E
    trainer.start_leg()  # (the leg recorded, the restored checkpoint adopted)
    trainer.log.close()
    assert_consistent(run, E)


def test_a_plain_resume_stepping_back_from_torn_rows_adopts_the_checkpoint_it_chose(
        run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The tables reach epoch E only (a kill tore the rest): the resume picks checkpoint E and the folder follows."""
    for table in ("metrics.csv", "learning.csv"):
        lines = (run / table).read_text().splitlines(keepends=True)
        (run / table).write_text("".join(lines[:1 + E]))
    result = train(TrainConfig(), resume_dir=run, overrides={"epochs": E})
    assert result.epochs == E
    assert f"resuming from epoch-{E:06d}" in capsys.readouterr().out
    assert_consistent(run, E)


def test_a_resume_from_the_latest_checkpoint_changes_no_checkpoint(run: Path) -> None:
    """Nothing to adopt: latest.json already names the checkpoint restored; its files are left as they are."""
    before = {p.relative_to(run): p.read_bytes() for p in (run / "checkpoints").rglob("*") if p.is_file()}
    train(TrainConfig(), resume_dir=run, from_checkpoint=f"epoch-{2 * E:06d}")
    after = {p.relative_to(run): p.read_bytes() for p in (run / "checkpoints").rglob("*") if p.is_file()}
    assert after == before
    assert_consistent(run, 2 * E)
