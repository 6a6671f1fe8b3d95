"""``triplesumo bench skill`` on tiny runs (16-unit networks, 20-step matches, 4 test matches): the JSON
it writes, the stop rule (the first evaluation at the target; "not reached" when the budget is spent),
and resuming (a raised budget, a lost record rebuilt from the runs, a lower target on a recorded curve)."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest

from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.ppo import PPOConfig
from triplesumo.benchmarks.skill import SkillConfig, outcome, run_skill
from triplesumo.cli import main
from triplesumo.train import checkpoint
from triplesumo.train.config import TrainConfig

TINY_TRAIN = TrainConfig(policies=("ant=random", "spider=random"), steps_per_epoch=20, n_envs=2, progress=False,
                         tensorboard=False, ddpg=DDPGConfig(hidden=(16, 16), buffer_size=2000, learning_starts=10,
                                                            batch_size=8),
                         ppo=PPOConfig(hidden=(16, 16), n_steps=8, n_minibatches=2, n_epochs=2))
EVERY = 40
"""Env steps between evaluations: one 20-step epoch of each of the 2 matches."""


def _tiny(out: Path, **kw: Any) -> SkillConfig:
    return SkillConfig(**{"algos": ("ddpg",), "seeds": (0,), "eval_every": EVERY, "eval_epochs": 4,
                          "max_env_steps": 3 * EVERY, "out": str(out), "train": TINY_TRAIN, **kw})


def _checkpoint_steps(run_dir: Path) -> list[int]:
    return [json.loads((folder / "state.json").read_text())["env_steps"]
            for _, folder in checkpoint.checkpoints(run_dir)]


@pytest.fixture(scope="module")
def not_reached(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("skill") / "b"
    return out, run_skill(_tiny(out, target=1.0))  # 4 wins in 4 twenty-step matches: not within 120 steps


@pytest.mark.slow  # 7 s alone on the shared 2-core box
def test_a_target_not_reached_within_the_budget_is_reported_so_with_the_whole_curve(
        not_reached: tuple[Path, dict[str, Any]]) -> None:
    out, result = not_reached
    assert json.loads((out / "skill.json").read_text()) == result and (out / "skill.png").stat().st_size > 0
    entry = result["algos"]["ddpg"]["runs"][0]
    ev = entry["evaluations"]
    assert entry["status"] == "not reached" and entry["reached"] is False and entry["env_steps"] is None
    assert [e["budget"] for e in ev] == [EVERY, 2 * EVERY, 3 * EVERY]
    assert all(e["budget"] <= e["env_steps"] < e["budget"] + 2 for e in ev)  # the step (of 2 matches) crossing it
    assert all(e["test_mwr"] < 1.0 and e["n_win"] + e["n_loss"] + e["n_draw"] == 4 for e in ev)
    assert entry["best_test_mwr"] == max(e["test_mwr"] for e in ev)
    assert entry["seconds"] is entry["reference_seconds"] is None
    assert result["algos"]["ddpg"]["summary"]["env_steps"] == {"median": None, "min": None, "max": None}
    for key in ("policy_train_seconds", "train_seconds", "eval_seconds", "wall_seconds"):
        assert all(a[key] < b[key] for a, b in zip(ev, ev[1:], strict=False)), key  # cumulative
    assert all(abs(e["wall_seconds"] - e["train_seconds"] - e["eval_seconds"]) < 2e-3 for e in ev)
    assert all(e["policy_train_seconds"] == e["train_seconds"] for e in ev)  # inline: frozen, played, written
    # the project's own training run with its evaluations (eval.csv), stopped at the budget after a checkpoint
    run = out / "ddpg" / "seed0"
    assert _checkpoint_steps(run)[-1] >= ev[-1]["env_steps"] >= 3 * EVERY
    with (run / "eval.csv").open() as fh:
        assert [float(r["test_mwr"]) for r in csv.DictReader(fh)] == [e["test_mwr"] for e in ev]
    config = json.loads((run / "config.json").read_text())
    assert config["learn"] == ["bug=ddpg"] and config["steps_per_epoch"] == 20 and config["seed"] == 0
    assert result["command"].startswith("triplesumo bench skill") and "--target 1.0" in result["command"]
    # the machine is named in the record and the table; a CPU-only run says its GPU figure is not measured
    import os

    from triplesumo.benchmarks.skill import format_skill
    from triplesumo.train.machine import cpu_name

    m = result["machine"]
    assert m["cores"] == os.cpu_count() and m["backend"] == "cpu" and m["device"] == "cpu" and m["gpu"] is None
    assert m["cpu"] == cpu_name()  # the CPU model where the OS names one (/proc/cpuinfo), not only "x86_64"
    assert f"measured on {os.cpu_count()} CPU cores ({m['cpu']})" in format_skill(result)
    assert "GPU: not measured" in format_skill(result)
    # and its speed, before and after: the same seeded collection of the run's 2 matches (100 steps each)
    from triplesumo.train.machine import REFERENCE_STEPS

    assert set(m["reference"]) == {"before", "after"}
    for when, ref in m["reference"].items():
        assert ref["env_steps"] == REFERENCE_STEPS * 2 and ref["n_envs"] == 2 and ref["repeats"] == 3
        assert 0 < ref["ms_per_env_step"] < 1000
        assert f"reference collection {when} the bench: {ref['ms_per_env_step']:.3f} ms per env step" in (
            format_skill(result))


@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_resume_raised_budget_lost_evaluation_and_lower_target(not_reached: tuple[Path, dict[str, Any]]) -> None:
    out, result = not_reached
    ev = result["algos"]["ddpg"]["runs"][0]["evaluations"]
    # a raised budget trains one more chunk from the last checkpoint; the recorded curve is kept
    more = run_skill(_tiny(out, target=1.0, max_env_steps=4 * EVERY))["algos"]["ddpg"]["runs"][0]
    assert more["evaluations"][:3] == ev and more["evaluations"][3]["budget"] == 4 * EVERY
    assert more["status"] == "not reached"
    # a lost record is rebuilt from the runs' eval.csv, without training
    record = json.loads((out / "skill.json").read_text())
    (out / "skill.json").unlink()
    steps = _checkpoint_steps(out / "ddpg" / "seed0")
    again = run_skill(_tiny(out, target=1.0, max_env_steps=4 * EVERY))
    assert again["algos"]["ddpg"]["runs"][0]["evaluations"] == record["algos"]["ddpg"]["runs"][0]["evaluations"]
    assert _checkpoint_steps(out / "ddpg" / "seed0") == steps
    # a lower target on the recorded curve: the first evaluation at it, no training; the eval.csv here as a run
    # from before policy_train_seconds wrote it: its time to skill is the time its row was written
    path = out / "ddpg" / "seed0" / "eval.csv"
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    for row, mwr in zip(rows, (-0.5, 0.25, 0.75, 0.5), strict=True):
        row["test_mwr"] = str(mwr)
        del row["policy_train_seconds"]
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    lower = run_skill(_tiny(out, target=0.2, max_env_steps=4 * EVERY))["algos"]["ddpg"]["runs"][0]
    assert lower["status"] == "reached" and lower["at"] == 1
    assert lower["env_steps"] == lower["evaluations"][1]["env_steps"]
    assert lower["seconds"] == lower["evaluations"][1]["policy_train_seconds"] == float(rows[1]["train_seconds"])
    assert _checkpoint_steps(out / "ddpg" / "seed0") == steps
    # nothing trained, so the record keeps the machine its times were measured on, not one measured now
    assert json.loads((out / "skill.json").read_text())["machine"] == again["machine"]
    with pytest.raises(ValueError, match="other eval_epochs"):
        run_skill(_tiny(out, eval_epochs=5))


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_a_reached_target_stops_training_at_the_first_evaluation_past_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out, path = tmp_path / "b", tmp_path / "r" / "skill.json"
    argv = ["bench", "skill", "--algos", "ppo", "--target", "-1", "--eval-every", str(EVERY), "--eval-epochs", "4",
            "--max-env-steps", str(10 * EVERY), "--out", str(out), "--json", str(path), "--seeds", "0",
            "--train.policies", "ant=random", "spider=random", "--train.steps-per-epoch", "20", "--train.n-envs",
            "2", "--no-train.eval-background", "--no-train.progress", "--no-train.tensorboard",
            "--train.ppo.hidden", "16", "16", "--train.ppo.n-steps", "8", "--train.ppo.n-minibatches", "2",
            "--train.ppo.n-epochs", "2"]
    assert main(argv) == 0
    result = json.loads(path.read_text())
    assert result == json.loads((out / "skill.json").read_text())
    entry = result["algos"]["ppo"]["runs"][0]
    assert entry["status"] == "reached" and entry["at"] == 0 and len(entry["evaluations"]) == 1
    assert entry["env_steps"] == entry["evaluations"][0]["env_steps"] == max(_checkpoint_steps(out / "ppo" / "seed0"))
    assert entry["seconds"] <= entry["wall_seconds"]
    table = capsys.readouterr().out
    assert f"{'ppo':6s} {0:4d} {'yes':>11s} {entry['env_steps']:11,d}" in table


def test_the_stop_rule_on_a_curve() -> None:
    cfg = SkillConfig(target=0.2, eval_every=10, max_env_steps=30)
    assert cfg.algos == ("sac",) and cfg.seeds == (0, 1, 2)  # the default learner, 3 seeds

    def curve(*mwrs: float) -> list[dict[str, Any]]:
        return [{"env_steps": 10 * k + 3, "budget": 10 * k, "test_mwr": m, "policy_train_seconds": float(k),
                 "train_seconds": 1.5 * k, "wall_seconds": 2.0 * k} for k, m in enumerate(mwrs, 1)]

    assert outcome(cfg, curve(0.1, 0.2, 0.5))["at"] == 1  # the first one at the target, not the best
    # the time to skill is the training's clock when that policy was frozen, not when its result came back
    assert outcome(cfg, curve(0.1, 0.2, 0.5))["seconds"] == 2.0
    assert outcome(cfg, curve(0.1, 0.2, 0.5))["wall_seconds"] == 4.0
    assert outcome(cfg, curve(0.1, 0.19))["status"] == "running"
    done = outcome(cfg, curve(0.1, 0.19, 0.0))
    assert done["status"] == "not reached" and done["best_test_mwr"] == 0.19 and done["best_at_env_steps"] == 23
    assert outcome(cfg, curve(0.1, 0.1, 0.1, 0.9))["status"] == "not reached"  # beyond the budget: not counted
    # without the stop a run at the target trains on to the budget, and is then reported as reached where it first was
    go_on = dataclasses.replace(cfg, stop_at_target=False)
    assert outcome(go_on, curve(0.1, 0.2))["status"] == "running"
    full = outcome(go_on, curve(0.1, 0.2, 0.0))
    assert full["status"] == "reached" and full["at"] == 1 and full["env_steps"] == 23 and full["seconds"] == 2.0
    assert outcome(go_on, curve(0.1, 0.19, 0.0)) == done
    assert cfg.run_config("sac", 0).eval_target == 0.2 and go_on.run_config("sac", 0).eval_target is None


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_without_the_stop_a_run_that_reaches_the_target_trains_to_the_budget(tmp_path: Path) -> None:
    out = tmp_path / "b"
    assert main(["bench", "skill", "--algos", "ddpg", "--seeds", "0", "--target", "-1", "--no-stop-at-target",
                 "--eval-every", str(EVERY), "--eval-epochs", "4", "--max-env-steps", str(3 * EVERY), "--out",
                 str(out), "--train.policies", "ant=random", "spider=random", "--train.steps-per-epoch", "20",
                 "--train.n-envs", "2", "--no-train.eval-background", "--no-train.progress",
                 "--no-train.tensorboard", "--train.ddpg.hidden", "16", "16", "--train.ddpg.learning-starts",
                 "10", "--train.ddpg.batch-size", "8"]) == 0
    entry = json.loads((out / "skill.json").read_text())["algos"]["ddpg"]["runs"][0]
    assert [e["budget"] for e in entry["evaluations"]] == [EVERY, 2 * EVERY, 3 * EVERY]  # not stopped at the first
    assert entry["status"] == "reached" and entry["at"] == 0
    assert entry["env_steps"] == entry["evaluations"][0]["env_steps"] < max(_checkpoint_steps(out / "ddpg" / "seed0"))
    assert json.loads((out / "ddpg" / "seed0" / "config.json").read_text())["eval_target"] is None


@pytest.mark.parametrize(("kw", "message"), [
    ({"target": 1.5}, "SkillConfig.target must be a test MWR in"),
    ({"algos": ("ddpg,a2c",)}, "SkillConfig.algos must be among"),
    ({"seeds": (0, 1, 0)}, "SkillConfig.seeds must be non-empty and without repeats"),
    ({"seeds": (0, -1)}, "SkillConfig.seeds must be a non-negative integer"),
    ({"train": TrainConfig(seed=3)}, "SkillConfig.train.seed is set by the bench"),
    ({"eval_every": 0}, "SkillConfig.eval_every must be an int >= 1"),
    ({"max_env_steps": 10, "eval_every": 20}, "SkillConfig.max_env_steps"),
    ({"train": TrainConfig(name="mine")}, "SkillConfig.train.name is set by the bench"),
    ({"train": TrainConfig(max_env_steps=5)}, "SkillConfig.train.max_env_steps is set by the bench"),
    ({"train": TrainConfig(eval_every=5)}, "SkillConfig.train.eval_every is set by the bench"),
])
def test_bad_options_name_the_field(kw: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        SkillConfig(**kw)


@pytest.mark.slow  # 19 s alone on the shared 2-core box
def test_background_evaluations_give_the_same_curve(tmp_path: Path,
                                                   not_reached: tuple[Path, dict[str, Any]]) -> None:
    """``--train.eval-background``: the evaluations play in a worker while Bug trains on; the curve in env
    steps is the inline one, and the record goes on with or without it (where they play is not what it measures)."""
    import dataclasses

    _, inline = not_reached
    cfg = _tiny(tmp_path / "bg", target=1.0, train=dataclasses.replace(TINY_TRAIN, eval_background=True))
    background = run_skill(cfg)["algos"]["ddpg"]["runs"][0]
    keys = ("env_steps", "budget", "test_mwr", "test_mwr_lo", "test_mwr_hi", "n_win", "n_loss", "n_draw")
    assert [{k: e[k] for k in keys} for e in background["evaluations"]] == [
        {k: e[k] for k in keys} for e in inline["algos"]["ddpg"]["runs"][0]["evaluations"]]
    assert background["status"] == "not reached"
    assert all(e["wall_seconds"] >= e["train_seconds"] >= e["policy_train_seconds"]
               for e in background["evaluations"])
    more = run_skill(_tiny(tmp_path / "bg", target=1.0, max_env_steps=4 * EVERY))["algos"]["ddpg"]["runs"][0]  # inline
    assert more["evaluations"][:3] == background["evaluations"] and len(more["evaluations"]) == 4


@pytest.mark.slow  # 18 s in the fast tier's run on the shared 2-core box
def test_the_progress_bar_counts_env_steps_to_the_budget(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    # the bench's runs have an epoch backstop of 10**9; the bar counts what stops them: env steps to max_env_steps
    run_skill(_tiny(tmp_path / "b", target=1.0, max_env_steps=EVERY, train=dataclasses.replace(TINY_TRAIN,
                                                                                              progress=True)))
    err = capfd.readouterr().err
    last = err.replace("\r", "\n").strip().splitlines()[-1]
    assert f"{EVERY:.1f}/{EVERY:.1f} [" in last and "step/s" in last, err[-800:]  # 40.0/40.0, scaled as 1.00M
    assert "1000000000" not in err and "epoch" not in err, err[-800:]


def test_reference_seconds_of_a_recorded_bench() -> None:
    """The recorded SAC bench of docs/runs (250,000 env steps after 348.229 s, reference collections of 0.6707 ms
    before and 0.7196 ms after): on a box whose reference collection takes 0.7 ms per env step it is
    348.229 * 0.7 / 0.69515 = 350.66 s."""
    from triplesumo.train.machine import reference_seconds

    record = json.loads((Path(__file__).parents[1] / "docs/runs/contest-v2/skill-sac32-ref/skill.json").read_text())
    measured = record["machine"]["reference"]
    assert (measured["before"]["ms_per_env_step"], measured["after"]["ms_per_env_step"]) == (0.6707, 0.7196)
    seconds = record["algos"]["sac"]["wall_seconds"]
    assert seconds == 348.229
    by_hand = 348.229 * 0.7 / ((0.6707 + 0.7196) / 2)
    assert reference_seconds(seconds, measured) == pytest.approx(by_hand, rel=1e-12)
    assert round(reference_seconds(seconds, measured), 2) == 350.66
    # a box twice as slow as the reference box: its seconds count half
    assert reference_seconds(100.0, {"before": {"ms_per_env_step": 1.4}}) == pytest.approx(50.0)


def test_the_plots_title_wraps_a_long_median_line_instead_of_running_off_the_figure() -> None:
    """docs/bench/skill_tau02.json: one seed of three reached, so its median line is 190 characters, which ran off
    both sides of the 11-inch figure before it was wrapped."""
    from triplesumo.benchmarks.skill import TITLE_WIDTH, plot_title

    record = json.loads((Path(__file__).parents[1] / "docs/bench/skill_tau02.json").read_text())
    title = plot_title(record)
    lines = title.split("\n")
    assert max(len(line) for line in lines) <= TITLE_WIDTH
    assert len(lines) == 4  # what, the machine, and the median line in two
    assert lines[1] == "2 CPU cores (AMD EPYC), reference collection 3.602 ms per env step"
    median = " ".join(lines[2:])  # nothing lost in the wrapping
    assert median == ("sac: median (min - max) over 3 seeds, 1 reached: not reached (100,000 - not reached) env steps, "
                      "not reached (1541 - not reached) s, not reached (299 - not reached) reference s")
    assert plot_title(record, width=1000).split("\n")[2] == median  # one line when it fits


def test_the_median_and_spread_over_seeds_count_a_seed_not_reached_as_beyond_the_budget() -> None:
    from triplesumo.benchmarks.skill import spread

    assert spread([300, 100, 200]) == {"median": 200, "min": 100, "max": 300}
    assert spread([100, None, 300]) == {"median": 300, "min": 100, "max": None}  # the middle seed: 300
    assert spread([None, 100, None]) == {"median": None, "min": 100, "max": None}  # most not reached
    assert spread([100, 200]) == {"median": 150, "min": 100, "max": 200}
    assert spread([100, None]) == {"median": None, "min": 100, "max": None}
    assert spread([None]) == {"median": None, "min": None, "max": None}


@pytest.mark.slow  # 51 s alone on the shared 2-core box
def test_quick_writes_the_table_the_json_and_the_plot_over_three_seeds(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``bench skill --quick``: the defaults (3 seeds, background evaluations, the shipped match) on a tiny budget;
    with a target every policy meets, each seed stops at its first evaluation."""
    import statistics

    out, path = tmp_path / "q", tmp_path / "r" / "skill.json"
    assert main(["bench", "skill", "--quick", "--algos", "sac", "--target", "-1", "--out", str(out),
                 "--json", str(path)]) == 0
    result = json.loads((out / "skill.json").read_text())
    assert json.loads(path.read_text()) == result
    assert (out / "skill.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert result["config"]["quick"] is True and result["eval_every"] == 40 and result["eval_background"] is True
    runs = result["algos"]["sac"]["runs"]
    assert [r["seed"] for r in runs] == result["seeds"] == [0, 1, 2]
    for run in runs:
        assert run["status"] == "reached" and run["at"] == 0 and 40 <= run["env_steps"] < 42
        first = run["evaluations"][0]
        assert run["seconds"] == first["policy_train_seconds"] <= first["train_seconds"] <= run["wall_seconds"]
        config = json.loads((out / "sac" / f"seed{run['seed']}" / "config.json").read_text())
        assert config["seed"] == run["seed"] and config["learn"] == ["bug=sac"]
    # the median and spread over the seeds, in seconds and in reference seconds
    summary = result["algos"]["sac"]["summary"]
    assert summary["seeds"] == summary["reached"] == 3
    seconds = [r["seconds"] for r in runs]
    assert summary["seconds"] == {"median": statistics.median(seconds), "min": min(seconds), "max": max(seconds)}
    assert summary["env_steps"]["median"] == statistics.median(r["env_steps"] for r in runs)
    measured = result["machine"]["reference"]
    ms = (measured["before"]["ms_per_env_step"] + measured["after"]["ms_per_env_step"]) / 2
    assert result["reference"]["ms_per_env_step"] == pytest.approx(ms, abs=1e-4)
    for run in runs:
        assert run["reference_seconds"] == pytest.approx(run["seconds"] * 0.7 / ms, abs=1e-3)
    assert summary["reference_seconds"]["median"] == statistics.median(r["reference_seconds"] for r in runs)
    table = capsys.readouterr().out
    assert f"{'sac':6s} {2:4d} {'yes':>11s} {runs[2]['env_steps']:11,d}" in table
    assert "sac: median (min - max) over 3 seeds, 3 reached:" in table
    assert f"reference collection after the bench: {measured['after']['ms_per_env_step']:.3f} ms" in table


HOLD = Path(__file__).parents[1] / "docs" / "runs" / "hold-n5u8"
"""The final-skill check of SAC's default recipe (n = 5 at UTD 1/8), in docs/runs, cited by docs/bench/skill.md."""


def test_the_default_recipes_final_skill_is_recomputed_from_its_committed_matches() -> None:
    """Each of the three runs trained the recipe that is SAC's default now for 1 M env steps in the shipped match;
    its final policy's test MWR on the 2,000 test starts, recomputed from the per-match rows, is the page's, and
    the rule written before the test (mean at least +0.40, no seed under +0.30) holds on them."""
    import numpy as np

    from triplesumo.agents.policy_file import load_policy
    from triplesumo.algos.sac import SACConfig
    from triplesumo.evaluation.metrics import summarize
    from triplesumo.evaluation.metrics_csv import open_table

    with open(HOLD / "test-2000" / "per_seed.csv", newline="") as fh:
        rows = {r["candidate"]: r for r in csv.DictReader(fh)}
    scores = []
    for seed in (0, 1, 2):
        run = HOLD / f"learn=bug=sac,seed={seed}"
        config = json.loads((run / "config.json").read_text())
        defaults = SACConfig()
        assert (config["sac"]["learn_every"], config["sac"]["n_step"]) == (defaults.learn_every, defaults.n_step)
        assert config["seed"] == seed and config["max_env_steps"] == 1_000_000
        assert config["policies"] == ["ant=zoo:ant", "spider=zoo:spider"]
        assert json.loads((run / "policy.json").read_text())["env_steps"] >= 1_000_000  # the final policy
        candidate = next(c for c in rows if c.endswith(f"sac-seed-{seed}-policy"))
        with open_table(HOLD / "test-2000" / candidate / "metrics.csv") as fh:
            matches = list(csv.DictReader(fh))
        assert len(matches) == 2000 and rows[candidate]["eval_seed"] == "10000"
        mwr = float(summarize([m["outcome"] for m in matches], [float(m["steps"]) for m in matches])["mean_lwr"])
        assert mwr == pytest.approx(float(rows[candidate]["test_mwr"]), abs=1e-12)
        scores.append(mwr)
        policy, _ = load_policy(run / "policy")  # safetensors and JSON: loads without pickle, acts
        assert np.all(np.abs(policy(np.zeros((2, policy.obs_dim), np.float32))) <= 1.0)
    assert np.mean(scores) >= 0.40 and min(scores) >= 0.30
    page = " ".join((Path(__file__).parents[1] / "docs" / "bench" / "skill.md").read_text().split())
    row = " | ".join(f"**{v:+.3f}**" for v in scores)
    assert f"| **n = 5 at UTD 1/8** (`learn_every 8`, `n_step 5`) | {row.split(' | ')[0]}" in page
    for value in scores:
        assert f"{value:+.3f}" in page
    assert f"(mean {np.mean(scores):+.3f})" in page


@pytest.mark.slow  # two tiny runs in two processes
def test_workers_train_seeds_at_once_and_give_the_curves_of_one_after_another(
        tmp_path: Path, not_reached: tuple[Path, dict[str, Any]], capsys: pytest.CaptureFixture[str]) -> None:
    """``--workers 2``: seeds 0 and 1 in two processes; seed 0's curve is the one the bench trained alone (the
    fixture's), the record lists the seeds in order, and the same bench run again one after another trains nothing
    (``workers`` is not part of what the curves depend on)."""
    _, alone = not_reached
    cfg = _tiny(tmp_path / "w", target=1.0, seeds=(1, 0), workers=2)
    result = run_skill(cfg)
    runs = result["algos"]["ddpg"]["runs"]
    assert [r["seed"] for r in runs] == [1, 0] and all(r["status"] == "not reached" for r in runs)
    keys = ("env_steps", "budget", "test_mwr", "n_win", "n_loss", "n_draw")
    assert [{k: e[k] for k in keys} for e in runs[1]["evaluations"]] == [
        {k: e[k] for k in keys} for e in alone["algos"]["ddpg"]["runs"][0]["evaluations"]]
    assert "2 at once" in capsys.readouterr().out
    metrics = tmp_path / "w" / "ddpg" / "seed1" / "metrics.csv"
    stamp = metrics.stat().st_mtime_ns
    again = run_skill(dataclasses.replace(cfg, workers=1))
    assert again["algos"] == result["algos"] and metrics.stat().st_mtime_ns == stamp
    with pytest.raises(ValueError, match=r"SkillConfig\.workers must be an int >= 1, got 0"):
        _tiny(tmp_path, workers=0)
