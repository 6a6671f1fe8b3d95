"""Tiny training runs that assert outcomes: the trainer, its run folder, resume and its errors.

Every run here is a few hundred env steps with 16-unit networks (a few seconds on the
2-core machine). ``uninterrupted`` is one run shared by the module: 4 epochs, a checkpoint
every 2, TensorBoard on. The resume tests rebuild it from a run killed at epoch 2 and
demand the very same bits.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import re
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from conftest import TINY_DDPG, E, tiny
from triplesumo.agents.policy_file import PolicyFileError, file_sha256, load_policy
from triplesumo.algos.ddpg import DDPG, DDPGConfig
from triplesumo.cli import main
from triplesumo.model.specs import V0_PHYSICS, PhysicsConfig
from triplesumo.rules.rewards import DENSE_TERMS
from triplesumo.train import checkpoint
from triplesumo.train import collect as train_collect
from triplesumo.train.checkpoint import CheckpointError, recorded_epoch
from triplesumo.train.config import TrainConfig
from triplesumo.train.logger import COLUMNS
from triplesumo.train.loop import Trainer, TrainResult, train
from triplesumo.train.run_folder import RunExistsError, config_from_json, config_to_json, run_id_of

PLOTS = ("rewards.png", "reward_terms.png", "mwr.png", "steps_to_win.png")
LWR = {"win": 1.0, "loss": -1.0, "draw": 0.0, "error": 0.0}


def read_rows(run: Path) -> tuple[list[str], list[dict[str, str]]]:
    with (run / "metrics.csv").open(newline="") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def without_wall_time(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    return [{k: v for k, v in r.items() if k != "wall_time"} for r in rows]


def assert_same_tensors(a_path: Path, b_path: Path) -> None:
    a, b = load_file(str(a_path)), load_file(str(b_path))
    assert a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), f"{b_path}: tensor {key} differs"


def assert_same_arrays(a_path: Path, b_path: Path) -> None:
    with np.load(a_path) as a, np.load(b_path) as b:
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            assert np.array_equal(a[key], b[key]), f"{b_path}: array {key} differs"


def assert_same_run(a: Path, b: Path) -> None:
    """Bit-identical weights (policy and last checkpoint), replay, arrays; CSV equal but for wall_time."""
    assert_same_tensors(a / "policy.safetensors", b / "policy.safetensors")
    last_a, last_b = checkpoint.latest(a), checkpoint.latest(b)
    assert last_a.name == last_b.name
    assert_same_tensors(last_a / "weights.safetensors", last_b / "weights.safetensors")
    assert_same_arrays(last_a / "replay.npz", last_b / "replay.npz")
    assert_same_arrays(last_a / "arrays.npz", last_b / "arrays.npz")
    assert without_wall_time(read_rows(a)[1]) == without_wall_time(read_rows(b)[1])


@dataclass
class Trained:
    cfg: TrainConfig
    trainer: Trainer
    result: TrainResult
    initial: dict[str, torch.Tensor]

    @property
    def run(self) -> Path:
        return self.result.run_dir


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory: pytest.TempPathFactory) -> Trained:
    """2E epochs straight through, checkpoint every E, TensorBoard on."""
    cfg = tiny(tmp_path_factory.mktemp("runs"), name="A", tensorboard=True)
    trainer = Trainer(cfg)
    initial = trainer.learners[0].algo.state_dict()
    result = trainer.run()
    return Trained(cfg, trainer, result, initial)


@pytest.fixture
def run_copy(uninterrupted: Trained, tmp_path: Path) -> Path:
    """A copy of the uninterrupted run's folder, free to be damaged."""
    return Path(shutil.copytree(uninterrupted.run, tmp_path / "copy"))


# ----------------------------------------------------------------- one tiny run


@pytest.mark.slow  # 7 s alone on the shared 2-core box
def test_tiny_run_learns_finite_losses(uninterrupted: Trained) -> None:
    trainer, result, ddpg = uninterrupted.trainer, uninterrupted.result, uninterrupted.cfg.ddpg
    assert result.epochs == trainer.collector.epochs_done >= uninterrupted.cfg.epochs
    bug = trainer.learners[0]
    assert set(bug.last_stats) == {"critic_loss", "actor_loss", "q_mean"}
    assert all(math.isfinite(v) for v in bug.last_stats.values()), bug.last_stats
    # One gradient step per learn_every transitions from learning_starts on (n_envs divides both).
    expected_updates = (result.env_steps - ddpg.learning_starts) // ddpg.learn_every + 1
    assert result.updates == bug.algo.num_updates == expected_updates


def test_tiny_run_fills_replay_with_every_learner_transition(uninterrupted: Trained) -> None:
    trainer, result = uninterrupted.trainer, uninterrupted.result
    replay = trainer.learners[0].replay  # type: ignore[attr-defined]
    assert result.env_steps == trainer.collector.env_steps > 0
    _, rows = read_rows(uninterrupted.run)
    errors = sum(r["outcome"] == "error" for r in rows)  # a physics error's transition is dropped
    assert 0 < len(replay) == result.env_steps - errors <= result.env_steps
    batch = replay.sample(len(replay), np.random.default_rng(0))
    assert all(np.isfinite(v).all() for v in batch.values())
    assert np.abs(batch["act"]).max() <= 1.0


