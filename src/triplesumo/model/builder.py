"""Compile the match's ``MjModel`` from the tatami scene and one body per agent.

Each agent's body (:mod:`triplesumo.model.bodies`: ant, bug or spider) is attached with
``mujoco.MjSpec.attach`` under the agent's name prefix (as dm_control's composer attaches
PyMJCF models), then given the agent's colour and control range. Start poses
(:mod:`triplesumo.model.layout`): agents evenly spaced on a circle of
``PhysicsConfig.start_radius``, the first at angle 0, each facing the centre, widened
and turned only where bodies would touch; the compiled ``qpos0`` is that start pose.
``PhysicsConfig.border_rim`` (the default) turns the border markers into the paper's solid rim.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from triplesumo.model import names
from triplesumo.model.bodies import TORSO_HEIGHT, body_spec
from triplesumo.model.layout import start_layout
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
    if physics.border_rim:  # the paper's solid rim: MuJoCo's default flags, as RoboSumo's tatami.xml leaves them
        for name in names.BORDER_GEOMS:
            geom = spec.geom(name)
            geom.contype, geom.conaffinity = 1, 1
    half_size = abs(float(spec.geom(names.RING_MARKER_GEOM).fromto[0]))
    poses = start_layout([a.body for a in agents], physics.start_radius, half_size - START_MARGIN)
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
