"""Named games on the tatami: each scenario is data, a roster recipe plus rule-set fields.

A :class:`Scenario` is not a subclass per game: it says how to build the roster from a few
sizes (``n_agents``, ``n_pursuers``, ``team_sizes``) and which :class:`MatchConfig` fields
its rules set (``rules``, ``evader``). :func:`scenario_config` turns a name and overrides
into one frozen, validated :class:`MatchConfig`; every view (PettingZoo, Gymnasium, the
trainer, ``play``, ``evaluate``) takes that config. The rules themselves live once in
:mod:`triplesumo.rules.outcome` and :mod:`triplesumo.rules.rewards`.
"""

from __future__ import annotations

import colorsys
import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from triplesumo.model.specs import BLUE, BODIES_AGENTS, GREEN, RED, AgentSpec
from triplesumo.rules.config import MatchConfig
from triplesumo.version import ENV_VERSION

NAMES = ("ant", "bug", "spider", "beetle", "mantis", "wasp", "moth", "flea")
"""Agent names in roster order; agents past these are ``agent_<k>``."""
CTRL_RANGE = 0.20
"""Control range of every agent of the symmetric scenarios (the paper's Ant, the middle value)."""


def agent_name(k: int) -> str:
    """Name of the ``k``-th agent of a generated roster."""
    return NAMES[k] if k < len(NAMES) else f"agent_{k}"


def distinct_colours(n: int) -> list[tuple[float, float, float, float]]:
    """``n`` distinct RGBA colours: the paper's red, blue, green, then evenly spaced hues."""
    base = [RED, BLUE, GREEN]
    if n <= 3:
        return base[:n]
    return [(*colorsys.hsv_to_rgb(k / n, 0.8, 0.9), 1.0) for k in range(n)]


MAX_AGENTS = 8
"""Largest roster a scenario builds: no more quadrupeds stand clear of each other inside the ring (six need the
circle start), and checking the size first answers at once instead of after minutes of layout search."""


def ffa_roster(n_agents: int = 3) -> tuple[AgentSpec, ...]:
    """``n_agents`` agents, each its own team, in distinct colours."""
    _check_count("n_agents", n_agents, 2)
    colours = distinct_colours(n_agents)
    return tuple(AgentSpec(agent_name(k), agent_name(k), CTRL_RANGE, colours[k]) for k in range(n_agents))


def pursuit_roster(n_pursuers: int = 3) -> tuple[AgentSpec, ...]:
    """``n_pursuers`` pursuers (team ``pursuers``, red to orange) and one ``evader`` (green)."""
    _check_count("n_pursuers", n_pursuers, 1, total=n_pursuers + 1 if isinstance(n_pursuers, int) else None)
    pursuers = tuple(AgentSpec(f"pursuer_{k}", "pursuers", CTRL_RANGE,
                               (*colorsys.hsv_to_rgb(0.12 * k / max(1, n_pursuers - 1), 0.85, 0.85), 1.0))
                     for k in range(n_pursuers))
    return (*pursuers, AgentSpec("evader", "evader", CTRL_RANGE, GREEN))


def teams_roster(team_sizes: tuple[int, ...] = (2, 2)) -> tuple[AgentSpec, ...]:
    """Teams ``team_0``, ``team_1``, ... of the given sizes; a team's agents share its hue."""
    if not isinstance(team_sizes, tuple) or len(team_sizes) < 2:
        raise ValueError(f"team_sizes must be a tuple of >= 2 team sizes, got {team_sizes!r}")
    for size in team_sizes:
        _check_count("team_sizes", size, 1, total=0)  # each an int >= 1; the roster's size next
    if sum(team_sizes) > MAX_AGENTS:
        raise ValueError(f"team_sizes {team_sizes!r} make a roster of {sum(team_sizes)} agents; at most {MAX_AGENTS} "
                         "fit on the ring")
    agents, k = [], 0
    for t, size in enumerate(team_sizes):
        hue = t / len(team_sizes)
        for j in range(size):
            value = 0.95 - 0.45 * j / max(1, size - 1) if size > 1 else 0.9
            rgba = (*colorsys.hsv_to_rgb(hue, 0.8, value), 1.0)
            agents.append(AgentSpec(agent_name(k), f"team_{t}", CTRL_RANGE, rgba))
            k += 1
    return tuple(agents)


def _check_count(field: str, value: Any, minimum: int, total: int | None = None) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{field} must be an integer >= {minimum}, got {value!r}")
    if (total if total is not None else value) > MAX_AGENTS:
        raise ValueError(f"{field} {value!r} makes a roster of {total if total is not None else value} agents; at "
                         f"most {MAX_AGENTS} fit on the ring")


