"""A run's folder: what makes a folder hold a run, its ``config.json`` (written, read back across versions),
its id, whether its budget is reached, the command that makes it, its plots, and what a resume needs of its
tables and older checkpoints (the newest checkpoint its intact rows reach, a one-learner checkpoint read in
today's layout).

Nothing here trains: the functions are what the CLI, sweeps, forks and the trainer ask of a run folder before and
after training (a new run refuses a folder holding one; a resumed one reads its config back).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shlex
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from triplesumo._lock import held, move_held
from triplesumo.agents.policy_file import atomic_write_bytes, load_json
from triplesumo.algos.ddpg import DDPGConfig
from triplesumo.algos.ppo import PPOConfig
from triplesumo.algos.sac import SACConfig
from triplesumo.algos.td3 import TD3Config
from triplesumo.envs.match import Match
from triplesumo.evaluation.metrics_csv import table_exists, tables_in
from triplesumo.model.specs import V0_PHYSICS, PhysicsConfig, describe_ring, physics_record
from triplesumo.rules.config import MatchConfig, RewardConfig
from triplesumo.train import checkpoint
from triplesumo.train.config import TrainConfig
from triplesumo.train.league_config import LeagueConfig
from triplesumo.train.league_plots import plot_league
from triplesumo.train.learners import LearnerSpec
from triplesumo.train.logger import COLUMNS, LEARNING_COLUMNS, intact_rows, learning_row_problem, run_file
from triplesumo.version import ENV_VERSION, __version__

RUN_FILES = ("config.json", "metrics.csv", "checkpoints", "policy.json", "policy.safetensors")
"""What makes a folder hold a run: training never writes into such a folder afresh (with
``metrics-*.csv`` and ``policy-*.json`` of runs with several learners)."""


class RunExistsError(FileExistsError):
    """The run folder already holds a run (the message offers ``--resume`` and ``--start-over``)."""


def config_to_json(cfg: TrainConfig) -> dict[str, Any]:
    """``cfg`` as ``config.json`` holds it (without :data:`DEPRECATED_FIELDS`)."""
    data = json.loads(json.dumps(dataclasses.asdict(cfg)))
    return {k: v for k, v in data.items() if k not in DEPRECATED_FIELDS}


def write_run_config(run_dir: Path, cfg: TrainConfig) -> None:
    """Write ``RUN/config.json`` (what ``--resume`` reads) atomically; a failed write names the file."""
    with checkpoint.writing(Path(run_dir) / "config.json"):
        atomic_write_bytes(Path(run_dir) / "config.json", (json.dumps(config_to_json(cfg), indent=2) + "\n").encode())


FORK_FILE = "fork.json"
"""In a run folder made by ``train --fork`` (:mod:`triplesumo.train.fork`): where it came from."""


RESUME_OVERRIDES = ("epochs", "max_env_steps", "max_minutes", "progress", "save_replay", "n_threads",
                    "eval_background", "eval_workers", "allow_other_ring")
"""The TrainConfig fields a resumed run may change (``train --resume RUN --epochs N ...``): budgets (a run that
stopped at its epochs or env steps goes on to larger ones, e.g. ``--max-env-steps 2000000``, and trains what it
would have had it never stopped), output,
and ``n_threads``, the threads stepping the CPU physics, which advance every match alone and bit for bit
whatever their number (``tests/test_batch.py``), so that a run started on a laptop goes on with the cores of a
larger machine and trains exactly what it would have; and ``eval_background`` and ``eval_workers``, where the
evaluations play (their figures are the same); and ``allow_other_ring``, which lets a policy of another ring play
and changes nothing else."""


def flag_list(fields: Iterable[str]) -> str:
    """``--epochs, --max-minutes, ...``: the command-line flags of TrainConfig ``fields``, for the errors that
    say which may be given (a boolean's flag also has its ``--no-`` form)."""
    return ", ".join("--" + f.replace("_", "-") for f in fields)


def run_id_of(cfg: TrainConfig) -> str:
    """``NAME-HASH``: the run's name and a hash of its config less what a resume may change
    (:data:`RESUME_OVERRIDES`) or what only says where it is written (``out``). So a resumed run writes what
    the uninterrupted one would, and two runs share an id only if they are the same experiment. Taken when a
    run starts; its checkpoints keep it, whatever options later versions add."""
    kept = {k: v for k, v in config_to_json(cfg).items() if k not in ("out", *RESUME_OVERRIDES)}
    digest = hashlib.sha256(json.dumps(kept, sort_keys=True).encode()).hexdigest()
    return f"{cfg.name}-{digest[:12]}"


DEPRECATED_FIELDS = ("learner",)
"""TrainConfig fields kept only as deprecated aliases (``learner``: ``learn AGENT=ddpg``): a config never holds
them (one written while they were fields is read as its ``learn``)."""


def saved_learn(data: Mapping[str, Any], learner: str = "") -> list[Any]:
    """The learners a saved config names: its ``learn``, or, in one written while ``learner`` named the one DDPG
    learner (``learn`` empty), ``[LEARNER=ddpg]`` (``learner`` when the config names none either)."""
    return list(data.get("learn") or [f"{data.get('learner', learner)}=ddpg"])


def _check_keys(data: Any, cls: type, where: str, source: str) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise ValueError(f"{source}: {where or 'the file'} must be a JSON object, got {type(data).__name__}")
    names = {f.name for f in dataclasses.fields(cls)} - ({*DEPRECATED_FIELDS} if cls is TrainConfig else set())
    unknown, missing = sorted(set(data) - names), sorted(names - set(data))
    if unknown or missing:
        problems = [f"unknown key(s) {[where + k for k in unknown]}"] if unknown else []
        problems += [f"missing key(s) {[where + k for k in missing]}"] if missing else []
        raise ValueError(f"{source}: {' and '.join(problems)} (a {cls.__name__} has {sorted(names)})")
    return dict(data)


ADDED_LATER = ("learn", "share", "td3", "sac", "ppo", "self_play", "league", "max_env_steps", "physics", "backend",
               "device", "eval_every", "eval_epochs", "eval_seed", "eval_target", "learner_config",
               "eval_background", "allow_other_ring", "eval_workers")
"""TrainConfig fields newer than the first run folders (several learners, self-play, an env-step
budget, evaluations while training): a config.json without them gets their defaults; any other
missing key is an error."""


LEAGUE_ADDED_LATER: dict[str, Any] = {"live_share": 0.35, "draw_score": 0.0, "side_draw_score": [],
                                       "side_threshold": [], "keep_zoo": False, "zoo_share": 0.0}
"""LeagueConfig fields newer than the first self-play runs (both sides learning), each with the value every earlier
run used: a saved league section without one gets it. The values are written out, not read from today's defaults,
so that a default changed later cannot change how an old run resumes."""

ALGO_ADDED_LATER: dict[str, dict[str, Any]] = {
    "sac": {"critic_norm": "none", "n_step": 1, "update_dtype": "float32", "reset_every": 0, "critic_loss": "mse",
            "value_low": -1000.0, "value_high": 1000.0, "value_bins": 101, "pessimism": 1.0},
    "ddpg": {"n_step": 1, "update_dtype": "float32", "reset_every": 0, "pessimism": 1.0},
    "td3": {"n_step": 1, "update_dtype": "float32", "reset_every": 0, "pessimism": 1.0},
}
"""Learner config fields newer than the first run folders of their algorithm, with what every earlier run trained
with (no LayerNorm in SAC's critics, one-step TD targets, float32 updates, squared-error critics, the twin
critics' minimum), likewise written out."""
REWARD_ADDED_LATER: dict[str, Any] = {"axis_dead_zone": 0.0, "opponents": "mean"}
"""RewardConfig fields newer than the first run folders (the dead zone of the velocity terms' signs; how several
opponents' terms combine), with what every earlier run was paid by, likewise."""


def _with_added_later(data: Any, added_later: Mapping[str, Any]) -> Any:
    """``data`` (a saved config section) with the values in ``added_later`` of the fields it lacks; anything but a
    dict as it is, for :func:`_check_keys` to name."""
    if not isinstance(data, dict):
        return data
    return {**added_later, **data}


def config_from_json(data: dict[str, Any], source: str = "config.json") -> TrainConfig:
    """The :class:`TrainConfig` saved as ``data``; ``ValueError`` names ``source`` and any unknown or
    missing key (a config written by another version, or edited by hand)."""
    if isinstance(data, dict) and "learner" in data:
        data = {k: v for k, v in data.items() if k != "learner"} | {"learn": saved_learn(data)}
    if isinstance(data, dict):  # written before a field existed: that field's default, what the run used
        defaults = config_to_json(TrainConfig(physics=V0_PHYSICS))  # (physics came in env v0)
        data = {**{k: defaults[k] for k in ADDED_LATER if k not in data}, **data}
    data = _check_keys(data, TrainConfig, "", source)
    data["reward"] = _with_added_later(data["reward"], REWARD_ADDED_LATER)
    data["reward"] = RewardConfig(**_check_keys(data["reward"], RewardConfig, "reward.", source))
    try:
        data["physics"] = PhysicsConfig(**_check_keys(physics_record(data["physics"]), PhysicsConfig, "physics.",
                                                      source))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from exc
    for name, cls in (("ddpg", DDPGConfig), ("td3", TD3Config), ("sac", SACConfig), ("ppo", PPOConfig)):
        try:
            section = _with_added_later(data[name], ALGO_ADDED_LATER.get(name, {}))
            data[name] = cls(**_check_keys(section, cls, f"{name}.", source))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: {exc}") from exc
    data["policies"] = tuple(data["policies"])
    data["learn"] = tuple(data["learn"])
    data["league"] = _with_added_later(data["league"], LEAGUE_ADDED_LATER)
    try:
        league: dict[str, Any] = _check_keys(data["league"], LeagueConfig, "league.", source)
        data["league"] = LeagueConfig(**league)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from exc
    try:
        return TrainConfig(**data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from exc


def training_done(cfg: TrainConfig, run_dir: Path | None = None) -> bool:
    """Whether the run of ``cfg`` (in ``run_dir``, default ``OUT/NAME``) has reached its budget (``epochs``,
    or ``max_env_steps`` collected): its newest checkpoint says so, or, in a finished run whose
    checkpoints were deleted to keep it small (a run folder committed to a repository), its policy
    files do (each is written after the checkpoint it comes from, with that checkpoint's epochs and env steps)."""
    run_dir = Path(run_dir) if run_dir is not None else Path(cfg.out) / cfg.name
    saved = checkpoint.checkpoints(run_dir)
    if saved:
        epoch, folder = saved[-1]
        done: dict[str, Any] = {"epochs": epoch, "env_steps": load_json(folder / "state.json").get("env_steps", 0)}
    else:
        manifests = [load_json(p) for p in sorted(run_dir.glob("policy*.json"))] if run_dir.is_dir() else []
        if not manifests:
            return False
        done = {k: min(int(m.get(k, 0)) for m in manifests) for k in ("epochs", "env_steps")}
    if int(done["epochs"]) >= cfg.epochs:
        return True
    return cfg.max_env_steps > 0 and int(done["env_steps"]) >= cfg.max_env_steps


def command_for(cfg: TrainConfig) -> str:
    """The ``triplesumo train`` command line that makes ``cfg`` (its non-default options)."""
    from triplesumo import _dcargs

    return " ".join(shlex.quote(a) for a in ["triplesumo", "train", *_dcargs.to_argv(cfg)])


def holds_run(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds (part of) a training run."""
    run_dir = Path(run_dir)
    return (any((run_dir / name).exists() for name in RUN_FILES)
            or any(run_dir.glob("metrics-*.csv")) or any(run_dir.glob("policy-*.json")))


def refuse_existing_run(run_dir: Path, start_over: bool) -> Path | None:
    """Refuse to train afresh into a folder holding a run; with ``start_over`` move it aside.

    Returns where the old run went (``RUN.old-K``, the first free K), or None.
    """
    run_dir = Path(run_dir)
    if not holds_run(run_dir):
        return None
    if not start_over:
        raise RunExistsError(
            f"run folder {run_dir} already holds a run ({', '.join(n for n in RUN_FILES if (run_dir / n).exists())}); "
            f"nothing was changed. Continue it with `triplesumo train --resume {run_dir}` (add --epochs N for more), "
            f"or start over with the same command plus --start-over (the old run is moved to {run_dir}.old-K), "
            "or choose another --name")
    k = 1
    while (aside := run_dir.with_name(f"{run_dir.name}.old-{k}")).exists():
        k += 1
    with held(run_dir, "train --start-over"), checkpoint.writing(aside):  # (not while another process runs it)
        move_held(run_dir, aside, "train --start-over")
    print(f"start over: the earlier run in {run_dir} was moved to {aside}")
    return aside


def prepare_run_dir(run_dir: Path) -> Path:
    """Create the run folder and prove it is writable now, not after hours."""
    run_dir = Path(run_dir)
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        probe = run_dir / ".write-test"
        probe.write_bytes(b"ok")
        probe.unlink()
    except OSError as exc:
        raise PermissionError(f"run folder {run_dir} is not writable: {exc.strerror or exc}") from exc
    return run_dir


def _per_agent_tables(run_dir: Path, stem: str, learner: str, required: bool) -> list[tuple[str, Path, Path]]:
    """(agent, table, plots folder) for a run's ``<stem>-<agent>.csv`` tables (several learners: plots go to
    ``plots/<agent>/``), or its one ``<stem>.csv`` (the run's one ``learner``: ``plots/``), plain or packed; where
    the run has neither, none, or (``required``) the missing ``<stem>.csv``, for its reader to name."""
    agents = {t.stem.removeprefix(f"{stem}-"): t for t in tables_in(run_dir, f"{stem}-*.csv")}
    if agents:
        return [(agent, table, run_dir / "plots" / agent) for agent, table in agents.items()]
    one = run_dir / f"{stem}.csv"
    return [(learner, one, run_dir / "plots")] if required or table_exists(one) else []


def plot_metrics(run_dir: Path, window: int) -> list[Path]:
    """The paper's figures of every learning agent of a run: ``metrics.csv`` -> ``plots/``,
    ``metrics-<agent>.csv`` -> ``plots/<agent>/`` (agents without a finished epoch are skipped); and the test MWR
    of its evaluations while training against the paper's band, ``eval.csv`` -> ``plots/test_mwr.png``,
    ``eval-<agent>.csv`` -> ``plots/<agent>/test_mwr.png`` (where it has any)."""
    from triplesumo.evaluation.plots import plot_evaluations, plot_run, read_evaluations_csv, read_metrics_csv

    run_dir = Path(run_dir)
    learner = "bug"
    if (run_dir / "config.json").is_file():  # (its one learner names metrics.csv's plots)
        learner = str(saved_learn(load_json(run_dir / "config.json"), learner)[0]).split("=")[0]
    paths: list[Path] = []
    for agent, path, out in _per_agent_tables(run_dir, "metrics", learner, required=True):
        metrics = read_metrics_csv(path)
        if len(metrics["epoch"]):
            paths += plot_run(metrics, out, window=window, title=f"{agent} training ({run_dir.name})",
                              label=agent.capitalize())
    for agent, path, out in _per_agent_tables(run_dir, "eval", learner, required=False):
        columns = read_evaluations_csv(path)
        if len(columns["env_steps"]):
            paths.append(plot_evaluations({agent.capitalize(): columns}, out / "test_mwr.png",
                                          title=f"{agent} ({run_dir.name})"))
    if table_exists(run_dir / "league" / "league.csv"):  # a self-play run: rating curves and pool members
        paths.append(plot_league(run_dir))
    return paths


def checkpoint_within_rows(run_dir: Path, folder: Path, agents: list[str], learners: list[str]) -> Path:
    """``folder`` (the latest checkpoint of ``run_dir``), or, where a kill tore the run's last rows at or before its
    epoch, the newest checkpoint that the intact rows of the ``agents``' metrics and the ``learners``' learning
    tables reach (the rows after it are cut and its epochs trained again, as the torn-row repair promises);
    ``CheckpointError`` names ``--start-over`` when none does. (Self-play runs, whose agents may sit matches out,
    keep the check of their own tables: the trainer does not ask.)"""
    epoch = checkpoint.recorded_epoch(folder)
    if epoch is None:
        return folder
    several = len(agents) > 1 or len(learners) > 1 or agents != learners
    tables: list[tuple[Path, tuple[str, ...], Callable[[list[str], int], str | None] | None]] = [
        (run_dir / run_file("metrics", a, several, ".csv"), COLUMNS, None) for a in agents]
    tables += [(run_dir / run_file("learning", n, several, ".csv"), LEARNING_COLUMNS, learning_row_problem)
               for n in learners]
    rows = min(intact_rows(path, columns, problem) for path, columns, problem in tables if table_exists(path))
    if rows >= epoch:
        return folder
    fits = [(e, f) for e, f in checkpoint.checkpoints(run_dir) if e <= rows]
    if not fits:
        raise checkpoint.CheckpointError(
            f"{run_dir}: its tables hold the rows of epochs 1..{rows} only (a kill tore the rest), but every "
            f"checkpoint is later (the newest at epoch {epoch}): nothing to resume from; `triplesumo train "
            f"--resume {run_dir} --start-over` trains it again from the start")
    e, chosen = fits[-1]
    print(f"resume: the run's tables hold epochs 1..{rows} (a kill tore the rest) and the latest checkpoint is "
          f"at epoch {epoch}; resuming from {chosen.name} (epoch {e}), the newest within them")
    return chosen


def one_learner_checkpoint(name: str, n_envs: int, tensors: dict[str, torch.Tensor], state: dict[str, Any],
                           arrays: dict[str, np.ndarray], replay: Mapping[str, np.ndarray] | None) -> tuple[
        dict[str, torch.Tensor], dict[str, Any], dict[str, np.ndarray], Mapping[str, np.ndarray] | None]:
    """A checkpoint of the one-DDPG-learner trainer (before several learners) in today's layout, its learner
    named ``name``."""
    upgraded = {**state, "acc": {name: state["acc"]}, "final": {name: [None] * n_envs},
                "learners": {name: {"optimizer": state["optimizer"], "sample_rng": state["sample_rng"],
                                    "collected": state["env_steps"], "stats": [{}, {}]}}}
    moved = {f"{name}.{k}" if k.startswith("noise.") else k: v for k, v in arrays.items() if k != "lwr"}
    moved |= {f"lwr.{name}": arrays["lwr"], f"{name}.active": np.ones(n_envs, dtype=bool)}
    if replay is not None:
        replay = Prefixed(replay, f"{name}.")
    return {f"{name}.{k}": v for k, v in tensors.items()}, upgraded, moved, replay


class Prefixed(Mapping[str, np.ndarray]):
    """``mapping`` with every key prefixed (members still read lazily, one at a time)."""

    def __init__(self, mapping: Mapping[str, np.ndarray], prefix: str) -> None:
        self.mapping, self.prefix = mapping, prefix

    def __getitem__(self, key: str) -> np.ndarray:
        if not key.startswith(self.prefix):
            raise KeyError(key)
        return self.mapping[key.removeprefix(self.prefix)]

    def __iter__(self) -> Iterator[str]:
        return (self.prefix + k for k in self.mapping)

    def __len__(self) -> int:
        return len(self.mapping)


def physics_mismatch(state: Path, made: PhysicsConfig, config: Path, given: PhysicsConfig) -> str:
    """Why a checkpoint (``state``, made on ``made``) cannot resume on the physics ``given`` that the run's
    ``config`` says: a run never trains on another simulation than its checkpoint's. A ``config.json`` that
    records no physics is read as env v0's (:data:`~triplesumo.model.specs.V0_PHYSICS`, what run folders made
    before it was recorded ran); one whose checkpoint records other physics was written by hand or damaged."""
    raw = load_json(config) if config.is_file() else {}
    said = "records no physics, which reads as env v0's" if "physics" not in raw else "records other physics"
    fields = [f.name for f in dataclasses.fields(PhysicsConfig) if getattr(made, f.name) != getattr(given, f.name)]
    differ = ", ".join(f"physics.{f} {getattr(made, f)!r} there, {getattr(given, f)!r} here" for f in fields)
    return (f"{state}: incompatible checkpoint: it was made on {describe_ring(made)} ({differ}), but {config} "
            f"{said}: {describe_ring(given)}. Nothing was trained; to resume, set config.json's \"physics\" to the "
            f"checkpoint's (the \"physics\" inside the \"config\" of {state})")


def check_checkpoint_physics(run_dir: Path, physics: PhysicsConfig) -> None:
    """:class:`~triplesumo.train.checkpoint.CheckpointError` (:func:`physics_mismatch`) unless the newest
    checkpoint of ``run_dir`` whose ``state.json`` reads was made on ``physics``, before anything is loaded onto it
    (every checkpoint of a run is made on its one simulation); a run without a readable one passes here."""
    for _, folder in reversed(checkpoint.checkpoints(run_dir)):
        try:
            made = config_from_json(load_json(folder / "state.json")["config"]).physics
        except (ValueError, KeyError, TypeError):
            continue  # damaged: the resume names it, or goes on from an older one
        if made != physics:
            raise checkpoint.CheckpointError(physics_mismatch(folder / "state.json", made, run_dir / "config.json",
                                                              physics))
        return


RESUMED_FIELDS = ("learn", "share", "scenario", "obs_mode", "n_envs", "steps_per_epoch", "policies",
                  "reward", "ddpg", "td3", "sac", "ppo", "learner_config", "seed", "self_play", "league", "backend")
"""The config fields a resume must share with its checkpoint (``save_replay`` may differ: resuming without the
replay buffer is allowed, not exact)."""


def check_resumable(checkpointed: checkpoint.State, cfg: TrainConfig, run_dir: Path) -> None:
    """:class:`~triplesumo.train.checkpoint.CheckpointError` naming the file unless ``checkpointed`` can resume
    the run of ``cfg``: every entry there, made on the same physics, with the same :data:`RESUMED_FIELDS`."""
    folder, state = Path(checkpointed.folder or "."), checkpointed.json
    need: tuple[str, ...] = ("config", "learners", "rng", "matches", "epochs_done", "env_steps", "acc", "final")
    need += ("league", "seats", "seat_rngs") if cfg.self_play else ()
    missing = [k for k in need if k not in state]
    if missing:
        raise checkpoint.CheckpointError(f"{folder / 'state.json'}: missing entries {missing}")
    try:
        saved = config_from_json(state["config"], f"{folder / 'state.json'} (its config)")
    except ValueError as exc:
        raise checkpoint.CheckpointError(str(exc)) from exc
    if saved.physics != cfg.physics:
        raise checkpoint.CheckpointError(physics_mismatch(folder / "state.json", saved.physics,
                                                          run_dir / "config.json", cfg.physics))
    for name in RESUMED_FIELDS:
        if getattr(saved, name) != getattr(cfg, name):
            raise checkpoint.CheckpointError(
                f"{folder / 'state.json'}: incompatible checkpoint: it was made with {name}="
                f"{getattr(saved, name)!r}, this run has {getattr(cfg, name)!r} (from config.json)")


def forked_from(run_dir: Path) -> tuple[dict[str, Any] | None, str | None]:
    """A fork's parent as its policy manifests name it (``fork.json``: run, id, checkpoint, epoch, command, changes)
    and the fork's own command; None, None for a run that is no fork."""
    if not (run_dir / FORK_FILE).is_file():
        return None, None
    fork = load_json(run_dir / FORK_FILE)
    return {"run": fork["parent"], "run_id": fork["parent_run_id"], "checkpoint": fork["checkpoint"],
            "epoch": fork["epoch"], "command": fork["parent_command"], "changes": fork["changes"]}, fork["command"]


def load_to_resume(run_dir: Path, from_checkpoint: str | None, wants_replay: bool,
                   within_rows: tuple[list[str], list[str]] | None, learner: str, n_envs: int) -> checkpoint.State:
    """The checkpoint a resume continues (:attr:`~triplesumo.train.checkpoint.State.folder`), read: ``from_checkpoint``
    (``epoch-N``), else the latest, stepped back to the newest within the tables' rows of ``within_rows`` (agents,
    learners) where given; a damaged latest one names the newest intact one. One that holds no replay buffer
    (saved without, or compacted of it) resumes with an empty one (``wants_replay``: said). A checkpoint of the
    one-learner trainer is read in today's layout, its learner named ``learner`` (of ``n_envs`` matches)."""
    def load(folder: Path) -> checkpoint.State:
        need_replay = wants_replay and checkpoint.holds_replay(folder)
        if wants_replay and not need_replay:
            print(f"{folder}: the checkpoint holds no replay buffer (saved without or compacted of it): the "
                  "run resumes with an empty one, not exactly as it would have gone on")
        tensors, state, arrays, lazy = checkpoint.load(folder, need_replay=need_replay)
        replay: Mapping[str, np.ndarray] | None = lazy
        if "learners" not in state and "optimizer" in state:
            tensors, state, arrays, replay = one_learner_checkpoint(learner, n_envs, tensors, state, arrays, replay)
        return checkpoint.State(state, arrays, tensors, replay, folder)

    if from_checkpoint is not None:
        return load(checkpoint.find(run_dir, from_checkpoint))
    try:
        folder = checkpoint.latest(run_dir)
        if within_rows is not None:
            folder = checkpoint_within_rows(run_dir, folder, *within_rows)
        return load(folder)
    except checkpoint.CheckpointError as exc:
        intact = checkpoint.newest_intact(run_dir)
        if intact is None:
            raise
        raise checkpoint.CheckpointError(
            f"{exc} -- the latest checkpoint is damaged or missing; the newest intact one is {intact.name} "
            f"(epoch {checkpoint.recorded_epoch(intact)}): `triplesumo train --resume {run_dir} "
            f"--from {intact.name}` continues from it (later epochs are trained again)") from exc


def adopt_checkpoint(run_dir: Path, folder: Path, epochs_done: int, write_policies: Callable[[Path], None]) -> None:
    """Make ``run_dir`` that of checkpoint ``folder``, which a resume restored, before any epoch is trained.

    A resume from another checkpoint than the one ``latest.json`` names (``--from epoch-N``, or the newest
    checkpoint within torn rows) has cut the tables back to its epoch; so that the folder never contradicts
    itself, even when no epoch is left to train (``--epochs`` not past it), the policy files are written
    from the restored learners (``write_policies``), then ``latest.json`` names the restored checkpoint, then the
    checkpoints of later epochs are removed (the rows no longer reach them; the epochs trained next re-create
    them, as the first checkpoint after a ``--from`` always pruned them). In that order, a kill in between leaves
    ``latest.json`` beyond the rows, which the next plain ``--resume`` steps back from and adopts again.
    """
    try:
        named: Path | None = checkpoint.latest(run_dir)
    except checkpoint.CheckpointError:
        named = None
    if named is not None and named.resolve() == folder.resolve():
        return
    epoch = checkpoint.recorded_epoch(folder)
    epoch = epochs_done if epoch is None else epoch
    write_policies(folder)
    with checkpoint.writing(run_dir / "checkpoints" / "latest.json"):
        checkpoint.point_latest(run_dir, folder, epoch)
    checkpoint.drop_after(run_dir, epoch)


def policy_manifest(cfg: TrainConfig, probe: Match, match_cfg: MatchConfig, specs: Sequence[LearnerSpec],
                    learner: LearnerSpec, progress: Mapping[str, int], record: Mapping[str, Any],
                    trained_against: Sequence[str]) -> dict[str, Any]:
    """What a policy file of ``learner`` says of itself: what it plays and how its actions scale, the versions,
    the run's ``progress`` (epochs, env steps, updates) and ``record`` (:meth:`RunRecord.fields`), the policies
    it was ``trained_against``, the scenario and the physics."""
    spec = {a.name: a for a in match_cfg.agents}[learner.agents[0]]
    return {
        "agent": learner.name, "algo": learner.algo, "plays": list(learner.agents),
        "learners": {s.name: s.algo for s in specs}, "obs_mode": cfg.obs_mode,
        "action_scaling": f"normalised [-1, 1] scaled linearly to ctrl [-{spec.ctrl_range}, {spec.ctrl_range}]",
        "ctrl_range": spec.ctrl_range, "env_version": ENV_VERSION, "triplesumo_version": __version__,
        "mujoco_version": mujoco.__version__, "torch_version": torch.__version__, "seed": cfg.seed,
        "epochs": progress["epochs"], "env_steps": progress["env_steps"], "updates": progress["updates"], **record,
        "trained_against": list(trained_against),  # self-play: the seeds of the opponent pools
        "agents": list(probe.agents), "scenario": cfg.scenario,
        "partners": len(probe.teams.partners[probe.agents.index(spec.name)]),
        "physics": dataclasses.asdict(cfg.physics),  # the simulation (e.g. the paper's solid rim)
    }
