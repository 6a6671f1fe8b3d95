"""``triplesumo evaluate`` on a tiny budget: test epochs, their rows, the report and its plots.

The shipped zoo may be empty, so the module trains its own tiny zoo first (Ant and
Spider, 2 epochs of 20 steps with 16-unit networks) and a tiny Bug policy file, and
points :data:`triplesumo.agents.zoo.ZOO_DIR` at it where a test resolves ``zoo:NAME``.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import math
import shutil
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

import triplesumo.agents.zoo
from conftest import TinyZoo, small_disk
from triplesumo.agents.builtin import RandomPolicy, ZeroPolicy
from triplesumo.agents.policy_file import load_policy
from triplesumo.evaluation.evaluate import (
    EvaluateConfig,
    RowAppender,
    _label,
    add_paired,
    evaluate,
    finished_rows,
    format_summary,
    play_candidates_on,
    play_test_epochs,
)
from triplesumo.evaluation.metrics import OUTCOMES, summarize
from triplesumo.evaluation.parallel import ProcessRunner
from triplesumo.evaluation.runner import play_match
from triplesumo.model.specs import V0_PHYSICS, V1_PHYSICS
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.rewards import DENSE_TERMS
from triplesumo.train.logger import COLUMNS

LWR = {"win": 1.0, "loss": -1.0, "draw": 0.0, "error": 0.0}
STEPS = 30
"""Step limit of the test matches here."""
PNG = b"\x89PNG\r\n\x1a\n"




def fixed_others(zoo_dir: Path) -> dict[str, Any]:
    return {name: load_policy(zoo_dir / name, expect_obs_mode="paper")[0] for name in ("ant", "spider")}


def play(learner_policy: Any, others: dict[str, Any], epochs: int, n_envs: int, seed: int = 100) -> list[dict]:
    return play_test_epochs(learner_policy, others, "bug", epochs, seed, MatchConfig(max_steps=STEPS),
                            n_envs=n_envs, n_threads=1)


class Recorder:
    """Wraps a per-observation policy and keeps every observation it is asked about."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.seen: list[np.ndarray] = []

    def __deepcopy__(self, memo: dict) -> Recorder:
        # play_test_epochs copies stateful policies per match slot; the copies share `seen`.
        twin = Recorder(copy.deepcopy(self.inner, memo))
        twin.seen = self.seen
        return twin

    def reset(self, seed: int | None = None) -> None:
        reset = getattr(self.inner, "reset", None)
        if callable(reset):
            reset(seed=seed)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self.seen.append(np.array(obs, copy=True))
        return self.inner(obs)


# ----------------------------------------------------------------- play_test_epochs
@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_rows_are_one_per_epoch_in_order_with_the_metrics_schema(tiny_zoo: TinyZoo, tmp_path: Path) -> None:
    bug = load_policy(tiny_zoo.bug_policy)[0]
    rows = play(bug, fixed_others(tiny_zoo.zoo_dir), epochs=5, n_envs=2)
    assert [r["epoch"] for r in rows] == [1, 2, 3, 4, 5]
    for r in rows:
        assert set(r) == set(COLUMNS)
        assert r["outcome"] in OUTCOMES
        assert r["local_winning_rate"] == LWR[r["outcome"]]
        assert 1 <= r["steps"] <= STEPS
        if r["outcome"] == "draw":
            assert r["steps"] == STEPS
        assert r["total_reward"] == pytest.approx(r["dense_reward"] + r["sparse_reward"])
        assert r["dense_reward"] == pytest.approx(sum(r[t] for t in DENSE_TERMS))
        assert r["sparse_reward"] == pytest.approx(r["reward_outcome"])
    # Seeded reset noise: the test matches differ from each other.
    assert len({round(r["total_reward"], 9) for r in rows}) > 1
    with RowAppender(tmp_path / "m.csv", fresh=True) as append:
        for r in rows:
            append(r)
    with (tmp_path / "m.csv").open(newline="") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames or ()) == COLUMNS
        assert [int(r["epoch"]) for r in reader] == [1, 2, 3, 4, 5]
    assert finished_rows(tmp_path / "m.csv", 5) == 5


class PerRow:
    """A trained actor asked one observation at a time (``act_batch`` then calls it per row)."""

    def __init__(self, actor: Any) -> None:
        self.actor = actor

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.asarray(self.actor(obs[None]))[0]


def test_rows_are_exactly_independent_of_n_envs_for_per_row_policies(tiny_zoo: TinyZoo) -> None:
    """Epoch i is seeded ``seed + i`` whichever slot plays it: n_envs changes nothing."""
    bug = PerRow(load_policy(tiny_zoo.bug_policy)[0])
    others = {a: PerRow(p) for a, p in fixed_others(tiny_zoo.zoo_dir).items()}
    one = play(bug, others, epochs=4, n_envs=1)
    assert play(bug, others, epochs=4, n_envs=3) == one
    assert play(ZeroPolicy(), others, epochs=4, n_envs=1) == play(ZeroPolicy(), others, epochs=4, n_envs=3)