def test_tiny_run_moves_online_and_target_networks(uninterrupted: Trained) -> None:
    initial, now = uninterrupted.initial, uninterrupted.trainer.learners[0].algo.state_dict()
    for net in ("actor", "critic"):
        keys = [k for k in initial if k.startswith(f"{net}.")]
        assert keys
        for key in keys:
            target_key = f"{net}_target.{key.removeprefix(f'{net}.')}"
            assert torch.equal(initial[key], initial[target_key])  # targets start as copies
            assert not torch.equal(now[key], initial[key]), f"online {key} never changed"
            assert not torch.equal(now[target_key], initial[target_key]), f"target {target_key} never moved"
            assert not torch.equal(now[target_key], now[key]), f"{target_key} is a hard copy, not soft-updated"


def test_tiny_run_metrics_csv(uninterrupted: Trained) -> None:
    header, rows = read_rows(uninterrupted.run)
    assert tuple(header) == COLUMNS
    assert [int(r["epoch"]) for r in rows] == list(range(1, uninterrupted.result.epochs + 1))
    env_steps = [int(r["env_steps"]) for r in rows]
    assert env_steps == sorted(env_steps)
    for r in rows:
        assert r["outcome"] in LWR
        assert float(r["local_winning_rate"]) == LWR[r["outcome"]]
        assert 1 <= int(r["steps"]) <= uninterrupted.cfg.steps_per_epoch
        if r["outcome"] == "draw":
            assert int(r["steps"]) == uninterrupted.cfg.steps_per_epoch
        values = {k: float(r[k]) for k in COLUMNS if k not in ("outcome",)}
        assert all(math.isfinite(v) for v in values.values()), r
        assert values["total_reward"] == pytest.approx(values["dense_reward"] + values["sparse_reward"])
        assert values["dense_reward"] == pytest.approx(sum(values[t] for t in DENSE_TERMS))
        assert values["sparse_reward"] == pytest.approx(values["reward_outcome"])


def test_metrics_env_steps_include_the_finishing_step(uninterrupted: Trained) -> None:
    _, rows = read_rows(uninterrupted.run)
    # The run stops on the step that finishes its last epoch: that row has seen every env step.
    assert int(rows[-1]["env_steps"]) == uninterrupted.result.env_steps


def test_tiny_run_writes_plots_config_and_tensorboard(uninterrupted: Trained) -> None:
    run = uninterrupted.run
    for name in PLOTS:
        data = (run / "plots" / name).read_bytes()
        assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 1000, name
    assert config_from_json(json.loads((run / "config.json").read_text())) == uninterrupted.cfg
    assert list((run / "tensorboard").glob("events.out.tfevents.*"))


def test_tiny_run_policy_file_acts_deterministically(uninterrupted: Trained) -> None:
    bug = uninterrupted.trainer.learners[0]
    policy, manifest = load_policy(uninterrupted.run / "policy", expect_obs_mode="paper",
                                   expect_obs_dim=bug.obs_dim)
    assert manifest["agent"] == "bug" and manifest["obs_mode"] == "paper" and manifest["algo"] == "ddpg"
    assert manifest["epochs"] == uninterrupted.result.epochs and manifest["hidden"] == [16, 16]
    assert manifest["physics"] == asdict(PhysicsConfig())  # the ring it learned on, spelled out
    obs = np.random.default_rng(1).normal(size=(3, bug.obs_dim)).astype(np.float32)
    first = policy(obs)
    assert first.shape == (3, 8) and np.abs(first).max() <= 1.0
    assert np.array_equal(first, policy(obs))
    assert np.array_equal(first, bug.algo.act(obs))  # the final actor was saved
    assert policy(obs[0]).shape == (8,)


# ------------------------------------------------------------------------ resume


@pytest.mark.parametrize("folder", ["clean", "rows-past-checkpoint", "packed"])
@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_resume_equals_uninterrupted(uninterrupted: Trained, tmp_path: Path, folder: str) -> None:
    killed = train(tiny(tmp_path, name="B", epochs=E)).run_dir
    assert checkpoint.latest(killed).name == f"epoch-{E:06d}"
    if folder == "rows-past-checkpoint":  # the killed run logged an epoch its checkpoint does not hold
        bogus = read_rows(killed)[1][-1] | {"epoch": str(E + 1), "outcome": "win", "local_winning_rate": "1.0"}
        with (killed / "metrics.csv").open("a", newline="") as fh:
            csv.DictWriter(fh, COLUMNS).writerow(bogus)
    if folder == "packed":  # its tables gzipped (triplesumo pack): the resume unpacks them and appends
        from triplesumo.evaluation.metrics_csv import pack_tables

        packed = {p.name for p in pack_tables(killed, min_bytes=0)}
        assert {"metrics.csv.gz", "learning.csv.gz"} <= packed and not list(killed.glob("*.csv"))
    result = train(TrainConfig(), resume_dir=killed, overrides={"epochs": 2 * E})
    if folder == "packed":
        assert (killed / "metrics.csv").is_file() and not (killed / "metrics.csv.gz").exists()
    assert result.epochs == uninterrupted.result.epochs
    assert result.env_steps == uninterrupted.result.env_steps
    assert result.updates == uninterrupted.result.updates
    assert_same_run(uninterrupted.run, killed)


