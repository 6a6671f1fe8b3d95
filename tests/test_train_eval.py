"""``TrainConfig.eval_every``: the learner's current policy evaluated on seeded test matches during training.

Each evaluation plays the policy a policy file written at that moment would hold, frozen, on the
same test matches as ``triplesumo evaluate``; the training itself is the same with or without
evaluations, a resumed run writes the evaluations an uninterrupted one writes, and a run with
several learners evaluates each against the others' current policies.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from conftest import TINY_DDPG, E, tiny
from triplesumo.agents.zoo import make_policy, policies_from_pairs
from triplesumo.evaluation.evaluate import play_test_epochs
from triplesumo.evaluation.metrics import summarize
from triplesumo.rules.scenarios import scenario_config
from triplesumo.train.config import TrainConfig
from triplesumo.train.evaluations import shares
from triplesumo.train.logger import EVAL_COLUMNS
from triplesumo.train.loop import train

EVERY = 40
"""Env steps between evaluations: 2 matches of 30 steps make 60 env steps per match length."""
TESTS = 4


def _evals(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _metrics(run: Path) -> list[dict[str, str]]:
    with (run / "metrics.csv").open(newline="") as fh:
        return [{k: v for k, v in row.items() if k != "wall_time"} for row in csv.DictReader(fh)]


@pytest.mark.slow  # 8 s alone on the shared 2-core box
def test_evaluations_leave_the_training_unchanged(tmp_path: Path) -> None:
    with_eval = train(tiny(tmp_path, "with", eval_every=EVERY, eval_epochs=TESTS))
    without = train(tiny(tmp_path, "without"))
    assert (with_eval.run_dir / "policy.safetensors").read_bytes() == (
        without.run_dir / "policy.safetensors").read_bytes()
    assert _metrics(with_eval.run_dir) == _metrics(without.run_dir)
    assert not (without.run_dir / "eval.csv").exists()

    rows = _evals(with_eval.run_dir / "eval.csv")
    assert tuple(rows[0]) == EVAL_COLUMNS
    assert len(rows) == with_eval.env_steps // EVERY >= 3  # one per multiple of EVERY crossed
    for k, row in enumerate(rows, 1):
        steps = int(row["env_steps"])
        assert row["evaluation"] == str(k)
        assert k * EVERY <= steps < k * EVERY + 2  # the step (of 2 matches) that crossed it
        assert int(row["n_win"]) + int(row["n_loss"]) + int(row["n_draw"]) == int(row["test_matches"]) == TESTS
        assert -1.0 <= float(row["test_mwr"]) <= 1.0
    seconds = [float(r["train_seconds"]) for r in rows]
    assert seconds == sorted(seconds) and seconds[0] > 0
    # inline, the policy is frozen, played and written at one moment of the training's clock
    assert [float(r["policy_train_seconds"]) for r in rows] == seconds
    # its figure against the paper's band, beside the training's; a run without evaluations has none
    assert (with_eval.run_dir / "plots" / "test_mwr.png").is_file()
    assert (without.run_dir / "plots" / "mwr.png").is_file()
    assert not (without.run_dir / "plots" / "test_mwr.png").exists()


def test_an_evaluation_plays_the_policy_file_on_the_evaluate_matches(tmp_path: Path) -> None:
    """With learning that never starts the policy stays what the policy file holds: every evaluation
    then equals ``play_test_epochs`` of that file on the same seeded matches."""
    cfg = tiny(tmp_path, "frozen", eval_every=EVERY, eval_epochs=TESTS, eval_seed=77,
               ddpg=dataclasses.replace(TINY_DDPG, learning_starts=10**6))
    result = train(cfg)
    rows = _evals(result.run_dir / "eval.csv")
    match_cfg = scenario_config("paper", max_steps=cfg.steps_per_epoch)
    others = policies_from_pairs(("spider=random", "ant=zero"), 77, "paper")
    played = play_test_epochs(make_policy(str(result.run_dir / "policy")), others, "bug", TESTS, 77, match_cfg, 2, 1)
    stats = summarize([r["outcome"] for r in played], [r["steps"] for r in played])
    assert len(rows) >= 2
    for row in rows:
        assert float(row["test_mwr"]) == pytest.approx(float(stats["mean_lwr"]), abs=1e-12)
        assert (int(row["n_win"]), int(row["n_loss"]), int(row["n_draw"])) == (
            stats["n_win"], stats["n_loss"], stats["n_draw"])


@pytest.mark.slow  # 14 s alone on the shared 2-core box
def test_a_resumed_run_writes_the_evaluations_of_an_uninterrupted_one(tmp_path: Path) -> None:
    whole = train(tiny(tmp_path, "whole", epochs=4 * E, eval_every=EVERY, eval_epochs=TESTS))
    cut = tiny(tmp_path, "cut", epochs=4 * E, eval_every=EVERY, eval_epochs=TESTS)
    first = train(dataclasses.replace(cut, epochs=2 * E))
    made = _evals(first.run_dir / "eval.csv")
    with (first.run_dir / "eval.csv").open("a") as fh:  # a row past the checkpoint (a kill after an evaluation)
        fh.write(",".join([str(len(made) + 1), *list(made[-1].values())[1:]]) + "\n")
    resumed = train(TrainConfig(), resume_dir=Path(cut.out) / cut.name, overrides={"epochs": 4 * E})
    measured = ("policy_train_seconds", "train_seconds", "eval_seconds")
    same = [{k: v for k, v in r.items() if k not in measured} for r in _evals(whole.run_dir / "eval.csv")]
    assert [{k: v for k, v in r.items() if k not in measured}
            for r in _evals(resumed.run_dir / "eval.csv")] == same
    seconds = [float(r["train_seconds"]) for r in _evals(resumed.run_dir / "eval.csv")]
    assert seconds == sorted(seconds)  # the training time goes on across the resume


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_each_of_several_learners_is_evaluated_against_the_others(tmp_path: Path) -> None:
    result = train(tiny(tmp_path, "two", learn=("ant=ddpg", "bug=ddpg"), policies=("spider=random",),
                        eval_every=EVERY, eval_epochs=TESTS))
    ant, bug = (_evals(result.run_dir / f"eval-{name}.csv") for name in ("ant", "bug"))
    assert len(ant) == len(bug) >= 3
    for a, b in zip(ant, bug, strict=True):
        assert a["env_steps"] == b["env_steps"]
        # Ant and Bug are one team on the same matches: the same outcomes
        assert (a["n_win"], a["n_loss"], a["n_draw"]) == (b["n_win"], b["n_loss"], b["n_draw"])
        assert np.isclose(float(a["test_mwr"]), float(b["test_mwr"]))
    assert all((result.run_dir / "plots" / name / "test_mwr.png").is_file() for name in ("ant", "bug"))


def test_a_run_stops_at_the_first_evaluation_at_its_target(tmp_path: Path) -> None:
    result = train(tiny(tmp_path, "target", epochs=100, eval_every=EVERY, eval_epochs=TESTS, eval_target=-1.0))
    rows = _evals(result.run_dir / "eval.csv")
    assert len(rows) == 1 and EVERY <= result.env_steps == int(rows[0]["env_steps"]) < EVERY + 2
    assert result.epochs < 100
    state = (result.run_dir / "checkpoints").glob("epoch-*/state.json")
    assert max(json.loads(p.read_text())["env_steps"] for p in state) == result.env_steps


@pytest.mark.parametrize(("fields", "message"), [
    ({"eval_every": -1}, "TrainConfig.eval_every must be an int >= 0"),
    ({"eval_epochs": 0}, "TrainConfig.eval_epochs must be an int >= 1"),
    ({"eval_every": 100, "self_play": True}, "a self-play run is rated by its league"),
    ({"eval_target": 0.2}, "eval_target stops at an evaluation: set eval_every too"),
    ({"eval_every": 100, "eval_target": 1.5}, r"TrainConfig.eval_target must be a test MWR in \[-1, 1\]"),
    ({"eval_every": 100, "eval_background": True, "eval_workers": 0}, "TrainConfig.eval_workers must be an int >= 1"),
    ({"eval_every": 100, "eval_workers": 2}, "eval_workers splits the background evaluations over processes: set "
                                             "eval_background too"),
])
def test_bad_evaluation_settings_name_the_field(tmp_path: Path, fields: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        tiny(tmp_path, **fields)


def _figures(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    """An evaluation's rows less the wall times (what depends on the machine and on where it played)."""
    return [{k: v for k, v in r.items() if k not in ("policy_train_seconds", "train_seconds", "eval_seconds")}
            for r in rows]


