"""The compiled physics model: names, control ranges, colours, arena, physics options, rosters."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from triplesumo.envs.match import Match
from triplesumo.model import PAPER_AGENTS, V0_PHYSICS, V1_PHYSICS, AgentSpec, PhysicsConfig, build_model, ring_half_size
from triplesumo.model import names as mjcf_names
from triplesumo.model.specs import BLUE, GREEN, RED
from triplesumo.rules.config import MatchConfig, ResetNoise, RewardConfig


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return build_model(PAPER_AGENTS, PhysicsConfig())


def _actuator_names(model: mujoco.MjModel) -> list[str]:
    return [model.actuator(i).name for i in range(model.nu)]


# ------------------------------------------------------------------ names and ranges
@pytest.mark.parametrize(("agent", "limit"), [("spider", 0.22), ("ant", 0.20), ("bug", 0.18)])
def test_control_ranges_read_back_from_compiled_model(model: mujoco.MjModel, agent: str, limit: float) -> None:
    ids = [i for i, n in enumerate(_actuator_names(model)) if n.startswith(f"{agent}/")]
    assert len(ids) == 8
    ranges = model.actuator_ctrlrange[ids]
    np.testing.assert_allclose(ranges[:, 0], -limit, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ranges[:, 1], limit, rtol=0, atol=1e-12)
    assert model.actuator_ctrllimited[ids].all()


def test_every_actuator_belongs_to_an_agent_and_each_has_eight(model: mujoco.MjModel) -> None:
    prefixes = [n.split("/")[0] for n in _actuator_names(model)]
    assert sorted(set(prefixes)) == ["ant", "bug", "spider"]
    assert {p: prefixes.count(p) for p in set(prefixes)} == {"ant": 8, "bug": 8, "spider": 8}
    assert model.nu == 24


@pytest.mark.parametrize(
    ("kind", "name"),
    [
        (mujoco.mjtObj.mjOBJ_BODY, "spider/torso"),
        (mujoco.mjtObj.mjOBJ_JOINT, "spider/root"),
        (mujoco.mjtObj.mjOBJ_BODY, "ant/torso"),
        (mujoco.mjtObj.mjOBJ_JOINT, "bug/root"),
        (mujoco.mjtObj.mjOBJ_BODY, "bug/torso"),
        (mujoco.mjtObj.mjOBJ_JOINT, "ant/root"),
    ],
)
def test_prefixed_names_exist(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> None:
    assert mujoco.mj_name2id(model, kind, name) >= 0


def test_root_joints_are_free_joints(model: mujoco.MjModel) -> None:
    for agent in ("ant", "bug", "spider"):
        assert model.joint(f"{agent}/root").type[0] == mujoco.mjtJoint.mjJNT_FREE


def test_no_hand_suffixed_copies_of_the_paper_code(model: mujoco.MjModel) -> None:
    """The paper's code named copies ``torso2``, ``hip_12``...; ours has none of those names."""
    for name in ("torso", "torso1", "torso2", "torso3", "hip_12", "root2"):
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name) == -1
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name) == -1


def test_exactly_one_body_mjcf_in_assets_and_no_hand_written_legs() -> None:
    xmls = sorted(mjcf_names.ASSETS.glob("*.xml"))
    assert xmls == sorted([mjcf_names.BODY_XML, mjcf_names.TATAMI_XML])
    assert not any("<actuator" in p.read_text() or "type=\"hinge\"" in p.read_text() for p in xmls)
    body = mujoco.MjModel.from_xml_path(str(mjcf_names.BODY_XML))
    assert body.nu == 0
    assert body.njnt == 1  # the free joint: legs are grown by triplesumo.model.bodies


# -------------------------------------------------------------------------- colours
@pytest.mark.parametrize(("agent", "channel"), [("ant", 0), ("spider", 1), ("bug", 2)])
def test_agent_geoms_are_coloured_by_agent(model: mujoco.MjModel, agent: str, channel: int) -> None:
    ids = [g for g in range(model.ngeom) if model.geom(g).name.startswith(f"{agent}/")]
    assert len(ids) == 13
    rgb = model.geom_rgba[ids, :3]
    others = [c for c in range(3) if c != channel]
    assert (rgb[:, channel] > rgb[:, others].max(axis=1) + 0.2).all(), rgb


