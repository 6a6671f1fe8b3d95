"""``triplesumo sweep``: a grid of ``triplesumo train`` runs as tasks (on Ray from the command line), resumable,
with one summary.

The grid names any :class:`~triplesumo.train.config.TrainConfig` field by its dotted
name with its values (``seed=0,1,2``, ``ddpg.actor_lr=1e-4,1e-3``, ``scenario=paper,2v2``);
every combination is one *trial*: a ``triplesumo train`` run with the sweep's fixed train
options and the trial's values, in the run folder ``OUT/NAME`` where NAME joins the
trial's values (``seed=0,ddpg.actor_lr=1e-4``). Values are read with the field's type;
a tuple field takes its items separated by spaces (``policies=ant=zoo:ant spider=random``).

Trials run as tasks of the runner :func:`run_sweep` is handed (:func:`run_trials`; the command
line hands down :class:`triplesumo.integrations.ray_tasks.RayRunner`, so trials are Ray tasks, or with ``--workers``
a :class:`~triplesumo.evaluation.parallel.ProcessRunner` of this machine's processes),
not Ray Tune trials: recovery is the project's own. A trial is :func:`run_trial`: it
resumes its run folder from the last checkpoint when one exists
(``train(..., resume_dir=...)``), else it starts the run. So a trial whose worker dies is
run again by Ray and resumes, rows and replay buffer intact; a sweep run again skips
finished trials and resumes the others. Run again with a larger budget (``epochs``, ``max_env_steps``: the one
change of the fixed train options it takes), every trial trains on from its checkpoint and ends as a trial made at
that budget would; the evaluation and compare of the smaller one move to ``OUT/at-<budget>/`` (:func:`set_aside`).
Tune would add a second checkpoint system, an
experiment state and a per-epoch report hook in the trainer, for nothing a grid needs.

The summary (``summary.csv``, ``summary.json``): per trial its values, epochs, env
steps, the final training MWR (over the last ``window`` epochs) and whether it was
resumed. With ``evaluate_epochs`` each *group* (the trials that differ only in ``seed``)
is evaluated (``triplesumo evaluate`` with one policy per seed, its test epochs as Ray
tasks, into ``OUT/evaluation/GROUP``), each trial gets its test MWR, and the
``compare`` table across seeds (IQM with bootstrap intervals, by group) is written to
``OUT/compare``.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime
import io
import itertools
import json
import math
import shutil
import typing
from collections.abc import Callable, Mapping, Sequence
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from triplesumo._lock import held
from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.envs.seeding import check_seed
from triplesumo.evaluation.metrics import moving_winning_rate
from triplesumo.evaluation.metrics_csv import open_table, table_exists, write_table
from triplesumo.evaluation.parallel import TaskRunner, check_counts
from triplesumo.train import checkpoint
from triplesumo.train.config import TrainConfig, typed_value
from triplesumo.train.loop import train
from triplesumo.train.run_folder import config_to_json, holds_run, training_done

RECORD_FILE = "sweep.json"
SUMMARY_COLUMNS = ("trial", "group", "epochs", "env_steps", "final_mwr", "resumed_from", "seconds", "test_mwr",
                   "error", "run_dir")


@dataclass(frozen=True)
class SweepConfig:
    """A grid of training runs as Ray tasks, or on this machine's processes (``workers``); the fixed train options
    come beside it."""

    grid: tuple[str, ...] = ()
    """FIELD=V1,V2,...: a TrainConfig field by dotted name (seed, ddpg.actor_lr, scenario, ...) and its
    values; every combination is one trial. Tuple fields take space-separated items."""
    out: str = "runs/sweep"
    """Sweep folder: one run folder per trial, sweep.json, summary.csv/json, evaluation/, compare/."""
    address: str = ""
    """Ray cluster to run on (e.g. auto, ray://HOST:10001); empty: start a local Ray on this machine."""
    num_cpus: int = 0
    """Local Ray only: CPUs it may use (0: all)."""
    cpus_per_trial: int = 1
    """CPUs Ray reserves for each trial (a trial trains on one MuJoCo thread plus its update thread)."""
    max_retries: int = 3
    """Times Ray runs a task again whose worker died (a trial resumes from its last checkpoint; a chunk of the
    evaluation after training replays exactly)."""
    workers: int = 0
    """Run the trials, and the evaluation after them, on this many processes of this machine instead of Ray (0: on
    Ray). Needs no Ray. The outputs are those of a sweep on Ray; a trial whose process dies is not run again here, and
    re-running the sweep resumes it from its last checkpoint."""
    evaluate_epochs: int = 0
    """Test epochs per trial's policy after training (0: no evaluation and no compare table)."""
    eval_seed: int = 10_000
    """Test epoch i resets with eval_seed + i (the same starts for every trial)."""

    def __post_init__(self) -> None:
        check_seed(self.eval_seed, "SweepConfig.eval_seed")
        for name, low in (("num_cpus", 0), ("cpus_per_trial", 1), ("max_retries", 0), ("evaluate_epochs", 0),
                          ("workers", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"SweepConfig.{name} must be an int >= {low}, got {value!r}")
        if self.address and self.num_cpus:
            raise ValueError("SweepConfig.num_cpus sizes a local Ray; a cluster (address) has its own CPUs")
        if self.workers and (self.address or self.num_cpus):
            raise ValueError("SweepConfig.workers runs the trials on this machine's processes, not on Ray: leave out "
                             "SweepConfig.address and SweepConfig.num_cpus")
        parse_grid(self.grid)


def _field_type(dotted: str) -> Any:
    """The type of TrainConfig field ``dotted`` (``ddpg.actor_lr``); errors list the fields there."""
    cls: Any = TrainConfig
    parts = dotted.split(".")
    for k, part in enumerate(parts):
        hints = typing.get_type_hints(cls)
        if part not in hints:
            where = ".".join(parts[:k]) or "TrainConfig"
            raise ValueError(f"--grid {dotted}: {where} has no field {part!r} (its fields: {', '.join(hints)})")
        cls = hints[part]
        if k < len(parts) - 1 and not dataclasses.is_dataclass(cls):
            raise ValueError(f"--grid {dotted}: {'.'.join(parts[:k + 1])} is not a group of fields")
    if dataclasses.is_dataclass(cls):
        raise ValueError(f"--grid {dotted}: a group of fields; name one of them ({dotted}.FIELD)")
    return cls


def field_value(dotted: str, raw: str) -> Any:
    """The value ``raw`` typed for TrainConfig field ``dotted`` (``reward.still``, ``"-1"`` -> ``-1.0``)."""
    return typed_value(_field_type(dotted), raw, f"--grid {dotted}={raw}")


def parse_grid(grid: tuple[str, ...]) -> list[tuple[str, list[tuple[str, Any]]]]:
    """``("seed=0,1", "ddpg.actor_lr=1e-4,1e-3")`` -> ``[("seed", [("0", 0), ("1", 1)]), ...]``:
    each field with its values as given and as typed."""
    out: list[tuple[str, list[tuple[str, Any]]]] = []
    for item in grid:
        key, sep, values = item.partition("=")
        if not sep or not key or not values:
            raise ValueError(f"--grid expects FIELD=V1,V2,..., got {item!r}")
        if key in ("out", "name"):
            raise ValueError(f"--grid {key}: the sweep sets it (run folders are OUT/<trial values>)")
        if key in (k for k, _ in out):
            raise ValueError(f"--grid {key} given twice")
        tp = _field_type(key)
        raws = [v.strip() for v in values.split(",")]
        if "" in raws or len(set(raws)) < len(raws):
            raise ValueError(f"--grid {key}: values must be non-empty and different, got {values!r}")
        out.append((key, [(raw, typed_value(tp, raw, f"--grid {key}={raw}")) for raw in raws]))
    return out


def with_field(cfg: Any, dotted: str, value: Any) -> Any:
    """``cfg`` with field ``dotted`` (``ddpg.actor_lr``) set to ``value`` (nested dataclasses replaced)."""
    head, _, rest = dotted.partition(".")
    return dataclasses.replace(cfg, **{head: with_field(getattr(cfg, head), rest, value) if rest else value})


def _safe(text: str) -> str:
    return "".join("-" if c in "/\\" else "+" if c.isspace() else c for c in text)


@dataclass(frozen=True)
class Trial:
    """One combination of the grid: its run and the group it is compared in."""

    name: str
    """Run name: the grid values, ``seed=0,ddpg.actor_lr=1e-4`` (``base`` for an empty grid)."""
    group: str
    """The non-seed values (``all`` when only seeds vary): the trials compared across seeds."""
    config: TrainConfig


def trials(cfg: SweepConfig, base: TrainConfig) -> list[Trial]:
    """Every combination of the grid over ``base``, as train configs in ``cfg.out`` (absolute)."""
    grid = parse_grid(cfg.grid)
    out = str(Path(cfg.out).resolve())
    made = []
    for combo in itertools.product(*(values for _, values in grid)):
        train_cfg = dataclasses.replace(base, out=out, progress=False)
        for (key, _), (raw, value) in zip(grid, combo, strict=True):
            try:
                train_cfg = with_field(train_cfg, key, value)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"--grid {key}={raw}: {exc}") from None
        values = [f"{key}={_safe(raw)}" for (key, _), (raw, _) in zip(grid, combo, strict=True)]
        name = ",".join(values) or "base"
        group = ",".join(v for v in values if not v.startswith("seed=")) or "all"
        made.append(Trial(name, group, dataclasses.replace(train_cfg, name=name)))
    return made


def run_trial(cfg: TrainConfig) -> dict[str, Any]:
    """Train ``cfg``'s run to its epochs: resumed from its last checkpoint when its folder holds one,
    started (a folder without a checkpoint is moved aside first) otherwise. What a Ray task runs."""
    run_dir = Path(cfg.out) / cfg.name
    saved = checkpoint.checkpoints(run_dir)
    resumed_from = 0
    if saved and (run_dir / "config.json").exists():
        resumed_from = saved[-1][0]
        # the trial's budget, which may have grown since (a run at its old budget goes on to the new one)
        result = train(cfg, resume_dir=run_dir, overrides={"epochs": cfg.epochs, "max_env_steps": cfg.max_env_steps})
    else:
        result = train(cfg, start_over=holds_run(run_dir))
    return {"trial": cfg.name, "run_dir": str(result.run_dir), "resumed_from": resumed_from,
            "seconds": round(result.seconds, 3), "env_steps_here": result.env_steps}


def run_trials(runner: TaskRunner, configs: Sequence[TrainConfig],
               on_done: Callable[[int, dict[str, Any]], None] | None = None,
               cpus_per_trial: int = 1) -> list[dict[str, Any]]:
    """Train every config of ``configs`` as a task of ``runner`` (:func:`run_trial`); results in ``configs``
    order, each handed to ``on_done(index, result)`` as it finishes. On Ray a task whose worker dies is run
    again and resumes its run from the last checkpoint; a trial that fails for good gives
    ``{"trial", "error"}`` and the others go on."""
    check_counts(cpus_per_trial=cpus_per_trial)
    results: dict[int, dict[str, Any]] = {}
    with closing(runner(run_trial, [(cfg,) for cfg in configs], cpus=cpus_per_trial)) as finished:
        for k, get in finished:
            try:
                results[k] = get()
            except Exception as exc:  # the trial failed (or, on Ray, its retries ran out): the others go on
                cause = getattr(exc, "cause", None) or exc  # (Ray's task error carries the trial's own)
                last = str(cause).strip().splitlines()[-1:] or [""]
                results[k] = {"trial": getattr(configs[k], "name", str(k)),
                              "error": f"{type(cause).__name__}: {last[0]}"}
            if on_done is not None:
                on_done(k, results[k])
    return [results[k] for k in range(len(configs))]


def finished(trial: Trial) -> bool:
    """Whether the trial's run holds a checkpoint at its budget (epochs, or ``max_env_steps``)."""
    return training_done(trial.config, Path(trial.config.out) / trial.name)


def run_facts(run_dir: Path, window: int) -> dict[str, Any]:
    """Epochs, env steps and the final MWR (last ``window`` epochs) of a one-learner run, from its ``metrics.csv``."""
    with open_table(run_dir / "metrics.csv") as fh:
        rows = list(csv.DictReader(fh))
    lwr = np.array([float(r["local_winning_rate"]) for r in rows])
    mwr = float(moving_winning_rate(lwr[-window:], window)[-1]) if len(lwr) else 0.0
    return {"epochs": len(rows), "env_steps": int(rows[-1]["env_steps"]) if rows else 0, "final_mwr": mwr}


GROWABLE = ("epochs", "max_env_steps")
"""The fixed train options a sweep run again may raise: its trials train on from their checkpoints to the new budget
and end as trials made at it would (:func:`run_trial`)."""
GROWN_STALE = ("evaluation", "compare")
"""What a grown budget makes stale in a sweep's folder: it is set aside (:func:`set_aside`), then made again."""


def budget_grows(then: Any, now: Any) -> bool:
    """Whether a training budget (epochs, env steps) given ``now`` is larger than the one recorded ``then``; 0 (no
    limit) is the largest."""
    if isinstance(then, bool) or isinstance(now, bool) or not isinstance(then, int) or not isinstance(now, int):
        return False
    return then != 0 and (now == 0 or now > then)


def budget_changes(then: Mapping[str, Any], now: Mapping[str, Any],
                   fields: Sequence[str]) -> tuple[dict[str, dict[str, Any]], list[str]]:
    """Of the budget ``fields``, those ``now`` grows over ``then`` (``{field: {"from": old, "to": new}}``,
    :func:`budget_grows`) and those it changes otherwise (a shrink: to be refused)."""
    grown = {k: {"from": then.get(k), "to": now.get(k)} for k in fields if budget_grows(then.get(k), now.get(k))}
    return grown, [k for k in fields if then.get(k) != now.get(k) and k not in grown]


def set_aside(out: Path, names: Sequence[str], grown: dict[str, dict[str, Any]],
              runs: Sequence[Path]) -> tuple[Path, list[str]]:
    """Before runs train on to a grown budget: move ``out/NAME`` for each of ``names`` there is to
    ``out/at-<budget>/`` (``at-max-env-steps-100000``), with a copy of each run's ``policy.*`` under
    ``policies/<the run's path in out>/`` (a run's policy is replaced when it trains on). Returns that folder and the
    names moved; nothing is deleted. ``FileExistsError`` if the folder exists."""
    label = "-".join(f"{k.replace('_', '-')}-{v['from']}" for k, v in grown.items())
    aside = out / f"at-{label}"
    if aside.exists():
        raise FileExistsError(f"cannot set aside what the smaller budget made: {aside} exists already")
    aside.mkdir()
    moved = []
    for name in names:
        if (out / name).exists():
            (out / name).rename(aside / name)
            moved.append(name)
    for run in runs:
        kept = aside / "policies" / Path(run).resolve().relative_to(out.resolve())
        for f in sorted(run.glob("policy.*")):
            kept.mkdir(parents=True, exist_ok=True)
            shutil.copy2(f, kept / f.name)
    return aside, moved


def _check_record(out: Path, record: dict[str, Any], runs: Sequence[Path]) -> None:
    """Write the sweep's record, or check that the one in ``out`` has the same grid and fixed train options but for
    budgets that grow (:data:`GROWABLE`); a grown budget sets aside the evaluation made at the smaller one and is
    listed under ``grown``."""
    path = out / RECORD_FILE
    if not path.exists():
        atomic_write_bytes(path, (json.dumps(record, indent=2) + "\n").encode())
        return
    old = json.loads(path.read_text(encoding="utf-8"))
    then, now = old.get("base", {}), record["base"]

    def both(keys: list[str]) -> str:
        return ", ".join(f"{k}: {then.get(k)!r} then, {now.get(k)!r} now" for k in keys)

    if old.get("grid") != record["grid"]:
        raise ValueError(f"{out} holds a sweep with other grid ({old.get('grid')} then, {record['grid']} now): "
                         "re-running a sweep resumes it and needs the same options; choose another --out")
    grown, shrunk = budget_changes(then, now, GROWABLE)
    if shrunk:
        raise ValueError(f"{out} holds a sweep whose trials trained to a larger budget ({both(shrunk)}): a budget "
                         "can grow on a re-run, not shrink; choose another --out")
    differ = sorted(k for k in {*then, *now} if k not in GROWABLE and then.get(k) != now.get(k))
    if differ:
        raise ValueError(f"{out} holds a sweep with other fixed train options ({both(differ)}): re-running a sweep "
                         "resumes it and needs the same options but for a larger budget (epochs, max_env_steps); "
                         "choose another --out")
    if grown:
        aside, moved = set_aside(out, GROWN_STALE, grown, runs)
        entry = {"budget": grown, "at": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
                 "folder": aside.name, "moved": moved}
        atomic_write_bytes(path, (json.dumps({**record, "grown": [*old.get("grown", []), entry]}, indent=2)
                                  + "\n").encode())
        print(f"sweep {out}: budget grown (" + ", ".join(f"{k} {v['from']:,} -> {v['to']:,}" for k, v in grown.items())
              + f"): the trials train on from their checkpoints; what the smaller budget made is kept in {aside}")


def run_sweep(cfg: SweepConfig, base: TrainConfig | None, runner: TaskRunner) -> dict[str, Any]:
    """Run (or resume) the sweep's trials as tasks of ``runner`` (the command line hands down a
    :class:`~triplesumo.integrations.ray_tasks.RayRunner` built from ``cfg.address``, ``num_cpus`` and
    ``max_retries``), evaluate and compare when asked (on the same runner), write the summary; returns it."""
    out = Path(cfg.out).resolve()
    with held(out, "sweep"):  # one sweep per folder (each trial holds its own run folder)
        return _run_sweep(cfg, base or TrainConfig(), runner, out)


def _run_sweep(cfg: SweepConfig, base: TrainConfig, runner: TaskRunner, out: Path) -> dict[str, Any]:
    todo_all = trials(cfg, base)
    canonical = {k: v for k, v in config_to_json(dataclasses.replace(base, progress=False)).items()
                 if k not in ("out", "name")}  # what the sweep sets itself
    _check_record(out, {"grid": list(cfg.grid), "base": canonical}, [Path(t.config.out) / t.name for t in todo_all])
    results_path = out / "trials.json"
    previous = json.loads(results_path.read_text()) if results_path.exists() else {}
    todo = [t for t in todo_all if not finished(t)]
    print(f"sweep {out}: {len(todo_all)} trials, {len(todo_all) - len(todo)} finished already, {len(todo)} to train")

    def done(k: int, result: dict[str, Any]) -> None:
        previous[todo[k].name] = result
        atomic_write_bytes(results_path, (json.dumps(previous, indent=2) + "\n").encode())
        state = f"error: {result['error']}" if "error" in result else (
            f"{result['seconds']:.0f} s" + (f", resumed from epoch {result['resumed_from']}"
                                            if result["resumed_from"] else ""))
        print(f"  trial {todo[k].name}: {state}")

    evaluation: dict[str, dict[str, Any]] = {}
    compare_table = None
    run_trials(runner, [t.config for t in todo], done, cfg.cpus_per_trial)
    if cfg.evaluate_epochs:
        evaluation, compare_table = _evaluate(cfg, out, [t for t in todo_all if finished(t)], runner)
    summary = _summary(cfg, out, todo_all, previous, evaluation, compare_table)
    return summary


def _evaluate(cfg: SweepConfig, out: Path, done: list[Trial],
              runner: TaskRunner) -> tuple[dict[str, dict[str, Any]], Any]:
    """Each group's policies evaluated in one folder (by ``runner``); the compare table across seeds."""
    from triplesumo.evaluation.compare import CompareConfig, compare
    from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate

    groups: dict[str, list[Trial]] = {}
    for t in done:
        groups.setdefault(t.group, []).append(t)
    test_mwr: dict[str, dict[str, Any]] = {}
    folders = []
    for group, members in groups.items():
        first = members[0].config
        folder = out / "evaluation" / _safe(group)
        folder.mkdir(parents=True, exist_ok=True)  # (a name like ddpg.actor_lr=1e-4 looks like a file to evaluate)
        policies = {str(Path(t.config.out) / t.name / "policy"): t.name for t in members}
        learner = next(iter(first.learners()))  # (the seat each policy plays: the group's first learner)
        ecfg = EvaluateConfig(learner=learner, policy=tuple(policies), policies=first.policies, baselines=(),
                              epochs=cfg.evaluate_epochs, seed=cfg.eval_seed, steps_per_epoch=first.steps_per_epoch,
                              obs_mode=first.obs_mode, scenario=first.scenario, window=first.window,
                              out=str(folder), n_threads=1, progress=False,
                              resume=(folder / "evaluation.json").exists(), ray=True,
                              ray_chunk=max(1, min(50, math.ceil(cfg.evaluate_epochs / 4))))
        summary = evaluate(ecfg, runner)
        for c in summary["candidates"].values():
            test_mwr[policies[c["policy"]]] = {"test_mwr": c["mean_lwr"], "group": group}
        folders.append(str(folder))
    table = compare(CompareConfig(folders=tuple(folders), by="folder", out=str(out / "compare"), seed=cfg.eval_seed))
    return test_mwr, table


def _summary(cfg: SweepConfig, out: Path, all_trials: list[Trial], results: dict[str, Any],
             evaluation: dict[str, dict[str, Any]], table: Any) -> dict[str, Any]:
    rows = []
    for t in all_trials:
        run_dir = Path(t.config.out) / t.name
        result = results.get(t.name, {})
        facts = run_facts(run_dir, t.config.window) if table_exists(run_dir / "metrics.csv") else {}
        rows.append({"trial": t.name, "group": t.group, **facts, "resumed_from": result.get("resumed_from", ""),
                     "seconds": result.get("seconds", ""), "error": result.get("error", ""),
                     "test_mwr": evaluation.get(t.name, {}).get("test_mwr", ""), "run_dir": str(run_dir),
                     "finished": finished(t)})
    summary = {"config": dataclasses.asdict(cfg), "trials": rows, "compare": table}
    buf = io.StringIO()
    writer = csv.DictWriter(buf, SUMMARY_COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_table(out / "summary.csv", buf.getvalue().encode())
    atomic_write_bytes(out / "summary.json", (json.dumps(summary, indent=2, default=str) + "\n").encode())
    return summary


def format_sweep(summary: dict[str, Any]) -> str:
    """The per-trial table printed by ``triplesumo sweep`` (and the compare table when there is one)."""
    lines = [f"{'trial':40s} {'epochs':>6s} {'env steps':>9s} {'final MWR':>9s} {'test MWR':>8s}  resumed"]
    for r in summary["trials"]:
        mwr = "-" if "final_mwr" not in r else f"{r['final_mwr']:+.3f}"
        test = "-" if r["test_mwr"] in ("", None) else f"{r['test_mwr']:+.3f}"
        resumed = f"from epoch {r['resumed_from']}" if r["resumed_from"] else ("error" if r["error"] else "-")
        lines.append(f"{r['trial'][:40]:40s} {r.get('epochs', 0):6d} {r.get('env_steps', 0):9d} {mwr:>9s} "
                     f"{test:>8s}  {resumed}")
    if summary["compare"] is not None:
        from triplesumo.evaluation.compare import format_compare

        lines += ["", format_compare(summary["compare"])]
    return "\n".join(lines)
