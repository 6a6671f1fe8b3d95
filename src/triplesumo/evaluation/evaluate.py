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
test MWR over the whole run) with its 95% interval, and mean steps to win.

Resuming: each candidate's rows are appended to its ``metrics.csv`` as the epochs finish
(in epoch order), and ``evaluation.json`` records what the rows depend on (learner,
policies and the sha256 of their files, seed, step limit, observation mode). A test
epoch's result depends on its seed alone, so ``resume=True`` keeps the finished epochs,
plays the rest and gives exactly the rows of an uninterrupted run; it can also extend a
finished run to more epochs.
"""

from __future__ import annotations

import copy
import csv
import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from triplesumo.agents.builtin import BUILTIN
from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.agents.zoo import check_policy_pairs, make_policy, policies_from_pairs, policy_fingerprint
from triplesumo.envs.batch import MatchBatch
from triplesumo.envs.match import ACTION_SIZE
from triplesumo.evaluation.metrics import OUTCOMES, local_winning_rate, summarize
from triplesumo.evaluation.video import check_writable
from triplesumo.rules.config import OBS_MODES, MatchConfig
from triplesumo.rules.outcome import outcome_name
from triplesumo.rules.rewards import TERMS
from triplesumo.train.logger import COLUMNS


@dataclass(frozen=True)
class EvaluateConfig:
    """Test epochs of a learner policy against baselines in the same matches."""

    learner: str = "bug"
    """The agent whose policy is evaluated."""
    policy: str = "zoo:bug"
    """The learner's policy: zoo:NAME, a policy file (e.g. runs/bug/policy), zero or random."""
    policies: tuple[str, ...] = ("ant=zoo:ant", "spider=zoo:spider")
    """AGENT=POLICY for the other agents (fixed, no exploration noise)."""
    compare: tuple[str, ...] = ()
    """Other learner policies played in the same matches (e.g. zoo:bug, a policy file)."""
    baselines: tuple[str, ...] = ("passive", "random")
    """Baseline learner policies played in the same matches (built-in names)."""
    epochs: int = 2000
    """Test epochs per candidate (the paper used 20,000)."""
    seed: int = 10_000
    """Test epoch i resets with seed + i (the same starts for every candidate)."""
    steps_per_epoch: int = 500
    """Step limit of a match (a draw when reached)."""
    obs_mode: str = "paper"
    """Observation mode the policies expect."""
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
    """Continue the evaluation in ``out`` (killed, or to more epochs): finished epochs are kept."""

    def __post_init__(self) -> None:
        for name in ("epochs", "steps_per_epoch", "window", "n_envs", "n_threads"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"EvaluateConfig.{name} must be an int >= 1, got {value!r}")
        agents = [a.name for a in MatchConfig().agents]
        if self.learner not in agents:
            raise ValueError(f"EvaluateConfig.learner must be one of {agents}, got {self.learner!r}")
        check_policy_pairs("EvaluateConfig.policies", self.policies, self.learner, agents)
        unknown = [b for b in self.baselines if b not in BUILTIN]
        if unknown:
            raise ValueError(f"EvaluateConfig.baselines must be built-in policies {sorted(BUILTIN)}, got {unknown}")
        if self.obs_mode not in OBS_MODES:
            raise ValueError(f"EvaluateConfig.obs_mode must be one of {OBS_MODES}, got {self.obs_mode!r}")


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
) -> list[dict[str, Any]]:
    """Play test epochs ``first .. epochs - 1`` (epoch ``i`` seeded ``seed + i``); one metrics row per
    epoch, in order. ``on_row`` is called with each row in epoch order as soon as it and every
    earlier one have finished (matches end out of order)."""
    if not 0 <= first < epochs:
        raise ValueError(f"first must be in [0, epochs={epochs}), got {first}")
    n_envs = min(n_envs, epochs - first)
    batch = MatchBatch(match_cfg, n_envs, n_threads)
    agents = batch.matches[0].agents
    if learner not in agents:
        raise ValueError(f"learner must be one of {list(agents)}, got {learner!r}")
    L = agents.index(learner)
    named = [*others.items(), (learner, learner_policy)]
    # Stateful policies (with reset(seed)) get one copy per match slot, re-seeded from
    # (test epoch, agent) at every epoch start, and every policy is called one observation
    # at a time: so each test epoch's result depends on its seed only, never on n_envs.
    drivers = [(agents.index(name), [copy.deepcopy(p) for _ in range(n_envs)] if callable(getattr(p, "reset", None))
                else [p] * n_envs) for name, p in named]
    rows: dict[int, dict[str, Any]] = {}
    slot_epoch = [-1] * n_envs
    obs: list[list[np.ndarray]] = [[] for _ in range(n_envs)]
    acc = [dict.fromkeys(("dense_reward", "sparse_reward", *TERMS), 0.0) for _ in range(n_envs)]
    next_epoch = first
    next_row = first  # the next row to hand to on_row

    def start(k: int) -> None:
        nonlocal next_epoch
        epoch = next_epoch if next_epoch < epochs else -1  # -1: a filler match, discarded
        next_epoch += 1
        slot_epoch[k] = epoch
        for i, per_slot in drivers:
            reset = getattr(per_slot[k], "reset", None)
            if callable(reset):
                reset(seed=int(np.random.SeedSequence([seed + max(epoch, 0), i]).generate_state(1)[0]))
        obs[k] = batch.reset_one(k, seed=seed + epoch if epoch >= 0 else seed - 1 - k)[0]
        acc[k] = dict.fromkeys(acc[k], 0.0)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=epochs, initial=first, unit="epoch", desc=f"evaluate {label}".strip(),
                   dynamic_ncols=True)
    for k in range(n_envs):
        start(k)
    try:
        with batch:
            while len(rows) < epochs - first:
                actions = np.zeros((n_envs, len(agents), ACTION_SIZE))
                for i, per_slot in drivers:
                    for k in range(n_envs):
                        actions[k, i] = per_slot[k](obs[k][i])
                for k, res in enumerate(batch.step(actions)):
                    info = res.infos[L]
                    for key in acc[k]:
                        acc[k][key] += info[key]
                    if res.terminated or res.truncated:
                        e = slot_epoch[k]
                        if e >= 0:
                            a = acc[k]
                            outcome = outcome_name(info["outcome"])
                            rows[e] = {
                                "epoch": e + 1,
                                "outcome": outcome,
                                "local_winning_rate": float(local_winning_rate([outcome])[0]),
                                "steps": info["step"],
                                "total_reward": a["dense_reward"] + a["sparse_reward"],
                                **a,
                                "env_steps": 0,
                                "wall_time": 0.0,
                            }
                            if bar is not None:
                                bar.update(1)
                            while on_row is not None and next_row in rows:
                                on_row(rows[next_row])
                                next_row += 1
                        start(k)
                    else:
                        obs[k] = res.observations
    finally:
        if bar is not None:
            bar.close()
    return [rows[e] for e in range(first, epochs)]


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _label(spec: str) -> str:
    """A folder-safe label for a policy spec (``zoo:bug`` -> ``zoo-bug``)."""
    return "".join(c if c.isalnum() or c in "-_" else "-" for c in spec).strip("-") or "policy"


