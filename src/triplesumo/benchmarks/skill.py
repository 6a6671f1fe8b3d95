"""``triplesumo bench skill``: time to skill, the env steps and wall time until Bug's team first reaches a
test MWR of ``target`` (default +0.2), per algorithm, over several training seeds.

For each algorithm and each of ``seeds`` Bug is trained with the project's own ``triplesumo train``
(``--learn bug=ALGO --seed S``, the match of ``--train.*``: by default the paper's ongoing match of
``zoo:ant`` and ``zoo:spider``) in its own run folder ``OUT/ALGO/seedS``, with the trainer's own evaluations
(``train --eval-every``): every ``eval_every`` env steps (25,000), at the step that crosses a multiple of it,
Bug's current policy plays frozen (no exploration) the same ``eval_epochs`` seeded test matches (200; test
match ``i`` resets with ``eval_seed + i``, as ``triplesumo evaluate``), into the run's ``eval.csv``. By
default they play in a worker process while Bug trains on (``--train.eval-background``;
``--no-train.eval-background``: inline). A run stops at the first evaluation whose test MWR is ``>= target``
(*reached*, ``train --eval-target``) or at ``max_env_steps`` (*not reached*: reported as such, with the best
test MWR seen). ``--no-stop-at-target`` trains every run to ``max_env_steps`` instead, so that every seed has a
value at every evaluation (a comparison of recipes at a fixed budget needs them: a seed stopped at its first
crossing has none later); the report is the same, the first evaluation at the target.

Times, from each evaluation's row: ``seconds`` is the training's own wall time (collection, learning and
checkpoints; the trainer's clock, carried across resumes) when the policy that reached the target was frozen
(``eval.csv``'s ``policy_train_seconds``): the time to skill. ``wall_seconds`` is when its result was known:
the training's clock when the row was written (``train_seconds``; later than the policy's in the background,
the training went on while it played) plus the time the training spent on evaluations (``eval_seconds``). A row
written before ``policy_train_seconds`` existed gives its ``train_seconds`` instead (the same inline; an upper
bound in the background). Measured on the machine at hand, never projected.

The machine's speed goes with the times: ``machine.reference`` is the wall time per env step of a fixed
seeded collection (the run's ``n_envs`` matches of its match, uniform random actions, its MuJoCo threads;
:func:`~triplesumo.train.machine.reference_speed`), measured just before and just after the bench trains. Two
boxes of the same name (a shared cloud machine, at different hours) can differ by a factor of two; the
reference tells a reader which one a time came from, and *reference seconds* set the times side by side:
each time scaled to a box whose reference collection takes 0.7 ms per env step (``seconds * 0.7 / ms``,
``ms`` the mean of the before and after collections; :func:`~triplesumo.train.machine.reference_seconds`).

Over the seeds each algorithm gets the median and the spread (min-max) of its env steps, seconds and
reference seconds to the target. A seed that has not reached it counts as beyond the budget: the median is
then unknown (None, "not reached") when half the seeds or more have not, and so is the max when any has not.

Resumable: ``OUT/skill.json`` is rebuilt from each run's ``eval.csv``; a killed bench, run again with the same
options, resumes each run from its last checkpoint (exactly: the checkpoints hold the replay, and the
evaluations past the checkpoint are played again). The test-MWR curve of a seed depends only on ``train``,
``eval_every``, ``eval_epochs`` and ``eval_seed``; ``target``, ``max_env_steps``, ``seeds``, ``algos`` and
``workers`` may change between runs (the stop rule is applied to the recorded curve first, so a lower target needs no
training; a bench that trains nothing keeps the record's machine and reference collections, those of the box the
times were measured on). Writes ``OUT/skill.json`` (and ``--json F``), ``OUT/skill.png`` (test MWR against env steps and
against training wall time, one line per seed) and prints a table. ``--quick`` checks all of it on a tiny
budget in minutes (not a time to skill).

``--workers N`` trains N runs at once, each in its own process, for the many seeds a comparison of recipes needs
(docs/bench/skill.md: about 30 per recipe to find a lift of +0.1 in test MWR); the curves are the ones the runs give
one after another.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import multiprocessing
import statistics
import textwrap
from concurrent.futures import ProcessPoolExecutor, as_completed
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
from triplesumo.train.logger import policy_seconds
from triplesumo.train.loop import train
from triplesumo.train.machine import (
    REFERENCE_MS_PER_ENV_STEP,
    machine,
    machine_ms_per_env_step,
    reference_seconds,
    reference_speed,
)
from triplesumo.train.run_folder import holds_run

RECORD = "skill.json"
"""The bench's record and result in OUT (what ``triplesumo reproduce`` reads from ``OUT/skill``)."""
PLOT = "skill.png"
CURVE_DEPENDS_ON = ("train", "eval_every", "eval_epochs", "eval_seed")
"""The :class:`SkillConfig` fields the test-MWR curves depend on: a resumed bench must keep them."""
DEFAULT_OUT = "runs/skill"
TITLE_WIDTH = 130
"""Characters per line of the plot's title, which fit its 11-inch width at 9 points."""
QUICK = {"eval_every": 40, "eval_epochs": 4, "max_env_steps": 120}
"""``--quick``'s budget: an evaluation on 4 test matches every 40 env steps (one 20-step epoch of 2 matches),
up to 120 env steps."""


