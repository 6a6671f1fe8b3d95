"""What a reproduction folder says: ``REPRODUCTION.md`` (and its copy inside a docs page), the status table,
the time-to-skill curves."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import re
import shlex
from pathlib import Path
from typing import Any

from triplesumo._lock import LOCK_FILE, holder
from triplesumo.agents.policy_file import atomic_write_bytes
from triplesumo.evaluation.compare import trial_group
from triplesumo.evaluation.metrics_csv import open_table, table_exists
from triplesumo.reproduce.config import PUSH_MIN, REPORT_FILE, RUN_OPTIONS, SKILL, ReproduceConfig
from triplesumo.reproduce.protocol import ENGAGEMENT_FILE, NOT_PLAYED, Protocol, _read_csv, contest_can_pass
from triplesumo.train.logger import policy_seconds
from triplesumo.train.sweep import Trial, finished, run_facts

DOCS_BEGIN, DOCS_END = "<!-- reproduce:begin -->", "<!-- reproduce:end -->"


def _write_report(protocol: Protocol, record: dict[str, Any]) -> None:
    """``OUT/REPRODUCTION.md``, and with ``--docs`` the same report inside that Markdown file."""
    text = report(protocol, record)
    atomic_write_bytes(protocol.out / REPORT_FILE, text.encode())
    if protocol.cfg.docs:
        docs = Path(protocol.cfg.docs)
        atomic_write_bytes(docs, embed_report(text, protocol.out, docs.read_text(), docs.parent).encode())
        print(f"report written into {docs}")


def _docs_markers(lines: list[str]) -> tuple[int, int]:
    """Where a docs page's two marker lines are; ``ValueError`` unless both are there, in order."""
    if DOCS_BEGIN not in lines or DOCS_END not in lines or lines.index(DOCS_BEGIN) > lines.index(DOCS_END):
        raise ValueError(f"--docs file needs a line {DOCS_BEGIN} and, after it, a line {DOCS_END}: the report goes "
                         "between them")
    return lines.index(DOCS_BEGIN), lines.index(DOCS_END)


def embed_report(text: str, out: Path, page: str, page_dir: Path) -> str:
    """``page`` with the report ``text`` (of the folder ``out``) between its two marker lines: the report's title
    left out, its headings one level down, its links to files of ``out`` made relative to ``page_dir``."""
    lines = page.splitlines()
    start, end = _docs_markers(lines)
    prefix = os.path.relpath(out.resolve(), page_dir.resolve())
    body, fenced = [], False
    for line in text.splitlines()[1:]:
        fenced ^= line.startswith("```")
        if not fenced and line.startswith("#"):
            line = "#" + line
        elif not fenced:
            line = re.sub(r"\]\((?![a-z]+:|/|#)([^)]+)\)", lambda m: f"]({prefix}/{m.group(1)})", line)
        body.append(line)
    return "\n".join([*lines[:start + 1], *body, *lines[end:]]) + "\n"


def status(protocol: Protocol) -> list[dict[str, Any]]:
    """Where each stage and each Bug run of the folder stands: rows of stage, run, state, env steps, the newest test
    MWR of the run's evaluations while training, and ``left``: a running Bug run's seconds to its env-step budget at
    its recent pace (:func:`pace`; None when not known). The state is ``complete``, ``running (PID N)`` while a
    process holds the run's folder or one inside it (an evaluation, a screen), ``stopped`` when it started and no
    process holds it (a re-run resumes it), or ``not started``."""
    trials = {"bug": protocol.bug_trials(), "ablations": protocol.ablation_trials()}
    rows: list[dict[str, Any]] = []
    for stage in protocol.stages:
        if stage.name in trials:  # one row per Bug run
            runs = [(t.name, Path(t.config.out) / t.name, finished(t), t.config.max_env_steps)
                    for t in trials[stage.name]]
        else:  # one row for the stage; a training stage's run folder is named after it
            runs = [(stage.name, protocol.out / stage.name, stage.complete(), 0)]
        for name, folder, done, budget in runs:
            started = table_exists(folder / "metrics.csv")
            who = None if done else holder_in(folder)
            steps = run_facts(folder, 200)["env_steps"] if started else None
            evals = _evals(folder)
            rate = pace(folder) if who and steps is not None and budget else None
            rows.append({"stage": stage.name, "run": name,
                         "state": ("complete" if done else f"running ({who})" if who else "stopped" if started
                                   else "not started"),
                         "env_steps": steps, "test_mwr": float(evals[-1]["test_mwr"]) if evals else None,
                         "left": max(budget - steps, 0) / rate if rate and steps is not None else None})
    return rows


