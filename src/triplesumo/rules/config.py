"""Configuration of a match: roster, physics, rules, reward weights and observations.

Frozen, typed dataclasses validated in ``__post_init__`` with errors that name the
field. Paper values (and, where the paper is silent, its original code's) are the
defaults.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from triplesumo.model.specs import PAPER_AGENTS, AgentSpec, PhysicsConfig, validate_roster

OBS_MODES = ("paper", "egocentric")
SEAT_BLIND_MODES = ("paper",)
"""Observation modes that give every agent the same vector: nothing in it says which seat reads it."""


def check_shared_network(obs_mode: str, seats: list[str] | tuple[str, ...], where: str) -> None:
    """Refuse one network driving several ``seats`` on seat-blind observations.

    With ``paper`` observations every seat reads the same vector, so a network shared by
    several seats (a team's shared network, a free-for-all snapshot taking any seat) gives
    them all the actions of one seat, whichever body it drives. ``where`` names the option.
    """
    if obs_mode in SEAT_BLIND_MODES and len(seats) > 1:
        raise ValueError(f"{where}: one network for seats {list(seats)} with obs_mode {obs_mode!r}: every seat "
                         "reads the same vector there, so the network cannot tell which body it drives; use "
                         "obs_mode 'egocentric' (--obs-mode egocentric), whose vector is the seat's own, or one "
                         "network per seat")
PHYSICS_ERROR_MODES = ("truncate", "raise")
RULES = ("first_out", "elimination")
"""Rule sets (:mod:`triplesumo.rules.outcome`): the paper's first ring exit ends the match, or
agents leave one by one until one team is left."""


@dataclass(frozen=True)
class RewardConfig:
    """Weights of the paper's hybrid reward (dense + sparse), the same for every agent."""

    opponent_velocity: float = 5.0
    """C1: weight of the opponent-velocity term (paper's code: 5)."""
    self_velocity: float = 5.0
    """C2: weight of the self-velocity term (paper's code: 5)."""
    partner_velocity: float = 5.0
    """C3: weight of the partner-velocity term (paper's code: 5)."""
    still: float = -4.0
    """Still punishment added every step (paper's code: -4); must be <= 0. A constant, so over a match a
    time penalty: a 500-step draw costs 500 x still (-2000 at -4), more than a loss, and a side that
    cannot win earns most by losing fast (docs/LEAGUE.md (i)); 0 removes it."""
    win: float = 500.0
    """Sparse reward to every agent of the winning side (elimination rules: place 1, the last
    team standing)."""
    loss: float = -400.0
    """Sparse reward to every agent of a losing side (elimination rules: the last place, first
    out; places between are interpolated linearly)."""
    draw: float = 0.0
    """Sparse reward of a draw under the ``first_out`` rules: the step limit reached, or both sides out together.
    Under ``elimination`` rules survivors at the limit share their places instead (``win`` to ``loss``
    interpolated, :func:`triplesumo.rules.outcome.place_value`), so ``MatchConfig`` refuses a ``draw`` other than
    0 there rather than ignore it."""

    axis_dead_zone: float = 0.0
    """Half-width (m) of the band around 0 in which a per-axis direction sign of the velocity terms counts
    as 0 (:mod:`triplesumo.rules.rewards`). 0 (the paper's sign) keeps env v2's reward exactly. On the fair
    start Spider stands level with Ant in y and with Bug in x, so the sign of those axes is decided by 2 cm of
    reset noise: with 0, walking straight at Ant pays Spider either twice the single-opponent term or nothing
    (measured on 200 starts: nothing in 106, double in 94; docs/notes/contest-log.md); a band wider than the noise (e.g.
    0.25) pays it half on every start, as Ant is paid the whole term for walking at Spider."""

    opponents: str = "mean"
    """How an agent with several opponents combines its per-opponent velocity terms: ``mean`` (the default; env
    v2's reward unchanged) or ``sum``. With one opponent (Ant, Bug in the paper's match) both are the same. With
    ``mean`` Spider, whose two opponents are Ant and Bug, is paid half for approaching or shoving one of them what
    Ant is paid for approaching or shoving Spider; in the contest's stage 1, where Bug stands still, that halves
    Spider's only signal toward the opponent that fights back (docs/notes/contest-log.md). ``sum`` pays each opponent at
    full weight."""

    def __post_init__(self) -> None:
        if self.opponents not in OPPONENT_REDUCTIONS:
            raise ValueError(f"RewardConfig.opponents must be one of {OPPONENT_REDUCTIONS}, got {self.opponents!r}")
        for name in ("opponent_velocity", "self_velocity", "partner_velocity", "still", "win", "loss", "draw",
                     "axis_dead_zone"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value):
                raise ValueError(f"RewardConfig.{name} must be a finite number, got {value!r}")
        if self.still > 0:
            raise ValueError(f"RewardConfig.still is a punishment and must be <= 0, got {self.still}")
        if self.axis_dead_zone < 0:
            raise ValueError(f"RewardConfig.axis_dead_zone is a half-width in metres and must be >= 0, "
                             f"got {self.axis_dead_zone}")


OPPONENT_REDUCTIONS = ("mean", "sum")
"""How :attr:`RewardConfig.opponents` combines an agent's per-opponent velocity terms."""


@dataclass(frozen=True)
class ResetNoise:
    """Seeded noise added to the documented start pose at every reset."""

    position: float = 0.1
    """Half-width (m) of the uniform noise on each torso's x and y."""
    yaw: float = 0.1
    """Half-width (rad) of the uniform noise on each torso's heading."""
    joints: float = 0.1
    """Half-width (rad) of the uniform noise on each leg joint angle."""
    velocity: float = 0.1
    """Standard deviation of the Gaussian noise on every qvel entry."""

    def __post_init__(self) -> None:
        for name in ("position", "yaw", "joints", "velocity"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"ResetNoise.{name} must be finite and >= 0, got {value!r}")


MAX_EVADER_OBS_NOISE = 100.0
"""Largest standard deviation of the evader's observation noise: far past any use (the ring is 4 m across),
and small enough that the noisy observations stay finite."""
LAYOUT_NOISE = {"fair": ResetNoise(position=0.02, yaw=0.05), "circle": ResetNoise()}
"""The reset noise of each start layout (``PhysicsConfig.layout``) where a match config names none."""


@dataclass(frozen=True)
class MatchConfig:
    """Everything that defines one TripleSumo match."""

    agents: tuple[AgentSpec, ...] = PAPER_AGENTS
    """The roster; agents sharing a ``team`` label are partners."""
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    """MuJoCo options (timestep, integrator, physics steps per env step)."""
    reward: RewardConfig = field(default_factory=RewardConfig)
    """Reward weights."""
    reset_noise: ResetNoise = None  # type: ignore[assignment]  # (None: the layout's, set in __post_init__)
    """Start-pose noise; all zeros gives an identical start every reset. Left out (None), the layout's
    (:data:`LAYOUT_NOISE`): on the fair start (env v2) torsos move at most 2 cm and turn at most 0.05 rad, so
    that the agents' distances to the edges stay within 5 cm of each other; on env v0/v1's circle, 0.1 and
    0.1, as those versions ran (so their physics, ``V1_PHYSICS``, replays them exactly)."""
    max_steps: int = 500
    """Step limit of a match; reaching it is a draw (truncation)."""
    obs_mode: str = "paper"
    """Observation mode: "paper" (global vector) or "egocentric" (agent's own frame)."""
    contact_force_clip: float = 100.0
    """Contact forces in observations are clipped to +-this many newtons."""
    on_physics_error: str = "truncate"
    """On a MuJoCo warning: "truncate" the match (info["physics_error"]) or "raise"."""
    rules: str = "first_out"
    """Rule set: "first_out" (the paper: the first ring exit ends the match) or "elimination"
    (an agent out leaves; the match goes on until one team is left or the step limit)."""
    evader: str | None = None
    """Agent name of a pursuit's evader (elimination rules only): its team wins at the step
    limit instead of sharing a draw, and ``evader_obs_noise`` applies to it."""
    evader_obs_noise: float = 0.0
    """Standard deviation of Gaussian noise (seeded from ``reset``) on the evader's torso
    position and velocity (and its free joint's qpos/qvel entries) in what its opponents
    observe; 0 observes it exactly."""

    def __post_init__(self) -> None:
        if self.reset_noise is None:
            object.__setattr__(self, "reset_noise", LAYOUT_NOISE[self.physics.layout])
        if not isinstance(self.reset_noise, ResetNoise):
            raise ValueError(f"MatchConfig.reset_noise must be a ResetNoise (or None: the layout's), "
                             f"got {self.reset_noise!r}")
        if not isinstance(self.agents, tuple) or not all(isinstance(a, AgentSpec) for a in self.agents):
            raise ValueError("MatchConfig.agents must be a tuple of AgentSpec")
        validate_roster(self.agents)
        if not isinstance(self.max_steps, int) or isinstance(self.max_steps, bool) or self.max_steps < 1:
            raise ValueError(f"MatchConfig.max_steps must be an int >= 1, got {self.max_steps!r}")
        if self.obs_mode not in OBS_MODES:
            raise ValueError(f"MatchConfig.obs_mode must be one of {OBS_MODES}, got {self.obs_mode!r}")
        if not (math.isfinite(self.contact_force_clip) and self.contact_force_clip > 0):
            raise ValueError(
                f"MatchConfig.contact_force_clip must be finite and > 0, got {self.contact_force_clip!r}"
            )
        if self.on_physics_error not in PHYSICS_ERROR_MODES:
            raise ValueError(
                f"MatchConfig.on_physics_error must be one of {PHYSICS_ERROR_MODES}, "
                f"got {self.on_physics_error!r}"
            )
        if self.rules not in RULES:
            raise ValueError(f"MatchConfig.rules must be one of {RULES}, got {self.rules!r}")
        if self.rules == "elimination" and self.reward.draw != 0.0:
            raise ValueError(f"MatchConfig.reward.draw is {self.reward.draw} but rules='elimination' never pays it: "
                             "survivors at the step limit share their places (win to loss interpolated); leave "
                             "RewardConfig.draw at 0, or set win and loss")
        if self.evader is not None:
            if self.evader not in self.agent_names:
                raise ValueError(f"MatchConfig.evader must be one of the agents {list(self.agent_names)}, "
                                 f"got {self.evader!r}")
            if self.rules != "elimination":
                raise ValueError("MatchConfig.evader needs rules='elimination'")
        if not (isinstance(self.evader_obs_noise, int | float) and math.isfinite(self.evader_obs_noise)
                and 0 <= self.evader_obs_noise <= MAX_EVADER_OBS_NOISE):
            raise ValueError(f"MatchConfig.evader_obs_noise must be in [0, {MAX_EVADER_OBS_NOISE:g}] (m, m/s: the "
                             f"ring is 4 m across), got {self.evader_obs_noise!r}")
        if self.evader_obs_noise > 0 and self.evader is None:
            raise ValueError("MatchConfig.evader_obs_noise needs an evader (MatchConfig.evader)")

    @property
    def agent_names(self) -> tuple[str, ...]:
        """Agent names in roster order."""
        return tuple(a.name for a in self.agents)
