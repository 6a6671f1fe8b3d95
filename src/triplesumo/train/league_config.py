"""The rules of a self-play league (:class:`LeagueConfig`): admission, sampling, pool size, the zoo's seeds,
checked when the config is made (see :mod:`triplesumo.train.league` for what they mean)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from triplesumo.agents.builtin import BUILTIN
from triplesumo.agents.zoo import find_policy_file, policy_stem
from triplesumo.evaluation.ratings import MODELS
from triplesumo.model.specs import PhysicsConfig
from triplesumo.zoo import check_ring

SAMPLING = ("uniform", "latest", "pfsp")
"""Opponent sampling rules (see the module docstring)."""
PFSP_WEIGHTINGS = ("hard", "variance")
"""AlphaStar's PFSP weightings: ``hard`` ``(1 - p) ** exponent``, ``variance`` ``p (1 - p)``."""


@dataclass(frozen=True)
class LeagueConfig:
    """Self-play: learners play against pools of their own past snapshots and the zoo."""

    threshold: float = 0.55
    """Admit a learner's snapshot when its win rate over the last ``window`` matches is greater than this."""
    window: int = 50
    """Matches in the win-rate window that admission looks at (it must be full)."""
    sampling: str = "pfsp"
    """How opponents are drawn from a pool: uniform, latest or pfsp (prioritised fictitious self-play)."""
    pfsp_weighting: str = "hard"
    """pfsp weights of a member the learner beats with probability p: hard ((1 - p) ** pfsp_exponent) or
    variance (p (1 - p))."""
    pfsp_exponent: float = 2.0
    """Exponent of the hard pfsp weighting (AlphaStar: 2)."""
    max_size: int = 20
    """Most members a pool holds; past it the oldest goes (FIFO), never the first nor the best-rated."""
    keep_zoo: bool = False
    """Never evict the members seeded from ``zoo`` (they do not count against ``max_size`` either): a fixed
    opponent the learner must keep beating, such as a still team (``ant=passive bug=passive``), stays in
    the pool however many snapshots join."""
    zoo_share: float = 0.0
    """The share of a pool's draws, in [0, 1], that goes to its seeded (``zoo``) members, evenly; its snapshots
    get the rest by ``sampling``. 0: every member drawn by ``sampling`` alike. A pool holding only seeds or only
    snapshots ignores it."""
    snapshot_every: int = 50
    """Check the learners for admission every this many epochs."""
    zoo: tuple[str, ...] = ()
    """ROLE=POLICY entries seeding the pools (POLICY: zero, passive, random, zoo:NAME or a policy file,
    e.g. another run's league/members/spider-0094/spider); a pool is seeded when every one of its roles is
    named, with one member per entry of a role: naming a role k times seeds k members (a side's roles
    named equally often, the i-th entries of its roles making its i-th member). A policy file is copied into
    the pool when it is seeded, so a resume does not need it again."""
    draw_score: float = 0.0
    """What a match a learner finishes first but not alone (a draw: the time limit, or tied places) adds to
    its win-rate window: 0 (only a win counts, the default) or e.g. 0.5 (half a win, as chess scores it),
    which lets a league started from scratch, where most matches are draws, admit its first snapshots."""
    side_draw_score: tuple[str, ...] = ()
    """SIDE=SCORE entries that give one side another draw score than ``draw_score``: in the paper's 2-vs-1
    ``spider=0`` (with ``draw_score`` 0.5) admits a Spider snapshot only for pushing the team out, while a
    team that keeps both quadrupeds in still scores its draws."""
    side_threshold: tuple[str, ...] = ()
    """SIDE=T entries that give one side its own admission threshold (T in [0, 1)) instead of ``threshold``:
    in the paper's 2-vs-1 ``team=0.3`` lets a team that loses most of its matches to a pushing Spider still
    add snapshots when it improves, so the Spider meets a growing pool of teams rather than one early one."""
    live_share: float = 0.35
    """With several learning sides (both sides of the 2-vs-1 learn): the probability that a match is between
    the live learners; otherwise one learning side (uniform) plays members of the others' pools."""
    rating_model: str = "PlackettLuce"
    """openskill model of the ratings: PlackettLuce, BradleyTerryFull, BradleyTerryPart,
    ThurstoneMostellerFull or ThurstoneMostellerPart."""

    def __post_init__(self) -> None:
        for name in ("zoo", "side_draw_score", "side_threshold"):  # JSON (config.json, pool.json) gives lists
            if isinstance(getattr(self, name), list):
                object.__setattr__(self, name, tuple(getattr(self, name)))
        if not (isinstance(self.threshold, int | float) and not isinstance(self.threshold, bool)
                and 0.0 <= self.threshold < 1.0):
            raise ValueError(f"LeagueConfig.threshold must be a number in [0, 1), got {self.threshold!r}")
        if not (isinstance(self.draw_score, int | float) and not isinstance(self.draw_score, bool)
                and 0.0 <= self.draw_score <= 1.0):
            raise ValueError(f"LeagueConfig.draw_score must be a number in [0, 1], got {self.draw_score!r}")
        if not (isinstance(self.live_share, int | float) and not isinstance(self.live_share, bool)
                and 0.0 <= self.live_share <= 1.0):
            raise ValueError(f"LeagueConfig.live_share must be a number in [0, 1], got {self.live_share!r}")
        if not (isinstance(self.zoo_share, int | float) and not isinstance(self.zoo_share, bool)
                and 0.0 <= self.zoo_share <= 1.0):
            raise ValueError(f"LeagueConfig.zoo_share must be a number in [0, 1], got {self.zoo_share!r}")
        for name, minimum in (("window", 1), ("max_size", 3), ("snapshot_every", 1)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
                raise ValueError(f"LeagueConfig.{name} must be an int >= {minimum}, got {value!r}")
        if self.sampling not in SAMPLING:
            raise ValueError(f"LeagueConfig.sampling must be one of {SAMPLING}, got {self.sampling!r}")
        if self.pfsp_weighting not in PFSP_WEIGHTINGS:
            raise ValueError(f"LeagueConfig.pfsp_weighting must be one of {PFSP_WEIGHTINGS}, "
                             f"got {self.pfsp_weighting!r}")
        if not (isinstance(self.pfsp_exponent, int | float) and math.isfinite(self.pfsp_exponent)
                and self.pfsp_exponent > 0):
            raise ValueError(f"LeagueConfig.pfsp_exponent must be a finite number > 0, got {self.pfsp_exponent!r}")
        if self.rating_model not in MODELS:
            raise ValueError(f"LeagueConfig.rating_model must be one of {sorted(MODELS)}, "
                             f"got {self.rating_model!r}")
        side_values(self.side_draw_score, "side_draw_score", "SCORE", "[0, 1]", lambda v: 0.0 <= v <= 1.0)
        side_values(self.side_threshold, "side_threshold", "T", "[0, 1)", lambda v: 0.0 <= v < 1.0)
        for entry in self.zoo:
            role, sep, spec = entry.partition("=")
            if not sep or not role or not spec:
                raise ValueError(f"LeagueConfig.zoo: expected ROLE=POLICY, got {entry!r}")
            check_spec(spec, "LeagueConfig.zoo", files=False)

    def draw_score_of(self, side: str) -> float:
        """What a draw adds to ``side``'s win-rate window: its :attr:`side_draw_score` entry, else
        :attr:`draw_score`."""
        return side_values(self.side_draw_score).get(side, float(self.draw_score))

    def threshold_of(self, side: str) -> float:
        """The win rate ``side``'s window must pass for its learner to be admitted: its
        :attr:`side_threshold` entry, else :attr:`threshold`."""
        return side_values(self.side_threshold).get(side, float(self.threshold))

    def sides_named(self) -> dict[str, list[str]]:
        """Field -> the sides its SIDE=VALUE entries name (checked against a run's sides by :class:`League`)."""
        return {name: list(side_values(getattr(self, name))) for name in ("side_draw_score", "side_threshold")}


def side_values(entries: Sequence[str], name: str = "", value: str = "", bounds: str = "",
                 ok: Callable[[float], bool] = lambda v: True) -> dict[str, float]:
    """SIDE=VALUE ``entries`` as side -> value; ``ValueError`` naming ``LeagueConfig.<name>`` for an entry
    without a side, a value that is not a number or fails ``ok``, or a side named twice."""
    out: dict[str, float] = {}
    for entry in entries:
        side, sep, text = entry.partition("=")
        try:
            number = float(text)
        except ValueError:
            number = math.nan
        if not sep or not side or not ok(number):
            raise ValueError(f"LeagueConfig.{name}: expected SIDE={value} with {value} in {bounds}, got {entry!r}")
        if side in out:
            raise ValueError(f"LeagueConfig.{name}: side {side!r} named twice")
        out[side] = number
    return out


def check_seeds(entries: Sequence[str]) -> None:
    """``ValueError`` naming the first ROLE=POLICY entry (:attr:`LeagueConfig.zoo`'s form) whose policy is
    neither built in, shipped nor a policy file: what seeding them needs, checked before anything is copied."""
    for entry in entries:
        check_spec(entry.partition("=")[2], "LeagueConfig.zoo")


def check_seed_rings(entries: Sequence[str], physics: PhysicsConfig, allow_other_ring: bool = False) -> None:
    """``ValueError`` naming :attr:`LeagueConfig.zoo`, the policy file and both rings for the first ROLE=POLICY entry
    whose policy was trained on another ring than ``physics`` (the run's), unless ``allow_other_ring``
    (:func:`triplesumo.zoo.check_ring`): the seeds play on the run's ring."""
    for entry in entries:
        try:
            check_ring(entry.partition("=")[2], physics, allow_other_ring)
        except ValueError as err:
            raise ValueError(f"LeagueConfig.zoo: {err}") from None


def check_spec(spec: str, where: str, files: bool = True) -> None:
    """``ValueError`` naming ``where`` unless ``spec`` is a built-in policy, a shipped ``zoo:NAME`` or (with
    ``files``) a policy file. A config checks its seeds without ``files``: a seed's file is needed only
    when it is copied into the pool (:meth:`League.seed`), and a run resumed after its seed's file went
    away (say, another run's member that ``triplesumo compact`` pruned) has the pool's copy."""
    if spec in BUILTIN:
        return
    try:
        if files:
            find_policy_file(spec)
        else:
            policy_stem(spec)
    except (ValueError, FileNotFoundError) as err:  # not a policy file; an unknown zoo:NAME
        raise ValueError(f"{where}: {err}") from None
