"""Running the protocol from one command, resumable (:func:`run_reproduce`), and publishing its policies."""

from __future__ import annotations

import dataclasses
import datetime
import json
import signal
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from triplesumo._lock import held, holder
from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.model.specs import PhysicsConfig
from triplesumo.reproduce.config import GROWABLE, RECORD_FILE, REPORT_FILE, RUN_OPTIONS, ReproduceConfig, bug_runs
from triplesumo.reproduce.protocol import Protocol
from triplesumo.reproduce.reporting import _docs_markers, _write_report, format_status, stage_seconds
from triplesumo.train import legs
from triplesumo.train.sweep import budget_changes, set_aside
from triplesumo.version import ENV_VERSION, __version__


def code_version() -> str:
    """``git SHORT-SHA`` (``-dirty`` when the package's tracked files differ from it) of the checkout the
    package was imported from (:func:`triplesumo.train.legs.code_version`), else the package version."""
    code = legs.code_version()
    if code is not None:
        return f"git {code['commit'][:7]}{'-dirty' if code['dirty'] else ''}"
    return f"triplesumo {__version__}"


OPTIONS_ADDED_LATER: dict[str, Any] = {"bug_n_step": 1}
"""Options added to :class:`ReproduceConfig` with a default other than what the reproductions recorded before them
did (one-step returns for the TD3 and SAC Bugs), written out: a record without one counts as this value."""


def check_same_options(out: Path, recorded: dict[str, Any], cfg: ReproduceConfig) -> dict[str, dict[str, int]]:
    """``ValueError`` unless the reproduction recorded in ``out`` was made with ``cfg``'s options (:data:`RUN_OPTIONS`
    aside, the Bug runs' algorithms and seeds where ``cfg`` keeps every run the record names, and Bug budgets that
    grow); an option added since the record was written counts as what that run used: its value in
    :data:`OPTIONS_ADDED_LATER`, else its default. Returns the Bug budgets ``cfg`` grows (:data:`GROWABLE`:
    ``{field: {"from": old, "to": new}}``, empty when they are the same)."""
    config = json.loads(json.dumps(dataclasses.asdict(cfg)))
    defaults = json.loads(json.dumps(dataclasses.asdict(ReproduceConfig()))) | OPTIONS_ADDED_LATER
    recorded = {**{k: v for k, v in defaults.items() if k not in recorded}, **recorded}
    # the folder by its place, however it was written; --status only reads, so a moved folder may be read
    config["out"], recorded["out"] = str(Path(config["out"]).resolve()), str(Path(recorded["out"]).resolve())
    ignore = (*RUN_OPTIONS, "out") if cfg.status else RUN_OPTIONS
    runs = ("algos", "seeds", "ddpg_runs")  # may grow: the Bug runs made are kept, new ones train beside them
    if set(bug_runs(recorded["algos"], recorded["seeds"], recorded["ddpg_runs"])) <= set(
            bug_runs(cfg.algos, cfg.seeds, cfg.ddpg_runs)):
        ignore = (*ignore, *runs)
    def both(keys: list[str]) -> str:
        return ", ".join(f"{k}: {recorded.get(k)!r} there, {config.get(k)!r} given" for k in keys)

    grown, shrunk = budget_changes(recorded, config, GROWABLE)
    if shrunk:
        raise ValueError(f"{out} holds a reproduction whose Bugs trained to a larger budget ({both(shrunk)}); "
                         "a Bug budget can grow on a re-run, not shrink: choose another --out")
    ignore = (*ignore, *GROWABLE)
    differ = sorted(k for k in {*config, *recorded} if k not in ignore and recorded.get(k) != config.get(k))
    if differ:
        raise ValueError(f"{out} holds a reproduction with other options ({both(differ)}); "
                         "re-running resumes it and needs the same options: choose another --out")
    return grown


TEST_STAGES = ("evaluation", "compare")
"""The stages that play and summarise the Bugs' test: what a grown Bug budget makes stale."""


