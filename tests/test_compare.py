"""``triplesumo compare``: IQM, stratified bootstrap intervals, probability of improvement; and the
per-seed rows that ``evaluate`` writes for it over several policies."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rliable import metrics as rly_metrics

import triplesumo.agents.zoo
from conftest import TinyZoo
from triplesumo.cli import main
from triplesumo.evaluation.compare import (
    CompareConfig,
    _iqm_rows,
    _poi_rows,
    compare,
    format_compare,
    interval_estimates,
    iqm,
    probability_of_improvement,
    stratified_resamples,
)
from triplesumo.evaluation.evaluate import PER_SEED_COLUMNS, EvaluateConfig, evaluate

PNG = b"\x89PNG\r\n\x1a\n"


def col(values: list[float]) -> np.ndarray:
    return np.asarray(values, dtype=np.float64)[:, None]


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_the_cli_parser_loads_rliable_only_when_statistics_are_computed() -> None:
    """rliable imports scipy.stats (about a second): ``triplesumo --help``, ``train`` and ``play`` need neither,
    and a machine without them (a GPU box given only the simulation's packages) still runs them."""
    script = ("import sys; import triplesumo.cli as cli; cli._parser()\n"
              "print(sorted({m.split('.')[0] for m in sys.modules} & {'rliable', 'scipy'}))\n"
              "from triplesumo.evaluation.compare import iqm; import numpy as np\n"
              "print(iqm(np.arange(8.0).reshape(4, 2)), 'rliable' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, text=True).stdout.split("\n")
    assert out[0] == "[]", out
    assert out[1] == f"{rly_metrics.aggregate_iqm(np.arange(8.0).reshape(4, 2))} True", out


def test_iqm_of_a_known_array_is_the_mean_of_its_middle_half() -> None:
    assert iqm(col([1, 2, 3, 4, 5, 6, 7, 8])) == pytest.approx(4.5)  # mean of 3, 4, 5, 6
    assert iqm(col([0, 0, 1, 1, 1, 1, 100, -100])) == pytest.approx(0.75)  # outliers trimmed: 0, 1, 1, 1
    assert iqm(np.array([[1.0, 5.0], [2.0, 6.0], [3.0, 7.0], [4.0, 8.0]])) == pytest.approx(4.5)  # runs x tasks


def test_intervals_hold_the_estimate_and_narrow_with_more_seeds() -> None:
    rng = np.random.default_rng(3)
    few, many = col(list(rng.normal(0.2, 0.1, 5))), col(list(rng.normal(0.2, 0.1, 60)))
    est = interval_estimates({"few": few, "many": many}, reps=4000, seed=1)["groups"]
    for g, scores in (("few", few), ("many", many)):
        assert est[g]["lo"] <= est[g]["iqm"] <= est[g]["hi"]
        assert est[g]["iqm"] == pytest.approx(rly_metrics.aggregate_iqm(scores))
    assert est["many"]["hi"] - est["many"]["lo"] < 0.6 * (est["few"]["hi"] - est["few"]["lo"])
    assert est["many"]["lo"] < 0.2 < est["many"]["hi"]
    again = interval_estimates({"few": few, "many": many}, reps=4000, seed=1)["groups"]
    assert again == est  # seeded


def test_probability_of_improvement_is_one_for_separated_groups_and_a_half_for_identical_ones() -> None:
    good, bad = col([0.5, 0.6, 0.55, 0.7, 0.65]), col([-0.2, -0.1, 0.0, -0.3, -0.15])
    assert probability_of_improvement(good, bad) == 1.0
    assert probability_of_improvement(bad, good) == 0.0
    assert probability_of_improvement(good, good.copy()) == 0.5
    pairs = interval_estimates({"good": good, "bad": bad, "same": good.copy()}, reps=2000, seed=0)["pairs"]
    assert pairs[("good", "bad")] == {"poi": 1.0, "lo": 1.0, "hi": 1.0}
    same = pairs[("good", "same")]
    assert same["poi"] == 0.5 and same["lo"] < 0.5 < same["hi"]
    overlapping = interval_estimates({"a": col([0.1, 0.3, 0.5]), "b": col([0.2, 0.4, 0.6])}, reps=2000)["pairs"]
    assert overlapping[("a", "b")]["poi"] == pytest.approx(3 / 9)  # 0.3 > 0.2, 0.5 > 0.2, 0.5 > 0.4


def test_vectorised_bootstrap_statistics_are_rliables_functions_per_resample() -> None:
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(7, 2)), rng.normal(size=(4, 2)).round(1)
    xs, ys = stratified_resamples(x, 50, rng), stratified_resamples(y, 50, rng)
    np.testing.assert_allclose(_iqm_rows(xs), [rly_metrics.aggregate_iqm(s) for s in xs])
    np.testing.assert_allclose(_poi_rows(xs, ys), [rly_metrics.probability_of_improvement(a, b)
                                                   for a, b in zip(xs, ys, strict=True)])


def test_stratified_resamples_draw_runs_within_each_task() -> None:
    scores = np.array([[0.0, 100.0], [1.0, 101.0], [2.0, 102.0]])
    samples = stratified_resamples(scores, 500, np.random.default_rng(0))
    assert samples.shape == (500, 3, 2)
    assert set(np.unique(samples[:, :, 0])) == {0.0, 1.0, 2.0}
    assert set(np.unique(samples[:, :, 1])) == {100.0, 101.0, 102.0}


@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_bootstrap_agrees_with_rliable_library_where_it_imports() -> None:
    try:
        from rliable import library as rly
    except TypeError as exc:  # rliable 1.2 -> arch 7 -> pandas 3: `deprecate_kwarg` changed
        pytest.skip(f"rliable.library does not import here: {exc}")
    rng = np.random.default_rng(5)
    scores = {"a": rng.normal(0.3, 0.2, (10, 1)), "b": rng.normal(0.0, 0.2, (10, 1))}
    ours = interval_estimates(scores, reps=20_000, seed=0)["groups"]
    np.random.seed(0)  # noqa: NPY002  (rliable's bootstrap draws from numpy's global generator)
    points, intervals = rly.get_interval_estimates(scores, lambda s: np.array([rly_metrics.aggregate_iqm(s)]),
                                                   reps=20_000)
    for g in scores:
        assert ours[g]["iqm"] == pytest.approx(points[g][0])
        assert ours[g]["lo"] == pytest.approx(intervals[g][0, 0], abs=0.02)
        assert ours[g]["hi"] == pytest.approx(intervals[g][1, 0], abs=0.02)


# ------------------------------------------------------------------- end to end
@pytest.fixture
def seeds_eval(tiny_zoo: TinyZoo, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An evaluation of two 'seeds' (the tiny Bug and its published zoo copy) plus passive and random."""
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", tiny_zoo.zoo_dir)
    out = tmp_path / "eval"
    evaluate(EvaluateConfig(policy=(str(tiny_zoo.bug_policy), "zoo:bug"), epochs=4, steps_per_epoch=30,
                            out=str(out), n_envs=4, n_threads=1, progress=False))
    return out


def per_seed(folder: Path) -> list[dict[str, str]]:
    with (folder / "per_seed.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow  # 17 s alone on the shared 2-core box
def test_evaluate_writes_one_row_per_seed_and_compare_reads_them(seeds_eval: Path, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    rows = per_seed(seeds_eval)
    assert tuple(rows[0]) == PER_SEED_COLUMNS
    assert [r["group"] for r in rows] == ["trained", "trained", "passive", "random"]
    assert rows[1]["candidate"] == "trained-zoo-bug" and rows[1]["policy"] == "zoo:bug"
    assert [r["algo"] for r in rows] == ["ddpg", "ddpg", "passive", "random"]
    summary = json.loads((seeds_eval / "summary.json").read_text())
    for r in rows:
        c = summary["candidates"][r["candidate"]]
        assert float(r["test_mwr"]) == pytest.approx(c["mean_lwr"])
        assert int(r["n_win"]) + int(r["n_loss"]) + int(r["n_draw"]) <= int(r["epochs"]) == 4
    out = tmp_path / "cmp"
    # The folder twice: its evaluations are counted once.
    assert main(["compare", str(seeds_eval), str(seeds_eval), "--out", str(out), "--reps", "500"]) == 0
    printed = capsys.readouterr().out
    assert "IQM" in printed
    table = json.loads((out / "compare.json").read_text())
    groups = {g["group"]: g for g in table["groups"]}
    assert set(groups) == {"trained", "passive", "random"}
    assert groups["trained"]["n_seeds"] == 2 and groups["passive"]["n_seeds"] == 1
    assert sorted(groups["trained"]["scores"]) == sorted(float(r["test_mwr"]) for r in rows[:2])
    assert groups["trained"]["iqm"] == pytest.approx(np.mean(groups["trained"]["scores"]))
    # two seeds and two baselines: per-run values and their mean, no interval and no P(X > Y)
    assert all(g["lo"] is None and g["hi"] is None for g in table["groups"]) and table["improvement"] == []
    assert "fewer than 5 runs, no interval and no P(X > Y)" in printed
    assert (out / "compare.png").read_bytes().startswith(PNG)
    with (out / "compare.csv").open(newline="") as fh:
        assert {r["group"] for r in csv.DictReader(fh)} == set(groups)
    by_algo = compare(CompareConfig(folders=(str(seeds_eval),), by="algo", reps=200, out=str(tmp_path / "a")))
    assert {g["group"] for g in by_algo["groups"]} == {"ddpg", "passive", "random"}


def test_evaluate_expands_a_glob_of_policy_files(tiny_zoo: TinyZoo, tmp_path: Path) -> None:
    from triplesumo.evaluation.evaluate import expand_policies

    stem = str(tiny_zoo.zoo_dir / "*")
    found = expand_policies((stem,))
    assert [Path(p).name for p in found] == ["ant", "bug", "spider"]
    with pytest.raises(ValueError, match="matches no policy file"):
        expand_policies((str(tmp_path / "nothing-*"),))


def test_bad_input_gives_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="by must be one of"):
        CompareConfig(by="colour")
    with pytest.raises(ValueError, match="reps must be an int >= 100"):
        CompareConfig(reps=5)
    with pytest.raises(FileNotFoundError, match="per_seed.csv not found"):
        compare(CompareConfig(folders=(str(tmp_path),), out=str(tmp_path / "o")))
    (tmp_path / "per_seed.csv").write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="expected the columns"):
        compare(CompareConfig(folders=(str(tmp_path),), out=str(tmp_path / "o")))
    assert main(["compare", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    with pytest.raises(ValueError, match="at least one policy"):
        EvaluateConfig(policy=())


@pytest.mark.parametrize(("policy", "group", "algo", "expected"), [
    ("/r/bug/learn=bug=ddpg,seed=0/policy", "trained", "ddpg", "ddpg"),
    ("/r/ablations/learn=bug=ddpg,reward.still=-1,seed=2/policy", "trained", "ddpg", "ddpg,reward.still=-1"),
    ("/r/sweep/seed=1,ddpg.actor_lr=0.001/policy", "trained", "ddpg", "ddpg.actor_lr=0.001"),
    ("/r/runs/bug/policy", "trained", "td3", "td3"),
    ("passive", "passive", "passive", "passive"),
])
def test_trial_group_is_the_run_folder_without_its_seed(policy: str, group: str, algo: str, expected: str) -> None:
    from triplesumo.evaluation.compare import trial_group

    assert trial_group({"policy": policy, "group": group, "algo": algo}) == expected


def test_the_printed_table_keeps_long_group_names_whole() -> None:
    long = "ddpg,ddpg.noise=gaussian,reward.still=-1"
    groups = [{"group": g, "n_seeds": 5, "iqm": -0.6, "lo": -0.7, "hi": -0.5, "mean": -0.6,
               "scores": [-0.7, -0.6, -0.6, -0.6, -0.5]} for g in (long, "ppo")]
    table = {"confidence": 0.95, "groups": groups,
             "improvement": [{"x": long, "y": "ppo", "poi": 0.5, "lo": 0.0, "hi": 1.0},
                             {"x": "ppo", "y": long, "poi": 0.5, "lo": 0.0, "hi": 1.0}]}
    lines = format_compare(table).splitlines()
    assert lines[1].startswith(long + " ") and lines[2].startswith("ppo ")
    assert f"{long} > ppo" in lines[-2] and lines[-1].endswith(f"ppo > {long}  0.500 [0.000, 1.000]")
    assert len({line.index(" > ") for line in lines[-2:]}) == 1  # the columns line up


def _per_seed_folder(folder: Path, scores: dict[str, list[float]]) -> Path:
    """An evaluation folder's per_seed.csv with the given test MWR per algorithm, one row per run."""
    folder.mkdir(parents=True)
    with (folder / "per_seed.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(PER_SEED_COLUMNS)
        for algo, values in scores.items():
            for k, v in enumerate(values):
                w.writerow(["trained", f"{algo}-{k}", f"runs/{algo}-{k}/policy", f"{algo}{k:062d}", algo, k, "bug",
                            10_000, 2000, 0, 0, 0, v, v - 0.04, v + 0.04])
    return folder


def test_three_runs_report_their_values_and_mean_and_ten_runs_rliables_interval(tmp_path: Path) -> None:
    from rliable import library as rly_library

    ten = [0.58, 0.36, 0.38, 0.44, 0.51, 0.29, 0.47, 0.40, 0.62, 0.33]
    folder = _per_seed_folder(tmp_path / "ev", {"sac": ten, "ddpg": [0.06, 0.12, 0.18]})
    table = compare(CompareConfig(folders=(str(folder),), by="algo", reps=2000, out=str(tmp_path / "cmp")))
    groups = {g["group"]: g for g in table["groups"]}
    few = groups["ddpg"]
    assert few["lo"] is None and few["hi"] is None and few["mean"] == pytest.approx(0.12)
    assert table["improvement"] == []  # a group of 3 runs is compared with nothing
    many = groups["sac"]
    scores = np.array(ten)[:, None]
    assert many["iqm"] == pytest.approx(rly_metrics.aggregate_iqm(scores))
    np.random.seed(0)  # noqa: NPY002 (rliable's bootstrap draws from numpy's global generator)
    _, ci = rly_library.get_interval_estimates({"sac": scores}, lambda x: np.array([rly_metrics.aggregate_iqm(x)]),
                                               reps=2000)
    assert many["lo"] == pytest.approx(ci["sac"][0, 0], abs=0.03)
    assert many["hi"] == pytest.approx(ci["sac"][1, 0], abs=0.03)
    assert many["lo"] < many["iqm"] < many["hi"]
    with (tmp_path / "cmp" / "compare.csv").open(newline="") as fh:
        rows = {r["group"]: r for r in csv.DictReader(fh)}
    assert rows["ddpg"]["lo"] == rows["ddpg"]["hi"] == ""
    assert float(rows["sac"]["lo"]) == pytest.approx(many["lo"], abs=1e-4)
    printed = format_compare(table)
    assert "mean +0.120" in printed and f"{many['iqm']:+.3f} [{many['lo']:+.3f}, {many['hi']:+.3f}]" in printed
    assert (tmp_path / "cmp" / "compare.png").read_bytes().startswith(PNG)
    # five runs against five: P(X > Y) with its interval
    five = compare(CompareConfig(folders=(str(_per_seed_folder(tmp_path / "ev5", {"a": ten[:5], "b": ten[5:]})),),
                                 by="algo", reps=500, out=str(tmp_path / "cmp5")))
    assert {(p["x"], p["y"]) for p in five["improvement"]} == {("a", "b"), ("b", "a")}


def _with_opponents(folder: Path, others: dict[str, str]) -> Path:
    """Give a per_seed.csv folder the opponents' record ``evaluate`` writes beside it."""
    (folder / "evaluation.json").write_text(json.dumps({"rows_depend_on": {}, "others": others, "candidates": {}}))
    return folder


def test_the_same_policy_against_other_opponents_is_another_run_and_against_the_same_ones_is_not(
        tmp_path: Path) -> None:
    """A passive Bug in two from-scratch pairs is two evaluations; one evaluation copied to two folders is one."""
    pair_a = {"ant=a/policy": "a" * 64, "spider=s/policy": "s" * 64}
    pair_b = {"ant=b/policy": "b" * 64, "spider=t/policy": "t" * 64}
    one = _with_opponents(_per_seed_folder(tmp_path / "one", {"passive": [-0.3]}), pair_a)
    other = _with_opponents(_per_seed_folder(tmp_path / "other", {"passive": [-0.4]}), pair_b)
    copy = _with_opponents(_per_seed_folder(tmp_path / "copy", {"passive": [-0.3]}), pair_a)
    table = compare(CompareConfig(folders=(str(one), str(other), str(copy)), by="algo", reps=200,
                                  out=str(tmp_path / "cmp")))
    assert [g["scores"] for g in table["groups"]] == [[-0.3, -0.4]]
    (copy / "evaluation.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"copy/evaluation\.json: not an evaluation record"):
        compare(CompareConfig(folders=(str(copy),), out=str(tmp_path / "bad")))


def test_tasks_folder_draws_runs_within_each_folder_and_leaves_an_unbalanced_group_without_an_interval(
        tmp_path: Path) -> None:
    """The headline over two pairs: SAC's 5 + 5 runs as a (5, 2) task matrix, its IQM and interval rliable's;
    DDPG, run on one pair only, and a baseline of one run per pair get their values and mean."""
    from rliable import library as rly_library

    pair_1, pair_3 = [0.15, 0.21, 0.06, 0.02, -0.03], [0.62, 0.48, 0.55, 0.41, 0.70]
    one = _with_opponents(_per_seed_folder(tmp_path / "p1", {"sac": pair_1, "ddpg": [-0.5, -0.3, -0.2],
                                                             "passive": [-0.30]}), {"ant=a": "a" * 64})
    three = _with_opponents(_per_seed_folder(tmp_path / "p3", {"sac": pair_3, "passive": [-0.43]}),
                            {"ant=b": "b" * 64})
    table = compare(CompareConfig(folders=(str(one), str(three)), by="algo", tasks="folder", reps=4000,
                                  out=str(tmp_path / "cmp")))
    groups = {g["group"]: g for g in table["groups"]}
    sac = groups["sac"]
    matrix = np.array([pair_1, pair_3]).T
    assert sac["n_seeds"] == 10 and sac["iqm"] == pytest.approx(rly_metrics.aggregate_iqm(matrix))
    np.random.seed(0)  # noqa: NPY002 (rliable's bootstrap draws from numpy's global generator)
    _, ci = rly_library.get_interval_estimates({"sac": matrix}, lambda x: np.array([rly_metrics.aggregate_iqm(x)]),
                                               reps=4000)
    assert sac["lo"] == pytest.approx(ci["sac"][0, 0], abs=0.02)
    assert sac["hi"] == pytest.approx(ci["sac"][1, 0], abs=0.02)
    # drawing within each pair keeps each pair's five runs: narrower than drawing 10 runs from one pool
    pooled = compare(CompareConfig(folders=(str(one), str(three)), by="algo", reps=4000, out=str(tmp_path / "pool")))
    wide = next(g for g in pooled["groups"] if g["group"] == "sac")
    assert wide["iqm"] == pytest.approx(sac["iqm"]) and wide["hi"] - wide["lo"] > sac["hi"] - sac["lo"]
    assert groups["ddpg"]["lo"] is None and groups["ddpg"]["no_interval"].startswith("runs per folder differ (3, 0)")
    assert groups["passive"]["lo"] is None and groups["passive"]["no_interval"] == "fewer than 5 runs"
    assert groups["passive"]["scores"] == [-0.30, -0.43]
    assert table["improvement"] == []  # only SAC may have one, and it has no partner
    printed = format_compare(table)
    assert "(runs per folder differ (3, 0): no task matrix, no interval and no P(X > Y)" in printed
    assert "(fewer than 5 runs, no interval" in printed and "mean -0.365" in printed


def test_tasks_must_be_one_or_folder() -> None:
    with pytest.raises(ValueError, match=r"CompareConfig\.tasks must be one of \('one', 'folder'\), got 'pair'"):
        CompareConfig(tasks="pair")


def test_by_folder_tells_apart_folders_of_the_same_name(tmp_path: Path) -> None:
    one = _per_seed_folder(tmp_path / "seed-1" / "evaluation", {"sac": [0.1, 0.2]})
    three = _per_seed_folder(tmp_path / "seed-3" / "evaluation", {"td3": [0.5]})
    table = compare(CompareConfig(folders=(str(one), str(three)), by="folder", reps=200, out=str(tmp_path / "c")))
    assert {g["group"]: g["scores"] for g in table["groups"]} == {"seed-1/evaluation/trained": [0.1, 0.2],
                                                                  "seed-3/evaluation/trained": [0.5]}
    alone = compare(CompareConfig(folders=(str(one),), by="folder", reps=200, out=str(tmp_path / "d")))
    assert [g["group"] for g in alone["groups"]] == ["evaluation/trained"]