def _quick_train(t: TrainConfig) -> TrainConfig:
    """``--quick``'s runs: 2 matches of 20 steps, 16-unit networks learning from the 10th transition, no
    TensorBoard, no progress bar."""
    small: dict[str, Any] = {"hidden": (16, 16), "buffer_size": 2_000, "learning_starts": 10, "batch_size": 8}
    return dataclasses.replace(
        t, n_envs=2, steps_per_epoch=20, tensorboard=False, progress=False,
        ddpg=dataclasses.replace(t.ddpg, **small), td3=dataclasses.replace(t.td3, **small),
        sac=dataclasses.replace(t.sac, **small),
        ppo=dataclasses.replace(t.ppo, hidden=(16, 16), n_steps=8, n_minibatches=2, n_epochs=2))


@dataclass(frozen=True)
class SkillConfig:
    """Time to skill: train Bug per algorithm and seed, evaluate every eval_every env steps, stop at the target."""

    algos: tuple[str, ...] = ("sac",)
    """Algorithms Bug learns with (any of ddpg td3 sac ppo, or one comma-separated item: ddpg,td3); the default is
    ``--learn bug=sac``'s learner, the one the demo and reproduce train."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Training seeds: each its own run of each algorithm (OUT/ALGO/seedS, train --seed S); the report gives the
    median and the spread (min-max) over them."""
    target: float = 0.2
    """Skill: the first evaluation whose test MWR is >= this (in [-1, 1]) is the time to skill, and the run
    stops there unless ``stop_at_target`` is off."""
    stop_at_target: bool = True
    """Stop a run at its first evaluation at the target; off: train every run to max_env_steps, for the test MWR
    of every seed at every evaluation (the time to skill is reported the same)."""
    eval_every: int = 25_000
    """Env steps between evaluations (each at the step that crosses a multiple of it)."""
    eval_epochs: int = 200
    """Seeded test matches per evaluation (the same matches for every algorithm, seed and evaluation)."""
    eval_seed: int = 10_000
    """Test match i resets with eval_seed + i."""
    max_env_steps: int = 1_000_000
    """Budget per run: not reached when no evaluation up to this many env steps hits the target."""
    quick: bool = False
    """A check of the bench on a tiny budget, in minutes, not a time to skill: sets eval_every 40, eval_epochs 4,
    max_env_steps 120 and the runs' sizes (2 matches of 20 steps, 16-unit networks); out runs/skill-quick unless
    given."""
    workers: int = 1
    """Runs trained at once, each in its own process (one algorithm and seed each); 1: one after another in this
    process. The curves do not depend on it (each run is its own seed's), the wall times do (the runs share the
    machine): give each run the cores it uses (``train.n_threads`` for MuJoCo, one for its updates, and its
    background evaluations')."""
    out: str = DEFAULT_OUT
    """Folder of the run folders (OUT/ALGO/seedS), skill.json and skill.png."""
    json: str = ""
    """Also write the result as JSON to this file."""
    train: TrainConfig = field(default_factory=lambda: TrainConfig(eval_background=True))
    """The training runs (--train.*: match, policies of the others, hyper-parameters, n_envs; evaluations in
    the background unless --no-train.eval-background); the bench sets their out, name, seed, learn (bug=ALGO),
    epochs, max_env_steps and evaluations."""

    def __post_init__(self) -> None:
        if self.quick:
            for name, value in QUICK.items():
                object.__setattr__(self, name, value)
            object.__setattr__(self, "train", _quick_train(self.train))
            if self.out == DEFAULT_OUT:
                object.__setattr__(self, "out", DEFAULT_OUT + "-quick")
        check_seed(self.eval_seed, "SkillConfig.eval_seed")
        algos = tuple(a for item in self.algos for a in str(item).split(",") if a)
        object.__setattr__(self, "algos", algos)
        if not algos or len(set(algos)) < len(algos) or any(a not in ALGOS for a in algos):
            raise ValueError(f"SkillConfig.algos must be among {ALGOS}, non-empty and without repeats, got {algos}")
        seeds = tuple(self.seeds)
        object.__setattr__(self, "seeds", seeds)
        if not seeds or len(set(seeds)) < len(seeds):
            raise ValueError(f"SkillConfig.seeds must be non-empty and without repeats, got {seeds}")
        for seed in seeds:
            check_seed(seed, "SkillConfig.seeds")
        if isinstance(self.target, bool) or not isinstance(self.target, int | float) or not -1 <= self.target <= 1:
            raise ValueError(f"SkillConfig.target must be a test MWR in [-1, 1], got {self.target!r}")
        for name in ("eval_every", "eval_epochs", "max_env_steps", "workers"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"SkillConfig.{name} must be an int >= 1, got {value!r}")
        if self.max_env_steps < self.eval_every:
            raise ValueError(f"SkillConfig.max_env_steps ({self.max_env_steps}) must be >= eval_every "
                             f"({self.eval_every}): no evaluation would be made")
        set_here = [f"train.{name}" for name in ("out", "name", "seed", "learn", "epochs", "max_env_steps",
                                                 "eval_every", "eval_epochs", "eval_seed", "eval_target")
                    if getattr(self.train, name) != getattr(TrainConfig(), name)]
        if set_here:
            raise ValueError(f"SkillConfig.{set_here[0]} is set by the bench (Bug learns with each of algos and "
                             "each of seeds in OUT/ALGO/seedS up to max_env_steps, evaluated every eval_every): "
                             "leave it out")

    def run_config(self, algo: str, seed: int) -> TrainConfig:
        """The train config of ``algo``'s run with ``seed``: evaluated every eval_every, stopped at the target
        (unless ``stop_at_target`` is off) or the budget."""
        return dataclasses.replace(self.train, out=str(Path(self.out).resolve() / algo), name=f"seed{seed}",
                                   seed=seed, learn=(f"bug={algo}",), epochs=10**9, max_env_steps=self.max_env_steps,
                                   eval_every=self.eval_every, eval_epochs=self.eval_epochs, eval_seed=self.eval_seed,
                                   eval_target=self.stop_target)

    def run_dir(self, algo: str, seed: int) -> Path:
        """The run folder of ``algo``'s run with ``seed``: OUT/ALGO/seedS."""
        run_cfg = self.run_config(algo, seed)
        return Path(run_cfg.out) / run_cfg.name

    @property
    def stop_target(self) -> float | None:
        """The runs' ``train --eval-target``: the target, or None (train to the budget) without stop_at_target."""
        return self.target if self.stop_at_target else None


