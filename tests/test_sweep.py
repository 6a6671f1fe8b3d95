"""``triplesumo sweep``: the grid, trials as Ray tasks on a real local Ray, resume after a killed worker."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from conftest import own_ray_workers
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.evaluation.parallel import ProcessRunner
from triplesumo.train.config import TrainConfig
from triplesumo.train.sweep import SweepConfig, parse_grid, run_sweep, trials

TINY = TrainConfig(epochs=4, steps_per_epoch=30, n_envs=2, checkpoint_every=2, tensorboard=False, progress=False,
                   policies=("ant=zero", "spider=random"),
                   ddpg=DDPGConfig(hidden=(16, 16), buffer_size=2000, learning_starts=20, batch_size=16, learn_every=4))


def test_the_grid_takes_any_field_by_its_dotted_name(tmp_path: Path) -> None:
    cfg = SweepConfig(grid=("seed=0,1", "ddpg.actor_lr=1e-4,1e-3", "policies=ant=zero spider=random,ant=zoo:ant"),
                      out=str(tmp_path))
    made = trials(cfg, TINY)
    assert len(made) == 8
    first = made[0]
    assert first.name == "seed=0,ddpg.actor_lr=1e-4,policies=ant=zero+spider=random"
    assert first.group == "ddpg.actor_lr=1e-4,policies=ant=zero+spider=random"
    assert first.config.ddpg.actor_lr == 1e-4 and first.config.seed == 0
    assert first.config.policies == ("ant=zero", "spider=random")
    assert made[-1].config.policies == ("ant=zoo:ant",) and made[-1].config.ddpg.hidden == (16, 16)
    assert first.config.out == str(tmp_path.resolve()) and first.config.epochs == 4
    assert {t.group for t in made if t.config.ddpg.actor_lr == 1e-3 and len(t.config.policies) == 1} == {
        "ddpg.actor_lr=1e-3,policies=ant=zoo:ant"}
    assert [(k, [v for _, v in vs]) for k, vs in parse_grid(("save_replay=true,false",))] == [
        ("save_replay", [True, False])]


@pytest.mark.parametrize(("grid", "message"), [
    (("sed=0,1",), "TrainConfig has no field 'sed'"),
    (("ddpg.actor_l=1",), "ddpg has no field 'actor_l'"),
    (("ddpg=1",), "a group of fields"),
    (("seed=0,x",), "'x' is not a int"),
    (("seed=0,0",), "non-empty and different"),
    (("seed",), "expects FIELD=V1,V2"),
    (("name=a,b",), "the sweep sets it"),
    (("scenario=paper,nope",), r"--grid scenario=nope: TrainConfig.scenario must be one of"),
])
def test_bad_grids_name_the_field(grid: tuple[str, ...], message: str, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=message):
        trials(SweepConfig(grid=grid, out=str(tmp_path)), TINY)


def _on_ray() -> Any:
    """The runner ``triplesumo sweep`` hands down (imported here: Ray is an extra; the tests using it need it)."""
    from triplesumo.integrations.ray_tasks import RayRunner

    return RayRunner()


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _timeless(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    """Table rows without their wall time, which no two runs share."""
    return [{k: v for k, v in r.items() if k != "wall_time"} for r in rows]


@pytest.mark.slow  # 29 s alone on the shared 2-core box
def test_a_two_seed_sweep_trains_evaluates_compares_and_resumes_by_skipping(ray_session: Any,
                                                                           tmp_path: Path) -> None:
    cfg = SweepConfig(grid=("seed=0,1", "ddpg.actor_lr=1e-3"), out=str(tmp_path / "sweep"), evaluate_epochs=2)
    summary = run_sweep(cfg, TINY, _on_ray())
    rows = summary["trials"]
    names = ["seed=0,ddpg.actor_lr=1e-3", "seed=1,ddpg.actor_lr=1e-3"]
    assert [r["trial"] for r in rows] == names
    for r in rows:
        run = tmp_path / "sweep" / r["trial"]
        metrics = _rows(run / "metrics.csv")
        assert r["epochs"] == len(metrics) >= 4 and r["env_steps"] == int(metrics[-1]["env_steps"])
        assert r["finished"] and r["resumed_from"] == 0 and r["test_mwr"] != ""
        saved = json.loads((run / "config.json").read_text())
        assert (saved["seed"], saved["ddpg"]["actor_lr"]) == (int(r["trial"][5]), 1e-3)
    assert _rows(tmp_path / "sweep" / names[0] / "metrics.csv") != _rows(tmp_path / "sweep" / names[1] / "metrics.csv")
    group = summary["compare"]["groups"]
    assert [(g["group"], g["n_seeds"]) for g in group] == [("ddpg.actor_lr=1e-3/trained", 2)]
    assert sorted(group[0]["scores"]) == sorted(r["test_mwr"] for r in rows)
    assert (tmp_path / "sweep" / "compare" / "compare.csv").exists()
    with (tmp_path / "sweep" / "summary.csv").open() as fh:
        assert [r["trial"] for r in csv.DictReader(fh)] == names
    # Run again: both trials are finished, nothing is trained; other options are refused.
    before = {r["trial"]: (tmp_path / "sweep" / r["trial"] / "metrics.csv").read_bytes() for r in rows}
    again = run_sweep(cfg, TINY, _on_ray())
    assert [r["test_mwr"] for r in again["trials"]] == [r["test_mwr"] for r in rows]
    assert {t: (tmp_path / "sweep" / t / "metrics.csv").read_bytes() for t in before} == before
    with pytest.raises(ValueError, match="holds a sweep with other fixed train options"):
        run_sweep(cfg, TINY.__class__(**{**TINY.__dict__, "steps_per_epoch": 31}), _on_ray())
    # The same sweep on two processes of this machine (SweepConfig.workers): the rows and test MWRs of the one on Ray.
    local = dataclasses.replace(cfg, out=str(tmp_path / "local"), workers=2)
    on_processes = run_sweep(local, TINY, ProcessRunner(local.workers))
    assert [r["test_mwr"] for r in on_processes["trials"]] == [r["test_mwr"] for r in rows]
    for name in names:
        ray_rows, local_rows = (_rows(tmp_path / where / name / "metrics.csv") for where in ("sweep", "local"))
        assert _timeless(local_rows) == _timeless(ray_rows)


@pytest.mark.slow  # three tiny sweeps of two trials on two processes
def test_a_sweep_run_again_with_a_larger_budget_trains_its_trials_on_to_what_a_sweep_at_that_budget_makes(
        tmp_path: Path) -> None:
    """A larger epochs budget resumes every trial from its checkpoint; its rows and test MWRs are those of a sweep made
    at that budget. The smaller budget's evaluation and compare move to ``at-epochs-2/`` with the policies they
    played, ``sweep.json`` lists the growth, and a smaller budget or another option is refused, naming both values."""
    runner = ProcessRunner(2)
    small, large = (dataclasses.replace(TINY, epochs=e) for e in (2, 4))
    cfg = SweepConfig(grid=("seed=0,1",), out=str(tmp_path / "grown"), evaluate_epochs=2, workers=2)
    first = run_sweep(cfg, small, runner)
    before = {r["trial"]: (tmp_path / "grown" / r["trial"] / "policy.safetensors").read_bytes()
              for r in first["trials"]}
    grown = run_sweep(cfg, large, runner)
    straight = run_sweep(dataclasses.replace(cfg, out=str(tmp_path / "straight")), large, runner)
    assert [r["epochs"] for r in grown["trials"]] == [4, 4] and [r["resumed_from"] for r in grown["trials"]] == [2, 2]
    assert [r["test_mwr"] for r in grown["trials"]] == [r["test_mwr"] for r in straight["trials"]]
    for name in before:
        grown_rows, straight_rows = (_rows(tmp_path / where / name / "metrics.csv") for where in ("grown", "straight"))
        assert _timeless(grown_rows) == _timeless(straight_rows)
        kept = tmp_path / "grown" / "at-epochs-2" / "policies" / name / "policy.safetensors"
        assert kept.read_bytes() == before[name] != (tmp_path / "grown" / name / "policy.safetensors").read_bytes()
    aside = tmp_path / "grown" / "at-epochs-2"
    assert (aside / "evaluation").is_dir() and (aside / "compare" / "compare.csv").is_file()
    assert (tmp_path / "grown" / "compare" / "compare.csv").is_file()  # made again at the larger budget
    record = json.loads((tmp_path / "grown" / "sweep.json").read_text())
    assert [g["budget"] for g in record["grown"]] == [{"epochs": {"from": 2, "to": 4}}]
    assert record["base"]["epochs"] == 4
    with pytest.raises(ValueError, match=r"larger budget \(epochs: 4 then, 3 now\)"):
        run_sweep(cfg, dataclasses.replace(TINY, epochs=3), runner)
    with pytest.raises(ValueError, match=r"other fixed train options \(steps_per_epoch: 30 then, 31 now\)"):
        run_sweep(cfg, dataclasses.replace(large, steps_per_epoch=31), runner)


def _latest_epoch(latest: Path) -> int:
    try:
        return int(json.loads(latest.read_text())["epoch"])
    except (OSError, ValueError, KeyError):  # replaced between the check and the read
        return 0


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds Ray's worker processes through /proc")
@pytest.mark.slow  # 23 s alone on the shared 2-core box
def test_a_trial_whose_worker_is_killed_resumes_from_its_checkpoint(ray_session: Any, tmp_path: Path) -> None:
    # long enough that the kill lands mid-run: on the rim of env v1 a tiny match often ends in a few steps
    base = TINY.__class__(**{**TINY.__dict__, "epochs": 120, "steps_per_epoch": 40})
    cfg = SweepConfig(grid=("seed=3",), out=str(tmp_path / "sweep"))
    run = tmp_path / "sweep" / "seed=3"
    result: dict[str, Any] = {}
    thread = threading.Thread(target=lambda: result.update(summary=run_sweep(cfg, base, _on_ray())))
    thread.start()
    killed = None
    deadline = time.monotonic() + 120
    while killed is None and thread.is_alive() and time.monotonic() < deadline:
        # latest.json is written (atomically) once a checkpoint is whole; a checkpoint folder alone may be half written
        latest = run / "checkpoints" / "latest.json"
        if latest.is_file() and _latest_epoch(latest) < 60 and (pids := own_ray_workers("run_trial")):
            killed = pids[0]
            os.kill(killed, signal.SIGKILL)
        time.sleep(0.05)
    thread.join(timeout=300)
    assert killed is not None, "no trial worker was seen running after its first checkpoint"
    (trial,) = result["summary"]["trials"]
    assert trial["finished"] and not trial["error"]
    assert trial["resumed_from"] >= 2  # resumed from a checkpoint, not restarted
    epochs = [int(r["epoch"]) for r in _rows(run / "metrics.csv")]
    assert epochs == list(range(1, len(epochs) + 1)) and len(epochs) >= 40
    assert not list(tmp_path.glob("sweep/seed=3.old-*"))  # nothing was started over


def test_the_command_line_takes_repeated_grids_and_fixed_train_options(capsys: pytest.CaptureFixture[str]) -> None:
    import argparse

    from triplesumo import _dcargs
    from triplesumo.cli import _parser, main

    args = _parser().parse_args(["sweep", "--grid", "seed=0,1", "--grid", "ddpg.actor_lr=1e-4,1e-3", "scenario=paper",
                                 "--epochs", "7", "--ddpg.batch-size", "8", "--out", "runs/s", "--address", "auto"])
    scfg = _dcargs.build(SweepConfig, args)
    base = _dcargs.build(TrainConfig, argparse.Namespace(**{k: v for k, v in vars(args).items() if k != "out"}))
    assert scfg.grid == ("seed=0,1", "ddpg.actor_lr=1e-4,1e-3", "scenario=paper") and scfg.address == "auto"
    assert (base.epochs, base.ddpg.batch_size, base.out) == (7, 8, TrainConfig().out)
    # one --eval-seed for the sweep's evaluation after training and its trials' evaluations during it
    args = _parser().parse_args(["sweep", "--grid", "seed=0,1", "--eval-seed", "123", "--eval-every", "5000"])
    scfg = _dcargs.build(SweepConfig, args)
    base = _dcargs.build(TrainConfig, argparse.Namespace(**{k: v for k, v in vars(args).items() if k != "out"}))
    assert (scfg.eval_seed, base.eval_seed, base.eval_every) == (123, 123, 5000)
    assert main(["sweep", "--grid", "ddpg.actr_lr=1"]) == 2
    assert "ddpg has no field 'actr_lr'" in capsys.readouterr().err


def test_without_ray_sweep_and_ray_options_name_the_extra_and_sweep_runs_on_workers(tmp_path: Path) -> None:
    import subprocess
    import sys

    script = ("import sys; sys.modules['ray'] = None\n"
              "from triplesumo.cli import main\n"
              f"codes = [main(['sweep', '--grid', 'seed=0', '--out', {str(tmp_path / 's')!r}]),\n"
              f"         main(['evaluate', '--ray', '--epochs', '1', '--out', {str(tmp_path / 'e')!r}]),\n"
              f"         main(['tournament', '--ray', '--out', {str(tmp_path / 't')!r}]),\n"
              "         main(['sweep', '--grid', 'seed=0', '--workers', '1', '--epochs', '2',\n"
              "               '--steps-per-epoch', '10', '--n-envs', '1', '--no-tensorboard', '--no-progress',\n"
              f"               '--out', {str(tmp_path / 'w')!r}])]\n"
              "assert codes == [2, 2, 2, 0], codes\n"
              "assert not [m for m, v in sys.modules.items() if v is not None and m.split('.')[0] == 'ray']\n")
    err = subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1] / "src")}).stderr
    assert err.count('pip install "triplesumo[ray]"') == 3 and "--workers N" in err, err
    assert not (tmp_path / "s").exists()
    assert len(_rows(tmp_path / "w" / "seed=0" / "metrics.csv")) == 2  # --workers: trained without Ray


@pytest.mark.slow  # 24 s alone on the shared 2-core box
def test_bench_ray_reports_rates_per_core_figures_and_a_labelled_projection(ray_session: Any, tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture[str]) -> None:
    from triplesumo.benchmarks.ray import main

    assert main(["--epochs", "2", "--steps", "20", "--eval-epochs", "2", "--cores", "64", "--rllib", "64",
                 "--json", str(tmp_path / "b.json")]) == 0
    printed = capsys.readouterr().out
    result = json.loads((tmp_path / "b.json").read_text())
    v = result["variants"]
    assert v["sweep_2"]["env_steps"] > v["sweep_1"]["env_steps"] > 0
    assert v["evaluate_ray"]["env_steps"] == v["evaluate_local"]["env_steps"] > 0
    for row in v.values():
        assert row["env_steps_per_s"] == pytest.approx(row["env_steps"] / row["seconds"])
    assert result["per_core"]["sweep"] == pytest.approx(v["sweep_2"]["env_steps_per_s"] / 2)
    assert result["projection"]["sweep_env_steps_per_s"] == pytest.approx(64 * result["per_core"]["sweep"])
    assert "PROJECTION to 64 cores" in printed and "not measured" in printed
    assert v["rllib_ppo"]["env_steps"] >= 64 and v["trainer_ppo"]["env_steps"] >= 64  # the same budget each
    assert result["scaling"]["trainer_ppo_vs_rllib_ppo"] == pytest.approx(
        v["trainer_ppo"]["env_steps_per_s"] / v["rllib_ppo"]["env_steps_per_s"])
