"""``train --fork``: a new run continuing another run's checkpoint under changed league rules.

The tiny two-sided self-play run of ``test_train_selfplay`` (both sides of the 2-vs-1 learning,
16 matches of 20 steps): a fork that changes nothing but the budget continues exactly as the
uninterrupted run; a fork that changes the admission threshold admits by the new rule from its
first epoch; the parent is never touched; what a fork may not change is refused by name.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import read_only, tiny
from test_train_selfplay import BOTH_COMMAND, both
from triplesumo.agents.policy_file import file_sha256, load_policy, load_tensors
from triplesumo.cli import main
from triplesumo.train.fork import added_seeds, check_fork, fork_run
from triplesumo.train.league_config import LeagueConfig
from triplesumo.train.legs import read_legs
from triplesumo.train.loop import Trainer, train
from triplesumo.train.run_folder import config_from_json


def rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return [{k: v for k, v in r.items() if k != "wall_time"} for r in csv.DictReader(fh)]


def digests(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): file_sha256(p) for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Trainer, Trainer]:
    """The uninterrupted 16-epoch run and its first 8 epochs (the parent of the forks)."""
    full = Trainer(both(tmp_path_factory.mktemp("full")), command=BOTH_COMMAND)
    full.run()
    half = Trainer(both(tmp_path_factory.mktemp("half"), epochs=8), command=BOTH_COMMAND)
    half.run()
    return full, half


@pytest.mark.slow  # 81 s alone on the shared 2-core box
def test_a_fork_that_changes_only_the_budget_continues_as_the_uninterrupted_run(
        runs: tuple[Trainer, Trainer], tmp_path: Path) -> None:
    full, half = runs
    before = digests(half.run_dir)
    cfg = dataclasses.replace(half.cfg, name="more", out=str(tmp_path), epochs=16)
    fork_dir = fork_run(half.run_dir, cfg)
    assert digests(half.run_dir) == before  # the parent is untouched
    record = json.loads((fork_dir / "fork.json").read_text())
    assert record["epoch"] == 8 and record["checkpoint"] == "epoch-000008" and record["changes"] == {
        "name": ["both", "more"], "out": [half.cfg.out, str(tmp_path)], "epochs": [8, 16]}
    assert record["parent_command"] == BOTH_COMMAND and record["parent_run_id"] == half.record.run_id
    result = train(dataclasses.replace(cfg, epochs=1), resume_dir=fork_dir)  # the saved config is used
    assert result.epochs == 16
    assert full.seats.league is not None
    a, b = full.run_dir, fork_dir
    for name in ("metrics-ant.csv", "metrics-spider.csv", "learning-ant+bug.csv", "learning-spider.csv"):
        assert rows(a / name) == rows(b / name), name
    assert (a / "league/league.csv").read_text() == (b / "league/league.csv").read_text()
    mine, theirs = (json.loads((r / "league/pool.json").read_text()) for r in (b, a))
    def weights_only(members: list[dict[str, object]]) -> list[dict[str, object]]:
        """A member less the digests of its manifests (they name the fork's command and run id)."""
        return [m | {"sha256": {f: d for f, d in m["sha256"].items() if f.endswith(".safetensors")}}  # type: ignore
                for m in members]

    for side, pool in theirs["pools"].items():
        assert weights_only(mine["pools"][side]["members"]) == weights_only(pool["members"])
        assert mine["pools"][side]["window"] == pool["window"]
        assert {m["id"] for m in mine["pools"][side]["evicted"]} <= {m["id"] for m in pool["evicted"]}
    assert mine["ratings"] == theirs["ratings"] and mine["rng"] == theirs["rng"]
    for learner in ("ant+bug", "spider"):
        x, y = load_tensors(a / f"policy-{learner}.safetensors"), load_tensors(b / f"policy-{learner}.safetensors")
        assert x.keys() == y.keys() and all((x[k] == y[k]).all() for k in x), learner
        _, manifest = load_policy(b / f"policy-{learner}")
        assert manifest["command"] == record["command"] and manifest["command"].startswith(
            f"triplesumo train --fork {half.run_dir} --name more")
        assert manifest["forked_from"]["run_id"] == half.record.run_id and manifest["forked_from"]["epoch"] == 8
        assert manifest["run_id"] != half.record.run_id
    # the fork resumes like any run
    assert train(cfg, resume_dir=fork_dir, overrides={"epochs": 18}).epochs >= 18


@pytest.mark.slow  # 39 s alone on the shared 2-core box
def test_a_packed_parent_forks_and_resumes_as_the_uninterrupted_run(runs: tuple[Trainer, Trainer],
                                                                     tmp_path: Path) -> None:
    """Its tables gzipped (``triplesumo pack``: metrics, learning, the league log), a self-play run forks and
    resumes as the plain one: the tables come back plain, with the uninterrupted run's rows."""
    from triplesumo.evaluation.metrics_csv import pack_tables

    full, half = runs
    parent = tmp_path / "packed" / half.run_dir.name
    shutil.copytree(half.run_dir, parent)
    packed = {p.relative_to(parent).as_posix() for p in pack_tables(parent, min_bytes=0)}
    assert {"league/league.csv.gz", "metrics-ant.csv.gz", "learning-spider.csv.gz"} <= packed
    cfg = dataclasses.replace(half.cfg, name="more", out=str(tmp_path), epochs=16)
    fork_dir = fork_run(parent, cfg)
    train(cfg, resume_dir=fork_dir)
    resumed = train(half.cfg, resume_dir=parent, overrides={"epochs": 16}).run_dir
    for run in (fork_dir, resumed):
        assert not list(run.rglob("*.csv.gz"))
        for name in ("metrics-ant.csv", "metrics-spider.csv", "learning-ant+bug.csv", "learning-spider.csv"):
            assert rows(full.run_dir / name) == rows(run / name), (run, name)
        assert (full.run_dir / "league/league.csv").read_text() == (run / "league/league.csv").read_text()


@pytest.mark.slow  # 15 s alone on the shared 2-core box
def test_a_fork_admits_by_its_own_league_rules_from_the_fork_epoch(
        runs: tuple[Trainer, Trainer], tmp_path: Path) -> None:
    full, half = runs
    assert full.seats.league is not None
    admitted_after = [m for p in full.seats.league.pools.values() for m in (*p.members, *p.evicted) if m.epoch > 8]
    assert admitted_after  # uninterrupted, the threshold of 0 goes on admitting
    strict = dataclasses.replace(half.cfg.league, snapshot_every=1000, side_threshold=("team=0.95",))
    cfg = dataclasses.replace(half.cfg, name="strict", out=str(tmp_path), epochs=16, league=strict)
    fork_dir = fork_run(half.run_dir, cfg)
    record = json.loads((fork_dir / "fork.json").read_text())
    assert record["changes"]["league.snapshot_every"] == [2, 1000]
    assert record["changes"]["league.side_threshold"] == [[], ["team=0.95"]]
    trainer = Trainer(cfg, run_dir=fork_dir, resume=True)
    trainer.run()
    league = trainer.seats.league
    assert league is not None and league.config == strict
    assert league.pools["team"].threshold == 0.95 and league.pools["spider"].threshold == 0.0
    assert not [m for p in league.pools.values() for m in (*p.members, *p.evicted) if m.epoch > 8]
    assert "--league.snapshot-every 1000 --league.side-threshold team=0.95" in record["command"]


@pytest.mark.slow  # 12 s alone on the shared 2-core box
def test_a_fork_may_fine_tune_under_other_reward_weights_from_the_fork_epoch(
        runs: tuple[Trainer, Trainer], tmp_path: Path) -> None:
    """``--reward.still 0``: every step after the fork is scored without the time penalty, every step
    before it with the parent's; a match in flight at the fork is charged for its steps before it only."""
    _, half = runs
    assert half.cfg.reward.still == -4.0
    cfg = dataclasses.replace(half.cfg, name="still0", out=str(tmp_path), epochs=14,
                              reward=dataclasses.replace(half.cfg.reward, still=0.0))
    fork_dir = fork_run(half.run_dir, cfg)
    record = json.loads((fork_dir / "fork.json").read_text())
    assert record["changes"]["reward.still"] == [-4.0, 0.0] and "--reward.still 0.0" in record["command"]
    trainer = Trainer(cfg, run_dir=fork_dir, resume=True)
    trainer.run()
    assert trainer.cfg.reward.still == 0.0
    after = 0
    for name in ("metrics-ant.csv", "metrics-spider.csv"):
        parent, fork = rows(half.run_dir / name), rows(fork_dir / name)
        assert fork[:len(parent)] == parent and len(fork) > len(parent)
        for row in parent:  # before the fork: the full time penalty, -4 a step
            assert float(row["reward_still"]) == -4.0 * int(row["steps"])
        new = [float(r["reward_still"]) for r in fork[len(parent):]]
        steps = [int(r["steps"]) for r in fork[len(parent):]]
        # after it: nothing, but for the steps before the fork of the matches in flight then (one a slot)
        assert all(-4.0 * n < v <= 0.0 for v, n in zip(new, steps, strict=True))
        assert sum(v != 0.0 for v in new) <= cfg.n_envs
        after += sum(v == 0.0 for v in new)
    assert after  # some matches were played wholly after the fork


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_a_fork_may_fine_tune_the_learners_step_sizes_and_exploration(
        runs: tuple[Trainer, Trainer], tmp_path: Path) -> None:
    """``--ddpg.actor-lr``, ``--ddpg.noise-sigma`` and one learner's ``--learner-config``: the fork's learners
    step with the new rates and explore with the new σ, while their Adam moments and update count go on
    from the checkpoint's (a fresh optimiser would have restarted them)."""
    _, half = runs
    ddpg = dataclasses.replace(half.cfg.ddpg, actor_lr=half.cfg.ddpg.actor_lr / 5, noise_sigma=0.05)
    cfg = dataclasses.replace(half.cfg, name="tuned", out=str(tmp_path), epochs=10, ddpg=ddpg,
                              learner_config=("spider.critic_lr=0.0002",))
    fork_dir = fork_run(half.run_dir, cfg)
    record = json.loads((fork_dir / "fork.json").read_text())
    assert record["changes"]["ddpg.actor_lr"] == [half.cfg.ddpg.actor_lr, ddpg.actor_lr]
    assert record["changes"]["ddpg.noise_sigma"] == [half.cfg.ddpg.noise_sigma, 0.05]
    assert record["changes"]["learner_config"] == [[], ["spider.critic_lr=0.0002"]]
    assert "--ddpg.noise-sigma 0.05" in record["command"]
    assert "--learner-config spider.critic_lr=0.0002" in record["command"]
    parent = Trainer(half.cfg, run_dir=half.run_dir, resume=True)  # the parent's checkpoint, loaded as it was
    trainer = Trainer(cfg, run_dir=fork_dir, resume=True)
    for old, new in zip(parent.learners, trainer.learners, strict=True):
        assert new.algo.num_updates == old.algo.num_updates > 0
        lrs = [g["lr"] for g in new.algo.actor_optimizer.param_groups]
        assert lrs == [ddpg.actor_lr] and [g["lr"] for g in old.algo.actor_optimizer.param_groups] == [
            half.cfg.ddpg.actor_lr]
        critic = 0.0002 if new.spec.name == "spider" else half.cfg.ddpg.critic_lr
        assert [g["lr"] for g in new.algo.critic_optimizer.param_groups] == [critic]
        for name in ("actor_optimizer", "critic_optimizer"):
            a, b = (getattr(x.algo, name).state_dict()["state"] for x in (old, new))
            assert a.keys() == b.keys() and a
            assert all(torch.equal(a[i]["exp_avg"], b[i]["exp_avg"]) for i in a)
        assert new.noise is not None and new.noise.sigma == 0.05 and old.noise is not None
        assert np.array_equal(new.noise.state_dict()["x"], old.noise.state_dict()["x"])  # the process goes on
    before = [lr.algo.num_updates for lr in trainer.learners]
    trainer.run()
    assert all(lr.algo.num_updates > n for lr, n in zip(trainer.learners, before, strict=True))
    assert [g["lr"] for g in trainer.learners[0].algo.actor_optimizer.param_groups] == [ddpg.actor_lr]


@pytest.mark.slow  # uses the module's runs fixture, 40 s to build
def test_what_a_fork_may_not_change_is_refused_by_name_and_nothing_is_written(
        runs: tuple[Trainer, Trainer], tmp_path: Path) -> None:
    _, half = runs
    base = dataclasses.replace(half.cfg, name="bad", out=str(tmp_path))
    for change, flag in (({"seed": 4}, "--seed"), ({"ddpg": dataclasses.replace(half.cfg.ddpg, hidden=(8,))},
                                                   "--ddpg.hidden"),
                         ({"ddpg": dataclasses.replace(half.cfg.ddpg, noise="gaussian")}, "--ddpg.noise"),
                         ({"learner_config": ("spider.buffer_size=100",)}, "--learner-config spider.buffer_size"),
                         ({"league": dataclasses.replace(half.cfg.league, rating_model="BradleyTerryFull")},
                          "--league.rating-model")):
        with pytest.raises(ValueError, match=f"a fork continues .* not {flag}"):
            fork_run(half.run_dir, dataclasses.replace(base, **change))
        assert not (tmp_path / "bad").exists()
    with pytest.raises(ValueError, match="the parent's folder"):
        fork_run(half.run_dir, dataclasses.replace(half.cfg, epochs=9))
    fork_run(half.run_dir, base)
    with pytest.raises(ValueError, match="already holds a run"):
        fork_run(half.run_dir, base)
    with pytest.raises(FileNotFoundError, match="no run to fork"):
        fork_run(tmp_path / "nothing", base)


@pytest.mark.slow  # 6 s alone on the shared 2-core box
def test_cli_fork_writes_beside_the_parent_and_needs_a_name(
        runs: tuple[Trainer, Trainer], capsys: pytest.CaptureFixture[str]) -> None:
    _, half = runs
    assert main(["train", "--fork", str(half.run_dir), "--epochs", "10"]) == 2
    assert "--fork needs --name" in capsys.readouterr().err
    assert main(["train", "--fork", str(half.run_dir), "--name", "cli", "--seed", "5"]) == 2
    assert "not --seed" in capsys.readouterr().err
    assert main(["train", "--fork", str(half.run_dir), "--name", "cli", "--epochs", "10",
                 "--league.side-threshold", "team=0.5", "--from", "epoch-8"]) == 0
    fork_dir = half.run_dir.parent / "cli"
    saved = json.loads((fork_dir / "config.json").read_text())
    assert saved["epochs"] == 10 and saved["league"]["side_threshold"] == ["team=0.5"] and saved["name"] == "cli"
    assert json.loads((fork_dir / "checkpoints/latest.json").read_text())["epoch"] == 10
    assert LeagueConfig(**json.loads((fork_dir / "league/pool.json").read_text())["config"]).threshold_of(
        "team") == 0.5


@pytest.mark.slow  # 66 s alone on the shared 2-core box
def test_compact_keeps_what_resuming_needs_and_the_resumed_run_is_unchanged(
        runs: tuple[Trainer, Trainer], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    long = Trainer(both(tmp_path / "long", epochs=32), command=BOTH_COMMAND)  # pools of 3, 16 admission checks
    long.run()
    run, plain = tmp_path / "compacted" / "both", tmp_path / "plain" / "both"
    shutil.copytree(long.run_dir, run)
    shutil.copytree(long.run_dir, plain)
    pool = json.loads((run / "league/pool.json").read_text())
    evicted = {m["id"] for p in pool["pools"].values() for m in p["evicted"]}
    assert evicted  # something to compact
    assert sorted(p.name for p in (run / "checkpoints").glob("epoch-*")) == ["epoch-000024", "epoch-000032"]
    assert main(["compact", str(run)]) == 0
    assert "evicted league member(s)" in capsys.readouterr().out
    assert [p.name for p in (run / "checkpoints").glob("epoch-*")] == ["epoch-000032"]
    pruned = json.loads((run / "league/pruned.json").read_text())["members"]
    state = json.loads((run / "checkpoints/epoch-000032/state.json").read_text())
    seated = {m for seats in state["seats"] for m in seats if m}
    assert pruned and {m["id"] for m in pruned} == evicted - seated and all(m["sha256"] for m in pruned)
    for m in pruned:
        assert not (run / "league/members" / m["id"]).exists() and (plain / "league/members" / m["id"]).exists()
    kept = json.loads((run / "league/pool.json").read_text())
    assert kept["pools"] == state["league"]["pools"]
    assert {m["id"] for p in kept["pools"].values() for m in p["evicted"]} == evicted & seated
    # resumed after compaction, it trains exactly what the run resumed without compaction does
    for folder in (run, plain):
        assert train(long.cfg, resume_dir=folder, overrides={"epochs": 40}).epochs == 40
    for name in ("metrics-ant.csv", "metrics-spider.csv", "learning-ant+bug.csv", "learning-spider.csv"):
        assert rows(plain / name) == rows(run / name), name
    assert (plain / "league/league.csv").read_text() == (run / "league/league.csv").read_text()
    for learner in ("ant+bug", "spider"):
        assert (plain / f"policy-{learner}.safetensors").read_bytes() == (
            run / f"policy-{learner}.safetensors").read_bytes()
    assert main(["compact", str(run)]) == 0  # again: the list of pruned members grows, nothing is lost from it
    assert {m["id"] for m in pruned} <= {m["id"] for m in json.loads((run / "league/pruned.json").read_text())[
        "members"]}
    assert main(["compact", str(tmp_path / "nothing")]) == 2


@pytest.mark.parametrize("frozen", [".", "checkpoints"])
@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_compact_of_a_read_only_run_fails_naming_the_path_and_removes_nothing(
        tmp_path: Path, frozen: str, capsys: pytest.CaptureFixture[str]) -> None:
    run = train(tiny(tmp_path)).run_dir  # checkpoints at epochs 2 and 4
    before = digests(run)
    assert {p.name for p in (run / "checkpoints").glob("epoch-*")} == {"epoch-000002", "epoch-000004"}
    with read_only(run / frozen):
        assert main(["compact", str(run)]) == 2
    out, err = capsys.readouterr()
    assert "removed" not in out
    assert (f"{run}: cannot write its lock file" if frozen == "." else
            f"cannot remove {run / 'checkpoints' / 'epoch-000002'}") in err, err
    assert digests(run) == before  # nothing removed, nothing half-removed
    assert main(["compact", str(run)]) == 0  # writable again: it goes as it should
    assert "removed 1 older checkpoint(s) ['epoch-000002']" in capsys.readouterr().out
    assert [p.name for p in (run / "checkpoints").glob("*epoch-*")] == ["epoch-000004"]


@pytest.mark.slow  # 15 s alone on the shared 2-core box
def test_a_fork_may_add_seeds_that_join_at_the_fork_epoch_and_keep_zoo_keeps_them(
        runs: tuple[Trainer, Trainer], tmp_path: Path) -> None:
    _, half = runs
    (tmp_path / "seed").mkdir()  # a seed from policy files (not the first member's), removed after the fork
    for ext in ("json", "safetensors"):
        shutil.copyfile(half.run_dir / f"policy-spider.{ext}", tmp_path / "seed" / f"spider.{ext}")
    spider_file = tmp_path / "seed" / "spider"
    seeds = ("ant=passive", "bug=passive", f"spider={spider_file}")
    lcfg = dataclasses.replace(half.cfg.league, zoo=seeds, keep_zoo=True)
    cfg = dataclasses.replace(half.cfg, name="seeded", out=str(tmp_path), epochs=16, league=lcfg)
    before = digests(half.run_dir)
    fork_dir = fork_run(half.run_dir, cfg)
    assert digests(half.run_dir) == before
    record = json.loads((fork_dir / "fork.json").read_text())
    pool = json.loads((fork_dir / "league" / "pool.json").read_text())
    seeded = {m["id"]: m for side in pool["pools"].values() for m in side["members"] if m["source"] == "zoo"}
    assert sorted(record["seeded"]) == sorted(seeded) and len(seeded) == 2
    assert {m["side"]: m["epoch"] for m in seeded.values()} == {"team": 8, "spider": 8}
    team_seed = next(m for m in seeded.values() if m["side"] == "team")
    assert team_seed["policies"] == {"ant": "passive", "bug": "passive"}
    spider_seed = next(m for m in seeded.values() if m["side"] == "spider")
    copied = fork_dir / "league" / spider_seed["policies"]["spider"]
    assert file_sha256(copied.with_suffix(".safetensors")) == file_sha256(spider_file.with_suffix(".safetensors"))
    state = json.loads(next((fork_dir / "checkpoints").glob("epoch-*/state.json")).read_text())
    assert state["league"]["pools"] == pool["pools"]  # the checkpoint a resume reads holds the seeds too
    # the pool holds its copy: the seed's own file is not needed again (e.g. another run's member that
    # `triplesumo compact` pruned), so the fork's config still loads and the fork resumes without it
    seed_bytes = file_sha256(spider_file.with_suffix(".safetensors"))
    shutil.rmtree(tmp_path / "seed")
    assert config_from_json(json.loads((fork_dir / "config.json").read_text())) == cfg
    trainer = Trainer(cfg, run_dir=fork_dir, resume=True)  # (resuming seeds nothing again: files unchanged)
    trainer.run()
    assert trainer.seats.league is not None and trainer.collector.epochs_done == 16
    pools = trainer.seats.league.pools
    members = {m.id: m for p in pools.values() for m in p.members}
    assert set(seeded) <= set(members)  # keep_zoo: never evicted, though snapshots were
    assert any(m.epoch > 8 for p in pools.values() for m in (*p.members, *p.evicted))
    assert sum(members[i].games for i in seeded) > 0  # the learners met the seeds
    assert all(len(p.members) - sum(m.source == "zoo" for m in p.members) <= lcfg.max_size for p in pools.values())
    assert "--league.zoo ant=passive bug=passive" in record["command"] and "--league.keep-zoo" in record["command"]
    assert file_sha256(copied.with_suffix(".safetensors")) == seed_bytes


@pytest.mark.slow  # uses the module's runs fixture, 40 s to build
def test_a_seed_whose_policy_file_is_missing_is_refused_before_anything_is_written(
        runs: tuple[Trainer, Trainer], tmp_path: Path) -> None:
    _, half = runs
    missing = tmp_path / "gone" / "spider"
    lcfg = dataclasses.replace(half.cfg.league, zoo=(f"spider={missing}",))  # a config may name it...
    cfg = dataclasses.replace(half.cfg, name="seeded", out=str(tmp_path), league=lcfg)
    with pytest.raises(ValueError, match=r"LeagueConfig.zoo: unknown policy '.*gone/spider'"):
        fork_run(half.run_dir, cfg)  # ...but seeding it needs the file
    assert not (tmp_path / "seeded").exists()
    fresh = dataclasses.replace(cfg, name="fresh")
    with pytest.raises(ValueError, match=r"LeagueConfig.zoo: unknown policy '.*gone/spider'"):
        Trainer(fresh)
    assert not (tmp_path / "fresh").exists()


@pytest.mark.slow  # uses the module's runs fixture, 40 s to build
def test_a_fork_may_only_append_to_the_parents_zoo(runs: tuple[Trainer, Trainer]) -> None:
    _, half = runs
    parent = dataclasses.replace(half.cfg, league=dataclasses.replace(half.cfg.league, zoo=("spider=passive",)))
    fork = dataclasses.replace(parent, name="f")
    assert added_seeds(parent, dataclasses.replace(
        fork, league=dataclasses.replace(parent.league, zoo=("spider=passive", "ant=zero", "bug=zero")))) == (
        "ant=zero", "bug=zero")
    for zoo in ((), ("spider=random",), ("ant=zero", "bug=zero", "spider=passive")):
        with pytest.raises(ValueError, match=r"must start with the parent's \['spider=passive'\]"):
            check_fork(parent, dataclasses.replace(fork, league=dataclasses.replace(parent.league, zoo=zoo)))


@pytest.mark.slow  # 8 s alone on the shared 2-core box
def test_compact_drop_replay_leaves_a_checkpoint_that_resumes_with_an_empty_buffer(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A long run's resume state, committed: ``compact --drop-replay`` deletes the checkpoint's replay buffer and its
    manifest's record of it; a resume then trains on from the checkpoint with an empty buffer (and says so), while a
    checkpoint whose manifest records a buffer that is gone is refused as damaged, naming the file."""
    from conftest import tiny
    from triplesumo.train import checkpoint

    first = train(tiny(tmp_path, "run", epochs=4, checkpoint_every=2, save_replay=True))
    run = first.run_dir
    damaged = tmp_path / "damaged"
    shutil.copytree(run, damaged)
    newest = checkpoint.latest(run)
    assert checkpoint.holds_replay(newest) and (newest / "replay.npz").is_file()
    assert main(["compact", str(run), "--drop-replay"]) == 0
    assert "and the replay buffer; it resumes with an empty replay buffer" in capsys.readouterr().out
    assert not (newest / "replay.npz").exists() and not checkpoint.holds_replay(newest)
    checkpoint.verify(newest, need_replay=True)  # the manifest names only what the folder holds
    assert [p.name for p in (run / "checkpoints").glob("epoch-*")] == [newest.name]
    resumed = train(tiny(tmp_path, "run", epochs=4, save_replay=True), resume_dir=run, overrides={"epochs": 6})
    assert resumed.epochs == 6
    assert "holds no replay buffer" in capsys.readouterr().out
    assert [(leg["kind"], leg.get("replay")) for leg in read_legs(run)] == [("start", None), ("resume", "empty")]
    assert checkpoint.holds_replay(checkpoint.latest(run))  # and saves its new buffer again
    (checkpoint.latest(damaged) / "replay.npz").unlink()
    with pytest.raises(checkpoint.CheckpointError, match=r"replay.npz: file not found"):
        train(tiny(tmp_path, "damaged", epochs=4, save_replay=True), resume_dir=damaged, overrides={"epochs": 6})
