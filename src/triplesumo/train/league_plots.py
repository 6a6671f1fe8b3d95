"""Figures of a self-play league (``RUN/league/league.csv`` and its pool files), and :func:`league_demo`, a
league played by scripted learners without a trainer to show them."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from triplesumo.agents.builtin import BUILTIN
from triplesumo.agents.policy_file import load_json
from triplesumo.evaluation.metrics_csv import open_table, table_exists
from triplesumo.train.league import LOG_FILE, POOL_FILE, PRUNED_FILE, League, Snapshot
from triplesumo.train.league_config import LeagueConfig


def member_ticks(n: int, most: int = 24) -> list[int]:
    """Which of ``n`` member rows of the league plot get a label: all up to ``most``, else every k-th
    (the first and last always), so a league of a hundred snapshots stays readable."""
    if n <= most:
        return list(range(n))
    step = -(-(n - 1) // (most - 1))
    ticks = list(range(0, n, step))
    if n - 1 - ticks[-1] < step and len(ticks) > 1:  # closer to the last row's label than a line: they overlap
        ticks.pop()
    return sorted({*ticks, n - 1})


def spec_label(spec: str) -> str:
    """A seed's POLICY as the league plot labels it: a policy file by its last two path parts (``.../team-0120/ant``
    for another run's ``league/members/team-0120/ant``), so a long path does not crowd out the plot; a built-in or
    ``zoo:NAME`` as it is."""
    parts = Path(spec).parts
    return spec if len(parts) <= 2 else ".../" + "/".join(parts[-2:])


def member_labels(run_dir: Path) -> dict[str, str]:
    """``ID seed: POLICY`` of every seeded (``--league.zoo``) member of the run in ``run_dir``, by id, from
    ``RUN/league/pool.json`` (and ``pruned.json``, which keeps the records of members ``compact`` deleted).
    The i-th seeded member of a side holds the i-th entries its roles have in the config's zoo, as
    :meth:`League.seed` made it (a fork's entries come after the parent's); POLICY joins the roles'
    policies (:func:`spec_label`) with ``+``, or is one name where they agree. ``{}`` for a run without
    ``pool.json``."""
    root = Path(run_dir) / "league"
    if not (root / POOL_FILE).is_file():
        return {}
    state = load_json(root / POOL_FILE)
    per_role: dict[str, list[str]] = {}
    for entry in state.get("config", {}).get("zoo", []):
        role, _, spec = entry.partition("=")
        per_role.setdefault(role, []).append(spec)
    pruned = load_json(root / PRUNED_FILE)["members"] if (root / PRUNED_FILE).is_file() else []
    by_side: dict[str, list[dict[str, Any]]] = {}
    for m in (*pruned, *(m for pool in state["pools"].values() for m in (*pool["members"], *pool["evicted"]))):
        if m.get("source") == "zoo":
            by_side.setdefault(m["side"], []).append(m)
    roles = {m["side"]: list(m["policies"]) for pool in state["pools"].values() for m in pool["members"]}
    labels: dict[str, str] = {}
    for side, seeds in by_side.items():
        for i, m in enumerate(sorted(seeds, key=lambda m: int(m["id"].rsplit("-", 1)[1]))):
            specs = [per_role[r][i] if i < len(per_role.get(r, ())) else m.get("policies", {}).get(r, "?")
                     for r in roles.get(side, m.get("policies", ()))]
            labels[m["id"]] = f"{m['id']} seed: {'+'.join(dict.fromkeys(map(spec_label, specs)))}"
    return labels


def plot_league(run_dir: Path, path: Path | None = None) -> Path:
    """Plot ``RUN/league/league.csv`` (:func:`league_figure`) to ``RUN/plots/league.png``, or ``path`` when
    given; returns the path."""
    fig = league_figure(run_dir)
    out = Path(path) if path is not None else Path(run_dir) / "plots" / "league.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    fig.clear()
    return out


def league_figure(run_dir: Path) -> Any:
    """The figure of ``RUN/league/league.csv``: each learner's rating mu over epochs with its +- 1.96 sigma
    band (top) and the members its pool held (bottom; at most 24 snapshots labelled; seeded members,
    :func:`member_labels`, drawn as black crosses and always labelled with their policy; seeds in adjacent rows
    share one label of a line each)."""
    from matplotlib.figure import Figure

    log = Path(run_dir) / "league" / LOG_FILE
    if not table_exists(log):
        raise FileNotFoundError(f"{log}: no league log (a run without --self-play?)")
    with open_table(log) as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise ValueError(f"{log}: no rows yet")
    fig = Figure(figsize=(7.5, 6.0))
    ax, bx = fig.subplots(2, 1, sharex=True)
    rows_of_members: list[str] = []  # the members' rows on the lower axis, side by side, oldest first
    seeded = member_labels(Path(run_dir))
    for side in dict.fromkeys(r["side"] for r in rows):
        mine = [r for r in rows if r["side"] == side]
        epoch = np.array([int(r["epoch"]) for r in mine])
        mu = np.array([float(r["learner_mu"]) for r in mine])
        sigma = np.array([float(r["learner_sigma"]) for r in mine])
        # a learner never rated (its side does not learn): nan, or in logs before nan its prior throughout
        rated = np.isfinite(mu).any() and not (np.ptp(mu) == 0 and np.ptp(sigma) == 0 and len(mine) > 1)
        line = ax.plot(epoch, mu if rated else np.full(len(mine), np.nan), label=f"{side} learner" if rated
                       else "_")[0]
        if rated:
            ax.fill_between(epoch, mu - 1.96 * sigma, mu + 1.96 * sigma, color=line.get_color(), alpha=0.2)
        opp = np.array([float(r["mean_opponent_mu"]) for r in mine])
        if np.isfinite(opp).any():
            ax.plot(epoch, opp, linestyle="--", color=line.get_color(), alpha=0.7, label=f"{side} pool mean")
        ids = sorted({m for r in mine for m in r["members"].split()}, key=lambda m: int(m.rsplit("-", 1)[1]))
        held_by = [set(r["members"].split()) for r in mine]
        for m in ids:
            held = epoch[[m in members for members in held_by]]
            y = np.full(len(held), len(rows_of_members))
            if m in seeded:
                bx.scatter(held, y, s=14, marker="x", color="black", linewidths=0.8)
            else:
                bx.scatter(held, y, s=6, color=line.get_color())
            rows_of_members.append(m)
    gap = math.ceil(len(rows_of_members) / 48)  # half the spacing of the sampled labels (about half a line)
    groups: list[list[int]] = []  # seeds closer than a line apart (a fork's seeds sit side by side): one label
    for i in (i for i, m in enumerate(rows_of_members) if m in seeded):
        if groups and i - groups[-1][-1] < 2 * gap:
            groups[-1].append(i)
        else:
            groups.append([i])
    ticks = {sum(g) / len(g): "\n".join(seeded[rows_of_members[i]] for i in g) for g in groups}
    for i in member_ticks(len(rows_of_members)):  # sampled snapshots (a line: 2 gap), clear of k-line seed labels
        if all(abs(i - sum(g) / len(g)) >= gap * (len(g) + 1) for g in groups):
            ticks[i] = rows_of_members[i]
    bx.set_yticks(sorted(ticks), [ticks[y] for y in sorted(ticks)])
    ax.set_ylabel("rating mu (95% band)")
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    bx.set_xlabel("epoch")
    bx.set_ylabel("pool members")
    bx.tick_params(axis="y", labelsize=7)
    bx.grid(alpha=0.3)
    fig.tight_layout()
    return fig


DEMO_STAGES: dict[str, tuple[str, str]] = {"team": ("random", "passive"), "spider": ("random", "passive")}
"""The scripted learners of :func:`league_demo`: each side plays the first policy, then the second
(in the paper's match a passive quadruped out-stays a random one, which walks itself out)."""


def league_demo(run_dir: Path, epochs: int = 40, seed: int = 0, max_steps: int = 150,
                config: LeagueConfig | None = None, n_envs: int = 8) -> League:
    """A self-play league in the paper's 2-vs-1 without a trainer: scripted learners get stronger.

    Sides ``team`` (Ant and Bug) and ``spider``; each pool is seeded with random players.
    Epoch ``e`` is one match: the team learner against a Spider drawn from the spider pool on
    even epochs, the Spider learner against a team drawn from the team pool on odd ones. A
    learner plays :data:`DEMO_STAGES`' first policy before epoch ``epochs // 4`` and its second
    after (built-ins: a snapshot is admitted as its built-in names). Matches run through
    :func:`~triplesumo.evaluation.runner.play_matches`, ``snapshot_every`` at a time, each
    seeded by its epoch; the league is saved and plotted at the end.
    """
    import dataclasses

    from triplesumo.evaluation.runner import play_matches
    from triplesumo.rules.scenarios import scenario_config

    config = config or LeagueConfig(threshold=0.5, window=10, snapshot_every=10, max_size=4, draw_score=0.5,
                                    zoo=("ant=random", "bug=random", "spider=random"))
    league = League(run_dir, config, {"team": ("ant", "bug"), "spider": ("spider",)}, seed=seed)
    match_cfg = dataclasses.replace(scenario_config("paper"), max_steps=max_steps)
    order = ("ant", "bug", "spider")
    block = config.snapshot_every

    def learner_policies(side: str, epoch: int) -> dict[str, str]:
        spec = DEMO_STAGES[side][0 if epoch < epochs // 4 else 1]
        return {role: spec for role in league.pools[side].roles}

    for start in range(1, epochs + 1, block):
        chunk = list(range(start, min(start + block, epochs + 1)))
        plan: list[tuple[str, Snapshot, dict[str, str]]] = []
        for epoch in chunk:
            side, other = ("team", "spider") if epoch % 2 == 0 else ("spider", "team")
            plan.append((side, league.sample(other)[0], learner_policies(side, epoch)))
        lineups, seeds = [], [seed * 100_003 + epoch for epoch in chunk]
        for epoch, (_, opponent, mine) in zip(chunk, plan, strict=True):
            seated = league.policies(opponent, seed=seed + epoch) | {
                r: BUILTIN[s](seed + epoch) if s == "random" else BUILTIN[s]() for r, s in mine.items()}
            lineups.append([seated[a] for a in order])
        results = play_matches(lineups.__getitem__, seeds.__getitem__, len(chunk), match_cfg,
                               n_envs=min(n_envs, len(chunk)), n_threads=1)
        for epoch, (side, opponent, _), res in zip(chunk, plan, results, strict=True):
            if "error" in res.outcomes:
                continue
            team_player, spider_player = ((League.learner("team"), opponent.id) if side == "team"
                                          else (opponent.id, League.learner("spider")))
            league.record_seat_outcomes([team_player, team_player, spider_player], res.outcomes,
                                        [a.team for a in match_cfg.agents])
            for s in league.pools:
                if league.admit_due(s, epoch):
                    league.admit(s, epoch, builtin=learner_policies(s, epoch))
            league.epoch_end(epoch)
    league.save()
    plot_league(run_dir)
    return league
