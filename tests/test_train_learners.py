"""Several learners in one run: tiny runs of two algorithms at once, PPO, a shared team network,
elimination, exact resume, and the errors of bad ``--learn`` input.

Every run is 2 matches of 30 steps with 16-unit networks (a second or a few each).
"""

from __future__ import annotations

import csv
import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from triplesumo.agents.policy_file import load_policy
from triplesumo.algos.ppo import PPOConfig
from triplesumo.algos.sac import SACConfig
from triplesumo.algos.td3 import TD3Config
from triplesumo.cli import main
from triplesumo.train import checkpoint
from triplesumo.train.config import TrainConfig
from triplesumo.train.learners import OffPolicyLearner, PPOLearner
from triplesumo.train.logger import COLUMNS, LEARNING_COLUMNS
from triplesumo.train.loop import DivergenceError, Trainer, TrainResult, train

E = 2
SAC = SACConfig(hidden=(16, 16), buffer_size=2000, learning_starts=40, batch_size=16, learn_every=2)
TD3 = TD3Config(hidden=(16, 16), buffer_size=2000, learning_starts=40, batch_size=16, learn_every=2)
PPO = PPOConfig(hidden=(16, 16), n_steps=16, n_epochs=2, n_minibatches=2)
"""A rollout of 16 steps: the checkpoint after 30 steps holds one half-collected."""


def tiny(out: Path, name: str, **fields: Any) -> TrainConfig:
    values: dict[str, Any] = {
        "name": name, "out": str(out), "epochs": 2 * E, "steps_per_epoch": 30, "n_envs": 2,
        "checkpoint_every": E, "seed": 3, "sac": SAC, "td3": TD3, "ppo": PPO, "progress": False,
        "tensorboard": False,
    }
    return TrainConfig(**(values | fields))


PAIR = {"learn": ("ant=sac", "bug=td3"), "policies": ("spider=zoo:spider",)}
PPO_RUN = {"learn": ("bug=ppo",), "policies": ("ant=zoo:ant", "spider=random")}


def rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def same_tensors(a: Path, b: Path) -> None:
    x, y = load_file(str(a)), load_file(str(b))
    assert x.keys() == y.keys()
    for key in x:
        assert torch.equal(x[key], y[key]), f"{b}: {key} differs"


def same_arrays(a: Path, b: Path) -> None:
    with np.load(a) as x, np.load(b) as y:
        assert sorted(x.files) == sorted(y.files)
        for key in x.files:
            assert np.array_equal(x[key], y[key]), f"{b}: {key} differs"


@dataclass
class Run:
    trainer: Trainer
    result: TrainResult
    initial: dict[str, dict[str, torch.Tensor]]
    frozen: dict[str, dict[str, torch.Tensor]]


def run(cfg: TrainConfig) -> Run:
    trainer = Trainer(cfg)
    initial = {lr.name: lr.algo.state_dict() for lr in trainer.learners}
    frozen = {a: {k: v.clone() for k, v in p.actor.state_dict().items()}
              for a, p in trainer.seats.fixed.items() if hasattr(p, "actor")}
    return Run(trainer, trainer.run(), initial, frozen)


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> Run:
    """Ant learns with SAC, Bug with TD3, Spider plays the zoo's policy."""
    return run(tiny(tmp_path_factory.mktemp("pair"), "pair", **PAIR))