def holder_in(folder: Path) -> str | None:
    """Who holds ``folder`` or a folder inside it (:func:`triplesumo._lock.holder`), or None."""
    if not folder.is_dir():
        return None
    return next((who for lock in folder.rglob(LOCK_FILE) if (who := holder(lock.parent)) is not None), None)


PACE_SECONDS = 600.0
""":func:`pace` reads a run's last rows back this far in wall time (or to a stop between two rows, or 400 rows)."""


def pace(run: Path) -> float | None:
    """A run's recent env steps per second, from the wall times of the last rows of its ``metrics.csv`` (the rows
    since a gap of more than :data:`PACE_SECONDS` between two of them: a stop and a resume), or None when those
    rows span less than 30 s."""
    with open_table(run / "metrics.csv") as fh:
        rows = [(float(r["wall_time"]), int(r["env_steps"])) for r in list(csv.DictReader(fh))[-400:]]
    if not rows:
        return None
    end_time, end_steps = rows[-1]
    first = len(rows) - 1
    while first > 0 and rows[first][0] - rows[first - 1][0] <= PACE_SECONDS \
            and end_time - rows[first - 1][0] <= PACE_SECONDS:
        first -= 1
    seconds = end_time - rows[first][0]
    return (end_steps - rows[first][1]) / seconds if seconds >= 30 else None


def format_status(protocol: Protocol) -> str:
    """:func:`status` as a table."""
    lines = [f"{'stage':<11} {'run':<44} {'state':<19} {'env steps':>11} {'test MWR':>9}  left"]
    for r in status(protocol):
        steps = "-" if r["env_steps"] is None else f"{r['env_steps']:,}"
        mwr = "-" if r["test_mwr"] is None else f"{r['test_mwr']:+.3f}"
        left = "" if r["left"] is None else f"  {_duration(r['left'])}"
        lines.append(f"{r['stage']:<11} {r['run']:<44} {r['state']:<19} {steps:>11} {mwr:>9}{left}")
    return "\n".join(lines)


def _run_row(protocol: Protocol, name: str) -> str:
    """A table row of a run's training."""
    run = protocol.out / name
    if not table_exists(run / "metrics.csv"):
        return f"| {name} | - | - | - |"
    facts = run_facts(run, 200)
    return f"| {name} | {facts['epochs']:,} | {facts['env_steps']:,} | {facts['final_mwr']:+.3f} |"


def _machines(record: dict[str, Any]) -> list[str]:
    """Where each run of the protocol ran (several runs of it may share one folder): its CPU, cores and reference
    speed (ms per env step of a fixed seeded collection: a slower box takes longer for the same stages), the
    stages it ran."""
    runs = [r for r in record.get("runs", []) if r.get("machine") and r.get("ran")]
    if not runs:
        return []
    lines = ["| run started | machine | reference (ms per env step) | stages run |", "| --- | --- | ---: | --- |"]
    for r in runs:
        m = r["machine"]
        where = f"{m['cpu']}, {m['cores']} cores"
        if m.get("backend") == "warp":  # the sides and Bugs trained on the device; the checks played on this CPU
            dev = m.get("device_reference")
            where += (f"; trained on Warp's {m['device']} device ({m.get('gpu') or 'no GPU'}"
                      + (f", {dev['env_steps_per_s']:,.0f} env steps/s of {dev['n_envs']:,} matches with random "
                         f"actions" if dev else "") + ")")
        lines.append(f"| {r['started']} | {where} | {m['reference']['ms_per_env_step']:.3f} | {', '.join(r['ran'])} |")
    return [*lines, ""]