def _depends(cfg: SkillConfig) -> dict[str, Any]:
    values: dict[str, Any] = json.loads(json.dumps({k: dataclasses.asdict(cfg)[k] for k in CURVE_DEPENDS_ON}))
    for name in ("progress", "tensorboard", "out", "name", "seed", "eval_background"):  # (how it shows or where
        # it plays, or set per run by the bench)
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

    def evaluation(r: dict[str, str]) -> dict[str, Any]:
        written = float(r["train_seconds"])
        return {"env_steps": int(r["env_steps"]), "budget": int(r["env_steps"]) // cfg.eval_every * cfg.eval_every,
                "test_mwr": float(r["test_mwr"]), "test_mwr_lo": number(r["test_mwr_lo"]),
                "test_mwr_hi": number(r["test_mwr_hi"]), "n_win": int(r["n_win"]), "n_loss": int(r["n_loss"]),
                "n_draw": int(r["n_draw"]), "policy_train_seconds": policy_seconds(r), "train_seconds": written,
                "eval_seconds": float(r["eval_seconds"]),
                "wall_seconds": round(written + float(r["eval_seconds"]), 3)}

    return [evaluation(r) for r in rows]


def outcome(cfg: SkillConfig, evaluations: list[dict[str, Any]]) -> dict[str, Any]:
    """The stop rule on a curve: the first evaluation with test MWR >= target (reached: its env steps, the
    training's clock when its policy was frozen, ``seconds``, and when its result was known, ``wall_seconds``),
    else whether the budget is spent (not reached) or training goes on. Without ``stop_at_target`` a run that has
    reached the target goes on (status running) until the budget is spent. Evaluations past max_env_steps (a
    raised budget, later lowered) do not count."""
    within = [e for e in evaluations if e["budget"] <= cfg.max_env_steps]  # a prefix: budgets grow
    spent = bool(within) and within[-1]["budget"] + cfg.eval_every > cfg.max_env_steps  # no evaluation left
    for k, e in enumerate(within):
        if e["test_mwr"] >= cfg.target and (cfg.stop_at_target or spent):
            return {"status": "reached", "reached": True, "at": k, "env_steps": e["env_steps"],
                    "seconds": e["policy_train_seconds"], "wall_seconds": e["wall_seconds"]}
    best = max(within, key=lambda e: e["test_mwr"]) if within else None
    return {"status": "not reached" if spent else "running", "reached": False, "at": None, "env_steps": None,
            "seconds": None, "wall_seconds": None,
            "best_test_mwr": None if best is None else best["test_mwr"],
            "best_at_env_steps": None if best is None else best["env_steps"]}