def set_aside_test(protocol: Protocol, record: dict[str, Any], grown: dict[str, dict[str, int]]) -> dict[str, Any]:
    """Before the Bugs train on to a grown budget: move the test of the smaller one (``evaluation/``, ``compare/``)
    to ``OUT/at-<budget>/`` with a copy of every Bug policy it played (each run's ``policy.*`` is replaced when it
    trains on), and move those stages' entries from ``record["stages"]`` into the returned entry of
    ``record["grown"]``. Nothing is deleted: the set-aside folder is the smaller budget's test, whole."""
    out = protocol.out
    runs = [Path(t.config.out) / t.name for t in [*protocol.bug_trials(), *protocol.ablation_trials()]]
    aside, moved = set_aside(out, TEST_STAGES, grown, runs)  # policies/bug/NAME, policies/ablations/NAME
    return {"budget": grown, "at": _now(), "version": code_version(), "folder": aside.name, "moved": moved,
            "stages": {k: record["stages"].pop(k) for k in TEST_STAGES if k in record["stages"]}}


HEARTBEAT_SECONDS = 60.0
"""How often the running stage's leg writes its wall time so far into ``reproduce.json``: a process killed without
warning (SIGKILL, a machine going down) loses at most this much of it."""


class Record:
    """``reproduce.json``, written whole and atomically on every change, from the main thread or the heartbeat."""

    def __init__(self, path: Path, data: dict[str, Any]) -> None:
        self.path, self.data = path, data
        self.lock = threading.Lock()

    def write(self) -> None:
        with self.lock:
            atomic_write_bytes(self.path, (json.dumps(self.data, indent=2) + "\n").encode())


