"""Nothing lost, ever (issue 8): re-runs, kills, torn rows, pruning, damaged files, divergence,
resume memory, full disks and the smaller error cases, each as a scenario.

Every training here is a few tiny epochs (2 matches of 30 steps, 16-unit networks). The
module's ``reference`` run trains 2E epochs straight through; the scenarios that resume
demand its very bits (weights, replay, arrays) and its rows.
"""

from __future__ import annotations

import csv
import dataclasses
import errno
import json
import os
import re
import shutil
import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from conftest import TINY_DDPG, E, tiny
from triplesumo.agents import policy_file
from triplesumo.cli import main
from triplesumo.envs.match import Match
from triplesumo.envs.single import TripleSumoEnv
from triplesumo.evaluation import evaluate as evaluate_module
from triplesumo.evaluation.plots import read_metrics_csv
from triplesumo.model.specs import PhysicsConfig
from triplesumo.rules.config import MatchConfig
from triplesumo.train import checkpoint
from triplesumo.train import logger as logger_module
from triplesumo.train.checkpoint import CheckpointError, CheckpointWriteError
from triplesumo.train.config import TrainConfig
from triplesumo.train.logger import COLUMNS, repair_metrics_csv
from triplesumo.train.loop import DivergenceError, Trainer, train
from triplesumo.train.run_folder import RunExistsError

SRC = Path(__file__).resolve().parents[1] / "src"