RECORD_FILE = "evaluation.json"
"""What an evaluation folder's rows depend on, for resuming (see the module docstring)."""
ROW_FIELDS = ("learner", "policies", "seed", "steps_per_epoch", "obs_mode")
"""The :class:`EvaluateConfig` fields a test epoch's row depends on, besides the candidate's policy."""


def evaluate(cfg: EvaluateConfig) -> dict[str, Any]:
    """Run every candidate, write CSVs, plots and ``summary.json``; returns the summary.

    With ``cfg.resume`` the rows already in ``out`` are kept (see the module docstring);
    ``ValueError`` names what changed if they no longer fit the config.
    """
    from triplesumo.evaluation.plots import plot_comparison, plot_run, read_metrics_csv

    out = check_writable(Path(cfg.out))
    match_cfg = MatchConfig(max_steps=cfg.steps_per_epoch, obs_mode=cfg.obs_mode)
    others = policies_from_pairs(cfg.policies, cfg.seed, cfg.obs_mode)
    candidates = {"trained": cfg.policy, **{_label(c): c for c in cfg.compare}, **{b: b for b in cfg.baselines}}
    policies = {label: make_policy(spec, seed=cfg.seed, expect_obs_mode=cfg.obs_mode)
                for label, spec in candidates.items()}  # every file checked before any epoch is played
    record = _record(cfg, candidates)
    kept: dict[str, Any] = {}
    if cfg.resume:
        kept = _previous_candidates(out / RECORD_FILE, record)
        record["candidates"] = {**kept, **record["candidates"]}
    _write_json(out / RECORD_FILE, record)
    summary: dict[str, Any] = {"config": asdict(cfg), "candidates": {}}
    curves = {}
    for label, spec in candidates.items():
        path = out / label / "metrics.csv"
        done = finished_rows(path, cfg.epochs) if label in kept else 0
        if done < cfg.epochs:
            with RowAppender(path, fresh=done == 0) as append:
                play_test_epochs(policies[label], others, cfg.learner, cfg.epochs, cfg.seed, match_cfg, cfg.n_envs,
                                 cfg.n_threads, label=f"{cfg.learner}={spec}", progress=cfg.progress, first=done,
                                 on_row=append)
        metrics = read_metrics_csv(path)
        plot_run(
            metrics, out / label / "plots", window=cfg.window, title=f"test: {cfg.learner}={spec}", label=cfg.learner
        )
        curves[f"{cfg.learner} {label} ({spec})"] = metrics
        stats = summarize(metrics["outcome"].tolist(), metrics["steps"])
        summary["candidates"][label] = {
            "policy": spec,
            **{k: _clean(v) for k, v in dict(stats).items()},
            **{f"mean_{name}": float(np.mean(metrics[name].astype(np.float64)))
               for name in ("total_reward", "dense_reward", "sparse_reward")},
        }
    plot_comparison(curves, out, window=cfg.window)
    _write_json(out / "summary.json", summary)
    return summary


