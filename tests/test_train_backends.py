"""The trainer on the batched API: runs of the trainer before it still resume (and give the same
results), and ``--backend warp`` trains on MuJoCo Warp with everything on the device.

``data/old_trainer_run`` was written by the trainer that drove ``MatchBatch`` match by match
(commit e666681): ``run`` is ``tiny(out, "run", epochs=2, checkpoint_every=2)`` (its checkpoint at
epoch 2, replay included) and ``ref`` holds the metrics, learning CSV and policy of the same config
trained straight to epoch 4 by that trainer.

The Warp runs use Warp's CPU device (CI has no GPU); they skip, saying why, without
``mujoco-warp``. Their first call compiles Warp's kernels (about 30 s, cached in ``~/.cache/warp``).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.numpy import load_file

from conftest import tiny
from triplesumo.agents.builtin import act_batch
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.ppo import PPOConfig
from triplesumo.algos.replay import ReplayBuffer, TorchReplayBuffer
from triplesumo.model.specs import V0_PHYSICS, PhysicsConfig
from triplesumo.rules.outcome import OUTCOME_CODES
from triplesumo.train import checkpoint
from triplesumo.train.config import TrainConfig
from triplesumo.train.league_config import LeagueConfig
from triplesumo.train.loop import Trainer, train

OLD_RUN = Path(__file__).parent / "data" / "old_trainer_run"


def _metrics(path: Path) -> list[dict[str, str]]:
    return [{k: v for k, v in row.items() if k != "wall_time"} for row in csv.DictReader(path.open())]


def _same_run(path: Path, ref: Path) -> bool:
    """The rows of ``path`` are those of the fixture ``ref``: outcomes, epochs and steps exactly, the reward
    columns to a relative 1e-6. The fixture was recorded on another CPU; torch's and MuJoCo's vector kernels
    differ by CPU in the last bits (about 2e-8 relative on an AVX-512 machine), which a resume that lost or
    replayed anything would exceed by orders of magnitude."""
    a, b = _metrics(path), _metrics(ref)
    exact = ("epoch", "outcome", "steps", "env_steps", "local_winning_rate")
    return len(a) == len(b) > 0 and all(
        x.keys() == y.keys() and all(x[k] == y[k] for k in exact)
        and all(float(x[k]) == pytest.approx(float(y[k]), rel=1e-6, abs=1e-6) for k in x if k not in exact)
        for x, y in zip(a, b, strict=True))


def _close_policy(a: Path, ref: Path) -> bool:
    """The weights of ``a`` are the fixture's to 1e-6 (see :func:`_same_run` for why not bit for bit)."""
    x, y = load_file(a), load_file(ref)
    return x.keys() == y.keys() and all(np.allclose(x[k], y[k], rtol=0.0, atol=1e-6) for k in x)


def _same_policy(a: Path, b: Path) -> bool:
    x, y = load_file(a), load_file(b)
    return x.keys() == y.keys() and all(np.array_equal(x[k], y[k]) for k in x)