@contextmanager
def stage_leg(record: Record, name: str, version: str, every: float = HEARTBEAT_SECONDS) -> Iterator[dict[str, Any]]:
    """One invocation's work on stage ``name`` (a *leg*): appended to the stage's ``legs`` in the record at once,
    its ``seconds`` rewritten every ``every`` seconds while it runs and at its end (``finished``: it completed
    the stage's work without an exception). A stage's wall time is the sum over its legs, whenever they ran.
    SIGTERM (``pkill``, a scheduler) ends the leg as an interrupt does, so its time is written."""
    entry = record.data["stages"].setdefault(name, {})
    leg: dict[str, Any] = {"started": _now(), "seconds": 0.0, "version": version, "finished": False}
    entry.setdefault("legs", []).append(leg)
    start = time.perf_counter()
    stop = threading.Event()

    def beat() -> None:
        while not stop.wait(every):
            leg["seconds"] = round(time.perf_counter() - start, 3)
            record.write()

    def terminate(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    previous = (signal.signal(signal.SIGTERM, terminate)
                if threading.current_thread() is threading.main_thread() else None)
    heart = threading.Thread(target=beat, name=f"reproduce-{name}-clock", daemon=True)
    record.write()
    heart.start()
    try:
        yield leg
        leg["finished"] = True
    finally:
        stop.set()
        heart.join()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        leg["seconds"] = round(time.perf_counter() - start, 3)
        record.write()


def run_reproduce(cfg: ReproduceConfig) -> dict[str, Any]:
    """Run (or finish) every stage in order, skipping complete ones; write reproduce.json and the report."""
    protocol = Protocol(cfg)
    out = protocol.out
    if cfg.docs:  # before hours of training: the file and its markers are there
        _docs_markers(Path(cfg.docs).read_text().splitlines())
    if cfg.status and (who := holder(out)) is not None:  # read while the reproduction there works: nothing written
        record, _ = _check_record(cfg, out)
        print(format_status(protocol))
        print(f"(a reproduction is at work in {out}, {who}: it writes the report; --status wrote nothing)")
        return record
    with held(out, "reproduce"), protocol.one_ray():  # one reproduction per folder (each run and evaluation holds
        return _run_reproduce(cfg, protocol, out)  # its own too); the stages on Ray share one


def _check_record(cfg: ReproduceConfig, out: Path) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """The folder's record (empty if none) and the Bug budgets ``cfg`` grows, after :func:`check_same_options`
    held this config to it."""
    path = out / RECORD_FILE
    record: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    return record, check_same_options(out, record["config"], cfg) if record else {}


def _run_reproduce(cfg: ReproduceConfig, protocol: Protocol, out: Path) -> dict[str, Any]:
    path = out / RECORD_FILE
    record, grown = _check_record(cfg, out)
    config = json.loads(json.dumps(dataclasses.asdict(cfg)))
    record = {"config": config, "stages": record.get("stages", {}), "runs": record.get("runs", []),
              **{k: record[k] for k in ("published", "grown") if k in record}}  # published: until a later --publish
    run_now: dict[str, Any] = {"version": code_version(), "started": _now(), "ran": [], "skipped": []}
    if cfg.status:
        print(format_status(protocol))
        _write_report(protocol, {**record, "runs": [*record["runs"], run_now]})
        print(f"report (so far): {out / REPORT_FILE}")
        return record
    record["runs"].append(run_now)
    run_now["machine"] = _machine(protocol)
    book = Record(path, record)
    if grown:
        entry = set_aside_test(protocol, record, grown)
        record.setdefault("grown", []).append(entry)
        book.write()
        print("Bug budget grown (" + ", ".join(f"{k} {v['from']:,} -> {v['to']:,}" for k, v in grown.items())
              + f"): the Bugs train on from their last checkpoints; the test of the smaller budget is kept in "
              f"{out / entry['folder']}")
    n = len(protocol.stages)
    made_before = {stage.name for stage in protocol.stages if stage.complete()}
    made_with: dict[str, str] = {}  # a stage made alongside an earlier one of this run (the Spider beside the Ant)
    for k, stage in enumerate(protocol.stages, 1):
        if stage.complete() and stage.name not in made_before and stage.commands is not None:
            by = next(name for name in reversed(run_now["ran"]) if name not in made_with)
            print(f"[{k}/{n}] {stage.name}: made alongside {by} ({stage.title})")
            record["stages"][stage.name] = {**record["stages"][by], "with": by, "commands": stage.commands()}
            made_with[stage.name] = by
            run_now["ran"].append(stage.name)
            book.write()
            continue
        if stage.complete():
            print(f"[{k}/{n}] {stage.name}: complete, skipped ({stage.title})")
            run_now["skipped"].append(stage.name)
            continue
        print(f"[{k}/{n}] {stage.name}: {stage.title}")
        with stage_leg(book, stage.name, run_now["version"]):
            commands = stage.run()
        if not stage.complete():
            raise RuntimeError(f"stage {stage.name} ran but its outputs are not complete: {stage.outputs}")
        entry = record["stages"][stage.name]
        entry.update({"done": _now(), "seconds": round(stage_seconds(entry), 3), "version": run_now["version"],
                      "commands": commands, "outputs": [str(p.relative_to(out)) for p in stage.outputs]})
        run_now["ran"].append(stage.name)
        book.write()
    if cfg.publish:
        record["published"] = _publish(protocol, run_now["version"])
    book.write()
    _write_report(protocol, record)
    print(f"report: {out / REPORT_FILE}; record: {path}")
    return record


def _machine(protocol: Protocol) -> dict[str, Any]:
    """The machine this run of the protocol ran on and its speed, as ``bench skill`` records them: the CPU and a
    fixed seeded collection of the Bug stage's matches (ms per env step), so that stage times measured on two
    machines can be set side by side."""
    from triplesumo.train.machine import DEVICE_REFERENCE_STEPS, device_reference, machine, reference_speed

    base = protocol.bug_base()
    host = dataclasses.replace(base, backend="cpu", device=None, n_envs=protocol.n_envs)  # what the tests play on
    found = {**machine(base), "reference": reference_speed(host, repeats=1 if protocol.cfg.tiny else 3)}
    if base.backend == "warp":  # the device's speed and start-up (building, compiling or loading Warp's kernels)
        found["device_reference"] = device_reference(base, steps=5 if protocol.cfg.tiny else DEVICE_REFERENCE_STEPS)
    return found


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def _shown(path: Path) -> str:
    """``path`` relative to the working directory when it lies inside it (a manifest that names
    ``docs/runs/...`` stays true in every checkout), else absolute."""
    here = Path.cwd().resolve()
    return str(path.relative_to(here)) if path.is_relative_to(here) else str(path)


SELECT_WINDOW = 200
"""The shipped Bug of each algorithm is its seed with the highest training MWR over its last this many training
matches (training starts only: the test starts pick nothing; docs/CONTEST.md, the Bug stage's rules)."""


BUG_RULE = ("the shipped Bug (bug-ALGO) of the algorithm with the highest IQM test MWR across its seeds, "
            "DDPG (the paper preset) on a tie")
"""Why ``zoo:bug`` is the alias of the Bug it names (recorded in its manifest)."""


def _publish(protocol: Protocol, version: str) -> list[dict[str, Any]]:
    """Ship Ant and Spider (with the contest check they passed), ``bug-<algo>`` for every algorithm (its seed with
    the highest training MWR over the last :data:`SELECT_WINDOW` training matches) and ``bug``, an alias of that Bug of
    the algorithm with the highest IQM test MWR across its seeds, the protocol's measure of an algorithm. Each manifest
    carries the code version, the ring, and for a Bug its test MWR with its 95 % interval and how it was picked."""
    from triplesumo import zoo  # (its publish refuses an invalid ring)
    from triplesumo.agents.zoo import publish_alias
    from triplesumo.train.sweep import run_facts

    by_policy = {str(Path(t.config.out) / t.name / "policy"): Path(t.config.out) / t.name
                 for t in protocol.bug_trials()}  # not the ablations
    rows = [r for r in protocol.evaluation_rows() if r["policy"] in by_policy]
    # the ring every stage trained on, and the env version whose default it is (the trainer wrote the one it ran under)
    extra: dict[str, Any] = {"code_version": version, "reproduction": _shown(protocol.out),
                             "physics": dataclasses.asdict(protocol.physics),
                             **({"env_version": ENV_VERSION} if protocol.physics == PhysicsConfig() else {})}
    train_mwr = {r["policy"]: run_facts(by_policy[r["policy"]], SELECT_WINDOW)["final_mwr"] for r in rows}
    groups = {g["group"]: g for g in json.loads((protocol.out / "compare" / "compare.json").read_text())["groups"]}

    def evaluation(row: dict[str, str]) -> dict[str, Any]:
        return {"test_mwr": float(row["test_mwr"]), "test_mwr_lo": float(row["test_mwr_lo"]),
                "test_mwr_hi": float(row["test_mwr_hi"]), "confidence": 0.95, "test_matches": int(row["epochs"]),
                "eval_seed": int(row["eval_seed"]), "n_win": int(row["n_win"]), "n_loss": int(row["n_loss"]),
                "n_draw": int(row["n_draw"]), "opponents": [f"ant={protocol.ant_policy}",
                                                            f"spider={protocol.spider_policy}"],
                "selection": {"rule": f"the seed with the highest training MWR over its last {SELECT_WINDOW} "
                                      "training matches", "train_mwr": train_mwr[row["policy"]],
                              "algo_iqm_test_mwr": groups[row["algo"]]["iqm"],
                              "seeds": groups[row["algo"]]["n_seeds"]}}

    # Ant and Spider: the stage-2 contest checks they passed (recomputable from contest/*/metrics.csv)
    contest = {"contest": json.loads((protocol.out / "contest" / "contest.json").read_text())}
    ship: list[tuple[Path, str, dict[str, Any] | None]] = [(Path(protocol.ant_policy), "ant", None),
                                                           (Path(protocol.spider_policy), "spider", None)]
    picks = {}
    for algo in sorted({r["algo"] for r in rows}):  # per algorithm: its seed by training MWR, lower seed on a tie
        mine = sorted((r for r in rows if r["algo"] == algo), key=lambda r: int(r["train_seed"]))
        picks[algo] = max(mine, key=lambda r: train_mwr[r["policy"]])
    ship += [(Path(row["policy"]), f"bug-{algo}", row) for algo, row in picks.items()]
    if picks:  # zoo:bug, an alias (its weights are stored once, as bug-ALGO's), made once its target is there
        best = max(picks, key=lambda a: (groups[a]["iqm"], a == "ddpg"))  # the paper preset on a tie
        ship.append((Path(picks[best]["policy"]), "bug", picks[best]))
    made = []
    for stem, name, row in ship:
        if name == "bug" and row is not None:
            path = publish_alias(name, f"bug-{row['algo']}",
                                 extra={"rule": BUG_RULE, "reproduction": extra["reproduction"]})
        else:
            path = zoo.publish(stem, name, contest if row is None else evaluation(row), extra=extra)
        made.append({"name": name, "file": str(path), "policy": str(stem),
                     **({} if row is None else {"algo": row["algo"], "train_seed": row["train_seed"],
                                                "train_mwr": train_mwr[row["policy"]],
                                                "test_mwr": float(row["test_mwr"]),
                                                "test_mwr_lo": float(row["test_mwr_lo"]),
                                                "test_mwr_hi": float(row["test_mwr_hi"])})})
    return made