@pytest.mark.slow  # 12 s alone on the shared 2-core box
def test_two_algorithms_learn_at_once(pair: Run) -> None:
    trainer, folder = pair.trainer, pair.result.run_dir
    assert [(lr.name, lr.spec.algo) for lr in trainer.learners] == [("ant", "sac"), ("bug", "td3")]
    assert pair.result.updates == sum(lr.algo.num_updates for lr in trainer.learners)
    for learner in trainer.learners:
        assert learner.algo.num_updates > 0, learner.name
        assert learner.last_stats and all(math.isfinite(v) for v in learner.last_stats.values())
        now = learner.algo.state_dict()
        moved = [k for k in now if k.startswith("actor.") and not torch.equal(now[k], pair.initial[learner.name][k])]
        assert moved, f"{learner.name}'s actor never changed"
        table = rows(folder / f"learning-{learner.name}.csv")
        assert [int(r["epoch"]) for r in table] == list(range(1, pair.result.epochs + 1))
        assert int(table[-1]["updates"]) == learner.algo.num_updates
        losses = [float(r["critic_loss"]) for r in table if r["critic_loss"]]
        assert losses and all(math.isfinite(x) for x in losses)
    assert "alpha" in trainer.learners[0].last_stats  # SAC reports its temperature
    spider = trainer.seats.fixed["spider"]
    for key, value in spider.actor.state_dict().items():
        assert torch.equal(value, pair.frozen["spider"][key]), f"the fixed Spider's {key} changed"


@pytest.mark.slow  # uses the module's pair fixture, 17 s to build
def test_each_learning_agent_has_its_metrics_and_each_learner_its_policy_file(pair: Run) -> None:
    folder = pair.result.run_dir
    assert not (folder / "metrics.csv").exists() and not (folder / "policy.json").exists()
    for learner in pair.trainer.learners:
        table = rows(folder / f"metrics-{learner.name}.csv")
        assert tuple(table[0]) == COLUMNS and len(table) == pair.result.epochs
        policy, manifest = load_policy(folder / f"policy-{learner.name}", expect_obs_mode="paper")
        assert manifest["agent"] == learner.name and manifest["algo"] == learner.spec.algo
        assert manifest["learners"] == {"ant": "sac", "bug": "td3"} and manifest["epochs"] == pair.result.epochs
        obs = np.random.default_rng(0).normal(size=(4, learner.obs_dim)).astype(np.float32)
        assert np.array_equal(policy(obs), learner.algo.act(obs))  # the final deterministic policy
    assert (folder / "plots" / "ant" / "mwr.png").is_file() and (folder / "plots" / "bug" / "mwr.png").is_file()
    assert tuple(rows(folder / "learning-ant.csv")[0]) == LEARNING_COLUMNS


def _assert_same_run(a: Path, b: Path, learners: list[str], replay: bool) -> None:
    several = len(learners) > 1
    for name in learners:
        stem = f"policy-{name}" if several else "policy"
        same_tensors(a / f"{stem}.safetensors", b / f"{stem}.safetensors")
        for table in ("metrics", "learning"):
            file = f"{table}-{name}.csv" if several else f"{table}.csv"
            strip = [{k: v for k, v in r.items() if k != "wall_time"} for r in rows(a / file)]
            assert strip == [{k: v for k, v in r.items() if k != "wall_time"} for r in rows(b / file)], file
    last_a, last_b = checkpoint.latest(a), checkpoint.latest(b)
    assert last_a.name == last_b.name
    same_tensors(last_a / "weights.safetensors", last_b / "weights.safetensors")
    same_arrays(last_a / "arrays.npz", last_b / "arrays.npz")
    if replay:
        same_arrays(last_a / "replay.npz", last_b / "replay.npz")


@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_resume_of_an_off_policy_pair_equals_uninterrupted(pair: Run, tmp_path: Path) -> None:
    killed = train(tiny(tmp_path, "pair", **PAIR | {"epochs": E})).run_dir
    result = train(TrainConfig(), resume_dir=killed, overrides={"epochs": 2 * E})
    assert (result.epochs, result.env_steps, result.updates) == (
        pair.result.epochs, pair.result.env_steps, pair.result.updates)
    _assert_same_run(pair.result.run_dir, killed, ["ant", "bug"], replay=True)


