"""Simulation-level invariants: contact forces and their fast path."""

from __future__ import annotations

import mujoco
import numpy as np

from triplesumo.envs.match import Match


def test_contact_forces_equal_the_sum_of_mj_contact_force_over_contacts() -> None:
    """The cfrc_ext fast path against mj_contactForce contact by contact, in scrums and on landing."""
    match = Match()
    match.reset(seed=4)
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(200):
        result = match.step_array(rng.uniform(-1, 1, (3, 8)))
        if result.terminated or result.truncated:
            match.reset()
        sim = match.sim
        np.testing.assert_allclose(sim.contact_forces(), sim.contact_forces_reference(), rtol=1e-12, atol=1e-9)
        checked += sim.data.ncon
    assert checked > 100


def test_contact_forces_leave_out_applied_perturbations() -> None:
    """A viewer-style push (xfrc_applied) is an external force but not a contact force."""
    match = Match()
    match.reset(seed=1)
    for _ in range(30):
        match.step_array(np.zeros((3, 8)))
    sim = match.sim
    torso = sim.agents[0].torso_body
    sim.data.xfrc_applied[torso] = [5.0, -3.0, 40.0, 0.1, 0.2, 0.3]
    mujoco.mj_forward(sim.model, sim.data)
    np.testing.assert_allclose(sim.contact_forces(), sim.contact_forces_reference(), atol=1e-9)
    assert np.abs(sim.data.cfrc_ext[torso, 3:]).max() >= 3.0  # cfrc_ext itself does include it


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
