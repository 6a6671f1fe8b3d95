"""``triplesumo demo``: the main job. A short, real run of the paper's experiment.

1. Train Bug with SAC (TripleSumo's recipe: one update per 8 transitions, 5-step returns; ``--algo ddpg``: the
   paper's preset) for 150,000 env steps in the shipped ongoing match: the zoo's trained Ant and Spider play, Bug
   learns to cooperate with Ant.
2. Evaluate the Bug it trained, the shipped Bug (``zoo:bug``: the reproduction's best, SAC after 1 M env steps,
   docs/CONTEST.md) and the passive and random Bug baselines, all in the same seeded test matches, with
   no exploration noise. The recipe reaches a test MWR of +0.2 in a median of 125,008 env steps over 5 training
   seeds (docs/bench/skill.md), so the demo's Bug usually starts to turn the match; the shipped Bug, with 1 M env
   steps, does.
3. Record one match of the shipped Bug with Ant against Spider as mp4: the first of the test
   matches of step 2 that the team won and that lasted at least :data:`MIN_VIDEO_STEPS` steps
   (long enough to watch), or, where it won none, its longest match; the output says which.

Everything lands in one folder (default ``runs/demo``); the end of the output says
where. The full reproduction is ``triplesumo reproduce`` (see docs/REPRODUCTION.md).

``--scenario NAME`` runs the same three steps in another named game: its default learner
(``ffa``: Bug, ``pursuit``: the evader, ``2v2``: Ant) trains with the same algorithm against random others, is
evaluated against the passive and random baselines, and plays the recorded match.
"""

from __future__ import annotations

import csv
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from triplesumo.agents.policy_file import load_json, policy_paths
from triplesumo.agents.zoo import policy_stem
from triplesumo.envs.seeding import check_seed
from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate, format_summary
from triplesumo.evaluation.metrics_csv import open_table
from triplesumo.evaluation.play import PlayConfig, run_play
from triplesumo.evaluation.video import check_writable
from triplesumo.rules.scenarios import get_scenario
from triplesumo.train.config import TrainConfig
from triplesumo.train.loop import train
from triplesumo.train.run_folder import holds_run
from triplesumo.version import ENV_VERSION
from triplesumo.zoo import older_pair

MIN_VIDEO_STEPS = 100
"""A recorded match lasts at least this many steps (5 s at 20 frames per second) where a win that long exists."""


def match_to_record(metrics_csv: Path, eval_seed: int, min_steps: int = MIN_VIDEO_STEPS) -> tuple[int, str]:
    """The reset seed of the test match to film from an evaluation's per-match rows (epoch ``i`` reset with
    ``eval_seed + i - 1``) and why it was chosen: the first win of at least ``min_steps`` steps, else the
    longest win, else the longest match."""
    with open_table(metrics_csv) as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise ValueError(f"{metrics_csv}: no test matches to choose a match to record from")
    wins = [r for r in rows if r["outcome"] == "win"]
    long_wins = [r for r in wins if int(r["steps"]) >= min_steps]
    if long_wins:
        row, why = long_wins[0], f"the first test match the team won in at least {min_steps} steps"
    elif wins:
        row = max(wins, key=lambda r: int(r["steps"]))
        why = f"the longest test match the team won (none lasted {min_steps})"
    else:
        row, why = max(rows, key=lambda r: int(r["steps"])), "the longest test match (the team won none)"
    return (eval_seed + int(row["epoch"]) - 1,
            f"{why}: test match {row['epoch']}, {row['outcome']} after {row['steps']} steps")


DEMO_ALGOS = {"sac": "SAC (TripleSumo's recipe)", "ddpg": "DDPG (the paper's preset)"}
"""The demo's learners, as its output names them."""