@pytest.mark.slow  # 4 s alone on the shared 2-core box
def test_ppo_learns_and_resumes_mid_rollout_exactly(tmp_path: Path) -> None:
    whole = run(tiny(tmp_path / "a", "ppo", **PPO_RUN))
    bug = whole.trainer.learners[0]
    assert isinstance(bug, PPOLearner)
    assert bug.algo.num_updates == whole.result.env_steps // (PPO.n_steps * 2)  # one update per full (T, 2) rollout
    assert {"actor_loss", "critic_loss", "entropy", "approx_kl", "clip_fraction"} <= set(bug.last_stats)
    assert all(math.isfinite(v) for v in bug.last_stats.values())
    now = bug.algo.state_dict()
    assert not torch.equal(now["actor.net.0.weight"], whole.initial["bug"]["actor.net.0.weight"])
    ant = whole.trainer.seats.fixed["ant"]
    assert all(torch.equal(v, whole.frozen["ant"][k]) for k, v in ant.actor.state_dict().items())
    assert load_policy(whole.result.run_dir / "policy")[1]["algo"] == "ppo"

    killed = train(tiny(tmp_path / "b", "ppo", **PPO_RUN | {"epochs": E})).run_dir
    with np.load(checkpoint.latest(killed) / "arrays.npz") as arrays:
        assert 0 < int(arrays["bug.rollout.step"]) < PPO.n_steps  # saved in the middle of a rollout
    assert not (checkpoint.latest(killed) / "replay.npz").exists()  # PPO keeps no replay buffer
    train(TrainConfig(), resume_dir=killed, overrides={"epochs": 2 * E})
    _assert_same_run(whole.result.run_dir, killed, ["bug"], replay=False)


def test_share_team_trains_one_network_for_both_team_mates(tmp_path: Path) -> None:
    shared = run(tiny(tmp_path, "team", learn=("ant=ppo", "bug=ppo"), share="team", policies=("spider=random",),
                      obs_mode="egocentric"))
    (learner,) = shared.trainer.learners
    assert learner.name == "ant+bug" and learner.n_rows == 2 * 2  # both team mates in both matches
    assert learner.algo.num_updates == shared.result.env_steps // (PPO.n_steps * 2)
    folder = shared.result.run_dir
    _, manifest = load_policy(folder / "policy-ant+bug")
    assert manifest["plays"] == ["ant", "bug"] and manifest["algo"] == "ppo"
    assert len(rows(folder / "metrics-ant.csv")) == len(rows(folder / "metrics-bug.csv")) == shared.result.epochs


def test_a_learner_out_of_an_elimination_match_stops_collecting_until_the_match_ends(tmp_path: Path) -> None:
    cfg = tiny(tmp_path, "ffa", scenario="ffa", learn=("ant=sac", "bug=ppo"), policies=("*=random",), epochs=5,
               steps_per_epoch=50, sac=SACConfig(hidden=(8, 8), buffer_size=200, learning_starts=1000,
                                                 n_step=1))  # one-step: each step's transitions reach the replay
    trainer = Trainer(cfg)
    ant, bug = trainer.learners
    assert isinstance(ant, OffPolicyLearner) and isinstance(bug, PPOLearner)

    def push_out(agent: str) -> None:
        match = trainer.collector.batch.matches[0]
        body = match.sim.agents[match.agents.index(agent)]
        match.data.qpos[body.root_qpos] = 2.6
        mujoco.mj_forward(match.model, match.data)
        trainer.collector.batch.reload(0)

    push_out("ant")
    trainer.step()
    assert trainer.collector.epochs_done == 0 and ant.active.tolist() == [False, True]
    assert ant.replay.done[:2].tolist() == [1.0, 0.0]  # ant's exit is terminal
    trainer.step()
    assert len(ant.replay) == 3  # only the ant still in match 1 collected
    assert bug.algo.rollout["valid"][:2].tolist() == [[1.0, 1.0], [1.0, 1.0]]
    push_out("bug")
    trainer.step()
    assert trainer.collector.epochs_done == 1  # every learning agent of match 0 is out: the epoch ends
    assert ant.active.tolist() == [True, True] and trainer.collector.batch.matches[0].steps == 0
    trainer.log.close()
    for agent in ("ant", "bug"):
        (row,) = rows(trainer.run_dir / f"metrics-{agent}.csv")
        assert row["outcome"] in ("loss", "win", "draw") and int(row["steps"]) <= 3