def test_trained_actors_and_random_policies_give_the_same_epochs_for_any_n_envs(tiny_zoo: TinyZoo) -> None:
    """Policies act one observation at a time and stateful ones are re-seeded per test epoch,
    so a test epoch's result depends on its seed only, never on how many matches run at once."""
    bug = load_policy(tiny_zoo.bug_policy)[0]
    others = fixed_others(tiny_zoo.zoo_dir)
    three = play(bug, others, epochs=4, n_envs=3)
    assert play(bug, others, epochs=4, n_envs=3) == three
    assert play(bug, others, epochs=4, n_envs=1) == three
    random_others = {**others, "spider": RandomPolicy(5)}
    assert play(bug, random_others, epochs=4, n_envs=1) == play(bug, random_others, epochs=4, n_envs=3)


class ThreadCounter:
    """A passive policy that notes torch's intra-op thread count at each call."""

    def __init__(self) -> None:
        self.seen: set[int] = set()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        self.seen.add(torch.get_num_threads())
        return np.zeros(8, np.float32)


def test_policies_play_on_one_torch_thread_with_the_same_rows_and_the_setting_restored(tiny_zoo: TinyZoo) -> None:
    """One-observation calls are not worth splitting: the runner plays them on one torch thread (also from two
    threads of a process at once), gives the rows of torch's other settings, and hands the setting back."""
    bug = load_policy(tiny_zoo.bug_policy)[0]
    others = fixed_others(tiny_zoo.zoo_dir)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = play(bug, others, epochs=4, n_envs=2)
        torch.set_num_threads(3)
        counter = ThreadCounter()
        assert play(bug, {**others, "spider": counter}, epochs=2, n_envs=2)
        assert counter.seen == {1}
        assert torch.get_num_threads() == 3
        assert play(bug, others, epochs=4, n_envs=2) == one
        assert torch.get_num_threads() == 3
        with ThreadPoolExecutor(2) as pool:  # two runs in one process share the setting and restore it once
            runs = list(pool.map(lambda _: play(bug, {**others, "spider": counter}, epochs=3, n_envs=2), range(2)))
        assert runs[0] == runs[1] and counter.seen == {1}
        assert torch.get_num_threads() == 3
        record = play_match({"bug": counter}, seed=5, config=MatchConfig(max_steps=STEPS))
        assert record.steps > 0 and counter.seen == {1} and torch.get_num_threads() == 3
    finally:
        torch.set_num_threads(before)


def test_a_random_learner_is_reseeded_so_runs_repeat(tiny_zoo: TinyZoo) -> None:
    others = fixed_others(tiny_zoo.zoo_dir)
    # Differently constructed random policies: play_test_epochs re-seeds them from its seed.
    a = play(RandomPolicy(1), others, epochs=3, n_envs=2)
    b = play(RandomPolicy(2), others, epochs=3, n_envs=2)
    assert a == b
    assert play(RandomPolicy(1), others, epochs=3, n_envs=2, seed=101) != a


def test_every_candidate_meets_the_same_starts(tiny_zoo: TinyZoo) -> None:
    """Epoch i starts from the reset seeded ``seed + i`` whatever the learner does (a paired comparison)."""
    others = fixed_others(tiny_zoo.zoo_dir)

    def starts(policy: Any, seed: int) -> list[np.ndarray]:
        rec = Recorder(policy)
        rows = play(rec, others, epochs=3, n_envs=1, seed=seed)
        first = np.cumsum([0] + [r["steps"] for r in rows[:-1]])
        assert len(rec.seen) == sum(r["steps"] for r in rows)
        return [rec.seen[i] for i in first]

    passive, random = starts(ZeroPolicy(), 200), starts(RandomPolicy(0), 200)
    for p, r in zip(passive, random, strict=True):
        np.testing.assert_array_equal(p, r)
    assert not np.array_equal(passive[0], passive[1])  # epochs differ from each other
    assert not np.array_equal(starts(ZeroPolicy(), 300)[0], passive[0])  # and with the seed


def test_an_unknown_learner_is_rejected() -> None:
    with pytest.raises(ValueError, match="learner must be one of"):
        play_test_epochs(ZeroPolicy(), {}, "cat", 1, 0, MatchConfig(max_steps=5), n_envs=1)