def test_colours_are_the_specs(model: mujoco.MjModel) -> None:
    for agent, rgba in (("ant", RED), ("bug", BLUE), ("spider", GREEN)):
        np.testing.assert_allclose(model.geom(f"{agent}/torso_geom").rgba, rgba, atol=1e-6)


# ---------------------------------------------------------------- arena and physics
def test_ring_half_size_is_two_from_the_model(model: mujoco.MjModel) -> None:
    assert ring_half_size(model) == pytest.approx(2.0)
    assert model.geom("border_left").pos[0] == pytest.approx(-2.0)


def test_physics_defaults_are_the_papers(model: mujoco.MjModel) -> None:
    assert PhysicsConfig().frame_skip == 5
    assert model.opt.timestep == pytest.approx(0.01)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    match = Match()
    assert match.sim.frame_skip == 5
    assert match.sim.dt == pytest.approx(0.05)


def test_physics_config_flows_into_the_model() -> None:
    model = build_model(PAPER_AGENTS, PhysicsConfig(timestep=0.005, integrator="implicitfast"))
    assert model.opt.timestep == pytest.approx(0.005)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST


def test_a_step_advances_frame_skip_physics_steps() -> None:
    match = Match(MatchConfig(physics=PhysicsConfig(frame_skip=3)))
    match.reset(seed=0)
    match.step_array(np.zeros((3, 8)))
    assert match.data.time == pytest.approx(0.03)


# --------------------------------------------------------------------------- rosters
def _pursuit_roster() -> tuple[AgentSpec, ...]:
    return (
        AgentSpec("p0", "pursuers", 0.2, RED),
        AgentSpec("p1", "pursuers", 0.2, RED),
        AgentSpec("p2", "pursuers", 0.2, RED),
        AgentSpec("evader", "evader", 0.22, GREEN),
    )


def _free_for_all() -> tuple[AgentSpec, ...]:
    return (AgentSpec("a", "a", 0.2), AgentSpec("b", "b", 0.2), AgentSpec("c", "c", 0.2))


@pytest.mark.parametrize("agents", [_pursuit_roster(), _free_for_all()], ids=["3-vs-1", "free-for-all"])
def test_other_rosters_compile_and_step(agents: tuple[AgentSpec, ...]) -> None:
    match = Match(MatchConfig(agents=agents, max_steps=20))
    obs, _ = match.reset(seed=1)
    n = len(agents)
    assert match.model.nu == 8 * n
    assert len(obs) == n
    for a in agents:
        assert mujoco.mj_name2id(match.model, mujoco.mjtObj.mjOBJ_JOINT, f"{a.name}/root") >= 0
    start = match.sim.torso_positions().copy()
    rng = np.random.default_rng(0)
    for _ in range(10):
        result = match.step_array(rng.uniform(-1, 1, (n, 8)))
    assert result.rewards.shape == (n,)
    assert len(result.infos) == n
    assert all(np.isfinite(o).all() for o in result.observations)
    assert not np.allclose(match.sim.torso_positions(), start)


def test_pursuit_roster_teams() -> None:
    match = Match(MatchConfig(agents=_pursuit_roster()))
    assert match.teams.names == ("pursuers", "evader")
    assert match.teams.team_of.tolist() == [0, 0, 0, 1]
    assert match.teams.opponents[3].tolist() == [0, 1, 2]
    assert match.teams.partners[0].tolist() == [1, 2]


