"""Who leaves the ring, from where, after how many steps, for Bug policies in the bench skill match.

``python benchmarks/skill_diagnosis.py --policy LABEL=SPEC ... --out DIR`` plays each Bug policy (a policy file
stem, ``zoo:NAME`` or ``passive``) on the test matches of ``triplesumo bench skill`` (``--epochs`` 200 starts,
test match ``i`` reset with ``--seed`` 10000 + i, the match and the other agents' policies of the bench's
default ``TrainConfig``: ``zoo:ant`` and ``zoo:spider``, or another pair's with ``--pair``) and writes
``DIR/LABEL.csv`` (one row per match: :func:`triplesumo.evaluation.exits.exit_row`) and ``DIR/summary.json``
(:func:`~triplesumo.evaluation.exits.summarize_exits` per label, kept across calls), and prints the summary as a
Markdown table.

``--snapshots PNG`` plays nothing: it reads ``DIR/summary.json``, groups the labels named ``GROUP-ENVSTEPS`` (policies
of one run taken at several env steps), and writes each group's test MWR against env steps to ``PNG`` and each group's
mean, standard deviation, range and share at or above ``--target`` to ``DIR/snapshots.json``: how much the test MWR
moves between neighbouring policies of one run on the same starts."""
from __future__ import annotations

import argparse
import csv
import json
import statistics
import time
import warnings
from pathlib import Path

from triplesumo.agents.zoo import make_policy, policies_from_pairs
from triplesumo.evaluation.exits import exit_rows, summarize_exits, write_rows
from triplesumo.train.config import TrainConfig

KEYS = ("mwr", "bug_out", "ant_out", "spider_out", "none_out", "median_exit_step", "median_step_bug_out",
        "bug_self_exit", "bug_out_touched_by_spider", "bug_touched_spider", "median_first_touch_spider",
        "bug_pushed_ant_out",
        "bug_pushed_spider_out", "mean_dist_spider", "median_end_radius", "median_touch_steps_spider", "median_path",
        "flipped")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--policy", nargs="*", action="extend", default=[], help="LABEL=SPEC Bug policies (SPEC: "
                        "file stem, zoo:NAME or passive); --policy may be given more than once")
    parser.add_argument("--summarize", action="store_true", help="rebuild summary.json from every OUT/LABEL.csv "
                        "(nothing is played)")
    parser.add_argument("--epochs", type=int, default=200, help="test matches per policy")
    parser.add_argument("--seed", type=int, default=10_000, help="test match i resets with seed + i")
    parser.add_argument("--out", required=True, help="folder of LABEL.csv and summary.json")
    parser.add_argument("--pair", nargs="*", default=None, metavar="AGENT=SPEC",
                        help="the other agents' policies (default: the bench's, zoo:ant and zoo:spider), e.g. "
                        "ant=docs/runs/scratch-v2/seed-1/ant/screens/policy-4000 to diagnose another pair")
    parser.add_argument("--snapshots", metavar="PNG", default=None, help="plot the test MWR of the GROUP-ENVSTEPS "
                        "labels of OUT/summary.json against env steps, one line per group, and write "
                        "OUT/snapshots.json (nothing is played)")
    parser.add_argument("--target", type=float, default=0.2, help="the test MWR snapshots.json counts shares at")
    args = parser.parse_args(argv)
    if args.snapshots:
        return snapshots(Path(args.out), Path(args.snapshots), args.target)
    warnings.simplefilter("ignore")
    import torch

    torch.set_num_threads(1)
    cfg = TrainConfig()
    match_cfg = cfg.match_config()
    others = policies_from_pairs(tuple(args.pair) if args.pair else cfg.policies, args.seed, cfg.obs_mode)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "summary.json"
    summary = json.loads(path.read_text()) if path.is_file() else {}
    if args.summarize:
        for table in sorted(out.glob("*.csv")):
            with open(table, newline="") as fh:
                rows = list(csv.DictReader(fh))
            kept = {k: summary.get(table.stem, {}).get(k) for k in ("spec", "seconds")}
            summary[table.stem] = {**kept, **summarize_exits(rows)}
        path.write_text(json.dumps(summary, indent=2) + "\n")
    for item in args.policy:
        label, spec = item.split("=", 1)
        bug = None if spec == "passive" else make_policy(spec, expect_obs_mode=cfg.obs_mode, frozen=True)
        t0 = time.perf_counter()
        rows = exit_rows({**others, "bug": bug}, args.epochs, args.seed, match_cfg)
        write_rows(out / f"{label}.csv", rows, {"policy": label})
        summary[label] = {"spec": spec, "seconds": round(time.perf_counter() - t0, 1), **summarize_exits(rows)}
        path.write_text(json.dumps(summary, indent=2) + "\n")
        print(f"{label}: {summary[label]['seconds']} s", flush=True)
    print("| policy | " + " | ".join(KEYS) + " |")
    print("|" + " --- |" * (len(KEYS) + 1))
    for label, s in summary.items():
        print(f"| {label} | " + " | ".join(str(s[k]) for k in KEYS) + " |")
    return 0


def snapshot_groups(summary: dict[str, dict]) -> dict[str, list[tuple[int, float]]]:
    """``(env_steps, test MWR)`` of every ``GROUP-ENVSTEPS`` label, by group, in env-step order."""
    groups: dict[str, list[tuple[int, float]]] = {}
    for label, entry in summary.items():
        group, _, steps = label.rpartition("-")
        if group and steps.isdigit():
            groups.setdefault(group, []).append((int(steps), float(entry["mwr"])))
    if not groups:
        raise ValueError("no label of the form GROUP-ENVSTEPS in the summary")
    return {group: sorted(points) for group, points in sorted(groups.items())}


def snapshots(out: Path, png: Path, target: float) -> int:
    path = out / "summary.json"
    if not path.is_file():
        raise SystemExit(f"{path}: no summary to read (play the policies first)")
    groups = snapshot_groups(json.loads(path.read_text()))
    stats = {}
    for group, points in groups.items():
        mwr = [m for _, m in points]
        stats[group] = {"policies": len(points), "env_steps": [e for e, _ in points], "mwr": mwr,
                        "mean": round(statistics.fmean(mwr), 4),
                        "sd": round(statistics.stdev(mwr), 4) if len(mwr) > 1 else None,
                        "min": min(mwr), "max": max(mwr), "target": target,
                        "share_at_target": round(sum(m >= target for m in mwr) / len(mwr), 4)}
    (out / "snapshots.json").write_text(json.dumps(stats, indent=2) + "\n")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    for group, points in groups.items():
        ax.plot([e for e, _ in points], [m for _, m in points], marker="o", label=group)
    ax.axhline(target, color="grey", linestyle="--", linewidth=1, label=f"target {target:+.2f}")
    ax.set_xlabel("env steps of the policy")
    ax.set_ylabel("test MWR (same starts)")
    ax.legend(fontsize="small")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110)
    print("| group | policies | mean | sd | min | max | share at target |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for group, st in stats.items():
        print(f"| {group} | {st['policies']} | {st['mean']:+.3f} | {st['sd']} | {st['min']:+.3f} | {st['max']:+.3f} "
              f"| {st['share_at_target']:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