# ------------------------------------------------------------------------ evaluate
@pytest.fixture(scope="module")
def report(tiny_zoo: TinyZoo, tmp_path_factory: pytest.TempPathFactory) -> tuple[EvaluateConfig, dict[str, Any]]:
    out = tmp_path_factory.mktemp("evaluation")
    cfg = EvaluateConfig(policy=(str(tiny_zoo.bug_policy),), policies=("ant=zoo:ant", "spider=zoo:spider"), epochs=6,
                         n_envs=2, steps_per_epoch=STEPS, out=str(out), progress=False)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
        summary = evaluate(cfg)
    return cfg, summary


@pytest.mark.slow  # 6 s alone on the shared 2-core box
def test_evaluate_writes_summary_json_with_counts_and_intervals(report: tuple[EvaluateConfig, dict]) -> None:
    cfg, summary = report
    saved = json.loads((Path(cfg.out) / "summary.json").read_text())
    assert saved["candidates"] == summary["candidates"]
    assert saved["config"]["epochs"] == 6
    cands = saved["candidates"]
    assert list(cands) == ["trained", "passive", "random"]
    assert cands["trained"]["policy"] == cfg.policy[0]
    for label, c in cands.items():
        assert c["n"] == 6, label
        assert c["n_win"] + c["n_loss"] + c["n_draw"] + c["n_error"] == c["n"]
        for kind in ("win", "loss", "draw"):
            lo, rate, hi = c[f"{kind}_rate_lo"], c[f"{kind}_rate"], c[f"{kind}_rate_hi"]
            assert rate == pytest.approx(c[f"n_{kind}"] / c["n"])
            assert 0.0 <= lo <= rate <= hi <= 1.0, (label, kind)
        assert c["mean_lwr"] == pytest.approx((c["n_win"] - c["n_loss"]) / c["n"])
        assert c["mean_lwr_lo"] <= c["mean_lwr"] <= c["mean_lwr_hi"]
        assert c["mean_steps_to_win"] is None or 1 <= c["mean_steps_to_win"] <= STEPS
        for key in ("mean_total_reward", "mean_dense_reward", "mean_sparse_reward"):
            assert math.isfinite(c[key])
        assert c["mean_total_reward"] == pytest.approx(c["mean_dense_reward"] + c["mean_sparse_reward"])


@pytest.mark.slow  # uses the module's report fixture, 10 s to build
def test_evaluate_writes_metrics_csv_and_plots_per_candidate(report: tuple[EvaluateConfig, dict]) -> None:
    cfg, summary = report
    out = Path(cfg.out)
    for name in ("compare_mwr.png", "compare_rewards.png"):
        assert (out / name).read_bytes()[:8] == PNG, name
    for label, c in summary["candidates"].items():
        with (out / label / "metrics.csv").open(newline="") as fh:
            reader = csv.DictReader(fh)
            assert tuple(reader.fieldnames or ()) == COLUMNS
            rows = list(reader)
        assert [int(r["epoch"]) for r in rows] == list(range(1, 7))
        outcomes = [r["outcome"] for r in rows]
        assert [outcomes.count(k) for k in OUTCOMES] == [c[f"n_{k}"] for k in OUTCOMES], label
        assert np.mean([float(r["total_reward"]) for r in rows]) == pytest.approx(c["mean_total_reward"])
        pngs = sorted(p.name for p in (out / label / "plots").glob("*.png"))
        assert pngs == ["mwr.png", "reward_terms.png", "rewards.png", "steps_to_win.png"], label
        assert all((out / label / "plots" / p).read_bytes()[:8] == PNG for p in pngs)


@pytest.mark.slow  # uses the module's report fixture, 10 s to build
def test_the_baselines_play_the_same_matches_as_direct_calls(report: tuple[EvaluateConfig, dict],
                                                              tiny_zoo: TinyZoo) -> None:
    """The passive baseline's CSV is what play_test_epochs gives for the config's seed."""
    cfg, _ = report
    rows = play_test_epochs(ZeroPolicy(), fixed_others(tiny_zoo.zoo_dir), "bug", cfg.epochs, cfg.seed,
                            MatchConfig(max_steps=STEPS), n_envs=3, n_threads=1)
    with (Path(cfg.out) / "passive" / "metrics.csv").open(newline="") as fh:
        saved = list(csv.DictReader(fh))
    assert [r["outcome"] for r in saved] == [r["outcome"] for r in rows]
    assert [int(r["steps"]) for r in saved] == [r["steps"] for r in rows]
    assert [float(r["total_reward"]) for r in saved] == pytest.approx([r["total_reward"] for r in rows])


