"""``triplesumo reproduce --tiny``: every stage end to end, skipped when complete, redone alone when removed."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest

from triplesumo.cli import main
from triplesumo.reproduce import ReproduceConfig


def _record(out: Path) -> dict:
    return json.loads((out / "reproduce.json").read_text())


def test_tiny_reproduction_runs_every_stage_then_skips_them_and_redoes_a_removed_one(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "rep"
    argv = ["reproduce", "--tiny", "--out", str(out), "--algos", "ddpg", "--seeds", "0", "--no-progress"]
    assert main(argv) == 0
    stages = ["ant", "spider", "contest", "bug", "evaluation", "compare"]
    record = _record(out)
    assert record["runs"][-1]["ran"] == stages and record["runs"][-1]["version"]
    for name in stages:
        for rel in record["stages"][name]["outputs"]:
            assert (out / rel).exists(), rel
        assert record["stages"][name]["commands"]
    assert record["stages"]["ant"]["commands"][0].startswith("triplesumo train --name ant")
    assert (out / "bug" / "learn=bug=ddpg,seed=0" / "policy.json").exists()
    contest = json.loads((out / "contest" / "contest.json").read_text())
    assert contest["matches"] == 4 and contest["spider_wins"] + contest["ant_wins"] + contest["draws"] == 1.0
    with (out / "evaluation" / "per_seed.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert sorted(r["algo"] for r in rows) == ["ddpg", "passive", "random"]
    assert {r["epochs"] for r in rows} == {"4"}
    assert (out / "compare" / "compare.png").exists()
    report = (out / "REPRODUCTION.md").read_text()
    assert "## Stage 6: per algorithm across seeds" in report
    ddpg = next(r for r in rows if r["algo"] == "ddpg")
    assert f"| ddpg | 1 | {float(ddpg['test_mwr']):+.3f} |" in report  # the number read from per_seed.csv
    assert "| passive (baseline) | 1 |" in report and "triplesumo evaluate --policy" in report

    policy = (out / "bug" / "learn=bug=ddpg,seed=0" / "policy.safetensors").stat().st_mtime_ns
    assert main(argv) == 0  # everything complete: nothing trained or evaluated again
    assert _record(out)["runs"][-1]["ran"] == [] and _record(out)["runs"][-1]["skipped"] == stages
    assert (out / "bug" / "learn=bug=ddpg,seed=0" / "policy.safetensors").stat().st_mtime_ns == policy

    shutil.rmtree(out / "contest")
    shutil.rmtree(out / "compare")
    assert main(argv) == 0
    assert _record(out)["runs"][-1]["ran"] == ["contest", "compare"]
    assert json.loads((out / "contest" / "contest.json").read_text()) == contest
    assert (out / "bug" / "learn=bug=ddpg,seed=0" / "policy.safetensors").stat().st_mtime_ns == policy

    # a killed evaluation (its last rows lost) resumes: the same rows as before
    metrics = out / "evaluation" / "random" / "metrics.csv"
    whole = metrics.read_text()
    metrics.write_text("".join(whole.splitlines(keepends=True)[:3]))
    assert main(argv) == 0
    assert _record(out)["runs"][-1]["ran"] == ["evaluation"]
    assert metrics.read_text() == whole

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
])
def test_bad_options_name_the_field(kw: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ReproduceConfig(**kw)