def test_a_resume_on_more_physics_threads_trains_what_the_run_would_have(uninterrupted: Trained,
                                                                         tmp_path: Path) -> None:
    """A run moved to a machine with more cores: ``--resume RUN --n-threads 2`` steps the matches on two
    threads and still writes, bit for bit, the run that went on with one."""
    assert uninterrupted.cfg.n_threads == 1
    killed = train(tiny(tmp_path, name="B", epochs=E)).run_dir
    result = train(TrainConfig(), resume_dir=killed, overrides={"epochs": 2 * E, "n_threads": 2})
    assert result.epochs == uninterrupted.result.epochs and result.updates == uninterrupted.result.updates
    assert_same_run(uninterrupted.run, killed)


def test_a_run_stopped_at_its_env_step_budget_goes_on_to_a_larger_one(uninterrupted: Trained,
                                                                       tmp_path: Path) -> None:
    """``--resume RUN --max-env-steps N`` (0: none): a run that stopped at its env-step budget trains on, bit for
    bit, as the run that never had that budget did; the budget a resume gives is in its leg."""
    budget = int(read_rows(uninterrupted.run)[1][E - 1]["env_steps"])  # env steps at the end of epoch E
    stopped = train(tiny(tmp_path, name="B", max_env_steps=budget))
    assert stopped.epochs == E and stopped.env_steps == budget < uninterrupted.result.env_steps
    assert main(["train", "--resume", str(stopped.run_dir), "--max-env-steps", "0", "--no-progress"]) == 0
    assert_same_run(uninterrupted.run, stopped.run_dir)
    legs = json.loads((stopped.run_dir / "legs.json").read_text())["legs"]
    assert [leg["budget"]["max_env_steps"] for leg in legs] == [budget, 0]


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_cli_resume_takes_n_threads_and_names_what_it_refuses(uninterrupted: Trained, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    killed = train(tiny(tmp_path, name="B", epochs=E)).run_dir
    assert main(["train", "--resume", str(killed), "--seed", "3"]) == 2
    err = capsys.readouterr().err
    assert "--seed" in err and "--n-threads" in err  # the refused flag, and the list of the allowed ones
    assert main(["train", "--resume", str(killed), "--epochs", str(2 * E), "--n-threads", "2"]) == 0
    assert_same_run(uninterrupted.run, killed)
    legs = json.loads((killed / "legs.json").read_text())["legs"]  # the session that changed it says so
    assert [leg["kind"] for leg in legs] == ["start", "resume"] and "--n-threads 2" in legs[-1]["command"]


class SimulatedKill(Exception):
    """Stands for the process dying inside a checkpoint write."""


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_kill_during_save_keeps_previous_checkpoint(uninterrupted: Trained, tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    real = checkpoint.atomic_save_tensors
    calls = []

    def dies_on_second_save(tensors: dict[str, torch.Tensor], path: Path, metadata: Any = None) -> None:
        calls.append(path)
        if len(calls) == 1:
            return real(tensors, path, metadata)
        Path(path).write_bytes(b"half a safetensors file")
        raise SimulatedKill(path)

    monkeypatch.setattr(checkpoint, "atomic_save_tensors", dies_on_second_save)
    with pytest.raises(SimulatedKill):
        train(tiny(tmp_path, name="B"))
    monkeypatch.undo()
    run = tmp_path / "B"
    first = run / "checkpoints" / f"epoch-{E:06d}"
    assert checkpoint.latest(run) == first
    assert (run / "checkpoints" / f".epoch-{2 * E:06d}.tmp").is_dir()  # the half-written save
    assert not (run / "checkpoints" / f"epoch-{2 * E:06d}").exists()
    checkpoint.load(first, need_replay=True)  # still complete
    train(TrainConfig(), resume_dir=run)
    assert not (run / "checkpoints" / f".epoch-{2 * E:06d}.tmp").exists()
    assert_same_run(uninterrupted.run, run)


def test_stray_temp_checkpoint_is_ignored(uninterrupted: Trained, run_copy: Path) -> None:
    before = checkpoint.latest(run_copy)
    stray = run_copy / "checkpoints" / ".epoch-000099.tmp"
    stray.mkdir()
    (stray / "weights.safetensors").write_bytes(b"\x00garbage")
    (stray / "state.json").write_text("{")
    assert checkpoint.latest(run_copy) == before
    result = train(TrainConfig(), resume_dir=run_copy, overrides={"epochs": uninterrupted.result.epochs + E})
    assert result.epochs >= uninterrupted.result.epochs + E
    _, rows = read_rows(run_copy)
    assert [int(r["epoch"]) for r in rows] == list(range(1, result.epochs + 1))


# ----------------------------------------------------------- corrupt checkpoints


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _latest_file(run: Path, name: str) -> Path:
    return checkpoint.latest(run) / name


CORRUPTIONS = {
    "no-checkpoint-at-all": (lambda run: [shutil.rmtree(f) if f.is_dir() else f.unlink()
                                          for f in (run / "checkpoints").iterdir()],
                             lambda run: run / "checkpoints" / "latest.json", "file not found"),
    "latest-json-points-nowhere": (
        lambda run: (run / "checkpoints" / "latest.json").write_text('{"dir": "epoch-000777"}'),
        lambda run: run / "checkpoints" / "latest.json", "epoch-000777, which does not exist"),
    "garbage-latest-json": (lambda run: (run / "checkpoints" / "latest.json").write_text("epoch-000004"),
                            lambda run: run / "checkpoints" / "latest.json", "corrupt JSON"),
    "truncated-weights": (lambda run: _truncate(_latest_file(run, "weights.safetensors")),
                          lambda run: _latest_file(run, "weights.safetensors"), "sha256 differs"),
    "garbage-state-json": (lambda run: _latest_file(run, "state.json").write_bytes(b"{\x00not json"),
                           lambda run: _latest_file(run, "state.json"), "sha256 differs"),
    "wrong-format-state-json": (lambda run: _latest_file(run, "state.json").write_text('{"format": "x"}'),
                                lambda run: _latest_file(run, "state.json"), "sha256 differs"),
    "truncated-arrays": (lambda run: _truncate(_latest_file(run, "arrays.npz")),
                         lambda run: _latest_file(run, "arrays.npz"), "sha256 differs"),
    "truncated-replay": (lambda run: _truncate(_latest_file(run, "replay.npz")),
                         lambda run: _latest_file(run, "replay.npz"), "sha256 differs"),
    "missing-replay": (lambda run: _latest_file(run, "replay.npz").unlink(),
                       lambda run: _latest_file(run, "replay.npz"), "file not found"),
    "missing-manifest": (lambda run: _latest_file(run, "manifest.json").unlink(),
                         lambda run: _latest_file(run, "manifest.json"), "file not found"),
    "garbage-manifest": (lambda run: _latest_file(run, "manifest.json").write_text("{"),
                         lambda run: _latest_file(run, "manifest.json"), "corrupt JSON"),
}


@pytest.mark.parametrize("case", list(CORRUPTIONS))
def test_corrupt_checkpoint_error_names_file_and_reason(run_copy: Path, case: str) -> None:
    corrupt, culprit, reason = CORRUPTIONS[case]
    path = culprit(run_copy)
    corrupt(run_copy)
    with pytest.raises(PolicyFileError, match=f"{re.escape(str(path))}.*{re.escape(reason)}"):
        train(TrainConfig(), resume_dir=run_copy, overrides={"epochs": 99})


def test_a_run_killed_before_latest_json_was_written_resumes_from_its_newest_checkpoint(run_copy: Path) -> None:
    """The checkpoint folder is renamed into place (complete) before ``latest.json`` names it."""
    newest = checkpoint.latest(run_copy)
    (run_copy / "checkpoints" / "latest.json").unlink()
    assert checkpoint.latest(run_copy) == newest
    result = train(TrainConfig(), resume_dir=run_copy, overrides={"epochs": recorded_epoch(newest) + 2})
    assert result.epochs >= recorded_epoch(newest) + 2
    rows = [int(r["epoch"]) for r in read_rows(run_copy)[1]]
    assert rows == list(range(1, len(rows) + 1))


@pytest.mark.slow  # 6 s alone on the shared 2-core box
def test_a_resumed_run_keeps_the_run_id_its_checkpoint_records(uninterrupted: Trained, run_copy: Path) -> None:
    """Policy manifests name the run (``run_id``) by the id its checkpoint holds, not by a hash of the config
    as this version reads it (which options added since would move); a run whose checkpoint was written
    before ids goes on without one (not splitting its files into two runs)."""
    assert load_policy(uninterrupted.run / "policy")[1]["run_id"] == uninterrupted.trainer.record.run_id
    state_path = _latest_file(run_copy, "state.json")
    state = json.loads(state_path.read_text())
    assert state["run_id"] == uninterrupted.trainer.record.run_id == run_id_of(uninterrupted.cfg)
    state["run_id"] = "started-under-an-older-version"
    state_path.write_text(json.dumps(state))
    _reseal(state_path.parent)
    epochs = recorded_epoch(checkpoint.latest(run_copy)) + 2
    train(TrainConfig(), resume_dir=run_copy, overrides={"epochs": epochs})
    assert load_policy(run_copy / "policy")[1]["run_id"] == "started-under-an-older-version"
    state_path = _latest_file(run_copy, "state.json")
    state = json.loads(state_path.read_text())
    assert state["run_id"] == "started-under-an-older-version"  # and the next checkpoint keeps it
    del state["run_id"]
    state_path.write_text(json.dumps(state))
    _reseal(state_path.parent)
    train(TrainConfig(), resume_dir=run_copy, overrides={"epochs": epochs + 2})
    assert "run_id" not in load_policy(run_copy / "policy")[1]


def test_corrupt_npz_members_are_checkpoint_errors(run_copy: Path) -> None:
    _truncate(_latest_file(run_copy, "arrays.npz"))
    with pytest.raises(CheckpointError, match="arrays.npz"):
        checkpoint.load(checkpoint.latest(run_copy), need_replay=False)


def test_missing_run_folder_names_config_json(tmp_path: Path) -> None:
    with pytest.raises(PolicyFileError, match=re.escape(str(tmp_path / "nope" / "config.json"))):
        train(TrainConfig(), resume_dir=tmp_path / "nope")


def _reseal(folder: Path) -> None:
    """Record the sha256 of a checkpoint's edited files in its manifest (as a well-formed but wrong file)."""
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["sha256"] = {name: file_sha256(folder / name) for name in manifest["sha256"]}
    (folder / "manifest.json").write_text(json.dumps(manifest))


def _drop_state_key(run: Path) -> None:
    path = _latest_file(run, "state.json")
    state = json.loads(path.read_text())
    del state["config"]
    path.write_text(json.dumps(state))
    _reseal(path.parent)


def _wrong_format(run: Path) -> None:
    path = _latest_file(run, "state.json")
    path.write_text('{"format": "x"}')
    _reseal(path.parent)


def _drop_array(run: Path) -> None:
    path = _latest_file(run, "arrays.npz")
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files if k != "lwr.bug"}
    with path.open("wb") as fh:
        np.savez(fh, **arrays)
    _reseal(path.parent)


@pytest.mark.parametrize(("damage", "name", "reason"), [
    (_drop_state_key, "state.json", "missing entries"), (_drop_array, "arrays.npz", "missing arrays"),
    (_wrong_format, "state.json", "format 'x'")], ids=["state-json-lacks-config", "arrays-npz-lacks-lwr", "format"])
def test_checkpoint_lacking_a_key_names_the_file(run_copy: Path, damage: Any, name: str, reason: str) -> None:
    """Files whose checksums fit their manifest, but which are still wrong, are named too."""
    path = _latest_file(run_copy, name)
    damage(run_copy)
    with pytest.raises(PolicyFileError, match=f"{re.escape(str(path))}.*{reason}"):
        train(TrainConfig(), resume_dir=run_copy, overrides={"epochs": 99})


@pytest.mark.parametrize(("field", "changes"), [
    ("learn", {"learn": ["spider=ddpg"], "policies": ["ant=zero", "bug=random"]}),
    ("obs_mode", {"obs_mode": "egocentric"}),
    ("ddpg", {"ddpg": {**json.loads(json.dumps(TINY_DDPG.__dict__)), "hidden": [8, 8]}}),
    ("learner_config", {"learner_config": ["bug.hidden=8 8"]}),
])
def test_incompatible_checkpoint_names_the_field(run_copy: Path, field: str, changes: dict[str, Any]) -> None:
    config = run_copy / "config.json"
    config.write_text(json.dumps(json.loads(config.read_text()) | changes))
    state = re.escape(str(_latest_file(run_copy, "state.json")))
    with pytest.raises(CheckpointError, match=f"{state}: incompatible checkpoint.*{field}="):
        train(TrainConfig(), resume_dir=run_copy)


# ---------------------------------------------- run folder and matches at start


class _BuildFailed(Exception):
    """Stands for building the run's matches failing (a model MuJoCo refuses, too little memory)."""


def _matches_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make building the matches raise :class:`_BuildFailed`. The trainer builds them with ``make_env``, which
    calls ``VectorMatches`` of :mod:`triplesumo.train.collect` (a cpu run); the tests below that expect
    ``_BuildFailed`` fail, rather than pass unseen, should that ever stop being the path."""
    def fails(*args: Any, **kwargs: Any) -> None:
        raise _BuildFailed("building the matches failed on purpose")

    monkeypatch.setattr(train_collect, "VectorMatches", fails)


def _files(folder: Path) -> dict[str, bytes | None]:
    """Everything under ``folder``: a file's bytes, None for a folder."""
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else None for p in sorted(folder.rglob("*"))}