def test_a_diverging_learner_among_several_is_named(tmp_path: Path) -> None:
    trainer = Trainer(tiny(tmp_path, "nan", epochs=8, **PAIR))
    ant = trainer.learners[0]
    for group in ant.algo.critic_optimizer.param_groups:  # type: ignore[attr-defined]
        group["lr"] = 1e30
    with pytest.raises(DivergenceError, match=r"learner 'ant' diverged at update \d+ .*sac\): .*--sac.actor-lr"):
        trainer.run()


# ------------------------------------------------------------------- bad input


@pytest.mark.parametrize(("fields", "named"), [
    ({"learn": ("ant=dqn",)}, r"TrainConfig.learn.*ddpg.*'ant=dqn'"),
    ({"learn": ("ant",)}, r"TrainConfig.learn.*AGENT=ALGO"),
    ({"learn": ("ant=sac", "ant=td3")}, r"TrainConfig.learn names an agent twice: \['ant'\]"),
    ({"learn": ("ant=sac", "bug=sac"), "policies": ("bug=zoo:bug",)}, r"TrainConfig.policies.*learner 'bug'"),
    ({"share": "everyone"}, r"TrainConfig.share"),
])
def test_bad_learn_input_names_the_field(tmp_path: Path, fields: dict[str, Any], named: str) -> None:
    with pytest.raises(ValueError, match=named):
        tiny(tmp_path, "bad", **fields)


def test_default_policies_leave_out_the_learning_agents() -> None:
    assert TrainConfig(learn=("ant=sac", "bug=sac")).policies == ("spider=zoo:spider",)
    assert TrainConfig(learn=("spider=ppo",)).policies == ("ant=zoo:ant",)
    assert TrainConfig().policies == ("ant=zoo:ant", "spider=zoo:spider")


@pytest.mark.parametrize(("fields", "named"), [
    ({"learn": ("ant=sac", "dragon=ppo")}, r"TrainConfig.learn names unknown agents \['dragon'\]"),
    ({"learn": ("ant=sac", "bug=td3"), "share": "team"}, r"team .* different algorithms \(ant=sac, bug=td3\)"),
    ({"learn": ("ant=sac", "bug=sac"), "share": "team"},  # paper observations: the same vector in both seats
     r"share=team \(team 'team'\): one network for seats \['ant', 'bug'\].*use obs_mode 'egocentric'"),
])
def test_trainer_rejects_bad_learners(tmp_path: Path, fields: dict[str, Any], named: str) -> None:
    with pytest.raises(ValueError, match=named):
        Trainer(tiny(tmp_path, "bad", policies=("spider=random",), **fields))
    assert not (tmp_path / "bad").exists()


