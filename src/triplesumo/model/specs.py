"""Who is in a match: agent specs, teams, and the physics options of the model.

These are plain frozen dataclasses with no knowledge of rewards or RL. The paper's
2-vs-1 roster is :data:`PAPER_AGENTS` (three identical ant bodies); :data:`BODIES_AGENTS`
is the same match with RoboSumo's ant, bug and spider bodies; free-for-all or M-vs-1
rosters are other tuples of :class:`AgentSpec`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace

from triplesumo.model.bodies import BODIES

RED = (0.85, 0.15, 0.15, 1.0)
BLUE = (0.15, 0.3, 0.9, 1.0)
GREEN = (0.15, 0.7, 0.2, 1.0)

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
INTEGRATORS = ("RK4", "Euler", "implicit", "implicitfast")
LAYOUTS = ("fair", "circle")
"""Start layouts (:mod:`triplesumo.model.layout`): ``fair`` (env v2) puts every torso equally far from
the ring's edges; ``circle`` (env v0 and v1) spaces agents evenly on a circle of ``start_radius``."""
RIM_SHAPES = ("box", "cylinder")
"""Shapes of the ring's rim: ``box`` (env v2), which MuJoCo and MuJoCo Warp collide alike, or RoboSumo's
``cylinder`` (env v1), where the two engines part once legs touch it."""


@dataclass(frozen=True)
class AgentSpec:
    """One agent in the match: its name, team, motors, colour and body."""

    name: str
    """Agent name and MJCF prefix (lower-case identifier), e.g. ``"bug"``."""
    team: str
    """Team label; agents with the same label are partners, all others opponents."""
    ctrl_range: float
    """Symmetric motor control range: every motor's ctrl lies in [-ctrl_range, ctrl_range]."""
    rgba: tuple[float, float, float, float] = (0.8, 0.6, 0.4, 1.0)
    """Colour of the agent's geoms."""
    body: str = "ant"
    """RoboSumo body: "ant" (4 legs, 8 motors), "bug" (6 legs, 12) or "spider" (8 legs, 16)."""

    def __post_init__(self) -> None:
        if not _NAME.match(self.name):
            raise ValueError(f"AgentSpec.name must be a lower-case identifier, got {self.name!r}")
        if not self.team:
            raise ValueError(f"AgentSpec.team of {self.name!r} must be a non-empty string")
        if not (math.isfinite(self.ctrl_range) and self.ctrl_range > 0):
            raise ValueError(
                f"AgentSpec.ctrl_range of {self.name!r} must be finite and > 0, got {self.ctrl_range}"
            )
        if len(self.rgba) != 4 or not all(0.0 <= c <= 1.0 for c in self.rgba):
            raise ValueError(f"AgentSpec.rgba of {self.name!r} must be 4 values in [0, 1]")
        if self.body not in BODIES:
            raise ValueError(f"AgentSpec.body of {self.name!r} must be one of {sorted(BODIES)}, got {self.body!r}")


PAPER_AGENTS: tuple[AgentSpec, ...] = (
    AgentSpec("ant", "team", 0.20, RED),
    AgentSpec("bug", "team", 0.18, BLUE),
    AgentSpec("spider", "spider", 0.22, GREEN),
)
"""The paper's roster: Ant (red, ±0.20) and Bug (blue, ±0.18) against Spider (green, ±0.22),
three identical ant (quadruped) bodies."""

BODIES_AGENTS: tuple[AgentSpec, ...] = tuple(replace(a, body=a.name) for a in PAPER_AGENTS)
"""The paper's match with RoboSumo's bodies: Ant a quadruped, Bug a hexapod, Spider an octopod
(8, 12 and 16 motors); names, teams, colours and control ranges as :data:`PAPER_AGENTS`."""


def validate_roster(agents: tuple[AgentSpec, ...]) -> None:
    """Raise ``ValueError`` unless the roster has >= 2 uniquely named agents in >= 2 teams."""
    if len(agents) < 2:
        raise ValueError(f"agents: a match needs at least 2 agents, got {len(agents)}")
    names = [a.name for a in agents]
    if len(set(names)) != len(names):
        raise ValueError(f"agents: names must be unique, got {names}")
    if len({a.team for a in agents}) < 2:
        raise ValueError("agents: a match needs at least 2 teams")


