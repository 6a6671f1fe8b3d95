"""Env v2's fair start: every agent as far from the ring's edges, legs off the rim (issue 38)."""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest

import triplesumo
from triplesumo.envs.match import Match
from triplesumo.model import V1_PHYSICS, PhysicsConfig, build_model, ring_half_size
from triplesumo.model import names as mjcf_names
from triplesumo.model.layout import edge_distances, fair_layout, rim_margin
from triplesumo.rules.config import MatchConfig, ResetNoise
from triplesumo.rules.scenarios import scenario_config

FAIR = 0.05
"""The issue's bound: every agent's distances within 5 cm of every other's."""

ROSTERS = [("paper", {}), ("bodies", {}), ("2v2", {}), ("ffa", {"n_agents": 2}), ("ffa", {"n_agents": 3}),
           ("ffa", {"n_agents": 4}), ("pursuit", {"n_pursuers": 1}), ("pursuit", {"n_pursuers": 2}),
           ("pursuit", {"n_pursuers": 3})]
"""Every scenario roster of up to four agents: all of them start fair."""
CROWDED = [("ffa", {"n_agents": 5}), ("ffa", {"n_agents": 6}), ("pursuit", {"n_pursuers": 5}),
           ("2v2", {"team_sizes": (3, 3)})]
"""Rosters of five and six quadrupeds, which no fair layout fits in the ring (they fall back to the circle)."""


def start_poses(match: Match) -> list[tuple[float, float, float]]:
    """``(x, y, yaw)`` of every torso after ``reset`` (yaw of the free joint's quaternion)."""
    out = []
    for a in match.sim.agents:
        x, y, _, w, _, _, z = match.data.qpos[a.root_qpos:a.root_qpos + 7]
        out.append((float(x), float(y), float(2 * math.atan2(z, w))))
    return out


def spread(match: Match) -> tuple[float, float]:
    """Largest difference between two agents' nearest-edge distances, and between their behind-edge ones."""
    half = ring_half_size(match.model)
    d = np.array([edge_distances(p, half) for p in start_poses(match)])
    return float(np.ptp(d[:, 0])), float(np.ptp(d[:, 1]))


@pytest.mark.parametrize(("scenario", "sizes"), ROSTERS)
def test_every_roster_of_up_to_four_starts_equally_far_from_the_edges(scenario: str, sizes: dict) -> None:
    """Noise-free, the distances are equal to a micrometre; with the default seeded noise, within 5 cm,
    over 20 seeds (the noise is the only thing that moves them)."""
    cfg = scenario_config(scenario, **sizes)
    assert cfg.physics.layout == "fair"
    bodies = [a.body for a in cfg.agents]
    assert fair_layout(bodies, cfg.physics.start_edge, 2.0) is not None
    quiet = Match(MatchConfig(agents=cfg.agents, reset_noise=ResetNoise(0, 0, 0, 0)))
    quiet.reset(seed=0)
    assert max(spread(quiet)) < 1e-6
    noisy = Match(MatchConfig(agents=cfg.agents))
    worst = 0.0
    for seed in range(20):
        noisy.reset(seed=seed)
        worst = max(worst, *spread(noisy))
    assert 0.0 < worst <= FAIR


def test_the_paper_roster_stands_where_the_papers_code_put_it() -> None:
    """Ant, Bug and Spider at (-1, -1), (1, 1) and (1, -1): 1.0 m from two edges and 1.0 m from the edge
    behind (each turned 45 degrees from facing the centre, legs along the diagonal); the Spider between
    the two of the team. Env v1's circle started the Ant 0.60 m from the edge behind it."""
    match = Match(MatchConfig(reset_noise=ResetNoise(0, 0, 0, 0)))
    match.reset(seed=0)
    poses = start_poses(match)
    np.testing.assert_allclose([p[:2] for p in poses], [(-1, -1), (1, 1), (1, -1)], atol=1e-9)
    for pose in poses:
        np.testing.assert_allclose(edge_distances(pose, 2.0), (1.0, 1.0), atol=1e-9)
    v1 = Match(MatchConfig(physics=V1_PHYSICS, reset_noise=ResetNoise(0, 0, 0, 0)))
    v1.reset(seed=0)
    assert edge_distances(start_poses(v1)[0], 2.0)[1] == pytest.approx(0.6)
    assert spread(v1)[0] > 0.15  # the unfair ring v2 replaces


