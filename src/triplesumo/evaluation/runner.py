"""Run matches between fixed policies: one seeded match, optionally filmed and recorded."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from triplesumo.envs.match import Match
from triplesumo.evaluation.recording import MatchRecorder
from triplesumo.evaluation.video import check_writable, write_mp4
from triplesumo.rules.config import MatchConfig
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
    places: dict[str, int] = field(default_factory=dict)
    """Each agent's final place (1 = winner; 0 if the match ended in a physics error)."""


def play_match(policies: Mapping[str, Policy], seed: int, config: MatchConfig | None = None,
               video: Path | None = None, width: int = 480, height: int = 480,
               match: Match | None = None, record: Path | None = None,
               policy_names: Mapping[str, str] | None = None) -> MatchRecord:
    """Play one match to its end; agents without a policy are passive.

    With ``video`` the match is rendered from the overview camera and written as mp4
    (one frame per env step, plus the start). With ``record`` it is written as a replayable
    match file (:mod:`triplesumo.evaluation.recording`); ``policy_names`` are stored in it.
    """
    match = match or Match(config)
    unknown = [a for a in policies if a not in match.agents]
    if unknown:
        raise ValueError(f"policies for unknown agents {unknown}; agents are {list(match.agents)}")
    for out in (video, record):
        if out is not None:
            check_writable(Path(out))
    for k, name in enumerate(match.agents):
        reset = getattr(policies.get(name), "reset", None)
        if callable(reset):
            reset(seed=seed * 1000 + k + 1)
    obs, _ = match.reset(seed=seed)
    recorder = MatchRecorder(match, seed, dict(policy_names or {})) if record is not None else None
    renderer = FrameRenderer(match.model, width, height) if video is not None else None
    frames = [renderer.render(match.data)] if renderer else []
    returns = dict.fromkeys(match.agents, 0.0)
    terms: dict[str, dict[str, float]] = {a: {} for a in match.agents}
    try:
        while True:
            actions = np.zeros((match.n_agents, match.action_width))
            for i, name in enumerate(match.agents):
                policy = policies.get(name)
                if policy is not None and match.alive[i]:  # an eliminated agent no longer acts
                    actions[i, :match.action_sizes[i]] = match.check_action(name, policy(obs[i]))
            result = match.step_array(actions)
            if recorder:
                recorder.step(actions)
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
    outcomes = {a: result.infos[i]["outcome"] for i, a in enumerate(match.agents)}
    if recorder is not None and record is not None:
        recorder.finish(outcomes).save(Path(record))
    n_frames = write_mp4(frames, Path(video), fps=round(1.0 / match.sim.dt)) if video is not None else 0
    return MatchRecord(
        outcomes=outcomes,
        steps=match.steps, returns=returns, out_of_ring=list(result.infos[0]["out_of_ring"]),
        terms=terms, frames=n_frames, places={a: int(result.infos[i]["place"]) for i, a in enumerate(match.agents)},
    )
