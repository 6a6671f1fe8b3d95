"""Run matches between fixed policies: one seeded match, optionally recorded."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from triplesumo.envs.match import Match
from triplesumo.evaluation.video import check_writable, write_mp4
from triplesumo.rules.config import MatchConfig
from triplesumo.rules.outcome import outcome_name
from triplesumo.sim.render import FrameRenderer

Policy = Callable[[np.ndarray], np.ndarray]


@dataclass
class MatchRecord:
    """What happened in one match, per agent in roster order."""

    outcomes: dict[str, str]
    """Each agent's side's result: win, loss, draw or error."""
    steps: int
    returns: dict[str, float]
    out_of_ring: list[str]
    terms: dict[str, dict[str, float]] = field(default_factory=dict)
    """Per agent, the sum over the match of each reward term and of dense/sparse reward."""
    frames: int = 0


def play_match(policies: Mapping[str, Policy], seed: int, config: MatchConfig | None = None,
               video: Path | None = None, width: int = 480, height: int = 480,
               match: Match | None = None) -> MatchRecord:
    """Play one match to its end; agents without a policy are passive.

    With ``video`` the match is rendered from the overview camera and written as mp4
    (one frame per env step, plus the start).
    """
    match = match or Match(config)
    unknown = [a for a in policies if a not in match.agents]
    if unknown:
        raise ValueError(f"policies for unknown agents {unknown}; agents are {list(match.agents)}")
    if video is not None:
        check_writable(Path(video))
    for k, name in enumerate(match.agents):
        reset = getattr(policies.get(name), "reset", None)
        if callable(reset):
            reset(seed=seed * 1000 + k + 1)
    obs, _ = match.reset(seed=seed)
    renderer = FrameRenderer(match.model, width, height) if video is not None else None
    frames = [renderer.render(match.data)] if renderer else []
    returns = dict.fromkeys(match.agents, 0.0)
    terms: dict[str, dict[str, float]] = {a: {} for a in match.agents}
    try:
        while True:
            actions = np.zeros((match.n_agents, 8))
            for i, name in enumerate(match.agents):
                policy = policies.get(name)
                if policy is not None:
                    actions[i] = match.check_action(name, policy(obs[i]))
            result = match.step_array(actions)
            obs = result.observations
            for i, name in enumerate(match.agents):
                returns[name] += float(result.rewards[i])
                for key, value in result.infos[i].items():
                    if key.startswith("reward_") or key in ("dense_reward", "sparse_reward"):
                        terms[name][key] = terms[name].get(key, 0.0) + value
            if renderer:
                frames.append(renderer.render(match.data))
            if result.terminated or result.truncated:
                break
    finally:
        if renderer:
            renderer.close()
    n_frames = write_mp4(frames, Path(video), fps=round(1.0 / match.sim.dt)) if video is not None else 0
    return MatchRecord(
        outcomes={a: outcome_name(result.infos[i]["outcome"]) for i, a in enumerate(match.agents)},
        steps=match.steps, returns=returns,
        out_of_ring=[a for i, a in enumerate(match.agents) if result.infos[i]["out_of_ring"]],
        terms=terms, frames=n_frames,
    )
