"""Forks and compaction: a new run that continues another run's checkpoint under changed league
rules, and a run folder cut down to what resuming it needs.

``train --resume`` continues a run exactly as it was configured; a fork is how a researcher
asks "what if this run had gone on with another admission threshold?" without training from
scratch again. :func:`fork_run` makes ``OUT/NAME`` from checkpoint ``epoch-N`` of a parent
run (its latest by default):

* the parent's checkpoint folder (networks, optimizers, every generator, the in-flight
  matches, the league's state; the replay buffer where one was kept and the fork keeps
  replay), with its ``state.json`` carrying the fork's config and run id;
* the league members the checkpoint needs: every member of every pool, and those evicted
  members still seated in an in-flight match (the other evicted members stay in the parent,
  listed in ``fork.json``), ``league/pool.json`` and ``league/league.csv``;
* the parent's metrics, learning and evaluation CSVs (cut back to the fork's epoch when
  training starts), so the fork's curves begin where the parent's stood;
* ``config.json`` (the fork's config) and ``fork.json``: the parent folder, its run id and
  command, the checkpoint and its epoch and env steps, each changed field as ``[parent,
  fork]``, the fork's command, and the evicted members left behind.
* ``legs.json``: the parent's legs (:mod:`triplesumo.train.legs`) up to the fork's epoch; the fork's
  first leg is appended by its first training (``kind`` ``fork``).

Training then resumes the new folder (:func:`~triplesumo.train.loop.train` with
``resume_dir``); the fork's policy files name the fork's command and carry ``forked_from``
(the parent's command, run id and checkpoint) in their manifests. A fork may change only
what leaves the checkpoint meaningful (:data:`FORK_FIELDS`: the league's rules but its rating
model, and the budget and bookkeeping fields); ``--league.zoo`` may only gain entries, which
join their pools at the fork's epoch as seeded members (``fork.json`` lists them under
``seeded``: e.g. a still team ``ant=passive bug=passive`` for a Spider whose league never
showed it one); ``--reward.*`` fine-tunes the networks under other reward weights from the fork's
epoch on (e.g. ``--reward.still 0``: no time penalty; the matches in flight are scored by the new
weights from their next step, and the returns logged before the fork keep the old ones); the
algorithms' ``TUNABLE`` fields fine-tune the learners from the fork's epoch on (e.g. ``--ddpg.actor-lr
2e-5 --ddpg.noise-sigma 0.1``: learning rates, the update schedule, target averaging, exploration;
the optimisers keep their moments and take the new rates); anything else (widths, replay, algorithms,
roster, seed) is refused naming the field, since the networks and matches being continued were made
under it.

:func:`compact_run` (``triplesumo compact RUN``) keeps, of a run folder, only what resuming it needs:
its newest checkpoint and the league members that checkpoint's pools and in-flight matches hold. A
self-play league keeps every member it ever admitted (evicted ones stay for tournaments' ladders), which
for a long run is most of its folder; compacting deletes the evicted ones no match seats and lists them
in ``league/pruned.json``.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import shutil
from pathlib import Path
from typing import Any

from triplesumo._lock import held
from triplesumo.agents.policy_file import atomic_write_bytes, load_json
from triplesumo.evaluation.metrics_csv import stored, tables_in
from triplesumo.train import checkpoint
from triplesumo.train.config import ALGOS, TrainConfig
from triplesumo.train.league import LOG_FILE, PRUNED_FILE, League, write_pool
from triplesumo.train.league_config import check_seed_rings, check_seeds
from triplesumo.train.legs import LEGS_FILE, legs_before, read_legs, write_legs
from triplesumo.train.run_folder import (
    FORK_FILE,
    RESUME_OVERRIDES,
    config_from_json,
    config_to_json,
    flag_list,
    holds_run,
    prepare_run_dir,
    run_id_of,
    write_run_config,
)

FORK_FORMAT = "triplesumo-fork/1"
FORK_FIELDS = ("name", "out", "checkpoint_every", "tensorboard", *RESUME_OVERRIDES, "league",
               "reward")
"""The TrainConfig fields a fork may change (``league`` but its ``rating_model``, and its ``zoo`` only by
appending entries; ``reward``: the networks fine-tune under the new weights from the fork's epoch)."""
NESTED = ("league", "reward", *ALGOS)
"""Config sections whose fields a fork records (and its command names) one by one."""
LEAGUE_FIXED = ("rating_model",)
"""League fields a fork keeps: the pools were rated under it."""


def added_seeds(parent: TrainConfig, cfg: TrainConfig) -> tuple[str, ...]:
    """The ``--league.zoo`` entries a fork appends to its parent's (they join the pools at the fork's epoch);
    ``ValueError`` when the fork's zoo does not start with the parent's: the members the parent seeded are
    in its pools and cannot be taken back."""
    old, new = tuple(parent.league.zoo), tuple(cfg.league.zoo)
    if new[:len(old)] != old:
        raise ValueError(f"a fork may add --league.zoo entries, not change or drop the parent's: the fork's "
                         f"{list(new)} must start with the parent's {list(old)}")
    return new[len(old):]


def _changes(parent: TrainConfig, cfg: TrainConfig) -> dict[str, list[Any]]:
    """Dotted field -> ``[parent value, fork value]`` for every field that differs (league fields one by one)."""
    old, new = config_to_json(parent), config_to_json(cfg)
    out: dict[str, list[Any]] = {}
    for key in new:
        if key in NESTED and isinstance(new[key], dict):
            out |= {f"{key}.{k}": [old[key][k], v] for k, v in new[key].items() if old[key][k] != v}
        elif old[key] != new[key]:
            out[key] = [old[key], new[key]]
    return out


def fork_command(parent_dir: Path, cfg: TrainConfig, changes: dict[str, list[Any]],
                 from_checkpoint: str | None) -> str:
    """The ``triplesumo train --fork`` command line that makes this fork."""
    argv = ["triplesumo", "train", "--fork", str(parent_dir)]
    argv += ["--from", from_checkpoint] if from_checkpoint else []
    argv += ["--name", cfg.name, "--out", cfg.out]
    for key, (_, value) in changes.items():
        if key in ("name", "out"):
            continue
        flag = "--" + key.replace("_", "-")
        if isinstance(value, bool):
            argv.append(flag if value else "--no-" + flag[2:])
        elif isinstance(value, list):
            argv += [flag, *map(str, value)]
        else:
            argv += [flag, str(value)]
    return " ".join(shlex.quote(a) for a in argv)


def untuned(parent: TrainConfig, cfg: TrainConfig, changes: dict[str, list[Any]]) -> list[str]:
    """The algorithm fields among ``changes`` a fork may not tune (``--ALGO.FIELD`` or, through
    ``--learner-config``, one learner's), as flags: those outside their config's ``TUNABLE``."""
    bad = []
    for key in changes:
        section, _, name = key.partition(".")
        if section in ALGOS and name not in type(getattr(cfg, section)).TUNABLE:
            bad.append("--" + key.replace("_", "-"))
    if "learner_config" in changes:
        for learner in sorted({*parent.learner_configs(), *cfg.learner_configs()}):
            old, new = (dataclasses.asdict(c.algo_config(learner)) for c in (parent, cfg))
            bad += [f"--learner-config {learner}.{f}" for f in new if new[f] != old[f]
                    and f not in type(cfg.algo_config(learner)).TUNABLE]
    return bad


def check_fork(parent: TrainConfig, cfg: TrainConfig) -> dict[str, list[Any]]:
    """The fork's changes (:func:`_changes`); ``ValueError`` naming a field a fork may not change."""
    changes = _changes(parent, cfg)
    bad = ["--" + k.replace("_", "-") for k in changes
           if k.split(".")[0] not in (*FORK_FIELDS, *ALGOS, "learner_config")
           or k.removeprefix("league.") in LEAGUE_FIXED] + untuned(parent, cfg, changes)
    if bad:
        flags = ", ".join(bad)
        tunable = "; ".join(f"{a}: {', '.join(type(getattr(cfg, a)).TUNABLE)}" for a in ALGOS)
        raise ValueError(f"a fork continues the parent's networks, matches and pools, so it keeps their config; "
                         f"it may change --league.* (not --league.rating-model; --league.zoo only by adding "
                         f"entries), --reward.*, the algorithms' step sizes, schedules and exploration "
                         f"(--ALGO.FIELD or --learner-config LEARNER.FIELD=VALUE; {tunable}), "
                         f"{flag_list(f for f in FORK_FIELDS if f not in ('name', 'out', *NESTED))}, not {flags}")
    added_seeds(parent, cfg)
    return changes


def drop_unseated_evicted(state: dict[str, Any]) -> tuple[list[str], list[dict[str, Any]]]:
    """Drop from a checkpoint ``state``'s league the evicted members no in-flight match seats (in place):
    what remains is all that resuming it needs. Returns the files (relative to ``RUN/league``) of the
    members kept, and the dropped members' records."""
    seated = {m for seats in state.get("seats", []) for m in seats if m}
    files: list[str] = []
    dropped: list[dict[str, Any]] = []
    for pool in state["league"]["pools"].values():
        kept = [m for m in pool["evicted"] if m["id"] in seated]
        dropped += [m for m in pool["evicted"] if m["id"] not in seated]
        pool["evicted"] = kept
        files += [rel for m in (*pool["members"], *kept) for rel in m["sha256"]]
    return files, dropped


def compact_run(run_dir: Path | str, drop_replay: bool = False) -> dict[str, Any]:
    """Keep only what resuming the run in ``run_dir`` needs, for committing a long run's folder: its newest
    checkpoint (older ones deleted) and the league members its pools and in-flight matches hold. The files of
    the other evicted members are deleted and their records (id, side, epoch, sha256) appended to
    ``league/pruned.json``; ``pool.json`` and the checkpoint's ``state.json`` (and its manifest's sha256) drop
    them. Metrics, policies and ``league.csv`` are kept. Resuming afterwards trains exactly what it would have;
    a tournament's ``--league RUN`` then picks among the kept snapshots. With ``drop_replay`` the checkpoint's
    replay buffer goes too (a repository keeps no buffer): a resume then starts with an empty one, not exactly
    as the run would have gone on. Returns what was removed."""
    run_dir = Path(run_dir)
    with held(run_dir, "compact"):  # not while a run trains or resumes in it
        return _compact(run_dir, drop_replay)


def _compact(run_dir: Path, drop_replay: bool) -> dict[str, Any]:
    folder = checkpoint.latest(run_dir)
    checkpoint.verify(folder, need_replay=(folder / "replay.npz").is_file())
    state = load_json(folder / "state.json")
    older = [f for e, f in checkpoint.checkpoints(run_dir) if f != folder]
    removed: dict[str, Any] = {"checkpoints": [f.name for f in older], "members": [],
                               "replay": drop_replay and checkpoint.holds_replay(folder)}
    if removed["replay"]:  # the manifest first (it then names no replay buffer), then the file
        (folder / "replay.npz").rename(folder / "replay.npz.dropping")
        checkpoint.rewrite_state(folder, state)
        (folder / "replay.npz.dropping").unlink()
    if "league" in state:
        _, dropped = drop_unseated_evicted(state)
        removed["members"] = [m["id"] for m in dropped]
        root = run_dir / "league"
        pruned_path = root / PRUNED_FILE
        pruned = load_json(pruned_path)["members"] if pruned_path.is_file() else []
        pruned += [{k: m[k] for k in ("id", "side", "source", "epoch", "sha256")} for m in dropped]
        # the state first (a kill between steps leaves a checkpoint that names no missing file), then the files
        checkpoint.rewrite_state(folder, state)
        write_pool(root, state["league"])
        atomic_write_bytes(pruned_path, (json.dumps({"members": pruned}, indent=1) + "\n").encode())
        for m in dropped:
            if (root / "members" / m["id"]).exists():
                checkpoint.remove_folder(root / "members" / m["id"])
    for old in older:  # a folder that cannot be removed fails the command, naming it (nothing claims it went)
        checkpoint.remove_folder(old)
    return removed


def parent_config(parent_dir: Path | str) -> TrainConfig:
    """The config of the run to fork (its ``config.json``); ``FileNotFoundError`` when there is none."""
    path = Path(parent_dir) / "config.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no run to fork (file not found)")
    return config_from_json(load_json(path), str(path))


