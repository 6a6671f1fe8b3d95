"""``triplesumo bench skill-gpu``: time to skill on a GPU, the seconds and env steps until Bug's team first reaches
each test MWR of ``thresholds`` (+0.2, then +0.4) while Bug learns in thousands of matches on MuJoCo Warp.

Each seed is one ``triplesumo train`` run (``--learn bug=ALGO``, SAC by default, in the paper's ongoing match of
``zoo:ant`` and ``zoo:spider`` unless ``--train.*`` says otherwise) on ``backend="warp"`` with ``n_envs`` matches
on ``device``, in ``OUT/ALGO/seedS``. Its schedule is the massively parallel one of docs/gpu.md: every step of all
the matches (``n_envs`` transitions), ``updates_per_step`` gradient steps of ``batch_size`` transitions
(``learn_every = n_envs``), after ``warmup_steps`` steps of all the matches of random warm-up. Every
``eval_every`` env steps the trainer's own evaluations (``train --eval-every``) freeze Bug's current policy and
play it, in a worker process on the CPU while Bug trains on (``--train.eval-background``), on the same seeded test
matches as ``bench skill`` and ``evaluate`` (test match ``i`` resets with ``eval_seed + i``; ``eval_epochs`` of
them, on ``eval_threads`` MuJoCo threads). A run stops at the first evaluation at the highest threshold, at
``max_env_steps``, or after ``max_seconds`` of training (then after the evaluations in flight are back).

Times, from each evaluation's row of the run's ``eval.csv``: ``seconds`` to a threshold is the training's own
wall time when the policy that first reached it was frozen (``policy_train_seconds``); ``wall_seconds`` is when
its result was known (the training's clock when the row was written, plus the time the training waited for
evaluations). The clock starts once the run's trainer is built; Warp's kernels are compiled and loaded before,
in the same process, by the device reference collection, so the time to skill holds no compiling. What that
collection took (``device.first_step_seconds``: building a batch, compiling or loading every kernel,
capturing the CUDA graphs) and its rate (env steps/s of ``n_envs`` matches, uniform random actions, no policy
and no learner) are recorded beside the times, with the GPU's name, the host CPU and its reference collection
(:func:`~triplesumo.train.machine.reference_speed` of 16 matches on one thread, the figure ``bench skill``
records on a CPU box; the evaluations run on that CPU). No "reference seconds": they scale CPU boxes.

``goal_seconds`` (60) is the aim for the first threshold: ``goal.met`` says whether the median seed's seconds to
it are within it (None when no seed was run). A seed that has not reached a threshold counts as beyond the
budget, as in ``bench skill``. Not resumable: each call trains its seeds afresh (an older run in the same folder
is moved aside to ``RUN.old-K``). Writes ``OUT/skill_gpu.json`` (and ``--json F``), ``OUT/skill_gpu.png`` and
prints a table. ``--quick`` checks all of it on Warp's CPU device on a tiny budget (minutes, most of them Warp's
first compile; not a time to skill).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import statistics
import textwrap
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from triplesumo import _dcargs
from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.benchmarks import report, versions
from triplesumo.envs.seeding import check_seed
from triplesumo.evaluation.metrics_csv import open_table, table_exists
from triplesumo.train.config import ALGOS, TrainConfig, parallel_schedule
from triplesumo.train.logger import policy_seconds
from triplesumo.train.loop import train
from triplesumo.train.machine import device_reference, machine, reference_speed
from triplesumo.train.run_folder import holds_run

RECORD = "skill_gpu.json"
PLOT = "skill_gpu.png"
DEFAULT_OUT = "runs/skill-gpu"
QUICK: dict[str, Any] = {"n_envs": 4, "device": "cpu", "updates_per_step": 2, "batch_size": 16, "warmup_steps": 2,
                         "eval_every": 40, "eval_epochs": 2, "eval_threads": 1, "max_env_steps": 120,
                         "max_seconds": 600.0}
"""``--quick``'s budget on Warp's CPU device: 4 matches of 20 steps, an evaluation on 2 test matches every 40 env
steps, up to 120 env steps."""
SET_BY_BENCH = ("out", "name", "seed", "learner", "learn", "epochs", "max_env_steps", "max_minutes", "eval_every",
                "eval_epochs", "eval_seed", "eval_target", "eval_workers", "backend", "device", "n_envs", "n_threads")
"""The train fields the bench sets itself (from its own options): ``--train.X`` for them is refused."""
SET_PER_ALGO = ("learn_every", "gradient_steps", "batch_size", "learning_starts")
"""The learner's schedule fields the bench sets from ``updates_per_step``, ``batch_size`` and ``warmup_steps``."""


