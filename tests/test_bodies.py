"""RoboSumo's three bodies: sizes and ranges from the compiled model, mixed rosters, start poses."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from triplesumo.envs.match import Match
from triplesumo.envs.parallel import TripleSumoParallelEnv
from triplesumo.model import BODIES, BODIES_AGENTS, PAPER_AGENTS, AgentSpec, PhysicsConfig, build_model
from triplesumo.model.layout import gap_between, start_layout
from triplesumo.model.specs import BLUE, GREEN, RED
from triplesumo.rules.config import MatchConfig, ResetNoise

MOTORS = {"ant": 8, "bug": 12, "spider": 16}
GEOMS = {"ant": 13, "bug": 19, "spider": 25}


@pytest.fixture(scope="module")
def mixed() -> Match:
    return Match(MatchConfig(agents=BODIES_AGENTS))


def test_bodies_agents_is_the_paper_match_with_three_bodies() -> None:
    assert [a.body for a in PAPER_AGENTS] == ["ant", "ant", "ant"]
    assert [a.body for a in BODIES_AGENTS] == ["ant", "bug", "spider"]
    assert [dataclasses.replace(a, body="ant") for a in BODIES_AGENTS] == list(PAPER_AGENTS)


def test_action_sizes_follow_the_bodies(mixed: Match) -> None:
    assert mixed.action_sizes == (8, 12, 16)
    assert mixed.action_width == 16
    model = mixed.model
    for agent in mixed.agents:
        body = model.body(f"{agent}/torso").id
        hinges = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
                  and model.body_rootid[model.jnt_bodyid[j]] == body]
        motors = [i for i in range(model.nu) if model.actuator(i).name.startswith(f"{agent}/")]
        assert len(hinges) == len(motors) == MOTORS[agent]
        assert len(mixed.sim.agents[mixed.agents.index(agent)].geoms) == GEOMS[agent]
    env = TripleSumoParallelEnv(MatchConfig(agents=BODIES_AGENTS))
    assert {a: env.action_space(a).shape for a in env.possible_agents} == {
        "ant": (8,), "bug": (12,), "spider": (16,)}


def test_control_ranges_are_read_from_the_compiled_model(mixed: Match) -> None:
    model, sim = mixed.model, mixed.sim
    for i, spec in enumerate(BODIES_AGENTS):
        n = MOTORS[spec.body]
        ids = sim.actuator_ids[i, :n]
        assert [model.actuator(k).name for k in ids] == [
            f"{spec.name}/{kind}_{leg}" for leg in range(1, n // 2 + 1) for kind in ("hip", "ankle")]
        np.testing.assert_array_equal(sim.ctrl_low[i, :n], model.actuator_ctrlrange[ids, 0])
        np.testing.assert_array_equal(sim.ctrl_high[i, :n], model.actuator_ctrlrange[ids, 1])
        np.testing.assert_allclose(model.actuator_ctrlrange[ids], [[-spec.ctrl_range, spec.ctrl_range]] * n)
        assert (sim.ctrl_high[i, n:] == 0).all() and (sim.actuator_ids[i, n:] == -1).all()


def test_every_motor_of_the_largest_body_is_driven(mixed: Match) -> None:
    """The spider's last action value reaches its last motor (ankle_8), scaled to its range."""
    mixed.reset(seed=0)
    actions = np.zeros((3, 16))
    actions[2, 15] = 1.0
    ctrl = mixed.prepare(actions)
    mixed.sim.step(ctrl)
    spider_ankle_8 = mixed.model.actuator("spider/ankle_8").id
    assert mixed.data.ctrl[spider_ankle_8] == pytest.approx(0.22)
    assert np.count_nonzero(mixed.data.ctrl) == 1


