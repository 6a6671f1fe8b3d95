"""``triplesumo bench skill``: time to skill, the wall time and env steps until Bug's team first
reaches a test MWR of ``target`` (the issue's +0.2), per algorithm.

For each algorithm Bug is trained with the project's own ``triplesumo train`` (``--learn
bug=ALGO``, the match of ``--train.*``: by default the paper's ongoing match of ``zoo:ant``
and ``zoo:spider``) in the run folder ``OUT/ALGO``. Every ``eval_every`` env steps the run
stops at the next epoch end after a checkpoint (``train --max-env-steps``), and the Bug policy
it wrote there is evaluated, frozen (no exploration), on the same ``eval_epochs`` seeded test
matches (:func:`~triplesumo.evaluation.evaluate.play_test_epochs`; test match ``i`` resets
with ``eval_seed + i``, as ``triplesumo evaluate``). Training resumes from that checkpoint
(an exact resume: the chunks train what one uninterrupted run trains) until the first
evaluation whose test MWR is ``>= target`` (*reached*) or until ``max_env_steps``
(*not reached*: reported as such, with the best test MWR seen).

Times: ``train_seconds`` is the training loop's own wall time (collection, learning and the
checkpoints at the evaluation points), ``wall_seconds`` adds the evaluations and the
reloading of each chunk's checkpoint (what running the bench took). Both are measured on
the machine at hand, never projected.

Resumable: ``OUT/skill.json`` is rewritten after each evaluation; a killed bench, run again
with the same options, goes on from the last checkpoint of each run (an evaluation lost with
the kill is played again on the same policy). The test-MWR curve depends only on ``train``,
``eval_every``, ``eval_epochs`` and ``eval_seed``; ``target`` and ``max_env_steps`` may
change between runs (the stop rule is applied to the recorded curve first, so a lower target
needs no training). Writes ``OUT/skill.json`` (and ``--json F``), ``OUT/skill.png`` (test
MWR against env steps and against training wall time, one line per algorithm) and prints a
table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from triplesumo import _dcargs
from triplesumo.agents.policy_file import atomic_write_bytes, load_json
from triplesumo.agents.zoo import expand_pairs, make_policy, policies_from_pairs
from triplesumo.benchmarks import report
from triplesumo.envs.match import Match
from triplesumo.evaluation.evaluate import play_test_epochs
from triplesumo.evaluation.metrics import summarize
from triplesumo.rules.scenarios import scenario_config
from triplesumo.train import checkpoint
from triplesumo.train.config import ALGOS, TrainConfig
from triplesumo.train.loop import holds_run, train

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
        set_here = [f"train.{name}" for name in ("out", "name", "learner", "learn", "epochs", "max_env_steps")
                    if getattr(self.train, name) != getattr(TrainConfig(), name)]
        if set_here:
            raise ValueError(f"SkillConfig.{set_here[0]} is set by the bench (Bug learns each of algos in OUT/ALGO "
                             "up to max_env_steps, evaluated every eval_every): leave it out")

    def run_config(self, algo: str) -> TrainConfig:
        """The train config of ``algo``'s run (its first chunk: the first evaluation's budget)."""
        return dataclasses.replace(self.train, out=str(Path(self.out).resolve()), name=algo, learn=(f"bug={algo}",),
                                   epochs=10**9, max_env_steps=self.eval_every)


def _depends(cfg: SkillConfig) -> dict[str, Any]:
    values: dict[str, Any] = json.loads(json.dumps({k: dataclasses.asdict(cfg)[k] for k in CURVE_DEPENDS_ON}))
    for name in ("progress", "tensorboard", "out", "name"):  # (how it shows, or set per algorithm by the bench)
        values["train"].pop(name)
    return values


def _latest(run_dir: Path) -> int:
    """Env steps at the run's latest checkpoint (0 when none)."""
    saved = checkpoint.checkpoints(run_dir)
    return int(load_json(saved[-1][1] / "state.json").get("env_steps", 0)) if saved else 0


