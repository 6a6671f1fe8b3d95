"""Simulation: step the physics, read per-agent state, render frames. No teams, no rewards."""

from triplesumo.sim.physics import PhysicsError, Simulation

__all__ = ["PhysicsError", "Simulation"]
