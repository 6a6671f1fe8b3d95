"""Can the time-to-skill screens tell their candidates apart? A pooled look at ``bench skill`` records.

``python benchmarks/skill_screens.py --record LABEL=FILE[@ALGO] [LABEL=FILE[@ALGO] ...] [--at 100000]
[--target 0.2] [--baseline LABEL] [--json OUT]``
reads ``bench skill`` records (``skill.json``, or the ``--json`` copy the docs keep), one label per candidate (a
label may name several files, e.g. seeds run apart), and takes from every seed of the record's learner (its only
one, or the one ``@ALGO`` names; a candidate may be another learner than SAC):

- its test MWR at the evaluation whose budget is ``--at`` env steps; a seed whose bench stopped earlier because it
  had reached ``--target`` (the bench ends a seed at its first evaluation at the target) has none there and is
  counted as *censored*: it enters the counts below but not the means;
- whether it reached ``--target`` at an evaluation of budget at most ``--at``.

Per candidate it gives the share of its seeds at the target by ``--at`` with its exact (Clopper-Pearson) 95%
interval, and from it the chance that the median of 3 fresh seeds reaches the target by ``--at`` (at least two of
three: ``3 p^2 - 2 p^3``, increasing in ``p``, so the interval's ends map to its ends): item 1's figure for that recipe.

It then asks whether the candidates differ by more than their seeds do: a one-way ANOVA of the values at ``--at``
over the candidates with at least two (``scipy.stats.f_oneway``), the pooled within-candidate standard deviation,
the between-candidate standard deviation by the method of moments for unequal groups (truncated at 0), and from the
pooled standard deviation the number of seeds per arm a two-sided 5% test needs to find a given lift with 80% power
(normal approximation: ``2 (z_0.975 + z_0.8)^2 σ^2 / Δ^2``). With ``--baseline LABEL`` it also pairs every candidate
with that label seed by seed (the same seed starts the same networks and warm-up under most candidates): the mean
difference per candidate, the standard deviation of the differences about it, and the pairs a paired test needs
(``(z_0.975 + z_0.8)^2 σ_d^2 / Δ^2``). Prints a table and, with ``--json``, writes it all.

A seed given twice for one label must carry the same curve (a bench repeats a seed exactly); two different curves
are refused, naming both files."""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

LIFTS = (0.05, 0.10, 0.15)
"""Lifts in test MWR the seed counts are given for."""


def seed_results(record: dict[str, Any], at: int, target: float, source: str,
                 algo: str | None = None) -> dict[int, dict[str, Any]]:
    """Per seed of one ``bench skill`` record's learner ``algo`` (None: the record's only one): ``value`` (test MWR
    at budget ``at``, None if censored), ``reached`` (at the target by ``at``), ``curve`` ((budget, test MWR)
    pairs) and ``source``."""
    algos = record.get("algos") if isinstance(record, dict) else None
    if not isinstance(algos, dict) or not algos:
        raise ValueError(f"{source}: not a bench skill record (no algos)")
    if algo is None:
        if len(algos) > 1:
            raise ValueError(f"{source}: holds {', '.join(algos)}; name one as FILE@ALGO")
        algo = next(iter(algos))
    try:
        runs = algos[algo]["runs"]
    except (KeyError, TypeError):
        raise ValueError(f"{source}: no runs of {algo} (the record holds {', '.join(algos)})") from None
    out = {}
    for run in runs:
        curve = [(int(e["budget"]), float(e["test_mwr"])) for e in run["evaluations"]]
        by_at = [m for b, m in curve if b == at]
        reached = any(b <= at and m >= target for b, m in curve)
        if by_at:
            value: float | None = by_at[0]
        elif reached and curve[-1][0] < at:
            value = None  # stopped at its first evaluation at the target, before `at`
        else:
            raise ValueError(f"{source}: seed {run['seed']} has no evaluation at {at:,} env steps and did not "
                             f"reach {target:+.2f} before it (budgets {[b for b, _ in curve]})")
        out[int(run["seed"])] = {"value": value, "reached": reached, "curve": curve, "source": source}
    return out


def gather(records: list[tuple[str, Path, str | None]], at: int,
           target: float) -> dict[str, dict[int, dict[str, Any]]]:
    """``{label: {seed: seed_results}}`` over every (label, file, learner or None) triple, in the order given."""
    out: dict[str, dict[int, dict[str, Any]]] = {}
    for label, path, algo in records:
        try:
            record = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{path}: cannot read a bench skill record ({e})") from None
        seeds = out.setdefault(label, {})
        for seed, result in seed_results(record, at, target, str(path), algo).items():
            if seed in seeds and seeds[seed]["curve"] != result["curve"]:
                raise ValueError(f"{label}: seed {seed} has two different curves, in {seeds[seed]['source']} and "
                                 f"{path}")
            seeds.setdefault(seed, result)
    return out