@pytest.mark.slow  # 10 s alone on the shared 2-core box
def test_a_checkpoint_of_the_previous_trainer_resumes_and_continues_its_run_exactly(tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(OLD_RUN / "run", run)
    result = train(TrainConfig(), resume_dir=run, overrides={"epochs": 4, "out": str(tmp_path)})
    assert result.epochs == 4 and result.env_steps == 120
    # the old trainer's uninterrupted run to epoch 4, row for row and weight for weight (to float rounding)
    assert _same_run(run / "metrics.csv", OLD_RUN / "ref" / "metrics.csv")
    assert _close_policy(run / "policy.safetensors", OLD_RUN / "ref" / "policy.safetensors")
    # and the new trainer, started afresh on that run's ring (env v0's), makes that same run
    fresh = train(dataclasses.replace(tiny(tmp_path, "fresh", epochs=4, checkpoint_every=2), physics=V0_PHYSICS))
    assert _same_run(fresh.run_dir / "metrics.csv", OLD_RUN / "ref" / "metrics.csv")
    assert _close_policy(fresh.run_dir / "policy.safetensors", OLD_RUN / "ref" / "policy.safetensors")


def test_the_torch_replay_buffer_samples_what_the_numpy_one_does() -> None:
    rng = np.random.default_rng(0)
    data = {"obs": rng.normal(size=(7, 3)), "act": rng.normal(size=(7, 2)), "rew": rng.normal(size=7),
            "next_obs": rng.normal(size=(7, 3)), "done": rng.integers(0, 2, 7).astype(float)}
    host, device = ReplayBuffer(5, 3, 2), TorchReplayBuffer(5, 3, 2, "cpu")
    host.add_batch(**data)
    device.add_batch(**{k: torch.as_tensor(v) for k, v in data.items()})
    assert len(device) == len(host) == 5 and device.pos == host.pos == 2
    assert isinstance(device.obs, torch.Tensor) and device.obs.device == torch.device("cpu")
    a, b = host.sample(4, np.random.default_rng(1)), device.sample(4, np.random.default_rng(1))
    assert all(isinstance(b[k], torch.Tensor) and np.array_equal(a[k], b[k].numpy()) for k in a)
    state = device.state_dict()
    assert all(np.array_equal(state[k], v) for k, v in host.state_dict().items())
    again = TorchReplayBuffer(5, 3, 2, "cpu")
    again.load_state_dict(host.state_dict())
    assert np.array_equal(again.sample(4, np.random.default_rng(2))["obs"].numpy(),
                          host.sample(4, np.random.default_rng(2))["obs"])


def test_warp_refuses_what_it_cannot_play_naming_the_option(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="TrainConfig.device='cuda' needs backend='warp'"):
        tiny(tmp_path, device="cuda")
    pytest.importorskip("mujoco_warp", reason='backend warp needs the "gpu" extra (pip install "triplesumo[gpu]")')
    with pytest.raises(ValueError, match=r"TrainConfig.backend='warp' \(scenario 'bodies'.*one body kind"):
        Trainer(tiny(tmp_path, backend="warp", device="cpu", scenario="bodies", learn=("ant=sac",),
                     policies=("*=random",)))
    assert not (tmp_path / "run").exists()  # refused before anything was made


@pytest.fixture(scope="module")
def warp_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Trainer]:
    """A tiny DDPG run (random Spider: host policy) and a tiny PPO run (the zoo's Ant and Spider, acting on
    the device) on Warp's CPU device (3 matches, 20-step epochs, 16-unit networks)."""
    pytest.importorskip("mujoco_warp", reason='backend warp needs the "gpu" extra (pip install "triplesumo[gpu]")')
    out = tmp_path_factory.mktemp("warp-train")
    runs = {}
    for name, fields in (("ddpg", {}), ("ppo", {"learn": ("bug=ppo",), "policies": ("ant=zoo:ant", "spider=zoo:spider"),
                                                 "ppo": PPOConfig(hidden=(16, 16), n_steps=10, n_minibatches=2,
                                                                  n_epochs=2),
                                                 "eval_every": 30, "eval_epochs": 2})):
        cfg = tiny(out, name, backend="warp", device="cpu", n_envs=3, steps_per_epoch=20, epochs=6,
                   checkpoint_every=3, **fields)
        trainer = Trainer(cfg)
        trainer.run()
        runs[name] = trainer
    return runs


@pytest.mark.parametrize("algo", ["ddpg", "ppo"])
@pytest.mark.slow  # 26 s alone on the shared 2-core box
def test_a_warp_run_trains_on_the_device_and_writes_the_usual_run_folder(
        warp_runs: dict[str, Trainer], algo: str) -> None:
    trainer = warp_runs[algo]
    run = trainer.run_dir
    assert isinstance(trainer.collector.obs, torch.Tensor) and trainer.collector.obs.device == torch.device("cpu")
    for name in ("config.json", "metrics.csv", "learning.csv", "policy.json", "policy.safetensors"):
        assert (run / name).is_file(), name
    rows = list(csv.DictReader((run / "metrics.csv").open()))
    assert trainer.collector.epochs_done >= 6 and len(rows) == trainer.collector.epochs_done
    assert [int(r["epoch"]) for r in rows] == list(range(1, len(rows) + 1))
    assert {r["outcome"] for r in rows} <= set(OUTCOME_CODES) - {"error"}
    for r in rows:  # the game's rules: a match lasts at most 20 steps, a draw only at the limit,
        steps = int(r["steps"])  # and the outcome's sparse reward is the configured one
        assert 1 <= steps <= 20 and (r["outcome"] != "draw" or steps == 20)
        expected = {"win": trainer.cfg.reward.win, "loss": trainer.cfg.reward.loss, "draw": trainer.cfg.reward.draw}
        assert float(r["sparse_reward"]) == pytest.approx(expected[r["outcome"]])
        assert float(r["total_reward"]) == pytest.approx(float(r["dense_reward"]) + float(r["sparse_reward"]))
    assert trainer.collector.env_steps == int(rows[-1]["env_steps"]) and trainer.collector.env_steps % 3 == 0
    learner = trainer.learners[0]
    assert trainer.updates() > 0 and learner.algo.device == torch.device("cpu")
    if algo == "ddpg":
        replay = learner.replay  # type: ignore[attr-defined]
        assert isinstance(replay, TorchReplayBuffer) and isinstance(replay.obs, torch.Tensor)
        assert len(replay) == trainer.collector.env_steps  # every Bug step was stored (no physics errors)
    else:
        assert all(v.device == torch.device("cpu") for v in learner.algo.rollout.values())  # type: ignore[attr-defined]
        # evaluations while training: the device policy, copied to the host, on CPU test matches
        evals = list(csv.DictReader((run / "eval.csv").open()))
        assert len(evals) == trainer.collector.env_steps // 30 >= 2
        assert all(int(e["n_win"]) + int(e["n_loss"]) + int(e["n_draw"]) == 2 for e in evals)