def spread(values: list[float | None]) -> dict[str, float | None]:
    """The median, min and max of per-seed times to skill, None standing for a seed that has not reached the
    target (beyond the budget): the median is None when half of them or more are, the max when any is."""
    known = [math.inf if v is None else v for v in values]
    median = statistics.median(known)  # (inf in the middle, or with the middle pair: inf)
    return {"median": None if math.isinf(median) else median, "min": None if math.isinf(min(known)) else min(known),
            "max": None if math.isinf(max(known)) else max(known)}


def summarize(result: dict[str, Any]) -> dict[str, Any]:
    """Fill in ``result``'s reference seconds (each run's, and the scale: ``reference``) from its machine's
    reference collections and each algorithm's ``summary`` over its seeds (:func:`spread` of env steps, seconds
    and reference seconds to the target); returns ``result``."""
    measured = result["machine"]["reference"]
    ms = machine_ms_per_env_step(measured)
    result["reference"] = {"ms_per_env_step": round(ms, 4), "reference_ms_per_env_step": REFERENCE_MS_PER_ENV_STEP,
                           "scale": round(REFERENCE_MS_PER_ENV_STEP / ms, 4),
                           "measured": sorted(measured)}
    for entry in result["algos"].values():
        for run in entry["runs"]:
            run["reference_seconds"] = (None if run["seconds"] is None
                                        else round(reference_seconds(run["seconds"], measured), 3))
        runs = entry["runs"]
        entry["summary"] = {"seeds": len(runs), "reached": sum(r["reached"] for r in runs),
                            **{key: spread([r[key] for r in runs])
                               for key in ("env_steps", "seconds", "reference_seconds", "wall_seconds")}}
    return result


def _bench_run(cfg: SkillConfig, algo: str, seed: int) -> list[dict[str, Any]]:
    """Train (or resume) the run of ``algo`` and ``seed`` until the stop rule decides on its curve; returns the
    curve."""
    run_cfg, run_dir = cfg.run_config(algo, seed), cfg.run_dir(algo, seed)
    if outcome(cfg, _curve(cfg, run_dir))["status"] == "running":
        if checkpoint.checkpoints(run_dir):  # goes on from the last checkpoint, to this bench's budget and target
            train(run_cfg, resume_dir=run_dir, overrides={"max_env_steps": cfg.max_env_steps,
                                                           "eval_target": cfg.stop_target})
        else:
            train(run_cfg, start_over=holds_run(run_dir))
    return _curve(cfg, run_dir)


def _write(path: Path, result: dict[str, Any]) -> None:
    atomic_write_bytes(path, (json.dumps(summarize(result), indent=2) + "\n").encode())