def test_padding_columns_are_ignored(mixed: Match) -> None:
    actions = np.random.default_rng(0).uniform(-1, 1, (3, 16))
    actions[0, 8:] = 0.0
    actions[1, 12:] = 0.0
    mixed.reset(seed=3)
    clean = mixed.step_array(actions).observations
    padded = actions.copy()
    padded[0, 8:], padded[1, 12:] = np.nan, 5.0
    mixed.reset(seed=3)
    assert all(np.array_equal(a, b) for a, b in zip(mixed.step_array(padded).observations, clean, strict=True))


def test_wrong_action_size_names_the_agent_and_its_size(mixed: Match) -> None:
    mixed.reset(seed=0)
    with pytest.raises(ValueError, match=r"action of 'bug' must have shape \(12,\)"):
        mixed.actions_from_dict({"ant": np.zeros(8), "bug": np.zeros(8), "spider": np.zeros(16)})
    with pytest.raises(ValueError, match=r"actions must have shape \(3, 16\)"):
        mixed.step_array(np.zeros((3, 8)))


def test_unknown_body_is_refused_naming_the_field() -> None:
    with pytest.raises(ValueError, match=r"AgentSpec.body of 'ant' must be one of \['ant', 'bug', 'spider'\]"):
        AgentSpec("ant", "a", 0.2, body="snake")


def test_egocentric_structure_follows_each_body() -> None:
    match = Match(MatchConfig(agents=BODIES_AGENTS, obs_mode="egocentric"))
    obs, _ = match.reset(seed=1)
    for i, spec in enumerate(BODIES_AGENTS):
        s = match.observer.structure[spec.name]
        assert s["self_joint_position"] == s["self_joint_velocity"] == MOTORS[spec.body]
        assert s["contact_force"] == 3 * GEOMS[spec.body]
        assert obs[i].shape == (sum(s.values()),)
        joints = match.sim.agents[i].joint_qpos
        start = 1 + 4
        np.testing.assert_array_equal(obs[i][start:start + len(joints)], match.data.qpos[joints].astype(np.float32))
    paper = Match(MatchConfig(agents=BODIES_AGENTS)).observer.sizes
    assert len(set(paper.values())) == 1  # the paper's global vector, the same for all


@pytest.mark.parametrize("obs_mode", ["paper", "egocentric"])
def test_mixed_bodies_pass_pettingzoo_checks(obs_mode: str) -> None:
    cfg = MatchConfig(agents=BODIES_AGENTS, obs_mode=obs_mode, max_steps=40)
    parallel_api_test(TripleSumoParallelEnv(cfg), num_cycles=60)
    parallel_seed_test(lambda: TripleSumoParallelEnv(cfg))


def _contacts_between_agents(match: Match) -> list[tuple[str, str]]:
    out = []
    for c in match.data.contact[:match.data.ncon]:
        a, b = (match.model.geom(g).name.partition("/")[0] for g in (c.geom1, c.geom2))
        if a in match.agents and b in match.agents and a != b:
            out.append((a, b))
    return out


ROSTER_COLOURS = (RED, BLUE, GREEN, (0.9, 0.8, 0.1, 1.0), (0.6, 0.2, 0.8, 1.0), (0.1, 0.8, 0.8, 1.0))


@pytest.mark.parametrize("bodies", [
    *[(kind,) * n for kind in ("ant", "bug", "spider") for n in range(2, 7)],
    ("spider", "ant", "bug", "spider", "ant", "bug"), ("bug", "bug", "spider", "ant", "ant"),
], ids=lambda b: "-".join(b))
def test_start_poses_are_contact_free_inside_the_ring(bodies: tuple[str, ...]) -> None:
    agents = tuple(AgentSpec(f"a{i}", f"t{i}", 0.2, ROSTER_COLOURS[i], body=b) for i, b in enumerate(bodies))
    match = Match(MatchConfig(agents=agents, reset_noise=ResetNoise(0.0, 0.0, 0.0, 0.0)))
    match.reset(seed=0)
    assert _contacts_between_agents(match) == []
    pos = match.sim.torso_positions()
    assert np.abs(pos[:, :2]).max() < match.half_size - 0.1
    gaps = [gap_between(bodies[i], p, bodies[j], q) for i, p in enumerate(match_poses(match))
            for j, q in enumerate(match_poses(match)) if i < j]
    assert min(gaps) >= 0.05


