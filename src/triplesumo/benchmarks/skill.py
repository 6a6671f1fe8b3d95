"""``triplesumo bench skill``: time to skill, the wall time and env steps until Bug's team first
reaches a test MWR of ``target`` (default +0.2), per algorithm.

For each algorithm Bug is trained with the project's own ``triplesumo train`` (``--learn
bug=ALGO``, the match of ``--train.*``: by default the paper's ongoing match of ``zoo:ant``
and ``zoo:spider``) in the run folder ``OUT/ALGO``, with the trainer's own evaluations
(``train --eval-every``): every ``eval_every`` env steps, at the step that crosses a multiple
of it, Bug's current policy plays frozen (no exploration) the same ``eval_epochs`` seeded
test matches (test match ``i`` resets with ``eval_seed + i``, as ``triplesumo evaluate``),
into ``OUT/ALGO/eval.csv``. The run stops at the first evaluation whose test MWR is
``>= target`` (*reached*, ``train --eval-target``) or at ``max_env_steps`` (*not reached*:
reported as such, with the best test MWR seen).

Times: ``train_seconds`` is the training's own wall time up to the evaluation's row (collection,
learning and checkpoints; the trainer's clock, carried across resumes), ``eval_seconds`` the time the
training spent on evaluations and ``wall_seconds`` both: the run's wall time when the test MWR was
known. With ``--train.eval-background`` the evaluations play in a worker process while Bug trains on
(the same curve in env steps: the same frozen policies on the same matches); a row is then written
when its evaluation is back, so the wall time to skill counts the training done meanwhile and none of
the earlier evaluations. Measured on the machine at hand, never projected.

The machine's speed goes with the times: ``machine.reference`` is the wall time per env step of a fixed
seeded collection (the run's ``n_envs`` matches of its match, uniform random actions, its MuJoCo threads;
:func:`reference_speed`), measured just before and just after the bench trains. Two boxes of the same name
(a shared cloud machine, at different hours) can differ by a factor of two; the reference tells a reader
which one a time came from.

Resumable: ``OUT/skill.json`` is rebuilt from each run's ``eval.csv``; a killed bench, run again
with the same options, resumes each run from its last checkpoint (exactly: the checkpoints hold
the replay, and the evaluations past the checkpoint are played again). The test-MWR curve
depends only on ``train``, ``eval_every``, ``eval_epochs`` and ``eval_seed``; ``target`` and
``max_env_steps`` may change between runs (the stop rule is applied to the recorded curve first, so a lower target
needs no training). Writes ``OUT/skill.json`` (and ``--json F``), ``OUT/skill.png`` (test
MWR against env steps and against training wall time, one line per algorithm) and prints a
table.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from triplesumo import _dcargs
from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.benchmarks import report
from triplesumo.envs.seeding import check_seed
from triplesumo.evaluation.metrics_csv import open_table, table_exists
from triplesumo.train import checkpoint
from triplesumo.train.config import ALGOS, TrainConfig
from triplesumo.train.loop import train
from triplesumo.train.machine import machine, reference_speed
from triplesumo.train.run_folder import holds_run

RECORD = "skill.json"
"""The bench's record and result in OUT (what ``triplesumo reproduce`` reads from ``OUT/skill``)."""
PLOT = "skill.png"
CURVE_DEPENDS_ON = ("train", "eval_every", "eval_epochs", "eval_seed")
"""The :class:`SkillConfig` fields the test-MWR curves depend on: a resumed bench must keep them."""