def stage_seconds(stage: dict[str, Any]) -> float:
    """A stage's wall time in the record: the sum over its legs (a record written before legs: the time of the
    invocation that finished it, which leaves out the legs before)."""
    return float(sum(leg["seconds"] for leg in stage["legs"])) if "legs" in stage else float(stage["seconds"])


def _stage_times(record: dict[str, Any]) -> list[str]:
    """Each stage's wall time, summed over the invocations that worked on it (its legs, whenever they ran)."""
    stages = record.get("stages", {})
    if not stages:
        return []
    lines = ["Wall time per stage: the sum of its legs (each invocation of `reproduce` that worked on it, whenever "
             "it ran; a leg's time is written every minute while it runs).", "",
             "| stage | wall time | legs | state |", "| --- | ---: | ---: | --- |"]
    for name, stage in stages.items():
        if "with" in stage:
            lines.append(f"| {name} | - | - | made alongside {stage['with']} |")
            continue
        legs = stage.get("legs")
        count = str(len(legs)) if legs is not None else "-"
        state = ("not finished" if "done" not in stage else "done" if legs is not None
                 else "done (recorded before legs: the time of the invocation that finished it)")
        lines.append(f"| {name} | {_duration(stage_seconds(stage))} | {count} | {state} |")
    return [*lines, ""]


def _stage_one_section(protocol: Protocol) -> list[str]:
    """Each side's screens (the checkpoint rule) and every pair played (the pair rule), from their records."""
    lines = [f"Screens: every {protocol.screen_every:,} epochs each side's policy, frozen, against still opponents on "
             f"{protocol.screen_epochs} starts (seed {protocol.cfg.screen_seed} + i); a side's pick is its earliest "
             f"checkpoint that pushes at least {PUSH_MIN:.0%} of them out.", "",
             "| side | epochs | env steps | pushes out (W / L / D) | passes | leg wall time | screen wall time |",
             "| --- | ---: | ---: | --- | --- | ---: | ---: |"]
    for role in ("ant", "spider"):
        side = protocol.side(role)
        for sc in side.screens():
            lines.append(f"| {role} | {sc['epoch']:,} | {sc['env_steps']:,} | {sc['n_win']} / {sc['n_loss']} / "
                         f"{sc['n_draw']} of {sc['n']} | {'yes' if sc['n_win'] / sc['n'] >= side.push_min else 'no'}"
                         f" | {_duration(sc['train_seconds'])} | {_duration(sc['screen_seconds'])} |")
    pair = protocol.pair_record()
    if pair.get("pairs"):
        lo, hi = pair["band"]
        lines += ["", f"Pairs played with Bug passive on the same starts (the pair rule: a team MWR in [{lo:+.2f}, "
                      f"{hi:+.2f}] makes the pair; below it the Ant trains on, above it the Spider):", "",
                  "| Ant | Spider | Spider W / L / D | team MWR | next |", "| ---: | ---: | --- | ---: | --- |"]
        for p in pair["pairs"]:
            c = p["counts"]
            nxt = "**the pair**" if p["move"] == "pair" else f"a stronger {p['move'].capitalize()}"
            lines.append(f"| {p['ant_epoch']:,} | {p['spider_epoch']:,} | {c['n_win']} / {c['n_loss']} / "
                         f"{c['n_draw']} | {p['team_mwr']:+.3f} | {nxt} |")
        if pair.get("failed"):
            lines += ["", f"**Stage 1 stopped: {pair['failed']}.** No contest was played and no Bug trained."]
    return [*lines, ""]