@dataclass(frozen=True)
class DemoConfig:
    """Train Bug briefly in the shipped ongoing match, evaluate it against baselines, record a match."""

    out: str = "runs/demo"
    """Folder for everything the demo writes."""
    algo: str = "sac"
    """Bug's learner: sac (its defaults, TripleSumo's recipe) or ddpg (the paper's preset)."""
    train_env_steps: int = 150_000
    """Env steps (of all matches together) Bug trains for: its run stops at the first match end past them. The
    recipe reaches +0.2 in a median of 125,008 (5 seeds); the paper's 20,000 epochs were about 5 M."""
    max_minutes: float = 15.0
    """Stop training after this many minutes even if train_env_steps are not done (0 = no limit)."""
    eval_epochs: int = 400
    """Test epochs for the trained Bug and for each baseline."""
    seed: int = 0
    """Seed of training; evaluation uses its own fixed seed."""
    steps_per_epoch: int = 500
    """Step limit of every match (paper: 500); smaller makes a quicker smoke run."""
    n_envs: int = 16
    """Matches played at once."""
    learning_starts: int | None = None
    """Random warm-up transitions before Bug's first update; None: the learner's own (SAC 5,000, DDPG 1,000)."""
    video: bool = True
    """Record one test match of the trained Bug as mp4, and as a page that replays it in a browser
    (``match.html``, as ``triplesumo view``)."""
    video_size: int = 480
    """Width and height of the video in pixels."""
    progress: bool = True
    """Show progress bars."""
    scenario: str = "paper"
    """Named game (paper, ffa, pursuit, 2v2); outside the paper its learner trains against random others."""

    def __post_init__(self) -> None:
        check_seed(self.seed, "DemoConfig.seed")
        get_scenario(self.scenario)
        if self.algo not in DEMO_ALGOS:
            raise ValueError(f"DemoConfig.algo must be one of {', '.join(DEMO_ALGOS)}, got {self.algo!r}")
        for name in ("train_env_steps", "eval_epochs", "n_envs", "steps_per_epoch"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"DemoConfig.{name} must be an int >= 1, got {value!r}")
        if self.max_minutes < 0:
            raise ValueError(f"DemoConfig.max_minutes must be >= 0, got {self.max_minutes}")
        if self.video_size < 16:
            raise ValueError(f"DemoConfig.video_size must be >= 16, got {self.video_size}")
        if self.learning_starts is not None and self.learning_starts < 0:
            raise ValueError(f"DemoConfig.learning_starts must be >= 0, got {self.learning_starts}")


def _train_config(cfg: DemoConfig, name: str, out: Path, **fields: Any) -> TrainConfig:
    """The demo's training run of agent ``name`` with ``cfg.algo``: ``cfg``'s budget, matches and seed, the
    learner's own hyper-parameters but for ``learning_starts`` when given."""
    base = TrainConfig(name=name, out=str(out), learn=(f"{name}={cfg.algo}",), epochs=10**9,
                       max_env_steps=cfg.train_env_steps, max_minutes=cfg.max_minutes,
                       steps_per_epoch=cfg.steps_per_epoch, seed=cfg.seed, n_envs=cfg.n_envs,
                       progress=cfg.progress, checkpoint_every=250, **fields)
    if cfg.learning_starts is None:
        return base
    learner = getattr(base, cfg.algo)
    return dataclasses.replace(base, **{cfg.algo: dataclasses.replace(learner, learning_starts=cfg.learning_starts)})