@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_cli_learn_trains_two_learners_and_plots_each(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["train", "--out", str(tmp_path), "--name", "cli", "--epochs", "2", "--learn", "ant=sac", "bug=ppo",
            "--policies", "spider=random", "--sac.hidden", "8", "8", "--sac.learning-starts", "20",
            "--sac.batch-size", "8", "--sac.buffer-size", "500", "--ppo.hidden", "8", "8", "--ppo.n-steps", "8",
            "--ppo.n-minibatches", "2", "--ppo.n-epochs", "1", "--n-envs", "2", "--steps-per-epoch", "20",
            "--no-progress", "--no-tensorboard"]
    assert main(args) == 0
    assert "MWR ant" in capsys.readouterr().out
    saved = json.loads((tmp_path / "cli" / "config.json").read_text())
    assert saved["learn"] == ["ant=sac", "bug=ppo"] and saved["ppo"]["n_steps"] == 8
    assert main(["plot", str(tmp_path / "cli"), "--window", "2"]) == 0
    out = capsys.readouterr().out
    assert str(tmp_path / "cli" / "plots" / "ant" / "mwr.png") in out and "plots/bug/mwr.png" in out
    assert main(["train", "--out", str(tmp_path), "--name", "bad", "--learn", "ant=dqn", "--no-progress"]) == 2
    assert "TrainConfig.learn" in capsys.readouterr().err


@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_learner_config_gives_one_learner_its_own_values(tmp_path: Path) -> None:
    """``--learner-config bug.learn_every=1 bug.hidden="8 8"``: the Bug's TD3 learns on every step with
    8-unit networks while the Ant's TD3 keeps the shared --td3.* values (every 2nd step, 16 units)."""
    cfg = tiny(tmp_path, "own", learn=("ant=td3", "bug=td3"), policies=("spider=random",),
               learner_config=("bug.learn_every=1", "bug.hidden=8 8"))
    assert cfg.algo_config("bug") == TD3.__class__(**{**TD3.__dict__, "learn_every": 1, "hidden": (8, 8)})
    assert cfg.algo_config("ant") == TD3
    trainer = Trainer(cfg)
    trainer.run()
    ant, bug = trainer.learners
    assert (ant.config.learn_every, ant.config.hidden) == (2, (16, 16))
    assert (bug.config.learn_every, bug.config.hidden) == (1, (8, 8))
    assert ant.collected == bug.collected  # the same steps collected, twice the updates
    assert bug.algo.num_updates == 2 * ant.algo.num_updates > 0
    shapes = {name: {k: tuple(v.shape) for k, v in load_file(str(tmp_path / "own" / f"policy-{name}.safetensors"))
                     .items()} for name in ("ant", "bug")}
    assert 16 in shapes["ant"]["actor.net.0.weight"] and 8 in shapes["bug"]["actor.net.0.weight"]
    saved = json.loads((tmp_path / "own" / "config.json").read_text())
    assert saved["learner_config"] == ["bug.learn_every=1", "bug.hidden=8 8"]


def test_a_schedule_that_would_mostly_update_is_warned_about_naming_the_gpu_setting(tmp_path: Path) -> None:
    """``learn_every`` counts transitions: 40 matches updating every transition, 2 gradient steps each, make
    80 updates per step of all the matches; 40 matches at learn_every 40 make 2 (docs/gpu.md, "GPU training")."""
    heavy = tiny(tmp_path, "heavy", n_envs=40, learn=("bug=td3", "ant=ppo"), policies=("spider=random",),
                 learner_config=("bug.learn_every=1", "bug.gradient_steps=2"))
    with pytest.warns(UserWarning, match=r"learner bug: td3.learn_every=1 and gradient_steps=2 with 40 "
                                         r"transitions per step of the 40 matches make 80 gradient steps per step"
                                         r".*set learn_every to 40 and gradient_steps to G"):
        Trainer(heavy)
    light = tiny(tmp_path, "light", n_envs=40, learn=("bug=td3", "ant=ppo"), policies=("spider=random",),
                 learner_config=("bug.learn_every=40", "bug.gradient_steps=2"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        Trainer(light)


@pytest.mark.parametrize(("entries", "named"), [
    (("bug.learn_every",), r"learner_config 'bug.learn_every': expected LEARNER.FIELD=VALUE"),
    (("learn_every=1",), r"expected LEARNER.FIELD=VALUE"),
    (("spider.learn_every=1",), r"'spider' is not a learner; the learning agents are \['ant', 'bug'\]"),
    (("bug.nope=1",), r"TD3Config \(the td3 config\) has no field 'nope' \(its fields: .*learn_every"),
    (("bug.TUNABLE=x",), r"TD3Config \(the td3 config\) has no field 'TUNABLE'"),  # a class variable
    (("bug.learn_every=x",), r"'bug.learn_every=x': 'x' is not a int"),
    (("bug.learn_every=0",), r"learner_config \(learner bug\): .*learn_every"),
    (("bug.learn_every=1", "bug.learn_every=2"), r"bug.learn_every given twice"),
    (("ant+bug.learn_every=1",), r"'ant\+bug' names a team's shared learner, which needs share=team"),
])
def test_bad_learner_config_names_the_entry(tmp_path: Path, entries: tuple[str, ...], named: str) -> None:
    with pytest.raises(ValueError, match=named):
        tiny(tmp_path, "bad", learn=("ant=td3", "bug=td3"), policies=("spider=random",), learner_config=entries)


def test_learner_config_names_a_shared_team_learner_by_its_name(tmp_path: Path) -> None:
    """With share=team the Ant and Bug are one learner, ``ant+bug``: its name takes values, a member's
    name is refused before anything is made."""
    fields = {"learn": ("ant=td3", "bug=td3"), "share": "team", "obs_mode": "egocentric",
              "policies": ("spider=random",)}
    cfg = tiny(tmp_path, "team", learner_config=("ant+bug.learn_every=1",), **fields)
    trainer = Trainer(cfg)
    assert [(lr.name, lr.config.learn_every) for lr in trainer.learners] == [("ant+bug", 1)]
    with pytest.raises(ValueError, match=r"learner_config names \['ant'\], not learners of this run; "
                                         r"its learners are \['ant\+bug'\]"):
        Trainer(tiny(tmp_path, "member", learner_config=("ant.learn_every=1",), **fields))
    assert not (tmp_path / "member").exists()


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_cli_learner_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = ["train", "--out", str(tmp_path), "--epochs", "2", "--learn", "ant=ddpg", "bug=ddpg",
            "--policies", "spider=random", "--ddpg.hidden", "8", "8", "--ddpg.learning-starts", "20",
            "--ddpg.batch-size", "8", "--ddpg.buffer-size", "500", "--n-envs", "2", "--steps-per-epoch", "20",
            "--no-progress", "--no-tensorboard"]
    assert main([*base, "--name", "cli", "--learner-config", "spider=1"]) == 2
    assert "TrainConfig.learner_config 'spider=1': expected LEARNER.FIELD=VALUE" in capsys.readouterr().err
    assert main([*base, "--name", "cli", "--learner-config", "ant.learn_every=1", "ant.noise=gaussian"]) == 0
    saved = json.loads((tmp_path / "cli" / "config.json").read_text())
    assert saved["learner_config"] == ["ant.learn_every=1", "ant.noise=gaussian"]
    ant, bug = (load_policy(tmp_path / "cli" / f"policy-{n}")[1] for n in ("ant", "bug"))
    assert ant["updates"] > bug["updates"] > 0  # every step against every 30th (--ddpg.learn-every)
    assert "--learner-config ant.learn_every=1 ant.noise=gaussian" in ant["command"]


def test_a_checkpoint_keeps_who_is_still_in_play(tmp_path: Path) -> None:
    """Under elimination rules a checkpoint taken mid-match holds who left, their places and
    outcomes: the resumed match plays on with the same agents, not with the eliminated one back."""
    cfg = tiny(tmp_path, "ffa", scenario="ffa", learn=("ant=sac", "bug=sac"), policies=("*=random",),
               steps_per_epoch=50, sac=SACConfig(hidden=(8, 8), buffer_size=200, learning_starts=1000))
    trainer = Trainer(cfg)
    match = trainer.collector.batch.matches[0]
    spider = match.sim.agents[match.agents.index("spider")]
    match.data.qpos[spider.root_qpos] = 2.6  # the non-learning spider leaves; ant and bug play on
    mujoco.mj_forward(match.model, match.data)
    trainer.collector.batch.reload(0)
    trainer.step()
    assert match.alive == [True, True, False] and trainer.collector.epochs_done == 0
    before = match.snapshot()
    folder = trainer.save()
    trainer.log.close()
    resumed = Trainer(TrainConfig(**{**cfg.__dict__}), run_dir=trainer.run_dir, resume=True)
    again = resumed.collector.batch.matches[0]
    assert again.alive == [True, True, False]
    after = again.snapshot()
    assert (after["places"], after["outcomes"], after["steps"]) == (before["places"], before["outcomes"],
                                                                   before["steps"])
    assert folder.exists()
    resumed.log.close()