@pytest.mark.parametrize(("scenario", "sizes"), ROSTERS)
def test_no_leg_rests_on_the_rim_at_a_fair_start(scenario: str, sizes: dict) -> None:
    """Zero actions for 15 steps from a noise-free and a noisy start: no agent geom touches a border geom
    (env v1's start put every agent's legs on it), and every body's zero pose is clear of it."""
    cfg = scenario_config(scenario, **sizes)
    for noise in (ResetNoise(0, 0, 0, 0), None):  # noise-free, and the fair layout's own noise
        match = Match(MatchConfig(agents=cfg.agents, reset_noise=noise))
        match.reset(seed=3)
        border = {match.model.geom(n).id for n in mjcf_names.BORDER_GEOMS}
        for a, pose in zip(cfg.agents, start_poses(match), strict=True):
            assert rim_margin(a.body, pose, 2.0) > 0.0
        for _ in range(15):
            match.step_array(np.zeros((len(cfg.agents), match.action_width)))
            n = match.data.ncon
            pairs = zip(match.data.contact.geom1[:n], match.data.contact.geom2[:n], strict=True)
            assert not any({int(g1), int(g2)} & border for g1, g2 in pairs), f"a leg on the rim at step {match.steps}"


@pytest.mark.parametrize(("scenario", "sizes"), CROWDED)
def test_rosters_no_fair_layout_fits_start_on_the_circle(scenario: str, sizes: dict) -> None:
    """Five or six quadrupeds cannot stand clear of each other and of the rim at equal distances from the
    edges; they get the circle layout (documented), and still start clear of each other."""
    cfg = scenario_config(scenario, **sizes)
    assert fair_layout([a.body for a in cfg.agents], cfg.physics.start_edge, 2.0) is None
    model = build_model(cfg.agents, cfg.physics)
    circle = build_model(cfg.agents, PhysicsConfig(layout="circle"))
    np.testing.assert_array_equal(model.qpos0, circle.qpos0)


def test_the_box_rim_has_the_cylinders_height_width_and_corners() -> None:
    """Env v2's rim: four boxes, 6 cm wide and 3 cm above the tatami like v1's cylinders, meeting at the
    corners; the ring's half-size is unchanged."""
    box, cyl = build_model(triplesumo.model.PAPER_AGENTS, PhysicsConfig()), build_model(
        triplesumo.model.PAPER_AGENTS, V1_PHYSICS)
    rim = [box.geom(n).id for n in mjcf_names.BORDER_GEOMS]
    assert (box.geom_type[rim] == 6).all() and (cyl.geom_type[rim] == 5).all()  # mjGEOM_BOX, mjGEOM_CYLINDER
    np.testing.assert_allclose(np.sort(box.geom_size[rim], axis=1), [[0.03, 0.03, 2.03]] * 4)
    np.testing.assert_allclose(box.geom_pos[rim], cyl.geom_pos[rim])
    assert ring_half_size(box) == ring_half_size(cyl) == 2.0


def test_v1_ids_are_deprecated_naming_v2() -> None:
    for old, new in (("TripleSumo-v1", "TripleSumo-v2"), ("TripleSumo-Paper-v1", "TripleSumo-Paper-v2"),
                     ("TripleSumo-FFA-v1", "TripleSumo-FFA-v2")):
        with pytest.raises(gymnasium.error.DeprecatedEnv, match=new):
            gymnasium.make(old)
    assert triplesumo.ENV_VERSION == "v2"
    assert triplesumo.parallel_env().metadata["name"] == "triplesumo_v2"


def test_old_records_read_back_as_the_circle_and_the_cylinder() -> None:
    """A run folder or manifest written before v2 has no layout or rim shape: it was the circle and the
    cylinders, and reads back so (a v1 policy keeps its ring); the new fields are recorded from now on."""
    import dataclasses

    from triplesumo.train.config import TrainConfig
    from triplesumo.train.run_folder import config_from_json, config_to_json

    saved = config_to_json(TrainConfig())
    assert saved["physics"]["layout"] == "fair" and saved["physics"]["rim_shape"] == "box"
    for key in ("layout", "start_edge", "rim_shape"):
        del saved["physics"][key]
    assert config_from_json(saved).physics == V1_PHYSICS
    assert dataclasses.asdict(V1_PHYSICS)["layout"] == "circle"
    with pytest.raises(ValueError, match="PhysicsConfig.layout must be one of"):
        PhysicsConfig(layout="square")
    with pytest.raises(ValueError, match="PhysicsConfig.rim_shape must be one of"):
        PhysicsConfig(rim_shape="torus")


def test_each_layout_brings_its_own_reset_noise() -> None:
    """A match config that names no noise gets its layout's: the fair start's small noise (edge distances within
    5 cm), v1's 0.1 m and 0.1 rad on the circle, so that V1_PHYSICS replays env v1 exactly."""
    from triplesumo.rules.config import LAYOUT_NOISE

    assert MatchConfig().reset_noise == LAYOUT_NOISE["fair"] == ResetNoise(position=0.02, yaw=0.05)
    assert MatchConfig(physics=V1_PHYSICS).reset_noise == ResetNoise() == ResetNoise(0.1, 0.1, 0.1, 0.1)
    assert MatchConfig(physics=V1_PHYSICS, reset_noise=ResetNoise(0, 0, 0, 0)).reset_noise.position == 0
    with pytest.raises(ValueError, match="MatchConfig.reset_noise must be a ResetNoise"):
        MatchConfig(reset_noise=0.1)  # type: ignore[arg-type]