def test_a_failed_match_build_leaves_no_run_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The trainer builds its matches before it creates the run folder: a failure leaves nothing behind."""
    _matches_fail(monkeypatch)
    with pytest.raises(_BuildFailed):
        Trainer(tiny(tmp_path / "out"))
    assert _files(tmp_path) == {}  # neither --out nor the run folder was made


def test_a_run_folder_holding_a_run_is_refused_before_the_matches_are_built(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    run = tmp_path / "out" / "run"
    run.mkdir(parents=True)
    (run / "config.json").write_text("{}")
    before = _files(tmp_path)
    _matches_fail(monkeypatch)
    with pytest.raises(RunExistsError, match=f"run folder {re.escape(str(run))} already holds a run"):
        Trainer(tiny(tmp_path / "out"))
    assert _files(tmp_path) == before
    with pytest.raises(_BuildFailed):  # the same build, for a free name: it is on the path the refusal came before
        Trainer(tiny(tmp_path / "out", "free"))


def _under_a_file(tmp_path: Path) -> tuple[Path, Path]:
    (tmp_path / "a-file").write_text("not a folder")
    return tmp_path / "a-file" / "sub", tmp_path / "a-file" / "sub" / "run"


def _run_is_a_file(tmp_path: Path) -> tuple[Path, Path]:
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "run").write_text("not a folder")
    return tmp_path / "out", tmp_path / "out" / "run"


@pytest.mark.parametrize("place", [_under_a_file, _run_is_a_file], ids=["under-a-file", "run-is-a-file"])
def test_a_run_folder_that_cannot_be_made_fails_at_start(tmp_path: Path, place: Any) -> None:
    """A path no mkdir can make, even as root: refused when the trainer is made, naming the folder, nothing
    written."""
    out, run = place(tmp_path)
    before = _files(tmp_path)
    with pytest.raises(PermissionError, match=f"run folder {re.escape(str(run))} is not writable"):
        Trainer(tiny(out))
    assert _files(tmp_path) == before


def test_read_only_run_folder_fails_at_start(tmp_path: Path) -> None:
    """chmod 500 on --out (skipped as root, who writes anyway: the test above holds for root too)."""
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if os.access(locked, os.W_OK):
            pytest.skip("chmod does not stop this user (root) from writing")
        with pytest.raises(PermissionError, match=f"run folder {re.escape(str(locked / 'run'))} is not writable"):
            Trainer(tiny(locked))
        assert not list(locked.iterdir())
    finally:
        locked.chmod(0o700)


# ------------------------------------------------------------------ validation


@pytest.mark.parametrize(("fields", "named"), [
    ({"epochs": 0}, "TrainConfig.epochs"),
    ({"epochs": True}, "TrainConfig.epochs"),
    ({"n_envs": 0}, "TrainConfig.n_envs"),
    ({"steps_per_epoch": -5}, "TrainConfig.steps_per_epoch"),
    ({"checkpoint_every": 0}, "TrainConfig.checkpoint_every"),
    ({"obs_mode": "pixels"}, "TrainConfig.obs_mode"),
    ({"policies": ("bug=random",)}, "TrainConfig.policies.*learner 'bug'"),
    ({"policies": ("spider",)}, "TrainConfig.policies.*AGENT=POLICY"),
    ({"policies": ("spider=random=zero",)}, "TrainConfig.policies.*AGENT=POLICY"),
    ({"policies": ("=random",)}, "TrainConfig.policies.*AGENT=POLICY"),
    ({"name": "a/b"}, "TrainConfig.name"),
    ({"max_minutes": -1.0}, "TrainConfig.max_minutes"),
])
def test_config_errors_name_the_field(tmp_path: Path, fields: dict[str, Any], named: str) -> None:
    with pytest.raises(ValueError, match=named):
        tiny(tmp_path, **fields)


def test_the_deprecated_learner_field_reads_as_a_one_ddpg_learner_learn() -> None:
    """``learner`` (``--learner``) was the one DDPG learner beside ``learn``; it stays a deprecated alias, and a
    config.json written while it was a field (``learn`` empty) reads as its ``learn``."""
    with pytest.warns(DeprecationWarning, match="TrainConfig.learner is deprecated: use learn AGENT=ddpg"):
        cfg = TrainConfig(learner="spider", policies=("ant=zero", "bug=random"))
    assert cfg.learn == ("spider=ddpg",) and cfg.learner is None and cfg.learners() == {"spider": "ddpg"}
    assert "learner" not in config_to_json(cfg)
    both = r"TrainConfig.learner \(deprecated\) and learn"
    with pytest.warns(DeprecationWarning), pytest.raises(ValueError, match=both):
        TrainConfig(learner="spider", learn=("bug=sac",))
    with pytest.raises(ValueError, match="TrainConfig.learn must name at least one"):
        TrainConfig(learn=())
    old = config_to_json(TrainConfig()) | {"learner": "spider", "learn": [], "policies": ["ant=zero", "bug=random"]}
    assert config_from_json(old).learn == ("spider=ddpg",)
    given = old | {"learn": ["bug=sac"], "policies": ["ant=zero", "spider=random"]}  # learn given: it replaced learner
    assert config_from_json(given).learn == ("bug=sac",)


@pytest.mark.parametrize(("fields", "named"), [
    ({"learn": ("dragon=ddpg",)}, "TrainConfig.learn.*dragon"),
    ({"policies": ("spider=random", "dragon=zero")}, "TrainConfig.policies.*dragon"),
    ({"policies": ("spider=random", "spider=zero")}, "'spider' given twice"),
    ({"policies": ("spider=telepathy",)}, "unknown policy 'telepathy'"),
])
def test_trainer_rejects_unknown_agents_and_policies(tmp_path: Path, fields: dict[str, Any], named: str) -> None:
    with pytest.raises(ValueError, match=named):
        Trainer(tiny(tmp_path, **fields))


def test_the_physics_field_reaches_the_matches_and_old_config_json_means_the_v0_ring(tmp_path: Path) -> None:
    rim = Trainer(tiny(tmp_path))  # the default since env v1
    try:
        assert rim.match_cfg.physics.border_rim
        model = rim.collector.batch.matches[0].model
        border = [g for g in range(model.ngeom) if (model.geom(g).name or "").startswith("border")]
        assert border and all(model.geom_contype[g] or model.geom_conaffinity[g] for g in border)  # solid rim
        assert rim.manifest(rim.learners[0])["physics"]["border_rim"] is True  # the policy file says which ring
    finally:
        rim.collector.batch.close()
    saved = config_to_json(tiny(tmp_path))
    del saved["physics"]  # a run folder written before the field existed: env v0's visual ring, as it ran
    assert config_from_json(saved).physics == V0_PHYSICS == PhysicsConfig(border_rim=False, layout="circle",
                                                                            rim_shape="cylinder")
    with pytest.raises(ValueError, match="PhysicsConfig.frame_skip"):
        config_from_json({**config_to_json(tiny(tmp_path)), "physics": {**asdict(PhysicsConfig()), "frame_skip": 0}})


# -------------------------------------------------------------------------- CLI

CLI_TINY = ["--policies", "spider=random", "ant=zero", "--ddpg.hidden", "16", "16", "--ddpg.buffer-size", "2000",
            "--ddpg.learning-starts", "50", "--ddpg.batch-size", "16", "--ddpg.learn-every", "2",
            "--n-envs", "2", "--steps-per-epoch", "20", "--checkpoint-every", "2", "--no-progress",
            "--no-tensorboard"]


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_cli_train_resume_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "cli"
    assert main(["train", "--out", str(tmp_path), "--name", "cli", "--epochs", "3", *CLI_TINY]) == 0
    assert "run folder" in capsys.readouterr().out
    saved = config_from_json(json.loads((run / "config.json").read_text()))
    assert saved.ddpg.hidden == (16, 16) and saved.policies == ("spider=random", "ant=zero") and saved.epochs == 3
    header, rows = read_rows(run)
    assert tuple(header) == COLUMNS
    first = len(rows)
    assert first >= 3 and [int(r["epoch"]) for r in rows] == list(range(1, first + 1))

    assert main(["train", "--resume", str(run), "--epochs", "6", "--no-progress"]) == 0
    _, rows = read_rows(run)
    assert len(rows) >= 6 and [int(r["epoch"]) for r in rows] == list(range(1, len(rows) + 1))
    assert json.loads((run / "policy.json").read_text())["epochs"] == len(rows)

    shutil.rmtree(run / "plots")
    assert main(["plot", str(run), "--window", "5"]) == 0
    assert all((run / "plots" / name).is_file() for name in PLOTS)
    assert "mwr.png" in capsys.readouterr().out


def test_cli_bad_value_exits_2_naming_the_field(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["train", "--out", str(tmp_path), "--name", "bad", *CLI_TINY, "--epochs", "0"]) == 2
    assert "TrainConfig.epochs" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_cli_resume_of_missing_run_exits_2_naming_the_file(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["train", "--resume", str(tmp_path / "gone")]) == 2
    assert str(tmp_path / "gone" / "config.json") in capsys.readouterr().err


def test_resume_without_the_replay_buffer_needs_saying_so(run_copy: Path) -> None:
    """A run committed without its replay buffer (to continue in another session) resumes
    only with save_replay=False, from the same weights and counters, with an empty buffer."""
    folder = checkpoint.latest(run_copy)
    (folder / "replay.npz").unlink()
    with pytest.raises(CheckpointError, match=re.escape(str(folder / "replay.npz"))):
        train(TrainConfig(), resume_dir=run_copy, overrides={"epochs": 3 * E})
    result = train(TrainConfig(), resume_dir=run_copy, overrides={"epochs": 3 * E, "save_replay": False})
    assert result.epochs >= 3 * E
    _, rows = read_rows(run_copy)
    assert [int(r["epoch"]) for r in rows] == list(range(1, len(rows) + 1))


@pytest.mark.slow  # 6 s alone on the shared 2-core box
def test_overlapped_learning_gives_the_same_run_as_serial_learning(tmp_path: Path) -> None:
    """Updates run in a thread while MuJoCo steps; they read the replay as it was before the
    step and their own sampling generator, so the run is bit for bit the serial one."""
    serial = train(tiny(tmp_path, "serial", overlap_learning=False)).run_dir
    overlapped = train(tiny(tmp_path, "overlap", overlap_learning=True)).run_dir
    assert_same_tensors(serial / "policy.safetensors", overlapped / "policy.safetensors")
    assert without_wall_time(read_rows(serial)[1]) == without_wall_time(read_rows(overlapped)[1])
    assert_same_tensors(checkpoint.latest(serial) / "weights.safetensors",
                        checkpoint.latest(overlapped) / "weights.safetensors")


@pytest.mark.slow  # 12 s alone on the shared 2-core box
@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_learners_acting_beside_their_updates_give_the_serial_run(tmp_path: Path, algo: str) -> None:
    """SAC and TD3 act at every step while their updates (one per step here) change the actor in the update
    thread: they act with a copy of the actor as the last step's updates left it, so the run is the serial one."""
    from triplesumo.algos.sac import SACConfig
    from triplesumo.algos.td3 import TD3Config

    small = {"hidden": (16, 16), "buffer_size": 5000, "learning_starts": 50, "batch_size": 16, "learn_every": 2}
    fields = {"learn": (f"bug={algo}",), algo: (SACConfig if algo == "sac" else TD3Config)(**small)}
    serial = train(tiny(tmp_path, "serial", overlap_learning=False, **fields)).run_dir
    overlapped = train(tiny(tmp_path, "overlap", overlap_learning=True, **fields)).run_dir
    assert_same_tensors(checkpoint.latest(serial) / "weights.safetensors",
                        checkpoint.latest(overlapped) / "weights.safetensors")
    assert without_wall_time(read_rows(serial)[1]) == without_wall_time(read_rows(overlapped)[1])


