"""``triplesumo bench skill-gpu``: the time to skill on MuJoCo Warp, run end to end on Warp's CPU device on a
tiny budget (what one short GPU run then measures), its record's fields, the crossing and goal rules on crafted
curves, and the options the bench sets itself."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from triplesumo.benchmarks.skill_gpu import (
    SkillGpuConfig,
    first_crossing,
    format_skill_gpu,
    level_key,
    summarize,
)
from triplesumo.train.config import TrainConfig


def _number_or_none(value: Any) -> bool:
    return value is None or (isinstance(value, int | float) and not isinstance(value, bool))


@pytest.mark.slow  # about a minute: Warp's CPU device launches every kernel serially
def test_quick_runs_end_to_end_on_warps_cpu_device_and_records_the_times_to_each_threshold(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("mujoco_warp", reason='backend warp needs the "gpu" extra (pip install "triplesumo[gpu]")')
    from triplesumo.cli import main

    out, copy = tmp_path / "skill-gpu", tmp_path / "copy.json"
    main(["bench", "skill-gpu", "--quick", "--out", str(out), "--json", str(copy)])
    printed = capsys.readouterr().out
    result = json.loads((out / "skill_gpu.json").read_text())
    assert json.loads(copy.read_text()) == result and (out / "skill_gpu.png").stat().st_size > 0

    # where it ran: Warp's CPU device, named as such, with no GPU figure claimed
    m = result["machine"]
    assert m["backend"] == "warp" and m["device"] == "cpu" and m["warp_device"] == "cpu" and m["gpu"] is None
    assert m["host_reference"]["before"]["ms_per_env_step"] > 0 and m["host_reference"]["after"]["n_envs"] == 16
    d = result["device"]
    assert d["device"] == "cpu" and d["n_envs"] == 4 and d["first_step_seconds"] > 0 and d["env_steps_per_s"] > 0
    assert "Warp's cpu device (not a GPU figure)" in printed and "goal: +0.20 within 60 s" in printed

    # the times to each threshold: numbers where reached, None where not, one entry per threshold and seed
    assert result["thresholds"] == [0.2, 0.4] and result["goal_seconds"] == 60.0 and result["seeds"] == [0]
    (run,) = result["runs"]
    assert set(run["to"]) == {"+0.20", "+0.40"}
    for at in run["to"].values():
        assert set(at) == {"reached", "env_steps", "seconds", "wall_seconds"}
        assert all(_number_or_none(at[k]) for k in ("env_steps", "seconds", "wall_seconds"))
        assert (at["env_steps"] is not None) == (at["seconds"] is not None) == at["reached"]
    ev = run["evaluations"]
    assert len(ev) >= 3 and all(e["n_win"] + e["n_loss"] + e["n_draw"] == 2 for e in ev)  # every 40 of 120 steps
    assert [e["env_steps"] // 40 for e in ev] == list(range(1, len(ev) + 1))
    assert all(e["policy_train_seconds"] <= e["train_seconds"] for e in ev)  # in the background: written later
    assert run["status"] in ("reached", "env-step budget spent") and run["env_steps"] >= 120
    for key in ("+0.20", "+0.40"):
        s = result["summary"][key]
        assert s["seeds"] == 1 and s["reached"] == int(run["to"][key]["reached"])
        assert all(_number_or_none(v) for what in ("env_steps", "seconds") for v in s[what].values())
    assert isinstance(result["goal"]["met"], bool) and _number_or_none(result["goal"]["median_seconds"])

    # the project's own training run on backend warp, with the massively parallel schedule
    config = json.loads((out / "sac" / "seed0" / "config.json").read_text())
    assert config["backend"] == "warp" and config["device"] == "cpu" and config["learn"] == ["bug=sac"]
    assert config["n_envs"] == 4 and config["eval_background"] and config["eval_target"] == 0.4
    sac = config["sac"]
    assert (sac["learn_every"], sac["gradient_steps"], sac["batch_size"], sac["learning_starts"]) == (4, 2, 16, 8)
    assert result["schedule"] == {"learn_every": 4, "gradient_steps": 2, "batch_size": 16, "learning_starts": 8}
    assert result["command"].startswith("triplesumo bench skill-gpu") and "--quick" in result["command"]


def _result(curves: list[list[tuple[int, float, float]]], goal: float = 60.0) -> dict[str, Any]:
    """A crafted record: per seed, evaluations as (env steps, test MWR, training seconds when frozen)."""
    runs = []
    for seed, curve in enumerate(curves):
        ev = [{"env_steps": n, "test_mwr": mwr, "policy_train_seconds": s, "train_seconds": s + 5.0,
               "eval_seconds": 0.0, "wall_seconds": s + 5.0, "n_win": 0, "n_loss": 0, "n_draw": 0}
              for n, mwr, s in curve]
        best = max(ev, key=lambda e: e["test_mwr"])
        to = {level_key(x): first_crossing(ev, x) for x in (0.2, 0.4)}
        status = "reached" if to["+0.40"]["reached"] else "time budget spent"
        runs.append({"seed": seed, "run_dir": "", "status": status, "to": to, "env_steps": curve[-1][0], "updates": 0,
                     "run_seconds": curve[-1][2],
                     "call_seconds": 0.0, "best_test_mwr": best["test_mwr"], "best_at_env_steps": best["env_steps"],
                     "evaluations": ev})
    machine = {"cpu": "X", "cores": 16, "backend": "warp", "device": "cuda", "gpu": "NVIDIA H200", "n_threads": 8,
               "torch_threads": 1, "warp_device": "cuda",
               "host_reference": {"before": {"ms_per_env_step": 0.5}}}
    return summarize({"algo": "sac", "thresholds": [0.2, 0.4], "goal_seconds": goal, "n_envs": 4096,
                      "schedule": {"learn_every": 4096, "gradient_steps": 16, "batch_size": 4096,
                                   "learning_starts": 32768},
                      "eval_every": 400_000, "eval_epochs": 200, "eval_background": True,
                      "max_env_steps": 20_000_000, "max_seconds": 240.0, "machine": machine,
                      "device": {"device": "cuda:0", "first_step_seconds": 30.0, "env_steps_per_s": 100_000.0},
                      "runs": runs})


def test_the_first_crossing_of_each_threshold_and_the_goal_over_seeds() -> None:
    result = _result([[(250_000, -0.3, 6.0), (500_000, 0.25, 12.0), (750_000, 0.1, 18.0), (1_000_000, 0.45, 24.0)],
                      [(250_000, 0.21, 7.0), (500_000, 0.3, 13.0)],
                      [(250_000, 0.0, 6.0), (500_000, 0.1, 70.0), (750_000, 0.2, 90.0)]])
    first, second, third = (r["to"] for r in result["runs"])
    assert first["+0.20"] == {"reached": True, "env_steps": 500_000, "seconds": 12.0, "wall_seconds": 17.0}
    assert first["+0.40"]["env_steps"] == 1_000_000 and first["+0.40"]["seconds"] == 24.0
    assert second["+0.40"] == {"reached": False, "env_steps": None, "seconds": None, "wall_seconds": None}
    assert third["+0.20"]["seconds"] == 90.0  # >= the threshold counts
    s = result["summary"]
    assert s["+0.20"]["reached"] == 3 and s["+0.20"]["seconds"] == {"median": 12.0, "min": 7.0, "max": 90.0}
    # two seeds of three never reached +0.4: its median and max are unknown (beyond the budget)
    assert s["+0.40"]["reached"] == 1 and s["+0.40"]["env_steps"] == {"median": None, "min": 1_000_000, "max": None}
    assert result["goal"] == {"threshold": 0.2, "seconds": 60.0, "median_seconds": 12.0, "met": True}
    table = format_skill_gpu(result)
    assert "NVIDIA H200" in table and "goal: +0.20 within 60 s of training: met (median 12.0 s)" in table
    assert "+0.40: 1 of 3 seeds" in table and "not reached" in table

    missed = _result([[(250_000, 0.3, 61.0)]])
    assert missed["goal"]["met"] is False and missed["goal"]["median_seconds"] == 61.0
    never = _result([[(250_000, 0.1, 10.0)]])
    assert never["goal"] == {"threshold": 0.2, "seconds": 60.0, "median_seconds": None, "met": False}


@pytest.mark.parametrize(("kw", "message"), [
    ({"algo": "ppo"}, "SkillGpuConfig.algo must be an off-policy learner"),
    ({"thresholds": (0.4, 0.2)}, "SkillGpuConfig.thresholds must be test MWRs in"),
    ({"thresholds": (0.2, 1.5)}, "SkillGpuConfig.thresholds"),
    ({"device": "tpu"}, "SkillGpuConfig.device must be cuda or cpu"),
    ({"n_envs": 0}, "SkillGpuConfig.n_envs must be an int >= 1"),
    ({"max_seconds": -1.0}, "SkillGpuConfig.max_seconds must be"),
    ({"eval_every": 1000, "max_env_steps": 10}, "SkillGpuConfig.max_env_steps"),
    ({"train": TrainConfig(backend="warp", eval_background=True, progress=False, tensorboard=False,
                           checkpoint_every=10**9, save_replay=False, n_envs=64)},
     "SkillGpuConfig.train.n_envs is set by the bench"),
])
def test_bad_options_name_the_field(kw: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message.replace(".", r"\.")):
        SkillGpuConfig(**kw)


def test_a_runs_config_is_the_warp_run_with_the_massively_parallel_schedule() -> None:
    cfg = SkillGpuConfig(n_envs=1024, updates_per_step=8, batch_size=2048, warmup_steps=4, out="x")
    run = cfg.run_config(3)
    assert (run.backend, run.device, run.n_envs, run.n_threads, run.seed, run.learn) == (
        "warp", "cuda", 1024, 8, 3, ("bug=sac",))
    assert (run.sac.learn_every, run.sac.gradient_steps, run.sac.batch_size, run.sac.learning_starts) == (
        1024, 8, 2048, 4096)
    assert run.eval_target == 0.4 and run.max_minutes == 4.0 and run.eval_background and not run.save_replay
    assert Path(run.out).name == "sac" and run.name == "seed3"
