"""Physics model: the tatami scene and one quadruped per agent, compiled with MjSpec."""

from triplesumo.model.builder import build_model, build_spec, ring_half_size, start_layout, tatami_top
from triplesumo.model.specs import PAPER_AGENTS, AgentSpec, PhysicsConfig

__all__ = [
    "PAPER_AGENTS",
    "AgentSpec",
    "PhysicsConfig",
    "build_model",
    "build_spec",
    "ring_half_size",
    "start_layout",
    "tatami_top",
]