def test_an_error_in_the_update_thread_reaches_the_caller(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(self: Any, batch: Any) -> dict[str, float]:
        raise RuntimeError("update failed on purpose")

    monkeypatch.setattr(DDPG, "update", broken)
    with pytest.raises(RuntimeError, match="update failed on purpose"):
        train(tiny(tmp_path, "broken", overlap_learning=True))


def _as_one_learner_layout(run: Path) -> None:
    """Rewrite a run's latest checkpoint, config and CSVs as the one-DDPG-learner trainer wrote them."""
    folder = checkpoint.latest(run)
    state = json.loads((folder / "state.json").read_text())
    learner = state.pop("learners")["bug"]
    state.pop("final")
    state |= {"optimizer": learner["optimizer"], "sample_rng": learner["sample_rng"], "acc": state["acc"]["bug"]}
    (folder / "state.json").write_text(json.dumps(state))
    tensors = {k.removeprefix("bug."): v for k, v in load_file(str(folder / "weights.safetensors")).items()}
    from safetensors.torch import save_file

    save_file(tensors, str(folder / "weights.safetensors"))
    for name, rename in (("arrays.npz", lambda k: {"lwr.bug": "lwr"}.get(k, k.removeprefix("bug."))),
                         ("replay.npz", lambda k: k.removeprefix("bug."))):
        with np.load(folder / name) as data:
            arrays = {rename(k): data[k] for k in data.files if k != "bug.active"}
        with (folder / name).open("wb") as fh:
            np.savez(fh, **arrays)
    _reseal(folder)
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({k: v for k, v in config.items()
                                                 if k not in ("learn", "share", "td3", "sac", "ppo")}))
    (run / "learning.csv").unlink()


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_a_run_of_the_one_learner_trainer_resumes_exactly(uninterrupted: Trained, tmp_path: Path) -> None:
    """Runs checkpointed before several learners existed (long runs resumed across sessions)."""
    killed = train(tiny(tmp_path, name="old", epochs=E)).run_dir
    _as_one_learner_layout(killed)
    train(TrainConfig(), resume_dir=killed, overrides={"epochs": 2 * E})
    assert_same_run(uninterrupted.run, killed)
    rows = list(csv.reader((killed / "learning.csv").open()))
    assert all(cell == "" for row in rows[1:E + 1] for cell in row[1:])  # the epochs before: empty learning rows
    assert int(rows[-1][1]) == uninterrupted.result.updates