def _evaluate(cfg: SkillConfig, run_dir: Path) -> dict[str, Any]:
    """The run's current Bug policy, frozen, on the bench's seeded test matches."""
    t = cfg.train
    match_cfg = scenario_config(t.scenario, max_steps=t.steps_per_epoch, obs_mode=t.obs_mode, physics=t.physics)
    probe = Match(match_cfg)
    sizes = probe.observer.sizes
    motors = dict(zip(probe.agents, probe.action_sizes, strict=True))
    pairs = expand_pairs(t.policies, [a for a in match_cfg.agent_names if a != "bug"])
    others = policies_from_pairs(pairs, cfg.eval_seed, t.obs_mode, action_sizes=motors, obs_dims=sizes)
    policy = make_policy(str(run_dir / "policy"), expect_obs_mode=t.obs_mode, action_size=motors["bug"],
                         expect_obs_dim=sizes["bug"])
    rows = play_test_epochs(policy, others, "bug", cfg.eval_epochs, cfg.eval_seed, match_cfg, t.n_envs,
                            t.n_threads)
    stats = summarize([r["outcome"] for r in rows], [r["steps"] for r in rows])

    def clean(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    return {"test_mwr": float(stats["mean_lwr"]), "test_mwr_lo": clean(stats["mean_lwr_lo"]),
            "test_mwr_hi": clean(stats["mean_lwr_hi"]), "n_win": stats["n_win"], "n_loss": stats["n_loss"],
            "n_draw": stats["n_draw"]}


def _budget(cfg: SkillConfig, done: int) -> int:
    """The env-step budget of the chunk after ``done`` env steps: the next multiple of ``eval_every``."""
    return (done // cfg.eval_every + 1) * cfg.eval_every


def outcome(cfg: SkillConfig, evaluations: list[dict[str, Any]]) -> dict[str, Any]:
    """The stop rule on a curve: the first evaluation with test MWR >= target (reached), else whether the
    budget is spent (not reached) or training goes on. Evaluations of chunks beyond max_env_steps (a
    raised budget, later lowered) do not count."""
    within = [e for e in evaluations if e["budget"] <= cfg.max_env_steps]  # a prefix: budgets grow
    for k, e in enumerate(within):
        if e["test_mwr"] >= cfg.target:
            return {"status": "reached", "reached": True, "at": k, "env_steps": e["env_steps"],
                    "train_seconds": e["train_seconds"], "wall_seconds": e["wall_seconds"]}
    spent = bool(within) and _budget(cfg, within[-1]["env_steps"]) > cfg.max_env_steps
    best = max(within, key=lambda e: e["test_mwr"]) if within else None
    return {"status": "not reached" if spent else "running", "reached": False, "at": None, "env_steps": None,
            "train_seconds": None, "wall_seconds": None,
            "best_test_mwr": None if best is None else best["test_mwr"],
            "best_at_env_steps": None if best is None else best["env_steps"]}


def _bench_algo(cfg: SkillConfig, algo: str, entry: dict[str, Any], save: Any) -> None:
    """Train and evaluate ``algo``'s run until the stop rule decides (``entry`` updated in place, saved after
    every evaluation)."""
    run_cfg = cfg.run_config(algo)
    run_dir = Path(run_cfg.out) / run_cfg.name
    evaluations: list[dict[str, Any]] = entry["evaluations"]
    while outcome(cfg, evaluations)["status"] == "running":
        budget = _budget(cfg, evaluations[-1]["env_steps"] if evaluations else 0)
        start = time.perf_counter()
        train_seconds = 0.0
        at = _latest(run_dir)
        if at < budget:  # the chunk to the first epoch end past budget (from the last checkpoint, if any)
            if at == 0:
                result = train(dataclasses.replace(run_cfg, max_env_steps=budget), start_over=holds_run(run_dir))
            else:
                result = train(run_cfg, resume_dir=run_dir, overrides={"max_env_steps": budget})
            train_seconds, at = result.seconds, result.env_steps
        # else: killed after the chunk's last checkpoint, before its evaluation: that policy file is evaluated now
        e0 = time.perf_counter()
        facts = _evaluate(cfg, run_dir)
        now = time.perf_counter()
        before = evaluations[-1] if evaluations else {"train_seconds": 0.0, "wall_seconds": 0.0, "eval_seconds": 0.0}
        evaluations.append({"env_steps": at, "budget": budget, **facts,
                            "train_seconds": round(before["train_seconds"] + train_seconds, 3),
                            "eval_seconds": round(before["eval_seconds"] + now - e0, 3),
                            "wall_seconds": round(before["wall_seconds"] + now - start, 3)})
        print(f"  {algo}: {at:,} env steps, test MWR {facts['test_mwr']:+.3f} "
              f"(training {evaluations[-1]['train_seconds']:.0f} s)")
        save()


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
        "max_env_steps": cfg.max_env_steps, "algos": {}}
    kept = {} if old is None else old["algos"]

    def save() -> None:
        for name, entry in result["algos"].items():
            entry.update(outcome(cfg, entry["evaluations"]))
            entry["run_dir"] = str(out / name)
        atomic_write_bytes(path, (json.dumps(result, indent=2) + "\n").encode())

    for algo in cfg.algos:
        result["algos"][algo] = {"evaluations": list(kept.get(algo, {}).get("evaluations", []))}
        print(f"bench skill: Bug with {algo}, target test MWR {cfg.target:+.2f}")
        _bench_algo(cfg, algo, result["algos"][algo], save)
    save()
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
    lines = [f"time to skill: first test MWR >= {result['target']:+.2f} ({result['eval_epochs']} seeded test "
             f"matches every {result['eval_every']:,} env steps, budget {result['max_env_steps']:,})", "",
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