# ------------------------------------------------------------------------ validation
@pytest.mark.parametrize(
    ("build", "field"),
    [
        (lambda: AgentSpec("ant", "team", -0.2), "ctrl_range"),
        (lambda: AgentSpec("ant", "team", float("nan")), "ctrl_range"),
        (lambda: AgentSpec("ant", "team", 0.0), "ctrl_range"),
        (lambda: AgentSpec("Ant!", "team", 0.2), "name"),
        (lambda: PhysicsConfig(integrator="Verlet"), "integrator"),
        (lambda: PhysicsConfig(timestep=0.0), "timestep"),
        (lambda: PhysicsConfig(frame_skip=0), "frame_skip"),
        (lambda: PhysicsConfig(memory="lots"), "memory"),
        (lambda: PhysicsConfig(border_rim=1), "border_rim"),
        (lambda: MatchConfig(obs_mode="pixels"), "obs_mode"),
        (lambda: MatchConfig(max_steps=0), "max_steps"),
        (lambda: MatchConfig(max_steps=2.5), "max_steps"),
        (lambda: MatchConfig(on_physics_error="ignore"), "on_physics_error"),
        (lambda: RewardConfig(still=1.0), "still"),
        (lambda: RewardConfig(opponent_velocity=float("inf")), "opponent_velocity"),
        (lambda: RewardConfig(axis_dead_zone=-0.1), "axis_dead_zone"),
        (lambda: RewardConfig(axis_dead_zone=float("nan")), "axis_dead_zone"),
        (lambda: MatchConfig(agents=(PAPER_AGENTS[0], PAPER_AGENTS[0], PAPER_AGENTS[2])), "agents"),
        (lambda: MatchConfig(agents=(PAPER_AGENTS[0], PAPER_AGENTS[1])), "agents"),
    ],
)
def test_config_errors_name_the_field(build, field: str) -> None:
    with pytest.raises(ValueError, match=field):
        build()


def test_duplicate_agent_names_are_rejected_by_the_builder_too() -> None:
    with pytest.raises(ValueError, match="unique"):
        build_model((PAPER_AGENTS[0], PAPER_AGENTS[0], PAPER_AGENTS[2]), PhysicsConfig())


def test_configs_are_frozen() -> None:
    for cfg in (PhysicsConfig(), MatchConfig(), RewardConfig(), PAPER_AGENTS[0]):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(cfg, dataclasses.fields(cfg)[0].name, None)


# ----------------------------------------------------------------- start pose at rest
def test_agents_at_rest_never_touch_and_stand_on_the_tatami(make_match, zeros) -> None:
    """On env v0's ring (visual border markers); on the paper's rim see the next test."""
    match = make_match(physics=V0_PHYSICS)
    owner = np.full(match.model.ngeom, -1)
    for i, a in enumerate(match.sim.agents):
        owner[a.geoms] = i
    start = match.sim.torso_positions().copy()
    for _ in range(300):
        result = match.step_array(zeros(match))
        assert not (result.terminated or result.truncated)
        n = match.data.ncon
        g1, g2 = owner[match.data.contact.geom1[:n]], owner[match.data.contact.geom2[:n]]
        assert not ((g1 >= 0) & (g2 >= 0) & (g1 != g2)).any(), f"agents touch at step {match.steps}"
    # Nobody drifted, and every torso rests above the tatami's top (z = 0.5).
    np.testing.assert_allclose(match.sim.torso_positions()[:, :2], start[:, :2], atol=0.05)
    assert (match.sim.torso_positions()[:, 2] > 0.5).all()
    # At rest, the contact forces summed over every geom of an agent carry its weight.
    forces = match.sim.contact_forces()
    g = match.sim.geom_counts[0]
    gravity = -match.model.opt.gravity[2]
    for i, a in enumerate(match.sim.agents):
        weight = match.model.body_subtreemass[a.torso_body] * gravity
        np.testing.assert_allclose(forces[i * g:(i + 1) * g].sum(axis=0), [0.0, 0.0, weight], atol=1e-3 * weight)