@dataclass(frozen=True)
class PhysicsConfig:
    """MuJoCo options of the compiled model (defaults: RoboSumo / the paper's code)."""

    timestep: float = 0.01
    """Physics timestep in seconds."""
    integrator: str = "RK4"
    """MuJoCo integrator: RK4 (paper), Euler, implicit or implicitfast."""
    frame_skip: int = 5
    """Physics steps per env step (env dt = timestep * frame_skip)."""
    memory: str = "16M"
    """Arena memory for contacts and constraints (MJCF ``<size memory>``)."""
    layout: str = "fair"
    """Start layout: "fair" (default since env v2) starts every torso ``start_edge`` from its nearest
    edge and as far from the edge behind it, legs clear of the rim; "circle" (env v0 and v1) spaces
    agents on a circle of ``start_radius``, facing the centre (:mod:`triplesumo.model.layout`)."""
    start_edge: float = 1.0
    """Fair layout: distance (m) from every torso to its nearest edge of the ring and to the edge behind
    it. The paper's code started the torsos at (-1, -1), (1, -1) and (1, 1): 1.0 m from two edges."""
    start_radius: float = 1.4
    """Circle layout: agents start evenly spaced on a circle of this radius, facing the centre. RoboSumo
    used 1.15 for two agents; with three, legs touch below 1.4 (measured), so 1.4."""
    start_height: float = 1.25
    """Start height of the torso centre; agents fall onto the tatami (top at z = 0.5)."""
    border_rim: bool = True
    """The ring's border collides: a solid ridge 3 cm high along the edge that agents hit, as the
    colliding border cylinders of RoboSumo's and the paper's ``tatami.xml``. True (default since env
    v1) is the paper's ring; False makes the border a visual marker only, the ring of env v0
    (:data:`V0_PHYSICS`)."""
    rim_shape: str = "box"
    """Shape of the border geoms: "box" (default since env v2; 6 cm wide, its top 3 cm above the
    tatami, as the cylinder's) or "cylinder" (RoboSumo's, env v0 and v1). MuJoCo Warp collides a
    cylinder with the legs' capsules unlike MuJoCo (torsos part by 2 cm within 14 steps), boxes alike."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.timestep) and self.timestep > 0):
            raise ValueError(f"PhysicsConfig.timestep must be > 0, got {self.timestep}")
        if self.integrator not in INTEGRATORS:
            raise ValueError(
                f"PhysicsConfig.integrator must be one of {INTEGRATORS}, got {self.integrator!r}"
            )
        if not isinstance(self.frame_skip, int) or isinstance(self.frame_skip, bool) or self.frame_skip < 1:
            raise ValueError(f"PhysicsConfig.frame_skip must be an int >= 1, got {self.frame_skip!r}")
        if not re.fullmatch(r"\d+[KMG]?", self.memory):
            raise ValueError(f"PhysicsConfig.memory must look like '16M', got {self.memory!r}")
        if not (0.0 <= self.start_radius < 2.0):
            raise ValueError(f"PhysicsConfig.start_radius must be in [0, 2), got {self.start_radius}")
        if self.layout not in LAYOUTS:
            raise ValueError(f"PhysicsConfig.layout must be one of {LAYOUTS}, got {self.layout!r}")
        if not (isinstance(self.start_edge, int | float) and 0.2 <= self.start_edge < 2.0):
            raise ValueError(f"PhysicsConfig.start_edge must be in [0.2, 2), got {self.start_edge!r}")
        if self.rim_shape not in RIM_SHAPES:
            raise ValueError(f"PhysicsConfig.rim_shape must be one of {RIM_SHAPES}, got {self.rim_shape!r}")
        if not isinstance(self.border_rim, bool):
            raise ValueError(f"PhysicsConfig.border_rim must be a bool, got {self.border_rim!r}")
        if not self.start_height > 0.5:
            raise ValueError(f"PhysicsConfig.start_height must be > 0.5, got {self.start_height}")


V1_PHYSICS = PhysicsConfig(layout="circle", rim_shape="cylinder")
"""The simulation of env v1: the agents on a circle of 1.4 m and RoboSumo's colliding border cylinders."""
V0_PHYSICS = PhysicsConfig(layout="circle", rim_shape="cylinder", border_rim=False)
"""The simulation of env v0 (visual-only border markers): what a run folder, policy manifest or
evaluation record without a ``physics`` entry was made on."""
PHYSICS_ADDED_LATER = {"layout": "circle", "start_edge": 1.0, "rim_shape": "cylinder"}
"""PhysicsConfig fields newer than env v1, with the value every record written before them used."""


RING_FIELDS = ("border_rim", "rim_shape", "layout", "start_edge", "start_radius", "start_height")
"""The PhysicsConfig fields that make the ring a policy plays on: its rim and where the agents start (the
timestep, integrator, frame skip and memory are not the ring). A policy is trained on one ring, the one its
manifest records (:func:`recorded_physics`), and refused on another unless that is allowed explicitly."""
RINGS = {"v0": V0_PHYSICS, "v1": V1_PHYSICS, "v2": PhysicsConfig()}
"""The default simulation of each env version: the ring of a record (a policy manifest) that names its env version
(``env_version``) but holds no ``physics``."""


class RingError(ValueError):
    """A record names no valid ring (:func:`recorded_physics`), or a policy was trained on another ring than the
    match it is loaded into (:func:`ring_problem`)."""


