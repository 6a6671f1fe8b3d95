"""Physics model: the tatami scene and one RoboSumo body per agent, compiled with MjSpec."""

from triplesumo.model.bodies import BODIES, BodyPlan
from triplesumo.model.builder import build_model, build_spec, ring_half_size, tatami_top
from triplesumo.model.layout import start_layout
from triplesumo.model.specs import BODIES_AGENTS, PAPER_AGENTS, V0_PHYSICS, V1_PHYSICS, AgentSpec, PhysicsConfig

__all__ = [
    "BODIES",
    "BODIES_AGENTS",
    "PAPER_AGENTS",
    "BodyPlan",
    "AgentSpec",
    "PhysicsConfig",
    "V0_PHYSICS",
    "V1_PHYSICS",
    "build_model",
    "build_spec",
    "ring_half_size",
    "start_layout",
    "tatami_top",
]