def finished_rows(path: Path, epochs: int) -> int:
    """How many test epochs ``path`` (a candidate's ``metrics.csv``) holds, in order from epoch 1.

    A run killed while writing leaves a partial last line, and the file is cut back to
    its last complete, valid row (rewritten atomically). ``ValueError`` if the file is
    not a metrics CSV or holds more than ``epochs`` epochs.
    """
    if not path.exists():
        return 0
    lines = path.read_text(encoding="utf-8").split("\n")
    complete = lines[:-1]  # a file ending in a newline leaves "" last; anything else is cut off
    rows = list(csv.reader(complete))
    if not rows or tuple(rows[0]) != COLUMNS:
        raise ValueError(f"{path}: not a metrics CSV of an evaluation (expected the header {list(COLUMNS)})")
    good = 0
    for row in rows[1:]:
        if not _valid_row(row, good + 1):
            break
        good += 1
    if good > epochs:
        raise ValueError(f"{path} already holds {good} test epochs, more than epochs={epochs}: "
                         "raise epochs, or evaluate into a new out folder")
    if good + 1 < len(lines):  # drop the partial or invalid tail
        atomic_write_bytes(path, ("\n".join(complete[:good + 1]) + "\n").encode("utf-8"))
    return good


def _valid_row(row: list[str], epoch: int) -> bool:
    if len(row) != len(COLUMNS):
        return False
    values = dict(zip(COLUMNS, row, strict=True))
    if values["epoch"] != str(epoch) or values["outcome"] not in OUTCOMES:
        return False
    try:
        return all(math.isfinite(float(values[c])) for c in COLUMNS if c not in ("epoch", "outcome"))
    except ValueError:
        return False


class RowAppender:
    """Appends rows to a metrics CSV, flushed one by one (a killed run keeps what it finished)."""

    def __init__(self, path: Path, fresh: bool) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = path.open("w" if fresh else "a", newline="", encoding="utf-8")
        self._writer = csv.DictWriter(self._fh, COLUMNS, lineterminator="\n")
        if fresh:
            self._writer.writeheader()

    def __call__(self, row: dict[str, Any]) -> None:
        self._writer.writerow(row)
        self._fh.flush()

    def __enter__(self) -> RowAppender:
        return self

    def __exit__(self, *exc: object) -> None:
        self._fh.close()


def _record(cfg: EvaluateConfig, candidates: dict[str, str]) -> dict[str, Any]:
    """What the rows depend on: the ROW_FIELDS and the sha256 of every policy's files."""
    fields = json.loads(json.dumps({f: getattr(cfg, f) for f in ROW_FIELDS}))  # tuples as JSON lists
    return {
        "rows_depend_on": fields,
        "others": {pair: policy_fingerprint(pair.split("=", 1)[1]) for pair in cfg.policies},
        "candidates": {label: {"policy": spec, "sha256": policy_fingerprint(spec)}
                       for label, spec in candidates.items()},
    }


def _previous_candidates(path: Path, record: dict[str, Any]) -> dict[str, Any]:
    """The candidates of the evaluation recorded in ``path``, once it is checked to fit ``record``."""
    folder = path.parent
    if not path.exists():
        raise FileNotFoundError(f"nothing to resume in {folder}: {path.name} not found (run without resume to "
                                "start an evaluation there)")
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
        old_fields, old_others, old_candidates = old["rows_depend_on"], old["others"], old["candidates"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"cannot resume {folder}: {path} is unreadable or corrupt ({exc})") from None
    for name, value in record["rows_depend_on"].items():
        if old_fields.get(name) != value:
            raise ValueError(f"cannot resume {folder}: {name} was {old_fields.get(name)!r}, now {value!r}")
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
    lines = [
        f"{'candidate':10s} {'policy':28s} {'n':>6s} {'win':>6s} {'loss':>6s} {'draw':>6s} "
        f"{'test MWR [95% CI]':>26s} {'steps to win':>12s}"
    ]
    for label, c in summary["candidates"].items():
        lo, hi = c["mean_lwr_lo"], c["mean_lwr_hi"]
        ci = f"{c['mean_lwr']:+.3f} " + ("[n/a]" if lo is None or hi is None else f"[{lo:+.3f}, {hi:+.3f}]")
        stw = "-" if c["mean_steps_to_win"] is None else f"{c['mean_steps_to_win']:.0f}"
        counts = f"{c['n']:6d} {c['n_win']:6d} {c['n_loss']:6d} {c['n_draw']:6d}"
        lines.append(f"{label:10s} {c['policy'][:28]:28s} {counts} {ci:>26s} {stw:>12s}")
    return "\n".join(lines)
