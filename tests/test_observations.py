"""Observation modes against plain references written agent by agent from the module docstring."""

from __future__ import annotations

import numpy as np
import pytest

from triplesumo.envs.match import Match
from triplesumo.model import AgentSpec
from triplesumo.rules import MatchConfig, ResetNoise


def reference_egocentric(match: Match) -> list[np.ndarray]:
    """rules/observations.py's ``egocentric`` layout, one agent at a time."""
    sim, obs = match.sim, []
    forces = np.clip(sim.contact_forces_reference(), -match.config.contact_force_clip, match.config.contact_force_clip)
    pos, vel, quat = sim.torso_positions(), sim.torso_velocities(), sim.torso_quaternions()
    g = sim.geom_counts[0]
    for i, a in enumerate(sim.agents):
        w, x, y, z = quat[i]
        yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        to_heading = np.array([[np.cos(yaw), np.sin(yaw), 0], [-np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        others = [*match.teams.partners[i], *match.teams.opponents[i]]
        blocks = [[pos[i, 2]], quat[i], sim.data.qpos[a.joint_qpos], to_heading @ vel[i],
                  sim.torso_angular_velocities()[i], sim.data.qvel[a.joint_qvel],
                  [2.0 - max(abs(pos[i, 0]), abs(pos[i, 1]))]]
        for j in others:
            blocks += [to_heading @ (pos[j] - pos[i]), to_heading @ (vel[j] - vel[i])]
        blocks.append((forces[i * g:(i + 1) * g] @ to_heading.T).ravel())
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
    """At a noise-free start every agent faces the centre: the others are ahead (+x), left and right (+-y)."""
    match = Match(MatchConfig(obs_mode="egocentric", reset_noise=ResetNoise(0, 0, 0, 0)))
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
