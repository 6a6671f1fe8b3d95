"""Who leaves the ring, from where, after how many steps, and what one agent (the *focus*, by default Bug) did
before: a per-match account of seeded test matches, to tell how a policy wins and loses.

Each match is played to its end with one :class:`~triplesumo.envs.match.Match`, as
:func:`~triplesumo.evaluation.runner.play_match` plays it (match ``i`` resets with ``seed + i``, the seeds of
``triplesumo evaluate`` and of a training's evaluations), and watched step by step: the torso positions, and
which agents touch which (any contact between two agents' geoms after the step). :func:`exit_rows` gives one row
per match (:data:`COLUMNS`), :func:`summarize_exits` the shares over them. It reads a match under the
``first_out`` rules (the paper's: the match ends at the first exit); under ``elimination`` rules it describes the
last step only.

The row's words:

- ``first_out``: the agents whose torso centre left the ring on the match's last step, joined by ``+`` (two may
  leave on the same step), or ``none`` (the step limit: a draw).
- ``edge``: the ring edge each of them left through (``+x``, ``-x``, ``+y``, ``-y``: the coordinate past the
  half-size that is the furthest past it), joined by ``;``.
- ``pushed_by``: the agents that touched one who left within the last ``recent`` steps before the exit. An exit
  with nobody in ``pushed_by`` is a *self-exit*: that agent walked or fell out on its own.
- ``focus_*``: the focus agent's start and final distance from the centre (the square ring's ``max(|x|, |y|)``
  over the ring's half-size: 1 is the edge), the edge it is nearest at the end, how far its torso ended from
  where it started (``travel``) and the length of its path, the first step its torso was upside down
  (``flipped``, -1 for never) and how upright it ends (:func:`upright`); then for each other agent its first
  contact with it (step, -1 for never), steps in contact, and the mean and final distance between their torso
  centres.
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from triplesumo.envs.match import Match
from triplesumo.evaluation.runner import Policy
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.outcome import outcome_name

RECENT = 20
"""Steps before an exit in which a contact counts as a push (20 env steps: 1 s of simulated time)."""


def edge_of(x: float, y: float) -> str:
    """The edge a torso at ``(x, y)`` is past (or nearest to): the axis with the larger magnitude and its sign."""
    return ("+x" if x >= 0 else "-x") if abs(x) >= abs(y) else ("+y" if y >= 0 else "-y")


def upright(quat: np.ndarray) -> float:
    """The world-z component of a body's z axis from its quaternion ``(w, x, y, z)``: 1 upright, below 0 upside
    down."""
    _, x, y, _ = (float(q) for q in quat)
    return 1.0 - 2.0 * (x * x + y * y)


def geom_owners(match: Match) -> np.ndarray:
    """``(ngeom,)`` each geom's agent index in roster order, ``-1`` for the arena's geoms."""
    owner = np.full(match.model.ngeom, -1, dtype=np.int64)
    for k, agent in enumerate(match.sim.agents):
        owner[agent.geoms] = k
    return owner


def touching(match: Match, owner: np.ndarray) -> np.ndarray:
    """``(n, n)`` bool: which pairs of agents have a contact between their geoms now (symmetric)."""
    n = match.n_agents
    out = np.zeros((n, n), dtype=bool)
    ncon = match.data.ncon
    if ncon:
        geoms = match.data.contact.geom[:ncon]
        a, b = owner[geoms[:, 0]], owner[geoms[:, 1]]
        keep = (a >= 0) & (b >= 0) & (a != b)
        out[a[keep], b[keep]] = True
        out[b[keep], a[keep]] = True
    return out


def exit_row(policies: Mapping[str, Policy | None], seed: int, match: Match, focus: str = "bug",
             recent: int = RECENT, owner: np.ndarray | None = None) -> dict[str, Any]:
    """Play one match from ``reset(seed)`` (agents without a policy are passive) and account for it (one row of
    :data:`COLUMNS`)."""
    agents = list(match.agents)
    n, f = len(agents), agents.index(focus)
    owner = geom_owners(match) if owner is None else owner
    for k, name in enumerate(agents):
        reset = getattr(policies.get(name), "reset", None)
        if callable(reset):
            reset(seed=seed * 1000 + k + 1)
    obs, _ = match.reset(seed=seed)
    start = match.sim.torso_positions()[:, :2].copy()
    first_touch = np.full((n, n), -1, dtype=np.int64)
    last_touch = np.full((n, n), -1, dtype=np.int64)
    touch_steps = np.zeros((n, n), dtype=np.int64)
    dist_sum = np.zeros(n)
    path, flipped, prev = 0.0, -1, start[f].copy()
    while True:
        actions = np.zeros((n, match.action_width))
        for i, name in enumerate(agents):
            policy = policies.get(name)
            if policy is not None and match.alive[i]:
                actions[i, :match.action_sizes[i]] = match.check_action(name, policy(obs[i]))
        result = match.step_array(actions)
        obs, step = result.observations, match.steps
        touch = touching(match, owner)
        first_touch[touch & (first_touch < 0)] = step
        last_touch[touch] = step
        touch_steps += touch
        pos = match.sim.torso_positions()[:, :2]
        dist_sum += np.linalg.norm(pos - pos[f], axis=1)
        path += float(np.linalg.norm(pos[f] - prev))
        prev = pos[f].copy()
        if flipped < 0 and upright(match.sim.torso_quaternions()[f]) < 0:
            flipped = step
        if result.terminated or result.truncated:
            break
    infos = result.infos
    out = [i for i in range(n) if infos[i]["out_of_ring"]]
    pushers = sorted({agents[j] for i in out for j in range(n) if j != i and last_touch[i, j] > step - recent})
    row: dict[str, Any] = {
        "seed": seed, "outcome": outcome_name(infos[f]["outcome"]), "steps": step,
        "first_out": "+".join(agents[i] for i in out) or "none",
        "edge": ";".join(edge_of(*pos[i]) for i in out),
        "pushed_by": "+".join(pushers),
        "self_exit": bool(out) and not pushers,
        "focus_start_radius": round(float(np.abs(start[f]).max() / match.half_size), 4),
        "focus_end_radius": round(float(np.abs(pos[f]).max() / match.half_size), 4),
        "focus_edge": edge_of(*pos[f]),
        "focus_travel": round(float(np.linalg.norm(pos[f] - start[f])), 4),
        "focus_path": round(path, 4),
        "focus_flipped": flipped,
        "focus_end_upright": round(upright(match.sim.torso_quaternions()[f]), 4),
    }
    for j, other in enumerate(agents):
        if j == f:
            continue
        row[f"focus_first_touch_{other}"] = int(first_touch[f, j])
        row[f"focus_touch_steps_{other}"] = int(touch_steps[f, j])
        row[f"focus_mean_dist_{other}"] = round(float(dist_sum[j] / step), 4)
        row[f"focus_end_dist_{other}"] = round(float(np.linalg.norm(pos[j] - pos[f])), 4)
    return row


COLUMNS = ("seed", "outcome", "steps", "first_out", "edge", "pushed_by", "self_exit", "focus_start_radius",
           "focus_end_radius", "focus_edge", "focus_travel", "focus_path", "focus_flipped", "focus_end_upright")
"""The columns every row has; ``focus_first_touch_A``, ``focus_touch_steps_A``, ``focus_mean_dist_A`` and
``focus_end_dist_A`` follow for each other agent ``A`` in roster order."""


def exit_rows(policies: Mapping[str, Policy | None], n: int, seed: int, config: MatchConfig | None = None,
              focus: str = "bug", recent: int = RECENT) -> list[dict[str, Any]]:
    """Rows of :func:`exit_row` for matches ``0 .. n - 1`` (match ``i`` resets with ``seed + i``)."""
    match = Match(config)
    if focus not in match.agents:
        raise ValueError(f"focus must be one of {list(match.agents)}, got {focus!r}")
    unknown = [a for a in policies if a not in match.agents]
    if unknown:
        raise ValueError(f"policies for unknown agents {unknown}; agents are {list(match.agents)}")
    owner = geom_owners(match)
    return [exit_row(policies, seed + i, match, focus, recent, owner) for i in range(n)]


def summarize_exits(rows: Sequence[Mapping[str, Any]], agents: Sequence[str] = ("ant", "bug", "spider"),
                    focus: str = "bug", opponent: str = "spider", partner: str = "ant") -> dict[str, Any]:
    """Shares over the rows (fractions of all matches unless said): the team's MWR (the focus agent's wins minus
    losses, over all), who left first (an agent counts in every match it left in) and the median step it left
    at, the median step of the exits,
    each agent's self-exits, contacts with the opponent, the partner pushed out by the focus agent, the
    opponent pushed out with the focus agent among the pushers, the focus agent's mean distance to the opponent,
    its final distance from the centre, its steps in contact with the opponent, its path and how often it was
    upside down."""
    n = len(rows)
    if n == 0:
        raise ValueError("summarize_exits needs at least one row")

    def share(flags: Sequence[bool]) -> float:
        return round(sum(flags) / n, 4)

    def left(row: Mapping[str, Any], agent: str) -> bool:
        return agent in str(row["first_out"]).split("+")

    ended = [int(r["steps"]) for r in rows if r["first_out"] != "none"]
    touch = [int(r[f"focus_first_touch_{opponent}"]) for r in rows if int(r[f"focus_first_touch_{opponent}"]) >= 0]
    return {
        "matches": n,
        "mwr": round((sum(r["outcome"] == "win" for r in rows) - sum(r["outcome"] == "loss" for r in rows)) / n, 4),
        **{f"{a}_out": share([left(r, a) for r in rows]) for a in agents},
        **{f"median_step_{a}_out": _median([int(r["steps"]) for r in rows if left(r, a)]) for a in agents},
        "none_out": share([r["first_out"] == "none" for r in rows]),
        "median_exit_step": float(np.median(ended)) if ended else None,
        **{f"{a}_self_exit": share([left(r, a) and _true(r["self_exit"]) for r in rows]) for a in agents},
        f"{focus}_out_touched_by_{opponent}": share([left(r, focus) and opponent in str(r["pushed_by"]).split("+")
                                                     for r in rows]),
        f"{focus}_touched_{opponent}": share([int(r[f"focus_first_touch_{opponent}"]) >= 0 for r in rows]),
        f"median_first_touch_{opponent}": float(np.median(touch)) if touch else None,
        f"{focus}_pushed_{partner}_out": share([left(r, partner) and focus in str(r["pushed_by"]).split("+")
                                               for r in rows]),
        f"{focus}_pushed_{opponent}_out": share([left(r, opponent) and focus in str(r["pushed_by"]).split("+")
                                                for r in rows]),
        f"mean_dist_{opponent}": round(float(np.mean([float(r[f"focus_mean_dist_{opponent}"]) for r in rows])), 4),
        "median_end_radius": float(np.median([float(r["focus_end_radius"]) for r in rows])),
        f"median_touch_steps_{opponent}": float(np.median([int(r[f"focus_touch_steps_{opponent}"]) for r in rows])),
        "median_path": float(np.median([float(r["focus_path"]) for r in rows])),
        "flipped": share([int(r["focus_flipped"]) >= 0 for r in rows]),
    }


def _median(values: Sequence[float]) -> float | None:
    """The median, or None for no values."""
    return float(np.median(values)) if len(values) else None


def _true(value: Any) -> bool:
    """A row's boolean as played (``True``) or as read back from a CSV (``"True"``)."""
    return value is True or value == "True"


def write_rows(path: Path | str, rows: Sequence[Mapping[str, Any]], extra: Mapping[str, Any] | None = None) -> None:
    """Write rows (with the ``extra`` columns first, the same in every row) as a CSV table."""
    extra = dict(extra or {})
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=[*extra, *rows[0]])
        writer.writeheader()
        for row in rows:
            writer.writerow({**extra, **row})
