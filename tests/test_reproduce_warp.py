"""``triplesumo reproduce --backend warp``: stage 1's sides and the Bugs train on MuJoCo Warp with the parallel
schedule, while every screen, contest check and test plays on the CPU reference; run end to end on Warp's CPU device
(what one GPU run then measures), and the options Warp cannot take refused by name."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from triplesumo.reproduce import ReproduceConfig
from triplesumo.reproduce.protocol import Protocol
from triplesumo.train.config import TrainConfig, parallel_schedule


def test_warp_options_that_cannot_work_are_refused_naming_them(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"ReproduceConfig.backend must be one of \('cpu', 'warp'\), got 'gpu'"):
        ReproduceConfig(backend="gpu")
    with pytest.raises(ValueError, match="ReproduceConfig.algos: ppo does not train on backend warp"):
        ReproduceConfig(backend="warp", algos=("sac", "ppo"))
    with pytest.raises(ValueError, match="ReproduceConfig.ray with backend warp"):
        ReproduceConfig(backend="warp", algos=("sac",), ray=True)
    with pytest.raises(ValueError, match="ReproduceConfig.device must be cuda or cpu"):
        ReproduceConfig(backend="warp", algos=("sac",), device="tpu")
    with pytest.raises(ValueError, match="ReproduceConfig.warp_envs must be an int >= 1, got 0"):
        ReproduceConfig(backend="warp", algos=("sac",), warp_envs=0)
    with pytest.raises(ValueError, match="ReproduceConfig.warp_warmup must be an int >= 0, got -1"):
        ReproduceConfig(warp_warmup=-1)
    ReproduceConfig(algos=("sac", "ppo"), ray=True)  # (the CPU backend takes both)


def test_parallel_schedule_updates_after_every_step_of_all_the_matches() -> None:
    t = parallel_schedule(TrainConfig(n_envs=512), "sac", 16, 1024, 8)
    assert (t.sac.learn_every, t.sac.gradient_steps, t.sac.batch_size, t.sac.learning_starts) == (512, 16, 1024, 4096)
    assert t.sac.n_step == TrainConfig().sac.n_step and t.td3 == TrainConfig().td3  # the rest is kept
    with pytest.raises(ValueError, match="an off-policy algorithm .* got 'ppo'"):
        parallel_schedule(TrainConfig(), "ppo", 1, 1, 1)


def test_on_warp_the_sides_and_bugs_train_on_the_device_and_every_check_plays_on_the_cpu(tmp_path: Path) -> None:
    cpu = Protocol(ReproduceConfig(out=str(tmp_path / "cpu"), algos=("ddpg", "sac")))
    warp = Protocol(ReproduceConfig(out=str(tmp_path / "warp"), algos=("ddpg", "sac"), backend="warp", warp_envs=1024,
                                    warp_updates=12, warp_batch=2048, warp_warmup=4, warp_eval_workers=3))
    # stage 1: the CPU recipe (one DDPG step per 5 transitions), and its parallel counterpart on the device
    side = cpu.pretrain("ant")
    assert (side.backend, side.n_envs, side.ddpg.learn_every, side.checkpoint_every) == ("cpu", 16, 5, 250)
    side = warp.pretrain("ant")
    assert (side.backend, side.device, side.n_envs, side.checkpoint_every) == ("warp", "cuda", 1024, 10**9)
    assert (side.ddpg.learn_every, side.ddpg.gradient_steps, side.ddpg.batch_size,
            side.ddpg.learning_starts) == (1024, 12, 2048, 4096)
    assert side.epochs == cpu.pretrain("ant").epochs and side.reward == cpu.pretrain("ant").reward
    # the Bugs: the parallel schedule replaces learn_every, the recipe's n-step returns stay; evaluations in the
    # background on the host's workers
    bug = warp.bug_base()
    assert (bug.backend, bug.n_envs, bug.sac.learn_every, bug.sac.gradient_steps) == ("warp", 1024, 1024, 12)
    assert bug.sac.n_step == cpu.bug_base().sac.n_step == 5 and bug.ddpg.learn_every == 1024
    assert bug.eval_background and bug.eval_workers == 3 and bug.eval_every == cpu.bug_base().eval_every
    assert bug.max_env_steps == cpu.bug_base().max_env_steps and bug.epochs == cpu.bug_base().epochs
    assert not cpu.bug_base().eval_background
    # screens, contest and test: on the CPU, in n_envs matches, the same configs as the CPU protocol's
    for p in (cpu, warp):
        assert {c.n_envs for c in p.contest_configs().values()} == {16} and p.evaluation_config().n_envs == 16
    def strip(e: object) -> dict[str, object]:  # (what differs by folder alone)
        return {k: v for k, v in vars(e).items() if k not in ("out", "policy", "policies")}

    assert strip(warp.evaluation_config()) == strip(cpu.evaluation_config())


@pytest.mark.slow  # 285 s at nice 5 beside three training runs on the 2-core box: Warp on its CPU device is slow
def test_tiny_reproduction_on_warps_cpu_device_runs_every_stage_and_records_the_device(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("mujoco_warp", reason='backend warp needs the "gpu" extra (pip install "triplesumo[gpu]")')
    from triplesumo.cli import main

    monkeypatch.chdir(tmp_path)
    out = tmp_path / "rep"
    assert main(["reproduce", "--tiny", "--backend", "warp", "--device", "cpu", "--algos", "sac", "--seeds", "0",
                 "--out", str(out), "--no-progress", "--no-sides-at-once"]) == 0
    record = json.loads((out / "reproduce.json").read_text())
    assert record["runs"][-1]["ran"] == ["ant", "spider", "pair", "contest", "engagement", "bug", "evaluation",
                                         "compare"]
    assert record["config"]["backend"] == "warp" and record["config"]["device"] == "cpu"
    # the machine: Warp's CPU device, no GPU claimed; the device's start-up and rate beside the host's reference
    machine = record["runs"][-1]["machine"]
    assert machine["backend"] == "warp" and machine["device"] == "cpu" and machine["gpu"] is None
    assert machine["reference"]["n_envs"] == 2 and machine["reference"]["ms_per_env_step"] > 0
    dev = machine["device_reference"]
    assert dev["device"] == "cpu" and dev["n_envs"] == 2 and dev["first_step_seconds"] > 0
    # every training ran on Warp (its run folder's config), on the parallel schedule
    for run in (out / "ant", out / "spider", out / "bug" / "learn=bug=sac,seed=0"):
        cfg = json.loads((run / "config.json").read_text())
        assert cfg["backend"] == "warp" and cfg["device"] == "cpu" and cfg["n_envs"] == 2, run
        algo = cfg["learn"][0].split("=")[1]
        assert (cfg[algo]["learn_every"], cfg[algo]["gradient_steps"], cfg[algo]["batch_size"]) == (2, 2, 8), run
    # ... and was screened and tested on the CPU: the screens' rows, the contest's checks, the test's candidates
    screens = json.loads((out / "ant" / "screens.json").read_text())["screens"]
    assert screens and all(s["n"] == 4 for s in screens)
    contest = json.loads((out / "contest" / "contest.json").read_text())
    assert contest["matches"] == 4 and set(contest["counts"]) == {"ant-pushes", "spider-pushes", "match"}
    with open(out / "evaluation" / "per_seed.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert sorted(r["candidate"] for r in rows)[-1] and {int(r["epochs"]) for r in rows} == {4} and len(rows) == 3
    evaluations = (out / "bug" / "learn=bug=sac,seed=0" / "eval.csv").read_text().splitlines()
    assert len(evaluations) >= 2  # the Bug's evaluations while it trained, played in the background
    report = (out / "REPRODUCTION.md").read_text()
    assert "| bug |" in report and "trained on Warp's cpu device (no GPU, " in report
