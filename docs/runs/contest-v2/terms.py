"""Per-step velocity terms and outcomes of each learner of a run, per window of epochs (docs/CONTEST.md, "Why the
Spider does not push"). Usage: python3 terms.py RUN_DIR [WINDOW]"""
import csv
import sys
from collections import Counter
from pathlib import Path


def per_step(part: list[dict[str, str]], term: str) -> float:
    """Mean over the window's matches of a reward term per step."""
    return sum(float(r[term]) / int(r["steps"]) for r in part) / len(part)


def main() -> None:
    run, window = Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 500
    for table in sorted(run.glob("metrics*.csv")):
        rows = list(csv.DictReader(table.open()))
        print(table.name)
        for lo in range(0, len(rows), window):
            part = rows[lo:lo + window]
            counts = Counter(r["outcome"] for r in part)
            print(f"  epochs {lo + 1:>5}-{lo + len(part):<5} per step: "
                  f"opponent {per_step(part, 'reward_opponent_velocity'):+.3f} "
                  f"self {per_step(part, 'reward_self_velocity'):+.3f} "
                  f"partner {per_step(part, 'reward_partner_velocity'):+.3f}  "
                  f"W/L/D {counts['win']}/{counts['loss']}/{counts['draw']}  "
                  f"steps {sum(int(r['steps']) for r in part) / len(part):.0f}")


if __name__ == "__main__":
    main()