def seeds_per_arm(sd: float, lift: float, alpha: float = 0.05, power: float = 0.8, paired: bool = False) -> int:
    """Seeds per arm for a two-sided two-sample test at ``alpha`` to find ``lift`` with ``power``, normal
    approximation, standard deviation ``sd`` in both arms; ``paired``: pairs for a paired test whose differences
    have standard deviation ``sd``."""
    from scipy.stats import norm

    z = norm.ppf(1 - alpha / 2) + norm.ppf(power)
    return math.ceil((1 if paired else 2) * z * z * sd * sd / (lift * lift))


def pooled_variance(groups: list[np.ndarray]) -> float:
    """The groups' squared deviations about their own means, over their degrees of freedom (sum of n_i - 1)."""
    return float(sum(((g - g.mean()) ** 2).sum() for g in groups)) / sum(len(g) - 1 for g in groups)


def paired(results: dict[str, dict[int, dict[str, Any]]], baseline: str) -> dict[str, Any]:
    """Each candidate against ``baseline`` on the seeds both have values for: the mean difference per candidate, and
    the pooled standard deviation of the differences about their candidate's mean (candidates with two pairs or
    more), with the pairs a paired two-sided 5% test with 80% power needs per lift."""
    if baseline not in results:
        raise ValueError(f"baseline {baseline!r} is not one of the labels {sorted(results)}")
    base = {k: s["value"] for k, s in results[baseline].items() if s["value"] is not None}
    diffs = {label: [s["value"] - base[k] for k, s in seeds.items() if s["value"] is not None and k in base]
             for label, seeds in results.items() if label != baseline}
    out: dict[str, Any] = {"baseline": baseline,
                           "mean_difference": {lbl: float(np.mean(d)) if d else None for lbl, d in diffs.items()}}
    groups = [np.array(d) for d in diffs.values() if len(d) >= 2]
    if groups:
        sd = math.sqrt(pooled_variance(groups))
        out |= {"pairs": int(sum(len(g) for g in groups)), "difference_sd": sd,
                "pairs_needed": {f"{lift:.2f}": seeds_per_arm(sd, lift, paired=True) for lift in LIFTS}}
    return out


def median_of_three(p: float) -> float:
    """The chance that at least two of three independent seeds, each at the target with chance ``p``, are: the
    median of three seeds' env steps to the target is then within the budget."""
    return 3 * p * p - 2 * p ** 3


def reach_share(reached: int, n: int) -> dict[str, Any]:
    """``reached`` of ``n`` seeds: the share, its exact 95% interval, and :func:`median_of_three` at each."""
    from scipy.stats import binomtest

    ci = binomtest(reached, n).proportion_ci(confidence_level=0.95, method="exact")
    share, lo, hi = reached / n, float(ci.low), float(ci.high)
    return {"share": share, "ci": [lo, hi], "median_of_3": median_of_three(share),
            "median_of_3_ci": [median_of_three(lo), median_of_three(hi)]}


def analyse(results: dict[str, dict[int, dict[str, Any]]]) -> dict[str, Any]:
    """Per-candidate rows and the pooled statistics (see the module's doc)."""
    from scipy.stats import f_oneway

    rows = []
    for label, seeds in results.items():
        values = [s["value"] for s in seeds.values() if s["value"] is not None]
        reached = sum(s["reached"] for s in seeds.values())
        rows.append({"candidate": label, "seeds": sorted(seeds), "values": {k: s["value"] for k, s in seeds.items()},
                     "reached": reached, "n": len(seeds), "censored": sum(s["value"] is None for s in seeds.values()),
                     "mean": float(np.mean(values)) if values else None, "reach": reach_share(reached, len(seeds))})
    groups = [np.array([v for v in r["values"].values() if v is not None]) for r in rows]
    groups = [g for g in groups if len(g) >= 2]
    pooled: dict[str, Any] = {"candidates": len(groups), "values": int(sum(len(g) for g in groups))}
    if len(groups) >= 2:
        n_i = np.array([len(g) for g in groups], float)
        big_n, k = n_i.sum(), len(groups)
        grand = np.concatenate(groups).mean()
        ssb = float(sum(len(g) * (g.mean() - grand) ** 2 for g in groups))
        msw, msb = pooled_variance(groups), ssb / (k - 1)
        n0 = (big_n - (n_i ** 2).sum() / big_n) / (k - 1)
        test = f_oneway(*groups)
        within = math.sqrt(msw)
        pooled |= {"f": float(test.statistic), "p": float(test.pvalue), "within_sd": within,
                   "between_sd": math.sqrt(max(0.0, (msb - msw) / n0)), "grand_mean": float(grand),
                   "seeds_per_arm": {f"{lift:.2f}": seeds_per_arm(within, lift) for lift in LIFTS}}
    pooled |= {"runs": sum(r["n"] for r in rows), "reached": sum(r["reached"] for r in rows)}
    return {"rows": rows, "pooled": pooled}