def test_max_env_steps_stops_at_the_first_epoch_end_past_the_budget(tmp_path: Path) -> None:
    """An env-step budget ends the run at the first epoch end past it, with a checkpoint there,
    and ``training_done`` (what sweeps and ``reproduce`` skip on) sees the run as done."""
    from triplesumo.train.run_folder import training_done

    cfg = TrainConfig(name="budget", out=str(tmp_path), policies=("spider=random", "ant=zero"), epochs=1000,
                      steps_per_epoch=20, n_envs=2, checkpoint_every=1000, max_env_steps=60, progress=False,
                      tensorboard=False, ddpg=DDPGConfig(hidden=(8, 8), buffer_size=500, learning_starts=1000))
    result = train(cfg)
    assert 60 <= result.env_steps < 60 + 2 * 20 and result.epochs < 1000
    saved = checkpoint.checkpoints(result.run_dir)
    assert saved and saved[-1][0] == result.epochs  # the stop left a checkpoint
    assert training_done(cfg) and not training_done(dataclasses.replace(cfg, max_env_steps=0))
    shutil.rmtree(result.run_dir / "checkpoints")  # a finished run kept small: its policy file says it is done
    assert training_done(cfg) and not training_done(dataclasses.replace(cfg, max_env_steps=0))
    assert training_done(dataclasses.replace(cfg, epochs=result.epochs, max_env_steps=0))
    (result.run_dir / "policy.json").unlink()
    assert not training_done(cfg)
    with pytest.raises(ValueError, match="TrainConfig.max_env_steps must be an int >= 0"):
        TrainConfig(max_env_steps=-1)


