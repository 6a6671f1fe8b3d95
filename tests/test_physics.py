"""Simulation-level invariants: contact forces and their fast path."""

from __future__ import annotations

import mujoco
import numpy as np

from triplesumo.envs.match import Match


def test_vectorised_contact_forces_equal_mj_contact_force() -> None:
    match = Match()
    match.reset(seed=4)
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(200):
        result = match.step_array(rng.uniform(-1, 1, (3, 8)))
        if result.terminated or result.truncated:
            match.reset()
        sim = match.sim
        idx = np.arange(sim.data.ncon)
        fast = sim._contact_frame_forces(idx)
        slow = np.empty((len(idx), 6))
        for i in idx:
            mujoco.mj_contactForce(sim.model, sim.data, int(i), slow[i])
        np.testing.assert_array_equal(fast, slow[:, :3])
        checked += len(idx)
    assert checked > 100


def test_contact_forces_of_an_agent_at_rest_carry_its_weight() -> None:
    from triplesumo.rules.config import MatchConfig, ResetNoise

    match = Match(MatchConfig(reset_noise=ResetNoise(0, 0, 0, 0)))
    match.reset(seed=0)
    for _ in range(60):
        match.step_array(np.zeros((3, 8)))
    forces = match.sim.contact_forces().reshape(3, -1, 3).sum(axis=1)
    weight = match.model.body_mass[match.sim.agents[0].torso_body:].sum() / 3 * 9.81
    np.testing.assert_allclose(forces[:, 2], weight, rtol=0.02)
    np.testing.assert_allclose(forces[:, :2], 0.0, atol=0.05 * weight)