@pytest.mark.slow  # 13 s alone on the shared 2-core box
def test_a_killed_warp_run_resumes_exactly(warp_runs: dict[str, Trainer], tmp_path: Path) -> None:
    """Killed after a checkpoint written 10 steps into its second matches (the loop writes one whenever an
    epoch ends, other matches under way) and resumed, a warp run writes the rows, learning rows and policy
    of the uninterrupted one, byte for byte (Warp's CPU device is deterministic)."""
    whole = warp_runs["ddpg"]
    cfg = dataclasses.replace(whole.cfg, out=str(tmp_path))
    killed = Trainer(cfg)
    while killed.collector.env_steps < 30 * cfg.n_envs:
        killed.step()
    killed.save()
    killed.log.close()
    # the matches in progress
    assert killed.collector.env.steps.tolist() == [10, 10, 10] and killed.collector.epochs_done == 3
    result = train(cfg, resume_dir=killed.run_dir)
    assert (result.epochs, result.env_steps, result.updates) == (
        whole.collector.epochs_done, whole.collector.env_steps, whole.updates())
    assert _metrics(killed.run_dir / "metrics.csv") == _metrics(whole.run_dir / "metrics.csv")
    assert _metrics(killed.run_dir / "learning.csv") == _metrics(whole.run_dir / "learning.csv")
    assert _same_policy(killed.run_dir / "policy.safetensors", whole.run_dir / "policy.safetensors")


@pytest.mark.slow  # 40 s on the shared 2-core box (108 s under a load of 14)
def test_a_warp_free_for_all_run_plays_eliminations_and_resumes_exactly(tmp_path: Path) -> None:
    """Issue 54: the trainer plays the elimination scenarios on warp. Started 1.7 m out, agents leave mid-match and
    the learner (Spider) plays on while another is out; killed while an agent is out of a match still under way
    and resumed, the run writes the uninterrupted run's rows, learning rows and policy byte for byte (the
    snapshots carry who is in play)."""
    pytest.importorskip("mujoco_warp", reason='backend warp needs the "gpu" extra (pip install "triplesumo[gpu]")')
    cfg = tiny(tmp_path, "whole", backend="warp", device="cpu", scenario="ffa", learn=("spider=ddpg",),
               policies=("ant=random", "bug=random"), n_envs=3, steps_per_epoch=20, epochs=8, checkpoint_every=4,
               physics=PhysicsConfig(layout="circle", start_radius=1.7))
    whole = Trainer(cfg)
    whole.run()
    rows = list(csv.DictReader((whole.run_dir / "metrics.csv").open()))
    assert len(rows) == whole.collector.epochs_done >= 8
    assert any(int(r["steps"]) < 20 for r in rows)  # epochs ended by ring exits before the step limit
    killed = Trainer(dataclasses.replace(cfg, name="killed"))
    env = killed.collector.env
    while env._alive.all():  # until an agent is out of a match still under way (the v1 circle's Ant, first)
        killed.step()
        assert killed.collector.epochs_done < 6, "no agent left a match within the first epochs"
    killed.save()
    killed.log.close()
    snaps = env.snapshot()
    assert any(not all(s["alive"]) for s in snaps)
    train(dataclasses.replace(cfg, name="killed"), resume_dir=killed.run_dir)
    assert _metrics(killed.run_dir / "metrics.csv") == _metrics(whole.run_dir / "metrics.csv")
    assert _metrics(killed.run_dir / "learning.csv") == _metrics(whole.run_dir / "learning.csv")
    assert _same_policy(killed.run_dir / "policy.safetensors", whole.run_dir / "policy.safetensors")


