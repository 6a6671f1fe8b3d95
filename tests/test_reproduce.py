"""``triplesumo reproduce --tiny``: every stage end to end, skipped when complete, redone alone when removed."""

from __future__ import annotations

import csv
import dataclasses
import gzip
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import triplesumo.agents.zoo
from triplesumo import ENV_VERSION
from triplesumo.agents.zoo import make_policy, policies_from_pairs, policy_fingerprint
from triplesumo.cli import main
from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate
from triplesumo.evaluation.metrics_csv import read_table_bytes
from triplesumo.evaluation.tournament import _manifest as tournament_manifest
from triplesumo.model.specs import PhysicsConfig
from triplesumo.reproduce import ReproduceConfig, check_same_options
from triplesumo.rules.config import RewardConfig
from triplesumo.train.config import ALGOS


def _record(out: Path) -> dict:
    return json.loads((out / "reproduce.json").read_text())


@pytest.mark.slow  # 83 s alone on the shared 2-core box
def test_tiny_reproduction_runs_every_stage_then_skips_them_and_redoes_a_removed_one(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    out, zoo = tmp_path / "rep", tmp_path / "zoo"
    zoo.mkdir()
    monkeypatch.setattr(triplesumo.agents.zoo, "ZOO_DIR", zoo)
    monkeypatch.chdir(tmp_path)  # the manifests name the folder from here
    argv = ["reproduce", "--tiny", "--out", str(out), "--algos", "ddpg", "ppo", "--seeds", "0", "--no-progress",
            "--ablations", "noise=gaussian", "still=-1", "--publish"]
    assert main(argv) == 0
    stages = ["ant", "spider", "pair", "contest", "engagement", "bug", "ablations", "evaluation", "compare"]
    record = _record(out)
    assert record["runs"][-1]["ran"] == stages and record["runs"][-1]["version"]
    for name in stages:
        for rel in record["stages"][name]["outputs"]:
            assert (out / rel).exists(), rel
        assert record["stages"][name]["commands"] and record["stages"][name]["seconds"] > 0  # each stage's wall time
        if name != "spider":  # (made alongside the Ant: its record is the Ant's)
            [leg] = record["stages"][name]["legs"]  # one invocation made it, and finished it
            assert leg["finished"] and leg["seconds"] == record["stages"][name]["seconds"]
    assert "| bug |" in (out / "REPRODUCTION.md").read_text()  # the wall time per stage table
    # the pair with Bug passive, watched match by match on the contest's first starts: reported, not a gate
    engagement = json.loads((out / "contest" / "engagement.json").read_text())
    assert engagement["matches"] == 4 and engagement["bug"] == "passive" and engagement["seed"] == 20000
    assert engagement["ant"] == "ant/screens/policy-1" and engagement["spider"] == "spider/screens/policy-1"
    with open(out / "contest" / "engagement.csv", newline="") as fh:
        watched = list(csv.DictReader(fh))
    assert len(watched) == 4 and all(row["seed"] == str(20000 + i) for i, row in enumerate(watched))
    out_shares = [engagement[f"{a}_out"] for a in ("ant", "bug", "spider")] + [engagement["none_out"]]
    assert sum(out_shares) >= 1.0 - 1e-9  # every match ends with someone out (two may leave at once) or a draw
    assert f"| {engagement['mwr']:+.3f} | {engagement['bug_out']:.1%} |" in (out / "REPRODUCTION.md").read_text()
    # the machine and its speed, as bench skill records them; the Spider trained beside the Ant
    machine = record["runs"][-1]["machine"]
    assert machine["cores"] and machine["reference"]["ms_per_env_step"] > 0
    assert record["stages"]["spider"]["with"] == "ant"
    assert record["stages"]["spider"]["seconds"] == record["stages"]["ant"]["seconds"]
    # stage 1 as code: a screen after every leg (tiny: every epoch, the rules recorded but not enforced), the pair
    # rule's pick, and the contest played on it
    for role in ("ant", "spider"):
        screens = json.loads((out / role / "screens.json").read_text())["screens"]
        assert [s["epoch"] for s in screens] == [1] and screens[0]["n"] == 4
        assert (out / role / "screens" / "policy-1.safetensors").is_file()
    pair = json.loads((out / "pair" / "pair.json").read_text())
    assert [(p["ant_epoch"], p["spider_epoch"]) for p in pair["pairs"]] == [(1, 1)]
    assert pair["pick"]["ant"]["policy"] == "ant/screens/policy-1"
    for role, others in (("ant", "bug=passive spider=passive"), ("spider", "ant=passive bug=passive")):
        cmd = record["stages"][role]["commands"][0]  # each side alone against still opponents
        assert cmd.startswith(f"triplesumo train --name {role}") and f"--learn {role}=ddpg" in cmd
        assert f"--policies {others}" in cmd
        # the pre-training reward: losing costs more than surviving, a draw costs, the band, summed terms
        for option in ("--reward.still -1", "--reward.draw -200", "--reward.axis-dead-zone 0.25",
                       "--reward.opponents sum"):
            assert option in cmd, (option, cmd)
        assert json.loads((out / role / "config.json").read_text())["reward"]["opponents"] == "sum"
    assert (out / "bug" / "learn=bug=ddpg,seed=0" / "policy.json").exists()
    contest = json.loads((out / "contest" / "contest.json").read_text())
    assert (contest["ant"], contest["spider"]) == ("ant/screens/policy-1", "spider/screens/policy-1")
    assert contest["matches"] == 4 and contest["team_wins"] + contest["team_losses"] + contest["draws"] == 1.0
    assert set(contest["counts"]) == {"ant-pushes", "spider-pushes", "match"}
    assert contest["contest"] == (not contest["failed"])  # tiny: recorded, not enforced (the Bug stage ran)
    with (out / "evaluation" / "per_seed.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert sorted(r["algo"] for r in rows) == ["ddpg", "ddpg", "ddpg", "passive", "ppo", "random"]
    assert {r["epochs"] for r in rows} == {"4"}
    assert (out / "compare" / "compare.png").exists()
    # the ablations: the DDPG Bug run with one change each, the same seeds and budgets otherwise
    base = json.loads((out / "bug" / "learn=bug=ddpg,seed=0" / "config.json").read_text())
    for name, field, value in (("ddpg.noise=gaussian", "ddpg", {**base["ddpg"], "noise": "gaussian"}),
                               ("reward.still=-1", "reward", {**base["reward"], "still": -1.0})):
        ablated = json.loads((out / "ablations" / f"learn=bug=ddpg,{name},seed=0" / "config.json").read_text())
        assert ablated == {**base, field: value, "name": ablated["name"], "out": str(out / "ablations")}
    groups = {g["group"]: g for g in json.loads((out / "compare" / "compare.json").read_text())["groups"]}
    assert set(groups) == {"ddpg", "ppo", "ddpg,ddpg.noise=gaussian", "ddpg,reward.still=-1", "passive", "random"}
    report = (out / "REPRODUCTION.md").read_text()
    assert "## Stage 5: per algorithm across seeds" in report and "Ring: `border_rim=True`" in report
    assert "## Stage 2: is it a contest?" in report and f"{contest['team_mwr']:+.3f}" in report
    # time to skill: from the evaluations the Bug runs made while training (every 20 env steps when tiny)
    with (out / "bug" / "learn=bug=ddpg,seed=0" / "eval.csv").open() as fh:
        evals = list(csv.DictReader(fh))
    assert len(evals) >= 2 and all(int(r["env_steps"]) >= 20 * int(r["evaluation"]) for r in evals)
    skill = report[report.index("## Time to skill"):]
    hit = next((r for r in evals if float(r["test_mwr"]) >= 0.2), None)
    assert f"| learn=bug=ddpg,seed=0 | {'no' if hit is None else 'yes'} |" in skill
    if hit is None:  # not reached: within how many env steps and how much training time
        assert f"| learn=bug=ddpg,seed=0 | no | > {int(evals[-1]['env_steps']):,} | > " in skill
    assert f"| {len(evals)} |" in skill and (out / "bug" / "test_mwr.png").stat().st_size > 0
    ddpg = next(r for r in rows if r["policy"].endswith("learn=bug=ddpg,seed=0/policy"))
    assert f"| ddpg | 1 | {float(ddpg['test_mwr']):+.3f} |" in report  # the number read from per_seed.csv
    assert "| passive (baseline) | 1 |" in report and "triplesumo evaluate --policy" in report
    ablations = report[report.index("## Ablations"):]
    g = groups["ddpg,reward.still=-1"]
    row = f"| reward.still=-1 | 1 | {g['scores'][0]:+.3f} | mean {g['mean']:+.3f} (no interval: 1 run(s)) |"
    assert row in ablations
    assert "| ddpg,reward.still=-1 |" not in report.split("## Ablations")[0].split("## Stage 5")[1]
    # published: every algorithm's Bug as bug-ALGO, its seed picked by training MWR (the test starts pick nothing),
    # and as zoo:bug that Bug of the algorithm with the higher IQM test MWR
    trained = [r for r in rows if "/bug/" in r["policy"]]
    assert sorted(p.stem for p in zoo.glob("*.json")) == ["ant", "bug", "bug-ddpg", "bug-ppo", "spider"]
    top = max(("ddpg", "ppo"), key=lambda a: (groups[a]["iqm"], a == "ddpg"))
    best = next(r for r in trained if r["algo"] == top)  # one seed each
    shipped = json.loads((zoo / f"bug-{best['algo']}.json").read_text())
    assert shipped["algo"] == best["algo"] and shipped["code_version"] == _record(out)["runs"][-1]["version"]
    assert shipped["command"].startswith("triplesumo train") and shipped["seed"] == 0 and shipped["env_steps"] > 0
    assert shipped["physics"] == dataclasses.asdict(PhysicsConfig()) and shipped["env_version"] == ENV_VERSION
    assert shipped["reproduction"] == "rep"  # relative to the working directory it lies in
    for name in ("ant", "spider"):  # every stage's ring, and the contest check of the pair
        pair = json.loads((zoo / f"{name}.json").read_text())
        assert pair["physics"] == shipped["physics"] and pair["evaluation"]["contest"] == contest
    assert [shipped["evaluation"][k] for k in ("test_mwr", "test_mwr_lo", "test_mwr_hi")] == [
        float(best[k]) for k in ("test_mwr", "test_mwr_lo", "test_mwr_hi")]
    with (out / "bug" / f"learn=bug={top},seed=0" / "metrics.csv").open() as fh:  # the pick, recomputed
        lwr = [float(r["local_winning_rate"]) for r in csv.DictReader(fh)]
    picked = shipped["evaluation"]["selection"]
    assert picked["train_mwr"] == pytest.approx(sum(lwr[-200:]) / len(lwr[-200:]))
    assert picked["algo_iqm_test_mwr"] == groups[top]["iqm"] and picked["seeds"] == 1
    assert json.loads((zoo / "bug.json").read_text())["alias_of"] == f"bug-{top}"  # an alias: one copy of its weights
    assert not (zoo / "bug.safetensors").exists()
    assert f"| `zoo:bug-{best['algo']}` | {best['algo']} | 0 | {picked['train_mwr']:+.3f} |" in report
    # zoo:bug-ALGO resolves where a zoo spec is accepted: a policy, an evaluated candidate, a seat, a tournament entry
    assert make_policy(f"zoo:bug-{best['algo']}", expect_obs_mode="paper") is not None
    summary = evaluate(EvaluateConfig(policy=(f"zoo:bug-{best['algo']}",), policies=("ant=zoo:ant",
                                                                                      "spider=zoo:spider"),
                                      baselines=(), epochs=2, steps_per_epoch=20, n_envs=2, progress=False,
                                      out=str(tmp_path / "ev")))
    assert summary["candidates"]["trained"]["n"] == 2
    seats = policies_from_pairs((f"bug=zoo:bug-{best['algo']}",), 0, "paper")  # what train and evaluate seat
    assert set(seats) == {"bug"}
    assert tournament_manifest(f"zoo:bug-{best['algo']}")["zoo_name"] == f"bug-{best['algo']}"

    policy = (out / "bug" / "learn=bug=ddpg,seed=0" / "policy.safetensors").stat().st_mtime_ns
    assert main(argv) == 0  # everything complete: nothing trained or evaluated again
    report = (out / "REPRODUCTION.md").read_text()
    assert "## Time to skill" in report
    assert _record(out)["runs"][-1]["ran"] == [] and _record(out)["runs"][-1]["skipped"] == stages
    assert (out / "bug" / "learn=bug=ddpg,seed=0" / "policy.safetensors").stat().st_mtime_ns == policy
    # what was published stays in the record and the report of later runs and of --status
    assert main([a for a in argv if a != "--publish"] + ["--status"]) == 0
    assert f"| `zoo:bug-{best['algo']}` | {best['algo']} | 0 |" in (out / "REPRODUCTION.md").read_text()
    assert [p["name"] for p in _record(out)["published"]] == ["ant", "spider", "bug-ddpg", "bug-ppo", "bug"]

    # packed (triplesumo pack: every table gzipped, as a reproduction kept beside a docs page), it is the same
    # reproduction: complete, nothing trained or played again, the same report
    report = (out / "REPRODUCTION.md").read_text()
    assert main(["pack", str(out), "--min-kb", "0"]) == 0
    assert not list(out.rglob("*.csv")) and (out / "evaluation" / "per_seed.csv.gz").is_file()
    assert main(argv) == 0
    assert _record(out)["runs"][-1]["ran"] == [] and (out / "REPRODUCTION.md").read_text() == report

    shutil.rmtree(out / "contest")
    shutil.rmtree(out / "compare")
    assert main(argv) == 0
    assert _record(out)["runs"][-1]["ran"] == ["contest", "engagement", "compare"]
    assert json.loads((out / "contest" / "contest.json").read_text()) == contest
    assert (out / "bug" / "learn=bug=ddpg,seed=0" / "policy.safetensors").stat().st_mtime_ns == policy

    # a killed evaluation (its last rows lost), packed, resumes: the same rows as before, in a plain table again
    metrics = out / "evaluation" / "random" / "metrics.csv"
    whole = read_table_bytes(metrics).decode()
    (out / "evaluation" / "random" / "metrics.csv.gz").write_bytes(
        gzip.compress("".join(whole.splitlines(keepends=True)[:3]).encode()))
    assert main(argv) == 0
    assert _record(out)["runs"][-1]["ran"] == ["evaluation"]
    assert metrics.read_text() == whole and not (out / "evaluation" / "random" / "metrics.csv.gz").exists()

    # a Bug whose policy changed since its evaluation: the evaluation is not complete any more (and evaluate's
    # resume names the changed file rather than mixing rows of two policies)
    bug = out / "bug" / "learn=bug=ddpg,seed=0"
    (bug / "policy.json").write_text((bug / "policy.json").read_text().replace('"seed": 0', '"seed": 5'))
    capsys.readouterr()
    assert main(argv) == 2
    assert "learn=bug=ddpg,seed=0/policy" in capsys.readouterr().err

    # other options in the same folder are refused
    assert main([*argv, "--eval-epochs", "7"]) == 2


@pytest.mark.parametrize(("kw", "message"), [
    ({"algos": ("ddpg", "a2c")}, "ReproduceConfig.algos must be among"),
    ({"seeds": ()}, "ReproduceConfig.seeds must be non-empty"),
    ({"seeds": (0, 0)}, "without repeats"),
    ({"bug_epochs": 0}, "ReproduceConfig.bug_epochs must be an int >= 1"),
    ({"bug_learn_every": -1}, "ReproduceConfig.bug_learn_every must be an int >= 0"),
    ({"bug_n_step": -1}, "ReproduceConfig.bug_n_step must be an int >= 0"),
    ({"ablations": ("noise=brownian",)}, r"ReproduceConfig.ablations: 'noise=brownian': .*DDPGConfig.noise"),
    ({"ablations": ("still=2",)}, "RewardConfig.still is a punishment"),
    ({"ablations": ("seed=3",)}, "seed is set by the protocol"),
    ({"ablations": ("noise",)}, "expected FIELD=VALUE"),
    ({"ablations": ("ddpg.colour=red",)}, "has no field 'colour'"),
    ({"ablations": ("noise=gaussian", "ddpg.noise=gaussian")}, "a change given twice"),
    ({"ablations": ("noise=gaussian",), "algos": ("sac",)}, "algos must include ddpg"),
    ({"cpus_per_trial": 0}, "ReproduceConfig.cpus_per_trial must be an int >= 1"),
    ({"pretrain": RewardConfig(still=-4.0)}, r"pretrain.still -4.0: surviving without a result would be worth -400"),
    ({"pretrain": RewardConfig(still=-3.0, loss=-250.0)}, r"pretrain.still -3.0: .*worth -300.*losing \(-250\)"),
    ({"pretrain": "still=-1"}, "pretrain must be a RewardConfig"),
    ({"pair": ("zoo:ant",)}, "pair must be two policies"),
    ({"num_cpus": 2}, "options of ray"),
])
def test_bad_options_name_the_field(kw: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ReproduceConfig(**kw)


def test_a_record_written_before_an_option_existed_resumes_with_its_default(tmp_path: Path) -> None:
    import dataclasses

    recorded = json.loads(json.dumps(dataclasses.asdict(ReproduceConfig(tiny=True))))
    del recorded["ablations"]  # a record of a version without --ablations
    check_same_options(tmp_path, recorded, ReproduceConfig(tiny=True, progress=False))
    check_same_options(tmp_path, recorded, ReproduceConfig(tiny=True, ray=True, cpus_per_trial=2))  # how, not what
    check_same_options(tmp_path, recorded, ReproduceConfig(tiny=True, publish=True))  # publishing comes after
    with pytest.raises(ValueError, match=r"other options \(ablations: \[\] there, \['still=-1'\] given\)"):
        check_same_options(tmp_path, recorded, ReproduceConfig(tiny=True, ablations=("still=-1",)))


def test_the_folder_is_compared_by_its_place_and_status_may_read_a_moved_one(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import dataclasses

    monkeypatch.chdir(tmp_path)
    recorded = json.loads(json.dumps(dataclasses.asdict(ReproduceConfig(tiny=True, out=str(tmp_path / "rep")))))
    check_same_options(tmp_path / "rep", recorded, ReproduceConfig(tiny=True, out="rep"))  # relative, same place
    check_same_options(tmp_path / "moved", recorded, ReproduceConfig(tiny=True, out="moved", status=True))
    with pytest.raises(ValueError, match=r"\(out: "):  # a run (not --status) would write into another folder
        check_same_options(tmp_path / "moved", recorded, ReproduceConfig(tiny=True, out="moved"))


def test_bug_trials_give_td3_and_sac_the_shared_schedule_and_keep_ddpg_at_the_paper_preset(tmp_path: Path) -> None:
    from triplesumo.reproduce import Protocol
    from triplesumo.train.run_folder import command_for

    assert ReproduceConfig().algos == ("ddpg", "sac")  # the paper preset and the best of TD3/SAC/PPO (CONTEST.md)
    by_algo = {t.config.learn[0].split("=")[1]: t.config
               for t in Protocol(ReproduceConfig(out=str(tmp_path), seeds=(0,), algos=ALGOS)).bug_trials()}
    assert sorted(by_algo) == ["ddpg", "ppo", "sac", "td3"]
    assert (by_algo["td3"].td3.learn_every, by_algo["td3"].td3.n_step) == (8, 5)
    assert (by_algo["sac"].sac.learn_every, by_algo["sac"].sac.n_step) == (8, 5)
    assert (by_algo["ddpg"].ddpg.learn_every, by_algo["ddpg"].ddpg.n_step) == (30, 1)  # the paper preset, untouched
    assert by_algo["td3"].max_env_steps == 2_000_000  # protocol change 2's budget
    assert "--td3.learn-every 8 --td3.n-step 5" in command_for(by_algo["td3"])  # the recorded command says so
    shipped = {t.config.learn[0].split("=")[1]: t.config  # the recipe the shipped pair's Bugs trained with
               for t in Protocol(ReproduceConfig(out=str(tmp_path), seeds=(0,), algos=ALGOS, bug_learn_every=16,
                                                 bug_n_step=1)).bug_trials()}
    assert (shipped["sac"].sac.learn_every, shipped["sac"].sac.n_step) == (16, 1)
    default = {t.config.learn[0].split("=")[1]: t.config
               for t in Protocol(ReproduceConfig(out=str(tmp_path), seeds=(0,), algos=ALGOS,
                                                 bug_learn_every=0, bug_n_step=0)).bug_trials()}
    assert (default["td3"].td3.learn_every, default["td3"].td3.n_step) == (1, 1)
    assert (default["sac"].sac.learn_every, default["sac"].sac.n_step) == (8, 5)  # SAC's own default is the recipe


def test_a_record_written_before_bug_n_step_resumes_only_with_one_step_returns(tmp_path: Path) -> None:
    """A reproduction recorded before ``bug_n_step`` existed trained its TD3 and SAC Bugs with one-step returns:
    resuming it with today's default (5) is refused, naming the option; with ``--bug-n-step 1`` it resumes."""
    from triplesumo.reproduce.run import check_same_options

    recorded = json.loads(json.dumps(dataclasses.asdict(ReproduceConfig(out=str(tmp_path), bug_learn_every=16))))
    del recorded["bug_n_step"]
    with pytest.raises(ValueError, match=r"bug_n_step: 1 there, 5 given"):
        check_same_options(tmp_path, recorded, ReproduceConfig(out=str(tmp_path), bug_learn_every=16))
    check_same_options(tmp_path, recorded, ReproduceConfig(out=str(tmp_path), bug_learn_every=16, bug_n_step=1))


@pytest.mark.slow  # 109 s alone on the shared 2-core box, before the --workers leg
def test_with_ray_or_workers_the_bug_runs_train_at_once_and_give_the_outputs_of_a_local_reproduction(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """``--ray``: the stage-4 Bug runs train as Ray tasks (two at once here) and the contest's and test's matches play
    as Ray tasks, all on one local Ray of ``--num-cpus``, started once and shut down at the end. ``--workers 2``: the
    same on two processes of this machine, without Ray. Every run's rows, the contest and the per-seed test MWRs are
    those of the same reproduction in one process, and the folder resumes with or without either."""
    ray = pytest.importorskip("ray", reason='the "ray" extra is not installed (pip install "triplesumo[ray]")')
    assert not ray.is_initialized()
    starts: list[Any] = []
    real_init = ray.init

    def init(*args: Any, **kwargs: Any) -> Any:  # the real ray.init, its calls noted
        starts.append(kwargs.get("num_cpus"))
        return real_init(*args, **kwargs)

    monkeypatch.setattr(ray, "init", init)
    argv = ["reproduce", "--tiny", "--algos", "ddpg", "ppo", "--seeds", "0", "1", "--no-progress"]
    assert main([*argv, "--out", str(tmp_path / "local")]) == 0
    assert starts == []
    capsys.readouterr()
    assert main([*argv, "--out", str(tmp_path / "ray"), "--ray", "--num-cpus", "2", "--cpus-per-trial", "1"]) == 0
    assert "4 Bug trials as Ray tasks" in capsys.readouterr().out
    assert starts == [2] and not ray.is_initialized()  # the contest, the Bug runs and the test shared one Ray
    assert main([*argv, "--out", str(tmp_path / "workers"), "--workers", "2"]) == 0
    assert "4 Bug trials in 2 processes at once" in capsys.readouterr().out
    assert starts == [2]  # no Ray
    commands = " ".join(c for stage in _record(tmp_path / "workers")["stages"].values() for c in stage["commands"])
    assert commands.count("--workers 2") == 4  # the contest's three checks and the test
    names = sorted(p.name for p in (tmp_path / "local" / "bug").iterdir() if p.is_dir() and "seed=" in p.name)
    assert len(names) == 4

    def scores(where: str) -> dict[str, str]:
        rows = _csv_rows(tmp_path / where / "evaluation" / "per_seed.csv", header=True)
        return {Path(r["policy"]).parent.name or r["policy"]: r["test_mwr"] for r in rows}

    for where in ("ray", "workers"):
        assert names == sorted(p.name for p in (tmp_path / where / "bug").iterdir() if p.is_dir() and "seed=" in p.name)
        for name in names:
            local, there = (tmp_path / w / "bug" / name / "metrics.csv" for w in ("local", where))
            assert_same_rows(_csv_rows(there), _csv_rows(local))
        assert (tmp_path / where / "contest/contest.json").read_text() == (
            tmp_path / "local" / "contest/contest.json").read_text()
        assert scores(where) == scores("local") and len(scores(where)) == 6
        assert main([*argv, "--out", str(tmp_path / where)]) == 0  # the same protocol: resumes (all skipped) as it is
        assert _record(tmp_path / where)["runs"][-1]["ran"] == []


def assert_same_rows(got: list[list[str]], want: list[list[str]]) -> None:
    """Two runs' ``metrics.csv`` rows are the same game, all but the wall time (the last column): outcomes, steps and
    env steps equal, every other number equal to 1e-6 relative. Not to the bit: a run in another process can differ
    in the last bits (CI's machine once gave 1e-8 relative in the partner's velocity term from the first match on,
    in a Bug run on a Ray worker or a spawned process against the same run in pytest's own), while a seed, a policy or
    a setting mixed up changes these sums in their first digits."""
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert len(g) == len(w) and g[:2] == w[:2] and g[3] == w[3] and g[-2] == w[-2], (g, w)  # epoch, outcome, steps
        numbers = [k for k in range(2, len(w) - 1) if k not in (3, len(w) - 2)]
        got, wanted = ([float(row[k]) for k in numbers] for row in (g, w))
        assert got == pytest.approx(wanted, rel=1e-6, abs=1e-9), (g, w)


def _csv_rows(path: Path, header: bool = False) -> list[Any]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh)) if header else list(csv.reader(fh))[1:]


@pytest.mark.slow  # 34 s alone on the shared 2-core box
def test_status_runs_nothing_and_tells_where_each_stage_and_bug_run_stands(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "rep"
    argv = ["reproduce", "--tiny", "--out", str(out), "--algos", "ddpg", "--seeds", "0", "1", "--no-progress"]
    assert main([*argv, "--status"]) == 0
    table = capsys.readouterr().out
    assert "learn=bug=ddpg,seed=1" in table and "complete" not in table and not (out / "bug").exists()
    assert main(argv) == 0
    record = _record(out)
    # the folder moved (a clone elsewhere, a copy): --status reads it whole, every stage complete, the evaluation too
    # although its records name the policies at the old place (they are this folder's policies, the same files)
    moved = tmp_path / "moved"
    shutil.copytree(out, moved)
    capsys.readouterr()
    assert main([*argv[:3], str(moved), *argv[4:], "--status"]) == 0
    rows = {line.split()[1]: line.split()[2:] for line in capsys.readouterr().out.splitlines()[1:-1]}
    assert {name: row[0] for name, row in rows.items()} == dict.fromkeys(rows, "complete"), rows
    assert {"evaluation", "learn=bug=ddpg,seed=1"} <= set(rows)
    (moved / "bug" / "learn=bug=ddpg,seed=1" / "policy.safetensors").unlink()  # and it checks the files found there
    capsys.readouterr()
    assert main([*argv[:3], str(moved), *argv[4:], "--status"]) == 0
    rows = {line.split()[1]: line.split()[2:] for line in capsys.readouterr().out.splitlines()[1:-1]}
    assert rows["evaluation"][0] != "complete" and rows["contest"][0] == "complete"
    # one Bug run loses its checkpoints and policy (as a run stopped part way): it is not done, the rest is
    run = out / "bug" / "learn=bug=ddpg,seed=1"
    shutil.rmtree(run / "checkpoints")
    for f in run.glob("policy.*"):
        f.unlink()
    (out / "REPRODUCTION.md").unlink()
    capsys.readouterr()
    assert main([*argv, "--status"]) == 0
    rows = {line.split()[1]: line.split()[2:] for line in capsys.readouterr().out.splitlines()[1:-1]}
    assert rows["learn=bug=ddpg,seed=0"][:2] == ["complete", _rows_env_steps(out / "bug" / "learn=bug=ddpg,seed=0")]
    assert rows["learn=bug=ddpg,seed=1"][0] == "stopped"
    assert rows["ant"][0] == rows["spider"][0] == rows["contest"][0] == rows["compare"][0] == "complete"
    assert _record(out) == record  # nothing ran, nothing recorded
    # while a reproduction works in the folder (another process holds it and the run it trains), --status reads it
    # as it is, names that process and writes nothing (the report is that reproduction's)
    report = (out / "REPRODUCTION.md").read_bytes()
    (out / "REPRODUCTION.md").write_bytes(b"the live run's report\n")
    live = subprocess.Popen([sys.executable, "-c", HOLD_ALL, str(out), str(run)], stdout=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(Path(triplesumo.__file__).parents[1])})
    try:
        assert live.stdout is not None and live.stdout.readline() == b"held\n"
        capsys.readouterr()
        assert main([*argv, "--status"]) == 0
        printed = capsys.readouterr().out
        rows = {line.split()[1]: line.split()[2:] for line in printed.splitlines()[1:-1]}
        assert rows["learn=bug=ddpg,seed=1"][:3] == ["running", "(PID", f"{live.pid})"], printed
        assert rows["learn=bug=ddpg,seed=0"][0] == "complete"
        assert f"a reproduction is at work in {out}, PID {live.pid}" in printed.splitlines()[-1]
        assert (out / "REPRODUCTION.md").read_bytes() == b"the live run's report\n" and _record(out) == record
        assert (out / ".lock").read_text().strip() == str(live.pid)
    finally:
        live.kill()
        live.wait()
    (out / "REPRODUCTION.md").write_bytes(report)
    skill = (out / "REPRODUCTION.md").read_text().split("## Time to skill")[1]
    assert "| learn=bug=ddpg,seed=1 | not yet |" in skill and "| learn=bug=ddpg,seed=0 | not yet |" not in skill
    whole = next(line for line in skill.splitlines() if line.startswith("The whole protocol"))
    assert "--tiny" in whole and "--status" not in whole  # what makes the outputs, not how this run went

    # --docs writes the same report into a page of the docs, between its markers, the rest kept
    page = tmp_path / "docs" / "REPRODUCTION.md"
    page.parent.mkdir()
    page.write_text("# Ours\n\nintro\n\n<!-- reproduce:begin -->\nold\n<!-- reproduce:end -->\n\n## History\n")
    assert main([*argv, "--status", "--docs", str(page)]) == 0
    text, generated = page.read_text(), (out / "REPRODUCTION.md").read_text()
    assert text.startswith("# Ours\n\nintro\n\n<!-- reproduce:begin -->\n") and text.endswith(
        "<!-- reproduce:end -->\n\n## History\n") and "\nold\n" not in text
    assert "\n### Time to skill\n" in text and "\n## Time to skill\n" in generated
    assert "](../rep/bug/test_mwr.png)" in text and "](bug/test_mwr.png)" in generated
    assert "\n# spider (" in text  # the commands block keeps its bash comments
    page.write_text("# Ours, no markers\n")
    capsys.readouterr()
    assert main([*argv, "--status", "--docs", str(page)]) == 2
    assert "<!-- reproduce:begin -->" in capsys.readouterr().err and page.read_text() == "# Ours, no markers\n"


HOLD_ALL = """
import sys, time, contextlib
from triplesumo._lock import held
with contextlib.ExitStack() as stack:
    for folder in sys.argv[1:]:
        stack.enter_context(held(folder))
    print("held", flush=True)
    time.sleep(600)
"""
"""A process that holds the folders it is given (as a reproduction and the run it trains do) until killed."""


def test_the_pace_of_a_run_is_read_from_its_last_rows_since_its_last_stop(tmp_path: Path) -> None:
    """``pace``: env steps per second over the last rows' wall times, back at most 600 s and never across a stop
    (a gap of more than 600 s between two rows); None over less than 30 s."""
    from triplesumo.reproduce.reporting import pace

    def rows(*spans: tuple[float, int, float, int]) -> None:  # (start time, rows, seconds per row, steps per row)
        lines, steps = ["epoch,env_steps,wall_time"], 0
        for start, n, dt, per in spans:
            for k in range(n):
                steps += per
                lines.append(f"{len(lines)},{steps},{start + k * dt}")
        (tmp_path / "metrics.csv").write_text("\n".join(lines) + "\n")

    rows((1e9, 300, 10.0, 100))
    assert pace(tmp_path) == pytest.approx(10.0)  # 100 env steps every 10 s, the last 600 s of 3,000
    rows((1e9, 300, 10.0, 100), (1e9 + 3000 + 7200, 20, 5.0, 200))  # resumed after 2 h at twice the pace
    assert pace(tmp_path) == pytest.approx(40.0)
    rows((1e9, 300, 10.0, 100), (1e9 + 3000 + 7200, 3, 5.0, 200))  # 10 s since the resume: too short to tell
    assert pace(tmp_path) is None


def _rows_env_steps(run: Path) -> str:
    return f"{int(_csv_rows(run / 'metrics.csv', header=True)[-1]['env_steps']):,}"


def test_the_contest_rule_checks_each_side_and_the_band() -> None:
    from triplesumo.reproduce import CONTEST_BAND, PUSH_MIN, contest_verdict

    def counts(ant_wins: int, spider_wins: int, match: tuple[int, int, int]) -> dict[str, dict[str, int]]:
        return {"ant-pushes": {"n": 100, "n_win": ant_wins, "n_loss": 0, "n_draw": 100 - ant_wins},
                "spider-pushes": {"n": 100, "n_win": spider_wins, "n_loss": 0, "n_draw": 100 - spider_wins},
                "match": dict(zip(("n_win", "n_loss", "n_draw"), match, strict=True)) | {"n": 100}}

    assert CONTEST_BAND == (-0.5, -0.1) and PUSH_MIN == 0.5
    ok = contest_verdict(counts(60, 70, (50, 20, 30)), "a", "s")  # the Spider's 50 wins, the team's 20
    assert ok["contest"] and ok["team_mwr"] == pytest.approx(-0.30) and ok["failed"] == []
    edge = contest_verdict(counts(50, 50, (60, 10, 30)), "a", "s")  # -0.50 and 50 %: both bounds included
    assert edge["contest"]
    hopeless = contest_verdict(counts(60, 70, (82, 4, 14)), "a", "s")  # the v1 pair: Spider won 82 %
    assert not hopeless["contest"] and hopeless["failed"] == [
        "with Bug passive the team's MWR is -0.780 (the band is [-0.50, -0.10])"]
    lazy = contest_verdict(counts(0, 70, (30, 10, 60)), "a", "s")  # the v1 Ant: 0 of 32 against a passive Spider
    assert lazy["failed"] == ["the Ant pushes a passive Spider out in 0.0% of the starts (at least 50%)"]


def _counts(outcomes: list[str]) -> dict[str, int]:
    return {"n": len(outcomes), **{f"n_{o}": outcomes.count(o) for o in ("win", "loss", "draw")}}


def test_a_contest_check_is_decided_once_the_starts_left_cannot_change_it() -> None:
    """The decision rule on scripted counts: a push check fails once its wins plus every start left are under 50%,
    the match once every reachable team MWR lies outside the band; until then the next block ends where the starts
    could first decide it (never sooner than the matches played at once)."""
    from triplesumo.reproduce.protocol import contest_block, contest_can_pass

    def c(n: int, win: int = 0, loss: int = 0) -> dict[str, int]:
        return {"n": n, "n_win": win, "n_loss": loss, "n_draw": n - win - loss}

    assert contest_can_pass("ant-pushes", c(500), 1000)  # 500 wins in the 500 left: exactly 50 %
    assert not contest_can_pass("ant-pushes", c(501), 1000)  # decided: at most 499 of 1,000
    assert contest_can_pass("spider-pushes", c(900, win=450), 1000) and not contest_can_pass(
        "spider-pushes", c(1000, win=499), 1000)
    # the match on 100 starts (the band: team wins - losses in [-50, -10]), from the Spider's seat
    assert contest_can_pass("match", c(70, win=60), 100)  # team -60 so far, 30 left: [-90, -30] meets the band
    assert not contest_can_pass("match", c(81, win=81), 100)  # hopeless: at best -81 + 19 = -62
    assert not contest_can_pass("match", c(60, loss=60), 100)  # too easy: at worst +60 - 40 = +20
    assert contest_can_pass("match", c(100, win=50, loss=0), 100)  # -0.50: the band's end is included
    # the next block ends where the starts could first decide the check
    assert contest_block("ant-pushes", c(0), 1000) == 501 and contest_block("ant-pushes", c(0), 10, least=2) == 6
    assert contest_block("ant-pushes", c(501, win=300), 1000, least=16) == 801  # 300 more without a win: 499 at most
    assert contest_block("match", c(0), 1000) == 451  # 451 team wins would leave the team above -0.10
    assert contest_block("ant-pushes", c(990, win=495), 1000, least=16) == 1000  # no block smaller than least left
    assert contest_block("ant-pushes", c(600, win=590), 1000, least=16) == 1000  # passed already: play it out


def test_a_contest_stops_on_its_first_decided_check_and_a_passing_pair_plays_every_start() -> None:
    """play_contest on scripted outcomes: a passive pair stops after the Ant's first block (the other checks are not
    played, and the record says so); the pair env v2's zoo ships, on its real 1,000 starts per check
    (docs/runs/contest-v2), is never stopped and its verdict is the shipped record; a hopeless match stops early."""
    from triplesumo.evaluation.metrics_csv import open_table
    from triplesumo.reproduce.protocol import contest_can_pass, contest_verdict, format_contest, play_contest
    from triplesumo.reproduce.reporting import _contest_section

    played: list[tuple[str, int]] = []

    def player(outcomes: dict[str, list[str]]) -> Any:
        def play(check: str, end: int) -> dict[str, int]:
            played.append((check, end))
            return _counts(outcomes[check][:end])
        return play

    passive = dict.fromkeys(("ant-pushes", "spider-pushes", "match"), ["draw"] * 1000)
    counts = play_contest(player(passive), 1000, least=16)
    assert played == [("ant-pushes", 501)] and list(counts) == ["ant-pushes"]
    facts = contest_verdict(counts, "passive", "passive", matches=1000)
    assert facts["contest"] is False and facts["matches"] == 1000
    assert facts["stopped"] == {"check": "ant-pushes", "after": 501}
    assert facts["not_played"] == ["spider-pushes", "match"] and facts["spider_pushes"] is facts["team_mwr"] is None
    assert facts["failed"] == ["the Ant pushes a passive Spider out in 0 of the first 501 of 1,000 starts, so in at "
                               "most 49.9% of them (at least 50%)"]
    text = format_contest(facts)
    assert text.count("not played: the contest failed on an earlier check") == 2 and "0.0% of the first 501" in text
    with pytest.raises(ValueError, match="a contest stops at its first check that can no longer pass"):
        contest_verdict({"ant-pushes": _counts(["draw"] * 500)}, "a", "s", matches=1000)  # it could still pass

    shipped = Path(__file__).parents[1] / "docs" / "runs" / "contest-v2" / "reproduce" / "contest"
    real = {}
    for check in ("ant-pushes", "spider-pushes", "match"):
        with open_table(shipped / check / "trained" / "metrics.csv") as fh:
            real[check] = [r["outcome"] for r in csv.DictReader(fh)]
        assert all(contest_can_pass(check, _counts(real[check][:k]), 1000) for k in range(1001))  # at every start
    played.clear()
    counts = play_contest(player(real), 1000, least=16)
    assert {check: end for check, end in played} == dict.fromkeys(real, 1000)  # each check to its last start
    assert 3 < len(played) < 20  # in blocks, a few per check
    record = json.loads((shipped / "contest.json").read_text())
    assert contest_verdict(counts, record["ant"], record["spider"], matches=1000) == record
    assert "\n".join(_contest_section(record, 20_000)) in (shipped.parent / "REPRODUCTION.md").read_text()  # as before

    hopeless = {**real, "match": ["win"] * 820 + ["loss"] * 40 + ["draw"] * 140}  # the v1 pair: Spider won 82 %
    played.clear()
    counts = play_contest(player(hopeless), 1000, least=16)
    assert [check for check, _ in played].count("match") >= 1 and played[-1][0] == "match"
    n = counts["match"]["n"]
    assert n < 1000 and not contest_can_pass("match", counts["match"], 1000)
    assert contest_can_pass("match", _counts(hopeless["match"][:n - 1]), 1000)  # one start sooner: undecided
    facts = contest_verdict(counts, "a", "s", matches=1000)
    assert facts["not_played"] == [] and facts["stopped"] == {"check": "match", "after": n}
    assert facts["failed"][0].startswith(f"with Bug passive the team's MWR is -1.000 on the first {n:,} of 1,000")


@pytest.mark.slow  # 5 s alone on the shared 2-core box
def test_the_bug_stage_refuses_a_pair_that_is_no_contest(tmp_path: Path) -> None:
    """A scripted pair, both passive: nobody pushes anybody (all draws). The contest stops after the first block of
    the Ant's check, the fewest starts that decide it (6 of 10: at most 4 wins left), plays neither the Spider's
    check nor the match (30 matches before the contest stopped early), and is recorded as failed; the Bug stage
    refuses to start, naming the failed check and the file; no Bug trains."""
    from triplesumo.reproduce import ContestError, run_reproduce

    cfg = ReproduceConfig(out=str(tmp_path / "rep"), pair=("passive", "passive"), contest_epochs=10, n_envs=2,
                          algos=("ddpg",), seeds=(0,), progress=False)
    with pytest.raises(ContestError, match=r"stage bug refused: the pair passive / passive failed the contest rule: "
                                           r"the Ant pushes a passive Spider out in 0 of the first 6 of 10 starts, "
                                           r"so in at most 40.0% of them \(at least 50%\) \(.*contest.json\)"):
        run_reproduce(cfg)
    contest_dir = tmp_path / "rep" / "contest"
    contest = json.loads((contest_dir / "contest.json").read_text())
    assert contest["contest"] is False and contest["matches"] == 10
    assert contest["counts"] == {"ant-pushes": {"n": 6, "n_win": 0, "n_loss": 0, "n_draw": 6}}
    assert contest["stopped"] == {"check": "ant-pushes", "after": 6}
    assert contest["not_played"] == ["spider-pushes", "match"]
    metrics = contest_dir / "ant-pushes" / "trained" / "metrics.csv"
    assert len(read_table_bytes(metrics).decode().splitlines()) == 1 + 6  # the header and 6 matches
    assert not (contest_dir / "spider-pushes").exists() and not (contest_dir / "match").exists()
    assert not (tmp_path / "rep" / "bug").exists()
    record = _record(tmp_path / "rep")
    assert record["stages"].keys() == {"contest", "engagement", "bug"}
    [refused] = record["stages"]["bug"]["legs"]  # the Bug stage's one leg: it began, refused, and made nothing
    assert not refused["finished"] and "done" not in record["stages"]["bug"]
    [command] = record["stages"]["contest"]["commands"]  # the Ant's check, to the start that decided it
    assert "--learner ant " in command and f"{command} ".count("--epochs 6 ") == 1
    played = metrics.stat().st_mtime_ns
    with pytest.raises(ContestError):  # and again on a re-run: the recorded verdict stands, nothing is played again
        run_reproduce(cfg)
    assert metrics.stat().st_mtime_ns == played and json.loads((contest_dir / "contest.json").read_text()) == contest
    run_reproduce(dataclasses.replace(cfg, status=True))  # the report: the checks not played, and why
    stage2 = (tmp_path / "rep" / "REPRODUCTION.md").read_text().split("## Stage 2")[1].split("## Stage 3")[0]
    assert "| Ant pushes a passive Spider out | 0.0% on the first 6 | >= 50% | failed: could no longer pass |" in stage2
    assert stage2.count("| not played: the contest failed on an earlier check |") == 2
    assert "decided by `ant-pushes` after 6 of its 10 starts" in stage2


def test_the_checkpoint_rule_takes_the_earliest_screen_that_pushes_half() -> None:
    from triplesumo.reproduce.pretrain import first_passing

    def screen(epoch: int, wins: int) -> dict[str, int]:
        return {"epoch": epoch, "n": 100, "n_win": wins, "n_loss": 0, "n_draw": 100 - wins}

    # the shipped Spider's screens (docs/CONTEST.md): 14, 33, 47, 61, 74 of 100 at 2,000 .. 7,000
    screens = [screen(7000, 74), screen(2000, 14), screen(3000, 33), screen(5000, 47), screen(6000, 61)]
    assert first_passing(screens)["epoch"] == 6000  # the earliest at >= 50 %, whatever the order recorded
    assert first_passing(screens, after=6000)["epoch"] == 7000  # the next one, for the pair rule
    assert first_passing(screens, after=7000) is None
    assert first_passing([screen(1000, 49)]) is None and first_passing([screen(1000, 50)])["epoch"] == 1000
    assert first_passing([screen(1000, 0)], push_min=0.0)["epoch"] == 1000  # tiny: recorded, not enforced


def test_the_pair_rule_keeps_the_band_and_names_the_side_to_strengthen() -> None:
    from triplesumo.reproduce.pretrain import pair_move

    assert [pair_move(m) for m in (-0.75, -0.50, -0.46, -0.10, +0.05)] == ["ant", "pair", "pair", "pair", "spider"]
    assert pair_move(0.9, band=(-1.0, 1.0)) == "pair"


def _scripted_side(tmp_path: Path, role: str, wins: dict[int, int], trained: list[tuple[str, int]],
                   budget: int = 5000) -> Any:
    """A side whose legs write a policy file and whose screens answer from ``wins`` (epoch -> pushes of 100)."""
    from triplesumo.agents.policy_file import policy_paths
    from triplesumo.reproduce.pretrain import Side

    run = tmp_path / role

    def train(epochs: int) -> int:
        trained.append((role, epochs))
        run.mkdir(exist_ok=True)
        for path in policy_paths(run / "policy"):
            path.write_text(f"{role} at {epochs}")
        return 100 * epochs

    def screen(policy: str, out: Path) -> dict[str, int]:
        epoch = int(policy.rsplit("-", 1)[1])
        assert Path(policy + ".json").read_text() == f"{role} at {epoch}"  # the leg's own policy, kept
        return {"n": 100, "n_win": wins[epoch], "n_loss": 0, "n_draw": 100 - wins[epoch]}

    return Side(role, run, 1000, budget, "100, seed 30000 + i", train, screen)


def test_stage_one_trains_each_side_to_its_first_passing_screen_then_the_pair_rule_strengthens_the_loser(
        tmp_path: Path) -> None:
    """Scripted screens and pair matches: the Ant passes at 2,000, the Spider at 1,000; their pair leaves the team
    hopeless (-0.70), so the Ant trains on to its next passing screen (4,000: 3,000 does not pass), and that pair lies
    in the band. Every leg, screen and pair is recorded; a re-run trains and plays nothing."""
    from triplesumo.reproduce.pretrain import PAIR_FILE, play_pair_rule

    trained: list[tuple[str, int]] = []
    sides = {"ant": _scripted_side(tmp_path, "ant", {1000: 10, 2000: 55, 3000: 48, 4000: 60}, trained),
             "spider": _scripted_side(tmp_path, "spider", {1000: 51}, trained)}
    team = {(2000, 1000): (80, 10), (4000, 1000): (60, 30)}  # (Spider wins, team wins) of 100
    played: list[tuple[int, int]] = []

    def play(ant: dict[str, Any], spider: dict[str, Any]) -> dict[str, int]:
        played.append((ant["epoch"], spider["epoch"]))
        w, lo = team[played[-1]]
        return {"n": 100, "n_win": w, "n_loss": lo, "n_draw": 100 - w - lo}

    record = play_pair_rule(sides, tmp_path / "pair" / PAIR_FILE, play)
    assert trained == [("ant", 1000), ("ant", 2000), ("spider", 1000), ("ant", 3000), ("ant", 4000)]
    assert played == [(2000, 1000), (4000, 1000)]
    assert [(p["team_mwr"], p["move"]) for p in record["pairs"]] == [(-0.7, "ant"), (-0.3, "pair")]
    assert record["pick"] == {"ant": {"epoch": 4000, "policy": "ant/screens/policy-4000"},
                              "spider": {"epoch": 1000, "policy": "spider/screens/policy-1000"}}
    screens = json.loads((tmp_path / "ant" / "screens.json").read_text())["screens"]
    assert [(s["epoch"], s["n_win"], s["env_steps"]) for s in screens] == [
        (1000, 10, 100_000), (2000, 55, 200_000), (3000, 48, 300_000), (4000, 60, 400_000)]
    assert all(s["train_seconds"] >= 0 and s["screen_seconds"] >= 0 for s in screens)
    assert json.loads((tmp_path / "pair" / PAIR_FILE).read_text()) == record
    assert play_pair_rule(sides, tmp_path / "pair" / PAIR_FILE, play) == record  # resumed: nothing again
    assert len(trained) == 5 and len(played) == 2


def test_a_pair_rule_that_needs_a_stronger_side_past_its_budget_stops_stage_one_saying_why(tmp_path: Path) -> None:
    """Pair seed 2's case: both sides pass, but with Bug passive the team wins (above the band) with every Spider
    the budget gives; stage 1 stops naming the last pair, the band and the spent budget, and pair.json keeps it."""
    from triplesumo.reproduce import PairError
    from triplesumo.reproduce.pretrain import PAIR_FILE, play_pair_rule
    from triplesumo.reproduce.reporting import _stage_one_section

    trained: list[tuple[str, int]] = []
    sides = {"ant": _scripted_side(tmp_path, "ant", {1000: 72}, trained),
             "spider": _scripted_side(tmp_path, "spider", {1000: 52, 2000: 70}, trained, budget=2000)}

    def play(ant: dict[str, Any], spider: dict[str, Any]) -> dict[str, int]:
        return {"n": 100, "n_win": 38, "n_loss": 57, "n_draw": 5}  # team MWR +0.19

    path = tmp_path / "pair" / PAIR_FILE
    with pytest.raises(PairError, match=r"the pair rule found no pair: with Ant 1,000 / Spider 2,000 and Bug passive "
                                        r"the team's MWR is \+0\.190, above the band \[-0\.50, -0\.10\], so the Spider "
                                        r"must get stronger, but stage 1: the Spider has no checkpoint after epoch "
                                        r"2,000: its budget of 2,000 epochs is spent \(52/100 at 1,000, 70/100 at "
                                        r"2,000; "):
        play_pair_rule(sides, path, play)
    record = json.loads(path.read_text())
    assert [(p["spider_epoch"], p["move"]) for p in record["pairs"]] == [(1000, "spider"), (2000, "spider")]
    assert record["failed"].startswith("the pair rule found no pair") and "pick" not in record
    assert trained == [("ant", 1000), ("spider", 1000), ("spider", 2000)]  # nothing past the budget

    from types import SimpleNamespace

    protocol = SimpleNamespace(screen_every=1000, screen_epochs=100, cfg=SimpleNamespace(screen_seed=30000),
                               side=sides.__getitem__, pair_record=lambda: json.loads(path.read_text()))
    text = "\n".join(_stage_one_section(protocol))  # (what the report reads of the protocol)
    assert "**Stage 1 stopped: the pair rule found no pair" in text and "No contest was played" in text


def test_a_side_that_never_passes_within_its_budget_stops_stage_one_naming_its_screens(tmp_path: Path) -> None:
    from triplesumo.reproduce import PairError

    trained: list[tuple[str, int]] = []
    side = _scripted_side(tmp_path, "spider", {1000: 6, 2000: 14, 3000: 33}, trained, budget=3000)
    with pytest.raises(PairError, match=r"the Spider pushed still opponents out in fewer than 50% .* up to its budget "
                                        r"of 3,000 epochs \(6/100 at 1,000, 14/100 at 2,000, 33/100 at 3,000; "
                                        r".*screens.json\)\. Raise the budget \(--spider-epochs\)"):
        side.until_pass()
    assert [e for _, e in trained] == [1000, 2000, 3000]
    with pytest.raises(PairError):  # a re-run trains nothing again: the screens are recorded
        side.until_pass()
    assert len(trained) == 3


def test_the_cli_stops_a_refused_pair_with_rc_2_and_a_message(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["reproduce", "--out", str(tmp_path / "rep"), "--pair", "passive", "passive", "--contest-epochs", "2",
            "--n-envs", "2", "--algos", "ddpg", "--seeds", "0", "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "triplesumo reproduce: stopped: stage bug refused" in err and "Traceback" not in err


@pytest.mark.slow  # 43 s alone on the shared 2-core box
def test_a_reproduction_grows_by_more_bug_runs_keeping_those_made_and_refuses_to_drop_any(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """More seeds (or algorithms) on a folder: the Bug runs made are kept as they are, the new ones train and
    join the test on the same starts; fewer is refused (their runs would be orphans of the record)."""
    out = tmp_path / "rep"
    base = ["reproduce", "--tiny", "--out", str(out), "--no-progress"]
    assert main([*base, "--algos", "ddpg", "--seeds", "0"]) == 0
    made = out / "bug" / "learn=bug=ddpg,seed=0" / "metrics.csv"
    before = made.read_bytes()
    first = {r["candidate"]: r["test_mwr"]
             for r in _csv_rows(out / "evaluation" / "per_seed.csv", header=True)}
    assert main([*base, "--algos", "ddpg", "sac", "--seeds", "0", "1", "--ddpg-runs", "1"]) == 0
    assert made.read_bytes() == before  # kept, not trained again
    assert sorted(p.name for p in (out / "bug").iterdir() if "seed=" in p.name) == [
        "learn=bug=ddpg,seed=0", "learn=bug=sac,seed=0", "learn=bug=sac,seed=1"]  # DDPG on the first 1 seed
    rows = {r["candidate"]: r for r in _csv_rows(out / "evaluation" / "per_seed.csv", header=True)}
    assert len(rows) == 5 and {k: rows[k]["test_mwr"] for k in first} == first  # same starts, same rows
    capsys.readouterr()
    assert main([*base, "--algos", "sac", "--seeds", "0", "1"]) == 2  # drops the DDPG run
    err = capsys.readouterr().err
    assert "other options" in err and "algos: ['ddpg', 'sac'] there, ['sac'] given" in err


def test_a_stage_leg_keeps_its_time_when_it_fails_is_killed_or_resumed(tmp_path: Path) -> None:
    """Each invocation's work on a stage is a leg in reproduce.json: written at its start, every heartbeat while it
    runs, and at its end, finished or not (SIGTERM ends it as an interrupt does); the stage's time sums its legs."""
    import os
    import signal
    import time

    from triplesumo.reproduce.reporting import _stage_times, stage_seconds
    from triplesumo.reproduce.run import Record, stage_leg

    path = tmp_path / "reproduce.json"
    book = Record(path, {"stages": {}})
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(RuntimeError, match="a stage that fails"), stage_leg(book, "bug", "git abc", every=0.05):
        assert json.loads(path.read_text())["stages"]["bug"]["legs"][0]["seconds"] == 0.0  # written at its start
        time.sleep(0.3)
        assert json.loads(path.read_text())["stages"]["bug"]["legs"][0]["seconds"] > 0.1  # the heartbeat
        raise RuntimeError("a stage that fails")
    with pytest.raises(KeyboardInterrupt), stage_leg(book, "bug", "git def", every=10.0):
        time.sleep(0.1)
        os.kill(os.getpid(), signal.SIGTERM)  # pkill, or a scheduler's stop
        time.sleep(5)  # (not reached: the signal interrupts it)
    assert signal.getsignal(signal.SIGTERM) is before  # the handler is the leg's only while it runs
    with stage_leg(book, "bug", "git def", every=10.0):
        time.sleep(0.05)
    legs = json.loads(path.read_text())["stages"]["bug"]["legs"]
    assert [(leg["version"], leg["finished"]) for leg in legs] == [("git abc", False), ("git def", False),
                                                                   ("git def", True)]
    assert legs[0]["seconds"] >= 0.3 and 0.1 <= legs[1]["seconds"] < 4 and legs[2]["seconds"] >= 0.05
    assert stage_seconds(book.data["stages"]["bug"]) == pytest.approx(sum(leg["seconds"] for leg in legs))
    assert "| bug | 0.0 min | 3 | not finished |" in "\n".join(_stage_times(book.data))
    assert stage_seconds({"seconds": 12.5, "done": "x"}) == 12.5  # a record from before legs


@pytest.mark.slow  # three tiny reproductions from a given pair, 40 s each on the shared 2-core box
def test_a_grown_bug_budget_trains_each_bug_on_as_one_longer_run_and_keeps_the_smaller_budgets_test(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--bug-env-steps larger on a re-run: each Bug resumes from its last checkpoint to the new budget and ends as a
    run made at that budget from the start would; the test of the smaller budget moves to at-bug-env-steps-N/ with
    the policies it played, the test is played again, and a smaller budget is refused."""
    base = ["reproduce", "--tiny", "--pair", "zoo:ant", "zoo:spider", "--algos", "sac", "--seeds", "0",
            "--no-progress"]
    out, straight = tmp_path / "grown", tmp_path / "straight"
    run, run_straight = (f / "bug" / "learn=bug=sac,seed=0" for f in (out, straight))
    assert main([*base, "--out", str(out), "--bug-env-steps", "40"]) == 0
    assert _csv_rows(run / "metrics.csv", header=True)[-1]["env_steps"] == "40"  # (tiny: 2 matches of 20 steps)
    first_test = (out / "evaluation" / "per_seed.csv").read_bytes()
    first_policy = (run / "policy.safetensors").read_bytes()

    assert main([*base, "--out", str(out), "--bug-env-steps", "80"]) == 0
    assert main([*base, "--out", str(straight), "--bug-env-steps", "80"]) == 0
    assert _csv_rows(run / "metrics.csv", header=True)[-1]["env_steps"] == "80"
    assert [leg["kind"] for leg in json.loads((run / "legs.json").read_text())["legs"]] == ["start", "resume"]
    assert (run / "policy.safetensors").read_bytes() == (run_straight / "policy.safetensors").read_bytes()
    assert [r[:4] for r in _csv_rows(run / "metrics.csv")] == [r[:4] for r in _csv_rows(run_straight / "metrics.csv")]
    tests = [{r["candidate"]: r for r in _csv_rows(f / "evaluation" / "per_seed.csv", header=True)}
             for f in (out, straight)]
    assert {k: r["test_mwr"] for k, r in tests[0].items()} == {k: r["test_mwr"] for k, r in tests[1].items()}
    assert tests[0]["trained"]["sha256"] == policy_fingerprint(str(run / "policy"))  # played again, the grown Bug

    aside = out / "at-bug-env-steps-40"
    assert (aside / "evaluation" / "per_seed.csv").read_bytes() == first_test  # the smaller budget's test, whole
    assert (aside / "compare" / "compare.json").exists()
    assert (aside / "policies" / "bug" / "learn=bug=sac,seed=0" / "policy.safetensors").read_bytes() == first_policy
    record = _record(out)
    [grown] = record["grown"]
    assert grown["budget"] == {"bug_env_steps": {"from": 40, "to": 80}} and grown["folder"] == aside.name
    assert sorted(grown["stages"]) == ["compare", "evaluation"] and grown["moved"] == ["evaluation", "compare"]
    assert record["config"]["bug_env_steps"] == 80 and record["runs"][-1]["ran"] == ["bug", "evaluation", "compare"]
    assert len(record["stages"]["bug"]["legs"]) == 2

    capsys.readouterr()
    assert main([*base, "--out", str(out), "--bug-env-steps", "40"]) == 2
    err = capsys.readouterr().err
    assert "can grow on a re-run, not shrink" in err and "bug_env_steps: 80 there, 40 given" in err
    assert sorted(p.name for p in out.iterdir()) == sorted(["REPRODUCTION.md", "at-bug-env-steps-40", "bug", "compare",
                                                            "contest", "evaluation", "reproduce.json"])
