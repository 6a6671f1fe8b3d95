"""``triplesumo bench train --quick``: the report's shape and arithmetic (never its speed).

Speed lives in the benchmark itself; here the rates only have to exist, be positive
and finite, and the derived numbers have to follow from them.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from pathlib import Path
from typing import Any

import pytest

from triplesumo.benchmarks.train import PAPER_EPOCHS, main

LABELS = {"env_only": "env alone (collection, no learning)", "train_paper": "training, paper preset",
          "sb3_ddpg": "Stable-Baselines3 DDPG, same schedule"}
QUICK_STEPS, QUICK_ENVS, QUICK_WARM_UP = 64, 2, 32
"""What ``--quick`` sets: env steps per variant, matches, warm-up transitions."""


def run_bench(argv: list[str]) -> tuple[int, str]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(argv)
    return rc, buf.getvalue()


def run_bench_json(path: Path, argv: list[str]) -> tuple[int, str, dict[str, Any]]:
    """``bench train ARGV --json PATH``: its exit code, what it printed and the JSON it wrote."""
    rc, printed = run_bench([*argv, "--json", str(path)])
    return rc, printed, json.loads(path.read_text())


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, str, dict[str, Any], Path]:
    path = tmp_path_factory.mktemp("bench") / "sub" / "b.json"
    return *run_bench_json(path, ["--quick"]), path


@pytest.fixture(scope="module")
def quick_no_sb3(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, str, dict[str, Any]]:
    return run_bench_json(tmp_path_factory.mktemp("bench") / "n.json", ["--quick", "--no-sb3"])


@pytest.mark.slow  # 45 s alone on the shared 2-core box
def test_quick_prints_the_table_with_all_three_variants(quick: tuple) -> None:
    rc, printed, result, path = quick
    assert rc == 0
    for name, label in LABELS.items():
        line = next(line for line in printed.splitlines() if line.startswith(label))
        assert float(line.split()[-3]) == pytest.approx(result["rates"][name], abs=0.5)
    assert "SB3: measured" in printed
    assert "train / env alone:" in printed and "train / SB3 DDPG:" in printed
    assert printed.rstrip().endswith(f"wrote {path}")


@pytest.mark.slow  # uses the module's quick fixture, 63 s to build
def test_quick_json_rates_ratios_split_and_projection_follow_from_each_other(quick: tuple) -> None:
    _, _, result, _ = quick
    rates = result["rates"]
    assert set(LABELS) <= set(rates)  # (other variants may be measured too)
    assert all(math.isfinite(r) and r > 0 for r in rates.values()), rates
    assert result["ratios"]["train_vs_env"] == pytest.approx(rates["train_paper"] / rates["env_only"])
    assert result["ratios"]["train_vs_sb3"] == pytest.approx(rates["train_paper"] / rates["sb3_ddpg"])
    split = result["time_split"]
    assert set(split) == {"env", "act", "wait_for_learning"}
    assert all(0.0 <= v <= 1.0 for v in split.values())
    assert sum(split.values()) == pytest.approx(1.0)
    assert result["learning_busy"] > 0  # the paper preset did learn during the timed steps
    hours = result["projected_hours_20000_epochs"]
    assert hours["at_500_steps_per_epoch"] == pytest.approx(PAPER_EPOCHS * 500 / rates["train_paper"] / 3600)
    assert hours["at_measured_epoch_length"] > 0 and hours["at_500_steps_per_epoch"] > 0
    setup = result["setup"]
    assert (setup["steps"], setup["n_envs"], setup["learning_starts"]) == (QUICK_STEPS, QUICK_ENVS, QUICK_WARM_UP)
    assert setup["sb3"] == "measured"


ALGO_ROWS = ("train_td3", "train_sac", "train_ppo", "train_3_learners", "sb3_td3", "sb3_sac", "sb3_ppo",
             "train_td3_bf16", "train_sac_bf16")


@pytest.mark.slow  # uses the module's quick fixture, 63 s to build
def test_quick_measures_each_algorithm_three_learners_and_sb3s_same_algorithm(quick: tuple) -> None:
    _, printed, result, _ = quick
    rates, updates, ratios = result["rates"], result["updates_per_s"], result["ratios"]
    assert set(ALGO_ROWS) <= set(rates) and set(rates) == set(updates)
    assert all(math.isfinite(u) and u >= 0 for u in updates.values())
    assert updates["train_paper"] > 0 and updates["sb3_ppo"] > 0  # (quick runs are too short for the rest)
    for algo in ("td3", "sac", "ppo"):
        assert ratios[f"{algo}_vs_sb3"] == pytest.approx(rates[f"train_{algo}"] / rates[f"sb3_{algo}"])
        assert f"train {algo.upper()} / SB3 {algo.upper()}:" in printed
    for algo in ("td3", "sac"):  # bfloat16 updates, against SB3's (float32) same algorithm and the env alone
        assert ratios[f"{algo}_bf16_vs_sb3"] == pytest.approx(rates[f"train_{algo}_bf16"] / rates[f"sb3_{algo}"])
        assert ratios[f"{algo}_bf16_vs_env"] == pytest.approx(rates[f"train_{algo}_bf16"] / rates["env_only"])
        assert f"train {algo.upper()} (bfloat16 updates) / SB3 {algo.upper()}: " in printed
        verdict = "met" if ratios[f"{algo}_bf16_vs_env"] >= 0.8 else "NOT met"
        assert f"train {algo.upper()} (bfloat16 updates) / env alone: {ratios[f'{algo}_bf16_vs_env']:.2f} " \
               f"(target >= 0.8: {verdict})" in printed
    assert result["setup"]["algo_schedule"]["three_learners"] == ["ant=sac", "bug=td3", "spider=ppo"]
    line = next(line for line in printed.splitlines() if line.startswith("training 3 learners"))
    assert float(line.split()[-1]) == pytest.approx(updates["train_3_learners"], abs=0.05)


@pytest.mark.slow  # uses the module's quick fixture, 63 s to build
def test_quick_never_reports_an_epoch_longer_than_any_match_has_run(quick: tuple) -> None:
    _, _, result, _ = quick
    longest_possible = (QUICK_WARM_UP + QUICK_STEPS) / QUICK_ENVS  # steps any one match has taken
    assert result["mean_epoch_steps"] is None or result["mean_epoch_steps"] <= longest_possible


@pytest.mark.slow  # 15 s alone on the shared 2-core box
def test_no_sb3_leaves_sb3_out(quick_no_sb3: tuple[int, str, dict[str, Any]]) -> None:
    rc, printed, result = quick_no_sb3
    assert rc == 0
    assert {"env_only", "train_paper"} <= set(result["rates"])
    assert "sb3_ddpg" not in result["rates"] and "train_vs_sb3" not in result["ratios"]
    assert all(math.isfinite(r) and r > 0 for r in result["rates"].values())
    assert result["setup"]["sb3"] == "skipped"
    assert "SB3: skipped" in printed
    assert LABELS["sb3_ddpg"] not in printed
    assert "train / SB3" not in printed
    assert any(line.startswith(LABELS["train_paper"]) for line in printed.splitlines())


@pytest.mark.slow  # uses the module's quick fixture, 63 s to build
def test_quick_cpu_rates_and_the_update_profile_follow_from_each_other(quick: tuple) -> None:
    _, printed, result, _ = quick
    cpu = result["cpu_rates"]
    assert set(cpu) == set(result["rates"]) and all(math.isfinite(r) and r > 0 for r in cpu.values())
    for algo, ours in (("ddpg", "train_paper"), ("td3", "train_td3"), ("sac", "train_sac"), ("ppo", "train_ppo")):
        assert result["cpu_ratios"][f"{algo}_vs_sb3"] == pytest.approx(cpu[ours] / cpu[f"sb3_{algo}"])
    for algo in ("td3", "sac"):
        assert result["cpu_ratios"][f"{algo}_bf16_vs_sb3"] == pytest.approx(cpu[f"train_{algo}_bf16"]
                                                                            / cpu[f"sb3_{algo}"])
    assert "per CPU-second of the process" in printed
    profile = result["update_profile_ms"]
    assert set(profile) == {"ddpg", "td3", "sac", "ppo", "td3_bf16", "sac_bf16"}
    for algo in ("td3_bf16", "sac_bf16"):  # ours only: SB3 has no bfloat16 updates
        assert set(profile.pop(algo)) == {"ours"}
    for algo, row in profile.items():
        assert set(row) == {"ours", "sb3"}, algo
        for side in row.values():
            assert side["backward"] > 0 and side["optimizer"] > 0 and side["forward_and_rest"] > 0
            assert side["forward_and_rest"] + side["backward"] + side["optimizer"] == pytest.approx(side["total"])
        line = next(line for line in printed.splitlines() if line.strip().startswith(algo.upper() + " "))
        assert float(line.split()[-1]) == pytest.approx(row["sb3"]["total"] / row["ours"]["total"], abs=0.005)


def test_the_phase_timer_counts_backward_and_adam_and_puts_everything_back() -> None:
    import torch

    from triplesumo.benchmarks.train import _PhaseTimer

    w = torch.nn.Parameter(torch.ones(300, 300))
    opt = torch.optim.Adam([w])  # the first optimizer of a process wraps Adam.step in torch's profiling hook
    backward, step = torch.Tensor.backward, torch.optim.Adam.step
    with _PhaseTimer() as timer:
        for _ in range(20):
            (w @ w).square().sum().backward()
            opt.step()
    assert timer.backward > 0 and timer.optimizer > 0
    assert (torch.Tensor.backward, torch.optim.Adam.step) == (backward, step)


PROFILE_PARTS = ("env", "act", "seats", "store", "bookkeeping", "update")


@pytest.fixture(scope="module")
def quick_profile(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, str, dict[str, Any]]:
    return run_bench_json(tmp_path_factory.mktemp("bench") / "profile.json", ["--profile", "--quick"])


@pytest.mark.slow  # 30 s alone on the shared 2-core box
def test_profile_cuts_an_env_step_into_parts_that_add_up_for_every_learner(quick_profile: tuple) -> None:
    rc, printed, result = quick_profile
    assert rc == 0
    learners = result["learners"]
    assert set(learners) == {"env", "ddpg", "td3", "sac", "ppo", "td3_bf16", "sac_bf16"}
    for name, modes in learners.items():
        assert set(modes) == ({"overlap"} if name == "env" else {"overlap", "inline"}), name
        for mode, r in modes.items():
            parts = r["cpu_us_per_env_step"]
            assert tuple(parts) == PROFILE_PARTS
            assert all(math.isfinite(v) and v >= 0 for v in parts.values()), (name, mode, parts)
            assert parts["env"] > 0 and parts["act"] > 0 and parts["store"] > 0
            assert (parts["update"] > 0) == (name != "env")
            total = r["cpu_us_per_env_step_total"]
            assert total == pytest.approx(sum(parts.values()))
            # the critical path holds all the collecting thread does and, of the updates, at most all
            collecting = total - (parts["update"] if mode == "overlap" else 0.0)
            assert collecting * (1 - 1e-9) <= r["critical_path_us_per_env_step"] <= total * (1 + 1e-9)
            if mode == "inline" or name in ("env", "ppo"):  # nothing runs beside the collecting thread
                assert r["critical_path_us_per_env_step"] == pytest.approx(total)
                assert r["blocked_per_step"]["update_thread"] == 0
            # the update's per-gradient-step and per-env-step figures are one measurement read two ways
            assert name == "env" or r["update_ms_per_gradient_step"] * r["gradient_steps"] == pytest.approx(
                parts["update"] * r["env_steps"] / 1e3)
            assert all(t["intra_op"] == 1 for t in r["torch_threads"].values())  # the trainer's torch_threads
            assert ("update" in r["torch_threads"]) == (mode == "overlap" and name not in ("ppo", "env"))
            line = next(line for line in printed.splitlines() if line.startswith(f"{name} {mode} "))
            assert float(line.split()[2]) == pytest.approx(parts["env"], abs=0.5)
    # the schedules: TD3 and SAC one gradient step per n_envs transitions (2 here), PPO 10 x 32 per 64-step rollout
    for name in ("td3", "sac", "td3_bf16", "sac_bf16"):
        assert learners[name]["overlap"]["gradient_steps_per_env_step"] == 0.5
    assert learners["ppo"]["inline"]["gradient_steps_per_env_step"] == 10 * 32 / 64
    assert result["setup"]["n_envs"] == QUICK_ENVS