@dataclass(frozen=True)
class SkillConfig:
    """Time to skill: train Bug per algorithm, evaluate every eval_every env steps, stop at the target."""

    algos: tuple[str, ...] = ALGOS
    """Algorithms Bug learns with (ddpg td3 sac ppo, or one comma-separated item: ddpg,td3)."""
    target: float = 0.2
    """Stop at the first evaluation whose test MWR is >= this (in [-1, 1])."""
    eval_every: int = 50_000
    """Env steps between evaluations (each at the first epoch end past a multiple of it)."""
    eval_epochs: int = 200
    """Seeded test matches per evaluation (the same matches for every algorithm and evaluation)."""
    eval_seed: int = 10_000
    """Test match i resets with eval_seed + i."""
    max_env_steps: int = 1_000_000
    """Budget per algorithm: not reached when no evaluation up to this many env steps hits the target."""
    out: str = "runs/skill"
    """Folder of the run folders (OUT/ALGO), skill.json and skill.png."""
    json: str = ""
    """Also write the result as JSON to this file."""
    train: TrainConfig = field(default_factory=TrainConfig)
    """The training run (--train.*: match, policies of the others, hyper-parameters, seed, n_envs); the bench
    sets its out, name, learn (bug=ALGO), epochs and max_env_steps."""

    def __post_init__(self) -> None:
        check_seed(self.eval_seed, "SkillConfig.eval_seed")
        algos = tuple(a for item in self.algos for a in str(item).split(",") if a)
        object.__setattr__(self, "algos", algos)
        if not algos or len(set(algos)) < len(algos) or any(a not in ALGOS for a in algos):
            raise ValueError(f"SkillConfig.algos must be among {ALGOS}, non-empty and without repeats, got {algos}")
        if isinstance(self.target, bool) or not isinstance(self.target, int | float) or not -1 <= self.target <= 1:
            raise ValueError(f"SkillConfig.target must be a test MWR in [-1, 1], got {self.target!r}")
        for name in ("eval_every", "eval_epochs", "max_env_steps"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"SkillConfig.{name} must be an int >= 1, got {value!r}")
        if self.max_env_steps < self.eval_every:
            raise ValueError(f"SkillConfig.max_env_steps ({self.max_env_steps}) must be >= eval_every "
                             f"({self.eval_every}): no evaluation would be made")
        set_here = [f"train.{name}" for name in ("out", "name", "learner", "learn", "epochs", "max_env_steps",
                                                 "eval_every", "eval_epochs", "eval_seed", "eval_target")
                    if getattr(self.train, name) != getattr(TrainConfig(), name)]
        if set_here:
            raise ValueError(f"SkillConfig.{set_here[0]} is set by the bench (Bug learns each of algos in OUT/ALGO "
                             "up to max_env_steps, evaluated every eval_every): leave it out")

    def run_config(self, algo: str) -> TrainConfig:
        """The train config of ``algo``'s run: evaluated every eval_every, stopped at the target or the budget."""
        return dataclasses.replace(self.train, out=str(Path(self.out).resolve()), name=algo, learn=(f"bug={algo}",),
                                   epochs=10**9, max_env_steps=self.max_env_steps, eval_every=self.eval_every,
                                   eval_epochs=self.eval_epochs, eval_seed=self.eval_seed, eval_target=self.target)


def _depends(cfg: SkillConfig) -> dict[str, Any]:
    values: dict[str, Any] = json.loads(json.dumps({k: dataclasses.asdict(cfg)[k] for k in CURVE_DEPENDS_ON}))
    for name in ("progress", "tensorboard", "out", "name", "eval_background"):  # (how it shows or where it
        # plays, or set per algorithm by the bench)
        values["train"].pop(name)
    return values


def _curve(cfg: SkillConfig, run_dir: Path) -> list[dict[str, Any]]:
    """The evaluations of a run, from its ``eval.csv`` (none yet: empty), with the multiple of eval_every each
    crossed (``budget``)."""
    path = run_dir / "eval.csv"
    if not table_exists(path):
        return []
    with open_table(path) as fh:
        rows = list(csv.DictReader(fh))

    def number(x: str) -> float | None:
        return float(x) if math.isfinite(float(x)) else None

    return [{"env_steps": int(r["env_steps"]), "budget": int(r["env_steps"]) // cfg.eval_every * cfg.eval_every,
             "test_mwr": float(r["test_mwr"]), "test_mwr_lo": number(r["test_mwr_lo"]),
             "test_mwr_hi": number(r["test_mwr_hi"]), "n_win": int(r["n_win"]), "n_loss": int(r["n_loss"]),
             "n_draw": int(r["n_draw"]), "train_seconds": float(r["train_seconds"]),
             "eval_seconds": float(r["eval_seconds"]),
             "wall_seconds": round(float(r["train_seconds"]) + float(r["eval_seconds"]), 3)} for r in rows]


def outcome(cfg: SkillConfig, evaluations: list[dict[str, Any]]) -> dict[str, Any]:
    """The stop rule on a curve: the first evaluation with test MWR >= target (reached), else whether the
    budget is spent (not reached) or training goes on. Evaluations past max_env_steps (a raised budget,
    later lowered) do not count."""
    within = [e for e in evaluations if e["budget"] <= cfg.max_env_steps]  # a prefix: budgets grow
    for k, e in enumerate(within):
        if e["test_mwr"] >= cfg.target:
            return {"status": "reached", "reached": True, "at": k, "env_steps": e["env_steps"],
                    "train_seconds": e["train_seconds"], "wall_seconds": e["wall_seconds"]}
    spent = bool(within) and within[-1]["budget"] + cfg.eval_every > cfg.max_env_steps  # no evaluation left
    best = max(within, key=lambda e: e["test_mwr"]) if within else None
    return {"status": "not reached" if spent else "running", "reached": False, "at": None, "env_steps": None,
            "train_seconds": None, "wall_seconds": None,
            "best_test_mwr": None if best is None else best["test_mwr"],
            "best_at_env_steps": None if best is None else best["env_steps"]}


def _bench_algo(cfg: SkillConfig, algo: str) -> list[dict[str, Any]]:
    """Train (or resume) ``algo``'s run until the stop rule decides on its curve; returns the curve."""
    run_cfg = cfg.run_config(algo)
    run_dir = Path(run_cfg.out) / run_cfg.name
    if outcome(cfg, _curve(cfg, run_dir))["status"] == "running":
        if checkpoint.checkpoints(run_dir):  # goes on from the last checkpoint, to this bench's budget and target
            train(run_cfg, resume_dir=run_dir, overrides={"max_env_steps": cfg.max_env_steps,
                                                           "eval_target": cfg.target})
        else:
            train(run_cfg, start_over=holds_run(run_dir))
    return _curve(cfg, run_dir)


