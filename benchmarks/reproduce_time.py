"""Where a reproduction's wall time goes, and what each of its levers saved, from a finished folder's own records.

``python benchmarks/reproduce_time.py FOLDER ... [--json FILE]`` reads each reproduction folder (``reproduce.json``,
``ROLE/screens.json``, the Bug runs' ``eval.csv``) and prints one Markdown row per folder:

* **stage 1, side by side**: the two sides' own time (every leg's training and screen, ``screens.json``) one after
  the other, against the stage's wall time with ``--sides-at-once`` (``reproduce.json``);
* **screens**: the screens' share of the sides' own time (what screening every 1,000 epochs costs);
* **Bug evaluations**: the share of the Bug runs' time spent in their evaluations while training (every 100,000 env
  steps on 200 test starts, inline: ``eval_seconds`` against ``train_seconds`` of each run's last ``eval.csv``
  row), what evaluations in the background would overlap on a spare core;
* **Bugs at once**: the Bug runs' own time (training and evaluations) one after the other, against the stage's wall
  time (two at a time on the 2-core boxes, ``--ray --num-cpus 2``);
* the contest's and the test's wall time.

Measured on the machines that ran them (each folder's ``reproduce.json`` names them), under whatever else those
shared boxes ran: ratios within one folder, never across folders. Nothing is played again."""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path
from typing import Any


def levers(folder: Path) -> dict[str, Any]:
    """The time facts of one finished reproduction folder (see the module's docstring); None where the folder has no
    such stage (a reproduction from ``--pair`` has no stage 1)."""
    record = json.loads((folder / "reproduce.json").read_text())
    # a stage's wall time is the sum of its legs; a record written before legs kept only the invocation that
    # finished it, which leaves out the others: not recorded
    stages = {name: entry for name, entry in record["stages"].items() if entry.get("legs")}
    facts: dict[str, Any] = {"folder": str(folder), "machines": sorted({r["machine"]["cpu"] for r in record["runs"]
                                                                        if r.get("machine")}),
                             "contest_seconds": stages.get("contest", {}).get("seconds"),
                             "test_seconds": stages.get("evaluation", {}).get("seconds")}
    sides = {}
    for role in ("ant", "spider"):
        path = folder / role / "screens.json"
        if path.exists():
            screens = json.loads(path.read_text())["screens"]
            sides[role] = {"train_seconds": sum(s["train_seconds"] for s in screens),
                           "screen_seconds": sum(s["screen_seconds"] for s in screens)}
    if sides:
        own = sum(s["train_seconds"] + s["screen_seconds"] for s in sides.values())
        wall = stages.get("ant", {}).get("seconds")
        facts["stage1"] = {"sides": sides, "one_after_other_seconds": round(own, 1), "wall_seconds": wall,
                           "side_by_side_speedup": round(own / wall, 2) if wall else None,
                           "screen_share": round(sum(s["screen_seconds"] for s in sides.values()) / own, 3)}
    else:
        facts["stage1"] = None
    runs = {}
    for path in sorted((folder / "bug").glob("*/eval.csv")):
        with open(path, newline="") as fh:
            last = list(csv.DictReader(fh))[-1]
        runs[path.parent.name] = {"train_seconds": float(last["train_seconds"]),
                                  "eval_seconds": float(last["eval_seconds"])}
    own = sum(r["train_seconds"] + r["eval_seconds"] for r in runs.values())
    wall = stages.get("bug", {}).get("seconds")
    facts["bug"] = {"runs": runs, "one_after_other_seconds": round(own, 1), "wall_seconds": wall,
                    "at_once_speedup": round(own / wall, 2) if wall else None,
                    "eval_share": round(sum(r["eval_seconds"] for r in runs.values()) / own, 3)}
    return facts


def hours(seconds: float | None) -> str:
    if seconds is None:
        return "not recorded"
    minutes = round(seconds / 60)
    return f"{minutes // 60} h {minutes % 60:02d} min" if minutes >= 60 else f"{seconds / 60:.1f} min"


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| folder | stage 1: sides one after the other / side by side (speed-up) | screens' share of stage 1 "
             "| Bugs one after the other / at once (speed-up) | evaluations' share of the Bugs | contest | test |",
             "| --- | --- | ---: | --- | ---: | ---: | ---: |"]
    for f in rows:
        s1, bug = f["stage1"], f["bug"]
        side = "(given pair)"
        if s1:
            side = f"{hours(s1['one_after_other_seconds'])} / {hours(s1['wall_seconds'])}" + (
                f" ({s1['side_by_side_speedup']:.2f}x)" if s1["wall_seconds"] else "")
        screens = f"{s1['screen_share']:.1%}" if s1 else "-"
        at_once = f" ({bug['at_once_speedup']:.2f}x)" if bug["wall_seconds"] else ""
        lines.append(f"| {f['folder']} | {side} | {screens} | "
                     f"{hours(bug['one_after_other_seconds'])} / {hours(bug['wall_seconds'])}{at_once} | "
                     f"{bug['eval_share']:.1%} | {hours(f['contest_seconds'])} | {hours(f['test_seconds'])} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="finished reproduction folders")
    parser.add_argument("--json", type=Path, help="also write the facts as JSON to this file")
    args = parser.parse_args(argv)
    for folder in args.folders:
        if not (folder / "reproduce.json").is_file():
            parser.error(f"{folder}: no reproduce.json (not a reproduction folder)")
    rows = [levers(folder) for folder in args.folders]
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