def run_skill(cfg: SkillConfig) -> dict[str, Any]:
    """Run (or resume) the bench for every algorithm and seed; writes OUT/skill.json, OUT/skill.png; returns the
    result."""
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
        "eval_background": cfg.train.eval_background, "max_env_steps": cfg.max_env_steps, "seeds": list(cfg.seeds),
        "machine": machine(cfg.train), "algos": {}}
    pairs = [(algo, seed) for algo in cfg.algos for seed in cfg.seeds]
    trains = any(outcome(cfg, _curve(cfg, cfg.run_dir(a, s)))["status"] == "running" for a, s in pairs)
    recorded = old.get("machine") if old is not None else None
    kept = not trains and recorded is not None and "reference" in recorded
    if kept:  # nothing to train: the times are the recorded runs', so is the machine they ran on
        result["machine"] = recorded
    else:
        result["machine"]["reference"] = {"before": reference_speed(cfg.train)}

    done: dict[tuple[str, int], list[dict[str, Any]]] = {}

    def finished(algo: str, seed: int, evaluations: list[dict[str, Any]]) -> None:
        """Record a finished run; the record lists the finished runs in the order of algos and seeds."""
        done[algo, seed] = evaluations
        result["algos"] = {a: {"runs": [{"seed": s, "evaluations": done[a, s], **outcome(cfg, done[a, s]),
                                          "run_dir": str(cfg.run_dir(a, s))} for s in cfg.seeds if (a, s) in done]}
                           for a in cfg.algos if any((a, s) in done for s in cfg.seeds)}
        _write(path, result)

    if cfg.workers == 1:
        for algo, seed in pairs:
            print(f"bench skill: Bug with {algo}, seed {seed}, target test MWR {cfg.target:+.2f}")
            finished(algo, seed, _bench_run(cfg, algo, seed))
    else:
        with ProcessPoolExecutor(min(cfg.workers, len(pairs)), mp_context=multiprocessing.get_context("spawn")) as ex:
            futures = {ex.submit(_bench_run, cfg, algo, seed): (algo, seed) for algo, seed in pairs}
            print(f"bench skill: Bug with {', '.join(cfg.algos)}, seeds {', '.join(map(str, cfg.seeds))}, "
                  f"{min(cfg.workers, len(pairs))} at once, target test MWR {cfg.target:+.2f}")
            try:
                for future in as_completed(futures):
                    algo, seed = futures[future]
                    finished(algo, seed, future.result())
                    print(f"bench skill: Bug with {algo}, seed {seed}: {outcome(cfg, done[algo, seed])['status']}")
            except BaseException:
                ex.shutdown(wait=False, cancel_futures=True)
                raise
    if not kept:
        result["machine"]["reference"]["after"] = reference_speed(cfg.train)
    _write(path, result)
    plot_skill(result, out / PLOT)
    report(format_skill(result), result, cfg.json or None)
    return result