def run_skill(cfg: SkillConfig) -> dict[str, Any]:
    """Run (or resume) the bench for every algorithm; writes OUT/skill.json, OUT/skill.png; returns the result."""
    out = Path(cfg.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    path = out / RECORD
    old = json.loads(path.read_text()) if path.exists() else None
    if old is not None and old["depends_on"] != _depends(cfg):
        changed = [k for k in CURVE_DEPENDS_ON if old["depends_on"].get(k) != _depends(cfg)[k]]
        raise ValueError(f"{out} holds a skill bench made with other {', '.join(changed)}; its curves would not "
                         "continue: give the same options, or choose another --out")
    result: dict[str, Any] = {
        "config": json.loads(json.dumps(dataclasses.asdict(cfg))), "depends_on": _depends(cfg),
        "command": " ".join(["triplesumo", "bench", "skill", *_dcargs.to_argv(cfg)]),
        "target": cfg.target, "eval_every": cfg.eval_every, "eval_epochs": cfg.eval_epochs,
        "max_env_steps": cfg.max_env_steps, "machine": machine(cfg.train), "algos": {}}
    result["machine"]["reference"] = {"before": reference_speed(cfg.train)}

    for algo in cfg.algos:
        print(f"bench skill: Bug with {algo}, target test MWR {cfg.target:+.2f}")
        evaluations = _bench_algo(cfg, algo)
        result["algos"][algo] = {"evaluations": evaluations, **outcome(cfg, evaluations), "run_dir": str(out / algo)}
        atomic_write_bytes(path, (json.dumps(result, indent=2) + "\n").encode())
    result["machine"]["reference"]["after"] = reference_speed(cfg.train)
    atomic_write_bytes(path, (json.dumps(result, indent=2) + "\n").encode())
    plot_skill(result, out / PLOT)
    report(format_skill(result), result, cfg.json or None)
    return result


def plot_skill(result: dict[str, Any], path: Path) -> Path:
    """Test MWR against env steps and against training wall time, one line per algorithm, the target dashed."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, 2, sharey=True)
    for algo, entry in result["algos"].items():
        ev = entry["evaluations"]
        label = algo + ("" if entry["reached"] else " (not reached)")
        for ax, key in zip(axes, ("env_steps", "train_seconds"), strict=True):
            ax.plot([e[key] for e in ev], [e["test_mwr"] for e in ev], marker="o", label=label)
            if entry["reached"]:
                ax.plot([entry[key]], [ev[entry["at"]]["test_mwr"]], marker="*", markersize=14, color="black")
    for ax, xlabel in zip(axes, ("env steps", "training wall time (s)"), strict=True):
        ax.axhline(result["target"], linestyle="--", color="grey", label=f"target {result['target']:+.2f}")
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"test MWR ({result['eval_epochs']} seeded test matches)")
    axes[0].legend(fontsize=8)
    fig.suptitle("time to skill: Bug's test MWR while training (star: first evaluation at the target)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def format_skill(result: dict[str, Any]) -> str:
    """The table printed by the bench (also the reproduction report's)."""
    m = result.get("machine")
    where = ("" if m is None else
             f"measured on {m['cores']} CPU cores ({m['cpu']}), backend {m['backend']} on "
             f"{m['gpu'] or m['device']}, {m['n_threads']} MuJoCo / {m['torch_threads']} torch threads"
             + ("" if m["gpu"] else "; GPU: not measured")
             + "".join(f"\nreference collection {when} the bench: {r['ms_per_env_step']:.3f} ms per env step "
                       f"({r['env_steps']:,} env steps, best of {r['repeats']})"
                       for when, r in m.get("reference", {}).items()))
    lines = [f"time to skill: first test MWR >= {result['target']:+.2f} ({result['eval_epochs']} seeded test "
             f"matches every {result['eval_every']:,} env steps, budget {result['max_env_steps']:,})",
             *([where] if where else []), "",
             f"{'algo':6s} {'reached':>11s} {'env steps':>11s} {'train (s)':>10s} {'with eval (s)':>13s} "
             f"{'evals':>5s}  test MWR curve"]
    for algo, e in result["algos"].items():
        curve = " ".join(f"{x['test_mwr']:+.2f}" for x in e["evaluations"])
        if e["reached"]:
            lines.append(f"{algo:6s} {'yes':>11s} {e['env_steps']:11,d} {e['train_seconds']:10.0f} "
                         f"{e['wall_seconds']:13.0f} {len(e['evaluations']):5d}  {curve}")
        else:
            best = "" if e.get("best_test_mwr") is None else f" (best {e['best_test_mwr']:+.3f})"
            lines.append(f"{algo:6s} {e['status']:>11s} {'-':>11s} {'-':>10s} {'-':>13s} "
                         f"{len(e['evaluations']):5d}  {curve}{best}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="triplesumo bench skill", description=__doc__.split("\n\n")[0])
    _dcargs.add_arguments(parser, SkillConfig)
    run_skill(_dcargs.build(SkillConfig, parser.parse_args(argv)))
    return 0