def test_a_config_written_before_the_axis_dead_zone_reads_with_the_paper_sign() -> None:
    """Run folders written before ``RewardConfig.axis_dead_zone`` existed (e.g. the committed contest run) resume
    with 0, the sign they were trained under; any other missing reward key is still an error naming it."""
    import json

    from triplesumo.train.run_folder import config_from_json

    data = json.loads((Path(__file__).resolve().parents[1] / "docs/runs/contest-v2/contest-co-draw200/config.json")
                      .read_text())
    assert "axis_dead_zone" not in data["reward"] and "opponents" not in data["reward"]
    read = config_from_json(data).reward
    assert read.axis_dead_zone == 0.0 and read.opponents == "mean"  # (and the mean over opponents, likewise)
    del data["reward"]["still"]
    with pytest.raises(ValueError, match=r"missing key\(s\) \['reward.still'\]"):
        config_from_json(data)


def test_fields_added_later_read_with_what_earlier_runs_used_not_todays_defaults() -> None:
    """A run folder written before SAC's ``n_step``, ``critic_norm`` and ``update_dtype`` (and the others' ``n_step``
    and ``update_dtype``) existed resumes with one-step targets, plain critics and float32 updates, what it trained
    with, whatever the learners' defaults are now: the filled values are written out, not read from the defaults."""

    from triplesumo.algos.sac import SACConfig
    from triplesumo.train.run_folder import config_from_json, config_to_json

    data = config_to_json(TrainConfig(sac=SACConfig(n_step=5, critic_norm="layer", update_dtype="bfloat16")))
    for algo in ("sac", "ddpg", "td3"):
        for name in ("n_step", "update_dtype"):
            del data[algo][name]
    del data["sac"]["critic_norm"]
    read = config_from_json(data)
    assert (read.sac.n_step, read.sac.critic_norm, read.sac.update_dtype) == (1, "none", "float32")
    assert all((getattr(read, a).n_step, getattr(read, a).update_dtype) == (1, "float32") for a in ("ddpg", "td3"))
    del data["sac"]["alpha"]
    with pytest.raises(ValueError, match=r"missing key\(s\) \['sac.alpha'\]"):
        config_from_json(data)
