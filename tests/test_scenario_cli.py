"""The rest of the project follows the scenarios: play, evaluate, the trainer and bench env take ``--scenario``."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import pytest

from triplesumo.agents.zoo import expand_pairs
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.benchmarks.env import run_env_benchmark
from triplesumo.cli import main
from triplesumo.evaluation.evaluate import EvaluateConfig
from triplesumo.evaluation.play import PlayConfig, run_play
from triplesumo.train.config import TrainConfig
from triplesumo.train.loop import Trainer


def test_wildcard_pairs_expand_in_roster_order() -> None:
    assert expand_pairs(("*=random",), ("ant", "bug", "spider")) == ("ant=random", "bug=random", "spider=random")
    assert expand_pairs(("bug=zoo:bug", "*=zero"), ("ant", "bug", "spider")) == ("bug=zoo:bug", "ant=zero",
                                                                                  "spider=zero")


def test_play_a_pursuit_match_records_places() -> None:
    record = run_play(PlayConfig(scenario="pursuit", seed=1, max_steps=60))
    assert set(record.outcomes) == {"pursuer_0", "pursuer_1", "pursuer_2", "evader"}
    assert set(record.places.values()) <= {1, 2} and 1 in record.places.values()
    winners = {a for a, o in record.outcomes.items() if o == "win"}
    assert winners == {a for a, p in record.places.items() if p == 1}


def test_play_names_a_policy_that_does_not_fit_the_roster(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["play", "--scenario", "2v2", "--policies", "ant=zoo:ant", "--max-steps", "5"]) == 2
    err = capsys.readouterr().err
    assert "scenario '2v2'" in err and "'ant'" in err and "222" in err and "296" in err
    assert main(["play", "--scenario", "ffa", "--policies", "pursuer_0=random", "--max-steps", "5"]) == 2
    assert "unknown agent" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown scenario 'sumo'"):
        PlayConfig(scenario="sumo")


def test_evaluate_and_train_configs_check_the_scenario() -> None:
    with pytest.raises(ValueError, match="learner must be one of .*evader.*scenario 'pursuit'"):
        EvaluateConfig(scenario="pursuit", policies=("*=random",))
    EvaluateConfig(scenario="pursuit", learner="evader", policies=("*=random",))
    with pytest.raises(ValueError, match="TrainConfig.scenario must be one of"):
        TrainConfig(scenario="sumo")


def test_trainer_ends_the_learners_epoch_when_it_is_eliminated(tmp_path: Path) -> None:
    tiny = DDPGConfig(hidden=(8, 8), buffer_size=200, learning_starts=1000, batch_size=4)
    cfg = TrainConfig(out=str(tmp_path), name="ffa", scenario="ffa", learn=("bug=ddpg",), policies=("*=random",),
                      epochs=1, steps_per_epoch=50, n_envs=2, ddpg=tiny, progress=False, tensorboard=False)
    trainer = Trainer(cfg)
    assert trainer.collector.batch.matches[0].config.rules == "elimination"
    match = trainer.collector.batch.matches[0]
    bug = match.sim.agents[match.agents.index("bug")]
    match.data.qpos[bug.root_qpos] = 2.6
    mujoco.mj_forward(match.model, match.data)
    trainer.collector.batch.reload(0)
    trainer.step()
    assert trainer.collector.epochs_done == 1
    assert match.steps == 0 and all(match.alive)  # reset for the next epoch
    replay = trainer.learners[0].replay  # type: ignore[attr-defined]
    assert len(replay) == 2
    assert replay.done[:2].tolist() == [1.0, 0.0]  # the eliminated learner's transition is terminal
    assert json.loads((tmp_path / "ffa" / "config.json").read_text())["scenario"] == "ffa"


@pytest.mark.parametrize("scenario", ["ffa", "pursuit"])
def test_bench_env_measures_a_scenario(scenario: str) -> None:
    result = run_env_benchmark(steps=6, n_matches=2, n_threads=1, rounds=1, chunk=3, scenario=scenario)
    assert result["setup"]["scenario"] == scenario
    assert all(rate > 0 for rate in result["rates"].values())


def test_a_policy_file_plays_only_the_seats_it_was_trained_for(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 39, item 16 S: play, evaluate and train seated a paper-observation policy in a seat it was not
    trained for (the tournament refused it), and took a manifest naming agent "zebra". One check now serves all."""
    import json
    import shutil

    from triplesumo.agents.zoo import ZOO_DIR
    from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate
    from triplesumo.train.config import TrainConfig
    from triplesumo.train.loop import Trainer

    assert main(["play", "--policies", "ant=zoo:spider", "--max-steps", "5"]) == 2
    err = capsys.readouterr().err
    assert "policy 'zoo:spider'" in err and "cannot play 'ant'" in err and "spider.json" in err
    assert main(["play", "--policies", "ant=zoo:spider", "spider=zoo:ant", "--max-steps", "5"]) == 2
    assert "cannot play" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"policy 'zoo:spider' .*spider.json\) cannot play 'ant'"):
        evaluate(EvaluateConfig(learner="ant", policy=("zoo:spider",), policies=("spider=zoo:spider", "bug=passive"),
                                epochs=1, steps_per_epoch=5, n_envs=1, progress=False, out=str(tmp_path / "ev")))
    assert not (tmp_path / "ev" / "evaluation.json").exists()
    zebra = tmp_path / "zebra"
    shutil.copy(ZOO_DIR / "spider.safetensors", zebra.with_suffix(".safetensors"))
    manifest = json.loads((ZOO_DIR / "spider.json").read_text())
    zebra.with_suffix(".json").write_text(json.dumps({**manifest, "agent": "zebra"}))
    with pytest.raises(ValueError, match=r"zebra.json: agent 'zebra' is not in the roster it records"):
        Trainer(TrainConfig(out=str(tmp_path), name="t", policies=(f"spider={zebra}", "ant=passive")))
    assert main(["play", "--policies", "spider=zoo:spider", "ant=zoo:ant", "--max-steps", "3"]) == 0  # their seats