@pytest.mark.slow  # 7 s alone on the shared 2-core box
def test_a_warp_checkpoint_without_match_states_still_resumes_restarting_its_matches(
        warp_runs: dict[str, Trainer], tmp_path: Path) -> None:
    """Checkpoints written before warp resumed exactly hold no match state: their unfinished matches restart."""
    run = tmp_path / "old"
    shutil.copytree(warp_runs["ppo"].run_dir, run)
    before, folder = checkpoint.checkpoints(run)[-1]
    tensors, state, arrays, _ = checkpoint.load(folder, need_replay=False)
    shutil.rmtree(folder)
    checkpoint.save(run, before, tensors, state | {"matches": []},
                    {k: v for k, v in arrays.items() if not k.startswith("match")}, None)
    result = train(warp_runs["ppo"].cfg, resume_dir=run, overrides={"epochs": before + 3})
    rows = list(csv.DictReader((run / "metrics.csv").open()))
    assert result.epochs >= before + 3 and len(rows) == result.epochs
    assert [int(r["epoch"]) for r in rows] == list(range(1, len(rows) + 1))
    assert all(int(r["steps"]) <= 20 for r in rows)


@pytest.mark.slow  # 8 s alone on the shared 2-core box
def test_bench_train_measures_the_warp_trainer_rows(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("mujoco_warp", reason='backend warp needs the "gpu" extra (pip install "triplesumo[gpu]")')
    from triplesumo.benchmarks.train import main

    path = tmp_path / "b.json"
    assert main(["--backend", "warp", "--device", "cpu", "--quick", "--json", str(path)]) == 0
    result = json.loads(path.read_text())
    printed = capsys.readouterr().out
    assert result["setup"]["backend"] == "warp" and result["setup"]["device"] == "cpu"
    assert set(result["rates"]) == {"env_only", "train_ddpg", "train_ppo"}
    assert all(math.isfinite(r) and r > 0 for r in result["rates"].values())
    assert result["updates_per_s"]["env_only"] == 0 and result["updates_per_s"]["train_ddpg"] > 0
    assert result["updates_per_s"]["train_ppo"] > 0
    assert "not a speed figure" in printed


def test_a_random_policy_draws_a_batch_as_it_draws_row_by_row() -> None:
    from triplesumo.agents.builtin import RandomPolicy

    one, many = RandomPolicy(4, action_size=5), RandomPolicy(4, action_size=5)
    rows = np.stack([one(np.zeros(3)) for _ in range(7)])
    batch = many.sample(7)
    assert batch.dtype == np.float32 and batch.shape == (7, 5) and np.array_equal(batch, rows)
    assert one.rng.bit_generator.state == many.rng.bit_generator.state


def test_a_frozen_policy_on_the_device_acts_as_on_the_host() -> None:
    from triplesumo.agents.frozen import FrozenPolicy

    rng = np.random.default_rng(0)
    policy = FrozenPolicy([rng.normal(size=(16, 6)), rng.normal(size=(4, 16))], [rng.normal(size=16),
                          rng.normal(size=4)], obs_mean=rng.normal(size=6), obs_var=rng.uniform(0.5, 2, 6))
    obs = rng.normal(size=(32, 6)).astype(np.float32)
    on_device = policy.on_device(torch.device("cpu"))(torch.as_tensor(obs))
    assert on_device.dtype == torch.float32 and on_device.shape == (32, 4)
    np.testing.assert_allclose(on_device.numpy(), policy(obs), rtol=0, atol=1e-6)


@pytest.mark.slow  # uses the module's warp_runs fixture, 70 s to build
def test_both_backends_start_the_trainers_matches_from_the_same_seeded_states(
        warp_runs: dict[str, Trainer], tmp_path: Path) -> None:
    cpu = Trainer(tiny(tmp_path, "cpu", n_envs=3))
    warp = Trainer(tiny(tmp_path, "warp", n_envs=3, backend="warp", device="cpu"))
    try:
        assert isinstance(cpu.collector.obs, np.ndarray) and isinstance(warp.collector.obs, torch.Tensor)
        # float32 physics on Warp
        np.testing.assert_allclose(warp.collector.obs.numpy(), cpu.collector.obs, rtol=0, atol=1e-4)
        assert cpu.rng.bit_generator.state == warp.rng.bit_generator.state  # the same seeds were drawn
        for trainer in (cpu, warp):  # a step: the random Spider and the warm-up draw the same numbers on both
            trainer.step()
        assert cpu.rng.bit_generator.state == warp.rng.bit_generator.state
        assert cpu.seats.fixed["spider"].rng.bit_generator.state == warp.seats.fixed["spider"].rng.bit_generator.state
    finally:
        for trainer in (cpu, warp):
            trainer.log.close()
            trainer.collector.env.close()


@pytest.mark.slow  # 30 s alone on the shared 2-core box
def test_both_sides_self_play_on_warp_seats_members_on_the_device_and_resumes_exactly(tmp_path: Path) -> None:
    """``--self-play --backend warp`` (paper scenario, both sides learning, one network per seat): live and pool
    matches, snapshots admitted, the Spider pool's zoo member acting on the device, the team pool's random
    seed member from its own generators; resumed from its epoch-3 checkpoint, the same league,
    seats, rows and policies as the uninterrupted run. 2 matches of 20 steps, started 1.7 m out (ring-outs)."""
    pytest.importorskip("mujoco_warp", reason='backend warp needs the "gpu" extra (pip install "triplesumo[gpu]")')
    ddpg = DDPGConfig(hidden=(16, 16), buffer_size=4000, learning_starts=40, batch_size=8, learn_every=8)
    league = LeagueConfig(threshold=0.0, window=2, snapshot_every=2, max_size=3, live_share=0.5,
                          zoo=("ant=random", "bug=random", "spider=zoo:spider"))

    def both(name: str, epochs: int) -> TrainConfig:
        return TrainConfig(name=name, out=str(tmp_path), epochs=epochs, steps_per_epoch=20, n_envs=2,
                           checkpoint_every=3, seed=3, ddpg=ddpg, progress=False, tensorboard=False, self_play=True,
                           league=league, learn=("ant=ddpg", "bug=ddpg", "spider=ddpg"),
                           physics=PhysicsConfig(layout="circle", start_radius=1.7), backend="warp", device="cpu",
                           allow_other_ring=True)  # (zoo:spider was trained on env v2's ring)

    whole = Trainer(both("whole", 6))
    whole.run()
    lg = whole.seats.league
    assert lg is not None
    members = {m.id: m for pool in lg.pools.values() for m in (*pool.members, *pool.evicted)}
    assert any(m.source == "self" for m in members.values())  # snapshots admitted
    assert members["team-0001"].policies == {"ant": "random", "bug": "random"} and members["team-0001"].games > 0
    assert members["spider-0001"].games > 0  # the zoo's Spider played (a trained network, on the device)
    assert (lg.root / f"{members['spider-0001'].policies['spider']}.safetensors").is_file()
    # the members' actions on the device are the host's: the network within float rounding, random draws alike
    seats = (([None, None, "spider-0001"], 0), (["team-0001", "team-0001", None], 5))
    whole.seats.policies = [whole.seats.policies_of(members, seed) for members, seed in seats]
    whole.seats._groups = None
    twins = [whole.seats.policies_of(members, seed) for members, seed in seats]  # fresh generators, same seeds
    host = [{i: act_batch(p, whole.collector.obs[k, i][None].numpy())[0] for i, p in seated.items()}
            for k, seated in enumerate(twins)]
    actions = torch.zeros((2, 3, 8))
    whole.seats.act_on_device(actions, whole.collector.obs)
    for k, seat, action in ((0, 2, host[0][2]), (1, 0, host[1][0]), (1, 1, host[1][1])):
        np.testing.assert_allclose(actions[k, seat].numpy(), action, rtol=0, atol=1e-6)
    assert not actions[0, :2].any() and not actions[1, 2].any()
    run = whole.run_dir
    team, spider = (list(csv.DictReader((run / f"metrics-{a}.csv").open())) for a in ("ant", "spider"))
    assert 0 < len(team) < 6 or 0 < len(spider) < 6  # a learner sat a pool match out: no row for it
    killed = tmp_path / "killed"  # the run again from its epoch-3 checkpoint (--from; the later files overwritten)
    shutil.copytree(run, killed)
    resumed = train(whole.cfg, resume_dir=killed, from_checkpoint="epoch-000003")
    assert (resumed.epochs, resumed.env_steps) == (whole.collector.epochs_done, whole.collector.env_steps)
    assert (run / "league" / "league.csv").read_text() == (killed / "league" / "league.csv").read_text()
    for name in ("metrics-ant.csv", "metrics-spider.csv", "learning-ant.csv", "learning-bug.csv",
                 "learning-spider.csv"):
        assert _metrics(run / name) == _metrics(killed / name), name
    for learner in ("ant", "bug", "spider"):
        assert _same_policy(run / f"policy-{learner}.safetensors", killed / f"policy-{learner}.safetensors")