def ring_of(physics: PhysicsConfig) -> dict[str, object]:
    """The fields of :data:`RING_FIELDS` that shape ``physics``' ring: the rim's shape only where it collides
    (``border_rim``), ``start_edge`` only for the fair layout and ``start_radius`` only for the circle."""
    ring: dict[str, object] = {"border_rim": physics.border_rim, "layout": physics.layout,
                               "start_height": physics.start_height}
    if physics.border_rim:
        ring["rim_shape"] = physics.rim_shape
    if physics.layout == "fair":
        ring["start_edge"] = physics.start_edge
    else:
        ring["start_radius"] = physics.start_radius
    return ring


def describe_ring(physics: PhysicsConfig) -> str:
    """``physics``' ring in words, e.g. "a box rim, the fair start 1.0 m from the edges (env v2's ring)"."""
    rim = f"a {physics.rim_shape} rim" if physics.border_rim else "no rim (visual border markers)"
    start = (f"the fair start {physics.start_edge} m from the edges" if physics.layout == "fair"
             else f"the circle start of radius {physics.start_radius} m")
    height = f", torsos {physics.start_height} m high" if physics.start_height != PhysicsConfig().start_height else ""
    versions = [v for v, p in RINGS.items() if ring_of(p) == ring_of(physics)]
    return f"{rim}, {start}{height}" + (f" (env {versions[-1]}'s ring)" if versions else "")


def ring_problem(trained: PhysicsConfig, match: PhysicsConfig) -> str | None:
    """Why a policy trained on the simulation ``trained`` does not play on ``match``'s ring (both rings in words,
    the fields that differ and the options that give its own), or ``None`` on the same ring."""
    a, b = ring_of(trained), ring_of(match)
    if a == b:
        return None
    differ = [f for f in RING_FIELDS if (f in a or f in b) and getattr(trained, f) != getattr(match, f)]
    own = " ".join(_flag(f, getattr(trained, f)) for f in differ)
    return (f"the policy was trained on another ring: {describe_ring(trained)}; this match is on "
            f"{describe_ring(match)} (they differ in {', '.join(f'physics.{f}' for f in differ)}). Play it on its own "
            f"ring ({own}), or say that it may play on this one (--allow-other-ring; allow_other_ring=True in Python)")


def _flag(field: str, value: object) -> str:
    """The command-line option that sets PhysicsConfig ``field`` to ``value``."""
    name = "physics." + field.replace("_", "-")
    if isinstance(value, bool):
        return f"--{name}" if value else f"--no-{name}"
    return f"--{name} {value}"


def recorded_physics(record: Mapping[str, object], where: str = "the record") -> PhysicsConfig:
    """The simulation a record (a policy manifest) says it was made on: its ``physics`` (fields newer than the record
    filled in as env v0 and v1 ran them, :func:`physics_record`), else the default simulation of the env version it
    names (:data:`RINGS`; a record naming none is env v0's, made before either was recorded). :class:`RingError`
    naming ``where`` and the field for a ``physics`` that is no valid PhysicsConfig, an unknown env version without
    one, or a ``physics`` that its env version could not have written (a v1 record with v2's fair layout)."""
    version = record.get("env_version", "v0")
    if "physics" not in record:
        if not isinstance(version, str) or version not in RINGS:
            raise RingError(f"{where}: env_version {version!r} is none of {sorted(RINGS)} and it records no physics: "
                            "the ring it was made on is unknown")
        return RINGS[version]
    data = record["physics"]
    if not isinstance(data, dict):
        raise RingError(f"{where}: physics must be a JSON object of PhysicsConfig's fields, got {data!r}")
    known = {f.name for f in fields(PhysicsConfig)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise RingError(f"{where}: physics has unknown field(s) {unknown} (a PhysicsConfig has {sorted(known)})")
    try:
        physics = PhysicsConfig(**{**{k: v for k, v in PHYSICS_ADDED_LATER.items() if k not in data}, **data})
    except (TypeError, ValueError) as exc:
        raise RingError(f"{where}: physics: {exc}") from None
    if version in ("v0", "v1"):  # fields those versions did not have can only hold what they ran
        newer = [k for k, v in PHYSICS_ADDED_LATER.items() if data.get(k, v) != v]
        if newer:
            ran = ", ".join(f"{k}={PHYSICS_ADDED_LATER[k]!r}" for k in newer)
            raise RingError(f"{where}: env_version {version!r} contradicts its physics: "
                            + ", ".join(f"physics.{k} {data[k]!r}" for k in newer) + f" (env {version} ran {ran})")
    return physics


def physics_record(data: object) -> object:
    """A physics record (``asdict(PhysicsConfig)`` read back from JSON) with the fields it predates
    filled in as env v0/v1 ran them; anything that is not a dict is returned as it is (for the caller
    to refuse by name)."""
    if not isinstance(data, dict):
        return data
    return {**{k: v for k, v in PHYSICS_ADDED_LATER.items() if k not in data}, **data}