def rows_of(run: Path) -> list[dict[str, str]]:
    with (run / "metrics.csv").open(newline="") as fh:
        return [{k: v for k, v in r.items() if k != "wall_time"} for r in csv.DictReader(fh)]


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` and its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def same_tensors(a: Path, b: Path) -> bool:
    x, y = load_file(str(a)), load_file(str(b))
    return x.keys() == y.keys() and all(torch.equal(x[k], y[k]) for k in x)


def assert_same_run(a: Path, b: Path) -> None:
    """Bit-identical final policy and last checkpoint (weights, replay, arrays); the same rows."""
    assert same_tensors(a / "policy.safetensors", b / "policy.safetensors")
    last_a, last_b = checkpoint.latest(a), checkpoint.latest(b)
    assert last_a.name == last_b.name
    assert same_tensors(last_a / "weights.safetensors", last_b / "weights.safetensors")
    for name in ("replay.npz", "arrays.npz"):
        with np.load(last_a / name) as x, np.load(last_b / name) as y:
            assert sorted(x.files) == sorted(y.files)
            assert all(np.array_equal(x[k], y[k]) for k in x.files), name
    assert rows_of(a) == rows_of(b)


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """2E epochs straight through, a checkpoint every E."""
    return train(tiny(tmp_path_factory.mktemp("ref"), "ref")).run_dir


@pytest.fixture(scope="module")
def killed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reference run as if killed after its first checkpoint (epoch E)."""
    return train(tiny(tmp_path_factory.mktemp("killed"), "ref", epochs=E)).run_dir


@pytest.fixture
def killed_copy(killed: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(killed, tmp_path / "ref"))


def resume(run: Path, **kwargs: Any) -> Any:
    return train(TrainConfig(), resume_dir=run, overrides={"epochs": 2 * E}, **kwargs)


class SimulatedKill(BaseException):
    """Stands for the process dying at the injected point."""


# ----------------------------------------------------------- 1. re-run into a run folder


@pytest.mark.slow  # 8 s alone on the shared 2-core box
def test_rerun_into_a_run_folder_refuses_and_changes_nothing(killed_copy: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    before = snapshot(killed_copy)
    with pytest.raises(RunExistsError, match=r"already holds a run.*--resume .*--start-over"):
        train(tiny(killed_copy.parent, "ref"))
    assert snapshot(killed_copy) == before
    argv = ["train", "--out", str(killed_copy.parent), "--name", "ref", "--no-progress", "--no-tensorboard"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"triplesumo train --resume {killed_copy}" in err and "--start-over" in err
    assert snapshot(killed_copy) == before
    resume(killed_copy)  # the refused run is still resumable, as if nothing had happened


@pytest.mark.slow  # 13 s alone on the shared 2-core box
def test_start_over_moves_the_old_run_aside(killed_copy: Path, reference: Path) -> None:
    before = snapshot(killed_copy)
    result = train(tiny(killed_copy.parent, "ref"), start_over=True)
    aside = killed_copy.with_name("ref.old-1")
    assert snapshot(aside) == before
    assert_same_run(reference, result.run_dir)  # a fresh run, not joined onto the old one
    train(tiny(killed_copy.parent, "ref"), start_over=True)
    assert killed_copy.with_name("ref.old-2").is_dir() and snapshot(aside) == before


def test_evaluate_into_an_evaluation_folder_refuses_without_resume(tmp_path: Path) -> None:
    cfg = evaluate_module.EvaluateConfig(policy="passive", policies=("ant=zero", "spider=random"), baselines=(),
                                         epochs=2, n_envs=2, steps_per_epoch=5, out=str(tmp_path), progress=False)
    evaluate_module.evaluate(cfg)
    before = snapshot(tmp_path)
    with pytest.raises(FileExistsError, match=r"already holds an evaluation.*--resume"):
        evaluate_module.evaluate(cfg)
    assert snapshot(tmp_path) == before
    evaluate_module.evaluate(dataclasses.replace(cfg, resume=True, epochs=3))  # extending it is fine


def test_cli_start_over_and_its_misuse(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["train", "--out", str(tmp_path), "--name", "c", "--epochs", "1", "--steps-per-epoch", "5", "--n-envs", "1",
            "--policies", "spider=random", "ant=zero", "--ddpg.hidden", "8", "--ddpg.buffer-size", "100",
            "--no-progress", "--no-tensorboard"]
    assert main(argv) == 0
    first = snapshot(tmp_path / "c")
    assert main(argv) == 2 and "--start-over" in capsys.readouterr().err
    assert main([*argv, "--start-over"]) == 0
    assert snapshot(tmp_path / "c.old-1") == first and (tmp_path / "c" / "metrics.csv").is_file()
    assert main(["train", "--resume", str(tmp_path / "c"), "--start-over"]) == 2
    assert main([*argv[:-2], "--from", "epoch-000001"]) == 2
    assert "--from needs --resume" in capsys.readouterr().err


# ------------------------------------------------ 2. a kill inside the metrics rewrite


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_kill_inside_the_metrics_rewrite_keeps_every_row(killed_copy: Path, reference: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    metrics = killed_copy / "metrics.csv"
    rows = metrics.read_text().splitlines(keepends=True)
    with metrics.open("a") as fh:  # the killed run had logged an epoch its checkpoint does not hold
        fh.write(rows[-1].replace(f"{E},", f"{E + 1},", 1))
    before = metrics.read_bytes()
    real_replace = os.replace

    def dies_before_the_rename(src: Any, dst: Any, **kwargs: Any) -> None:
        if Path(dst).name == "metrics.csv":
            raise SimulatedKill(dst)
        real_replace(src, dst, **kwargs)

    monkeypatch.setattr(os, "replace", dies_before_the_rename)
    with pytest.raises(SimulatedKill):
        resume(killed_copy)
    monkeypatch.undo()
    assert metrics.read_bytes() == before  # the whole history is still there
    assert not [p for p in killed_copy.iterdir() if p.name.startswith(".metrics.csv")]  # no temp file left
    resume(killed_copy)
    assert_same_run(reference, killed_copy)


# ------------------------------------------------------------------- 3. torn last row


def test_torn_last_row_is_cut_off_on_resume(tmp_path: Path) -> None:
    """Killed while writing row 11 after a checkpoint at epoch 10: only "1" of "11,win,..." reached
    the disk. That is no row of epoch 1; it is cut off, and the run goes on from row 10."""
    run = train(tiny(tmp_path, epochs=10, checkpoint_every=10, steps_per_epoch=5)).run_dir
    assert checkpoint.latest(run).name == "epoch-000010"
    before = rows_of(run)
    with (run / "metrics.csv").open("a") as fh:
        fh.write("1")
    result = train(TrainConfig(), resume_dir=run, overrides={"epochs": 11})
    rows = rows_of(run)
    assert rows[:10] == before
    assert [int(r["epoch"]) for r in rows] == list(range(1, result.epochs + 1))
    metrics = read_metrics_csv(run / "metrics.csv")  # what plot reads: every outcome known
    assert len(metrics["epoch"]) == result.epochs >= 11


@pytest.mark.slow  # 6 s alone on the shared 2-core box
def test_a_row_torn_at_the_checkpoints_epoch_resumes_from_the_checkpoint_before(tmp_path: Path,
                                                                                  capsys: pytest.CaptureFixture[str]
                                                                                  ) -> None:
    """Issue 39, item 15: the newest checkpoint is at epoch 6, whose metrics row the kill tore. The resume goes on
    from the newest checkpoint the intact rows reach (epoch 4), cutting the rows after it, and ends exactly as an
    uninterrupted run does; with no such checkpoint it names --start-over."""
    whole = train(tiny(tmp_path / "whole", epochs=8, checkpoint_every=2, steps_per_epoch=5, save_replay=True)).run_dir
    run = train(tiny(tmp_path / "torn", epochs=6, checkpoint_every=2, steps_per_epoch=5, save_replay=True)).run_dir
    assert checkpoint.latest(run).name == "epoch-000006"
    text = (run / "metrics.csv").read_text()
    (run / "metrics.csv").write_text(text[: text.rindex("6,")] + "6,wi")  # row 6 torn by the kill
    capsys.readouterr()
    result = train(TrainConfig(), resume_dir=run, overrides={"epochs": 8})
    assert "resuming from epoch-000004 (epoch 4)" in capsys.readouterr().out
    assert result.epochs == 8 and rows_of(run) == rows_of(whole)
    for folder in (run / "checkpoints").glob("epoch-*"):  # a later kill, with only checkpoints past the rows
        if folder != checkpoint.latest(run):
            shutil.rmtree(folder)
    (run / "metrics.csv").write_text((run / "metrics.csv").read_text().split("\n", 1)[0] + "\n1,w")
    with pytest.raises(checkpoint.CheckpointError, match=r"epochs 1..0 only .* --start-over"):
        train(TrainConfig(), resume_dir=run, overrides={"epochs": 9})


def test_a_run_stopped_before_its_first_checkpoint_names_start_over(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 39, item 16: --resume of a run with no checkpoint yet said only 'no checkpoint', and a rerun says the
    folder holds a run; both name --start-over, which trains it again."""
    cfg = tiny(tmp_path, epochs=4, checkpoint_every=4, steps_per_epoch=5)
    run = train(cfg).run_dir
    shutil.rmtree(run / "checkpoints")  # as if killed before the first checkpoint was written
    with pytest.raises(checkpoint.CheckpointError, match="stopped before its first checkpoint.*--start-over"):
        train(TrainConfig(), resume_dir=run)
    argv = ["train", "--name", cfg.name, "--out", cfg.out, "--epochs", "4", "--steps-per-epoch", "5", "--n-envs", "2",
            "--no-progress", "--no-tensorboard"]
    capsys.readouterr()
    assert main(argv) == 2 and "--start-over" in capsys.readouterr().err
    assert main([*argv, "--start-over"]) == 0 and (run / "policy.json").exists()


def _csv(rows: int) -> str:
    line = "{},win,1.0,12,500.0,0.0,500.0," + ",".join("0.0" for _ in COLUMNS[7:-2]) + ",100,1.5\n"
    return ",".join(COLUMNS) + "\n" + "".join(line.format(i) for i in range(1, rows + 1))


def test_one_repair_routine_for_training_and_evaluation(tmp_path: Path) -> None:
    """evaluate --resume and training's resume cut a torn tail the same way (one routine), and both
    refuse, naming file and line, to drop finished rows after a garbage line."""
    assert evaluate_module.repair_metrics_csv is logger_module.repair_metrics_csv
    path = tmp_path / "metrics.csv"
    path.write_text(_csv(3) + "4,win,1.0,1")
    assert evaluate_module.finished_rows(path, 10) == 3
    assert path.read_text() == _csv(3)
    assert repair_metrics_csv(path, keep_through=2) == 2 and path.read_text() == _csv(2)
    path.write_text(_csv(2) + "garbage line\n" + _csv(4).split("\n", 3)[3])
    before = path.read_bytes()
    for call in (lambda: repair_metrics_csv(path), lambda: evaluate_module.finished_rows(path, 10)):
        with pytest.raises(ValueError, match=f"{re.escape(str(path))}, line 4: not the row of epoch 3"):
            call()
    assert path.read_bytes() == before


def test_garbage_line_in_metrics_names_the_file_on_resume(killed_copy: Path) -> None:
    metrics = killed_copy / "metrics.csv"
    lines = metrics.read_text().splitlines(keepends=True)
    metrics.write_text(lines[0] + "\x00garbage\n" + "".join(lines[1:]))
    with pytest.raises(ValueError, match=f"{re.escape(str(metrics))}, line 2"):
        resume(killed_copy)


# ------------------------------------------------------- 4. pruning past epoch 999,999


def test_pruning_orders_by_recorded_epoch_across_a_million(tmp_path: Path) -> None:
    tensors = {"w": torch.zeros(2)}
    arrays = {"a": np.zeros(1)}
    saved: list[int] = []
    for epoch in (999_998, 999_999, 1_000_000, 1_000_001):
        folder = checkpoint.save(tmp_path, epoch, tensors, {"epochs_done": epoch}, arrays, None)
        saved.append(epoch)
        assert checkpoint.latest(tmp_path) == folder and folder.is_dir()
        checkpoint.load(folder, need_replay=False)
        assert [e for e, _ in checkpoint.checkpoints(tmp_path)] == saved[-2:]
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == [
        "epoch-1000000", "epoch-1000001", "latest.json"]


# -------------------------------------------------------- 5. flipped bytes, --from


def _flip_last_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[-3] ^= 0x10  # in the data region: the file stays well-formed
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("name", ["weights.safetensors", "replay.npz", "arrays.npz"])
def test_flipped_data_bytes_are_named_and_the_newest_intact_checkpoint_offered(
        reference: Path, tmp_path: Path, name: str) -> None:
    run = Path(shutil.copytree(reference, tmp_path / "ref"))
    damaged = checkpoint.latest(run) / name
    if name == "weights.safetensors":
        load_file(str(damaged))  # (the flip below leaves a file safetensors reads without complaint)
    _flip_last_byte(damaged)
    with pytest.raises(CheckpointError, match=rf"{re.escape(str(damaged))}: sha256 differs.*newest intact one is "
                                              rf"epoch-{E:06d}.*--resume {re.escape(str(run))} --from epoch-{E:06d}"):
        resume(run)
    assert main(["train", "--resume", str(run), "--from", f"epoch-{E:06d}", "--no-progress"]) == 0
    assert_same_run(reference, run)  # the epochs after E were trained again, to the same bits
    assert [e for e, _ in checkpoint.checkpoints(run)] == [E, 2 * E]


def test_from_names_a_missing_checkpoint(reference: Path, tmp_path: Path) -> None:
    run = Path(shutil.copytree(reference, tmp_path / "ref"))
    with pytest.raises(CheckpointError, match=r"epoch-000003: no such checkpoint \(the run has: epoch-000002, "):
        resume(run, from_checkpoint="epoch-000003")


# ---------------------------------------------------------------- 6. divergence


@pytest.mark.parametrize("optimizer", ["actor_optimizer", "critic_optimizer"])
def test_diverging_learner_stops_naming_learner_update_and_checkpoint(tmp_path: Path, optimizer: str) -> None:
    # Learning starts after the first checkpoint; then a learning rate no config would accept.
    trainer = Trainer(tiny(tmp_path, epochs=20, ddpg=dataclasses.replace(TINY_DDPG, learning_starts=64)))
    for group in getattr(trainer.learners[0].algo, optimizer).param_groups:
        group["lr"] = 1e30
    with pytest.raises(DivergenceError) as caught:
        trainer.run()
    message = str(caught.value)
    good = tmp_path / "run" / "checkpoints" / f"epoch-{E:06d}"
    assert re.search(rf"learner 'bug' diverged at update \d+ .*last good checkpoint {re.escape(str(good))} ",
                     message), message
    assert "NaN or inf" not in message  # not blamed on the env
    checkpoint.load(good, need_replay=True)  # intact
    assert len(rows_of(tmp_path / "run")) >= E  # the finished epochs' rows are on disk


# ------------------------------------------------------------ 7. resume memory


MEMORY_SCRIPT = textwrap.dedent("""
    import resource, sys
    from pathlib import Path
    from triplesumo.algos.ddpg import DDPGConfig
    from triplesumo.train.config import TrainConfig
    from triplesumo.train.loop import train
    out, mode = Path(sys.argv[1]), sys.argv[2]
    ddpg = DDPGConfig(hidden=(16, 16), buffer_size=int(sys.argv[3]), learning_starts=50, batch_size=16,
                      learn_every=2)
    if mode == "fresh":
        train(TrainConfig(name="run", out=str(out), policies=("spider=random", "ant=zero"), epochs=4,
                          steps_per_epoch=10, n_envs=2, checkpoint_every=2, ddpg=ddpg, progress=False,
                          tensorboard=False))
    else:
        train(TrainConfig(), resume_dir=out / "run", overrides={"epochs": 4}, from_checkpoint="epoch-000002")
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
""")


@pytest.mark.slow
def test_resume_needs_no_more_memory_than_a_fresh_run(tmp_path: Path) -> None:
    """A buffer of 700 MB (capacity) holding a few hundred transitions: fresh runs touch only
    those; a resume that zero-filled the rest would need 700 MB more."""
    capacity = 700_000_000 // ((2 * 222 + 8 + 2) * 4)

    def peak(mode: str) -> int:
        env = {**os.environ, "PYTHONPATH": str(SRC), "OMP_NUM_THREADS": "1"}
        done = subprocess.run([sys.executable, "-c", MEMORY_SCRIPT, str(tmp_path), mode, str(capacity)],
                              capture_output=True, text=True, env=env, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        return int(done.stdout.split()[-1])  # KiB

    fresh = peak("fresh")
    resumed = peak("resume")
    assert resumed <= 1.2 * fresh, f"resume peak {resumed} KiB, fresh {fresh} KiB"


# --------------------------------------------------------------- 8. full disk


def _no_space(path: Path) -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def _weights_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    real = checkpoint.atomic_save_tensors

    def writer(tensors: dict[str, torch.Tensor], path: Path, metadata: Any = None) -> None:
        if f"epoch-{2 * E:06d}" in str(path):
            Path(path).write_bytes(b"half a file")
            raise SafetensorError('Error while serializing: IoError(Os { code: 28, kind: StorageFull, '
                                  'message: "No space left on device" })')
        real(tensors, path, metadata)
    monkeypatch.setattr(checkpoint, "atomic_save_tensors", writer)


def _replay_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    real = checkpoint._save_npz

    def writer(path: Path, arrays: dict[str, np.ndarray]) -> None:
        if f"epoch-{2 * E:06d}" in str(path) and path.name == "replay.npz":
            path.write_bytes(b"PK\x03\x04 half")
            raise _no_space(path)
        real(path, arrays)
    monkeypatch.setattr(checkpoint, "_save_npz", writer)


def _latest_json_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    real = checkpoint.atomic_write_bytes

    def writer(path: Path, payload: bytes) -> None:
        if Path(path).name == "latest.json" and f"epoch-{2 * E:06d}" in payload.decode():
            raise OSError(errno.EROFS, os.strerror(errno.EROFS))
        real(path, payload)
    monkeypatch.setattr(checkpoint, "atomic_write_bytes", writer)


def _policy_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    real = policy_file.atomic_write_bytes

    def writer(path: Path, payload: bytes) -> None:
        if Path(path).name == "policy.json" and b'"epochs": 4' in payload:
            raise OSError(errno.EACCES, os.strerror(errno.EACCES))
        real(path, payload)
    monkeypatch.setattr(policy_file, "atomic_write_bytes", writer)


def _metrics_append_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    real = logger_module.MetricsLog.epoch

    def epoch(self: Any, agent: str, row: dict[str, Any], mwr: float) -> None:
        if row["epoch"] == E + 1:
            with checkpoint.writing(self.path):
                self.metrics[agent]._fh.write(f"{E + 1},lo")  # the row is torn where the disk ran out
                raise _no_space(self.path)
        real(self, agent, row, mwr)
    monkeypatch.setattr(logger_module.MetricsLog, "epoch", epoch)


FAULTS: dict[str, tuple[Callable[[pytest.MonkeyPatch], None], str, str, int]] = {
    "weights-disk-full": (_weights_fail, f"epoch-{2 * E:06d}.tmp/weights.safetensors", "No space left on device", E),
    "replay-disk-full": (_replay_fails, f"epoch-{2 * E:06d}.tmp/replay.npz", "No space left on device", E),
    "latest-read-only": (_latest_json_fails, "checkpoints/latest.json", "Read-only file system", E),
    "policy-no-permission": (_policy_fails, "policy.safetensors/.json", "Permission denied", 2 * E),
    "metrics-disk-full": (_metrics_append_fails, "metrics.csv", "No space left on device", E),
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_write_failure_names_path_and_cause_and_keeps_the_last_good_checkpoint(
        killed_copy: Path, reference: Path, monkeypatch: pytest.MonkeyPatch, fault: str) -> None:
    inject, culprit, cause, good = FAULTS[fault]
    inject(monkeypatch)
    with pytest.raises(CheckpointWriteError, match=rf"cannot write \S*{re.escape(culprit)}: {cause}.*"
                                                   rf"last good checkpoint \S*epoch-{good:06d} is intact"):
        resume(killed_copy)
    monkeypatch.undo()
    assert checkpoint.latest(killed_copy).name == f"epoch-{good:06d}"  # (the policy is written after its checkpoint)
    checkpoint.verify(checkpoint.latest(killed_copy))
    assert not list((killed_copy / "checkpoints").glob(".*.tmp"))  # the half-written folder is gone
    resume(killed_copy)  # space freed: the run goes on exactly
    assert_same_run(reference, killed_copy)


def _mount_tmpfs(where: Path, size: int) -> bool:
    where.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True)
    return done.returncode == 0


@pytest.mark.slow  # 7 s alone on the shared 2-core box
def test_full_tmpfs_while_saving(reference: Path, tmp_path: Path) -> None:
    """A real full disk: a small tmpfs (where this user may mount one) that fills up during a save."""
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, 64 << 20):
        pytest.skip("cannot mount a tmpfs here (needs root or CAP_SYS_ADMIN)")
    try:
        run = train(tiny(disk, "ref", epochs=E)).run_dir
        stat = os.statvfs(disk)
        used = (stat.f_blocks - stat.f_bfree) * stat.f_frsize
        first = sum(p.stat().st_size for p in checkpoint.latest(run).iterdir())
        subprocess.run(["mount", "-o", f"remount,size={used + first // 2}", str(disk)], check=True)
        with pytest.raises(CheckpointWriteError, match=rf"cannot write {re.escape(str(run))}\S*: No space left "
                                                       rf"on device.*epoch-{E:06d} is intact"):
            resume(run)
        assert checkpoint.latest(run).name == f"epoch-{E:06d}"
        checkpoint.verify(checkpoint.latest(run))
        subprocess.run(["mount", "-o", "remount,size=64m", str(disk)], check=True)
        resume(run)
        assert_same_run(reference, run)
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


# ------------------------------------------------------------- 9. smaller cases


@pytest.mark.parametrize(("edit", "message"), [
    (lambda c: c | {"colour": "red"}, r"unknown key\(s\) \['colour'\]"),
    (lambda c: {k: v for k, v in c.items() if k != "seed"}, r"missing key\(s\) \['seed'\]"),
    (lambda c: c | {"ddpg": {**c["ddpg"], "actor_learning_rate": 1}},
     r"unknown key\(s\) \['ddpg.actor_learning_rate'\]"),
])
def test_config_json_with_unknown_or_missing_key_names_file_and_key(killed_copy: Path, edit: Any,
                                                                     message: str) -> None:
    config = killed_copy / "config.json"
    config.write_text(json.dumps(edit(json.loads(config.read_text()))))
    with pytest.raises(ValueError, match=f"{re.escape(str(config))}: {message}"):
        resume(killed_copy)


def test_changed_n_envs_is_named_not_blamed_on_arrays(killed_copy: Path) -> None:
    config = killed_copy / "config.json"
    config.write_text(json.dumps(json.loads(config.read_text()) | {"n_envs": 3}))
    with pytest.raises(CheckpointError, match=r"state.json: incompatible checkpoint: it was made with n_envs=2, "
                                              r"this run has 3"):
        resume(killed_copy)


def test_step_before_reset_is_a_clear_error() -> None:
    from gymnasium.error import ResetNeeded

    env = TripleSumoEnv()
    with pytest.raises(ResetNeeded, match=r"step called before reset\(\)"):
        env.step(np.zeros(8))
    env.close()


@pytest.mark.parametrize("value", [2.5, 5.0, True])
def test_frame_skip_must_be_an_int(value: Any) -> None:
    with pytest.raises(ValueError, match="PhysicsConfig.frame_skip must be an int"):
        PhysicsConfig(frame_skip=value)


@pytest.mark.parametrize("name", ["..", ".", "a/b", "a\\b", ""])
def test_run_name_cannot_leave_out(tmp_path: Path, name: str) -> None:
    with pytest.raises(ValueError, match="TrainConfig.name"):
        tiny(tmp_path, name)


@pytest.mark.parametrize(("action", "reason"), [
    (torch.ones(8, dtype=torch.complex64) * 1j, "complex"),
    (np.ones(8) * (1 + 1j), "complex"),
    (torch.zeros(8, requires_grad=True), "requires grad"),
])
def test_complex_or_grad_tensor_actions_are_refused(action: Any, reason: str) -> None:
    match = Match(MatchConfig())
    with pytest.raises(ValueError, match=f"action of 'bug'.*{reason}"):
        match.check_action("bug", action)


@pytest.mark.parametrize(("flags", "named"), [
    (["--ddpg.buffer-size", str(10**12)], r"TrainConfig.ddpg.buffer_size=1000000000000"),
    (["--ddpg.hidden", "100000", "100000"], r"TrainConfig.ddpg.hidden=\[100000, 100000\]"),  # issue 39, 16 T
    (["--learn", "bug=ppo", "--ppo.n-steps", "100000000"], r"TrainConfig.ppo.n_steps=100000000"),
])
def test_runs_too_big_for_the_machine_are_refused_before_anything_is_made(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], flags: list[str], named: str) -> None:
    """Replay buffers, networks and PPO rollouts are sized before the run folder is made: a MemoryError there
    left files behind, so that a rerun needed --start-over."""
    argv = ["train", "--out", str(tmp_path), "--name", "huge", *flags, "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert re.search(rf"{named}.* need \d+\.\d GiB for 1 learner\(s\).*nothing was made", err), err
    assert not (tmp_path / "huge").exists()
