"""Compile the match's ``MjModel`` from the tatami scene and one body per agent.

Each agent's body (:mod:`triplesumo.model.bodies`: ant, bug or spider) is attached with
``mujoco.MjSpec.attach`` under the agent's name prefix (as dm_control's composer attaches
PyMJCF models), then given the agent's colour and control range. Start poses
(:mod:`triplesumo.model.layout`): agents evenly spaced on a circle of
``PhysicsConfig.start_radius``, the first at angle 0, each facing the centre, widened
and turned only where bodies would touch (env v0, v1), or the fair layout (v2: every torso as far
from the edges); the compiled ``qpos0`` is that start pose.
``PhysicsConfig.border_rim`` (the default) turns the border markers into the paper's solid rim, and
``PhysicsConfig.rim_shape`` (``box`` since env v2) gives it a shape both engines collide alike.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from triplesumo.model import names
from triplesumo.model.bodies import TORSO_HEIGHT, body_spec
from triplesumo.model.layout import RIM_HALF_WIDTH, fair_layout, start_layout
from triplesumo.model.specs import AgentSpec, PhysicsConfig, validate_roster

_INTEGRATOR = {
    "RK4": mujoco.mjtIntegrator.mjINT_RK4,
    "Euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
}


START_MARGIN = 0.15
"""Torsos start at least this far (m) inside the ring's edge."""


def build_spec(agents: tuple[AgentSpec, ...], physics: PhysicsConfig) -> mujoco.MjSpec:
    """The uncompiled scene: tatami plus one prefixed body per agent."""
    validate_roster(agents)
    spec = mujoco.MjSpec.from_file(str(names.TATAMI_XML))
    spec.option.timestep = physics.timestep
    spec.option.integrator = _INTEGRATOR[physics.integrator]
    spec.memory = _memory_bytes(physics.memory)
    half_size = abs(float(spec.geom(names.RING_MARKER_GEOM).fromto[0]))
    for name in names.BORDER_GEOMS:
        geom = spec.geom(name)
        if physics.border_rim:  # the paper's solid rim: MuJoCo's default flags, as RoboSumo's tatami.xml leaves them
            geom.contype, geom.conaffinity = 1, 1
        if physics.rim_shape == "box":
            _cylinder_to_box(geom)
    poses = start_poses([a.body for a in agents], physics, half_size)
    for agent, (x, y, yaw) in zip(agents, poses, strict=True):
        quat = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        frame = spec.worldbody.add_frame(pos=[x, y, physics.start_height - TORSO_HEIGHT], quat=quat)
        spec.attach(body_spec(agent.body), prefix=names.prefix(agent.name), frame=frame)
    pre = {a.name: names.prefix(a.name) for a in agents}
    by_prefix = {a.name: a for a in agents}
    for geom in spec.geoms:
        owner = _owner(geom.name, pre)
        if owner is not None:
            geom.rgba = list(by_prefix[owner].rgba)
    for act in spec.actuators:
        owner = _owner(act.name, pre)
        if owner is None:
            raise RuntimeError(f"actuator {act.name!r} belongs to no agent")
        r = by_prefix[owner].ctrl_range
        act.ctrlrange = [-r, r]
    return spec


def start_poses(bodies: list[str], physics: PhysicsConfig, half_size: float) -> list[tuple[float, float, float]]:
    """``(x, y, yaw)`` of each torso at the start (:mod:`triplesumo.model.layout`): the fair layout where
    ``physics.layout`` asks for it and the roster fits it, else the circle layout."""
    if physics.layout == "fair":
        fair = fair_layout(bodies, physics.start_edge, half_size)
        if fair is not None:
            return fair
    return start_layout(bodies, physics.start_radius, half_size - START_MARGIN)


def _cylinder_to_box(geom: mujoco.MjsGeom) -> None:
    """Turn a border cylinder (``fromto`` along the edge, radius ``RIM_HALF_WIDTH``) into a box of the
    same height and width whose length covers the corners (MuJoCo Warp collides boxes as MuJoCo does)."""
    start, end = np.array(geom.fromto[:3]), np.array(geom.fromto[3:])
    r = float(geom.size[0])
    assert abs(r - RIM_HALF_WIDTH) < 1e-9, "the rim's width is the layout's"
    half = np.abs(end - start) / 2 + r
    geom.type = mujoco.mjtGeom.mjGEOM_BOX
    geom.pos = (start + end) / 2
    geom.size = [max(half[0], r), max(half[1], r), r]
    geom.fromto = [np.nan] * 6


def build_model(agents: tuple[AgentSpec, ...], physics: PhysicsConfig) -> mujoco.MjModel:
    """Compile the match model."""
    return build_spec(agents, physics).compile()


def ring_half_size(model: mujoco.MjModel) -> float:
    """Playable half-size of the ring, read from the border marker in the MJCF."""
    gid = model.geom(names.RING_MARKER_GEOM).id
    return float(np.abs(model.geom_pos[gid, 0]))


def tatami_top(model: mujoco.MjModel) -> float:
    """Height of the tatami's top surface."""
    gid = model.geom(names.TATAMI_GEOM).id
    return float(model.geom_pos[gid, 2] + model.geom_size[gid, 2])


def _owner(name: str, prefixes: dict[str, str]) -> str | None:
    for agent, p in prefixes.items():
        if name.startswith(p):
            return agent
    return None


def _memory_bytes(text: str) -> int:
    scale = {"K": 2**10, "M": 2**20, "G": 2**30}
    if text[-1] in scale:
        return int(text[:-1]) * scale[text[-1]]
    return int(text)
