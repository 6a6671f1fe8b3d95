"""Observation modes against plain references written agent by agent from the module docstring."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from triplesumo.envs.match import Match
from triplesumo.model import AgentSpec, PhysicsConfig
from triplesumo.rules import MatchConfig, ResetNoise


def reference_egocentric(match: Match) -> list[np.ndarray]:
    """rules/observations.py's ``egocentric`` layout, one agent at a time."""
    sim, obs = match.sim, []
    clip = match.config.contact_force_clip
    forces = sim.contact_forces_reference()
    pos, vel, quat = sim.torso_positions(), sim.torso_velocities(), sim.torso_quaternions()
    g = sim.geom_counts[0]
    for i, a in enumerate(sim.agents):
        w, x, y, z = quat[i]
        yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        to_heading = np.array([[np.cos(yaw), np.sin(yaw), 0], [-np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        inverse_yaw, orientation = np.zeros(4), np.zeros(4)
        mujoco.mju_axisAngle2Quat(inverse_yaw, np.array([0.0, 0.0, 1.0]), -yaw)
        mujoco.mju_mulQuat(orientation, inverse_yaw, quat[i])
        orientation *= np.sign(orientation[0])
        others = [*match.teams.partners[i], *match.teams.opponents[i]]
        blocks = [[pos[i, 2]], orientation, sim.data.qpos[a.joint_qpos], to_heading @ vel[i],
                  sim.torso_angular_velocities()[i], sim.data.qvel[a.joint_qvel],
                  [2.0 - max(abs(pos[i, 0]), abs(pos[i, 1]))]]
        for j in others:
            blocks += [to_heading @ (pos[j] - pos[i]), to_heading @ (vel[j] - vel[i])]
        blocks.append(np.clip(forces[i * g:(i + 1) * g] @ to_heading.T, -clip, clip).ravel())
        obs.append(np.concatenate(blocks))
    return obs


@pytest.mark.parametrize(
    "agents",
    [None, (AgentSpec("p0", "p", 0.2), AgentSpec("p1", "p", 0.2), AgentSpec("p2", "p", 0.2),
            AgentSpec("e", "e", 0.22))],
    ids=["paper-roster", "3-vs-1"],
)
def test_egocentric_observations_equal_the_reference_over_a_rollout(agents) -> None:
    config = MatchConfig(obs_mode="egocentric") if agents is None else MatchConfig(obs_mode="egocentric",
                                                                                   agents=agents)
    match = Match(config)
    obs, _ = match.reset(seed=2)
    rng = np.random.default_rng(2)
    contacts = 0
    for _ in range(120):
        for got, want in zip(obs, reference_egocentric(match), strict=True):
            assert got.dtype == np.float32
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
        result = match.step_array(rng.uniform(-1, 1, (match.n_agents, 8)))
        obs = result.observations
        contacts += match.data.ncon
        if match.over:
            obs, _ = match.reset()
    assert contacts > 100


def test_egocentric_frame_puts_the_ring_centre_ahead() -> None:
    """At a noise-free start on the circle layout every agent faces the centre: the others are ahead (+x), left
    and right (+-y). (The fair layout turns each agent 45 degrees off the centre.)"""
    match = Match(MatchConfig(obs_mode="egocentric", reset_noise=ResetNoise(0, 0, 0, 0),
                              physics=PhysicsConfig(layout="circle")))
    obs, _ = match.reset(seed=0)
    structure = match.observer.structure
    for agent, o in zip(match.agents, obs, strict=True):
        offsets = np.cumsum([0, *structure[agent].values()])
        block = dict(zip(structure[agent], (o[s:e] for s, e in zip(offsets[:-1], offsets[1:], strict=True)),
                         strict=True))
        rel = [block[f"{other}_position"] for other in match.agents if other != agent]
        assert all(r[0] > 1.0 for r in rel), (agent, rel)
        assert sorted(np.sign(r[1]) for r in rel) == [-1.0, 1.0], (agent, rel)
        assert block["edge_distance"][0] == pytest.approx(2.0 - max(abs(match.sim.torso_positions()[
            match.agents.index(agent), :2])), abs=1e-6)


def test_paper_observation_is_the_global_state_for_every_agent_and_not_shared() -> None:
    match = Match()
    obs, _ = match.reset(seed=0)
    for _ in range(40):
        obs = match.step_array(np.zeros((3, 8))).observations
    sim = match.sim
    clip = match.config.contact_force_clip
    want = np.concatenate([sim.torso_positions().ravel(), sim.torso_velocities().ravel(),
                           np.clip(sim.contact_forces_reference(), -clip, clip).ravel(),
                           sim.data.qpos, sim.data.qvel]).astype(np.float32)
    for o in obs:
        np.testing.assert_allclose(o, want, rtol=1e-6, atol=1e-6)
    obs[0][:] = 0.0
    assert np.abs(obs[1]).sum() > 0  # each agent gets its own array


def _blocks(match: Match, obs: list[np.ndarray]) -> list[dict[str, np.ndarray]]:
    out = []
    for agent, o in zip(match.agents, obs, strict=True):
        sizes = match.observer.structure[agent]
        offsets = np.cumsum([0, *sizes.values()])
        out.append({k: o[s:e] for k, s, e in zip(sizes, offsets[:-1], offsets[1:], strict=True)})
    return out


def test_self_orientation_is_the_heading_frame_quaternion() -> None:
    """An upright agent yawed by 90 degrees reads the identity in its own heading frame (the world
    quaternion would read cos 45, 0, 0, sin 45); a tilted one reads its tilt only, w >= 0."""
    match = Match(MatchConfig(obs_mode="egocentric", reset_noise=ResetNoise(0, 0, 0, 0)))
    match.reset(seed=0)
    sim = match.sim
    qpos, qvel = sim.data.qpos.copy(), np.zeros(sim.model.nv)
    roll = np.zeros(4)
    mujoco.mju_axisAngle2Quat(roll, np.array([1.0, 0.0, 0.0]), 0.3)
    yawed, tilted = np.zeros(4), np.zeros(4)
    mujoco.mju_axisAngle2Quat(yawed, np.array([0.0, 0.0, 1.0]), np.pi / 2)
    mujoco.mju_mulQuat(tilted, yawed, roll)
    qpos[sim.quat_qpos[0]] = yawed
    qpos[sim.quat_qpos[1]] = -tilted  # the same rotation, the other sign
    sim.reset(qpos, qvel)
    blocks = _blocks(match, match.observer.build())
    np.testing.assert_allclose(blocks[0]["self_orientation"], [1.0, 0.0, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(blocks[1]["self_orientation"], roll, atol=1e-6)


def test_contact_forces_are_rotated_then_clipped() -> None:
    """With a small clip most contact forces saturate; no heading-frame component exceeds it (clipping
    on world axes and rotating after lets components reach sqrt(2) times the clip)."""
    clip = 2.0
    match = Match(MatchConfig(obs_mode="egocentric", contact_force_clip=clip))
    match.reset(seed=3)
    rng = np.random.default_rng(3)
    at_clip = 0
    for _ in range(40):
        obs = match.step_array(rng.uniform(-1, 1, (match.n_agents, 8))).observations
        for b in _blocks(match, obs):
            forces = b["contact_force"]
            assert np.abs(forces).max() <= clip + 1e-6
            at_clip += int(np.sum(np.isclose(np.abs(forces), clip)))
        if match.over:
            match.reset()
    assert at_clip > 20