def plot_skill(result: dict[str, Any], path: Path) -> Path:
    """Test MWR against env steps and against the training's wall time (when each policy was frozen), one line
    per seed (and algorithm), the target dashed, a star at each run's first evaluation at the target."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.4))
    axes = fig.subplots(1, 2, sharey=True)
    several = len(result["algos"]) > 1
    styles = ("-", "--", ":", "-.")
    for a, (algo, entry) in enumerate(result["algos"].items()):
        for s, run in enumerate(entry["runs"]):
            ev = run["evaluations"]
            label = f"{algo} seed {run['seed']}" + ("" if run["reached"] else " (not reached)")
            colour, style = (f"C{a}", styles[s % len(styles)]) if several else (f"C{s}", "-")
            for ax, key, at in zip(axes, ("env_steps", "policy_train_seconds"), ("env_steps", "seconds"),
                                   strict=True):
                ax.plot([e[key] for e in ev], [e["test_mwr"] for e in ev], marker="o", markersize=4, color=colour,
                        linestyle=style, label=label)
                if run["reached"]:
                    ax.plot([run[at]], [ev[run["at"]]["test_mwr"]], marker="*", markersize=13, color="black")
    for ax, xlabel in zip(axes, ("env steps", "training wall time when the policy was frozen (s)"), strict=True):
        ax.axhline(result["target"], linestyle="--", color="grey", label=f"target {result['target']:+.2f}")
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(f"test MWR ({result['eval_epochs']} seeded test matches)")
    axes[0].legend(fontsize=8)
    title = plot_title(result)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def plot_title(result: dict[str, Any], width: int = TITLE_WIDTH) -> str:
    """The plot's title: what it shows, the machine, and each algorithm's median line, wrapped to ``width``
    characters so that none runs off the figure."""
    m, ms = result["machine"], result["reference"]["ms_per_env_step"]
    lines = ["time to skill: Bug's test MWR while training (star: first evaluation at the target)",
             f"{m['cores']} CPU cores ({m['cpu']}), reference collection {ms:.3f} ms per env step"]
    for algo, entry in result["algos"].items():
        lines += textwrap.wrap(_summary_line(algo, entry["summary"], result["max_env_steps"]), width)
    return "\n".join(lines)


def _median_range(s: dict[str, float | None], fmt: str) -> str:
    def one(v: float | None) -> str:
        return "not reached" if v is None else format(v, fmt)

    return f"{one(s['median'])} ({one(s['min'])} - {one(s['max'])})"


def format_skill(result: dict[str, Any]) -> str:
    """The table printed by the bench: the machine and its reference speed, one row per run, and per algorithm
    the median and spread (min - max) over its seeds."""
    m = result["machine"]
    ref = result["reference"]
    where = (f"measured on {m['cores']} CPU cores ({m['cpu']}), backend {m['backend']} on "
             f"{m['gpu'] or m['device']}, {m['n_threads']} MuJoCo / {m['torch_threads']} torch threads"
             + ("" if m["gpu"] else "; GPU: not measured")
             + "".join(f"\nreference collection {when} the bench: {r['ms_per_env_step']:.3f} ms per env step "
                       f"({r['env_steps']:,} env steps, best of {r['repeats']})"
                       for when, r in m["reference"].items())
             + f"\nreference seconds: the time on a box whose reference collection takes "
               f"{ref['reference_ms_per_env_step']} ms per env step,\n  seconds x {ref['reference_ms_per_env_step']} / "
               f"{ref['ms_per_env_step']:.3f} (the mean reference collection here) = seconds x {ref['scale']:.3f}")
    where_eval = "in the background" if result.get("eval_background") else "inline"
    lines = [f"time to skill: first test MWR >= {result['target']:+.2f} ({result['eval_epochs']} seeded test "
             f"matches every {result['eval_every']:,} env steps, {where_eval}; budget {result['max_env_steps']:,} "
             f"env steps; seeds {' '.join(map(str, result['seeds']))})", where,
             "seconds: the training's wall time when the policy that reached the target was frozen;",
             "wall: when its result was known (the evaluations' time included)", "",
             f"{'algo':6s} {'seed':>4s} {'reached':>11s} {'env steps':>11s} {'seconds':>8s} {'ref. s':>8s} "
             f"{'wall (s)':>8s} {'evals':>5s}  test MWR curve"]
    for algo, entry in result["algos"].items():
        for run in entry["runs"]:
            curve = " ".join(f"{x['test_mwr']:+.2f}" for x in run["evaluations"])
            if run["reached"]:
                lines.append(f"{algo:6s} {run['seed']:4d} {'yes':>11s} {run['env_steps']:11,d} {run['seconds']:8.0f} "
                             f"{run['reference_seconds']:8.0f} {run['wall_seconds']:8.0f} "
                             f"{len(run['evaluations']):5d}  {curve}")
            else:
                best = "" if run.get("best_test_mwr") is None else f" (best {run['best_test_mwr']:+.3f})"
                lines.append(f"{algo:6s} {run['seed']:4d} {run['status']:>11s} {'-':>11s} {'-':>8s} {'-':>8s} "
                             f"{'-':>8s} {len(run['evaluations']):5d}  {curve}{best}")
    lines.append("")
    lines += [_summary_line(algo, entry["summary"], result["max_env_steps"]) for algo, entry in result["algos"].items()]
    return "\n".join(lines)


def _summary_line(algo: str, s: dict[str, Any], budget: int) -> str:
    if not s["reached"]:
        return f"{algo}: not reached by any of its {s['seeds']} seeds within {budget:,} env steps"
    return (f"{algo}: median (min - max) over {s['seeds']} seeds, {s['reached']} reached: "
            f"{_median_range(s['env_steps'], ',.0f')} env steps, {_median_range(s['seconds'], '.0f')} s, "
            f"{_median_range(s['reference_seconds'], '.0f')} reference s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="triplesumo bench skill", description=__doc__.split("\n\n")[0])
    _dcargs.add_arguments(parser, SkillConfig)
    run_skill(_dcargs.build(SkillConfig, parser.parse_args(argv)))
    return 0