def fork_run(parent_dir: Path | str, cfg: TrainConfig, from_checkpoint: str | None = None) -> Path:
    """Make the fork ``cfg.out/cfg.name`` of the run in ``parent_dir`` at its checkpoint ``from_checkpoint``
    (``epoch-N``; default its latest) and return its folder (module docstring). ``cfg`` is the parent's
    config with the fork's changes (:func:`check_fork`); nothing is written when a check fails. The new
    folder is held while it is made (:func:`triplesumo._lock.held`)."""
    with held(Path(cfg.out) / cfg.name, "train --fork"):
        return _fork_run(Path(parent_dir), cfg, from_checkpoint)


def _fork_run(parent_dir: Path, cfg: TrainConfig, from_checkpoint: str | None) -> Path:
    parent = parent_config(parent_dir)
    changes = check_fork(parent, cfg)
    seeds = added_seeds(parent, cfg)
    check_seeds(seeds)  # their files are copied into the fork's pools below
    check_seed_rings(seeds, cfg.physics, cfg.allow_other_ring)
    run_dir = Path(cfg.out) / cfg.name
    if run_dir.resolve() == parent_dir.resolve():
        raise ValueError(f"a fork needs its own folder: --name/--out give {run_dir}, the parent's folder")
    if holds_run(run_dir):
        raise ValueError(f"run folder {run_dir} already holds a run; a fork writes a new folder (choose another "
                         f"--name, or continue that run with `triplesumo train --resume {run_dir}`)")
    folder = checkpoint.find(parent_dir, from_checkpoint) if from_checkpoint else checkpoint.latest(parent_dir)
    parent_legs = read_legs(parent_dir)  # (a corrupt legs.json is refused before anything is written)
    need_replay = cfg.save_replay and (folder / "replay.npz").is_file()
    checkpoint.verify(folder, need_replay=need_replay)
    state = load_json(folder / "state.json")
    epoch = int(state["epochs_done"])

    league_files: list[str] = []
    left_behind: list[str] = []
    if "league" in state:
        league_files, dropped = drop_unseated_evicted(state)
        left_behind = [m["id"] for m in dropped]
        state["league"]["config"] = dataclasses.asdict(cfg.league)
    command = fork_command(parent_dir, cfg, changes, from_checkpoint)
    manifests = state.get("manifests") or {}
    record = {
        "format": FORK_FORMAT, "parent": str(parent_dir), "parent_run_id": state.get("run_id"),
        "parent_command": next((m.get("command") for m in manifests.values()), None),
        "checkpoint": folder.name, "epoch": epoch, "env_steps": int(state["env_steps"]), "changes": changes,
        "command": command, "evicted_left_behind": left_behind, "seeded": [],
    }
    state["config"] = config_to_json(cfg)
    state["run_id"] = run_id_of(cfg)

    # the run's own tables (metrics*, learning*, eval*) as they lie, plain or packed: cut back (and unpacked) on resume
    tables = [p for name in tables_in(parent_dir) if (p := stored(name)) is not None]
    created = not run_dir.exists()
    prepare_run_dir(run_dir)
    written: list[Path] = []
    try:
        target = run_dir / "checkpoints" / folder.name
        written += [run_dir / "checkpoints", run_dir / "league", run_dir / FORK_FILE, run_dir / "config.json",
                    run_dir / LEGS_FILE,
                    *(run_dir / f.name for f in tables)]
        target.mkdir(parents=True)
        for name in ("weights.safetensors", "arrays.npz", checkpoint.MANIFEST,
                     *(["replay.npz"] if need_replay else [])):
            shutil.copyfile(folder / name, target / name)
        if "league" in state:
            for rel in league_files:
                dest = run_dir / "league" / rel
                dest.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(parent_dir / "league" / rel, dest)
            write_pool(run_dir / "league", state["league"])
            log = stored(parent_dir / "league" / LOG_FILE)  # plain or packed: a resume unpacks it
            if log is not None:
                shutil.copyfile(log, run_dir / "league" / log.name)
            if seeds:  # the appended zoo entries join the pools now, as members seeded at the fork's epoch
                league = League.load(run_dir, cfg.league)
                record["seeded"] = [m.id for m in league.seed(seeds, epoch)]
                state["league"] = league.state_dict()
                league.save()
        checkpoint.rewrite_state(target, state)  # (its manifest then names no replay buffer it did not copy)
        checkpoint.point_latest(run_dir, target, epoch)
        for table in tables:
            shutil.copyfile(table, run_dir / table.name)
        atomic_write_bytes(run_dir / FORK_FILE, (json.dumps(record, indent=1) + "\n").encode())
        write_legs(run_dir, legs_before(parent_legs, epoch))  # the parent's legs up to the fork's epoch
        write_run_config(run_dir, cfg)
    except BaseException:  # a half-made fork is no run: take back what was written
        for path in [run_dir] if created else written:
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
        raise
    return run_dir

