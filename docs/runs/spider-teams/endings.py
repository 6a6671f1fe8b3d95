"""How a Spider's losses and draws end: replay an evaluation's non-wins and look at each one.

    python docs/runs/spider-teams/endings.py docs/runs/spider-teams/passive trained \
        docs-runs-spider-teams-policies-v1bzs-spider --out docs/runs/spider-teams/passive/endings.json

FOLDER is a ``triplesumo evaluate --learner spider`` folder (its ``evaluation.json`` names the team's
policies, the seed and the match config; ``CANDIDATE/metrics.csv`` one row per start). For every loss
and draw of each named candidate, the start (``seed + epoch - 1``) is played again, one match at a
time, with the same policies; the replay must end as its row did (outcome and length), else the
script stops naming the epoch. Per ending it records:

- ``reached``: the Spider's torso came within ``--reach`` metres (1.0) of an opponent's torso at some
  step (torso centres; a quadruped's legs span about 0.8 m);
- ``still``: the Spider's torso moved less than ``--still-distance`` (0.05 m) over the last
  ``--still-steps`` (50) steps of the match.

Prints a table per candidate (wins from the row counts, losses after or without reaching an opponent,
draws, draws standing still) and writes it as JSON (``--out``; candidates already in that file, made
from the same folder with the same settings, are kept beside the new ones).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

from triplesumo.agents.zoo import policies_from_pairs
from triplesumo.envs.match import Match
from triplesumo.model.specs import PhysicsConfig
from triplesumo.rules.outcome import outcome_name
from triplesumo.rules.scenarios import scenario_config


def replay(match: Match, policies: dict[str, object], seed: int) -> tuple[str, int, np.ndarray]:
    """Play the start ``seed``: the Spider's outcome, the match length and every agent's torso xy per step
    (``(steps + 1, n_agents, 2)``, the start included)."""
    obs, _ = match.reset(seed=seed)
    lineup = [policies[name] for name in match.agents]
    spider = match.agents.index("spider")
    track = [match.sim.torso_positions()[:, :2].copy()]
    while True:
        actions = np.zeros((match.n_agents, match.action_width))
        for i, policy in enumerate(lineup):
            actions[i, :match.action_sizes[i]] = match.check_action(match.agents[i], policy(obs[i]))  # type: ignore[operator]
        result = match.step_array(actions)
        obs = result.observations
        track.append(match.sim.torso_positions()[:, :2].copy())
        if result.terminated or result.truncated:
            return outcome_name(int(result.infos[spider]["outcome"])), match.steps, np.array(track)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="an evaluate --learner spider output folder")
    parser.add_argument("candidates", nargs="+", help="candidate folder names inside FOLDER (e.g. trained)")
    parser.add_argument("--reach", type=float, default=1.0)
    parser.add_argument("--still-steps", type=int, default=50)
    parser.add_argument("--still-distance", type=float, default=0.05)
    parser.add_argument("--out", type=Path, default=None, help="JSON file for the table")
    parser.add_argument("--limit", type=int, default=0, help="replay only the first N losses and draws (a check)")
    args = parser.parse_args(argv)

    record = json.loads((args.folder / "evaluation.json").read_text())
    depends = record["rows_depend_on"]
    if depends["learner"] != "spider":
        raise SystemExit(f"{args.folder}: an evaluation of {depends['learner']!r}, not of the Spider")
    cfg = scenario_config("paper", max_steps=depends["steps_per_epoch"], obs_mode=depends["obs_mode"],
                          physics=PhysicsConfig(**depends["physics"]))
    match = Match(cfg)
    sizes = dict(zip(match.agents, match.action_sizes, strict=True))
    table: dict[str, dict[str, object]] = {}
    for name in args.candidates:
        if name not in record["candidates"]:
            raise SystemExit(f"{args.folder}: no candidate {name!r}; it has {sorted(record['candidates'])}")
        pairs = (*depends["policies"], f"spider={record['candidates'][name]['policy']}")
        policies = policies_from_pairs(pairs, depends["seed"], depends["obs_mode"], obs_dims=match.observer.sizes,
                                       action_sizes=sizes)
        with (args.folder / name / "metrics.csv").open(newline="") as fh:
            rows = list(csv.DictReader(fh))
        counts = {"wins": sum(r["outcome"] == "win" for r in rows), "losses_reached": 0, "losses_not_reached": 0,
                  "draws": 0, "draws_still": 0}
        spider = match.agents.index("spider")
        opponents = [i for i in range(match.n_agents) if i != spider]
        others = [r for r in rows if r["outcome"] != "win"]
        for row in others[:args.limit] if args.limit else others:
            epoch = int(row["epoch"])
            outcome, steps, track = replay(match, policies, depends["seed"] + epoch - 1)
            if (outcome, steps) != (row["outcome"], int(row["steps"])):
                raise SystemExit(f"{name} epoch {epoch}: the replay ended {outcome} at step {steps}, the row says "
                                 f"{row['outcome']} at step {row['steps']} (not the evaluation's code or policies?)")
            gap = np.linalg.norm(track[:, opponents] - track[:, [spider]], axis=-1).min()
            if outcome == "loss":
                counts["losses_reached" if gap < args.reach else "losses_not_reached"] += 1
            else:
                counts["draws"] += 1
                moved = np.linalg.norm(track[-1, spider] - track[-1 - args.still_steps, spider])
                counts["draws_still"] += int(moved < args.still_distance)
        table[name] = {"policy": record["candidates"][name]["policy"], "matches": len(rows), **counts}
        print(f"{name}: " + ", ".join(f"{k} {v}" for k, v in table[name].items()), flush=True)
    if args.out is not None:  # candidates already in the file under the same folder and settings are kept
        settings = {"reach": args.reach, "still_steps": args.still_steps, "still_distance": args.still_distance}
        before = json.loads(args.out.read_text()) if args.out.is_file() else {}
        if before and (before["folder"], before["settings"]) != (str(args.folder), settings):
            raise SystemExit(f"{args.out}: made for {before['folder']} with {before['settings']}; choose another --out")
        table = {**before.get("candidates", {}), **table}
        args.out.write_text(json.dumps({"folder": str(args.folder), "settings": settings, "candidates": table},
                                       indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