class UnknownOptionError(TypeError, ValueError):
    """A keyword no scenario or :class:`MatchConfig` takes: a ``TypeError``, as Python raises for an unexpected
    keyword argument (clients such as TorchRL's ``GymEnv`` retry without an option on that), and a
    ``ValueError`` as every other bad option here."""


@dataclass(frozen=True)
class Scenario:
    """One named game: how to build its roster, and the rule fields it sets."""

    name: str
    """Scenario name, as passed to ``parallel_env(scenario=...)``."""
    gym_id: str
    """Registered Gymnasium id of its single-learner view."""
    learner: str
    """Default learner of its single-learner view."""
    roster: Callable[..., tuple[AgentSpec, ...]] | None
    """Roster recipe taking :attr:`sizes` as keywords; ``None``: the paper's roster."""
    sizes: Mapping[str, Any]
    """Roster sizes and their defaults (keywords of :attr:`roster`), overridable by name."""
    fields: Mapping[str, Any]
    """The :class:`MatchConfig` fields the scenario sets (rules, evader, ...)."""
    doc: str
    """Its documentation: Agents, Rules, Rewards, Episode End, as in the paper env's docstring."""

    @property
    def pettingzoo_name(self) -> str:
        """PettingZoo-style name, e.g. ``triplesumo_ffa_v2`` (the paper's: ``triplesumo_v2``)."""
        return f"triplesumo_{ENV_VERSION}" if self.name == "paper" else f"triplesumo_{self.name}_{ENV_VERSION}"

    def config(self, **overrides: Any) -> MatchConfig:
        """The scenario's :class:`MatchConfig`; ``overrides`` are roster sizes or MatchConfig fields."""
        known = {f.name for f in dataclasses.fields(MatchConfig)}
        unknown = sorted(set(overrides) - known - set(self.sizes))
        if unknown:
            sizes = f"; roster sizes: {sorted(self.sizes)}" if self.sizes else ""
            raise UnknownOptionError(f"scenario {self.name!r} got an unexpected keyword argument {unknown[0]!r}: "
                                     f"unknown option(s) {unknown}; MatchConfig fields: {sorted(known)}{sizes}")
        given = {k: overrides.pop(k) for k in list(overrides) if k in self.sizes}
        if given and "agents" in overrides:
            raise ValueError(f"scenario {self.name!r}: give either agents or {sorted(given)}, not both")
        fields = dict(self.fields)
        if "agents" not in overrides and self.roster is not None:
            fields["agents"] = self.roster(**{**self.sizes, **given})
        fields.update(overrides)
        try:
            return MatchConfig(**fields)
        except ValueError as err:
            raise ValueError(f"scenario {self.name!r}: {err}") from None


_PAPER_DOC = """\
## Agents
``ant`` (red, +-0.20) and ``bug`` (blue, +-0.18), one team, against ``spider`` (green, +-0.22).

## Rules
``first_out``: the match ends on the first step any agent's torso centre leaves the ring.

## Rewards
The paper's hybrid reward (velocity terms, still punishment) plus +500 to the winning side,
-400 to the losing side, 0 for a draw.

## Episode End
Termination on the first ring exit (Spider out: the team wins; Ant or Bug out: Spider wins;
both sides together: draw). Truncation at the step limit (500): a draw.
"""

_FFA_DOC = """\
## Agents
``n_agents`` (default 3, any N >= 2: ``ant``, ``bug``, ``spider``, ``beetle``, ...), each its
own team, in distinct colours, control range +-0.20.

## Rules
``elimination``: an agent whose torso centre leaves the ring is eliminated: terminated on
that step, absent from ``env.agents`` afterwards, its body gets zero control. Every other
agent still in play is an opponent.

## Rewards
Dense terms against the agents in play; on the step an agent's place is decided, its
placement reward: last one standing +500 (``RewardConfig.win``), first out -400
(``RewardConfig.loss``), places between linear; agents out in the same step share the best
of the places they span and get the mean of their rewards. ``info["place"]`` (1 = winner,
0 until decided) and ``info["eliminated"]``.

## Episode End
Termination when one agent is left (it wins) or none. Truncation at the step limit (500):
the survivors share places 1..s, a draw.
"""

