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


def test_general_paths_give_what_the_fast_paths_give() -> None:
    """The quadruped takes the fast paths (contiguous bodies and actuators); the general ones must agree."""
    fast, general = Match(), Match()
    sim = general.sim
    assert fast.sim._body_forces is not None and fast.sim._ctrl_view is not None
    sim._body_forces, sim._ctrl_view = None, None  # contact by contact; controls by fancy indexing
    for m in (fast, general):
        m.reset(seed=6)
    rng = np.random.default_rng(6)
    for _ in range(60):
        action = rng.uniform(-1, 1, (3, 8))
        a, b = fast.step_array(action), general.step_array(action)
        np.testing.assert_allclose(a.observations[0], b.observations[0], rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(fast.data.ctrl, general.data.ctrl)
        np.testing.assert_array_equal(fast.data.qpos, general.data.qpos)


def test_only_new_watched_warnings_are_reported_once() -> None:
    match = Match()
    match.reset(seed=0)
    sim = match.sim
    number = sim.data.warning.number
    assert sim.new_warnings() == []
    number[int(mujoco.mjtWarning.mjWARN_INERTIA)] += 1  # not watched: not a reason to stop a match
    assert sim.new_warnings() == []
    number[int(mujoco.mjtWarning.mjWARN_BADQACC)] += 1
    assert sim.new_warnings() == ["bad_qacc"]
    assert sim.new_warnings() == []  # reported once
    snapshot = sim.warnings_seen()
    number[int(mujoco.mjtWarning.mjWARN_CONTACTFULL)] += 2
    sim.set_warnings_seen(snapshot)
    assert sim.new_warnings() == ["contact_full"]