def _contest_section(c: dict[str, Any], seed: int) -> list[str]:
    """Stage 2's table from ``contest.json``: each check's value, bound and state; a contest stopped early shows the
    starts its deciding check played and the checks it did not play."""
    lo, hi = c["band"]
    stopped = c.get("stopped")
    verdict = "a contest" if c["contest"] else "**not a contest**: the Bug stage refuses it"
    if stopped:
        verdict += (f" (decided by `{stopped['check']}` after {stopped['after']:,} of its {c['matches']:,} starts, "
                    f"when it could no longer pass: {c['failed'][0]})")
    rows = []
    for check, what, value, bound in (
            ("ant-pushes", "Ant pushes a passive Spider out", "ant_pushes", f">= {c['push_min']:.0%}"),
            ("spider-pushes", "Spider pushes a passive Ant or Bug out", "spider_pushes", f">= {c['push_min']:.0%}"),
            ("match", "team MWR, Bug passive", "team_mwr", f"[{lo:+.2f}, {hi:+.2f}]")):
        if check in c.get("not_played", []):
            rows.append(f"| {what} | - | {bound} | {NOT_PLAYED} |")
            continue
        counts = c["counts"][check]
        shown = f"{c[value]:+.3f}" if check == "match" else f"{c[value]:.1%}"
        if check == "match":
            what += f" (wins {c['team_wins']:.1%}, losses {c['team_losses']:.1%}, draws {c['draws']:.1%})"
        state = "ok" if contest_can_pass(check, counts, c["matches"]) else "failed"
        if counts["n"] < c["matches"]:
            shown += f" on the first {counts['n']:,}"
            state = "failed: could no longer pass"
        rows.append(f"| {what} | {shown} | {bound} | {state} |")
    return [f"On {c['matches']:,} held-out starts each (seed {seed}): each side must push a passive opponent out in "
            f"at least {c['push_min']:.0%} of them, and with Bug passive the team's MWR must lie in [{lo:+.2f}, "
            f"{hi:+.2f}].", "",
            "| check | value | bound | |", "| --- | ---: | ---: | --- |", *rows, "", f"Verdict: {verdict}.", ""]


def _engagement_section(e: dict[str, Any]) -> list[str]:
    """Who leaves the ring with Bug passive (``contest/engagement.json``): reported, not a gate."""
    def pct(key: str) -> str:
        return f"{e[key]:.1%}"

    return ["With Bug passive, watched match by match on the contest's first "
            f"{e['matches']} starts (seed {e['seed']}; reported beside the Bugs, not a gate): who left the ring first, "
            "and whether the Spider meets the Bug at all (a Spider that hunts only the Ant leaves a Bug nothing to "
            "learn from).", "",
            "| team MWR | Bug out | Ant out | Spider out | nobody out | Bug touches Spider | "
            "Bug out, Spider touching |",
            "| ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
            f"| {e['mwr']:+.3f} | {pct('bug_out')} | {pct('ant_out')} | {pct('spider_out')} | {pct('none_out')} | "
            f"{pct('bug_touched_spider')} | {pct('bug_out_touched_by_spider')} |", ""]


def _trial_group(trial: Trial) -> str:
    """The compare group of a trial's policy (``ddpg``, ``ddpg,ddpg.noise=gaussian``)."""
    return trial_group({"group": "trained", "algo": "", "policy": str(Path(trial.config.out) / trial.name / "policy")})


def _ci(x: float, lo: float, hi: float) -> str:
    return f"{x:+.3f} [{lo:+.3f}, {hi:+.3f}]"


def _group_estimate(g: dict[str, Any]) -> str:
    """A compare group's IQM with its interval, or the mean of fewer runs than an interval needs."""
    return f"mean {g['mean']:+.3f} (no interval: {g['n_seeds']} run(s))" if g["lo"] is None else _ci(
        g["iqm"], g["lo"], g["hi"])


