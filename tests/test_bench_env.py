"""``triplesumo bench env`` at tiny sizes: the result's shape and consistency, never its speed."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from triplesumo.benchmarks.env import main, run_env_benchmark

SINGLE = ("raw_physics", "parallel_env", "match_core")
BATCHES = ("batch_threads_1t", "batch_mujoco_1t", "batch_mujoco_2t", "batch_threads_2t")


def _vector_rows(result: dict) -> tuple[str, str]:
    threads = result["setup"]["n_threads"]
    return f"raw_batch_{threads}t", f"vector_env_{threads}t"


def _check(result: dict) -> None:
    assert set(result) == {"setup", "rates", "rounds", "episodes", "ratios", "target"}
    raw_batch, vector = _vector_rows(result)
    batches = tuple(b for b in BATCHES if int(b[-2]) <= result["setup"]["n_threads"])
    assert set(result["rates"]) == set(SINGLE + batches + (raw_batch, vector))
    for name, rate in result["rates"].items():
        assert math.isfinite(rate) and rate > 0, name
        assert len(result["rounds"][name]) == result["setup"]["rounds"]
    rates, ratios = result["rates"], result["ratios"]
    assert ratios["parallel_env_vs_raw"] == pytest.approx(rates["parallel_env"] / rates["raw_physics"], rel=1e-12)
    assert ratios["match_core_vs_raw"] == pytest.approx(rates["match_core"] / rates["raw_physics"], rel=1e-12)
    assert ratios[f"{vector}_vs_raw_batch"] == pytest.approx(rates[vector] / rates[raw_batch], rel=1e-12)
    for name in batches:
        assert ratios[f"{name}_vs_one_match"] == pytest.approx(rates[name] / rates["match_core"], rel=1e-12)
        assert ratios[f"{name}_vs_sequential"] == pytest.approx(rates[name] / rates["batch_threads_1t"], rel=1e-12)
    if result["setup"]["scenario"] in ("ffa", "pursuit"):  # elimination: the ratios compare different matches
        assert result["target"] == {}
        return
    assert result["target"] == {"parallel_env_vs_raw": 0.85, "met": ratios["parallel_env_vs_raw"] >= 0.85,
                                "vector_env_vs_raw_batch": 0.9,
                                "vector_env_met": ratios[f"{vector}_vs_raw_batch"] >= 0.9}
    setup = result["setup"]
    assert setup["integrator"] == "RK4" and setup["cpu_count"] >= 1
    assert {"python", "mujoco", "numpy"} <= set(setup["versions"])


def test_run_env_benchmark_returns_consistent_rates_and_ratios() -> None:
    result = run_env_benchmark(steps=8, n_matches=2, n_threads=2, rounds=2, chunk=3)
    _check(result)
    assert result["setup"]["steps_per_match"] == 4


def test_single_match_variants_replay_the_same_episodes() -> None:
    """Raw physics restarts where the env's episodes end: the same trajectories, so the same count."""
    result = run_env_benchmark(steps=400, n_matches=2, n_threads=1, rounds=1)
    counts = {result["episodes"][name] for name in SINGLE}
    assert len(counts) == 1, result["episodes"]
    assert counts.pop() >= 1, "no episode ended: lengthen the run so the check means something"
    # and raw mujoco.batch physics restarts where vector_env's matches end
    raw_batch, vector = _vector_rows(result)
    assert result["episodes"][raw_batch] == result["episodes"][vector] >= 1, result["episodes"]


def test_main_quick_writes_json_with_the_documented_keys(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / "out" / "bench.json"
    assert main(["--quick", "--json", str(path)]) == 0
    _check(json.loads(path.read_text()))
    printed = capsys.readouterr().out
    assert "raw physics" in printed and "PettingZoo parallel_env" in printed and "MatchBatch" in printed
    assert "triplesumo.vector_env" in printed and "raw mujoco.batch physics" in printed


@pytest.mark.parametrize("scenario", ["pursuit", "2v2"])
def test_only_the_targets_that_apply_are_printed(scenario: str, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "bench.json"
    assert main(["--quick", "--scenario", scenario, "--json", str(path)]) == 0
    result = json.loads(path.read_text())
    _check(result)
    printed = capsys.readouterr().out
    if scenario == "pursuit":  # elimination rules: the raw reference restarts at the first ring exit
        assert "target parallel_env" not in printed and "target vector_env" not in printed and " met" not in printed
        assert "no speed target applies" in printed
    else:
        assert "target parallel_env >= 0.85" in printed and "target vector_env >= 0.9" in printed


def test_obs_mode_reaches_the_envs_and_the_setup() -> None:
    result = run_env_benchmark(steps=4, n_matches=2, n_threads=2, rounds=1, chunk=2, obs_mode="egocentric")
    _check(result)
    assert result["setup"]["obs_mode"] == "egocentric"
    with pytest.raises(ValueError, match="obs_mode"):
        run_env_benchmark(steps=4, n_matches=2, rounds=1, obs_mode="pixels")


def test_bad_sizes_are_value_errors() -> None:
    with pytest.raises(ValueError, match="steps"):
        run_env_benchmark(steps=0)


@pytest.mark.slow  # 8 s alone on the shared 2-core box
def test_warp_backend_reports_env_and_raw_rates_per_size(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("mujoco_warp", reason="mujoco-warp is not installed (pip install 'triplesumo[gpu]')")
    path = tmp_path / "warp.json"
    assert main(["--backend", "warp", "--device", "cpu", "--quick", "--json", str(path)]) == 0
    result = json.loads(path.read_text())
    assert result["setup"]["backend"] == "warp" and result["setup"]["device"] == "cpu"
    (row,) = result["rows"]
    assert row["num_envs"] == 2
    assert row["env_steps_per_s"] > 0 and row["raw_env_steps_per_s"] > 0
    assert row["env_vs_raw"] == pytest.approx(row["env_steps_per_s"] / row["raw_env_steps_per_s"], rel=1e-12)
    assert row["raw_physics_steps_per_s"] == pytest.approx(5 * row["raw_env_steps_per_s"], rel=1e-12)
    assert "raw mujoco_warp" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="num-envs"):
        main(["--backend", "warp", "--num-envs", "1,x"])
    # a named game reaches the Warp env too (elimination rules play there since issue 54)
    assert main(["--backend", "warp", "--device", "cpu", "--quick", "--scenario", "ffa", "--json", str(path)]) == 0
    assert json.loads(path.read_text())["setup"]["scenario"] == "ffa" and "scenario ffa" in capsys.readouterr().out