@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_background_evaluations_write_the_rows_of_inline_ones(tmp_path: Path) -> None:
    """In a worker process, or split over several, the evaluations play the same frozen policies on the same
    matches: the same rows (only the times differ), and the training is the same as without them."""
    inline = train(tiny(tmp_path, "inline", eval_every=EVERY, eval_epochs=TESTS))
    background = train(tiny(tmp_path, "background", eval_every=EVERY, eval_epochs=TESTS, eval_background=True))
    rows = _evals(background.run_dir / "eval.csv")
    assert len(rows) >= 3 and _figures(rows) == _figures(_evals(inline.run_dir / "eval.csv"))
    # split over three worker processes, each evaluation's matches in parts (eval_workers): the same rows again
    split = train(tiny(tmp_path, "split", eval_every=EVERY, eval_epochs=TESTS, eval_background=True, eval_workers=3))
    assert _figures(_evals(split.run_dir / "eval.csv")) == _figures(rows)
    assert _metrics(background.run_dir) == _metrics(inline.run_dir)
    assert (background.run_dir / "policy.safetensors").read_bytes() == (
        inline.run_dir / "policy.safetensors").read_bytes()
    seconds = [float(r["train_seconds"]) for r in rows]
    assert seconds == sorted(seconds)
    # each row gives the training's clock when its policy was frozen, and (later or at once) when it was written
    frozen = [float(r["policy_train_seconds"]) for r in rows]
    assert frozen == sorted(frozen) and all(f <= s for f, s in zip(frozen, seconds, strict=True))
    last = sorted((background.run_dir / "checkpoints").glob("epoch-*"))[-1]
    assert json.loads((last / "state.json").read_text())["pending_evaluations"] == []  # the end waited for them
    import multiprocessing

    assert multiprocessing.active_children() == []  # and the worker is gone with the run