def _gpu_train() -> TrainConfig:
    """The runs' defaults: Warp, evaluations in the background, no TensorBoard or progress bar, a checkpoint only
    at the end (no replay in it): a checkpoint of a million-transition replay every 200 epochs would cost more
    than the learning."""
    return TrainConfig(backend="warp", eval_background=True, progress=False, tensorboard=False,
                       checkpoint_every=10**9, save_replay=False)


def _quick_train(t: TrainConfig) -> TrainConfig:
    """``--quick``'s runs: 20-step matches, 16-unit networks, a small replay."""
    small: dict[str, Any] = {"hidden": (16, 16), "buffer_size": 2_000}
    return dataclasses.replace(
        t, steps_per_epoch=20, ddpg=dataclasses.replace(t.ddpg, **small), td3=dataclasses.replace(t.td3, **small),
        sac=dataclasses.replace(t.sac, **small))


@dataclass(frozen=True)
class SkillGpuConfig:
    """Time to skill on a GPU: Bug learns on MuJoCo Warp in many matches, evaluated in the background on the CPU."""

    algo: str = "sac"
    """Algorithm Bug learns with (an off-policy one: ddpg, td3 or sac)."""
    seeds: tuple[int, ...] = (0,)
    """Training seeds, each its own run (OUT/ALGO/seedS); the report gives the median and the spread over them."""
    thresholds: tuple[float, ...] = (0.2, 0.4)
    """Test MWRs whose first crossing is recorded (seconds and env steps to each); a run stops at the highest."""
    goal_seconds: float = 60.0
    """The aim for the first threshold, in seconds of training: goal.met says whether the median seed made it."""
    n_envs: int = 4096
    """Matches stepped at once on the device (the run's n_envs)."""
    device: str = "cuda"
    """Warp's device: cuda (a GPU) or cpu (Warp's CPU device: a check, not a speed)."""
    updates_per_step: int = 16
    """Gradient steps per step of all the matches (n_envs transitions): the learner's gradient_steps, with
    learn_every = n_envs."""
    batch_size: int = 4096
    """Transitions per gradient step."""
    warmup_steps: int = 8
    """Steps of all the matches of random warm-up before the first update (learning_starts = warmup_steps x
    n_envs transitions)."""
    eval_every: int = 400_000
    """Env steps between evaluations (each at the step of all the matches that crosses a multiple of it). About 10 s
    of training at 4,096 matches: an evaluation (200 test matches on 8 threads of the host) must take less, or
    they queue up, and the run's end waits for every one in flight."""
    eval_epochs: int = 200
    """Seeded test matches per evaluation (the same as bench skill's)."""
    eval_seed: int = 10_000
    """Test match i resets with eval_seed + i."""
    eval_threads: int = 8
    """MuJoCo threads of the evaluation worker (the run's n_threads; the matches themselves run on the device)."""
    eval_workers: int = 1
    """Worker processes each evaluation's test matches are split over (the run's eval_workers), each with
    eval_threads MuJoCo threads: the same figures, known sooner on a host with cores to spare. 1 is what the H200's
    figures were measured with (about 50 s an evaluation); ``benchmarks/gpu_check.sh`` gives 8 workers of 1 thread
    on a host of more than 10 cores, not yet measured on a GPU's host."""
    max_env_steps: int = 20_000_000
    """Budget per run in env steps."""
    max_seconds: float = 240.0
    """Budget per run in seconds of training (then the evaluations in flight are waited for); 0: none."""
    quick: bool = False
    """A check of the bench on Warp's CPU device on a tiny budget (4 matches of 20 steps, 16-unit networks, an
    evaluation on 2 test matches every 40 env steps, up to 120): out runs/skill-gpu-quick unless given."""
    out: str = DEFAULT_OUT
    """Folder of the run folders (OUT/ALGO/seedS), skill_gpu.json and skill_gpu.png."""
    json: str = ""
    """Also write the result as JSON to this file."""
    train: TrainConfig = field(default_factory=_gpu_train)
    """The training runs (--train.*: match, policies of the others, the algorithm's other hyper-parameters); the
    bench sets their backend, device, n_envs, n_threads, budget, evaluations and the learner's schedule."""

    def __post_init__(self) -> None:
        if self.quick:
            for name, value in QUICK.items():
                object.__setattr__(self, name, value)
            object.__setattr__(self, "train", _quick_train(self.train))
            if self.out == DEFAULT_OUT:
                object.__setattr__(self, "out", DEFAULT_OUT + "-quick")
        if self.algo not in ALGOS or self.algo == "ppo":
            raise ValueError(f"SkillGpuConfig.algo must be an off-policy learner ({', '.join(ALGOS[:3])}), "
                             f"got {self.algo!r}")
        seeds = tuple(self.seeds)
        object.__setattr__(self, "seeds", seeds)
        if not seeds or len(set(seeds)) < len(seeds):
            raise ValueError(f"SkillGpuConfig.seeds must be non-empty and without repeats, got {seeds}")
        for seed in seeds:
            check_seed(seed, "SkillGpuConfig.seeds")
        check_seed(self.eval_seed, "SkillGpuConfig.eval_seed")
        levels = tuple(self.thresholds)
        object.__setattr__(self, "thresholds", levels)
        if (not levels or list(levels) != sorted(set(levels))
                or any(isinstance(x, bool) or not isinstance(x, int | float) or not -1 <= x <= 1 for x in levels)):
            raise ValueError(f"SkillGpuConfig.thresholds must be test MWRs in [-1, 1], increasing, got {levels}")
        for name in ("n_envs", "updates_per_step", "batch_size", "eval_every", "eval_epochs", "eval_threads",
                     "eval_workers", "max_env_steps"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"SkillGpuConfig.{name} must be an int >= 1, got {value!r}")
        if not isinstance(self.warmup_steps, int) or isinstance(self.warmup_steps, bool) or self.warmup_steps < 0:
            raise ValueError(f"SkillGpuConfig.warmup_steps must be an int >= 0, got {self.warmup_steps!r}")
        for name in ("goal_seconds", "max_seconds"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not (math.isfinite(value)
                                                                                     and value >= 0):
                raise ValueError(f"SkillGpuConfig.{name} must be a number of seconds >= 0, got {value!r}")
        if self.device not in ("cuda", "cpu"):
            raise ValueError(f"SkillGpuConfig.device must be cuda or cpu (Warp's CPU device), got {self.device!r}")
        if self.max_env_steps < self.eval_every:
            raise ValueError(f"SkillGpuConfig.max_env_steps ({self.max_env_steps}) must be >= eval_every "
                             f"({self.eval_every}): no evaluation would be made")
        default = _gpu_train()
        set_here = [f"train.{name}" for name in SET_BY_BENCH if getattr(self.train, name) != getattr(default, name)]
        set_here += [f"train.{self.algo}.{name}" for name in SET_PER_ALGO
                     if getattr(getattr(self.train, self.algo), name) != getattr(getattr(default, self.algo), name)]
        if set_here:
            raise ValueError(f"SkillGpuConfig.{set_here[0]} is set by the bench (from n_envs, device, "
                             "updates_per_step, batch_size, warmup_steps, eval_threads, eval_workers, its budget and "
                             "evaluations): leave it out")

    def run_config(self, seed: int) -> TrainConfig:
        """The train config of the run with ``seed``: on Warp with n_envs matches, the learner's massively parallel
        schedule, evaluated every eval_every, stopped at the highest threshold or the budget."""
        t = parallel_schedule(dataclasses.replace(self.train, n_envs=self.n_envs), self.algo, self.updates_per_step,
                              self.batch_size, self.warmup_steps)
        return dataclasses.replace(
            t, backend="warp", device=self.device, n_threads=self.eval_threads, eval_workers=self.eval_workers,
            out=str(Path(self.out).resolve() / self.algo),
            name=f"seed{seed}", seed=seed, learn=(f"bug={self.algo}",), epochs=10**9,
            max_env_steps=self.max_env_steps, max_minutes=self.max_seconds / 60.0, eval_every=self.eval_every,
            eval_epochs=self.eval_epochs, eval_seed=self.eval_seed, eval_target=self.thresholds[-1])


def read_curve(run_dir: Path) -> list[dict[str, Any]]:
    """A run's evaluations from its ``eval.csv`` (none yet: empty), each with both of its times."""
    path = Path(run_dir) / "eval.csv"
    if not table_exists(path):
        return []
    with open_table(path) as fh:
        rows = list(csv.DictReader(fh))
    return [{"env_steps": int(r["env_steps"]), "test_mwr": float(r["test_mwr"]),
             "n_win": int(r["n_win"]), "n_loss": int(r["n_loss"]), "n_draw": int(r["n_draw"]),
             "policy_train_seconds": policy_seconds(r), "train_seconds": float(r["train_seconds"]),
             "eval_seconds": float(r["eval_seconds"]),
             "wall_seconds": round(float(r["train_seconds"]) + float(r["eval_seconds"]), 3)} for r in rows]


def first_crossing(evaluations: list[dict[str, Any]], level: float) -> dict[str, Any]:
    """The first evaluation whose test MWR is >= ``level``: its env steps, ``seconds`` (the training's clock when its
    policy was frozen) and ``wall_seconds`` (when its result was known); each None when none reached it."""
    for e in evaluations:
        if e["test_mwr"] >= level:
            return {"reached": True, "env_steps": e["env_steps"], "seconds": e["policy_train_seconds"],
                    "wall_seconds": e["wall_seconds"]}
    return {"reached": False, "env_steps": None, "seconds": None, "wall_seconds": None}


def level_key(level: float) -> str:
    """A threshold as the record's key: ``+0.20``."""
    return f"{level:+.2f}"


def _run(cfg: SkillGpuConfig, seed: int) -> dict[str, Any]:
    run_cfg = cfg.run_config(seed)
    run_dir = Path(run_cfg.out) / run_cfg.name
    print(f"bench skill-gpu: Bug with {cfg.algo}, seed {seed}, {cfg.n_envs:,} matches on {cfg.device}, "
          f"thresholds {' '.join(map(level_key, cfg.thresholds))}", flush=True)
    t0 = time.perf_counter()
    result = train(run_cfg, start_over=holds_run(run_dir))
    evaluations = read_curve(run_dir)
    to = {level_key(x): first_crossing(evaluations, x) for x in cfg.thresholds}
    top = to[level_key(cfg.thresholds[-1])]["reached"]
    status = ("reached" if top else "env-step budget spent" if result.env_steps >= cfg.max_env_steps
              else "time budget spent" if cfg.max_seconds and result.seconds >= cfg.max_seconds else "stopped")
    best = max(evaluations, key=lambda e: e["test_mwr"]) if evaluations else None
    return {"seed": seed, "run_dir": str(run_dir), "status": status, "to": to,
            "env_steps": result.env_steps, "updates": result.updates, "run_seconds": round(result.seconds, 3),
            "call_seconds": round(time.perf_counter() - t0, 3),
            "best_test_mwr": None if best is None else best["test_mwr"],
            "best_at_env_steps": None if best is None else best["env_steps"], "evaluations": evaluations}


def spread(values: list[float | None]) -> dict[str, float | None]:
    """The median, min and max of per-seed values, None standing for a seed that has not reached the threshold
    (beyond the budget): the median is None when half of them or more are, the max when any is (``bench skill``'s
    rule)."""
    known = [math.inf if v is None else v for v in values]
    median = statistics.median(known)
    return {key: None if math.isinf(v) else v for key, v in (("median", median), ("min", min(known)),
                                                             ("max", max(known)))}


def summarize(result: dict[str, Any]) -> dict[str, Any]:
    """Fill in ``result``'s ``summary`` (per threshold: seeds that reached it, :func:`spread` of env steps, seconds
    and wall seconds over the seeds) and ``goal`` (the median seconds to the first threshold against
    ``goal_seconds``); returns ``result``."""
    runs = result["runs"]
    result["summary"] = {
        key: {"seeds": len(runs), "reached": sum(r["to"][key]["reached"] for r in runs),
              **{what: spread([r["to"][key][what] for r in runs]) for what in ("env_steps", "seconds",
                                                                               "wall_seconds")}}
        for key in map(level_key, result["thresholds"])} if runs else {}
    first = level_key(result["thresholds"][0])
    median = result["summary"][first]["seconds"]["median"] if runs else None
    result["goal"] = {"threshold": result["thresholds"][0], "seconds": result["goal_seconds"],
                      "median_seconds": median,
                      "met": None if not runs else (median is not None and median <= result["goal_seconds"])}
    return result


def run_skill_gpu(cfg: SkillGpuConfig) -> dict[str, Any]:
    """Measure the device, then train every seed to the highest threshold or the budget; writes
    OUT/skill_gpu.json and OUT/skill_gpu.png; returns the result."""
    out = Path(cfg.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    path = out / RECORD
    sample = cfg.run_config(cfg.seeds[0])
    host = dataclasses.replace(sample, backend="cpu", device=None, n_envs=16, n_threads=1)
    result: dict[str, Any] = {
        "config": json.loads(json.dumps(dataclasses.asdict(cfg))),
        "command": " ".join(["triplesumo", "bench", "skill-gpu", *_dcargs.to_argv(cfg)]),
        "algo": cfg.algo, "thresholds": list(cfg.thresholds), "goal_seconds": cfg.goal_seconds,
        "n_envs": cfg.n_envs, "schedule": {"learn_every": cfg.n_envs, "gradient_steps": cfg.updates_per_step,
                                           "batch_size": cfg.batch_size,
                                           "learning_starts": cfg.warmup_steps * cfg.n_envs},
        "eval_every": cfg.eval_every, "eval_epochs": cfg.eval_epochs, "eval_seed": cfg.eval_seed,
        "eval_background": sample.eval_background, "max_env_steps": cfg.max_env_steps,
        "max_seconds": cfg.max_seconds, "seeds": list(cfg.seeds),
        "machine": machine(sample), "versions": versions("mujoco-warp", "warp-lang", "torch"), "runs": []}
    result["machine"]["warp_device"] = cfg.device
    result["machine"]["host_reference"] = {"before": reference_speed(host)}
    result["device"] = device_reference(sample)
    print(f"bench skill-gpu: device {result['device']['device']}: first step (build, kernels, graphs) "
          f"{result['device']['first_step_seconds']:.1f} s, then {result['device']['env_steps_per_s']:,.0f} env "
          f"steps/s with random actions", flush=True)
    for seed in cfg.seeds:
        result["runs"].append(_run(cfg, seed))
        atomic_write_bytes(path, (json.dumps(summarize(result), indent=2) + "\n").encode())
    result["machine"]["host_reference"]["after"] = reference_speed(host)
    atomic_write_bytes(path, (json.dumps(summarize(result), indent=2) + "\n").encode())
    plot_skill_gpu(result, out / PLOT)
    report(format_skill_gpu(result), result, cfg.json or None)
    return result


def plot_skill_gpu(result: dict[str, Any], path: Path) -> Path:
    """Test MWR against env steps and against the training's wall time (when each policy was frozen), one line
    per seed, the thresholds dashed and the goal's time dotted."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import EngFormatter

    fig = Figure(figsize=(11, 4.8))
    axes = fig.subplots(1, 2, sharey=True)
    for s, run in enumerate(result["runs"]):
        ev = run["evaluations"]
        for ax, key in zip(axes, ("env_steps", "policy_train_seconds"), strict=True):
            ax.plot([e[key] for e in ev], [e["test_mwr"] for e in ev], marker="o", markersize=4, color=f"C{s}",
                    label=f"seed {run['seed']} ({run['status']})")
    for ax, xlabel in zip(axes, ("env steps", "training wall time when the policy was frozen (s)"), strict=True):
        for level in result["thresholds"]:
            ax.axhline(level, linestyle="--", color="grey")
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
    axes[1].axvline(result["goal_seconds"], linestyle=":", color="black", label=f"goal {result['goal_seconds']:g} s")
    axes[0].xaxis.set_major_formatter(EngFormatter())  # 800k, 1.2M: millions of env steps stay legible
    axes[0].set_ylabel(f"test MWR ({result['eval_epochs']} seeded test matches)")
    axes[1].legend(fontsize=8)
    title = textwrap.wrap(_where(result).replace("\n", "; "), width=150)  # a long machine line stays on the page
    fig.suptitle("\n".join([*title, _goal_line(result)]), fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def _where(result: dict[str, Any]) -> str:
    m, d = result["machine"], result["device"]
    gpu = m["gpu"] or f"Warp's {m['warp_device']} device (not a GPU figure)"
    host = m["host_reference"]["before"]["ms_per_env_step"]
    return (f"{result['algo']} on MuJoCo Warp, {result['n_envs']:,} matches on {gpu}; host {m['cores']} CPU cores "
            f"({m['cpu']}), reference collection {host:.3f} ms per env step\n"
            f"device: first step {d['first_step_seconds']:.1f} s (build, kernels, graphs), then "
            f"{d['env_steps_per_s']:,.0f} env steps/s (random actions, no learner)")


def _goal_line(result: dict[str, Any]) -> str:
    goal = result["goal"]
    if goal["met"] is None:
        return f"goal: {level_key(goal['threshold'])} within {goal['seconds']:g} s: no seed run"
    median = "not reached" if goal["median_seconds"] is None else f"{goal['median_seconds']:.1f} s"
    return (f"goal: {level_key(goal['threshold'])} within {goal['seconds']:g} s of training: "
            f"{'met' if goal['met'] else 'missed'} (median {median})")


def format_skill_gpu(result: dict[str, Any]) -> str:
    """The table printed by the bench: where it ran, one row per seed and threshold, the median and spread per
    threshold, and the goal."""
    s = result["schedule"]
    lines = [f"time to skill on a GPU: first test MWR >= each of {' '.join(map(level_key, result['thresholds']))} "
             f"({result['eval_epochs']} seeded test matches every {result['eval_every']:,} env steps, on the CPU "
             f"{'in the background' if result['eval_background'] else 'inline'}; budget "
             f"{result['max_env_steps']:,} env steps or {result['max_seconds']:g} s per seed)",
             _where(result),
             f"schedule: {s['gradient_steps']} updates of {s['batch_size']:,} per step of all the matches, after "
             f"{s['learning_starts']:,} transitions of warm-up",
             "seconds: the training's wall time when the policy that reached the threshold was frozen; wall: when "
             "its result was known", "",
             f"{'seed':>4s} {'threshold':>9s} {'env steps':>12s} {'seconds':>8s} {'wall (s)':>8s}  status"]
    for run in result["runs"]:
        for key, at in run["to"].items():
            if at["reached"]:
                lines.append(f"{run['seed']:4d} {key:>9s} {at['env_steps']:12,d} {at['seconds']:8.1f} "
                             f"{at['wall_seconds']:8.1f}  {run['status']}")
            else:
                best = "" if run["best_test_mwr"] is None else f", best {run['best_test_mwr']:+.3f}"
                lines.append(f"{run['seed']:4d} {key:>9s} {'not reached':>12s} {'-':>8s} {'-':>8s}  {run['status']} "
                             f"after {run['env_steps']:,} env steps, {run['run_seconds']:.0f} s{best}")
        curve = " ".join(f"{e['test_mwr']:+.2f}" for e in run["evaluations"])
        lines.append(f"{'':4s} test MWR curve: {curve or '(no evaluation)'}")
    lines.append("")
    for key, entry in result["summary"].items():
        def one(v: float | None, fmt: str) -> str:
            return "not reached" if v is None else format(v, fmt)

        e, t = entry["env_steps"], entry["seconds"]
        lines.append(f"{key}: {entry['reached']} of {entry['seeds']} seeds; median (min - max) "
                     f"{one(e['median'], ',.0f')} ({one(e['min'], ',.0f')} - {one(e['max'], ',.0f')}) env steps, "
                     f"{one(t['median'], '.1f')} ({one(t['min'], '.1f')} - {one(t['max'], '.1f')}) s")
    lines.append(_goal_line(result))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="triplesumo bench skill-gpu", description=__doc__.split("\n\n")[0])
    _dcargs.add_arguments(parser, SkillGpuConfig)
    run_skill_gpu(_dcargs.build(SkillGpuConfig, parser.parse_args(argv)))
    return 0