def report(protocol: Protocol, record: dict[str, Any]) -> str:
    """``REPRODUCTION.md`` of a reproduction folder, every number read from the files it wrote."""
    out, cfg = protocol.out, protocol.cfg
    ring = ("`border_rim=True`: the paper's ring with its solid 3 cm rim (env v2: four boxes), agents starting "
            "fair (each 1.0 m from its nearest edge and from the edge behind it)" if cfg.border_rim
            else "`border_rim=False`: visual-only border markers (the ring of the first shipped zoo)")
    lines = [f"# Reproduction report ({out.name})", "",
             f"Written by `triplesumo reproduce` (code version {record['runs'][-1]['version']}) from the files in "
             f"`{out.name}/`." + (" **Tiny budgets (a smoke run): the numbers mean nothing.**"
                                                    if cfg.tiny else ""), "",
             f"Ring: {ring}; every stage trained and was evaluated on it.", "",
             *_machines(record), *_stage_times(record),
             "## Stage 1: the pair (each side learns to push still opponents)", "",
             *([f"Skipped: the pair was given (`--pair {' '.join(cfg.pair)}`).", ""] if cfg.pair else [
                 f"Pre-training reward: the paper's terms with still = {cfg.pretrain.still:g} (losing costs more than "
                 f"surviving), draw = {cfg.pretrain.draw:g}, per-axis dead zone {cfg.pretrain.axis_dead_zone:g} m, "
                 f"per-opponent terms as a {cfg.pretrain.opponents}.", "",
                 "| run | epochs | env steps | final training MWR (last 200 epochs) |", "| --- | ---: | ---: | ---: |",
                 _run_row(protocol, "ant"), _run_row(protocol, "spider"), "", *_stage_one_section(protocol)])]
    contest_path = out / "contest" / "contest.json"
    lines += ["## Stage 2: is it a contest?", ""]
    if contest_path.exists():
        lines += _contest_section(json.loads(contest_path.read_text()), cfg.contest_seed)
    engagement_path = out / "contest" / ENGAGEMENT_FILE
    if engagement_path.exists():
        lines += _engagement_section(json.loads(engagement_path.read_text()))
    budget = "" if cfg.tiny else f" (budget {cfg.bug_env_steps:,} env steps per run)"
    schedule = [] if cfg.tiny else [
        "DDPG: the paper preset (one gradient step per 30 transitions, one-step targets); TD3 and SAC: one "
        "gradient step per " + (f"{cfg.bug_learn_every} transitions (`--bug-learn-every`)" if cfg.bug_learn_every
                                else "transition or their default (`--bug-learn-every 0`)")
        + ", " + (f"{cfg.bug_n_step}-step returns (`--bug-n-step`)" if cfg.bug_n_step
                  else "their default returns (`--bug-n-step 0`)")
        + "; PPO: its rollouts. The exact commands are at the end.", ""]
    lines += [f"## Stage 3: Bug per algorithm and seed (training){budget}", "", *schedule,
              "| run | epochs | env steps | final training MWR (last 200 epochs) |", "| --- | ---: | ---: | ---: |"]
    lines += [_run_row(protocol, f"bug/{t.name}") for t in protocol.bug_trials()]
    lines += [_run_row(protocol, f"ablations/{t.name}") for t in protocol.ablation_trials()] + [""]
    rows = _read_csv(out / "evaluation" / "per_seed.csv")
    epochs = rows[0]["epochs"] if rows else "-"
    lines += [f"## Stage 4: test MWR per seed ({epochs} seeded test matches each, the same for all)", "",
              "| run | train seed | test MWR [95% CI] | wins | losses | draws |",
              "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {trial_group(r)} | {r['train_seed'] or '-'} | "
                     f"{_ci(float(r['test_mwr']), float(r['test_mwr_lo']), float(r['test_mwr_hi']))} | "
                     f"{r['n_win']} | {r['n_loss']} | {r['n_draw']} |")
    lines.append("")
    ablated = {_trial_group(t): t.name for t in protocol.ablation_trials()}
    cmp_path = out / "compare" / "compare.json"
    if cmp_path.exists():
        table = json.loads(cmp_path.read_text())
        pct = round(100 * table["confidence"])
        lines += ["## Stage 5: per algorithm across seeds (IQM, stratified bootstrap)", "",
                  f"| algorithm | seeds | per-seed test MWR | IQM [{pct}% CI] (mean of fewer than 5 runs) |",
                  "| --- | ---: | --- | ---: |"]
        for g in table["groups"]:
            if g["group"] in ablated:
                continue
            kind = " (baseline)" if g["group"] in ("passive", "random") else ""
            lines.append(f"| {g['group']}{kind} | {g['n_seeds']} | {' '.join(f'{s:+.3f}' for s in g['scores'])} | "
                         f"{_group_estimate(g)} |")
        lines += ["", "Plots: `compare/compare.png` (IQM by group), `evaluation/compare_mwr.png` (test curves), "
                  "`*/plots/` (training curves).", ""]
        lines += _ablation_section(table, ablated, pct)
    lines += _skill_section(protocol)
    if record.get("published"):
        lines += ["## Published into the zoo", "",
                  "| zoo name | algorithm | train seed | training MWR (picked by) | test MWR [95% CI] | file |",
                  "| --- | --- | ---: | ---: | ---: | --- |"]
        for p in record["published"]:
            if isinstance(p, str):  # a record written before the table
                lines.append(f"| - | - | - | - | - | `{p}` |")
                continue
            mwr = _ci(p["test_mwr"], p["test_mwr_lo"], p["test_mwr_hi"]) if "test_mwr" in p else "-"
            picked = f"{p['train_mwr']:+.3f}" if "train_mwr" in p else "-"
            lines.append(f"| `zoo:{p['name']}` | {p.get('algo', '-')} | {p.get('train_seed', '-')} | {picked} | "
                         f"{mwr} | `{p['file']}` |")
        lines.append("")
    lines += ["## Commands", "", "The whole protocol: `triplesumo reproduce "
              + " ".join(shlex.quote(a) for a in _argv(cfg)) + "`. Stage by stage:", "", "```bash"]
    for name, stage in record["stages"].items():
        if "done" not in stage:  # a stage still under way: its legs so far, no command yet
            continue
        lines.append(f"# {name} ({stage_seconds(stage):.0f} s, {stage['version']}, done {stage['done']})")
        lines += stage["commands"]
    lines += ["```", ""]
    return "\n".join(lines)