def format_table(result: dict[str, Any], at: int, target: float) -> str:
    """The printed table."""
    lines = [f"test MWR at {at:,} env steps per seed (c: stopped earlier at {target:+.2f}); reached: seeds at "
             f"{target:+.2f} by {at:,}, and their share with its 95% interval; 3-seed median: the chance that the "
             f"median of 3 fresh seeds is at {target:+.2f} by {at:,}", "",
             f"{'candidate':28s} {'seeds':>5s} {'reached':>7s} {'share (95%)':>17s} {'3-seed median':>19s} "
             f"{'mean':>7s}  values"]
    for r in result["rows"]:
        values = " ".join(f"s{k}:{'c' if v is None else f'{v:+.3f}'}" for k, v in sorted(r["values"].items()))
        mean = "-" if r["mean"] is None else f"{r['mean']:+.3f}"
        q = r["reach"]
        share = f"{q['share']:.2f} ({q['ci'][0]:.2f}-{q['ci'][1]:.2f})"
        med = f"{q['median_of_3']:.2f} ({q['median_of_3_ci'][0]:.2f}-{q['median_of_3_ci'][1]:.2f})"
        lines.append(f"{r['candidate']:28s} {r['n']:5d} {r['reached']:7d} {share:>17s} {med:>19s} {mean:>7s}  "
                     f"{values}")
    p = result["pooled"]
    lines.append("")
    lines.append(f"{p['reached']} of {p['runs']} seeds reached {target:+.2f} by {at:,}")
    if "f" in p:
        lines.append(f"one-way ANOVA over {p['candidates']} candidates with >= 2 values ({p['values']} values): "
                     f"F = {p['f']:.2f}, p = {p['p']:.2f}")
        lines.append(f"within-candidate SD {p['within_sd']:.3f}, between-candidate SD {p['between_sd']:.3f} "
                     f"(method of moments, truncated at 0), grand mean {p['grand_mean']:+.3f}")
        lines.append("seeds per arm for a two-sided 5% test with 80% power: " + ", ".join(
            f"lift {lift}: {n}" for lift, n in p["seeds_per_arm"].items()))
    q = result.get("paired")
    if q and "difference_sd" in q:
        lines.append(f"paired with {q['baseline']} on the same seed ({q['pairs']} pairs): SD of the differences "
                     f"{q['difference_sd']:.3f}; pairs needed: " + ", ".join(
                         f"lift {lift}: {n}" for lift, n in q["pairs_needed"].items()))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--record", nargs="+", required=True, metavar="LABEL=FILE[@ALGO]",
                        help="a candidate's label and one of its bench skill records (repeat a label for more "
                             "files); @ALGO picks the learner of a record that holds several")
    parser.add_argument("--at", type=int, default=100_000, help="env-step budget of the evaluation compared")
    parser.add_argument("--target", type=float, default=0.2, help="test MWR of skill")
    parser.add_argument("--baseline", help="also compare every candidate with this label on the same seeds")
    parser.add_argument("--json", type=Path, help="write the result here too")
    args = parser.parse_args(argv)
    records = []
    for item in args.record:
        label, sep, file = item.partition("=")
        file, at_sign, algo = file.partition("@")
        if not sep or not label or not file or (at_sign and not algo):
            parser.error(f"--record takes LABEL=FILE or LABEL=FILE@ALGO, got {item!r}")
        records.append((label, Path(file), algo or None))
    try:
        results = gather(records, args.at, args.target)
    except ValueError as e:
        parser.error(str(e))
    result = analyse(results) | {"at": args.at, "target": args.target,
                                 "records": [[lbl, str(f) + (f"@{a}" if a else "")] for lbl, f, a in records]}
    if args.baseline:
        try:
            result["paired"] = paired(results, args.baseline)
        except ValueError as e:
            parser.error(str(e))
    print(format_table(result, args.at, args.target))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