def test_an_evaluation_is_split_into_four_ordered_parts_per_worker_none_empty() -> None:
    assert shares(200, 1) == [(0, 200)]
    assert shares(200, 2) == [(0, 25), (25, 50), (50, 75), (75, 100), (100, 125), (125, 150), (150, 175), (175, 200)]
    assert shares(3, 8) == [(0, 1), (1, 2), (2, 3)]
    parts = shares(201, 5)
    assert len(parts) == 20 and parts[0][0] == 0 and parts[-1][1] == 201
    assert all(a < b for a, b in parts) and all(parts[k][1] == parts[k + 1][0] for k in range(19))


@pytest.mark.slow  # 11 s alone on the shared 2-core box
def test_an_evaluation_in_flight_at_a_checkpoint_is_played_by_the_resume(tmp_path: Path) -> None:
    """The first checkpoint comes milliseconds after the first evaluation went to the worker (which takes
    seconds to start): it holds that evaluation's frozen weights, and a resume from it writes the rows of the
    uninterrupted run."""
    cfg = tiny(tmp_path, "cut", eval_every=EVERY, eval_epochs=TESTS, eval_background=True)
    whole = train(cfg)
    first = whole.run_dir / "checkpoints" / f"epoch-{E:06d}"
    pending = json.loads((first / "state.json").read_text())["pending_evaluations"]
    assert [p["number"] for p in pending] == [1] and pending[0]["learners"]["bug"]["agents"] == ["bug"]
    made = _figures(_evals(whole.run_dir / "eval.csv"))
    resumed = train(TrainConfig(), resume_dir=whole.run_dir, from_checkpoint=first.name,
                    overrides={"eval_background": False})  # played by the worker all the same
    assert _figures(_evals(resumed.run_dir / "eval.csv")) == made
    # the checkpoint kept when that policy was frozen: the resume writes the same moment
    assert _evals(resumed.run_dir / "eval.csv")[0]["policy_train_seconds"] == (
        _evals(whole.run_dir / "eval.csv")[0]["policy_train_seconds"])


@pytest.mark.slow  # 7 s alone on the shared 2-core box
def test_a_run_from_before_policy_train_seconds_resumes_with_the_column(tmp_path: Path) -> None:
    """An eval CSV written before ``policy_train_seconds`` existed: a resume adds the column, empty in the old
    rows (their policy's moment was not recorded), filled in the new ones."""
    cut = tiny(tmp_path, "old", epochs=4 * E, eval_every=EVERY, eval_epochs=TESTS)
    first = train(dataclasses.replace(cut, epochs=2 * E))
    path = first.run_dir / "eval.csv"
    made = _evals(path)
    old = [c for c in EVAL_COLUMNS if c != "policy_train_seconds"]
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, old, extrasaction="ignore", lineterminator="\n")
        writer.writeheader()
        writer.writerows(made)
    resumed = train(TrainConfig(), resume_dir=first.run_dir, overrides={"epochs": 4 * E})
    rows = _evals(resumed.run_dir / "eval.csv")
    assert tuple(rows[0]) == EVAL_COLUMNS and len(rows) > len(made) >= 2
    assert [{k: v for k, v in r.items() if k != "policy_train_seconds"} for r in rows[:len(made)]] == [
        {k: v for k, v in r.items() if k != "policy_train_seconds"} for r in made]
    assert [r["policy_train_seconds"] for r in rows[:len(made)]] == [""] * len(made)
    assert all(float(r["policy_train_seconds"]) == float(r["train_seconds"]) for r in rows[len(made):])