def test_on_the_v1_rim_agents_at_rest_lean_on_it_and_slide_inward(make_match, zeros) -> None:
    """Env v1's ring: from its start (a circle of radius 1.4) legs land on the 3 cm rim, which pushes
    every agent toward the centre; nobody leaves the ring. (Env v2's fair start keeps legs off it.)"""
    match = make_match(physics=V1_PHYSICS)
    start = match.sim.torso_positions().copy()
    border = {match.model.geom(n).id for n in mjcf_names.BORDER_GEOMS}
    touched = set()
    for _ in range(50):
        result = match.step_array(zeros(match))
        assert not (result.terminated or result.truncated)
        n = match.data.ncon
        for g1, g2 in zip(match.data.contact.geom1[:n], match.data.contact.geom2[:n], strict=True):
            pair = {int(g1), int(g2)}
            if pair & border:
                touched |= {i for i, a in enumerate(match.sim.agents) if pair & {int(g) for g in a.geoms}}
    assert touched == {0, 1, 2}  # every agent's legs are on the rim
    moved_in = np.linalg.norm(start[:, :2], axis=1) - np.linalg.norm(match.sim.torso_positions()[:, :2], axis=1)
    assert (moved_in > 0.05).all(), moved_in


# ------------------------------------------------------------------------ the border rim
def _push_ant_at_the_rim(border_rim: bool) -> tuple[set[str], float]:
    """Ant, settled at its start, moved 0.3 m toward the right border and pushed at it at 2 m/s
    for 30 env steps: the names of its geoms that touched a border geom, and the x component of
    the border's contact forces on them, summed over contacts and steps."""
    match = Match(MatchConfig(physics=PhysicsConfig(border_rim=border_rim, layout="circle"),  # Ant at (1.4, 0)
                              reset_noise=ResetNoise(0, 0, 0, 0)))
    match.reset(seed=0)
    sim, model = match.sim, match.model
    for _ in range(30):
        sim.step(np.zeros((3, 8)))
    ant = sim.agents[0]
    qpos, qvel = sim.data.qpos.copy(), np.zeros(model.nv)
    qpos[ant.root_qpos] += 0.3
    qvel[ant.root_qvel] = 2.0
    sim.reset(qpos, qvel)
    rim = {model.geom(n).id for n in mjcf_names.BORDER_GEOMS}
    own = {int(g) for g in ant.geoms}
    touched: set[str] = set()
    push_x, wrench = 0.0, np.zeros(6)
    for _ in range(30):
        sim.step(np.zeros((3, 8)))
        for k, c in enumerate(sim.data.contact[:sim.data.ncon]):
            pair = {int(c.geom1), int(c.geom2)}
            if pair & rim and pair & own:
                touched.add(model.geom((pair & own).pop()).name)
                mujoco.mj_contactForce(model, sim.data, k, wrench)  # contact frame, acts on geom2
                on_ant = c.frame.reshape(3, 3).T @ wrench[:3]
                push_x += float(on_ant[0] if int(c.geom2) in own else -on_ant[0])
    return touched, push_x


def test_border_rim_is_solid_by_default_and_visual_in_v0() -> None:
    """RoboSumo's and the paper's rim: the four cylinders collide with agents (default flags) with
    ``border_rim`` (the default since env v1); the ring's half-size and every other geom stay the same."""
    plain = build_model(PAPER_AGENTS, PhysicsConfig(border_rim=False))
    solid = build_model(PAPER_AGENTS, PhysicsConfig())
    rim = [plain.geom(n).id for n in mjcf_names.BORDER_GEOMS]
    assert (plain.geom_contype[rim] == 0).all() and (plain.geom_conaffinity[rim] == 0).all()
    assert (solid.geom_contype[rim] == 1).all() and (solid.geom_conaffinity[rim] == 1).all()
    np.testing.assert_array_equal(solid.geom_size[rim], plain.geom_size[rim])
    np.testing.assert_allclose(solid.geom_size[rim, 2], 0.03)  # a 3 cm ridge on the tatami's top
    np.testing.assert_allclose(solid.geom_pos[rim, 2], 0.5)
    others = np.setdiff1d(np.arange(plain.ngeom), rim)
    np.testing.assert_array_equal(solid.geom_contype[others], plain.geom_contype[others])
    assert ring_half_size(solid) == ring_half_size(plain) == 2.0


def test_a_torso_pushed_against_the_rim_collides_with_it() -> None:
    touched, push_x = _push_ant_at_the_rim(True)
    assert "ant/torso_geom" in touched
    assert push_x < -1.0  # the rim pushes the torso back toward the centre (newton-steps)
    untouched, none = _push_ant_at_the_rim(False)
    assert untouched == set() and none == 0.0