def run_demo(cfg: DemoConfig) -> dict[str, Path]:
    if cfg.scenario != "paper":
        return _run_scenario_demo(cfg)
    out = check_writable(Path(cfg.out), folder=True)
    if holds_run(out / "bug") or (out / "evaluation").exists():
        raise FileExistsError(f"{out} already holds an earlier demo's results; nothing was changed: choose another "
                              "--out (or delete that folder)")
    older = older_pair()
    if older:
        print(f"note: the shipped {' and '.join(older)} were trained on env {', '.join(sorted(set(older.values())))}, "
              f"not {ENV_VERSION}, and the v2 pair is not built yet: this team is expected to lose "
              "(docs/CONTEST.md)")
    print(f"[1/3] training Bug with {DEMO_ALGOS[cfg.algo]} for {cfg.train_env_steps:,} env steps in the shipped "
          f"ongoing match -> {out / 'bug'}")
    result = train(_train_config(cfg, "bug", out))
    print(f"      {result.epochs} epochs, {result.env_steps} env steps, {result.updates} updates in "
          f"{result.seconds:.0f} s; training MWR {result.mwr:+.3f}")
    policy = str(result.run_dir / "policy")
    shipped = load_json(policy_paths(policy_stem("zoo:bug"))[0])  # the manifest of the Bug step 2 plays
    print(f"[2/3] evaluating this Bug, the shipped Bug (zoo:bug: {shipped['algo'].upper()}, "
          f"{shipped['env_steps']:,} env steps), passive and random Bug "
          f"({cfg.eval_epochs} test epochs each, the same matches)")
    eval_cfg = EvaluateConfig(policy=(policy,), compare=("zoo:bug",), epochs=cfg.eval_epochs,
                              out=str(out / "evaluation"), steps_per_epoch=cfg.steps_per_epoch,
                              n_envs=cfg.n_envs, progress=cfg.progress)
    summary = evaluate(eval_cfg)
    print(format_summary(summary))
    paths = {"run": result.run_dir, "training_plots": result.run_dir / "plots",
             "evaluation": out / "evaluation", "comparison_plot": out / "evaluation" / "compare_mwr.png"}
    if cfg.video:
        seed, why = match_to_record(out / "evaluation" / "zoo-bug" / "metrics.csv", eval_cfg.seed)
        print(f"[3/3] recording a test match of the shipped Bug with Ant against Spider: {why} (seed {seed})")
        video, page = out / "match.mp4", out / "match.html"
        run_play(PlayConfig(seed=seed, video=str(video), html=str(page), max_steps=cfg.steps_per_epoch,
                            width=cfg.video_size, height=cfg.video_size,
                            policies=("bug=zoo:bug", "ant=zoo:ant", "spider=zoo:spider")))
        paths["video"] = video
        paths["page"] = page
    print("\nwhere to look:")
    for name, path in paths.items():
        print(f"  {name:16s} {path}")
    return paths


def _run_scenario_demo(cfg: DemoConfig) -> dict[str, Path]:
    """The demo in a named game other than the paper's: its learner against random others."""
    learner = get_scenario(cfg.scenario).learner
    out = check_writable(Path(cfg.out), folder=True)
    print(f"[1/3] training {learner} with {DEMO_ALGOS[cfg.algo]} for {cfg.train_env_steps:,} env steps in "
          f"scenario {cfg.scenario!r} against random others -> {out / learner}")
    result = train(_train_config(cfg, learner, out, policies=("*=random",), scenario=cfg.scenario))
    print(f"      {result.epochs} epochs, {result.env_steps} env steps, {result.updates} updates in "
          f"{result.seconds:.0f} s; training MWR {result.mwr:+.3f}")
    policy = str(result.run_dir / "policy")
    print(f"[2/3] evaluating this {learner}, passive and random {learner} ({cfg.eval_epochs} test epochs each)")
    eval_cfg = EvaluateConfig(policy=(policy,), learner=learner, policies=("*=random",), scenario=cfg.scenario,
                              epochs=cfg.eval_epochs, out=str(out / "evaluation"),
                              steps_per_epoch=cfg.steps_per_epoch, n_envs=cfg.n_envs, progress=cfg.progress)
    print(format_summary(evaluate(eval_cfg)))
    paths = {"run": result.run_dir, "training_plots": result.run_dir / "plots",
             "evaluation": out / "evaluation", "comparison_plot": out / "evaluation" / "compare_mwr.png"}
    if cfg.video:
        print(f"[3/3] recording a test match of the trained {learner}")
        video, page = out / "match.mp4", out / "match.html"
        run_play(PlayConfig(seed=eval_cfg.seed, video=str(video), html=str(page), max_steps=cfg.steps_per_epoch,
                            width=cfg.video_size, height=cfg.video_size, scenario=cfg.scenario,
                            policies=(f"{learner}={policy}", "*=random")))
        paths["video"] = video
        paths["page"] = page
    print("\nwhere to look:")
    for name, path in paths.items():
        print(f"  {name:16s} {path}")
    return paths
