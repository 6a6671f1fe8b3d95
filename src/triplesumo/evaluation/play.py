"""``triplesumo play``: one seeded match between any policies, optionally recorded."""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from triplesumo.agents.zoo import check_policy_pairs, expand_pairs
from triplesumo.envs.match import Match
from triplesumo.envs.seeding import check_seed
from triplesumo.evaluation.recording import MatchFile
from triplesumo.evaluation.runner import MatchRecord, play_match
from triplesumo.evaluation.viewer import check_html_path, write_page
from triplesumo.model.specs import PhysicsConfig
from triplesumo.rules.scenarios import get_scenario
from triplesumo.zoo import policies_from_pairs


@dataclass(frozen=True)
class PlayConfig:
    """A seeded match between named policies."""

    seed: int = 0
    """Seed of the match's reset noise (and of random policies)."""
    policies: tuple[str, ...] = ("*=random",)
    """AGENT=POLICY pairs; POLICY is zero, passive, random, zoo:NAME or a policy-file path;
    ``*=POLICY`` stands for every agent not named. Agents not named are passive."""
    video: str | None = None
    """Write the match as mp4 to this path."""
    record: str | None = None
    """Write the match as a replayable match file (.npz: seed, config, actions, MuJoCo states) to this
    path; ``triplesumo replay FILE --video out.mp4`` re-renders it."""
    html: str | None = None
    """Write the match as one self-contained HTML page that replays it in a browser, offline (as
    ``triplesumo view``) to this path."""
    max_steps: int = 500
    """Step limit of the match (a draw when reached)."""
    obs_mode: str = "paper"
    """Observation mode the policies expect: paper or egocentric."""
    width: int = 480
    """Video width in pixels."""
    height: int = 480
    """Video height in pixels."""
    scenario: str = "paper"
    """Named game (paper, ffa, pursuit, 2v2; ``triplesumo.scenarios()``) with its default roster."""
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    """The simulation: its ring (rim, start layout) as the policies were trained on."""
    allow_other_ring: bool = False
    """Let a policy file trained on another ring (its manifest's physics: rim, start layout) play on this one;
    without it such a policy is refused, naming both rings."""

    def __post_init__(self) -> None:
        check_seed(self.seed, "PlayConfig.seed")
        get_scenario(self.scenario)
        check_policy_pairs("PlayConfig.policies", self.policies)
        if self.width < 16 or self.height < 16:
            raise ValueError("PlayConfig.width and height must be >= 16")
        if self.record is not None and not self.record.endswith(".npz"):
            raise ValueError(f"PlayConfig.record must be a .npz path, got {self.record!r}")
        if self.html is not None:
            check_html_path(self.html, "PlayConfig.html")


def run_play(cfg: PlayConfig) -> MatchRecord:
    """Play the match, print its outcome, and return its record."""
    match = Match(get_scenario(cfg.scenario).config(max_steps=cfg.max_steps, obs_mode=cfg.obs_mode,
                                                    physics=cfg.physics))
    pairs = expand_pairs(cfg.policies, match.agents)
    check_policy_pairs("PlayConfig.policies", pairs, agents=list(match.agents))
    try:
        policies = policies_from_pairs(pairs, cfg.seed, cfg.obs_mode, obs_dims=match.observer.sizes,
                                       action_sizes=dict(zip(match.agents, match.action_sizes, strict=True)),
                                       teams={a.name: a.team for a in match.config.agents},
                                       physics=cfg.physics, allow_other_ring=cfg.allow_other_ring)
    except ValueError as err:
        raise ValueError(f"scenario {cfg.scenario!r}: {err}") from None
    video = Path(cfg.video) if cfg.video else None
    file = Path(cfg.record) if cfg.record else None
    names = dict(pair.split("=") for pair in pairs)
    with tempfile.TemporaryDirectory() as scratch:
        # a page is built from a match file: the one asked for, else one kept only until the page is written
        source = file if file is not None or cfg.html is None else Path(scratch) / "match.npz"
        played = play_match(policies, seed=cfg.seed, video=video, width=cfg.width, height=cfg.height, match=match,
                            record=source, policy_names=names)
        if cfg.html is not None and source is not None:
            page = write_page(MatchFile.load(source), Path(cfg.html), title=f"{cfg.scenario} match, seed {cfg.seed}",
                              source=source)
    who = ", ".join(f"{a}: {o} (place {played.places.get(a, 0)})" for a, o in played.outcomes.items())
    out = f"; out of the ring: {', '.join(played.out_of_ring)}" if played.out_of_ring else ""
    print(f"match seed {cfg.seed}: {played.steps} steps; {who}{out}")
    print("returns: " + ", ".join(f"{a} {r:+.1f}" for a, r in played.returns.items()))
    if video is not None:
        print(f"video: {video} ({played.frames} frames)")
    if file is not None:
        print(f"match file: {file} (replay: triplesumo replay {file} --video out.mp4)")
    if cfg.html is not None:
        print(f"page: {page} (open it in a browser; no network needed)")
    return played