def test_play_test_epochs_from_a_later_epoch_gives_the_tail_of_the_full_run(tiny_zoo: TinyZoo) -> None:
    others = fixed_others(tiny_zoo.zoo_dir)
    full = play(ZeroPolicy(), others, epochs=5, n_envs=2)
    handed: list[dict] = []
    tail = play_test_epochs(ZeroPolicy(), others, "bug", 5, 100, MatchConfig(max_steps=STEPS), n_envs=3,
                            n_threads=1, first=2, on_row=handed.append)
    assert tail == full[2:]
    assert handed == tail  # on_row sees every row once, in epoch order
    with pytest.raises(ValueError, match="first"):
        play_test_epochs(ZeroPolicy(), others, "bug", 5, 100, MatchConfig(max_steps=STEPS), first=5)


def _kill_midway(folder: Path, keep: int) -> None:
    """What a kill leaves: each candidate's CSV cut after ``keep`` rows, plus half a line."""
    for path in folder.glob("*/metrics.csv"):
        lines = path.read_text().splitlines(keepends=True)
        path.write_text("".join(lines[:1 + keep]) + lines[1 + keep][:7])
    (folder / "summary.json").unlink()


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_a_killed_evaluation_resumes_to_exactly_the_uninterrupted_rows(
        report: tuple[EvaluateConfig, dict], tiny_zoo: TinyZoo, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    cfg, summary = report
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
    folder = tmp_path / "killed"
    shutil.copytree(cfg.out, folder)
    _kill_midway(folder, keep=2)
    assert finished_rows(folder / "passive" / "metrics.csv", cfg.epochs) == 2  # the half line is cut off
    resumed = evaluate(dataclasses.replace(cfg, out=str(folder), resume=True, n_envs=3))
    assert resumed["candidates"] == summary["candidates"]
    for label in summary["candidates"]:
        assert (folder / label / "metrics.csv").read_bytes() == (Path(cfg.out) / label / "metrics.csv").read_bytes()


@pytest.mark.slow  # 13 s alone on the shared 2-core box
def test_an_evaluation_killed_before_its_first_row_resumes_as_a_fresh_start(
        report: tuple[EvaluateConfig, dict], tiny_zoo: TinyZoo, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 39, item 16: a kill before the first row leaves a 0-byte metrics CSV (or one torn inside its
    header) and maybe a 0-byte record; --resume, which refused them, plays them as a fresh start."""
    cfg, summary = report
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
    folder = tmp_path / "killed"
    shutil.copytree(cfg.out, folder)
    (folder / "passive" / "metrics.csv").write_bytes(b"")
    (folder / "random" / "metrics.csv").write_text("epoch,outc")
    resumed = evaluate(dataclasses.replace(cfg, out=str(folder), resume=True))
    assert resumed["candidates"] == summary["candidates"]
    for label in summary["candidates"]:
        assert (folder / label / "metrics.csv").read_bytes() == (Path(cfg.out) / label / "metrics.csv").read_bytes()
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    (fresh / "evaluation.json").write_bytes(b"")
    again = evaluate(dataclasses.replace(cfg, out=str(fresh), resume=True))
    assert again["candidates"] == summary["candidates"]


@pytest.mark.slow  # 6 s alone on the shared 2-core box
def test_resume_extends_a_finished_evaluation_to_more_epochs(
        report: tuple[EvaluateConfig, dict], tiny_zoo: TinyZoo, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    cfg, _ = report
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
    folder = tmp_path / "longer"
    shutil.copytree(cfg.out, folder)
    longer = evaluate(dataclasses.replace(cfg, out=str(folder), resume=True, epochs=cfg.epochs + 2))
    assert longer["candidates"]["passive"]["n"] == cfg.epochs + 2
    with (folder / "passive" / "metrics.csv").open(newline="") as fh:
        outcomes = [r["outcome"] for r in csv.DictReader(fh)]
    direct = play(ZeroPolicy(), fixed_others(tiny_zoo.zoo_dir), epochs=cfg.epochs + 2, n_envs=2, seed=cfg.seed)
    assert outcomes == [r["outcome"] for r in direct]
    with pytest.raises(ValueError, match="more than epochs"):
        evaluate(dataclasses.replace(cfg, out=str(folder), resume=True))


@pytest.mark.slow  # 50 s alone on the shared 2-core box
def test_workers_write_the_bytes_of_one_process_and_resume(tiny_zoo: TinyZoo, tmp_path: Path) -> None:
    # policy files, not zoo names: the worker processes do not see a monkeypatched ZOO_DIR
    others = (f"ant={tiny_zoo.zoo_dir / 'ant'}", f"spider={tiny_zoo.zoo_dir / 'spider'}")
    base = EvaluateConfig(policy=(str(tiny_zoo.bug_policy),), policies=others, epochs=5, n_envs=2,
                          steps_per_epoch=STEPS, progress=False, ray_chunk=2)
    one = evaluate(dataclasses.replace(base, out=str(tmp_path / "one")))
    spread = dataclasses.replace(base, out=str(tmp_path / "workers"), workers=3)
    evaluate(dataclasses.replace(spread, epochs=3))  # a first part, as if stopped after 3 epochs
    resumed = evaluate(dataclasses.replace(spread, resume=True))
    assert resumed["candidates"] == one["candidates"]
    assert set(one["candidates"]) == {"trained", "passive", "random"}
    for label in one["candidates"]:
        got = (tmp_path / "workers" / label / "metrics.csv").read_bytes()
        assert got == (tmp_path / "one" / label / "metrics.csv").read_bytes()
        assert got.count(b"\n") == 6


@pytest.mark.slow  # 25 s alone on the shared 2-core box
def test_candidates_on_worker_processes_hand_on_each_ones_rows_in_order_and_raise_a_tasks_error(
        tiny_zoo: TinyZoo, tmp_path: Path) -> None:
    others = {"ant": str(tiny_zoo.zoo_dir / "ant"), "spider": str(tiny_zoo.zoo_dir / "spider")}
    seen: list[tuple[str, int]] = []
    rows = play_candidates_on(ProcessRunner(2), {"z": "zero", "r": "random"}, others, "bug", 7, 100,
                              MatchConfig(max_steps=STEPS), firsts={"r": 2}, chunk=2, n_envs=2,
                              on_row=lambda label, row: seen.append((label, row["epoch"])))
    assert [e for label, e in seen if label == "z"] == [1, 2, 3, 4, 5, 6, 7]
    assert [e for label, e in seen if label == "r"] == [3, 4, 5, 6, 7]  # from firsts["r"] on
    assert [r["epoch"] for r in rows["r"]] == [3, 4, 5, 6, 7]
    with pytest.raises(Exception, match="nowhere"):
        play_candidates_on(ProcessRunner(2), {"z": "zero", "x": str(tmp_path / "nowhere" / "bug")}, others, "bug",
                           4, 100, MatchConfig(max_steps=STEPS), chunk=2, n_envs=2)


def test_resume_refuses_what_would_change_the_rows(
        report: tuple[EvaluateConfig, dict], tiny_zoo: TinyZoo, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    cfg, _ = report
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
    with pytest.raises(ValueError, match="seed was 10000, now 7"):
        evaluate(dataclasses.replace(cfg, resume=True, seed=7))
    with pytest.raises(ValueError, match="candidate 'trained'"):
        evaluate(dataclasses.replace(cfg, resume=True, policy=("zoo:bug",)))
    with pytest.raises(ValueError, match="the policy was trained on another ring"):  # the tiny zoo's is v2's
        evaluate(dataclasses.replace(cfg, resume=True, physics=V1_PHYSICS))
    with pytest.raises(ValueError, match="physics was .*'border_rim': True.*, now None"):  # the v0 ring
        evaluate(dataclasses.replace(cfg, resume=True, physics=V0_PHYSICS, allow_other_ring=True))
    with pytest.raises(ValueError, match="physics was .*'layout': 'fair'.*, now .*'layout': 'circle'"):  # v1's
        evaluate(dataclasses.replace(cfg, resume=True, physics=V1_PHYSICS, allow_other_ring=True))
    # The same path, other contents: the policy file was retrained in place.
    stem = tmp_path / "bug"
    for suffix in (".json", ".safetensors"):
        shutil.copy(tiny_zoo.bug_policy.with_suffix(suffix), stem.with_suffix(suffix))
    small = dataclasses.replace(cfg, policy=(str(stem),), baselines=(), epochs=2, out=str(tmp_path / "e"))
    evaluate(small)
    manifest = json.loads(stem.with_suffix(".json").read_text())
    stem.with_suffix(".json").write_text(json.dumps({**manifest, "note": "retrained"}))
    with pytest.raises(ValueError, match="files changed"):
        evaluate(dataclasses.replace(small, resume=True))
    with pytest.raises(FileNotFoundError, match="nothing to resume"):
        evaluate(dataclasses.replace(small, resume=True, out=str(tmp_path / "empty")))
    (tmp_path / "e" / "evaluation.json").write_text("{not json")
    with pytest.raises(ValueError, match="corrupt"):
        evaluate(dataclasses.replace(small, resume=True))


@pytest.mark.slow  # 14 s alone on the shared 2-core box
def test_a_resume_that_names_no_baselines_keeps_the_folders_own(
        report: tuple[EvaluateConfig, dict], tiny_zoo: TinyZoo, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Not given, the baselines are passive and random for a new folder, and those the folder played for a
    resume: a resume that adds a candidate does not start playing baselines a folder made without them."""
    import argparse

    from triplesumo import _dcargs

    cfg, _ = report
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
    parser = argparse.ArgumentParser()
    _dcargs.add_arguments(parser, EvaluateConfig)
    assert _dcargs.build(EvaluateConfig, parser.parse_args([])).baselines is None
    assert _dcargs.build(EvaluateConfig, parser.parse_args(["--baselines"])).baselines == ()
    assert _dcargs.build(EvaluateConfig, parser.parse_args(["--baselines", "passive"])).baselines == ("passive",)
    bare = dataclasses.replace(cfg, baselines=(), epochs=2, out=str(tmp_path / "bare"))
    assert list(evaluate(bare)["candidates"]) == ["trained"]
    grown = evaluate(dataclasses.replace(bare, baselines=None, compare=("zoo:bug",), resume=True))
    assert list(grown["candidates"]) == ["trained", "zoo-bug"]
    assert not (tmp_path / "bare" / "passive").exists() and not (tmp_path / "bare" / "random").exists()
    assert grown["config"]["baselines"] == ()
    folder = tmp_path / "full"
    shutil.copytree(cfg.out, folder)
    again = evaluate(dataclasses.replace(cfg, baselines=None, out=str(folder), resume=True))
    assert list(again["candidates"]) == ["trained", "passive", "random"]
    fresh = evaluate(dataclasses.replace(bare, baselines=None, out=str(tmp_path / "fresh")))
    assert list(fresh["candidates"]) == ["trained", "passive", "random"]


@pytest.mark.slow  # 23 s alone on the shared 2-core box
def test_a_resume_keeps_every_finished_candidate_its_folder_recorded(
        report: tuple[EvaluateConfig, dict], tiny_zoo: TinyZoo, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``--resume --compare NEW`` grows a folder by one candidate: the summary, per_seed.csv and the paired
    differences keep the finished candidates it does not name (their files may be gone); an unfinished one
    is finished when named again and left out when not."""
    cfg, summary = report
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
    folder = tmp_path / "grown"
    shutil.copytree(cfg.out, folder)
    grown = evaluate(dataclasses.replace(cfg, out=str(folder), resume=True, baselines=(), compare=("zoo:bug",)))
    assert list(grown["candidates"]) == ["trained", "passive", "random", "zoo-bug"]
    for label in ("trained", "passive", "random"):
        assert grown["candidates"][label] == summary["candidates"][label]
    assert grown["candidates"]["zoo-bug"]["paired"]["vs"] == "trained"
    assert tuple(grown["config"]["baselines"]) == ("passive", "random")
    with (folder / "per_seed.csv").open(newline="") as fh:
        assert [r["candidate"] for r in csv.DictReader(fh)] == ["trained", "passive", "random", "zoo-bug"]
    # killed while random was playing: named again it is finished, to the uninterrupted rows
    path = folder / "random" / "metrics.csv"
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(lines[:3]) + lines[3][:5])
    again = evaluate(dataclasses.replace(cfg, out=str(folder), resume=True, baselines=("random",)))
    assert path.read_bytes() == (Path(cfg.out) / "random" / "metrics.csv").read_bytes()
    assert again["candidates"]["random"] == summary["candidates"]["random"]
    assert list(again["candidates"]) == ["trained", "passive", "random", "zoo-bug"]
    # ... and not named, it is left out of the summary and the record
    path.write_text("".join(lines[:3]))
    dropped = evaluate(dataclasses.replace(cfg, out=str(folder), resume=True, baselines=()))
    assert list(dropped["candidates"]) == ["trained", "passive", "zoo-bug"]
    assert "random" not in json.loads((folder / "evaluation.json").read_text())["candidates"]
    # a finished candidate from a file needs the file no more
    stem = tmp_path / "other"
    for suffix in (".json", ".safetensors"):
        shutil.copy(tiny_zoo.bug_policy.with_suffix(suffix), stem.with_suffix(suffix))
    small = dataclasses.replace(cfg, baselines=(), compare=(str(stem),), epochs=2, out=str(tmp_path / "small"))
    first = evaluate(small)
    for suffix in (".json", ".safetensors"):
        stem.with_suffix(suffix).unlink()
    assert evaluate(dataclasses.replace(small, compare=(), resume=True))["candidates"] == first["candidates"]


@pytest.mark.slow  # 6 s alone on the shared 2-core box
def test_compare_takes_a_glob_of_snapshots_each_its_own_candidate(
        report: tuple[EvaluateConfig, dict], tiny_zoo: TinyZoo, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``--compare 'RUN/league/members/spider-*/spider'``: every snapshot a candidate, on the same starts."""
    cfg, summary = report
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
    for member in ("bug-0002", "bug-0001"):
        (tmp_path / member).mkdir()
        for suffix in (".json", ".safetensors"):
            shutil.copy(tiny_zoo.bug_policy.with_suffix(suffix), (tmp_path / member / "bug").with_suffix(suffix))
    glob = str(tmp_path / "bug-*" / "bug")
    got = evaluate(dataclasses.replace(cfg, baselines=(), compare=(glob,), out=str(tmp_path / "e")))
    labels = [_label(str(tmp_path / m / "bug")) for m in ("bug-0001", "bug-0002")]
    assert list(got["candidates"]) == ["trained", *labels]  # sorted, one per file
    for label in labels:  # the same file as the trained policy, on the same starts: the same rows
        assert got["candidates"][label]["paired"]["diff"] == 0.0
        assert got["candidates"][label]["n_win"] == summary["candidates"]["trained"]["n_win"]
    with pytest.raises(ValueError, match=r"EvaluateConfig\.compare: .* matches no policy file"):
        evaluate(dataclasses.replace(cfg, baselines=(), compare=(str(tmp_path / "none-*"),), out=str(tmp_path / "f")))
    # the same glob expanded by the shell names both files of each pair: refused, nothing played or written
    shell = tuple(str((tmp_path / "bug-0001" / "bug").with_suffix(x)) for x in (".json", ".safetensors"))
    with pytest.raises(ValueError, match=r"'.*bug-0001/bug\.json' and '.*bug-0001/bug\.safetensors' name one policy "
                                         r"file pair .*quote it"):
        evaluate(dataclasses.replace(cfg, baselines=(), compare=shell, out=str(tmp_path / "g")))
    assert not (tmp_path / "g").exists()


def test_finished_rows_rejects_files_that_are_not_evaluation_csvs(tmp_path: Path) -> None:
    path = tmp_path / "metrics.csv"
    path.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="not a metrics CSV"):
        finished_rows(path, 5)
    assert finished_rows(tmp_path / "missing.csv", 5) == 0


@pytest.mark.slow  # uses the module's report fixture, 10 s to build
def test_every_later_candidate_gets_its_paired_difference_from_the_first(report: tuple[EvaluateConfig, dict]) -> None:
    cfg, summary = report
    lwr = {}
    for label in summary["candidates"]:
        with (Path(cfg.out) / label / "metrics.csv").open(newline="") as fh:
            lwr[label] = np.array([LWR[r["outcome"]] for r in csv.DictReader(fh)])
    assert "paired" not in summary["candidates"]["trained"]
    for label in ("passive", "random"):
        paired = summary["candidates"][label]["paired"]
        assert paired["vs"] == "trained"
        assert paired["diff"] == pytest.approx(float(np.mean(lwr[label] - lwr["trained"])))
        assert paired["diff"] == pytest.approx(summary["candidates"][label]["mean_lwr"]
                                               - summary["candidates"]["trained"]["mean_lwr"])
        assert paired["lo"] <= paired["diff"] <= paired["hi"]  # 6 epochs: a defined interval
    assert "paired, minus trained" in format_summary(summary).splitlines()[0]


def test_pairing_separates_what_two_unpaired_intervals_leave_overlapping() -> None:
    """The same starts decide most of both candidates' results; one does one outcome better on 30 of them."""
    rng = np.random.default_rng(0)
    reference = rng.choice([-1.0, 0.0, 1.0], size=200)
    better = reference.copy()
    better[np.flatnonzero(reference < 1.0)[:30]] += 1.0
    summary: dict[str, Any] = {"candidates": {
        label: dict(summarize(["win" if v > 0 else "loss" if v < 0 else "draw" for v in x], np.full(200, 10.0)))
        for label, x in (("trained", reference), ("better", better))}}
    add_paired(summary, {"trained": reference, "better": better})
    c, r = summary["candidates"]["better"], summary["candidates"]["trained"]
    assert c["mean_lwr_lo"] < r["mean_lwr_hi"]  # unpaired: overlapping
    assert c["paired"]["diff"] == pytest.approx(0.15) and c["paired"]["lo"] > 0.0  # paired: separated
    with pytest.raises(ValueError, match="needs the same starts"):
        add_paired(summary, {"trained": reference, "better": better[:100]})


@pytest.mark.slow  # uses the module's report fixture, 10 s to build
def test_format_summary_has_a_header_and_one_line_per_candidate(report: tuple[EvaluateConfig, dict]) -> None:
    _, summary = report
    lines = format_summary(summary).splitlines()
    assert len(lines) == 1 + len(summary["candidates"])
    assert "test MWR" in lines[0]
    for line, (label, c) in zip(lines[1:], summary["candidates"].items(), strict=True):
        assert line.split()[0] == label
        assert f"{c['mean_lwr']:+.3f}" in line
        assert str(c["n"]) in line.split()


def test_format_summary_survives_an_undefined_interval() -> None:
    one = {"policy": "zero", "n": 1, "n_win": 1, "n_loss": 0, "n_draw": 0, "n_error": 0, "mean_lwr": 1.0,
           "mean_lwr_lo": None, "mean_lwr_hi": None, "mean_steps_to_win": 12.0}
    assert len(format_summary({"candidates": {"trained": one}}).splitlines()) == 2


# -------------------------------------------------------------------- validation
@pytest.mark.parametrize(("fields", "names"), [
    ({"epochs": 0}, r"EvaluateConfig\.epochs"),
    ({"epochs": True}, r"EvaluateConfig\.epochs"),
    ({"steps_per_epoch": 0}, r"EvaluateConfig\.steps_per_epoch"),
    ({"window": 0}, r"EvaluateConfig\.window"),
    ({"n_envs": -1}, r"EvaluateConfig\.n_envs"),
    ({"n_threads": 0}, r"EvaluateConfig\.n_threads"),
    ({"workers": 0}, r"EvaluateConfig\.workers"),
    ({"workers": 2, "ray": True}, r"EvaluateConfig\.workers and EvaluateConfig\.ray"),
    ({"policies": ("ant",)}, r"EvaluateConfig\.policies"),
    ({"policies": ("ant=",)}, r"EvaluateConfig\.policies"),
])
def test_config_errors_name_the_field(fields: dict[str, Any], names: str) -> None:
    with pytest.raises(ValueError, match=names):
        EvaluateConfig(**fields)


def test_the_learner_cannot_have_a_fixed_policy() -> None:
    with pytest.raises(ValueError, match=r"EvaluateConfig\.policies.*'bug'"):
        EvaluateConfig(policies=("ant=zoo:ant", "bug=random"))
    with pytest.raises(ValueError, match=r"EvaluateConfig\.policies.*'ant'"):
        EvaluateConfig(learner="ant", policies=("ant=random",))


def test_a_full_disk_while_writing_rows_names_the_table(tmp_path: Path) -> None:
    """Issue 39, item 16: a full disk during evaluate (or a tournament, the same row appender) was an OSError
    naming no file. On a real 16 KiB tmpfs the error names the metrics CSV, and the rows before it stay."""
    with small_disk(tmp_path / "small", "16k") as small:
        cfg = EvaluateConfig(policy=("passive",), policies=("ant=passive", "spider=passive"), baselines=(),
                             epochs=400, steps_per_epoch=2, n_envs=1, progress=False, out=str(small / "ev"))
        with pytest.raises(OSError, match=rf"{small / 'ev' / 'trained' / 'metrics.csv'}: a row was not written"):
            evaluate(cfg)
        assert (small / "ev" / "trained" / "metrics.csv").read_text().count("\n") > 10  # the rows before it


def test_plot_redraws_an_evaluation_folders_comparison_from_its_recorded_rows(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`triplesumo plot` on an evaluation folder (a committed one: packed tables, absolute policy paths) draws
    compare_mwr.png and compare_rewards.png from summary.json's candidates and their rows, named as evaluate names
    them, at the window it used; a damaged summary is named."""
    from triplesumo.cli import main
    from triplesumo.evaluation import plots
    from triplesumo.evaluation.evaluate import curve_name

    folder = tmp_path / "evaluation"
    source = Path(__file__).parents[1] / "docs/runs/scratch-v4/seed-1/evaluation"
    shutil.copytree(source, folder, ignore=shutil.ignore_patterns("*.png"))
    summary = json.loads((folder / "summary.json").read_text())
    seen: dict[str, Any] = {}
    real = plots.plot_comparison

    def spy(curves: dict[str, dict[str, np.ndarray]], out: Path, window: int = 200) -> list[Path]:
        seen.update(names=list(curves), rows={n: len(c["outcome"]) for n, c in curves.items()}, window=window)
        return real(curves, out, window=window)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plots, "plot_comparison", spy)
        assert main(["plot", str(folder)]) == 0
    assert seen["names"] == [curve_name("bug", label, c["policy"]) for label, c in summary["candidates"].items()]
    assert set(seen["rows"].values()) == {2000} and seen["window"] == summary["config"]["window"] == 200
    printed = capsys.readouterr().out.split()
    assert printed == [str(folder / "compare_mwr.png"), str(folder / "compare_rewards.png")]
    for name in ("compare_mwr.png", "compare_rewards.png"):
        assert (folder / name).read_bytes()[:8] == PNG, name

    (folder / "summary.json").write_text('{"candidates": {}}')
    assert main(["plot", str(folder)]) == 2
    assert f"{folder / 'summary.json'}: not an evaluation summary" in capsys.readouterr().err