def _ablation_section(table: dict[str, Any], ablated: dict[str, str], pct: int) -> list[str]:
    """The ablations of the paper preset against it: IQM per change and P(change > preset)."""
    if not ablated:
        return []
    lines = ["## Ablations of the paper preset (DDPG Bug, one change each, same seeds and budget)", "",
             "Why: with a still punishment of -4 per step and gamma 0.99 the discounted cost of surviving is about the "
             "loss penalty, and OU noise reset per match stays small early in each match. The paper preset is kept "
             "as it is; these runs measure whether the choices matter.", "",
             f"| change | seeds | per-seed test MWR | IQM [{pct}% CI] | P(change > preset) [{pct}% CI] |",
             "| --- | ---: | --- | ---: | ---: |"]
    poi = {(p["x"], p["y"]): p for p in table["improvement"]}
    for g in table["groups"]:
        if g["group"] not in ablated:
            continue
        p = poi.get((g["group"], "ddpg"))
        vs = "-" if p is None else f"{p['poi']:.2f} [{p['lo']:.2f}, {p['hi']:.2f}]"
        change = g["group"].removeprefix("ddpg,")
        lines.append(f"| {change} | {g['n_seeds']} | {' '.join(f'{s:+.3f}' for s in g['scores'])} | "
                     f"{_group_estimate(g)} | {vs} |")
    return [*lines, ""]


