"""The main job (``triplesumo demo``) end to end on a tiny budget, and the zoo / evaluate / play commands.

The tests use the tiny zoo of ``conftest.py`` (Ant, Spider: 2 epochs of 20 steps,
16-unit networks), pointing :data:`triplesumo.agents.zoo.ZOO_DIR` at it, so they do not
depend on the shipped weights. The demo runs as the command does, with its own options
for short matches (``--steps-per-epoch``) and a small video (``--video-size``).
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import triplesumo  # noqa: F401  (registers the Gymnasium ids)
import triplesumo.agents.zoo
from conftest import TinyZoo
from triplesumo.agents.policy_file import load_fixed_policy, load_json, load_policy, save_policy
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.sac import SACConfig
from triplesumo.cli import main
from triplesumo.demo import match_to_record
from triplesumo.evaluation.evaluate import EvaluateConfig
from triplesumo.evaluation.video import count_frames
from triplesumo.evaluation.viewer import read_page_data
from triplesumo.train.logger import COLUMNS

PLOTS = ["mwr.png", "reward_terms.png", "rewards.png", "steps_to_win.png"]
PNG = b"\x89PNG\r\n\x1a\n"
DEMO_STEPS = 40
"""Match length the demo test plays (--steps-per-epoch; the default is 500)."""




@pytest.fixture
def zoo(tiny_zoo: TinyZoo, monkeypatch: pytest.MonkeyPatch) -> TinyZoo:
    """The tiny zoo, patched in as the shipped one for this test."""
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
    return tiny_zoo


# --------------------------------------------------------------------- the main job
@pytest.mark.slow  # 22 s alone on the shared 2-core box
def test_demo_trains_evaluates_records_and_says_where(zoo: TinyZoo, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo"
    rc = main(["demo", "--out", str(out), "--train-env-steps", "80", "--eval-epochs", "4", "--n-envs", "2",
               "--learning-starts", "20", "--max-minutes", "0", "--no-progress",
               "--steps-per-epoch", str(DEMO_STEPS), "--video-size", "64"])
    printed = capsys.readouterr().out
    assert rc == 0
    assert "note: the shipped" not in printed  # the tiny zoo is this env version's: no word of an older pair
    shipped = load_json(zoo.zoo_dir / "bug.json")  # the output says what the shipped Bug is, from its manifest
    assert f"(zoo:bug: {shipped['algo'].upper()}, {shipped['env_steps']:,} env steps)" in printed

    # 1. training: Bug with SAC's defaults in the (tiny) shipped ongoing match, up to the first match end past
    # its env-step budget
    assert "[1/3] training Bug with SAC (TripleSumo's recipe) for 80 env steps" in printed
    with (out / "bug" / "metrics.csv").open(newline="") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames or ()) == COLUMNS
        rows = list(reader)
    assert [int(r["epoch"]) for r in rows] == list(range(1, len(rows) + 1))
    assert sorted(p.name for p in (out / "bug" / "plots").glob("*.png")) == PLOTS
    manifest = load_json(out / "bug" / "policy.json")
    assert manifest["agent"] == "bug" and manifest["algo"] == "sac" and manifest["epochs"] == len(rows)
    assert 80 <= manifest["env_steps"] < 80 + 2 * DEMO_STEPS
    assert manifest["trained_against"] == ["ant=zoo:ant", "spider=zoo:spider"]
    assert manifest["hidden"] == list(SACConfig().hidden)
    config = json.loads((out / "bug" / "config.json").read_text())
    assert (config["sac"]["learn_every"], config["sac"]["n_step"], config["sac"]["learning_starts"]) == (8, 5, 20)
    # 2. evaluation against both baselines, on the policy it just trained
    summary = json.loads((out / "evaluation" / "summary.json").read_text())
    assert list(summary["candidates"]) == ["trained", "zoo-bug", "passive", "random"]
    assert summary["candidates"]["trained"]["policy"] == str(out / "bug" / "policy")
    assert summary["candidates"]["zoo-bug"]["policy"] == "zoo:bug"
    assert all(c["n"] == 4 for c in summary["candidates"].values())
    assert (out / "evaluation" / "compare_mwr.png").read_bytes()[:8] == PNG
    # 3. a decodable video of one test match: the one the demo says it chose, as long as that match
    seed, why = match_to_record(out / "evaluation" / "zoo-bug" / "metrics.csv", EvaluateConfig().seed)
    assert f"{why} (seed {seed})" in printed
    steps = int(why.split(" after ")[1].split()[0])
    frames = count_frames(out / "match.mp4")
    assert 1 < frames <= DEMO_STEPS + 1 and frames == steps + 1
    assert f"({frames} frames)" in printed
    # ... and a page of the same match, its path printed
    page = read_page_data((out / "match.html").read_text(encoding="utf-8"))
    assert page["steps"] == steps and len(page["frames"]) == frames
    assert f"page: {out / 'match.html'}" in printed
    # the end of the output says where everything is
    where = printed.split("where to look:")[1]
    for path in (out / "bug", out / "bug" / "plots", out / "evaluation", out / "evaluation" / "compare_mwr.png",
                 out / "match.mp4", out / "match.html"):
        assert str(path) in where, path
    for label in ("trained", "zoo-bug", "passive", "random"):
        assert re.search(rf"^{label}\s", printed, re.M), label


def test_the_demo_trains_the_learner_asked_for_with_its_own_hyper_parameters(tmp_path: Path) -> None:
    """``--algo ddpg`` trains the paper's preset (its warm-up too unless ``--learning-starts`` is given); a learner
    the demo does not offer is refused by name."""
    from triplesumo.demo import DemoConfig, _train_config

    cfg = _train_config(DemoConfig(algo="ddpg"), "bug", tmp_path)
    assert cfg.learn == ("bug=ddpg",) and cfg.ddpg == DDPGConfig() and cfg.max_env_steps == 150_000
    cfg = _train_config(DemoConfig(learning_starts=7), "bug", tmp_path)
    assert cfg.sac.learning_starts == 7 and cfg.sac.n_step == SACConfig().n_step and cfg.ddpg == DDPGConfig()
    with pytest.raises(ValueError, match="DemoConfig.algo must be one of sac, ddpg, got 'td3'"):
        DemoConfig(algo="td3")


# ------------------------------------------------------------------------------ zoo
def test_zoo_list_prints_each_entry_with_its_command_and_seed(zoo: TinyZoo,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["zoo", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == ["ant", "bug", "spider"]
    for line, name in zip(lines, ("ant", "bug", "spider"), strict=True):
        meta = load_json(zoo.zoo_dir / f"{name}.json")
        assert f"agent={name}" in line
        assert f"seed={meta['seed']}" in line and f" env={meta['env_version']} " in line
        assert line.endswith(f"made by: {meta['command']}")


def test_zoo_publish_records_the_evaluation_and_keeps_the_provenance(
        tiny_zoo: TinyZoo, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    shipped = Path(triplesumo.agents.zoo.ZOO_DIR)
    assert not (shipped / "x.json").exists()
    target = tmp_path / "zoo"
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", target)
    evaluation = {"mean_lwr": 0.25, "mean_lwr_lo": 0.1, "mean_lwr_hi": 0.4, "n": 100}
    (tmp_path / "eval.json").write_text(json.dumps(evaluation))
    run_policy = tiny_zoo.ant_run / "policy"
    assert main(["zoo", "publish", str(run_policy), "x", "--evaluation", str(tmp_path / "eval.json")]) == 0
    assert capsys.readouterr().out.strip() == str(target / "x.json")
    # written where ZOO_DIR points at call time, never into the package
    assert not (shipped / "x.json").exists() and not (shipped / "x.safetensors").exists()
    made = load_json(run_policy.with_suffix(".json"))
    manifest = load_json(target / "x.json")
    assert manifest["evaluation"] == evaluation
    assert manifest["zoo_name"] == "x"
    for key in ("command", "seed", "epochs", "agent", "obs_mode"):
        assert manifest[key] == made[key], key
    assert triplesumo.agents.zoo.available() == ["x"]
    published, _ = triplesumo.agents.zoo.load("x")
    original, _ = load_fixed_policy(run_policy)  # zoo.load's loader: the same weights act alike
    obs = np.random.default_rng(0).normal(size=(3, made["obs_dim"])).astype(np.float32)
    np.testing.assert_array_equal(published(obs), original(obs))


def test_zoo_publish_refuses_what_no_training_run_made(tmp_path: Path, tiny_zoo: TinyZoo,
                                                       monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tmp_path / "zoo")
    actor, manifest = load_policy(tiny_zoo.ant_run / "policy")
    bare = {k: manifest[k] for k in ("agent", "obs_mode")}
    save_policy(tmp_path / "handmade", actor.actor, bare)
    assert main(["zoo", "publish", str(tmp_path / "handmade"), "y"]) == 2
    assert "lacks 'command'" in capsys.readouterr().err
    assert main(["zoo", "publish"]) == 2
    assert not (tmp_path / "zoo" / "y.json").exists()


# ------------------------------------------------------------------------- evaluate
def test_evaluate_command_prints_the_table_and_writes_the_report(zoo: TinyZoo, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "ev"
    rc = main(["evaluate", "--policy", str(zoo.bug_policy), "--policies", "ant=zoo:ant", "spider=zoo:spider",
               "--epochs", "3", "--n-envs", "2", "--steps-per-epoch", "20", "--baselines", "passive",
               "--out", str(out), "--no-progress"])
    printed = capsys.readouterr().out
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary["candidates"]) == ["trained", "passive"]
    lines = printed.splitlines()
    assert "test MWR" in lines[0]
    for line, (label, c) in zip(lines[1:3], summary["candidates"].items(), strict=True):
        assert line.split()[0] == label
        assert f"{c['mean_lwr']:+.3f}" in line
    assert f"report: {out}/summary.json" in printed


# ----------------------------------------------------------------------------- play
def test_play_records_a_decodable_video_of_every_step(zoo: TinyZoo, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    video = tmp_path / "m.mp4"
    rc = main(["play", "--policies", "ant=zoo:ant", "spider=random", "--seed", "3", "--video", str(video),
               "--width", "64", "--height", "64", "--max-steps", "60"])
    printed = capsys.readouterr().out
    assert rc == 0
    steps = int(re.search(r"match seed 3: (\d+) steps", printed).group(1))
    assert 1 <= steps <= 60
    assert count_frames(video) == steps + 1
    assert f"video: {video} ({steps + 1} frames)" in printed


def test_play_with_an_unknown_policy_fails_with_exit_code_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["play", "--policies", "ant=nonsense"]) == 2
    assert "'nonsense'" in capsys.readouterr().err


# ---------------------------------------------------------------- the Gymnasium id
def test_paper_env_drives_ant_and_spider_with_the_zoo_and_passes_check_env(zoo: TinyZoo) -> None:
    env = gym.make("TripleSumo-Paper-v2")
    try:
        base = env.unwrapped
        match = base.match
        env.reset(seed=0)
        obs = match.observer.build()  # every agent's observation before the step
        env.step(np.zeros(8, dtype=np.float32))
        ctrl = base.data.ctrl
        for agent in ("ant", "spider"):
            i = match.agents.index(agent)
            policy, _ = load_policy(zoo.zoo_dir / agent)
            action = np.clip(np.asarray(policy(obs[i]), dtype=np.float64), -1.0, 1.0)
            low, high = match.sim.ctrl_low[i], match.sim.ctrl_high[i]
            expected = (high + low) / 2 + action * (high - low) / 2
            ids = match.sim.actuator_ids[i]
            assert np.abs(ctrl[ids]).sum() > 0, agent
            np.testing.assert_allclose(ctrl[ids], expected, rtol=1e-6, atol=1e-9, err_msg=agent)
        assert not ctrl[match.sim.actuator_ids[match.agents.index("bug")]].any()
        check_env(base, skip_render_check=True)
    finally:
        env.close()


def test_the_demo_films_the_first_long_win_else_the_longest_win_else_the_longest_match(tmp_path: Path) -> None:
    rows = [("loss", 300), ("win", 40), ("win", 150), ("win", 400), ("draw", 500)]
    path = tmp_path / "metrics.csv"

    def write(outcomes: list[tuple[str, int]]) -> None:
        path.write_text("epoch,outcome,steps\n" + "".join(f"{i},{o},{n}\n" for i, (o, n) in enumerate(outcomes, 1)))

    write(rows)
    assert match_to_record(path, 10_000) == (10_002, "the first test match the team won in at least 100 steps: "
                                                     "test match 3, win after 150 steps")
    write(rows[:2])
    assert match_to_record(path, 10_000)[0] == 10_001  # a short win beats no win
    write([("loss", 30), ("draw", 500), ("loss", 80)])
    seed, why = match_to_record(path, 5)
    assert seed == 6 and why.startswith("the longest test match (the team won none)")
    write([])
    with pytest.raises(ValueError, match="no test matches"):
        match_to_record(path, 5)