def match_poses(match: Match) -> list[tuple[float, float, float]]:
    """``(x, y, yaw)`` of every torso, read back from the compiled start pose."""
    out = []
    for a in match.sim.agents:
        x, y, _, w, _, _, z = match.model.qpos0[a.root_qpos:a.root_qpos + 7]
        out.append((float(x), float(y), float(2 * np.arctan2(z, w))))
    return out


def test_the_paper_start_pose_is_unchanged() -> None:
    """Three ants on a circle of 1.4 m, facing the centre: clear enough, so not widened or turned."""
    poses = start_layout(["ant"] * 3, 1.4, 1.85)
    for i, (x, y, yaw) in enumerate(poses):
        angle = 2 * np.pi * i / 3
        assert (x, y, yaw) == (1.4 * np.cos(angle), 1.4 * np.sin(angle), angle + np.pi)


def test_crowded_rosters_are_widened_and_turned_then_refused() -> None:
    poses = start_layout(["ant"] * 6, 1.4, 1.85)
    assert np.hypot(*poses[0][:2]) > 1.4
    with pytest.raises(ValueError, match=r"cannot place bodies \['ant', 'ant', 'ant', 'ant', 'ant', 'ant'\]"):
        start_layout(["ant"] * 6, 1.4, 1.45)


@pytest.mark.parametrize(("kind_a", "kind_b", "pose_b"), [
    ("ant", "spider", (1.9, 0.3, 2.0)), ("bug", "bug", (2.3, 0.0, 0.4)), ("spider", "ant", (1.5, 1.0, 1.0)),
])
def test_layout_gaps_equal_mujocos_geom_distances(kind_a: str, kind_b: str, pose_b: tuple[float, float, float]
                                                  ) -> None:
    """The layout's capsule geometry is the compiled bodies': its gap is MuJoCo's own distance."""
    agents = (AgentSpec("a", "x", 0.2, body=kind_a), AgentSpec("b", "y", 0.2, body=kind_b))
    model = build_model(agents, PhysicsConfig(start_radius=1.0))
    data = mujoco.MjData(model)
    qpos = model.qpos0.copy()
    x, y, yaw = pose_b
    b_root = model.joint("b/root").qposadr[0]
    qpos[model.joint("a/root").qposadr[0]:][:7] = [0, 0, 1.25, 1, 0, 0, 0]
    qpos[b_root:b_root + 7] = [x, y, 1.25, np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    geoms = {k: [g for g in range(model.ngeom) if model.geom(g).name.startswith(f"{k}/")] for k in "ab"}
    fromto = np.zeros(6)
    mj = min(mujoco.mj_geomDistance(model, data, g, h, 10.0, fromto) for g in geoms["a"] for h in geoms["b"])
    ours = gap_between(kind_a, (0.0, 0.0, 0.0), kind_b, pose_b)
    assert ours == pytest.approx(mj, abs=1e-6)
    assert set(BODIES) == {"ant", "bug", "spider"}


@pytest.mark.parametrize("backend", ["mujoco", "threads"])
def test_a_batch_of_mixed_body_matches_steps_like_single_matches(backend: str) -> None:
    from triplesumo.envs.batch import MatchBatch

    cfg = MatchConfig(agents=BODIES_AGENTS, max_steps=30)
    actions = np.random.default_rng(1).uniform(-1, 1, (5, 2, 3, 16))
    singles = [Match(cfg) for _ in range(2)]
    with MatchBatch(cfg, 2, 1, stepper=backend) as batch:
        for k in range(2):
            batch.reset_one(k, seed=k)
            singles[k].reset(seed=k)
        for step in actions:
            results = batch.step(step)
            for k, match in enumerate(singles):
                want = match.step_array(step[k]).observations
                assert all(np.array_equal(a, b) for a, b in zip(results[k].observations, want, strict=True))