def _evals(run: Path) -> list[dict[str, str]]:
    return _read_csv(run / "eval.csv")


def _skill_section(protocol: Protocol) -> list[str]:
    """Time to skill per algorithm and seed, from the evaluations the stage-4 runs made while training."""
    cfg, out = protocol.cfg, protocol.out
    if not cfg.bug_eval_every:
        return []
    runs = [(t, Path(t.config.out) / t.name) for t in protocol.bug_trials()]
    if not any(_evals(run) for _, run in runs):
        return []
    first = runs[0][0].config
    lines = ["## Time to skill", "",
             f"Env steps and training wall time (collection, learning, checkpoints; the evaluations apart), when the "
             f"policy was frozen, until "
             f"Bug's test MWR first reached {SKILL:+.2f}, from the evaluations stage 4 made while training: every "
             f"{first.eval_every:,} env steps, the current policy frozen on the first {first.eval_epochs} test "
             "matches of stage 5. Measured on the machine that ran each run, never projected; a resumed run adds "
             "the training times of its legs; it goes on with its replay buffer, or with an empty one from a "
             "checkpoint compacted of it (each resumed leg in its `legs.json` says which: `\"replay\"`).", "",
             "| run | reached | env steps | training wall time | evaluations | best test MWR (at env steps) |",
             "| --- | --- | ---: | ---: | ---: | ---: |"]
    for trial, run in runs:
        rows = _evals(run)
        if not rows:
            lines.append(f"| {trial.name} | not yet | - | - | 0 | - |")
            continue
        hit = next((r for r in rows if float(r["test_mwr"]) >= SKILL), None)
        best = max(rows, key=lambda r: float(r["test_mwr"]))
        top = f"{float(best['test_mwr']):+.3f} ({int(best['env_steps']):,})"
        if hit is None:  # not within the env steps and training time so far
            last = rows[-1]
            lines.append(f"| {trial.name} | {'no' if finished(trial) else 'not yet'} | > {int(last['env_steps']):,} | "
                         f"> {_duration(policy_seconds(last))} | {len(rows)} | {top} |")
        else:
            lines.append(f"| {trial.name} | yes | {int(hit['env_steps']):,} | "
                         f"{_duration(policy_seconds(hit))} | {len(rows)} | {top} |")
    plot = _plot_curves(runs, out / "bug" / "test_mwr.png")
    return [*lines, "", f"![test MWR while training]({plot.relative_to(out)})", ""]


def _duration(seconds: float) -> str:
    minutes = round(seconds / 60)
    return f"{minutes // 60} h {minutes % 60:02d} min" if minutes >= 60 else f"{seconds / 60:.1f} min"


def _plot_curves(runs: list[tuple[Trial, Path]], path: Path) -> Path:
    """Test MWR against env steps of every stage-4 run with evaluations, one line per seed and one colour per
    algorithm, against the paper's band and the +0.2 of time to skill."""
    from triplesumo.evaluation.plots import plot_evaluations, read_evaluations_csv

    evaluations, groups = {}, {}
    for trial, run in runs:
        columns = read_evaluations_csv(run / "eval.csv") if table_exists(run / "eval.csv") else None
        if columns is not None and len(columns["env_steps"]):
            evaluations[trial.name] = columns
            groups[trial.name] = trial.config.learners()["bug"]
    return plot_evaluations(evaluations, path, title="Bug, one line per seed", groups=groups, reference=SKILL)


def _argv(cfg: ReproduceConfig) -> list[str]:
    """The command-line options that make ``cfg``'s outputs (how it ran, :data:`RUN_OPTIONS`, left out)."""
    from triplesumo import _dcargs

    return _dcargs.to_argv(dataclasses.replace(cfg, **{k: getattr(ReproduceConfig(), k) for k in RUN_OPTIONS}))