_PURSUIT_DOC = """\
## Agents
``n_pursuers`` pursuers (default 3: ``pursuer_0``, ...; one team, red to orange) against one
``evader`` (green); control range +-0.20.

## Rules
``elimination``, with the evader named (``MatchConfig.evader``): a pursuer out leaves as in
``ffa`` and the match goes on. ``evader_obs_noise`` (default 0): standard deviation of the
Gaussian noise, seeded from ``reset``, on what pursuers observe of the evader's position and
velocity (the paper's "probabilistic observations").

## Rewards
Dense terms against the agents in play; +500 to the winning side, -400 to the losing side
(an eliminated pursuer gets -400 when it leaves).

## Episode End
Termination when the evader is out (the pursuers win) or every pursuer is out (the evader
wins). Truncation at the step limit (500): the evader wins by surviving.
"""

_TEAMS_DOC = """\
## Agents
``team_sizes`` (default (2, 2)): teams ``team_0``, ``team_1``, ... of ``ant``, ``bug``,
``spider``, ``beetle``, ...; a team's agents share its hue; control range +-0.20.

## Rules
The paper's ``first_out`` rules with team sizes > 1 on both sides: the first ring exit ends
the match; every team with an agent out loses, the others win.

## Rewards
The paper's hybrid reward: partner terms average over team-mates, opponent terms over the
other teams' agents; +500 win, -400 loss, 0 draw.

## Episode End
Termination on the first ring exit (every team out in the same step: draw). Truncation at
the step limit (500): a draw.
"""

_BODIES_DOC = """\
## Agents
The paper's roster with RoboSumo's three bodies: ``ant`` (red, +-0.20) a quadruped (8 action
values), ``bug`` (blue, +-0.18) a hexapod (12), ``spider`` (green, +-0.22) an octopod (16);
each leg a hip and an ankle hinge (``triplesumo.model.BODIES_AGENTS``).

## Rules
The paper's ``first_out`` rules (see ``paper``).

## Rewards
The paper's hybrid reward, +500 win, -400 loss, 0 draw.

## Episode End
As ``paper``: termination on the first ring exit, truncation at the step limit (500).
"""


def bodies_roster() -> tuple[AgentSpec, ...]:
    """The paper's 2-vs-1 with RoboSumo's ant, bug and spider bodies."""
    return BODIES_AGENTS


SCENARIOS: dict[str, Scenario] = {
    "paper": Scenario("paper", f"TripleSumo-Paper-{ENV_VERSION}", "bug", None, {}, {}, _PAPER_DOC),
    "ffa": Scenario("ffa", f"TripleSumo-FFA-{ENV_VERSION}", "bug", ffa_roster, {"n_agents": 3},
                    {"rules": "elimination"}, _FFA_DOC),
    "pursuit": Scenario("pursuit", f"TripleSumo-Pursuit-{ENV_VERSION}", "evader", pursuit_roster, {"n_pursuers": 3},
                        {"rules": "elimination", "evader": "evader"}, _PURSUIT_DOC),
    "2v2": Scenario("2v2", f"TripleSumo-2v2-{ENV_VERSION}", "ant", teams_roster, {"team_sizes": (2, 2)}, {},
                    _TEAMS_DOC),
    "bodies": Scenario("bodies", f"TripleSumo-Bodies-{ENV_VERSION}", "bug", bodies_roster, {}, {}, _BODIES_DOC),
}
"""Every scenario by name."""

def scenarios() -> tuple[str, ...]:
    """Names of the available scenarios (``"paper"`` first)."""
    return tuple(SCENARIOS)


def get_scenario(name: str) -> Scenario:
    """The scenario called ``name``, or ``ValueError`` listing the names."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; available: {list(SCENARIOS)}")
    return SCENARIOS[name]


def resolve(scenario: str, config: MatchConfig | None, learner: str | None,
            fields: Mapping[str, Any]) -> tuple[Scenario, MatchConfig, str]:
    """What a single-learner view was asked for: the scenario, its config (``config`` or the
    scenario's with ``fields``, not both) and the learner (default: the scenario's)."""
    if config is not None and fields:
        raise ValueError("pass either config=MatchConfig(...) or MatchConfig fields, not both")
    chosen = get_scenario(scenario)
    return chosen, config if config is not None else chosen.config(**fields), learner or chosen.learner


def scenario_config(name: str, **overrides: Any) -> MatchConfig:
    """The :class:`MatchConfig` of scenario ``name`` with ``overrides`` (roster sizes or fields)."""
    return get_scenario(name).config(**overrides)


def scenarios_doc() -> str:
    """Every scenario's documentation, one ``### name`` section each (appended to the ParallelEnv docstring)."""
    parts = []
    for sc in SCENARIOS.values():
        body = sc.doc.replace("## ", "#### ")
        parts.append(f"### {sc.name}\n``parallel_env(scenario={sc.name!r})``, Gymnasium id ``{sc.gym_id}``, "
                     f"PettingZoo name ``{sc.pettingzoo_name}``.\n\n{body}")
    return "\n".join(parts)
