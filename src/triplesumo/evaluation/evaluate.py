"""``triplesumo evaluate``: test epochs with fixed policies, against baselines.

A *candidate* is a learner policy (default: the trained Bug). It plays ``epochs`` test
matches with the other agents' fixed policies (default: the shipped Ant and Spider),
with no exploration noise; the reset noise of test epoch ``i`` is seeded with
``seed + i``, so the matches differ from each other but every candidate meets the very
same starts (a paired comparison). The baselines play the same matches: Bug passive
(zero action) and Bug random. Cooperation is shown by the difference between the
candidate and the baselines, not assumed.

Writes, into ``out``: ``<label>/metrics.csv`` (the training CSV schema) and its plots
per candidate, ``compare_mwr.png`` and ``compare_rewards.png``, and ``summary.json``
with win/loss/draw counts and 95% Wilson intervals, the mean local winning rate (the
test MWR over the whole run) with its 95% interval, and mean steps to win. Every candidate
after the first also gets ``paired``: its test MWR minus the first candidate's over the same
starts, the mean of the per-epoch differences with a 95% interval. Pairing cancels what the
start decides for both, so it separates candidates that the two intervals of their own leave
overlapping.

Resuming: each candidate's rows are appended to its ``metrics.csv`` as the epochs finish
(in epoch order), and ``evaluation.json`` records what the rows depend on (learner,
policies and the sha256 of their files, seed, step limit, observation mode). A test
epoch's result depends on its seed alone, so ``resume=True`` keeps the finished epochs,
plays the rest and gives exactly the rows of an uninterrupted run; it can also extend a
finished run to more epochs. A resume plays the candidates it names (new ones are added) and
keeps every finished candidate the folder recorded, named again or not (it needs no files):
``--resume --compare NEW`` grows a folder by one candidate, and its ``summary.json`` and plots
still hold them all. An unfinished candidate that is not named again is left out.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
from collections.abc import Callable, Iterator, Mapping
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from triplesumo._lock import held
from triplesumo.agents.builtin import BUILTIN
from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.agents.zoo import check_policy_pairs, check_seat, expand_pairs, policy_fingerprint
from triplesumo.envs.match import Match
from triplesumo.envs.seeding import check_seed
from triplesumo.evaluation.metrics import local_winning_rate, summarize
from triplesumo.evaluation.metrics_csv import (
    COLUMNS,
    open_table,
    packed_path,
    repair_metrics_csv,
    table_exists,
    write_table,
)
from triplesumo.evaluation.parallel import (
    ProcessRunner,
    Row,
    TaskRunner,
    check_counts,
    play_chunks,
    play_schedules,
    portable_spec,
)
from triplesumo.evaluation.runner import SeatedResult, play_matches
from triplesumo.evaluation.stats import mean_interval
from triplesumo.evaluation.video import check_writable
from triplesumo.model.specs import V0_PHYSICS, PhysicsConfig, physics_record
from triplesumo.rules.config import OBS_MODES, MatchConfig
from triplesumo.rules.scenarios import scenario_config
from triplesumo.zoo import make_policy, policies_from_pairs


@dataclass(frozen=True)
class EvaluateConfig:
    """Test epochs of a learner policy against baselines in the same matches."""

    learner: str = "bug"
    """The agent whose policy is evaluated."""
    policy: tuple[str, ...] = ("zoo:bug",)
    """The learner's policy: zoo:NAME, a policy file (e.g. runs/bug/policy), zero or random; or several,
    one per training seed (runs/s0/policy runs/s1/policy, or a quoted glob 'runs/s*/policy')."""
    policies: tuple[str, ...] = ("ant=zoo:ant", "spider=zoo:spider")
    """AGENT=POLICY for the other agents (fixed, no exploration noise)."""
    compare: tuple[str, ...] = ()
    """Other learner policies played in the same matches (e.g. zoo:bug, a policy file, or a quoted glob such as
    'runs/x/league/members/spider-*/spider' for every league snapshot of a run, to pick one on held-out starts)."""
    baselines: tuple[str, ...] | None = None
    """Baseline learner policies played in the same matches (built-in names; --baselines with none: no
    baselines). Not given: passive and random, or with ``resume`` the baselines the folder already played."""
    epochs: int = 2000
    """Test epochs per candidate (the paper used 20,000)."""
    seed: int = 10_000
    """Test epoch i resets with seed + i (the same starts for every candidate)."""
    steps_per_epoch: int = 500
    """Step limit of a match (a draw when reached)."""
    obs_mode: str = "paper"
    """Observation mode the policies expect."""
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    """The simulation (``border_rim``: the paper's solid ring rim); as the policies were trained on."""
    allow_other_ring: bool = False
    """Let a policy file trained on another ring (its manifest's physics: rim, start layout) play on this one;
    without it such a policy is refused, naming both rings."""
    window: int = 200
    """λ of the MWR and rolling curves (paper: 200)."""
    out: str = "runs/evaluation"
    """Folder for the report, CSVs and plots."""
    n_envs: int = 16
    """Matches played at once."""
    n_threads: int = 2
    """MuJoCo threads."""
    progress: bool = True
    """Show a progress bar."""
    resume: bool = False
    """Continue the evaluation in ``out`` (killed, to more epochs, or with more candidates): finished epochs
    and every finished candidate recorded there are kept."""
    record: int = 0
    """Write the first K test epochs of every candidate as replayable match files
    (``OUT/CANDIDATE/matches/epoch_00001.npz`` ...; ``triplesumo replay`` re-renders them)."""
    record_html: int = 0
    """Also write the first K test epochs of every candidate as self-contained HTML pages that replay them in a
    browser, offline (``OUT/CANDIDATE/matches/epoch_00001.html`` ..., beside their match files, which are
    written for them too; as ``triplesumo view``)."""
    scenario: str = "paper"
    """Named game (paper, ffa, pursuit, 2v2) with its default roster; policies may use *=POLICY
    for every other agent. Under elimination rules a test epoch ends when the learner is out."""
    ray: bool = False
    """Play the test epochs as Ray tasks (chunks of ray_chunk epochs; the same rows as a local run): the
    command line hands evaluate a Ray runner. Needs pip install "triplesumo[ray]"."""
    ray_address: str = ""
    """With ray: the Ray cluster to use (e.g. auto, ray://HOST:10001); empty: start a local Ray."""
    ray_chunk: int = 50
    """With ray (or any runner handed to evaluate) or workers > 1: test epochs per task. Every candidate's
    epochs are cut into such tasks in one queue, the first task of every candidate before the second of
    any, so a stopped run leaves them about equally far."""
    workers: int = 1
    """Processes playing the test epochs at once on this machine (no Ray needed), one MuJoCo thread
    each: evaluate plays on a ProcessRunner(workers), in tasks of ray_chunk epochs. The same rows as
    one process. 1: played here, on n_threads threads."""

    def __post_init__(self) -> None:
        check_seed(self.seed, "EvaluateConfig.seed")
        for name in ("record", "record_html"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise ValueError(f"EvaluateConfig.{name} must be an int >= 0, got {value!r}")
        for name in ("epochs", "steps_per_epoch", "window", "n_envs", "n_threads", "ray_chunk", "workers"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"EvaluateConfig.{name} must be an int >= 1, got {value!r}")
        if self.ray and self.workers > 1:
            raise ValueError("EvaluateConfig.workers and EvaluateConfig.ray both spread the test epochs: "
                             "choose one (workers on this machine, ray on a cluster)")
        check_ray("EvaluateConfig", self.ray, self.ray_address)
        agents = list(scenario_config(self.scenario).agent_names)  # names the scenario if unknown
        if self.learner not in agents:
            raise ValueError(f"EvaluateConfig.learner must be one of {agents} (scenario {self.scenario!r}), "
                             f"got {self.learner!r}")
        check_policy_pairs("EvaluateConfig.policies", self.policies, self.learner, agents)
        if isinstance(self.baselines, str):  # one name given as a plain string
            object.__setattr__(self, "baselines", (self.baselines,))
        unknown = [b for b in self.baselines or () if b not in BUILTIN]
        if unknown:
            raise ValueError(f"EvaluateConfig.baselines must be built-in policies {sorted(BUILTIN)}, got {unknown}")
        if isinstance(self.policy, str):  # one spec given as a plain string
            object.__setattr__(self, "policy", (self.policy,))
        if not self.policy:
            raise ValueError("EvaluateConfig.policy needs at least one policy")
        if self.obs_mode not in OBS_MODES:
            raise ValueError(f"EvaluateConfig.obs_mode must be one of {OBS_MODES}, got {self.obs_mode!r}")


def check_ray(owner: str, ray: bool, address: str) -> None:
    """``ValueError`` naming the extra when ``ray`` is asked for but not installed (Ray is not imported)."""
    import importlib.util

    if address and not ray:
        raise ValueError(f"{owner}.ray_address needs {owner}.ray (--ray)")
    if ray and importlib.util.find_spec("ray") is None:
        raise ValueError(f'{owner}.ray: Ray is not installed; install the extra: pip install "triplesumo[ray]"')


def play_test_epochs(
    learner_policy: Any,
    others: dict[str, Any],
    learner: str,
    epochs: int,
    seed: int,
    match_cfg: MatchConfig,
    n_envs: int = 16,
    n_threads: int = 2,
    label: str = "",
    progress: bool = False,
    first: int = 0,
    on_row: Callable[[dict[str, Any]], None] | None = None,
    record: int = 0,
    record_dir: Path | None = None,
    policy_names: dict[str, str] | None = None,
) -> list[dict[str, Any]]:
    """Play test epochs ``first .. epochs - 1`` (epoch ``i`` seeded ``seed + i``); one metrics row per
    epoch, in order. ``on_row`` is called with each row in epoch order as soon as it and every
    earlier one have finished (matches end out of order). The matches are played by
    :func:`~triplesumo.evaluation.runner.play_matches`: each row depends on its seed only.
    Under elimination rules a test epoch ends when the learner is out. Epochs ``< record`` are
    written to ``record_dir/epoch_NNNNN.npz`` as match files (``policy_names`` stored in them)."""
    agents = match_cfg.agent_names
    if learner not in agents:
        raise ValueError(f"learner must be one of {list(agents)}, got {learner!r}")
    L = agents.index(learner)
    seats = {**others, learner: learner_policy}
    lineup = [seats.get(name) for name in agents]

    def row(result: SeatedResult) -> dict[str, Any]:
        a, outcome = result.terms[L], result.outcomes[L]
        return {"epoch": result.index + 1, "outcome": outcome,
                "local_winning_rate": float(local_winning_rate([outcome])[0]), "steps": result.steps,
                "total_reward": a["dense_reward"] + a["sparse_reward"], **a, "env_steps": 0, "wall_time": 0.0}

    results = play_matches(lambda i: lineup, lambda i: seed + i, epochs, match_cfg, n_envs, n_threads, first,
                           on_result=None if on_row is None else lambda r: on_row(row(r)), terms_of=(L,),
                           progress=f"evaluate {label}".strip() if progress else None, end_seat=L,
                           record=record, record_dir=record_dir, policy_names=policy_names)
    return [row(r) for r in results]


def play_test_chunk(learner_spec: str, other_specs: dict[str, str], learner: str, seed: int, match_cfg: MatchConfig,
                    n_envs: int, record: int, record_dir: str | None, policy_names: dict[str, str] | None,
                    first: int, end: int) -> list[dict[str, Any]]:
    """The rows of test epochs ``first .. end - 1`` of the policy ``learner_spec`` against ``other_specs``
    (agent -> spec), played from the specs on one MuJoCo thread: what a worker process or a Ray task runs
    (the same rows as :func:`play_test_epochs` with those policies)."""
    probe = Match(match_cfg)
    motors = dict(zip(probe.agents, probe.action_sizes, strict=True))
    sizes = probe.observer.sizes
    obs_mode = match_cfg.obs_mode
    learner_policy = make_policy(learner_spec, seed=seed, expect_obs_mode=obs_mode, action_size=motors[learner],
                                 expect_obs_dim=sizes[learner])
    others = policies_from_pairs(tuple(f"{a}={s}" for a, s in other_specs.items()), seed, obs_mode,
                                 action_sizes=motors, obs_dims=sizes)
    return play_test_epochs(learner_policy, others, learner, end, seed, match_cfg, n_envs=min(n_envs, end - first),
                            n_threads=1, first=first, record=record,
                            record_dir=None if record_dir is None else Path(record_dir),
                            policy_names=policy_names or {**other_specs, learner: learner_spec})


def play_test_epochs_on(runner: TaskRunner, learner_spec: str, other_specs: Mapping[str, str], learner: str,
                        epochs: int, seed: int, match_cfg: MatchConfig | None = None, first: int = 0, chunk: int = 50,
                        n_envs: int = 8, on_row: Callable[[dict[str, Any]], None] | None = None, record: int = 0,
                        record_dir: Path | None = None, policy_names: dict[str, str] | None = None,
                        progress: str | None = None) -> list[dict[str, Any]]:
    """Rows of test epochs ``first .. epochs - 1``, played by ``runner`` as tasks of ``chunk`` epochs each
    (:func:`play_test_chunk`, through :func:`~triplesumo.evaluation.parallel.play_chunks`).

    The same rows as ``play_test_epochs`` with the same policies and seeds, in epoch order
    (``on_row`` gets each as soon as it and every earlier one are in). Match files of epochs
    ``< record`` are written by the tasks into ``record_dir`` (a folder every task can reach), with
    ``policy_names`` (default: the specs) stored in them.
    """
    check_counts(epochs=epochs, chunk=chunk, n_envs=n_envs)
    if not 0 <= first < epochs:
        raise ValueError(f"first must be in [0, epochs={epochs}), got {first}")
    args = _chunk_args(learner_spec, other_specs, learner, seed, match_cfg, n_envs, record, record_dir, policy_names)
    return play_chunks(runner, play_test_chunk, args, epochs, first, chunk, on_row, progress)


def play_candidates_on(runner: TaskRunner, candidates: Mapping[str, str], other_specs: Mapping[str, str],
                       learner: str, epochs: int, seed: int, match_cfg: MatchConfig | None = None,
                       firsts: Mapping[str, int] | None = None, chunk: int = 50, n_envs: int = 8,
                       on_row: Callable[[str, Row], None] | None = None, record: int = 0,
                       record_dirs: Mapping[str, Path] | None = None,
                       progress: str | None = None) -> dict[str, list[Row]]:
    """Rows of test epochs ``firsts[label] .. epochs - 1`` (default from 0) of every candidate (label ->
    learner spec), played by ``runner`` as tasks of ``chunk`` epochs in one queue, chunk-major (the first
    chunk of every candidate before the second of any: :func:`~triplesumo.evaluation.parallel.play_schedules`).

    Each candidate's rows are those of :func:`play_test_epochs_on` for it; ``on_row(label, row)`` gets them
    in epoch order, each as soon as it and every earlier one of that candidate are in. A failing task
    raises after the rows handed on before it (they stay valid: a resume plays the others). Match files of
    epochs ``< record`` go to ``record_dirs[label]``, with the specs as given stored in them."""
    check_counts(epochs=epochs, chunk=chunk, n_envs=n_envs)
    args = {label: _chunk_args(spec, other_specs, learner, seed, match_cfg, n_envs, record,
                               None if record_dirs is None else record_dirs[label], {**other_specs, learner: spec})
            for label, spec in candidates.items()}
    return play_schedules(runner, play_test_chunk, args, epochs, firsts, chunk, on_row, progress)


def _chunk_args(learner_spec: str, other_specs: Mapping[str, str], learner: str, seed: int,
                match_cfg: MatchConfig | None, n_envs: int, record: int, record_dir: Path | None,
                policy_names: dict[str, str] | None) -> tuple[Any, ...]:
    """The arguments of :func:`play_test_chunk` before ``first, end``, as plain data any process can use."""
    specs = {a: portable_spec(s) for a, s in other_specs.items()}
    return (portable_spec(learner_spec), specs, learner, seed, match_cfg or MatchConfig(), n_envs, record,
            None if record_dir is None else str(Path(record_dir).resolve()), policy_names)


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _label(spec: str) -> str:
    """A folder-safe label for a policy spec (``zoo:bug`` -> ``zoo-bug``)."""
    return "".join(c if c.isalnum() or c in "-_" else "-" for c in spec).strip("-") or "policy"


DEFAULT_BASELINES = ("passive", "random")
"""The baselines of an evaluation that names none (and is not a resume)."""


RECORD_FILE = "evaluation.json"
"""What an evaluation folder's rows depend on, for resuming (see the module docstring)."""
ROW_FIELDS = ("learner", "policies", "seed", "steps_per_epoch", "obs_mode")
"""The :class:`EvaluateConfig` fields a test epoch's row depends on, besides the candidate's policy."""


def evaluate(cfg: EvaluateConfig, runner: TaskRunner | None = None) -> dict[str, Any]:
    """Run every candidate, write CSVs, plots and ``summary.json``; returns the summary.

    With a ``runner`` (:mod:`triplesumo.evaluation.parallel`) the candidates' test epochs are
    played by it as tasks of ``cfg.ray_chunk`` epochs in one queue (:func:`play_candidates_on`; the
    same rows); ``cfg.ray`` asks for one (the command line hands down a
    :class:`~triplesumo.integrations.ray_tasks.RayRunner`), ``cfg.workers`` > 1 plays on a
    :class:`~triplesumo.evaluation.parallel.ProcessRunner` of that many processes. Without either,
    they are played here, on ``cfg.n_threads`` MuJoCo threads.
    With ``cfg.resume`` the rows already in ``out`` are kept (see the module docstring);
    ``ValueError`` names what changed if they no longer fit the config. ``out`` is held for the whole call
    (:func:`triplesumo._lock.held`): a second evaluation into it meanwhile is refused, naming this one's PID.
    """
    with held(Path(cfg.out), "evaluate"):
        return _evaluate(cfg, runner)


def _evaluate(cfg: EvaluateConfig, runner: TaskRunner | None) -> dict[str, Any]:
    if cfg.ray and runner is None:
        raise ValueError("EvaluateConfig.ray: evaluate plays on the runner it is handed; pass one, e.g. "
                         "triplesumo.integrations.ray_tasks.RayRunner() inside ray_tasks.session() (as --ray does)")
    if runner is not None and cfg.workers > 1:
        raise ValueError("EvaluateConfig.workers and a runner both spread the test epochs: choose one")
    if cfg.workers > 1:
        runner = ProcessRunner(cfg.workers)
    from triplesumo.evaluation.plots import plot_comparison, plot_run, read_metrics_csv

    trained, expanded = expand_policies(cfg.policy), expand_policies(cfg.compare, "compare")
    _one_name_each([*trained, *expanded])  # before anything is written
    out = check_writable(Path(cfg.out), folder=True)
    match_cfg = scenario_config(cfg.scenario, max_steps=cfg.steps_per_epoch, obs_mode=cfg.obs_mode,
                                physics=cfg.physics)
    probe = Match(match_cfg)
    sizes = probe.observer.sizes
    motors = dict(zip(probe.agents, probe.action_sizes, strict=True))
    pairs = expand_pairs(cfg.policies, [a for a in match_cfg.agent_names if a != cfg.learner])
    seeds = {"trained": trained[0]} if len(trained) == 1 else {f"trained-{_label(p)}": p for p in trained}
    if len(seeds) < len(trained):
        raise ValueError(f"EvaluateConfig.policy names a policy twice: {list(trained)}")
    old = _read_record(out / RECORD_FILE) if cfg.resume else None
    if old is not None:  # a policy the folder played keeps its label when more (or fewer) are named beside it
        played = {c["policy"]: label for label, c in old["candidates"].items() if _is_seed_label(label)}
        relabelled = {played.get(p, label): p for label, p in seeds.items()}
        seeds = relabelled if len(relabelled) == len(seeds) else seeds
    baselines = cfg.baselines
    if baselines is None:  # a resume keeps the baselines its folder played (recorded under their own name)
        baselines = DEFAULT_BASELINES if old is None else _baselines_in(
            {label: c["policy"] for label, c in old["candidates"].items()})
    compare = {_label(c): c for c in expanded}
    if len(compare) < len(expanded) or compare.keys() & seeds.keys():
        raise ValueError(f"EvaluateConfig.compare names a policy twice, or one whose label is taken: {expanded}")
    candidates = {**seeds, **compare, **{b: b for b in baselines}}
    try:
        teams = {a.name: a.team for a in match_cfg.agents}
        others = policies_from_pairs(pairs, cfg.seed, cfg.obs_mode, action_sizes=motors, obs_dims=sizes, teams=teams,
                                     physics=cfg.physics, allow_other_ring=cfg.allow_other_ring)
        for spec in candidates.values():  # a policy file drives the learner's seat only if trained for it
            check_seat(spec, cfg.learner, teams)
        policies = {label: make_policy(spec, seed=cfg.seed, expect_obs_mode=cfg.obs_mode,
                                       action_size=motors[cfg.learner], expect_obs_dim=sizes[cfg.learner],
                                       expect_physics=cfg.physics, allow_other_ring=cfg.allow_other_ring)
                    for label, spec in candidates.items()}  # every file checked before any epoch is played
    except ValueError as err:
        raise ValueError(f"scenario {cfg.scenario!r}: {err}") from None
    record = _record(cfg, candidates)
    kept: dict[str, Any] = {}
    if not cfg.resume:
        there = [p for p in (out / RECORD_FILE, *(out / label / "metrics.csv" for label in candidates))
                 if table_exists(p)]
        if there:
            names = ", ".join(str(p.relative_to(out)) for p in there)
            raise FileExistsError(f"{out} already holds an evaluation ({names}); "
                                  "nothing was changed: add --resume to continue or extend it, or choose another --out")
    carried: set[str] = set()
    if old is not None:
        # the finished candidates the folder recorded stay in it, in its order, whether this call names them
        # or not (they need no files); an unfinished one stays only if named, so a resume can drop it
        kept = _previous_candidates(old, out, record)
        left_out = [label for label in kept if label not in candidates
                    and finished_rows(out / label / "metrics.csv", cfg.epochs) < cfg.epochs]
        kept = {label: c for label, c in kept.items() if label not in left_out}
        if left_out and cfg.progress:
            print(f"evaluate: left out, unfinished and not named again: {', '.join(left_out)}")
        record["candidates"] = {**kept, **record["candidates"]}
        carried = kept.keys() - candidates.keys()
        candidates = {label: c["policy"] for label, c in record["candidates"].items()}
    _write_json(out / RECORD_FILE, record)
    baselines = _baselines_in(candidates)
    summary: dict[str, Any] = {"config": {**asdict(cfg), "baselines": baselines}, "candidates": {}}
    with ExitStack() as stack:
        other_specs = dict(p.split("=", 1) for p in pairs)
        firsts = {label: finished_rows(out / label / "metrics.csv", cfg.epochs) if label in kept else 0
                  for label in candidates}
        todo = [label for label in candidates if firsts[label] < cfg.epochs]
        if runner is not None:
            appenders = {label: stack.enter_context(RowAppender(out / label / "metrics.csv", fresh=firsts[label] == 0))
                         for label in todo}
            play_candidates_on(
                runner, {label: candidates[label] for label in todo}, other_specs, cfg.learner, cfg.epochs, cfg.seed,
                match_cfg, firsts, cfg.ray_chunk, cfg.n_envs, lambda label, row: appenders[label](row),
                record=max(cfg.record, cfg.record_html), record_dirs={label: out / label / "matches" for label in todo},
                progress=f"evaluate {len(todo)} candidates" if cfg.progress else None)
            todo = []
        for label in todo:
            spec, done = candidates[label], firsts[label]
            with RowAppender(out / label / "metrics.csv", fresh=done == 0) as append:
                play_test_epochs(policies[label], others, cfg.learner, cfg.epochs, cfg.seed, match_cfg, cfg.n_envs,
                                 cfg.n_threads, label=f"{cfg.learner}={spec}", progress=cfg.progress, first=done,
                                 on_row=append, record=max(cfg.record, cfg.record_html),
                                 record_dir=out / label / "matches",
                                 policy_names={**other_specs, cfg.learner: spec})
    curves, lwr = {}, {}
    for label, spec in candidates.items():
        path = out / label / "metrics.csv"
        metrics = read_metrics_csv(path)
        plot_run(
            metrics, out / label / "plots", window=cfg.window, title=f"test: {cfg.learner}={spec}", label=cfg.learner
        )
        curves[curve_name(cfg.learner, label, spec)] = metrics
        outcomes = metrics["outcome"].tolist()
        lwr[label] = local_winning_rate(outcomes)
        stats = summarize(outcomes, metrics["steps"])
        summary["candidates"][label] = {
            "policy": spec,
            "group": "trained" if label in seeds or _is_seed_label(label) and label in carried else label,
            **{k: _clean(v) for k, v in dict(stats).items()},
            **{f"mean_{name}": float(np.mean(metrics[name].astype(np.float64)))
               for name in ("total_reward", "dense_reward", "sparse_reward")},
        }
    add_paired(summary, lwr)
    plot_comparison(curves, out, window=cfg.window)
    for label in candidates:
        _write_pages(out / label / "matches", cfg.record_html)
    _write_json(out / "summary.json", summary)
    _write_per_seed(out / PER_SEED_FILE, summary, record)
    return summary


def curve_name(learner: str, label: str, spec: str) -> str:
    """A candidate's name in the comparison plots: the learning agent, the candidate and its policy."""
    return f"{learner} {label} ({spec})"


def plot_evaluation_folder(folder: str | os.PathLike[str], window: int | None = None) -> list[Path]:
    """Draw an evaluation folder's ``compare_mwr.png`` and ``compare_rewards.png`` again from its recorded rows
    (``summary.json``'s candidates and each one's ``metrics.csv``), playing nothing: e.g. after a change to the
    plots. ``window`` defaults to the one the evaluation used."""
    from triplesumo.evaluation.plots import plot_comparison, read_metrics_csv

    folder = Path(folder)
    source = folder / "summary.json"
    try:
        summary = json.loads(source.read_text())
        config, candidates = summary["config"], summary["candidates"]
    except FileNotFoundError:
        raise FileNotFoundError(f"{folder}: no summary.json, so no evaluation folder to plot") from None
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{source}: not an evaluation summary ({exc})") from None
    curves = {curve_name(config["learner"], label, c["policy"]): read_metrics_csv(folder / label / "metrics.csv")
              for label, c in candidates.items()}
    return plot_comparison(curves, folder, window=config["window"] if window is None else window)


def _write_pages(matches: Path, n: int) -> list[Path]:
    """The pages of the first ``n`` match files in ``matches`` (``epoch_00001.html`` beside ``epoch_00001.npz``;
    fewer where fewer test epochs were recorded)."""
    from triplesumo.evaluation.recording import MatchFile
    from triplesumo.evaluation.viewer import write_page

    pages = []
    for k in range(1, n + 1):
        source = matches / f"epoch_{k:05d}.npz"
        if source.is_file():
            pages.append(write_page(MatchFile.load(source), source.with_suffix(".html"),
                                    title=f"{matches.parent.name}, test epoch {k}", source=source))
    return pages


PER_SEED_FILE = "per_seed.csv"
"""One row per candidate policy of an evaluation (each training seed its own row): what ``compare`` reads."""
PER_SEED_COLUMNS = ("group", "candidate", "policy", "sha256", "algo", "train_seed", "learner", "eval_seed",
                    "epochs", "n_win", "n_loss", "n_draw", "test_mwr", "test_mwr_lo", "test_mwr_hi")


def add_paired(summary: dict[str, Any], lwr: dict[str, np.ndarray]) -> None:
    """Give every candidate after the first its paired difference from the first (see the module docstring)."""
    reference, *others = lwr
    for label in others:
        if len(lwr[label]) != len(lwr[reference]):
            raise ValueError(f"candidates {reference!r} and {label!r} played {len(lwr[reference])} and "
                             f"{len(lwr[label])} test epochs; a paired comparison needs the same starts")
        diff, lo, hi = mean_interval(lwr[label] - lwr[reference])
        summary["candidates"][label]["paired"] = {"vs": reference, "diff": _clean(diff), "lo": _clean(lo),
                                                  "hi": _clean(hi)}


HEAD_TO_HEAD_ROW = ("n", "n_win", "n_loss", "n_draw", "mean_lwr", "mean_lwr_lo", "mean_lwr_hi", "mean_steps_to_win")
"""The figures of a candidate that a published head-to-head claim (:func:`head_to_head`) copies."""


def head_to_head(folder: Path | str, this: str, others: tuple[str, ...] | list[str],
                 command: str) -> dict[str, Any]:
    """A head-to-head claim for a policy manifest, from an evaluation folder: the rows
    (:data:`HEAD_TO_HEAD_ROW`) of candidate ``this`` and of each of ``others`` (their labels in
    ``summary.json``), and for each other ``this`` minus it, paired over the same starts (mean of the
    per-start local winning rate differences, 95% interval), read from the candidates' ``metrics.csv``.
    ``command`` is the ``triplesumo evaluate`` command that made the folder (it is recorded, not run)."""
    from triplesumo.evaluation.plots import read_metrics_csv

    folder = Path(folder)
    summary = json.loads((folder / "summary.json").read_text())
    labels = [this, *others]
    missing = [label for label in labels if label not in summary["candidates"]]
    if missing:
        raise ValueError(f"{folder / 'summary.json'}: no candidates {missing}; it has {list(summary['candidates'])}")
    lwr = {label: local_winning_rate(read_metrics_csv(folder / label / "metrics.csv")["outcome"].tolist())
           for label in labels}
    paired = {}
    for other in others:
        if len(lwr[other]) != len(lwr[this]):
            raise ValueError(f"{folder}: {this!r} and {other!r} played {len(lwr[this])} and {len(lwr[other])} "
                             "test epochs; a paired comparison needs the same starts")
        diff, lo, hi = mean_interval(lwr[this] - lwr[other])
        paired[other] = {"diff": _clean(diff), "lo": _clean(lo), "hi": _clean(hi)}
    config = summary["config"]
    return {"command": command, "folder": folder.as_posix(), "seed": config["seed"], "epochs": config["epochs"],
            "learner": config["learner"], "opponents": list(config["policies"]), "this": this,
            "rows": {label: {k: summary["candidates"][label][k] for k in HEAD_TO_HEAD_ROW} for label in labels},
            "paired": paired}


def expand_policies(specs: tuple[str, ...], field: str = "policy") -> list[str]:
    """Policy specs with globs (``runs/s*/policy``) expanded to the policy files they match, sorted;
    ``ValueError`` naming ``EvaluateConfig.<field>`` for a glob that matches none."""
    import glob

    out: list[str] = []
    for spec in specs:
        if not any(c in spec for c in "*?["):
            out.append(spec)
            continue
        stems = sorted({str(Path(p).with_suffix("")) for p in glob.glob(spec) + glob.glob(spec + ".json")
                        if p.endswith(".json") or Path(p + ".json").exists()})
        if not stems:
            raise ValueError(f"EvaluateConfig.{field}: {spec!r} matches no policy file")
        out += stems
    return out


def _one_name_each(specs: list[str]) -> None:
    """``ValueError`` when two specs name one policy file pair by different names (``a.json`` and ``a.safetensors``,
    or ``a`` and ``a.json``): it would be played twice under two labels. The usual cause is a glob the shell
    expanded (``--compare runs/x/spider-*``) where quoted, :func:`expand_policies` takes each pair once."""
    from triplesumo.agents.policy_file import bare_stem

    seen: dict[Path, str] = {}
    for spec in specs:
        if spec in BUILTIN or spec.startswith("zoo:"):
            continue
        stem = bare_stem(spec)
        if stem in seen and seen[stem] != spec:
            raise ValueError(f"EvaluateConfig: {seen[stem]!r} and {spec!r} name one policy file pair ({stem}); "
                             f"give each policy once (a glob expanded by the shell names both files of a pair: "
                             f"quote it, or end it in .json)")
        seen.setdefault(stem, spec)


def _manifest_of(spec: str) -> dict[str, Any]:
    """A policy file's manifest; ``{}`` for a built-in policy."""
    from triplesumo.agents.policy_file import load_json, policy_paths
    from triplesumo.agents.zoo import policy_stem

    if spec in BUILTIN:
        return {}
    return load_json(policy_paths(policy_stem(spec))[0])


def algo_of(spec: str) -> str:
    """The algorithm that made a policy: its manifest's ``algo``; ``ddpg`` for ``triplesumo train``
    policies that predate the field; a built-in policy's own name."""
    if spec in BUILTIN:
        return spec
    manifest = _manifest_of(spec)
    if "algo" in manifest:
        return str(manifest["algo"])
    return "ddpg" if str(manifest.get("command", "")).startswith("triplesumo train") else "unknown"


def _write_per_seed(path: Path, summary: dict[str, Any], record: dict[str, Any]) -> None:
    import io

    cfg = summary["config"]
    previous: dict[str, dict[str, str]] = {}  # a resume's rows: a kept candidate's files may be gone
    try:
        with open_table(path) as fh:
            previous = {row["candidate"]: row for row in csv.DictReader(fh)}
    except (OSError, KeyError, csv.Error):
        pass
    buf = io.StringIO()
    writer = csv.DictWriter(buf, PER_SEED_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for label, c in summary["candidates"].items():
        sha = record["candidates"][label]["sha256"]
        then = previous.get(label, {})
        if then.get("sha256") == sha and then.get("policy") == c["policy"] and "algo" in then:
            algo, train_seed = then["algo"], then.get("train_seed", "")
        else:
            algo, train_seed = algo_of(c["policy"]), _manifest_of(c["policy"]).get("seed", "")
        writer.writerow({"group": c["group"], "candidate": label, "policy": c["policy"],
                         "sha256": sha, "algo": algo, "train_seed": train_seed, "learner": cfg["learner"],
                         "eval_seed": cfg["seed"],
                         "epochs": c["n"], "n_win": c["n_win"], "n_loss": c["n_loss"], "n_draw": c["n_draw"],
                         "test_mwr": c["mean_lwr"], "test_mwr_lo": c["mean_lwr_lo"], "test_mwr_hi": c["mean_lwr_hi"]})
    write_table(path, buf.getvalue().encode("utf-8"))


def finished_rows(path: Path, epochs: int, columns: tuple[str, ...] = COLUMNS,
                  valid_row: Callable[[dict[str, str], int], bool] | None = None,
                  what: tuple[str, str, str] = ("metrics CSV of an evaluation", "test epochs", "epochs")) -> int:
    """How many rows (numbered 1, 2, ...) ``path`` holds, in order from row 1.

    A run killed while writing leaves a partial last line, and the file is cut back to
    its last complete, valid row by :func:`~triplesumo.evaluation.metrics_csv.repair_metrics_csv`
    (the one routine training's resume uses too; rewritten atomically). ``ValueError`` if
    the file does not have the header ``columns``, has an invalid row before its last, or
    holds more than ``epochs`` rows. By default the file is a candidate's metrics CSV; other
    row-appended tables pass their ``columns`` and ``valid_row(values, number)``; ``what``
    names the table, its rows and the limit in errors.
    """
    problem = None
    if valid_row is not None:
        check = valid_row

        def problem(row: list[str], number: int) -> str | None:
            if len(row) != len(columns):
                return f"{len(row)} fields, expected {len(columns)}"
            return None if check(dict(zip(columns, row, strict=True)), number) else f"not row {number}"

    good = repair_metrics_csv(path, columns=columns, row_problem=problem, what=what[0])
    if good > epochs:
        raise ValueError(f"{path} already holds {good} {what[1]}, more than {what[2]}={epochs}: "
                         f"raise {what[2]}, or write into a new out folder")
    return good


class RowAppender:
    """Appends rows to a CSV (by default a metrics CSV), flushed one by one (a killed run keeps
    what it finished)."""

    def __init__(self, path: Path, fresh: bool, columns: tuple[str, ...] = COLUMNS) -> None:
        self.path = path
        with self._naming_the_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            if fresh:  # a packed copy of an earlier table is not this one's
                packed_path(path).unlink(missing_ok=True)
            self._fh = path.open("w" if fresh else "a", newline="", encoding="utf-8")
            self._writer = csv.DictWriter(self._fh, columns, lineterminator="\n")
            if fresh:
                self._writer.writeheader()

    def __call__(self, row: dict[str, Any]) -> None:
        with self._naming_the_file():
            self._writer.writerow(row)
            self._fh.flush()

    @contextlib.contextmanager
    def _naming_the_file(self) -> Iterator[None]:
        """An ``OSError`` (a full disk) names the table; the rows written before it stay, and a resume cuts a
        torn last one."""
        try:
            yield
        except OSError as exc:
            if str(self.path) in str(exc):
                raise
            raise OSError(exc.errno, f"{self.path}: a row was not written ({exc.strerror or exc}); the rows before "
                                     "it are kept, --resume goes on from them") from exc

    def __enter__(self) -> RowAppender:
        return self

    def __exit__(self, *exc: object) -> None:
        with contextlib.suppress(OSError):  # (a full disk fails the close too; the error above names the file)
            self._fh.close()


def _record(cfg: EvaluateConfig, candidates: dict[str, str]) -> dict[str, Any]:
    """What the rows depend on: the ROW_FIELDS and the sha256 of every policy's files."""
    fields = json.loads(json.dumps({f: getattr(cfg, f) for f in ROW_FIELDS}))  # tuples as JSON lists
    if cfg.scenario != "paper":  # (records of the paper's matches stay as they were)
        fields["scenario"] = cfg.scenario
    if cfg.physics != V0_PHYSICS:  # (likewise records made on env v0's simulation)
        fields["physics"] = asdict(cfg.physics)
    return {
        "rows_depend_on": fields,
        "others": {pair: policy_fingerprint(pair.split("=", 1)[1]) for pair in cfg.policies},
        "candidates": {label: {"policy": spec, "sha256": policy_fingerprint(spec)}
                       for label, spec in candidates.items()},
    }


def _baselines_in(candidates: dict[str, str]) -> tuple[str, ...]:
    """The baselines among ``candidates`` (label -> policy): built-in policies under their own name."""
    return tuple(label for label, spec in candidates.items() if label in BUILTIN and spec == label)


def _is_seed_label(label: str) -> bool:
    """Whether ``label`` is one that :func:`evaluate` gives the learner's own policies (``trained``, or
    ``trained-<policy>`` when there are several): how a carried candidate's group is known."""
    return label == "trained" or label.startswith("trained-")


def _read_record(path: Path) -> dict[str, Any] | None:
    """The record of the evaluation to resume, ``None`` for an empty file (killed before it was written: a fresh
    start); ``FileNotFoundError`` or ``ValueError`` naming the file when it is missing, unreadable or corrupt."""
    folder = path.parent
    if not path.exists():
        raise FileNotFoundError(f"nothing to resume in {folder}: {path.name} not found (run without resume to "
                                "start an evaluation there)")
    if path.stat().st_size == 0:
        return None
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
        if not all(isinstance(old[key], dict) for key in ("rows_depend_on", "others", "candidates")) or not all(
                isinstance(c, dict) and "policy" in c for c in old["candidates"].values()):
            raise ValueError("missing or malformed entries")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"cannot resume {folder}: {path} is unreadable or corrupt ({exc})") from None
    if "physics" in old["rows_depend_on"]:  # recorded before a PhysicsConfig field existed: as those runs played
        old["rows_depend_on"] = {**old["rows_depend_on"], "physics": physics_record(old["rows_depend_on"]["physics"])}
    return dict(old)


def _previous_candidates(old: dict[str, Any], folder: Path, record: dict[str, Any]) -> dict[str, Any]:
    """The candidates of the evaluation ``old`` recorded in ``folder``, once it is checked to fit ``record``."""
    old_fields, old_others, old_candidates = old["rows_depend_on"], old["others"], old["candidates"]
    now_fields = record["rows_depend_on"]
    for name in [*now_fields, *(k for k in old_fields if k not in now_fields)]:
        if old_fields.get(name) != now_fields.get(name):
            raise ValueError(f"cannot resume {folder}: {name} was {old_fields.get(name)!r}, "
                             f"now {now_fields.get(name)!r}")
    if old_others != record["others"]:
        raise ValueError(f"cannot resume {folder}: the other agents' policy files changed "
                         f"(sha256 {old_others} then, {record['others']} now)")
    for label, now in record["candidates"].items():
        then = old_candidates.get(label)
        if then is not None and then != now:
            raise ValueError(f"cannot resume {folder}: candidate {label!r} was {then}, now {now} "
                             "(another policy, or its files changed)")
    return dict(old_candidates)


def _write_json(path: Path, value: dict[str, Any]) -> None:
    atomic_write_bytes(path, (json.dumps(value, indent=2) + "\n").encode("utf-8"))


def format_summary(summary: dict[str, Any]) -> str:
    """A readable table of a summary."""
    def interval(mean: float | None, lo: float | None, hi: float | None) -> str:
        if mean is None:
            return "[n/a]"
        return f"{mean:+.3f} " + ("[n/a]" if lo is None or hi is None else f"[{lo:+.3f}, {hi:+.3f}]")

    first = next(iter(summary["candidates"]), "")
    w = max([10, *(len(label) for label in summary["candidates"])])  # long labels (compared files) stay aligned
    lines = [
        f"{'candidate':{w}s} {'policy':28s} {'n':>6s} {'win':>6s} {'loss':>6s} {'draw':>6s} "
        f"{'test MWR [95% CI]':>26s} {'steps to win':>12s} {('paired, minus ' + first)[:26]:>26s}"
    ]
    for label, c in summary["candidates"].items():
        ci = interval(c["mean_lwr"], c["mean_lwr_lo"], c["mean_lwr_hi"])
        stw = "-" if c["mean_steps_to_win"] is None else f"{c['mean_steps_to_win']:.0f}"
        counts = f"{c['n']:6d} {c['n_win']:6d} {c['n_loss']:6d} {c['n_draw']:6d}"
        paired = c.get("paired")
        diff = "-" if paired is None else interval(paired["diff"], paired["lo"], paired["hi"])
        lines.append(f"{label:{w}s} {c['policy'][:28]:28s} {counts} {ci:>26s} {stw:>12s} {diff:>26s}")
    return "\n".join(lines)
